"""matplotlib in the worker: the Agg backend whatever a filter's module asks for, nothing
that waits for a user who is not there, and modules that do nothing where matplotlib is not
installed."""

from __future__ import annotations

import importlib.abc
import importlib.machinery
import importlib.util
import sys
import types
from typing import Any, Callable, Optional


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


class WindowlessMatplotlib(importlib.abc.MetaPathFinder, importlib.abc.Loader):
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
