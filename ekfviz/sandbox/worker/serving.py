"""The worker's loop: a request read, the user's filter called, its state answered; the
user's module loaded, tolerant of a script's top-level work."""

from __future__ import annotations

import ast
import importlib
import os
import sys
import time
import traceback
import types
from typing import Any, Callable, Dict, List, Optional, Tuple

import numpy as np

from .course import COURSE_FUNCTIONS, CourseModule, Params
from .faults import ExitFault, FilterFault, UserError, said, top_level_line, user_line
from .framing import PROTOCOL, read_message, shown, write_message
from .no_windows import WindowlessMatplotlib

# the top-level statements of a course module that may be skipped when they raise at
# import: a script's work (calls, loops, assignments); never an import, a definition or a
# raise, which are the module's own and its error then
_SKIPPABLE = (
    ast.Expr, ast.Assign, ast.AugAssign, ast.AnnAssign, ast.For, ast.While, ast.With, ast.If,
    ast.Try,
)  # fmt: skip


def _identifier(text: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in text)


def _package_of(path: str) -> str:
    """The name of a package made for the folder of the module at ``path`` (its
    ``__init__.py``, if any, not run), so that the module's relative imports (``from
    .utils import wrap``) find the files beside it, as they do where it is run as part of
    its folder's package."""
    folder = os.path.dirname(os.path.abspath(path))
    name = "ekfviz_user_folder_" + _identifier(folder)[-60:]
    if name not in sys.modules:
        package = types.ModuleType(name)
        package.__path__ = [folder]
        package.__package__ = name
        sys.modules[name] = package
    return name


RESERVE_BYTES = 4 << 20  # memory kept to answer a MemoryError when the filter holds the rest


class Worker:
    def __init__(self, commands: Any, answers: Any) -> None:
        self.commands = commands
        self.answers = answers
        self.module: Any = None
        self.target: Optional[str] = None
        self.filter: Any = None
        self.matplotlib = WindowlessMatplotlib()
        sys.meta_path.insert(0, self.matplotlib)
        self.reserve: Optional[bytearray] = bytearray(RESERVE_BYTES)  # see serve()

    def serve(self) -> None:
        while True:
            try:
                header, arrays = read_message(self.commands)
            except EOFError:
                return
            op = header.get("op")
            if op == "close":
                self.reply({"ok": True})
                return
            started = time.perf_counter()
            try:
                answer, out = self.dispatch(op, header, arrays)
            except UserError as error:
                if isinstance(error.error, MemoryError):  # formatted, it would need memory
                    self.out_of_memory(error.function)  # that the filter may still hold
                else:
                    self.reply(self.fault(error.function, error.error, error.trace))
                continue
            except FilterFault as error:
                self.reply({"ok": False, "kind": error.kind, "message": str(error)})
                continue
            except SystemExit as error:
                code = error.code
                self.reply(
                    {
                        "ok": False,
                        "kind": "exit",
                        "message": "%s called sys.exit(%s)" % (op, shown(repr, code)),
                        "traceback": traceback.format_exc(),
                    }
                )
                continue
            except MemoryError:
                self.out_of_memory(str(op))
                continue
            except BaseException as error:
                self.reply(self.fault(str(op), error, traceback.format_exc()))
                continue
            answer["ok"] = True
            answer["seconds"] = time.perf_counter() - started
            self.reply(answer, out)

    def out_of_memory(self, where: str) -> None:
        """Say a MemoryError where the memory may still be held (a module's list grown
        without end): the reserve is given back to say it, without a traceback to format."""
        self.reserve = None
        answer = {"ok": False, "kind": "memory", "type": "MemoryError", "traceback": ""}
        answer["message"] = "%s raised MemoryError" % where
        self.reply(answer)
        try:
            self.reserve = bytearray(RESERVE_BYTES)
        except MemoryError:
            pass

    def fault(self, where: str, error: BaseException, trace: str) -> Dict[str, Any]:
        return {
            "ok": False,
            "kind": "memory" if isinstance(error, MemoryError) else "raised",
            "type": type(error).__name__,
            "message": "%s raised %s%s%s"
            % (where, type(error).__name__, said(error), user_line(error)),
            "traceback": trace,
        }

    def reply(self, header: Dict[str, Any], arrays: Optional[List[Any]] = None) -> None:
        for stream in (sys.stdout, sys.stderr):  # the user's, whatever it made of them
            try:  # (sys.stdout = None to silence prints: harmless in plain Python)
                stream.flush()
            except Exception:
                pass
        write_message(self.answers, header, arrays or [])

    def dispatch(
        self, op: Any, header: Dict[str, Any], arrays: List[Any]
    ) -> Tuple[Dict[str, Any], List[Any]]:
        if op == "hello":
            return {
                "protocol": PROTOCOL,
                "python": "%d.%d.%d" % sys.version_info[:3],
                "numpy": np.__version__,
                "pid": os.getpid(),
            }, []
        if op == "load":
            return self.load(header), []
        if op == "construct":
            return self.construct(header)
        if self.filter is None:
            raise FilterFault("no filter constructed")
        if op == "predict":
            self.call(
                "predict",
                lambda: (
                    self.filter.predict(header["d"], header["alpha"], header["dt"])
                    if header.get("dt_arg")
                    else self.filter.predict(header["d"], header["alpha"])
                ),
            )
        elif op == "update":
            ids, z = arrays
            self.call("update", lambda: self.filter.update(ids.copy(), z.copy()))
        elif op == "remove_landmarks":
            self.call("remove_landmarks", lambda: self.filter.remove_landmarks(list(header["ids"])))
        elif op == "finish":
            self.call("finish", self.filter.finish)
            return self.state(path=True)
        else:
            raise FilterFault("unknown request %r" % (op,))
        return self.state()

    def call(self, function: str, action: Callable[[], Any]) -> None:
        try:
            action()
        except (UserError, FilterFault, SystemExit, KeyboardInterrupt):
            raise
        except BaseException as error:
            raise UserError(function, error, traceback.format_exc()) from None

    def load(self, header: Dict[str, Any]) -> Dict[str, Any]:
        path = header.get("path")
        module_name = header.get("module")
        self.target = header.get("name")
        for entry in reversed(header.get("sys_path", [])):
            if entry not in sys.path:
                sys.path.insert(0, entry)
        try:
            if path is not None:
                name = _package_of(path) + ".ekfviz_user_" + _identifier(path)[-60:]
                spec = importlib.util.spec_from_file_location(name, path)
                if spec is None or spec.loader is None:
                    raise FilterFault("%s: not a Python file" % path)
                module = importlib.util.module_from_spec(spec)
                sys.modules[name] = module
                spec.loader.exec_module(module)
            else:
                module = importlib.import_module(str(module_name))
        except FilterFault:
            raise
        except SystemExit as error:
            raise ExitFault(
                "importing %s called sys.exit(%r)" % (path or module_name, error.code)
            ) from None
        except BaseException as error:
            trace = traceback.format_exc()
            # a course module's (not a class's): a student's script, not a developer's module
            course = path is not None and not self.target
            line = top_level_line(error, str(path)) if course else None
            if line is None:
                raise UserError("importing %s" % (path or module_name), error, trace) from None
            module = self.tolerant(str(path), name, line, error)
        self.module = module
        where = path or module_name
        if self.target:
            found = getattr(module, self.target, None)
            if not isinstance(found, type):
                raise FilterFault("%s has no class %s" % (where, self.target))
            return {"style": "class", "capabilities": self.capabilities(found)}
        missing = [f for f in COURSE_FUNCTIONS if not callable(getattr(module, f, None))]
        if missing:
            instance = self.course_class(module, str(where))
            if instance is not None:
                self.module = instance
                missing = []
        if missing:
            # the module's own classes first: an imported base class is not its filter
            classes = sorted(
                (
                    n
                    for n, v in vars(module).items()
                    if isinstance(v, type)
                    and callable(getattr(v, "predict", None))
                    and callable(getattr(v, "update", None))
                ),
                key=lambda n: (getattr(vars(module)[n], "__module__", "") != module.__name__, n),
            )
            also = "; or name its filter class: %s:%s" % (where, classes[0]) if classes else ""
            raise FilterFault(
                "%s has no function %s: a course module has init_landmarks, predict and update%s"
                % (where, " or ".join(missing), also)
            )
        return {
            "style": "functions",
            "capabilities": {
                "takes_dt": False,
                "removes_landmarks": False,
                "offline": False,
                "poses": False,
            },
        }

    def tolerant(self, path: str, name: str, line: Tuple[int, str], error: BaseException) -> Any:
        """The module at ``path`` loaded again one top-level statement at a time, without
        those that raise: its top-level code ran at import (the handout's ``main()`` left
        without its ``if __name__ == "__main__":`` guard, a script's loop over the data
        file) and raised ``error`` at ``line`` (the line, and the module's function it
        called there, if any). Said on the filter's output; an import that fails is the
        error then."""
        import __future__

        with open(path, "rb") as handle:
            tree = ast.parse(handle.read(), path)
        module = types.ModuleType(name)
        module.__file__ = path
        module.__package__ = name.rpartition(".")[0]  # its relative imports, as at import
        sys.modules[name] = module
        flags = 0
        skipped: List[int] = []
        for statement in tree.body:
            if isinstance(statement, ast.ImportFrom) and statement.module == "__future__":
                for alias in statement.names:
                    flags |= getattr(__future__, alias.name).compiler_flag
            body = ast.Module(body=[statement], type_ignores=[])
            code = compile(body, path, "exec", flags=flags, dont_inherit=True)
            try:
                exec(code, module.__dict__)
            except (SystemExit, KeyboardInterrupt):
                raise
            except BaseException as again:
                if not isinstance(statement, _SKIPPABLE):  # an import, a def, a raise
                    trace = traceback.format_exc()
                    raise UserError("importing %s" % path, again, trace) from None
                skipped.append(statement.lineno)
        number, function = line
        what = "calls %s() at import" % function if function else "runs at import"
        others = [n for n in skipped if n != number]
        also = ""
        if others:
            also = " (and line%s %s)" % ("s" * (len(others) > 1), ", ".join(map(str, others)))
        print(
            "ekfviz: importing %s raised %s%s%s; its line %d %s (no `if __name__ =="
            ' "__main__":` guard): ekfviz skipped it%s and loaded the rest (put it under'
            " the guard)"
            % (path, type(error).__name__, said(error), user_line(error), number, what, also),
            file=sys.stderr,
        )
        return module

    def course_class(self, module: Any, where: str) -> Any:
        """An instance of the module's class of the handout's functions as methods
        (``init_landmarks``, ``predict``, ``update``), made without arguments; None when
        the module has no such class. Raises when it has one that cannot be made."""
        classes = [
            value
            for value in vars(module).values()
            if isinstance(value, type)
            and getattr(value, "__module__", None) == module.__name__
            and all(callable(getattr(value, f, None)) for f in COURSE_FUNCTIONS)
        ]
        if len(classes) != 1:
            return None
        cls = classes[0]
        try:
            return cls()
        except Exception as error:
            raise FilterFault(
                "%s has the handout's functions as methods of class %s, which cannot be"
                " made without arguments (%s: %s): give it defaults, or write the functions"
                " at module level" % (where, cls.__name__, type(error).__name__, error)
            ) from None

    def capabilities(self, cls: Any) -> Dict[str, Any]:
        import inspect

        takes_dt = False
        predict = getattr(cls, "predict", None)
        if callable(predict):
            try:
                parameters = list(inspect.signature(predict).parameters.values())
            except (TypeError, ValueError):
                parameters = []
            positional = [
                p
                for p in parameters
                if p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD) and p.name != "self"
            ]
            takes_dt = len(positional) >= 3 or any(p.kind is p.VAR_POSITIONAL for p in parameters)
        return {
            "takes_dt": takes_dt,
            "removes_landmarks": callable(getattr(cls, "remove_landmarks", None)),
            "offline": callable(getattr(cls, "finish", None)),
            "poses": hasattr(cls, "poses_xytheta"),
        }

    def construct(self, header: Dict[str, Any]) -> Tuple[Dict[str, Any], List[Any]]:
        params = Params(header["params"], header["noise"])
        if self.target:
            cls = getattr(self.module, self.target)
            self.call("construction", lambda: setattr(self, "filter", cls(params)))
        else:
            self.filter = CourseModule(self.module, params, header["noise"])
        return self.state(noise=True)

    def state(self, path: bool = False, noise: bool = False) -> Tuple[Dict[str, Any], List[Any]]:
        """The filter's x, P and landmark ids (and its own noise, its path) as arrays."""
        slam = self.filter
        arrays = []
        for name in ("x", "P"):
            try:
                value = getattr(slam, name)
            except BaseException as error:
                raise UserError("reading %s" % name, error, traceback.format_exc()) from None
            array = _array_of(value, name)
            arrays.append(array.reshape(-1) if name == "x" else array)
        try:
            ids = [int(i) for i in list(np.asarray(slam.landmark_ids).reshape(-1))]
        except BaseException as error:
            raise UserError("reading landmark_ids", error, traceback.format_exc()) from None
        wide = [i for i in ids if not -(1 << 63) <= i < (1 << 63)]
        if wide:  # (a hash of 64 bits unsigned): refused here, not where ekfviz reads them
            raise FilterFault(
                "landmark_ids holds %d, expected ids that fit a 64-bit signed integer" % wide[0]
            )
        answer: Dict[str, Any] = {"ids": ids, "extra": []}
        if isinstance(slam, CourseModule):
            answer["convention"] = slam.convention()
        if noise:
            for name in ("measurement_noise", "motion_noise"):
                value = getattr(slam, name, None)
                if value is not None:
                    answer["extra"].append(name)
                    arrays.append(_array_of(value, name))
        if path:
            try:
                poses = getattr(slam, "poses_xytheta", None)
            except BaseException as error:
                raise UserError("reading poses_xytheta", error, traceback.format_exc()) from None
            if poses is not None:
                answer["extra"].append("poses_xytheta")
                arrays.append(_array_of(poses, "poses_xytheta"))
        return answer, arrays


def _array_of(value: Any, name: str) -> Any:
    if np.iscomplexobj(value):
        raise FilterFault("%s holds complex numbers, expected real ones" % name)
    try:
        array = np.array(value, dtype=np.float64)
    except Exception as error:  # complex values, ragged lists, objects
        raise FilterFault(
            "%s is not an array of real numbers (%s: %s)" % (name, type(error).__name__, error)
        ) from None
    return array
