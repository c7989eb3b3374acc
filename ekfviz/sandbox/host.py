"""A user's filter in a process of its own: started, spoken to, bounded, ended.

The filter's code runs in ``child.py`` (beside this file) under the interpreter of
``--python`` (ekfviz's own by default), which needs only the standard library and numpy:
its imports, globals, ``matplotlib.use``, prints, ``sys.exit``, crashes and hangs touch
nothing of ekfviz's. The worker starts in a sandbox (:mod:`.bwrap`: no network, no file of
the caller's but a private copy of the submission, :mod:`.submission`) unless
``WorkerOptions.sandbox`` is off; this module is the only place that starts one. What it
prints is captured (never on ekfviz's stdout) and shown escaped (:mod:`.text`); one call
is bounded by ``timeout_s``; its address space by ``memory_mb``. Its state crosses as raw
float64 buffers with their shapes (see ``worker/framing.py``), never as numpy pickles.

The filter protocol on this side is :mod:`.remote`'s. Numpy only.
"""

from __future__ import annotations

import atexit
import contextlib
import json
import math
import os
import select
import signal
import struct
import subprocess
import sys
import tempfile
import threading
import time
import weakref
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ekfviz.filters.plugged import PluginError
from ekfviz.sandbox import bwrap
from ekfviz.sandbox.options import WorkerOptions
from ekfviz.sandbox.text import printable

WORKER_SCRIPT = Path(__file__).with_name("child.py")
# the worker's own start (an interpreter and numpy) gets longer than one call
START_TIMEOUT_S = 120.0
# the user's code outside the calls (its module's import, its construction) is bounded as
# one call is (--filter-timeout), but never below this: an import of matplotlib or scipy
# takes seconds on a loaded machine
MIN_LOAD_TIMEOUT_S = 10.0
# what the filter may print before ekfviz stops echoing it (it is still drained)
ECHO_LIMIT_BYTES = 1 << 20
MAX_ANSWER_BYTES = 1 << 30  # a state of 11,000 numbers: P alone is 1 GB
LINE_KEPT_BYTES = 1 << 16  # of each line a worker prints, what ekfviz keeps (echoes)
LAST_OUTPUT_CHARS = 200  # of the worker's last line, what a one-line error quotes
DRAIN_POLL_S = 0.05  # how often the output reader looks whether it is told to stop
MIN_NUMPY = (1, 17)
# the longest JSON header of an answer (a state's are a few hundred bytes): four bytes of
# anything else read as a length must not make ekfviz wait for, or allocate, gigabytes
MAX_HEADER_BYTES = 1 << 24


class WorkerFault(PluginError):
    """The user's filter failed in its worker; one line, its traceback kept apart.

    :param kind: ``raised`` (an exception), ``fault`` (a wrong shape or value), ``exit``
        (``sys.exit``), ``timeout``, ``memory``, ``crashed`` (the process died), ``start``
        (the interpreter, its numpy or the sandbox cannot run the worker: ekfviz's side),
        ``refused`` (a submission not copied into the sandbox: over a bound, a link
        leading out)
    :param user_traceback: the filter's own traceback, for ``--debug``
    """

    def __init__(self, message: str, kind: str = "raised", user_traceback: str = "") -> None:
        super().__init__(message)
        self.kind = kind
        self.user_traceback = user_traceback

    def __reduce__(self) -> tuple[Any, ...]:
        return type(self), (str(self), self.kind, self.user_traceback)


@dataclass
class Output:
    """What a worker printed: a bounded tail of its lines and how much there was."""

    lines: deque[str] = field(default_factory=lambda: deque(maxlen=200))
    total_bytes: int = 0


def _signal_name(number: int) -> str:
    try:
        return signal.Signals(number).name
    except ValueError:
        return f"signal {number}"


def load_timeout(options: WorkerOptions) -> float:
    """Seconds the user's module may take to import, and its filter to be constructed: the
    bound of one call (at least :data:`MIN_LOAD_TIMEOUT_S`), :data:`START_TIMEOUT_S`
    where calls are not bounded. (A loop at import must not hold a command for minutes.)"""
    if options.timeout_s is None:
        return START_TIMEOUT_S
    return max(float(options.timeout_s), MIN_LOAD_TIMEOUT_S)


def load_limit_name(options: WorkerOptions) -> str:
    """Where :func:`load_timeout` comes from, for the message of a timeout."""
    if options.timeout_s is None:
        return "the bound of a worker's start"
    if options.timeout_s < MIN_LOAD_TIMEOUT_S:
        return f"--filter-timeout, at least {MIN_LOAD_TIMEOUT_S:g} s to load a filter"
    return "--filter-timeout"


class WorkerProcess:
    """One worker process and its channels.

    :param label: how messages name the filter (``filter ekf_slam.py``)
    :raises WorkerFault: the interpreter cannot start the worker (kind ``start``)
    """

    def __init__(
        self, options: WorkerOptions, label: str, mounts: Sequence[bwrap.Mount] = ()
    ) -> None:
        self.options = options
        self.label = label
        self.output = Output()
        self.numpy_version = "0"
        python = options.python or sys.executable
        settings: dict[str, object] = {}
        if options.memory_mb:
            settings["memory_bytes"] = int(options.memory_mb) * (1 << 20)
        launch = _sandboxed(options, mounts, settings) if options.sandbox else _plain(options)
        argv, env, cwd = launch
        try:
            self.process = subprocess.Popen(
                argv,
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                cwd=cwd,
                env=env,
                start_new_session=True,  # Ctrl-C reaches ekfviz, which ends the worker
            )
        except OSError as error:
            raise WorkerFault(
                f"--python {python}: cannot run it ({error.strerror or error})", "start"
            ) from None
        assert self.process.stdin and self.process.stdout and self.process.stderr
        for stream in (self.process.stdin, self.process.stdout):
            _widen_pipe(stream.fileno())
        self._commands = self.process.stdin
        self._answers = self.process.stdout.fileno()
        self._echo_lock = threading.Lock()
        self._held: list[tuple[str, int]] | None = []  # (line, bytes) until it started
        stop = threading.Event()
        self._reader = threading.Thread(
            target=self._drain, args=(self.process.stderr.fileno(), stop), daemon=True
        )
        _DRAINS[self.process.pid] = (stop, self._reader)
        self._reader.start()
        self._finalizer = weakref.finalize(self, _end, self.process)
        _LIVE.add(self.process)
        try:
            hello, _ = self.request({"op": "hello"}, [], "starting", timeout_s=START_TIMEOUT_S,
                                    limit_name="the bound of a worker's start")  # fmt: skip
        except WorkerFault as error:
            self.close()
            if error.kind == "timeout" and options.deadline is not None:  # a grade's time
                raise WorkerFault(f"its time ran out before its worker started: {error}",
                                  "timeout") from None  # fmt: skip
            needs = "" if options.sandbox else " (it needs Python >= 3.8 with numpy >= 1.17)"
            raise WorkerFault(
                f"--python {python}: the filter's worker did not start{needs}: {error}", "start"
            ) from None
        self.python_version = str(hello.get("python"))
        self.numpy_version = str(hello.get("numpy"))
        if _version(self.numpy_version) < MIN_NUMPY:
            self.close()
            raise WorkerFault(
                f"--python {python}: numpy {self.numpy_version} is too old, expected >= 1.17",
                "start",
            )
        self._started()

    # -- output -------------------------------------------------------------------------

    def _drain(self, fd: int, stop: threading.Event) -> None:
        """Read what the worker prints, line by line, till its end or ``stop``.

        Read from the descriptor, polled: a process the filter started in a session of
        its own outlives the worker's group and may hold the pipe open for ever, and a
        thread blocked in a buffered ``readline`` would hold the stream's lock, so that
        closing the stream waited for that process. Each line is kept to its first
        :data:`LINE_KEPT_BYTES` (its size still counted): a filter that prints 20 MB
        lines does not grow ekfviz's memory.
        """
        kept, size = b"", 0  # the line so far: its start, its bytes
        while not stop.is_set():
            try:
                ready, _, _ = select.select([fd], [], [], DRAIN_POLL_S)
                chunk = os.read(fd, 1 << 16) if ready else None
            except (OSError, ValueError):  # closed under it
                return
            if chunk is None:
                continue
            if not chunk:
                break
            start = 0
            while (end := chunk.find(b"\n", start)) >= 0:
                kept += chunk[start : end + 1][: max(0, LINE_KEPT_BYTES - len(kept))]
                self._line(kept, size + end + 1 - start)
                kept, size, start = b"", 0, end + 1
            kept += chunk[start:][: max(0, LINE_KEPT_BYTES - len(kept))]
            size += len(chunk) - start
        if size:
            self._line(kept, size)

    def _line(self, kept: bytes, size: int) -> None:
        """One line the worker printed: its start ``kept`` and its whole ``size``."""
        line = printable(kept.decode("utf-8", "replace").rstrip("\n"))
        if size > len(kept):
            line += f" ... ({size:,} bytes)"
        with self._echo_lock:
            self.output.total_bytes += size
            self.output.lines.append(line)
            if self._held is not None:
                self._held.append((line, size))
            else:
                self._echo(line, size, self.output.total_bytes)

    def _echo(self, line: str, size: int, total: int) -> None:
        """Echo one line the worker printed (``total``: bytes printed up to its end)."""
        if not self.options.echo:
            return
        if total <= ECHO_LIMIT_BYTES:
            sys.stderr.write(f"{self.label} | {line}\n")
        elif total - size <= ECHO_LIMIT_BYTES:
            sys.stderr.write(f"{self.label} | ... (its further output is not shown)\n")

    def _started(self) -> None:
        """The worker runs: echo what it printed while starting, and from now on as it
        comes. (Until then it is only kept: a worker that does not start is said in one
        line, its last output in it, not with that output echoed before.)"""
        with self._echo_lock:
            held, self._held = self._held or [], None
            total = 0
            for line, size in held:
                total += size
                self._echo(line, size, total)

    # -- requests -------------------------------------------------------------------------

    def request(
        self,
        header: dict[str, Any],
        arrays: Sequence[np.ndarray[Any, Any]],
        what: str,
        *,
        timeout_s: float | None = None,
        limit_name: str = "--filter-timeout",
    ) -> tuple[dict[str, Any], list[np.ndarray[Any, Any]]]:
        """Send one request, wait for its answer.

        :param what: the call, for messages (``predict``)
        :param timeout_s: its time limit (None: the options' bound of one call)
        :param limit_name: where that limit comes from, for the message of a timeout
        :raises WorkerFault: the filter failed, timed out or its process died
        """
        timeout = self.options.timeout_s if timeout_s is None else timeout_s
        if self.options.deadline is not None:
            left = max(0.0, self.options.deadline - time.time())
            timeout = left if timeout is None else min(timeout, left)
        if timeout is not None and not math.isfinite(timeout):  # inf: no bound
            timeout = None
        if self.process.poll() is not None:
            raise self._died(what)
        contiguous = [np.ascontiguousarray(a) for a in arrays]
        header = dict(header)
        header["arrays"] = [{"shape": list(a.shape), "dtype": a.dtype.str} for a in contiguous]
        data = json.dumps(header).encode()
        try:
            self._commands.write(struct.pack("<I", len(data)) + data)
            for a in contiguous:
                self._commands.write(a.tobytes())
            self._commands.flush()
        except (BrokenPipeError, OSError):
            raise self._died(what) from None
        deadline = None if timeout is None else time.monotonic() + timeout
        bound = (what, timeout, limit_name)
        (size,) = struct.unpack("<I", self._read(4, deadline, bound))
        if size > MAX_HEADER_BYTES:
            raise self._garbled(what)
        try:
            answer = json.loads(self._read(size, deadline, bound))
            metas = answer.get("arrays", [])
            layouts = [(np.dtype(m["dtype"]), tuple(int(v) for v in m["shape"])) for m in metas]
        except (ValueError, TypeError, KeyError, AttributeError):  # JSON, UTF-8, dtype, shape
            raise self._garbled(what) from None
        counts = [int(np.prod(shape)) if shape else 1 for _, shape in layouts]
        sized = list(zip(counts, layouts, strict=True))
        if any(count < 0 or dtype.hasobject for count, (dtype, _) in sized):
            raise self._garbled(what)
        total = sum(count * dtype.itemsize for count, (dtype, _) in sized)
        if total > MAX_ANSWER_BYTES:  # refused before ekfviz allocates it
            self.kill()
            shapes = ", ".join(str(shape) for _, shape in layouts)
            raise WorkerFault(
                f"after {what}, its arrays ({shapes}) are {total / 1e9:.1f} GB, more than the"
                f" {MAX_ANSWER_BYTES >> 30} GiB ekfviz takes from a filter; the filter was stopped",
                "memory",
            )
        received = []
        for count, (dtype, shape) in sized:
            buffer = self._read(count * dtype.itemsize, deadline, bound)
            received.append(np.frombuffer(buffer, dtype=dtype).reshape(shape))
        if not answer.get("ok"):
            kind = str(answer.get("kind", "raised"))
            message = printable(str(answer.get("message")))
            if "inhomogeneous" in message and _version(self.numpy_version) >= (1, 24):
                message += (
                    f" (this code builds a ragged array, which numpy {self.numpy_version}"
                    " refuses: run it with --python PATH, an interpreter of an environment"
                    " with numpy < 1.24)"
                )
            elif "only 0-dimensional arrays can be converted" in message:
                message += (
                    " (float() or int() of an array of one element, such as control[0] of a"
                    f" (2, 1) column: numpy {self.numpy_version} refuses it, older numpy took"
                    " it with a warning; take the element itself (control[0, 0], or"
                    " .item()), or run it with --python PATH, an interpreter of an"
                    " environment with numpy < 2)"
                )
            if kind not in _CHILD_KINDS:  # (what the worker may say; the rest is ekfviz's)
                kind = "raised"
            raise WorkerFault(message, kind, printable(str(answer.get("traceback", ""))))
        return answer, received

    def _read(
        self, count: int, deadline: float | None, bound: tuple[str, float | None, str]
    ) -> bytearray:
        """``count`` bytes of the answer, by ``deadline``.

        :param bound: (the call, its time limit in seconds, where that comes from), for
            the message of a timeout
        """
        what, limit, limit_name = bound
        buffer = bytearray(count)
        view = memoryview(buffer)
        got = 0
        while got < count:
            if deadline is not None:
                left = deadline - time.monotonic()
                ready = left > 0 and select.select([self._answers], [], [], left)[0]
                if not ready:
                    self.kill()
                    if self.options.deadline is not None:
                        said = f"{what} was still running when its time ran out (--timeout)"
                    else:
                        said = (
                            f"{what} did not return within {limit or 0:g} s ({limit_name});"
                            " the filter was stopped"
                        )
                    raise WorkerFault(said, "timeout")
            try:
                chunk = os.readv(self._answers, [view[got:]])
            except OSError:
                chunk = 0
            if chunk == 0:
                raise self._died(what)
            got += chunk
        return buffer

    def _garbled(self, what: str) -> WorkerFault:
        """The worker's answer is not ekfviz's protocol: it is stopped."""
        self.kill()
        return WorkerFault(
            f"the filter's worker answered {what} with bytes that are not ekfviz's protocol"
            " (--python is no Python interpreter, or the filter wrote to the worker's own"
            " channel); the filter was stopped",
            "crashed",
        )

    def _died(self, what: str) -> WorkerFault:
        try:
            code = self.process.wait(timeout=5)
        except subprocess.TimeoutExpired:
            self.kill()
            code = self.process.wait()
        self._reader.join(timeout=1)
        last = self.output.lines[-1] if self.output.lines else ""
        if self.options.sandbox and 128 < code < 128 + 65:  # bwrap: 128 + the signal
            code = 128 - code
        if code < 0:
            name = _signal_name(-code)
            why, kind = f"was killed by {name}", "crashed"
        else:
            why, kind = f"exited with code {code}", "exit" if code == 0 else "crashed"
        last = last.strip()
        if len(last) > LAST_OUTPUT_CHARS:  # one line, however long the filter's was
            last = last[:LAST_OUTPUT_CHARS] + " ..."
        said = f"; its last output: {last}" if last else ""
        return WorkerFault(f"the filter's process {why} during {what}{said}", kind)

    def kill(self) -> None:
        _end(self.process)

    def close(self) -> None:
        """End the worker (asked first, killed if it does not go)."""
        if self.process.poll() is None:
            try:
                data = json.dumps({"op": "close", "arrays": []}).encode()
                self._commands.write(struct.pack("<I", len(data)) + data)
                self._commands.flush()
                self.process.wait(timeout=1)
            except (OSError, subprocess.TimeoutExpired, ValueError):
                pass
        self._finalizer()
        self._reader.join(timeout=1)


_LIVE: weakref.WeakSet[subprocess.Popen[bytes]] = weakref.WeakSet()
# each worker's output reader, by its process id: told to stop, joined, before the
# worker's output pipe is closed
_DRAINS: dict[int, tuple[threading.Event, threading.Thread]] = {}


def _end(process: subprocess.Popen[bytes]) -> None:
    """Kill a worker and everything it started (its own session).

    The group is killed even when the worker itself has ended: a process the filter
    forked may still hold the worker's pipes, and closing them would wait for it. (The
    kernel keeps the group's id from being reused while any process is in it.)
    """
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(process.pid, signal.SIGKILL)
    if process.poll() is None:
        with contextlib.suppress(subprocess.TimeoutExpired):
            process.wait(timeout=5)
    streams = [process.stdin, process.stdout]
    stop, reader = _DRAINS.pop(process.pid, (None, None))
    if stop is not None and reader is not None:
        reader.join(timeout=DRAIN_POLL_S * 5)  # what the worker printed last, read
        stop.set()
        reader.join(timeout=DRAIN_POLL_S * 5)  # its poll sees the stop
        if not reader.is_alive():
            streams.append(process.stderr)  # else left open: its thread still reads it
    else:
        streams.append(process.stderr)
    for stream in streams:
        try:
            if stream is not None:
                stream.close()
        except OSError:
            pass


@atexit.register
def _end_all() -> None:
    for process in list(_LIVE):
        _end(process)


PIPE_BYTES = 1 << 20


def _widen_pipe(fd: int) -> None:
    """Give a pipe 1 MiB (Linux; else as it is): a state of a few MB then crosses in a
    few reads instead of dozens of 64 KiB ones."""
    try:
        import fcntl

        fcntl.fcntl(fd, getattr(fcntl, "F_SETPIPE_SZ", 1031), PIPE_BYTES)
    except (ImportError, OSError):
        pass


# the kinds of failure a worker may report of the user's code (the others are ekfviz's)
_CHILD_KINDS = frozenset(("raised", "fault", "exit", "memory"))
Launch = tuple[list[str], dict[str, str], str | None]


def _plain(options: WorkerOptions) -> Launch:
    """The worker's command line without the sandbox: (argv, environment, working
    directory)."""
    env = _clean_env(options.cwd) if options.clean_env else dict(os.environ)
    env["PYTHONUNBUFFERED"] = "1"
    env["PYTHONDONTWRITEBYTECODE"] = "1"  # no __pycache__ left in a submission's folder
    env.setdefault("MPLBACKEND", "Agg")
    settings = {"memory_bytes": options.memory_mb * (1 << 20)} if options.memory_mb else {}
    python = options.python or sys.executable
    return [python, str(WORKER_SCRIPT), json.dumps(settings)], env, options.cwd


def _sandboxed(
    options: WorkerOptions, mounts: Sequence[bwrap.Mount], settings: dict[str, object]
) -> Launch:
    """The worker's command line in the sandbox, its seccomp program in its settings.

    :raises WorkerFault: the sandbox cannot start here (kind ``start``)
    """
    try:
        view = bwrap.interpreter_view(options.python)
        bwrap.check(options.python)  # (once a process: why it cannot start, what to check)
    except bwrap.SandboxUnavailable as error:
        raise WorkerFault(str(error), "start") from None
    program = bwrap.seccomp_program()
    settings = {**settings, "sys_path": list(view.sys_path),
                "seccomp": "" if program is None else program.hex()}  # fmt: skip
    argv = bwrap.command(view, mounts, json.dumps(settings))
    return argv, dict(bwrap.ENVIRONMENT), "/"


def _clean_env(cwd: str | None) -> dict[str, str]:
    """An environment without the caller's variables: a PATH, a locale, a home of its own."""
    home = cwd or tempfile.gettempdir()
    return {
        "PATH": "/usr/local/bin:/usr/bin:/bin",
        "HOME": home,
        "TMPDIR": home,
        "LANG": "C.UTF-8",
        "LC_ALL": "C.UTF-8",
        "OPENBLAS_NUM_THREADS": "1",
        "OMP_NUM_THREADS": "1",
        "MKL_NUM_THREADS": "1",
    }


def _version(text: str) -> tuple[int, int]:
    parts = []
    for piece in text.split(".")[:2]:
        digits = "".join(c for c in piece if c.isdigit())
        parts.append(int(digits) if digits else 0)
    padded = [*parts, 0, 0]
    return padded[0], padded[1]
