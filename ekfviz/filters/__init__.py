"""Which filter a run uses: ``--filter ekf``, a registered backend, or a user's class.

``--filter`` takes

- ``ekf``: the built-in EKF-SLAM (:class:`~ekfviz.core.filter.EkfSlam`), the default;
- a registered name (:data:`REGISTRY`), imported only when asked for, so that optional
  backends (GTSAM) cost nothing when unused;
- ``PATH.py:ClassName``: a class in a Python file;
- ``package.module:ClassName``: a class in an importable module.

Every one is constructed as ``Class(params)`` and follows the
:class:`~ekfviz.core.protocol.SlamFilter` protocol. Numpy only: nothing here imports a
backend until it is asked for.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import re
import sys
from dataclasses import dataclass
from pathlib import Path

from ekfviz.core.plugged import FilterFactory

BUILTIN = "ekf"
# name -> ("module:Class", the extra that provides its dependency, or None)
REGISTRY: dict[str, tuple[str, str | None]] = {
    BUILTIN: ("ekfviz.core.filter:EkfSlam", None),
    "isam2": ("ekfviz.filters.gtsam:Isam2Slam", "gtsam"),
    "batch": ("ekfviz.filters.gtsam:BatchSlam", "gtsam"),
}


class FilterSpecError(ValueError):
    """A ``--filter`` that cannot be loaded; the message is one line."""


@dataclass(frozen=True, slots=True)
class FilterSpec:
    """A ``--filter`` value, loadable in any process (it pickles as its text).

    :param text: as given on the command line
    """

    text: str

    @property
    def is_builtin(self) -> bool:
        return self.text == BUILTIN

    @property
    def label(self) -> str:
        """A short name: ``ekf``, ``isam2``, the class name of a user's filter."""
        if self.text in REGISTRY:
            return self.text
        return self.text.rpartition(":")[2] or self.text

    @property
    def key(self) -> str:
        """The label, safe in an entity path."""
        return re.sub(r"[^A-Za-z0-9_.-]+", "_", self.label)

    def load(self) -> FilterFactory:
        """The filter class.

        :raises FilterSpecError: the file, module or class cannot be had; one line
        """
        return load_filter(self.text)


def load_filter(text: str) -> FilterFactory:
    """The filter class that ``--filter text`` names (see the module docstring).

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
                f" pip install 'ekfviz[{extra}]'"
            ) from error
    where, sep, name = text.rpartition(":")
    if not sep or not where or not name.isidentifier():
        names = ", ".join(REGISTRY)
        raise FilterSpecError(
            f"--filter {text}: expected one of {names}, PATH.py:ClassName or"
            " package.module:ClassName"
        )
    if where.endswith(".py") or "/" in where or "\\" in where:
        return _class_in(_import_file(Path(where), text), name, text)
    try:
        module = _import(where)
    except ModuleNotFoundError as error:
        raise FilterSpecError(f"--filter {text}: no module named {error.name!r}") from error
    return _class_in(module, name, text)


def _import(module: str) -> object:
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError:
        raise
    except Exception as error:  # the user's module failed while importing
        raise FilterSpecError(
            f"--filter: importing {module} raised {type(error).__name__}: {error}"
        ) from error


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
