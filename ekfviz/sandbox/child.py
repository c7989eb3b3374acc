"""The worker side of a user's filter: runs in a process of its own, any Python >= 3.8.

ekfviz starts this file with the interpreter of ``--python`` (its own by default); it needs
only the standard library and numpy >= 1.17, never ekfviz, so that a filter written for
another numpy runs unchanged in its own environment. It loads the user's module, runs the
filter's calls one by one and answers each with the filter's state.

Channels (set up before any user code runs):

- commands come on what was stdin, answers go on what was stdout; both are moved to
  private descriptors, stdin becomes /dev/null and stdout joins stderr, so that whatever the
  filter prints (Python or C) goes to stderr, which ekfviz captures as the filter's output;
- a message is a 4-byte little-endian length, a JSON header, then the raw bytes of each
  array the header lists (``{"__nd__": i}`` in the JSON; shape and dtype in
  ``header["arrays"]``): numpy objects never cross as pickles, so both sides may run
  different numpy versions.

Two kinds of filter: a class of ekfviz's filter protocol (``PATH.py:Class``), and a
course module of functions ``init_landmarks``, ``predict``, ``update`` in the handout's
shapes (column vectors), run here by :class:`CourseModule`, which detects which shapes the
functions take (control (2, 1) or (2,), measurements (2k, 1) or (2k,), X (3+2k, 1) or
(3+2k,)) and checks what they return.

Kept to Python 3.8's syntax and numpy 1.17's API on purpose (no ``X | Y`` outside
annotations, no ``zip(strict=...)``, no ``match``).
"""

from __future__ import annotations

import ast
import builtins
import importlib
import importlib.abc
import importlib.machinery
import importlib.util
import io
import json
import os
import signal
import struct
import sys
import time
import traceback
import types
from typing import Any, Callable, Dict, List, Optional, Tuple


def _sandbox_paths_first() -> None:
    """In a sandbox, the interpreter runs without its site-packages (``-S``): the folder
    that holds numpy there (the settings' ``sys_path``) goes first on ``sys.path``, before
    numpy is imported below."""
    if len(sys.argv) > 1 and sys.argv[1].startswith("{"):
        for entry in reversed(json.loads(sys.argv[1]).get("sys_path", [])):
            sys.path.insert(0, entry)


_sandbox_paths_first()

import numpy as np  # noqa: E402 (after the sandbox's sys.path)

PROTOCOL = 1
COURSE_FUNCTIONS = ("init_landmarks", "predict", "update")


# -- framing ---------------------------------------------------------------------------------


def _read_exact(stream: Any, count: int) -> bytes:
    chunks = []
    left = count
    while left:
        chunk = stream.read(left)
        if not chunk:
            raise EOFError
        chunks.append(chunk)
        left -= len(chunk)
    return b"".join(chunks)


# the longest message of a user's exception that ekfviz's one line shows (--debug shows
# the whole traceback): an exception may carry megabytes of text, or a __str__ that raises
MAX_MESSAGE = 1000


def _shown(convert: Any, value: Any) -> str:
    """``convert(value)`` (``str`` or ``repr``) cut to :data:`MAX_MESSAGE` characters,
    or a note where it raises."""
    try:
        text = convert(value)
    except BaseException as error:  # a __str__ or __repr__ that fails, or loops to the bound
        return "(its text cannot be shown: %s raised %s)" % (
            convert.__name__,
            type(error).__name__,
        )
    if not isinstance(text, str):
        return "(its text cannot be shown)"
    if len(text) > MAX_MESSAGE:
        return "%s... (%d characters in all)" % (text[:MAX_MESSAGE], len(text))
    return text


def read_message(stream: Any) -> Tuple[Dict[str, Any], List[Any]]:
    """One message: its JSON header and its arrays."""
    (size,) = struct.unpack("<I", _read_exact(stream, 4))
    header = json.loads(_read_exact(stream, size).decode("utf-8"))
    arrays = []
    for meta in header.get("arrays", []):
        dtype = np.dtype(meta["dtype"])
        shape = tuple(meta["shape"])
        count = int(np.prod(shape)) if shape else 1
        data = _read_exact(stream, count * dtype.itemsize)
        arrays.append(np.frombuffer(data, dtype=dtype).reshape(shape).copy())
    return header, arrays


def write_message(stream: Any, header: Dict[str, Any], arrays: List[Any]) -> None:
    """Send one message (see the module docstring)."""
    contiguous = [np.ascontiguousarray(a) for a in arrays]
    header = dict(header)
    header["arrays"] = [{"shape": list(a.shape), "dtype": a.dtype.str} for a in contiguous]
    data = json.dumps(header, allow_nan=True).encode("utf-8")
    stream.write(struct.pack("<I", len(data)))
    stream.write(data)
    for a in contiguous:
        # the array's own buffer, not a copy of it (a state of a few MB crosses every event)
        stream.write(memoryview(a.reshape(-1)).cast("B") if a.size else b"")  # type: ignore[arg-type]
    stream.flush()


# -- what the filter is given ------------------------------------------------------------------


class Params:
    """ekfviz's filter parameters as plain attributes, with ``Q`` and ``R`` as arrays (as
    ekfviz made them: ``noise``)."""

    def __init__(self, values: Dict[str, Any], noise: Dict[str, Any]) -> None:
        self._values = dict(values)
        self._noise = noise
        for name, value in values.items():
            setattr(self, name, tuple(value) if isinstance(value, list) else value)

    @property
    def Q(self) -> Any:
        """Motion noise covariance (3x3) in the robot frame."""
        return np.array(self._noise["Q"], dtype=np.float64)

    @property
    def R(self) -> Any:
        """Measurement noise covariance (2x2) of (bearing, range)."""
        return np.array(self._noise["R"], dtype=np.float64)

    def as_dict(self) -> Dict[str, Any]:
        return dict(self._values)

    def __repr__(self) -> str:
        return "FilterParams(%s)" % ", ".join("%s=%r" % kv for kv in self._values.items())


class FilterFault(Exception):
    """What the user's code did wrong, said in one line (no traceback of ours)."""

    kind = "fault"


class ExitFault(FilterFault):
    """The user's code called ``sys.exit``."""

    kind = "exit"


def _shape(value: Any) -> str:
    shape = getattr(value, "shape", None)
    if shape is not None:
        return str(tuple(shape))
    if isinstance(value, (list, tuple)):
        return "a %s of %d" % (type(value).__name__, len(value))
    return "a %s" % type(value).__name__


def _floats(value: Any, function: str, name: str) -> Any:
    if np.iscomplexobj(value):
        raise FilterFault(
            "%s returned %s with complex numbers, expected real ones" % (function, name)
        )
    try:
        array = np.array(value, dtype=np.float64)
    except Exception as error:  # ragged lists, objects, complex values
        raise FilterFault(
            "%s returned %s that is not an array of numbers (%s: %s)"
            % (function, name, type(error).__name__, error)
        ) from None
    return array


# -- course modules ------------------------------------------------------------------------------


class CourseModule:
    """A module of the handout's functions behind the filter protocol.

    The state is kept as a (3+2k, 1) column; k landmarks, all named by the first
    observation (the classic format). Each function is called with the shapes it takes
    (X a column (3+2k, 1) or flat (3+2k,), likewise the control, the measurements and the
    initial pose): the shapes it took last first, then the handout's, then the others, at
    every call. The adapter does no filter math: Q, R and the prior's covariance come
    from ekfviz (``noise``), and P after the first line is the handout's main()'s
    block_diag(pose_cov, landmark_cov) (with init_cross_covariance, where the module has
    it, in its off-diagonal blocks).
    """

    def __init__(self, module: Any, params: Params, noise: Dict[str, Any]) -> None:
        self.module = module
        self.X = np.array(params.init_pose, dtype=np.float64).reshape(3, 1)  # type: ignore[attr-defined]
        self.P = np.array(noise["prior"], dtype=np.float64)
        self.control_cov = np.array(noise["Q"], dtype=np.float64)
        self.measure_cov = np.array(noise["R"], dtype=np.float64)
        self.landmark_ids: List[int] = []
        # the shapes each function took at its last call (argument -> column?), and every
        # shape each argument was taken in (what check reports)
        self.last: Dict[str, Dict[str, bool]] = {}
        self.taken: Dict[str, List[bool]] = {"X": [], "control": [], "measure": []}

    # the protocol ------------------------------------------------------------------------

    @property
    def x(self) -> Any:
        return self.X.reshape(-1)

    @property
    def k(self) -> int:
        return len(self.landmark_ids)

    def convention(self) -> Dict[str, Any]:
        """The shapes taken so far, by argument: "column", "flat", "either" (both, by
        function or by call) or None."""
        said = {}
        for name, taken in self.taken.items():
            kinds = set(taken)
            said[name] = (
                None if not kinds else "either" if len(kinds) > 1
                else ("column" if taken[0] else "flat")
            )  # fmt: skip
        return said

    def predict(self, d: float, alpha: float) -> None:
        n = 3 + 2 * self.k

        def call(shape: Dict[str, bool]) -> Any:
            control = np.array([[d], [alpha]]) if shape["control"] else np.array([d, alpha])
            return self.module.predict(
                self._state_as(shape["X"]), self.P.copy(), control, self.control_cov.copy(), self.k
            )

        self.X, self.P = self._first_working("predict", ("X", "control"), call, n)

    def update(self, ids: Any, z: Any) -> None:
        ids_list = [int(i) for i in ids]
        z = np.asarray(z, dtype=np.float64).reshape(-1, 2)
        if not self.landmark_ids:
            self._initialise(ids_list, z)
            return
        if ids_list != self.landmark_ids:
            raise FilterFault(
                "a course module reads the classic format: every observation names the %d"
                " landmark%s of the first one, in the same order (ids %s); this one names %s"
                " (the handout's update takes the measurements of all k landmarks, in their"
                " order, and init_landmarks is called once, on the first line)"
                % (self.k, "" if self.k == 1 else "s", self.landmark_ids, ids_list)
            )
        n = 3 + 2 * self.k

        def call(shape: Dict[str, bool]) -> Any:
            measure = z.reshape(-1, 1) if shape["measure"] else z.reshape(-1)
            return self.module.update(
                self._state_as(shape["X"]), self.P.copy(), measure.copy(),
                self.measure_cov.copy(), self.k,
            )  # fmt: skip

        self.X, self.P = self._first_working("update", ("X", "measure"), call, n)

    # inside -------------------------------------------------------------------------------

    def _shapes(self, function: str, names: Tuple[str, ...]) -> List[Dict[str, bool]]:
        """The shapes to call ``function`` with, in order: those it took last, the
        handout's (every argument a column), then the others."""
        options = [{}]  # type: List[Dict[str, bool]]
        for name in names:
            options = [dict(o, **{name: column}) for o in options for column in (True, False)]
        last = self.last.get(function)
        if last is not None:
            options.sort(key=lambda option: option != last)
        return options

    def _state_as(self, column: bool) -> Any:
        """A copy of X as the functions take it: a (3+2k, 1) column or (3+2k,)."""
        X = self.X.reshape(-1, 1) if column else self.X.reshape(-1)
        return X.copy()

    def _took(self, function: str, shape: Dict[str, bool]) -> None:
        self.last[function] = shape
        for name, column in shape.items():
            taken = self.taken.setdefault("X" if name == "pose" else name, [])
            if column not in taken:
                taken.append(column)

    def _first_working(
        self, function: str, names: Tuple[str, ...], call: Callable[..., Any], n: int
    ) -> Tuple[Any, Any]:
        """X, P of the first of the shapes (see :meth:`_shapes`) ``function`` works with;
        the first failure is the one reported if none works."""
        first_error: Optional[BaseException] = None
        first_trace: Optional[str] = None
        for shape in self._shapes(function, names):
            try:
                X, P = self._checked(function, call(shape), n)
            except (SystemExit, KeyboardInterrupt):
                raise
            except BaseException as error:
                if first_error is None:
                    first_error = error
                    first_trace = traceback.format_exc()
                continue
            self._took(function, shape)
            return X, P
        assert first_error is not None
        if isinstance(first_error, FilterFault):
            raise first_error
        raise UserError(function, first_error, first_trace or "")

    def _checked(self, function: str, result: Any, n: int) -> Tuple[Any, Any]:
        """X and P as returned by ``function``, their shapes and values checked."""
        if not isinstance(result, (tuple, list)) or len(result) != 2:
            what = "None (no return statement?)" if result is None else _shape(result)
            raise FilterFault(
                "%s returned %s, expected (X, P): the state (%d, 1) and its covariance (%d, %d)"
                % (function, what, n, n, n)
            )
        X = _floats(result[0], function, "X")
        P = _floats(result[1], function, "P")
        if X.shape == (n, n) and P.shape in ((n, 1), (n,)):
            raise FilterFault(
                "%s returned (P, X), expected (X, P): its first value has shape %s, its"
                " second %s" % (function, X.shape, P.shape)
            )
        if X.shape not in ((n, 1), (n,), (1, n)):
            raise FilterFault(
                "%s returned X of shape %s, expected (%d, 1) or (%d,) (3 + 2k with k = %d)"
                % (function, X.shape, n, n, self.k)
            )
        if P.shape != (n, n):
            raise FilterFault(
                "%s returned P of shape %s, expected (%d, %d) to match X"
                % (function, P.shape, n, n)
            )
        return X.reshape(n, 1), P

    def _initialise(self, ids: List[int], z: Any) -> None:
        pose = self.X[:3].copy()
        pose_cov = self.P[:3, :3].copy()
        k = len(ids)

        def call(shape: Dict[str, bool]) -> Any:
            measure = z.reshape(-1, 1) if shape["measure"] else z.reshape(-1)
            init_pose = pose.reshape(3, 1) if shape["pose"] else pose.reshape(3)
            result = self.module.init_landmarks(
                measure.copy(), self.measure_cov.copy(), init_pose.copy(), pose_cov.copy()
            )
            landmark, landmark_cov = self._checked_init(result, k)
            cross = self._cross_covariance(measure, init_pose, pose_cov, k)
            return landmark, landmark_cov, cross

        errors: List[Tuple[BaseException, str]] = []
        for shape in self._shapes("init_landmarks", ("measure", "pose")):
            try:
                landmark, landmark_cov, cross = call(shape)
            except (SystemExit, KeyboardInterrupt):
                raise
            except BaseException as error:
                errors.append((error, traceback.format_exc()))
                continue
            n = 3 + 2 * k
            P = np.zeros((n, n))  # the handout's block_diag(pose_cov, landmark_cov)
            P[:3, :3] = pose_cov
            P[3:, 3:] = landmark_cov
            if cross is not None:
                P[3:, :3] = cross
                P[:3, 3:] = cross.T
            self.X = np.vstack([pose.reshape(3, 1), landmark.reshape(-1, 1)])
            self.P = P
            self.landmark_ids = list(ids)
            self._took("init_landmarks", shape)
            return
        first, trace = errors[0]
        if isinstance(first, FilterFault):
            raise first
        raise UserError("init_landmarks", first, trace)

    def _cross_covariance(self, measure: Any, init_pose: Any, pose_cov: Any, k: int) -> Any:
        """The module's own init_cross_covariance (2k, 3), where it has one; else None."""
        cross_of = getattr(self.module, "init_cross_covariance", None)
        if not callable(cross_of):
            return None
        cross = _floats(
            cross_of(measure.copy(), init_pose.copy(), pose_cov.copy()),
            "init_cross_covariance",
            "the cross-covariance",
        )
        if cross.shape != (2 * k, 3):
            raise FilterFault(
                "init_cross_covariance returned shape %s, expected (%d, 3)" % (cross.shape, 2 * k)
            )
        return cross

    def _checked_init(self, result: Any, k: int) -> Tuple[Any, Any]:
        if not isinstance(result, (tuple, list)) or len(result) != 3:
            raise FilterFault(
                "init_landmarks returned %s, expected (k, landmarks (%d, 1), landmark_cov"
                " (%d, %d))" % (_shape(result), 2 * k, 2 * k, 2 * k)
            )
        count, landmark, landmark_cov = result
        try:
            count_ok = int(count) == k
        except (TypeError, ValueError):
            count_ok = False
        if not count_ok:
            raise FilterFault(
                "init_landmarks returned k = %r, expected %d (the landmarks of the first line)"
                % (count, k)
            )
        landmark = _floats(landmark, "init_landmarks", "the landmarks")
        landmark_cov = _floats(landmark_cov, "init_landmarks", "landmark_cov")
        if landmark.shape not in ((2 * k, 1), (2 * k,), (1, 2 * k)):
            raise FilterFault(
                "init_landmarks returned the landmarks with shape %s, expected (%d, 1) or (%d,)"
                % (landmark.shape, 2 * k, 2 * k)
            )
        if landmark_cov.shape != (2 * k, 2 * k):
            raise FilterFault(
                "init_landmarks returned landmark_cov with shape %s, expected (%d, %d)"
                % (landmark_cov.shape, 2 * k, 2 * k)
            )
        return landmark, landmark_cov


class UserError(Exception):
    """An exception raised by the user's code, with where and its traceback."""

    def __init__(self, function: str, error: BaseException, trace: str) -> None:
        super().__init__("%s raised %s: %s" % (function, type(error).__name__, error))
        self.function = function
        self.error = error
        self.trace = trace


def _said(error: BaseException) -> str:
    """``": message"`` of an exception on one line (numpy's run over several: its lines
    joined by spaces), cut as :func:`_shown` cuts it; nothing when it has none."""
    text = " ".join(_shown(str, error).split())  # (a __str__ that raises is said)
    return ": " + text if text else ""


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


def _top_level_line(error: BaseException, path: str) -> Optional[Tuple[int, str]]:
    """The line of the module at ``path``'s top-level code from which ``error`` was
    raised, and the name of the module's function it called there (empty when it raised
    there itself); None when the error did not come from its top-level code."""
    frames = traceback.extract_tb(error.__traceback__)
    target = os.path.abspath(path)
    for index, frame in enumerate(frames):
        if frame.name != "<module>" or os.path.abspath(frame.filename) != target:
            continue
        if not frame.lineno:
            return None
        callee = frames[index + 1] if index + 1 < len(frames) else None
        inside = callee is not None and os.path.abspath(callee.filename) == target
        return frame.lineno, callee.name if inside and callee is not None else ""
    return None


def _user_line(error: BaseException) -> str:
    """Where in the user's code ``error`` was raised: the innermost frame that is neither
    this file's nor of an installed package or the standard library (a student needs the
    line of their own file, not numpy's or matplotlib's), as `` (at ekf_slam.py:47 in
    update: K = ...)``; empty when there is none."""
    import sysconfig

    installed = sysconfig.get_paths()
    skip = tuple(
        os.path.abspath(installed[key]) + os.sep
        for key in ("stdlib", "platstdlib", "purelib", "platlib")
        if key in installed
    ) + (os.path.dirname(np.__file__), os.path.abspath(__file__))
    try:
        frames = traceback.extract_tb(error.__traceback__)
    except Exception:
        return ""
    for frame in reversed(frames):
        if frame.filename.startswith("<"):
            continue
        filename = os.path.abspath(frame.filename)
        if filename.startswith(skip):
            continue
        code = (frame.line or "").strip()
        if len(code) > 80:
            code = code[:77] + "..."
        return " (at %s:%d in %s%s)" % (
            os.path.basename(filename),
            frame.lineno or 0,
            frame.name,
            ": " + code if code else "",
        )
    return ""


# -- matplotlib: no windows --------------------------------------------------------------------


class _Nothing:
    """Stands in for anything of matplotlib where it is not installed: does nothing."""

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        return _NOTHING

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__"):
            raise AttributeError(name)
        return _NOTHING

    def __getitem__(self, key: Any) -> Any:
        return _NOTHING

    def __setitem__(self, key: Any, value: Any) -> None:
        pass

    def __iter__(self) -> Any:
        return iter((_NOTHING, _NOTHING))

    def __enter__(self) -> Any:
        return _NOTHING

    def __exit__(self, *args: Any) -> None:
        pass


_NOTHING = _Nothing()


class _StubModule(types.ModuleType):
    def __getattr__(self, name: str) -> Any:
        if name.startswith("__"):
            raise AttributeError(name)
        return _NOTHING


def _no_waiting(module: Any) -> None:
    """Nothing of matplotlib waits for a user who is not there: the event loop of every
    canvas (``waitforbuttonpress``, ``ginput``: the handout's plots wait for a key
    after every step) returns at once, and pyplot's ``pause`` and ``show`` do nothing."""
    if module.__name__ == "matplotlib.backend_bases":
        module.FigureCanvasBase.start_event_loop = lambda self, timeout=0: None
    elif module.__name__ == "matplotlib.pyplot":
        module.pause = lambda interval=0: None
        module.show = lambda *args, **kwargs: None


class _Matplotlib(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """matplotlib without windows: the Agg backend, whatever ``matplotlib.use`` asks for
    (a filter's module runs here for its functions, never for its plots), and nothing
    that waits (:func:`_no_waiting`); where matplotlib is not installed, modules that do
    nothing, so that its import works."""

    def __init__(self) -> None:
        self.stubbed = False

    def find_spec(self, name: str, path: Any = None, target: Any = None) -> Any:
        if name != "matplotlib" and not name.startswith("matplotlib."):
            return None
        if name == "matplotlib" and not self.stubbed:
            sys.meta_path.remove(self)
            try:
                spec = importlib.util.find_spec("matplotlib")
            finally:
                sys.meta_path.insert(0, self)
            if spec is not None and spec.loader is not None:
                real = spec.loader
                spec.loader = _PatchingLoader(real)
                return spec
            self.stubbed = True
        if self.stubbed:
            return importlib.util.spec_from_loader(name, self, is_package=True)
        if name in ("matplotlib.backend_bases", "matplotlib.pyplot"):
            spec = importlib.machinery.PathFinder.find_spec(name, path)
            if spec is not None and spec.loader is not None:
                spec.loader = _PatchingLoader(spec.loader, _no_waiting)
                return spec
        return None

    def create_module(self, spec: Any) -> Any:
        module = _StubModule(spec.name)
        module.__path__ = []
        return module

    def exec_module(self, module: Any) -> None:
        pass


class _PatchingLoader(importlib.abc.Loader):
    """A module's own loader, then ``patch`` on the module (by default matplotlib's:
    ``use`` always Agg)."""

    def __init__(self, real: Any, patch: Optional[Callable[[Any], None]] = None) -> None:
        self.real = real
        self.patch = patch

    def create_module(self, spec: Any) -> Any:
        return self.real.create_module(spec)

    def exec_module(self, module: Any) -> None:
        self.real.exec_module(module)
        if self.patch is not None:
            self.patch(module)
            return
        original = module.use

        def use(backend: Any, *args: Any, **kwargs: Any) -> None:
            original("Agg", force=True)

        original("Agg", force=True)
        module.use = use


# -- the loop ----------------------------------------------------------------------------------


RESERVE_BYTES = 4 << 20  # memory kept to answer a MemoryError when the filter holds the rest


class Worker:
    def __init__(self, commands: Any, answers: Any) -> None:
        self.commands = commands
        self.answers = answers
        self.module: Any = None
        self.target: Optional[str] = None
        self.filter: Any = None
        self.matplotlib = _Matplotlib()
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
                        "message": "%s called sys.exit(%s)" % (op, _shown(repr, code)),
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
            % (where, type(error).__name__, _said(error), _user_line(error)),
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
            line = _top_level_line(error, str(path)) if course else None
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
            % (path, type(error).__name__, _said(error), _user_line(error), number, what, also),
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


def _no_input(prompt: Any = "") -> str:
    """``input()`` answered at once with an empty line, its prompt printed: nobody is
    there to type (a student's pause between steps would otherwise end the run with
    EOFError)."""
    print(prompt)
    return ""


def _die_with_parent() -> None:
    """Ask Linux to end this process when ekfviz ends (a hung filter left no orphan)."""
    try:
        import ctypes

        libc = ctypes.CDLL(None)
        libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except Exception:
        pass


# what the guard of a worker (see _guarded) ignores: a filter that signals its parent
# (os.kill(os.getppid(), SIGTERM)) reaches the guard, never ekfviz, and ends nothing
GUARD_IGNORES = ("SIGTERM", "SIGINT", "SIGHUP", "SIGQUIT", "SIGUSR1", "SIGUSR2", "SIGALRM")


def _undumpable() -> None:
    """No other process of the same user may ptrace this one or read its memory
    (``PR_SET_DUMPABLE`` 0); also no core file."""
    try:
        import ctypes

        ctypes.CDLL(None).prctl(4, 0, 0, 0, 0)  # PR_SET_DUMPABLE
    except Exception:
        pass


def _no_new_processes(program: bytes) -> None:
    """Load a seccomp filter (classic BPF, built by ekfviz: no new process, threads
    allowed) on this process and all it starts; raises where the kernel refuses it."""
    import ctypes

    class Filter(ctypes.Structure):
        _fields_ = [("len", ctypes.c_ushort), ("filter", ctypes.c_char_p)]

    libc = ctypes.CDLL(None, use_errno=True)
    program_buffer = ctypes.create_string_buffer(program, len(program))
    prog = Filter(len(program) // 8, ctypes.cast(program_buffer, ctypes.c_char_p))
    # PR_SET_NO_NEW_PRIVS 38, PR_SET_SECCOMP 22 with SECCOMP_MODE_FILTER 2
    if libc.prctl(38, 1, 0, 0, 0) != 0 or libc.prctl(22, 2, ctypes.byref(prog), 0, 0) != 0:
        raise OSError(ctypes.get_errno(), "seccomp: " + os.strerror(ctypes.get_errno()))


def _guarded(channels: List[Any]) -> None:
    """Serve in a child process, this one (the guard) waiting for it, then ending as it
    ended (its exit code, or the signal that killed it), for ekfviz to say.

    The user's code then runs in a process whose parent is the guard: what it does to its
    parent (a signal to ``os.getppid()``) touches the guard, which ignores the signals
    that end a process politely, and not ekfviz. ekfviz ends both by killing their process
    group. Where there is no ``fork``, this process serves itself.

    :param channels: the files of the requests and the answers, closed in the guard (the
        child's ends must be the only ones, for ekfviz to see the child's end)
    """
    if not hasattr(os, "fork"):
        return
    try:
        child = os.fork()
    except OSError:
        return
    if child == 0:
        _die_with_parent()  # with the guard (which dies with ekfviz)
        return
    _undumpable()  # (in a sandbox, the filter's only neighbour: nothing to ptrace or read)
    for name in GUARD_IGNORES:
        if hasattr(signal, name):
            signal.signal(getattr(signal, name), signal.SIG_IGN)
    for channel in channels:
        channel.close()
    while True:
        try:
            _, status = os.waitpid(child, 0)
            break
        except InterruptedError:
            continue
        except ChildProcessError:
            os._exit(1)
    if os.WIFSIGNALED(status):
        number = os.WTERMSIG(status)
        try:  # (SIGKILL and SIGSTOP take no handler: they need none)
            signal.signal(number, signal.SIG_DFL)
        except (OSError, ValueError):
            pass
        try:
            os.kill(os.getpid(), number)
        except OSError:
            pass
        os._exit(128 + number)
    os._exit(os.WEXITSTATUS(status) if os.WIFEXITED(status) else 1)


def probe() -> Dict[str, Any]:
    """What this interpreter needs to run the worker, for its sandbox (``--probe``): its
    executable, prefixes, standard library, ``sys.path`` and site-packages, numpy's folder,
    the files it maps once numpy and the standard library's compiled modules are loaded
    (its shared libraries), and where ekfviz would be imported from (to be hidden)."""
    import site
    import sysconfig

    for name in ("ctypes", "decimal", "hashlib", "zlib", "bz2", "lzma", "math", "select"):
        try:
            importlib.import_module(name)
        except Exception:  # (an interpreter built without it: not needed then)
            pass
    maps = set()
    try:
        with open("/proc/self/maps") as handle:
            for line in handle:
                fields = line.split(None, 5)
                if len(fields) == 6 and fields[5].startswith("/"):
                    maps.add(fields[5].strip())
    except OSError:
        pass
    sites = list(getattr(site, "getsitepackages", lambda: [])())
    user_site = getattr(site, "getusersitepackages", lambda: "")()
    paths = sysconfig.get_paths()
    base = getattr(sys, "base_prefix", sys.prefix)
    for key in ("purelib", "platlib"):  # the base interpreter's own, beside a venv's
        sites.append(sysconfig.get_paths(vars={"base": base, "platbase": base})[key])
    ekfviz: List[str] = []
    try:
        found = importlib.util.find_spec("ekfviz")
    except (ImportError, ValueError):
        found = None
    if found is not None:
        ekfviz = list(found.submodule_search_locations or [])
        if found.origin and not ekfviz:
            ekfviz = [os.path.dirname(found.origin)]
    return {
        "executable": sys.executable,
        "prefix": sys.prefix,
        "base_prefix": getattr(sys, "base_prefix", sys.prefix),
        "stdlib": [paths.get("stdlib", ""), paths.get("platstdlib", "")],
        "path": [p for p in sys.path if p],
        "site": sites + ([user_site] if user_site else []),
        "numpy": os.path.dirname(os.path.abspath(np.__file__)),
        "numpy_version": np.__version__,
        "maps": sorted(maps),
        "ekfviz": ekfviz,
    }


def _no_core_dumps() -> None:
    """No core file of the worker: a crash is said by its signal, and its memory (the
    filter's) is nobody's to keep."""
    try:
        import resource

        resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
    except (ImportError, ValueError, OSError):
        pass


def main() -> None:
    if sys.argv[1:] == ["--probe"]:
        sys.stdout.write(json.dumps(probe()))
        return
    # the script's own folder (ekfviz/filters) must not shadow the user's imports
    here = os.path.dirname(os.path.abspath(__file__))
    if sys.path and os.path.abspath(sys.path[0] or ".") == here:
        del sys.path[0]
    options = json.loads(sys.argv[1]) if len(sys.argv) > 1 else {}
    _die_with_parent()
    _no_core_dumps()
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # ekfviz handles Ctrl-C and ends this
    memory = options.get("memory_bytes")
    if memory:
        import resource

        # (soft, hard) both, so that the filter cannot raise it; a limit over what the
        # system takes (more than a C long, or above the hard limit) is the most it takes
        hard = resource.getrlimit(resource.RLIMIT_AS)[1]
        limit = int(memory) if hard == resource.RLIM_INFINITY else min(int(memory), hard)
        try:
            resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
        except (ValueError, OverflowError):
            pass  # larger than any address space: no limit to set
    commands = os.fdopen(os.dup(0), "rb")
    answers = os.fdopen(os.dup(1), "wb")
    null = os.open(os.devnull, os.O_RDONLY)
    os.dup2(null, 0)
    os.close(null)
    os.dup2(2, 1)  # what the filter prints goes where ekfviz captures it
    stdin = sys.stdin = open(os.devnull)  # noqa: SIM115 (for the whole life of the process)
    builtins.input = _no_input
    sys.stdout = io.TextIOWrapper(os.fdopen(1, "wb", closefd=False), line_buffering=True)
    _guarded([commands, answers])
    if options.get("seccomp"):  # the sandbox's bound: the filter starts no process
        _no_new_processes(bytes.fromhex(options["seccomp"]))
    try:
        Worker(commands, answers).serve()
    finally:  # closed, not left to the garbage collector (a ResourceWarning each, which
        for stream in (commands, answers, stdin):  # PYTHONWARNINGS=default prints)
            try:
                stream.close()
            except Exception:  # (an answer that cannot be flushed: ekfviz has gone)
                pass


if __name__ == "__main__":
    main()
