"""Which filter a run uses: ``--filter ekf``, a registered backend, or a user's code.

``--filter`` takes

- ``ekf``: the built-in EKF-SLAM (:class:`~ekfviz.filters.ekf.EkfSlam`), the default;
- a registered name (:data:`REGISTRY`), imported only when asked for, so that optional
  backends (GTSAM) cost nothing when unused;
- ``PATH.py``: a course module of functions ``init_landmarks``, ``predict``, ``update``
  (the handout's shapes), as handed in;
- ``PATH.py:ClassName``: a class in a Python file;
- ``package.module:ClassName``: a class in an importable module;
- any of these as ``LABEL=SPEC``: the same, called LABEL in tables and recordings.

The built-in and registered filters run in ekfviz's process; a user's code runs in a
worker process of its own (:mod:`ekfviz.sandbox.host`), in a sandbox that shows it a
private copy of its file's folder (its Python files), or of the top-level package of its
module, under ``--python`` if given.
Every class is constructed as ``Class(params)`` and follows the
:class:`~ekfviz.filters.protocol.SlamFilter` protocol. Numpy only: nothing here imports a
backend, nor the worker and its sandbox, until it is asked for.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.machinery
import importlib.util
import os
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from ekfviz.core.tables import utf8
from ekfviz.filters.plugged import FilterFactory
from ekfviz.sandbox.options import WorkerOptions

if TYPE_CHECKING:  # the sandbox is imported where a user's filter is loaded
    from ekfviz.sandbox.remote import StartedWorker, Target

BUILTIN = "ekf"
# name -> ("module:Class", the extra that provides its dependency, or None)
REGISTRY: dict[str, tuple[str, str | None]] = {
    BUILTIN: ("ekfviz.filters.ekf:EkfSlam", None),
    "isam2": ("ekfviz.filters.gtsam:Isam2Slam", "gtsam"),
    "batch": ("ekfviz.filters.gtsam:BatchSlam", "gtsam"),
}


class FilterSpecError(ValueError):
    """A ``--filter`` that cannot be loaded; the message is one line.

    :param kind: as :class:`~ekfviz.sandbox.host.WorkerFault`'s (``error`` where the
        spec itself is wrong)
    """

    def __init__(self, message: str, kind: str = "error", user_traceback: str = "") -> None:
        super().__init__(message)
        self.kind = kind
        self.user_traceback = user_traceback

    def __reduce__(self) -> tuple[object, ...]:
        return type(self), (str(self), self.kind, self.user_traceback)


_LABEL = re.compile(r"^([A-Za-z0-9_.-]+)=(.+)$")


@dataclass(frozen=True, slots=True)
class FilterSpec:
    """A ``--filter`` value, loadable in any process (it pickles as its text and options).

    :param text: as given on the command line, without a ``LABEL=`` prefix
    :param name: the label asked for (``--label`` or ``LABEL=SPEC``), if any
    :param worker: how a user's code runs (interpreter, time and memory bounds)
    """

    text: str
    name: str | None = None
    worker: WorkerOptions = field(default_factory=WorkerOptions)

    @classmethod
    def parse(
        cls, text: str, label: str | None = None, worker: WorkerOptions | None = None
    ) -> FilterSpec:
        """A spec from ``--filter`` text, which may be ``LABEL=SPEC``."""
        match = _LABEL.match(text)
        if match and not Path(text).exists():
            label, text = label or match.group(1), match.group(2)
        return cls(text, label, worker if worker is not None else WorkerOptions())

    @property
    def is_builtin(self) -> bool:
        return self.text == BUILTIN

    @property
    def in_process(self) -> bool:
        """Whether it is ekfviz's own code (built-in or registered), run in this process."""
        return self.text in REGISTRY

    @property
    def label(self) -> str:
        """A short name: the label given, ``ekf``, ``isam2``, a class name, a file's stem."""
        if self.name:
            return self.name
        if self.text in REGISTRY:
            return self.text
        where, sep, name = self.text.rpartition(":")
        if sep and name.isidentifier() and where:
            return name
        return utf8(Path(self.text).stem or self.text)  # a file's name may not be UTF-8

    @property
    def key(self) -> str:
        """The label, safe in an entity path."""
        return re.sub(r"[^A-Za-z0-9_.-]+", "_", self.label)

    def load(self, started: StartedWorker | None = None) -> FilterFactory:
        """The filter class, or for a user's code a factory of workers running it.

        :param started: see :func:`load_filter`
        :raises FilterSpecError: the file, module or class cannot be had; one line
        """
        return load_filter(self.text, self.worker, started)


def release(make_filter: object) -> None:
    """End what a loaded filter holds: the spare worker a user's filter keeps started
    (:class:`~ekfviz.sandbox.remote.WorkerFactory`); nothing for the others."""
    if isinstance(make_filter, type):  # a class of ekfviz's own: nothing held
        return
    from ekfviz.sandbox.remote import WorkerFactory

    if isinstance(make_filter, WorkerFactory):
        make_filter.close()


def target_of(text: str) -> Target:
    """What a user's ``--filter`` names: a file or module, and a class or functions.

    :raises FilterSpecError: neither ``PATH.py``, ``PATH.py:Class`` nor ``module:Class``
    """
    from ekfviz.sandbox.remote import Target

    where, sep, name = text.rpartition(":")
    if sep and where and name.isidentifier():
        if where.endswith(".py") or "/" in where or "\\" in where:
            return Target(_python_file(Path(where), text), None, name)
        return _module_target(where, name, text)
    if text.endswith(".py") or Path(text).is_dir():
        return Target(_python_file(Path(text), text), None, None)
    names = ", ".join(REGISTRY)
    raise FilterSpecError(
        f"--filter {text}: expected one of {names}, PATH.py (a course module),"
        " PATH.py:ClassName or package.module:ClassName"
    )


def _module_target(module: str, name: str, text: str) -> Target:
    """A class of an importable module: its top-level package (or module) found where
    Python would import it from, without importing anything of it, and shown to the
    worker as the submission.

    :raises FilterSpecError: nowhere to be found, or one of ekfviz's own modules
    """
    top = module.partition(".")[0]
    search = [os.getcwd(), *(p for p in sys.path if p)]
    try:
        found = importlib.machinery.PathFinder.find_spec(top, search)
    except (ImportError, ValueError):
        found = None
    if found is None:
        raise FilterSpecError(f"--filter {text}: No module named {top!r} (on Python's path)")
    locations = list(found.submodule_search_locations or [])
    here = str(Path(__file__).resolve().parents[1])
    place = locations[0] if locations else os.path.dirname(str(found.origin))
    if os.path.realpath(place).startswith(here):
        raise FilterSpecError(
            f"--filter {text}: one of ekfviz's own modules is not a user's filter: --filter"
            f" {BUILTIN} runs the built-in, in ekfviz's process"
        )
    from ekfviz.sandbox.remote import Target
    from ekfviz.sandbox.submission import Submission

    if locations:  # a package: its folder, shown in the folder that holds it
        return Target(None, module, name, os.path.dirname(place), Submission(place))
    origin = str(found.origin)
    only = Submission(os.path.dirname(origin), only=os.path.basename(origin))
    return Target(None, module, name, os.path.dirname(origin), only)


def _python_file(path: Path, text: str) -> str:
    if path.is_dir():
        raise FilterSpecError(f"--filter {text}: {path} is a directory, expected a Python file")
    if not path.is_file():
        raise FilterSpecError(f"--filter {text}: {path}: no such file")
    return str(path.resolve())


def load_filter(
    text: str, worker: WorkerOptions | None = None, started: StartedWorker | None = None
) -> FilterFactory:
    """The filter class that ``--filter text`` names, or a factory of workers running a
    user's code (see the module docstring).

    :param started: for a user's code, a worker already started to import it into (one
        kept waiting, so that a run does not wait for an interpreter to start)
    :raises FilterSpecError: one line naming what is wrong and what was expected
    """
    if text in REGISTRY:
        target, extra = REGISTRY[text]
        try:
            return _class_in(_import(target.partition(":")[0]), target, text)
        except ModuleNotFoundError as error:
            if extra is None:
                raise
            raise FilterSpecError(
                f"--filter {text} needs the optional dependency {error.name!r}:"
                f" the {extra} extra (pip install -e '.[{extra}]' in a clone of ekfviz)"
            ) from error
    from ekfviz.sandbox.host import WorkerFault
    from ekfviz.sandbox.remote import WorkerFactory

    user = target_of(text)
    options = worker if worker is not None else WorkerOptions()
    label = worker_label(user)
    try:
        return WorkerFactory(user, options, label, started)
    except WorkerFault as fault:
        message = f"--filter {text}: {fault}"
        raise FilterSpecError(message, fault.kind, fault.user_traceback) from None


def worker_label(target: Target) -> str:
    """How messages and the echo of its output name a user's filter: ``filter
    ekf_slam.py`` (a file's name), ``filter package.module:Class``."""
    return f"filter {Path(target.path).name if target.path else target.describe()}"


def _import(module: str) -> object:
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError:
        raise
    except Exception as error:  # the user's module failed while importing
        raise FilterSpecError(
            f"--filter: importing {module} raised {type(error).__name__}: {error}"
        ) from error


def load_in_process(text: str) -> FilterFactory:
    """The class that ``PATH.py:Class`` or ``module:Class`` names, imported into this
    process: for trusted code (tests, a library user's own class); ``--filter`` never
    does this with a user's code.

    :raises FilterSpecError: one line naming what is wrong
    """
    if text in REGISTRY:
        return load_filter(text)
    where, sep, name = text.rpartition(":")
    if sep and where and name.isidentifier() and not where.endswith(".py") and "/" not in where:
        return _class_in(_import(where), name, text)  # (a module's: imported as it is)
    target = target_of(text)
    if target.name is None:
        raise FilterSpecError(f"--filter {text}: expected PATH.py:ClassName")
    module = _import_file(Path(target.path), text) if target.path else _import(str(target.module))
    return _class_in(module, target.name, text)


def _import_file(path: Path, text: str) -> object:
    """Import a Python file as a module of its own (named after its path's hash)."""
    if not path.is_file():
        raise FilterSpecError(f"--filter {text}: {path}: no such file")
    resolved = path.resolve()
    module_name = "ekfviz_plugin_" + hashlib.sha256(str(resolved).encode()).hexdigest()[:16]
    if module_name in sys.modules:
        return sys.modules[module_name]
    spec = importlib.util.spec_from_file_location(module_name, resolved)
    if spec is None or spec.loader is None:
        raise FilterSpecError(f"--filter {text}: {path}: not a Python file")
    module = importlib.util.module_from_spec(spec)
    sys.modules[module_name] = module  # before running it: dataclasses and pickling need it
    try:
        spec.loader.exec_module(module)
    except Exception as error:  # the user's file: any exception is its fault
        del sys.modules[module_name]
        raise FilterSpecError(
            f"--filter {text}: importing {path} raised {type(error).__name__}: {error}"
        ) from error
    return module


def _class_in(module: object, target: str, text: str) -> FilterFactory:
    name = target.rpartition(":")[2]
    found = getattr(module, name, None)
    if not isinstance(found, type):
        where = getattr(module, "__file__", None) or getattr(module, "__name__", "")
        raise FilterSpecError(f"--filter {text}: {where} has no class {name}")
    return found
