"""Start-up of the command line: what a command does not use, the process does not import.

pyarrow (which Rerun imports) asks, the first time it is handed a Python list, whether
pandas is installed, and finds out by importing it: 0.3-1 s, more than replaying the
bundled sample, for a library that no ekfviz command uses (nor Rerun's logging or its
recording reader). :func:`pyarrow_without_pandas` has pyarrow ask that question as soon
as it is imported, while the import system answers that pandas cannot be found, in the
``ekfviz`` process only (the command line calls it; a program importing ekfviz keeps
pyarrow's pandas conversions). pyarrow remembers the answer; pandas itself stays
importable. pyarrow's type inference of a Python value imports pandas too, at every
inference until the import succeeds: ekfviz states the types of what it hands Rerun
(see :func:`ekfviz.viz.recording.any_values`), so that a command infers none.

:func:`one_blas_thread` runs numpy's BLAS on one thread in the ``ekfviz`` process unless
the user chose a number (``OPENBLAS_NUM_THREADS``, ``OMP_NUM_THREADS`` or
``MKL_NUM_THREADS`` set). The filter's products are small or bound by memory: a second
BLAS thread gains little, and while Python runs between two calls it spins, taking the
core that Rerun's encoder and the other processes need. Measured on a loaded 2-core
machine: Victoria Park 138 s of CPU with the default threads, 51 s with one; a map of
1000 landmarks 36 s against 4.9 s. (A user's filter in its worker runs on one thread
already.)
"""

from __future__ import annotations

import contextlib
import importlib.machinery
import importlib.util
import os
import sys
from collections.abc import Callable, Sequence
from types import ModuleType

BLAS_THREADS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def standard_streams() -> None:
    """Give a closed standard stream (``ekfviz ... >&-``) the null device, and one that
    cannot encode all of Unicode a "?" for what it cannot.

    With standard output closed, Python runs with ``sys.stdout`` None, and the first
    file the command opens (a recording, a report) would get descriptor 1: whatever
    writes to it as standard output, Python or a library's native code, would go into
    that file.
    """
    for fd, name, mode in ((0, "stdin", "r"), (1, "stdout", "w"), (2, "stderr", "w")):
        try:
            os.fstat(fd)
        except OSError:
            null = os.open(os.devnull, os.O_RDWR)  # the lowest free descriptor: this one
            if null != fd:
                os.dup2(null, fd)
                os.close(null)
            if getattr(sys, name) is None:
                setattr(sys, name, open(fd, mode, closefd=False))  # noqa: SIM115
    for stream in (sys.stdout, sys.stderr):
        encoding = str(getattr(stream, "encoding", None) or "utf-8").lower().replace("_", "-")
        if not encoding.startswith("utf") and hasattr(stream, "reconfigure"):
            # an ASCII or Latin-1 terminal (LC_ALL=C with PYTHONUTF8=0, PYTHONIOENCODING):
            # what it cannot show (sigma, the tables' lines, a name) becomes "?", not an
            # UnicodeEncodeError at the first table (rich draws its boxes in ASCII there)
            stream.reconfigure(errors="replace")


def one_blas_thread() -> None:
    """One BLAS thread for this process and its children, unless the user set a number;
    before numpy is imported (see the module). A variable set to nothing (``VAR=``) is no
    number: OpenBLAS would then take every core."""
    if not any(os.environ.get(name, "").strip() for name in BLAS_THREADS):
        for name in BLAS_THREADS:
            os.environ[name] = "1"


def quiet_rerun_logs(argv: Sequence[str]) -> None:
    """Rerun's own log lines off (``RUST_LOG=off``) unless the user set ``RUST_LOG`` or
    asked for ``--debug``; before rerun is imported.

    What goes wrong in a sink (a full disk under a file being saved, a viewer that does
    not answer) ekfviz says itself, in its one line; Rerun's log would put its own lines,
    coloured and timestamped, before it.
    """
    if "--debug" not in argv and "RUST_LOG" not in os.environ:
        os.environ["RUST_LOG"] = "off"


def collect_less() -> None:
    """Set the objects made so far (the imported modules, their functions and classes)
    apart from the cyclic garbage collector, and run its youngest generation every
    10,000 allocations instead of 700.

    A long log's records, rows and columns are made by the hundred thousand and hold no
    reference cycles; collecting them at Python's default pace took 0.45 s of the
    102,000-step log's 6.5 s, 0.07 s so. Cycles are still collected, less often.
    """
    import gc

    gc.freeze()
    gc.set_threshold(GC_YOUNG, 20, 20)


GC_YOUNG = 10_000  # allocations between two collections of the youngest generation


def collect_no_more() -> None:
    """Set every object apart from the cyclic garbage collector, the command being done.

    The interpreter's exit still runs as ever (the exit handlers, the streams flushed,
    the modules torn down), but its last collection goes over no object the process is
    about to drop whole: over the modules imported after :func:`collect_less` (rerun,
    pyarrow) and the run's records, it took 0.14 s of a classic replay's 0.16 s exit.
    """
    import gc

    gc.freeze()


def _answer_no(pyarrow: ModuleType) -> None:
    """Have pyarrow ask whether pandas is installed while the import system finds none.

    The question is pyarrow's Cython shim's (``pyarrow.lib._pandas_api``), which asks
    once and remembers the answer for the process.
    """
    if "pandas" in sys.modules:  # already imported by someone: nothing to save
        return
    shim = getattr(getattr(pyarrow, "lib", None), "_pandas_api", None)
    if shim is None:  # another pyarrow: leave it alone
        return
    finder = _NotFound("pandas")
    sys.meta_path.insert(0, finder)
    try:
        with contextlib.suppress(AttributeError):  # (another pyarrow may not have it)
            shim.have_pandas  # noqa: B018
    finally:
        sys.meta_path.remove(finder)


# The finders below are plain classes with find_spec, all the import system asks of
# one: importlib.abc's base class would import importlib.resources (17 ms) at start-up.


class _NotFound:
    """Finds module ``name`` absent, as the import system says of a module not installed
    (the finders after it are not asked)."""

    def __init__(self, name: str) -> None:
        self.name = name

    def find_spec(
        self,
        fullname: str,
        path: Sequence[str] | None,
        target: ModuleType | None = None,
    ) -> importlib.machinery.ModuleSpec | None:
        if fullname == self.name:
            raise ModuleNotFoundError(f"No module named {fullname!r}", name=fullname)
        return None


class _AfterImport:
    """Finds nothing itself: wraps the loader of module ``name`` so that ``callback``
    runs on the module right after it is executed, before anyone uses it."""

    def __init__(self, name: str, callback: Callable[[ModuleType], None]) -> None:
        self.name = name
        self.callback = callback

    def find_spec(
        self,
        fullname: str,
        path: Sequence[str] | None,
        target: ModuleType | None = None,
    ) -> importlib.machinery.ModuleSpec | None:
        if fullname != self.name:
            return None
        sys.meta_path.remove(self)  # once, and not to find the module through itself
        spec = importlib.util.find_spec(fullname)
        loader = None if spec is None else spec.loader
        if spec is None or loader is None or not hasattr(loader, "exec_module"):
            return spec
        execute, callback = loader.exec_module, self.callback

        def exec_module(module: ModuleType) -> None:
            execute(module)
            callback(module)

        loader.exec_module = exec_module  # type: ignore[method-assign]
        return spec


def after_import(name: str, callback: Callable[[ModuleType], None]) -> None:
    """Run ``callback`` on module ``name`` now if it is imported, else right after its
    import, whoever imports it (so that a module a run may not need is not imported
    only to be adjusted)."""
    module = sys.modules.get(name)
    if module is not None:
        callback(module)
    elif not any(
        isinstance(finder, _AfterImport) and finder.name == name and finder.callback == callback
        for finder in sys.meta_path
    ):
        sys.meta_path.insert(0, _AfterImport(name, callback))


def pyarrow_without_pandas() -> None:
    """From now on in this process, pyarrow takes pandas for absent (see the module)."""
    after_import("pyarrow", _answer_no)
