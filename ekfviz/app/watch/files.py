"""What ``ekfviz watch`` follows, and the thread that tells it of every save.

A filter's files are its module and the modules beside it that it imports, found from
its own import statements (``import helpers``, ``from .utils import wrap``, ``from
models import motion``), those modules' own imports in turn. An installed package or the
standard library is never among them: only a name that is a file or a package folder
beside the module counts.

Files are followed through the folders that hold them, not through the files themselves:
an editor that saves by writing a new file and renaming it over the old one (vim, VS
Code) replaces the file that a watch on it would have followed, and a file deleted and
made again is a new file. A folder's events are filtered by name to the files followed.
Bursts of events (an editor's save in several steps) come as one change: the watch waits
until no event has come for :data:`QUIET_MS`. watchfiles is imported here only.
"""

from __future__ import annotations

import ast
import os
import threading
from collections.abc import Callable, Iterable
from pathlib import Path

# an editor's save in several steps (write, rename, change the mode) is one change: the
# changes are handed over once no event came for this long, or at the latest after
# MAX_WAIT_MS of a stream of events. (Part of the time from a save to its run: the
# steps of a save are microseconds apart; a burst split by a longer pause still gives
# one run, the first change's run being cancelled by the next.)
QUIET_MS = 30
MAX_WAIT_MS = 1000


def absolute(path: Path) -> Path:
    """``path`` made absolute and normalised, its links not followed: the form a folder's
    events name their files in."""
    return Path(os.path.normpath(os.path.abspath(path)))


def filter_files(module: Path) -> list[Path]:
    """The module and the files beside it that it imports, directly or through each
    other, in the order found (the module first).

    A module that cannot be read or parsed (a syntax error while it is being edited)
    adds no imports of its own; it is still followed.
    """
    module = absolute(module)
    folder = module.parent
    found = [module]
    queue = [module]
    while queue:
        path = queue.pop(0)
        for name in _imported_names(path):
            for candidate in _files_of(folder, path.parent, name):
                if candidate not in found:
                    found.append(candidate)
                    queue.append(candidate)
    return found


def _imported_names(path: Path) -> list[tuple[int, str]]:
    """Every module ``path`` imports, as (level, dotted name): level 0 for an absolute
    import, 1 for ``from .name import ...`` (``from . import a`` gives (1, "a"))."""
    try:
        tree = ast.parse(path.read_bytes(), str(path))
    except (OSError, SyntaxError, ValueError):
        return []
    names: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names += [(0, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level <= 1:
            if node.module:
                names.append((node.level, node.module))
                # (from package import submodule: the submodule may be a file)
                names += [(node.level, f"{node.module}.{alias.name}") for alias in node.names]
            else:
                names += [(node.level, alias.name) for alias in node.names]
    return names


def _files_of(folder: Path, here: Path, imported: tuple[int, str]) -> list[Path]:
    """The files beside the module (in ``folder``, its first entry of ``sys.path``) that
    an import names: ``a.b`` is ``a.py``, or ``a/__init__.py`` and then ``a/b.py`` or
    ``a/b/__init__.py``; a relative import is looked up in the importing file's folder
    ``here``."""
    level, dotted = imported
    base = here if level else folder
    files: list[Path] = []
    for part in dotted.split("."):
        if not part.isidentifier():
            break
        if (base / f"{part}.py").is_file():
            files.append(base / f"{part}.py")
            break  # a module has no submodules
        if not (base / part).is_dir():
            break
        if (base / part / "__init__.py").is_file():
            files.append(base / part / "__init__.py")
        base = base / part
    return files


class Watcher:
    """A thread that hands every change to the files followed to ``on_change``.

    :param files: the files followed (absolute, see :func:`absolute`)
    :param on_change: called in the watcher's thread with the files changed (added,
        written, renamed over or deleted), once per burst
    :param quiet_ms: how long no event must come for a burst to be over
    """

    def __init__(
        self,
        files: Iterable[Path],
        on_change: Callable[[set[Path]], None],
        quiet_ms: int = QUIET_MS,
    ) -> None:
        self.files = frozenset(files)
        self.quiet_ms = quiet_ms
        self.folders = frozenset(path.parent for path in self.files)
        self.error: BaseException | None = None
        self._on_change = on_change
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="ekfviz-watch", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        import watchfiles

        names = {str(path) for path in self.files}
        try:
            changes = watchfiles.watch(
                *sorted(str(folder) for folder in self.folders),
                watch_filter=lambda _, path: os.path.normpath(path) in names,
                debounce=max(MAX_WAIT_MS, 2 * self.quiet_ms),
                step=self.quiet_ms,  # (its look at the stop event too)
                stop_event=self._stop,
                rust_timeout=0,  # no timeout of its own: stop_event ends it
                yield_on_timeout=False,
                raise_interrupt=False,
                recursive=False,
            )
            for batch in changes:
                self._on_change({Path(os.path.normpath(path)) for _, path in batch})
        except Exception as error:  # a folder that went away: said by the watch itself
            self.error = error
            self._on_change(set())

    def close(self) -> None:
        """Stop the thread (within ``quiet_ms``) and wait for it."""
        self._stop.set()
        self._thread.join()
