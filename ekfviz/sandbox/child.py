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
shapes (column vectors), run here by :class:`~.worker.course.CourseModule`, which detects
which shapes the functions take (control (2, 1) or (2,), measurements (2k, 1) or (2k,), X
(3+2k, 1) or (3+2k,)) and checks what they return.

The worker's code is this file and the folder ``worker`` beside it (:mod:`.worker`), run
as the package ``ekfviz_worker``; in a sandbox both are shown read-only at ``/run/ekfviz``.
Kept to Python 3.8's syntax and numpy 1.17's API on purpose (no ``X | Y`` outside
annotations, no ``zip(strict=...)``, no ``match``).
"""

from __future__ import annotations

import builtins
import importlib
import importlib.util
import io
import json
import os
import signal
import sys
import types


def _sandbox_paths_first() -> None:
    """In a sandbox, the interpreter runs without its site-packages (``-S``): the folder
    that holds numpy there (the settings' ``sys_path``) goes first on ``sys.path``, before
    the worker's modules import numpy."""
    if len(sys.argv) > 1 and sys.argv[1].startswith("{"):
        for entry in reversed(json.loads(sys.argv[1]).get("sys_path", [])):
            sys.path.insert(0, entry)


PACKAGE = "ekfviz_worker"  # the name of the worker's folder in the worker
HERE = os.path.dirname(os.path.abspath(__file__))


def worker_module(name: str) -> types.ModuleType:
    """The worker's module ``name`` (of the folder ``worker`` beside this file), imported
    from its file: no folder of ekfviz's goes on ``sys.path``, where the names of its
    modules would shadow the user's (``course``, ``faults``)."""
    if PACKAGE not in sys.modules:
        folder = os.path.join(HERE, "worker")
        spec = importlib.util.spec_from_file_location(
            PACKAGE, os.path.join(folder, "__init__.py"), submodule_search_locations=[folder]
        )
        assert spec is not None and spec.loader is not None
        package = importlib.util.module_from_spec(spec)
        sys.modules[PACKAGE] = package
        spec.loader.exec_module(package)
    return importlib.import_module(PACKAGE + "." + name)


def main() -> None:
    """Answer ``--probe``, or set the process up and serve the requests until ekfviz
    closes the channel."""
    # the script's own folder (ekfviz/sandbox) must not shadow the user's imports
    if sys.path and os.path.abspath(sys.path[0] or ".") == HERE:
        del sys.path[0]
    _sandbox_paths_first()
    # every module of the worker's, before the probe lists the files the process maps (its
    # shared libraries, for the sandbox to show) and before the limits
    process, serving = worker_module("process"), worker_module("serving")
    if sys.argv[1:] == ["--probe"]:
        sys.stdout.write(json.dumps(process.probe()))
        return
    options = json.loads(sys.argv[1]) if len(sys.argv) > 1 else {}
    process.die_with_parent()
    process.no_core_dumps()
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
    builtins.input = process.no_input
    sys.stdout = io.TextIOWrapper(os.fdopen(1, "wb", closefd=False), line_buffering=True)
    process.guarded([commands, answers])
    if options.get("seccomp"):  # the sandbox's bound: the filter starts no process
        process.no_new_processes(bytes.fromhex(options["seccomp"]))
    try:
        serving.Worker(commands, answers).serve()
    finally:  # closed, not left to the garbage collector (a ResourceWarning each, which
        for stream in (commands, answers, stdin):  # PYTHONWARNINGS=default prints)
            try:
                stream.close()
            except Exception:  # (an answer that cannot be flushed: ekfviz has gone)
                pass


if __name__ == "__main__":
    main()
