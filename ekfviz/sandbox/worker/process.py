"""The worker's process: its guard (the parent that ignores what the user's code signals
it), no new process (seccomp), no core dump, death with ekfviz, no terminal to read, and the
probe of what the interpreter needs for its sandbox."""

from __future__ import annotations

import importlib
import importlib.util
import os
import signal
import sys
from typing import Any, Dict, List

import numpy as np


def no_input(prompt: Any = "") -> str:
    """``input()`` answered at once with an empty line, its prompt printed: nobody is
    there to type (a student's pause between steps would otherwise end the run with
    EOFError)."""
    print(prompt)
    return ""


def die_with_parent() -> None:
    """Ask Linux to end this process when ekfviz ends (a hung filter left no orphan)."""
    try:
        import ctypes

        libc = ctypes.CDLL(None)
        libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except Exception:
        pass


# what the guard of a worker (see guarded) ignores: a filter that signals its parent
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


def no_new_processes(program: bytes) -> None:
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


def guarded(channels: List[Any]) -> None:
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
        die_with_parent()  # with the guard (which dies with ekfviz)
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


def no_core_dumps() -> None:
    """No core file of the worker: a crash is said by its signal, and its memory (the
    filter's) is nobody's to keep."""
    try:
        import resource

        resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
    except (ImportError, ValueError, OSError):
        pass
