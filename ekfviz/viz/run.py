"""One ``ekfviz replay`` run as a self-describing recording, sent to the sinks asked for.

``open_run`` makes the recording stream (application id "ekfviz", a recording id fixed
by the version, the input, the truth and the parameters), sends the default layout,
the recording properties, the run information and the input itself, attaches the sinks
and hands out a ``RunLogger`` built on :class:`~ekfviz.viz.recorder.Recorder`.
"""

from __future__ import annotations

import contextlib
import hashlib
import ipaddress
import json
import os
import shlex
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from urllib.parse import quote, urlsplit

import rerun as rr
from rerun.any_batch_value import ComponentValueLike

from ekfviz import __version__, signals
from ekfviz.core.errors import InputError
from ekfviz.core.records import EventRecord, EventRows
from ekfviz.core.tables import utf8
from ekfviz.core.truth import GroundTruth
from ekfviz.evaluation.errors import Evaluation
from ekfviz.filters.ekf import HAVE_KERNEL
from ekfviz.io.paths import (
    OutputPathError,
    check_output_path,
    real_path,
    temporary_prefix,
    unused_path,
)
from ekfviz.io.text import open_input
from ekfviz.models.range_bearing import RangeBearing
from ekfviz.viz import style
from ekfviz.viz.flush import (
    DiskFull,
    disk_full,
    flush_interruptibly,
    note_writer,
    watch_file,
    written_file,
)
from ekfviz.viz.recorder import Recorder

APPLICATION_ID = style.APPLICATION_ID
TIME_PROPERTY = "time"  # the span of the time timeline: start, end (seconds), kind
RESULTS_PROPERTY = "results"  # a replay's results beside its evaluation, as JSON
INPUT_TEXT_CAP = 4 * 1024 * 1024  # bytes of input embedded in a recording
GRPC_PORT = 9876
WEB_PORT = 9090
FLUSH_TIMEOUT_S = 60.0
# Fixed namespace: recording ids are uuid5(namespace, digest of what made the run).
RECORDING_NAMESPACE = uuid.UUID("6f1d3c52-8a47-5e0b-9c1e-2b7a4d9e0f31")


CONNECT_TIMEOUT_S = 3.0  # how long --connect waits for a viewer to answer


class SinkError(Exception):
    """A Rerun output that cannot be used, with a one-line reason and what to do instead."""


# The client's HTTP/2 connection preface, and the frame type a server must answer with
_HTTP2_PREFACE = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + bytes([0, 0, 0, 4, 0, 0, 0, 0, 0])
_HTTP2_SETTINGS = 4


def viewer_answers(url: str, timeout: float = CONNECT_TIMEOUT_S) -> bool | None:
    """Whether a gRPC server (a Rerun viewer) answers at ``url`` within ``timeout``.

    Rerun's own client waits about 100 s for an absent viewer, deaf to Ctrl-C, so the
    address is tried here first: a TCP connection, then the HTTP/2 preface, which a gRPC
    server answers at once with its SETTINGS frame. A port nobody listens on, or one whose
    listener never answers, is no viewer. Ctrl-C and SIGTERM are honoured while it waits,
    also while a replay still holds them back (see :mod:`ekfviz.signals`).

    :return: None when ``url`` has no host and port to try (Rerun then says what is wrong)
    """
    found: list[bool | None] = []
    helper = threading.Thread(
        target=lambda: found.append(_try_viewer(url, timeout)), name="ekfviz-probe", daemon=True
    )
    helper.start()
    while helper.is_alive():
        helper.join(0.1)
        signals.raise_pending()
    return found[0] if found else False


def _try_viewer(url: str, timeout: float) -> bool | None:
    """See :func:`viewer_answers`."""
    parts = urlsplit(url.removeprefix("rerun+"))
    try:
        host, port = parts.hostname, parts.port
    except ValueError:
        return None
    if host is None or port is None or parts.scheme not in ("http", "https"):
        return None
    if parts.scheme == "https":  # TLS: a TCP connection is all that can be tried here
        try:
            socket.create_connection((host, port), timeout=timeout).close()
        except OSError:
            return False
        return True
    deadline = time.monotonic() + timeout
    try:
        with socket.create_connection((host, port), timeout=timeout) as connection:
            connection.settimeout(max(0.1, deadline - time.monotonic()))
            connection.sendall(_HTTP2_PREFACE)
            header = b""
            while len(header) < 9:
                piece = connection.recv(9 - len(header))
                if not piece:
                    return False
                header += piece
    except OSError:  # refused, unreachable, timed out
        return False
    return header[3] == _HTTP2_SETTINGS


@dataclass(frozen=True, slots=True)
class RunInfo:
    """Everything that describes a run: what was replayed, how, and with which result.

    Build it with :func:`run_info`, which reads the input to fill in its size, sha256
    and text.
    """

    name: str
    command: str
    parameters: dict[str, object]
    input_path: Path
    input_size: int
    input_sha256: str
    input_text: str | None  # None when over INPUT_TEXT_CAP or not UTF-8 (see input_note)
    input_note: str | None
    truth: GroundTruth | None = None
    truth_path: Path | None = None
    truth_sha256: str | None = None
    version: str = field(default=__version__)
    kind: str = "replay"  # or "sweep": what ``ekfviz info`` says the recording is
    # each file's own sha256 where the input or truth is several files (a dataset)
    file_digests: dict[str, str] = field(default_factory=dict)

    @property
    def recording_id(self) -> str:
        """A UUID fixed by the version, the input, the truth and the parameters."""
        digest = hashlib.sha256(
            json.dumps(
                [self.version, self.input_sha256, self.truth_sha256, self.parameters],
                sort_keys=True,
                default=str,
            ).encode()
        ).hexdigest()
        return str(uuid.uuid5(RECORDING_NAMESPACE, digest))

    def markdown(self) -> str:
        """The run information as a markdown document for the viewer."""
        rows = [
            f"# {self.name}",
            "",
            f"- **ekfviz** {self.version}",
            f"- **command** `{self.command}`",
            f"- **input** `{self.input_path.name}`, {self.input_size} bytes,"
            f" sha256 `{self.input_sha256}`",
        ]
        if self.input_note:
            rows.append(f"- **input text** {self.input_note}")
        if self.truth_path is not None:
            rows.append(f"- **truth** `{self.truth_path.name}`, sha256 `{self.truth_sha256}`")
        rows += [
            f"- **file** `{path}`, sha256 `{digest}`" for path, digest in self.file_digests.items()
        ]
        rows += ["", "## Parameters", "", "| parameter | value |", "|---|---|"]
        rows += [f"| {key} | `{_json(value)}` |" for key, value in self.parameters.items()]
        return "\n".join(rows) + "\n"


def run_info(
    name: str,
    command: str,
    parameters: dict[str, object],
    input_path: Path,
    truth: GroundTruth | None = None,
    truth_path: Path | None = None,
    input_files: Sequence[Path] | None = None,
    truth_files: Sequence[Path] | None = None,
    kind: str = "replay",
) -> RunInfo:
    """Describe a run, reading the input (and truth) file for its size, sha256 and text.

    :param input_files: the files an input directory is read from (an MRCLAM dataset's
        robot): their size and sha256 together, the text of none
    :param truth_files: likewise for the truth, instead of ``truth_path`` alone
    :raises InputError: when the input or truth file cannot be read
    """
    if input_files is not None and input_path.is_dir():
        size, sha256 = _digest_files(input_files)
        return replace(
            _described(
                name, command, parameters, input_path, size, sha256, None,
                "not embedded: a dataset directory", truth, truth_path, truth_files, input_files,
            ),
            kind=kind,
        )  # fmt: skip
    size, sha256, data = _digest(input_path, keep_up_to=INPUT_TEXT_CAP)
    text: str | None = None
    note: str | None = None
    if data is None:
        note = f"not embedded: over the {INPUT_TEXT_CAP // (1024 * 1024)} MiB cap"
    else:
        try:
            text = data.decode("utf-8")
        except UnicodeDecodeError:
            note = "not embedded: not UTF-8 text"
    return replace(
        _described(
            name, command, parameters, input_path, size, sha256, text, note, truth, truth_path,
            truth_files,
        ),
        kind=kind,
    )  # fmt: skip


def _described(
    name: str,
    command: str,
    parameters: dict[str, object],
    input_path: Path,
    size: int,
    sha256: str,
    text: str | None,
    note: str | None,
    truth: GroundTruth | None,
    truth_path: Path | None,
    truth_files: Sequence[Path] | None,
    input_files: Sequence[Path] | None = None,
) -> RunInfo:
    truth_sha256 = None
    truth_list = list(truth_files or ([] if truth_path is None else [truth_path]))
    if len(truth_list) == 1:  # the file's own digest, as sha256sum prints it
        truth_sha256 = _digest(truth_list[0], keep_up_to=0)[1]
    elif truth_list:  # a dataset's files: a digest of them all, each in file_digests
        truth_sha256 = _digest_files(truth_list)[1]
    listed = [*(input_files or []), *truth_list] if len(truth_list) > 1 or input_files else []
    return RunInfo(
        name=name,
        command=command,
        parameters=dict(parameters),
        input_path=input_path,
        input_size=size,
        input_sha256=sha256,
        input_text=text,
        input_note=note,
        truth=truth,
        truth_path=truth_path,
        truth_sha256=truth_sha256,
        file_digests=_file_digests(listed),
    )


def _file_digests(paths: Sequence[Path]) -> dict[str, str]:
    """Each file's own sha256, by path as given."""
    return {str(path): _digest(path, keep_up_to=0)[1] for path in paths}


def _digest_files(paths: Sequence[Path]) -> tuple[int, str]:
    """Total size and the sha256 of several files, each named and hashed in turn."""
    sha = hashlib.sha256()
    total = 0
    for path in paths:
        size, digest, _ = _digest(path, keep_up_to=0)
        total += size
        sha.update(f"{path.name}\0{digest}\n".encode())
    return total, sha.hexdigest()


def _digest(path: Path, *, keep_up_to: int) -> tuple[int, str, bytes | None]:
    """Size, sha256 and, when at most ``keep_up_to`` bytes, the content of a file."""
    sha = hashlib.sha256()
    kept = bytearray()
    size = 0
    # opened as the readers open their files (a FIFO refused, not waited on for ever)
    with open_input(path, "a regular file") as file:
        try:
            while block := file.read(1 << 20):
                sha.update(block)
                size += len(block)
                if size <= keep_up_to:
                    kept += block
        except OSError as error:  # the same words as the readers' errors
            raise InputError(path, 0, f"cannot be read ({error.strerror})") from None
    return size, sha.hexdigest(), bytes(kept) if size <= keep_up_to else None


def _json(value: object) -> str:
    return json.dumps(value, default=str)


# -- sinks -----------------------------------------------------------------------------


LOOPBACK = "127.0.0.1"
SERVE_START_S = 15.0  # how long --serve waits for its viewer program to listen


@dataclass(frozen=True, slots=True)
class Sinks:
    """Where a recording goes: a file, a spawned viewer, a served web viewer, a viewer URL.

    :param bind: the address the served web viewer and its gRPC server listen on
        (loopback unless the user says otherwise)
    """

    save: Path | None = None
    spawn: bool = False
    serve: bool = False
    connect: str | None = None
    bind: str = LOOPBACK

    @property
    def any(self) -> bool:
        return self.save is not None or self.spawn or self.serve or self.connect is not None


def has_display() -> bool:
    """Whether a native viewer window can open here: on Linux, a display server answers
    where ``WAYLAND_DISPLAY`` or ``DISPLAY`` says (a variable left from a session that
    ended names none: the viewer would fail to open, and the run wait for it)."""
    return display_problem() is None


def display_problem() -> str | None:
    """Why no viewer window can open here, or None where one can."""
    if sys.platform in ("darwin", "win32"):
        return None
    wayland, x11 = os.environ.get("WAYLAND_DISPLAY"), os.environ.get("DISPLAY")
    if not wayland and not x11:
        return "DISPLAY/WAYLAND_DISPLAY is not set"
    said = []
    if wayland:
        folder = os.environ.get("XDG_RUNTIME_DIR", "")
        path = wayland if wayland.startswith("/") else os.path.join(folder, wayland)
        if _answers(socket.AF_UNIX, path):
            return None
        said.append(f"WAYLAND_DISPLAY={wayland}")
    if x11:
        if any(_answers(family, address) for family, address in _x_addresses(x11)):
            return None
        said.append(f"DISPLAY={x11}")
    return f"no display server answers at {' or '.join(said)}"


def _x_addresses(display: str) -> list[tuple[socket.AddressFamily, str | tuple[str, int]]]:
    """Where the X server of ``display`` (``[host]:N[.screen]``) listens: its local socket
    (a file, then Linux's abstract one) or, for a host, TCP port 6000 + N."""
    host, _, rest = display.rpartition(":")
    number = rest.split(".")[0]
    if not number.isdigit():
        return []
    if host in ("", "unix"):
        path = f"/tmp/.X11-unix/X{number}"
        return [(socket.AF_UNIX, path), (socket.AF_UNIX, "\0" + path)]
    if host.startswith("/"):  # a socket's path (macOS's launchd: /private/tmp/...:0)
        return [(socket.AF_UNIX, display)]
    return [(socket.AF_INET, (host, 6000 + int(number)))]


def _answers(family: socket.AddressFamily, address: str | tuple[str, int]) -> bool:
    """Whether something accepts a connection at ``address`` (within half a second)."""
    try:
        with socket.socket(family, socket.SOCK_STREAM) as probe:
            probe.settimeout(0.5)
            probe.connect(address)
        return True
    except (OSError, ValueError):  # (a host name that does not resolve; a path too long)
        return False


def resolve_default_sinks(
    sinks: Sinks, input_path: Path, recordings_dir: Path, name: str | None = None
) -> tuple[Sinks, str | None]:
    """The sinks asked for or, when none: a viewer where a display exists, else a file.

    :return: the sinks to use and a note to print about the choice (None when asked for)
    """
    if sinks.any:
        return sinks, None
    problem = display_problem()
    if problem is None:
        return Sinks(spawn=True), "No Rerun output option given: sent the run to a Rerun viewer."
    try:
        if not recordings_dir.is_dir():
            try:  # the default folder, in the current one: made when missing (not its parents)
                recordings_dir.mkdir()
            except OSError as error:
                raise SinkError(
                    f"cannot make the folder {recordings_dir} ({error.strerror})"
                ) from None
        path = unused_path(recordings_dir / f"{name or input_path.stem}.rrd")
    except OSError as error:  # a folder that cannot be read, a name too long for it
        where = error.filename if isinstance(error.filename, str) else recordings_dir
        raise SinkError(
            f"cannot save the recording as {where} ({error.strerror or error});"
            " name the file with --save"
        ) from None
    no_display = "no display" if problem.endswith("not set") else f"no display ({problem})"
    return Sinks(save=path), (
        f"No Rerun output option and {no_display}: saved the recording to {path}"
        f" (open it with: {shlex.quote(rerun_hint())} {shlex.quote(str(path))})"
    )


def rerun_hint() -> str:
    """How the user's shell runs the viewer: ``rerun`` if that is this installation's,
    else its path beside this Python (an unactivated virtual environment)."""
    beside = Path(sys.executable).parent / ("rerun.exe" if sys.platform == "win32" else "rerun")
    found = shutil.which("rerun")
    if not beside.is_file() or (found is not None and Path(found).resolve() == beside.resolve()):
        return "rerun"
    with contextlib.suppress(ValueError):
        return str(beside.relative_to(Path.cwd()))
    return str(beside)


def _rerun_executable() -> str | None:
    """The ``rerun`` viewer binary: on PATH, or beside this Python in an unactivated venv."""
    found = shutil.which("rerun")
    if found:
        return found
    beside = Path(sys.executable).parent / ("rerun.exe" if sys.platform == "win32" else "rerun")
    return str(beside) if beside.is_file() else None


def web_viewer_url(grpc_uri: str, web_port: int = WEB_PORT, host: str = "localhost") -> str:
    """The address of the served web viewer, pointed at the gRPC server."""
    return f"http://{host}:{web_port}/?url={quote(grpc_uri, safe=':/')}"


def check_bind(address: str) -> str:
    """An IP address to serve on, as given; a one-line complaint otherwise.

    :raises SinkError: not an IPv4 or IPv6 address
    """
    try:
        ipaddress.ip_address(address)
    except ValueError:
        raise SinkError(
            f"--bind {address}: expected an IP address, e.g. 127.0.0.1 (this machine only,"
            " the default) or 0.0.0.0 (every network interface)"
        ) from None
    return address


def _url_host(bind: str) -> str:
    """The host to put in a URL for a server bound to ``bind``."""
    address = ipaddress.ip_address(bind)
    if address.is_loopback:
        return "localhost" if address.version == 4 else "[::1]"
    if address.is_unspecified:  # every interface: the machine's name
        return socket.gethostname()
    return bind if address.version == 4 else f"[{bind}]"


class ServedViewer:
    """The web viewer and its gRPC server, served by Rerun's viewer program on ``bind``.

    Rerun's ``serve_web_viewer`` always listens on every network interface; its viewer
    program takes ``--bind``, so ``--serve`` runs that, as a child that ends with this
    process (terminated on close; on Linux also when this process is killed outright).
    """

    def __init__(self, bind: str) -> None:
        executable = _viewer_binary() or _rerun_executable()
        if executable is None:
            raise SinkError("--serve needs the rerun viewer program, which is not installed")
        self.bind = bind
        host = _url_host(bind)
        self.grpc_url = f"rerun+http://{host}:{GRPC_PORT}/proxy"
        self.url = web_viewer_url(self.grpc_url, WEB_PORT, host)
        self._log = tempfile.TemporaryFile()  # noqa: SIM115 (closed by close())
        self.process = subprocess.Popen(
            [
                executable, "--serve-web", "--bind", bind, "--port", str(GRPC_PORT),
                "--web-viewer-port", str(WEB_PORT), "--hide-welcome-screen",
            ],
            stdin=subprocess.DEVNULL,
            stdout=self._log,
            stderr=subprocess.STDOUT,
            preexec_fn=_end_with_parent if sys.platform == "linux" else None,
            start_new_session=True,  # its own group: stopped whole, wrapper script and all
        )  # fmt: skip
        local = LOOPBACK if ipaddress.ip_address(bind).is_unspecified else bind
        probe = f"http://{local if ':' not in local else f'[{local}]'}:{GRPC_PORT}"
        deadline = time.monotonic() + SERVE_START_S
        while not viewer_answers(probe, timeout=1.0):
            if self.process.poll() is not None or time.monotonic() > deadline:
                reason = self._last_line() or "it did not start"
                self.close()
                raise SinkError(f"--serve on {bind}, ports {WEB_PORT} and {GRPC_PORT}: {reason}")
            time.sleep(0.1)

    def _last_line(self) -> str:
        with contextlib.suppress(OSError):
            self._log.seek(0)
            lines = [
                line.strip() for line in self._log.read().decode(errors="replace").splitlines()
            ]
            lines = [line for line in lines if line]
            if lines:
                return lines[-1][:300]
        return ""

    def close(self) -> None:
        """Stop the viewer program."""
        for signum in (signal.SIGTERM, signal.SIGKILL):
            with contextlib.suppress(OSError):
                os.killpg(self.process.pid, signum)
            try:
                self.process.wait(2.0)
                break
            except subprocess.TimeoutExpired:
                continue
        self._log.close()


def _viewer_binary() -> str | None:
    """The viewer program itself, not the ``rerun`` script that runs it as a child."""
    import importlib.util

    spec = importlib.util.find_spec("rerun_cli")
    if spec is None or spec.origin is None:
        return None
    binary = Path(spec.origin).parent / ("rerun.exe" if sys.platform == "win32" else "rerun")
    return str(binary) if binary.is_file() and os.access(binary, os.X_OK) else None


def _end_with_parent() -> None:
    """In the viewer program's process (Linux): SIGTERM when its parent dies."""
    import ctypes

    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG


# -- the run ---------------------------------------------------------------------------


class Recording:
    """An open recording stream with its sinks; built by :func:`open_recording`.

    :ivar rec: the stream to log to
    :ivar url: the web viewer's address when serving, else None
    :ivar complete: set once everything is logged: only then is a ``--save`` file written
    :ivar partial: the run was cut short: its file goes to :func:`partial_path` when one
        is already at the ``--save`` path
    :ivar saved_to: where the ``--save`` file was written, once it is
    """

    def __init__(
        self, rec: rr.RecordingStream, url: str | None, unreachable: str | None = None
    ) -> None:
        self.rec = rec
        self.url = url
        self.complete = False
        self.save_failed: str | None = None  # why the --save file is not whole, if it is not
        self.save_path: Path | None = None  # the --save path, for messages
        self.partial = False  # a run cut short: never written over an existing file
        self.saved_to: Path | None = None  # where a --save file went, once written
        self.unreachable = unreachable  # a --connect URL without a viewer, when saving too

    def wait_while_serving(self) -> None:
        """Block until Ctrl-C while the web viewer is served; return at once otherwise."""
        if self.url is None:
            return
        try:
            while True:
                time.sleep(3600.0)
        except KeyboardInterrupt:
            return


class RunLogger:
    """Logs the records of one run; built by :func:`open_run`.

    :ivar url: the web viewer's address when serving, else None
    :ivar recorder: the :class:`Recorder` doing the logging
    """

    def __init__(self, recorder: Recorder, recording: Recording) -> None:
        self.recorder = recorder
        self.recording = recording
        self.url = recording.url
        self.logged = 0  # records logged so far
        self.last: EventRecord | None = None  # the last record logged
        self._rows: EventRows | None = None  # the predicts logged as rows, if any

    @property
    def finished(self) -> bool:
        return self.recording.complete

    def log(self, record: EventRecord) -> None:
        """Log one record of the core."""
        self.recorder.log_record(record)
        self.logged += 1
        self.last = record

    def event_rows(self) -> EventRows:
        """Where a replay writes its plain events as columns, for the recorder to log
        before the next record (see :class:`~ekfviz.viz.layers.pending.PendingEvents`)."""
        self._rows = self.recorder.pending.event_rows()
        return self._rows

    def finish(self, evaluation: Evaluation | None) -> None:
        """Log the evaluation document and send the buffered series: the run is complete;
        the span of the ``time`` timeline, if any, goes into the properties."""
        finish_recorders(self.recording, [(self.recorder, evaluation)])
        span = self.recorder.time_span
        if span is not None:
            kind = "timestamp" if self.recorder.time_is_epoch else "duration"
            self.recording.rec.send_property(
                TIME_PROPERTY, _any_values({"start": span[0], "end": span[1], "kind": kind})
            )

    def add_results(self, results: Mapping[str, object]) -> None:
        """Results of the run beside its evaluation (the association's counts, the GPS
        error of Victoria Park), as the property ``results`` that ``ekfviz info`` shows."""
        self.recording.rec.send_property(
            RESULTS_PROPERTY, _any_values({"json": json.dumps(dict(results), default=str)})
        )

    def stop(self, reason: str, evaluation: Evaluation | None) -> bool:
        """End a run cut short (bad input, a numerical fault, a signal): log why as the
        last line, send what is buffered and keep the recording if it holds any event.

        :return: whether the recording is kept (and, with ``--save``, written)
        """
        if not self.logged:
            return False
        self.recording.partial = True
        self.recorder.note(reason, level=rr.TextLogLevel.ERROR)
        last = self.last if self._rows is None else self._rows.latest(self.last)
        finish_recorders(
            self.recording,
            [(self.recorder, evaluation)],
            status={
                "state": "stopped",
                "reason": reason,
                "event": -1 if last is None else last.event,
                "step": -1 if last is None else last.step,
                "line": -1 if last is None else last.line,
            },
        )
        return True

    def wait_while_serving(self) -> None:
        """Block until Ctrl-C while the web viewer is served; return at once otherwise."""
        self.recording.wait_while_serving()


def _save_failure(rec: rr.RecordingStream, error: RuntimeError) -> str | None:
    """Why the file a recording is saved to was not written whole, if the flush that
    raised ``error`` says so (Rerun's file writer stopped, or its disk is full); None
    for another sink's failure (a viewer that did not answer)."""
    path = written_file(rec)
    if path is None:
        return None
    if isinstance(error, DiskFull):
        return str(error)
    text = str(error).lower()
    if "file-writer" in text or "file writer" in text or disk_full(path):
        return "no space left on its disk" if disk_full(path) else str(error).splitlines()[0]
    return None


def finish_recorders(
    recording: Recording,
    recorders: Sequence[tuple[Recorder, Evaluation | None]],
    status: Mapping[str, str | int] | None = None,
) -> None:
    """Finish every recorder of a recording (series, evaluation), record how the run
    ended (the property ``status``: finished unless told otherwise) and mark it complete.
    """
    recording.rec.send_property("status", _any_values(status or {"state": "finished"}))
    try:
        for recorder, evaluation in recorders:
            recorder.finish(evaluation)
    except RuntimeError as error:
        failed = _save_failure(recording.rec, error)
        if failed is not None:  # the file is not whole: it replaces nothing (not complete)
            recording.save_failed = failed
            raise SinkError(
                f"--save {recording.save_path}: the recording could not be written whole"
                f" ({failed}); nothing was replaced, no file left"
            ) from None
        # a viewer that never answered; a file is complete
        recording.complete = True
        reason = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise SinkError(f"the Rerun viewer did not take the recording: {reason}") from None
    recording.complete = True


@contextmanager
def open_recording(
    info: RunInfo, sinks: Sinks, *, recording_id: str | None = None, deferred: bool = False
) -> Iterator[Recording]:
    """A self-describing recording sent to ``sinks``, closed when the block ends.

    A ``--save`` file is written beside its path under a temporary name and moved over
    the path only once the recording is marked complete; otherwise the temporary file is
    removed and an existing file at the path is left untouched. The recording of a run
    cut short (marked ``partial``) never replaces a file: with one at the path it goes to
    :func:`partial_path` instead (``saved_to`` says where). Temporary files that runs
    killed outright (``kill -9``) left beside the path are removed first.

    :param recording_id: the recording's id (default: ``info.recording_id``, fixed by
        what made the run; one of its own for each of several runs of the same input)
    :param deferred: hold what is logged in memory and send it to the sinks only once
        the block ends with the recording complete: a viewer then never shows, and no
        file holds, a recording that was given up half-way
    :raises SinkError: when a sink cannot be used (no display for ``spawn``, ...)
    """
    if not sinks.any:
        raise SinkError("no Rerun output: use --save PATH, --spawn, --serve or --connect URL")
    rec = rr.RecordingStream(
        APPLICATION_ID, recording_id=recording_id or info.recording_id, send_properties=False
    )
    rec.set_log_time_enabled(False)  # only step and event: the same run gives the same data
    saving: tuple[Path, Path] | None = None  # the temporary file, the file it replaces
    recording: Recording | None = None
    unreachable: str | None = None
    if sinks.connect is not None and viewer_answers(sinks.connect) is False:
        if sinks.save is None and not sinks.spawn and not sinks.serve:
            raise SinkError(_no_viewer(sinks.connect))
        unreachable = sinks.connect  # the other outputs go on; said at the end
        sinks = Sinks(save=sinks.save, spawn=sinks.spawn, serve=sinks.serve)
    closers: list[Callable[[], None]] = []
    try:
        log_sinks, saving, url = _attach(rec, sinks, closers)
        if not deferred:
            rec.set_sinks(*log_sinks)
        _describe(rec, info)
        if not deferred:
            note_writer(rec)  # (its thread is running by now: the description took a while)
        recording = Recording(rec, url, unreachable)
        recording.save_path = sinks.save
        yield recording
    finally:
        complete = recording is not None and recording.complete
        failed = recording is not None and recording.save_failed is not None
        if deferred and complete:
            rec.set_sinks(*log_sinks)  # what was held goes to every sink now
            note_writer(rec)
        try:
            if saving is not None and (failed or (not complete and disk_full(saving[0]))):
                _abandon(rec)  # its file sink has stopped: a flush or disconnect would wait
            else:
                with contextlib.suppress(Exception):
                    flush_interruptibly(rec, FLUSH_TIMEOUT_S)
                rec.disconnect()  # finalises the file (footer) and stops a server
            for close in closers:
                close()
        except BaseException:  # a signal in the flush: the file is not known to be whole,
            if recording is not None:  # and is dropped (it left a hidden .part file)
                recording.complete = False
            raise
        finally:
            if saving is not None and sinks.save is not None:
                saved = _commit_or_remove(*saving, sinks.save, recording)
                if recording is not None:
                    recording.saved_to = saved
    if unreachable is not None:
        kept = f"; the recording is saved in {sinks.save}" if sinks.save is not None else ""
        raise SinkError(f"no Rerun viewer at {unreachable}{kept}")


def _no_viewer(url: str) -> str:
    return f"no Rerun viewer at {url} (start one with: {rerun_hint()}; or use --save PATH)"


@contextmanager
def open_run(
    info: RunInfo,
    sinks: Sinks,
    *,
    detail: bool = False,
    history: bool = False,
    sensor: RangeBearing | None = None,
    gps_reference: bool = False,
) -> Iterator[RunLogger]:
    """A recording of one replay (see :func:`open_recording`), logged by a RunLogger.

    :param detail: log every landmark's ellipse and error at every update (see
        :class:`~ekfviz.viz.recorder.Recorder`); by default a large map is logged whole
        only every ``MAP_EVERY_STEPS`` steps
    :param gps_reference: a GPS reference is logged after the run (its plot is laid out)
    """
    with open_recording(info, sinks) as recording:
        recorder = Recorder(
            recording.rec,
            truth=info.truth,
            run_documents=True,
            detail=detail,
            history=history,
            live_layout=sinks.spawn or sinks.serve or sinks.connect is not None,
            sensor=sensor,
            gps_reference=gps_reference,
        )
        yield RunLogger(recorder, recording)


def _attach(
    rec: rr.RecordingStream, sinks: Sinks, closers: list[Callable[[], None]]
) -> tuple[list[rr.LogSinkLike], tuple[Path, Path] | None, str | None]:
    """Make the sinks; return them, a save's temporary file and the file it is to
    replace (a symbolic link's target, not the link: see :func:`_commit_or_remove`),
    and a web viewer URL.

    :param closers: gets what must be stopped once the recording is closed
    """
    log_sinks: list[rr.LogSinkLike] = []
    saving: tuple[Path, Path] | None = None
    url: str | None = None
    if sinks.spawn:
        problem = display_problem()
        if problem is not None:
            raise SinkError(f"--spawn needs a display: {problem}; use --save or --serve")
        executable = _rerun_executable()
        if executable is None:
            raise SinkError("--spawn needs the rerun viewer, which is not installed; use --save")
        rr.spawn(
            port=GRPC_PORT,
            connect=False,
            executable_path=executable,
            hide_welcome_screen=True,
            recording=rec,  # without it, spawn() asks the (absent) global recording and skips
        )
        log_sinks.append(rr.GrpcSink(f"rerun+http://127.0.0.1:{GRPC_PORT}/proxy"))
    if sinks.connect is not None:
        try:
            log_sinks.append(rr.GrpcSink(sinks.connect))
        except (ValueError, RuntimeError) as error:
            raise SinkError(f"--connect {sinks.connect}: {error}") from None
    if sinks.serve:
        served = ServedViewer(check_bind(sinks.bind))
        closers.append(served.close)
        try:
            log_sinks.append(rr.GrpcSink(served.grpc_url))
        except (ValueError, RuntimeError) as error:
            raise SinkError(f"--serve: {error}") from None
        url = served.url
    if sinks.save is not None:
        target = sinks.save
        try:  # no folder is made: a path that cannot be written is refused before any work
            check_output_path(target, "--save")
        except OutputPathError as error:
            raise SinkError(str(error)) from None
        # Beside the file it replaces (same file system, so os.replace is atomic), made
        # by the FileSink itself so that it gets the usual permissions
        real = real_path(target)
        temporary = temporary_beside(real)
        log_sinks.append(rr.FileSink(temporary))
        watch_file(rec, temporary)  # a full disk stops a flush at once (see viz.flush)
        saving = temporary, real
    return log_sinks, saving, url


def _abandon(rec: rr.RecordingStream) -> None:
    """Let go of a stream whose file sink stopped on a full disk: its disconnect (which
    flushes) is left to a helper thread, and Rerun's flush at exit is not waited for
    (both would wait for ever); its temporary file is then removed, replacing nothing."""
    helper = threading.Thread(target=rec.disconnect, name="ekfviz-abandon", daemon=True)
    helper.start()
    helper.join(ABANDON_WAIT_S)
    rr.unregister_shutdown()


ABANDON_WAIT_S = 1.0


def temporary_beside(target: Path) -> Path:
    """A fresh hidden name in the folder of ``target``: the same file system, so a
    finished file can replace ``target`` atomically with ``os.replace``.

    The name holds this process's id, so that the next run to ``target`` can tell a
    file of a run that died (see :func:`remove_stale_parts`) from one being written.
    """
    remove_stale_parts(target)
    return target.with_name(f"{temporary_prefix(target)}{os.getpid()}.{uuid.uuid4().hex[:8]}.part")


def remove_stale_parts(target: Path) -> list[Path]:
    """Remove the temporary files beside ``target`` of runs whose process is gone (a
    run killed with ``kill -9`` cannot remove its own); those of live processes stay.

    :return: the files removed
    """
    removed: list[Path] = []
    prefix = temporary_prefix(target)
    try:
        names = [entry.name for entry in os.scandir(target.parent or Path("."))]
    except OSError:
        return removed
    for name in names:
        if not (name.startswith(prefix) and name.endswith(".part")):
            continue
        fields = name[len(prefix) : -len(".part")].split(".")
        if len(fields) != 2 or not fields[0].isdigit() or _alive(int(fields[0])):
            continue
        stale = target.with_name(name)
        with contextlib.suppress(OSError):
            stale.unlink()
            removed.append(stale)
    return removed


def _alive(pid: int) -> bool:
    """Whether a process with this id exists (one of another user's counts)."""
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError):
        return True
    return True


def partial_path(target: Path) -> Path:
    """Where the recording of a run cut short goes when a file is at ``target``:
    ``RUN.partial.rrd`` beside ``RUN.rrd`` (an earlier partial recording there is
    replaced)."""
    return target.with_name(f"{target.stem}.partial{target.suffix or '.rrd'}")


def _commit_or_remove(
    temporary: Path, real: Path, target: Path, recording: Recording | None
) -> Path | None:
    """Move a complete recording over its path and a partial one over its path or,
    when a file is there already, beside it; drop an incomplete one.

    ``real`` is ``target`` with its symbolic links followed: a link's target is
    written, the link kept (moved over the link itself, the file would replace it:
    ``--save /dev/stdout`` replaced the system's link with a recording).

    :return: where the recording was written (``target`` as given when it went there),
        None when it was dropped
    """
    if recording is None or not recording.complete:
        temporary.unlink(missing_ok=True)
        return None
    partial = recording.partial and real.exists()
    try:
        os.replace(temporary, partial_path(real) if partial else real)
    except OSError as error:  # e.g. a user's filter that cleaned up the folder meanwhile
        temporary.unlink(missing_ok=True)
        raise SinkError(
            f"{target}: the recording could not be saved: its temporary file {temporary.name}"
            f" did not move there ({error.strerror}: removed during the run?)"
        ) from None
    if partial:
        return partial_path(real) if target.is_symlink() else partial_path(target)
    return target


def _describe(rec: rr.RecordingStream, info: RunInfo) -> None:
    """Recording name and properties, the run information and the input, all static."""
    rec.send_recording_name(utf8(info.name))
    values: dict[str, str | int | bool | None] = {
        "version": info.version,
        "kind": info.kind,
        "command": info.command,
        "parameters": _json(info.parameters),
        "input_name": info.input_path.name,
        "input_size": info.input_size,
        "input_sha256": info.input_sha256,
        "input_embedded": info.input_text is not None,
        "truth_name": None if info.truth_path is None else info.truth_path.name,
        "truth_sha256": info.truth_sha256,
        "files_sha256": _json(info.file_digests) if info.file_digests else None,
        "compiled_kernel": HAVE_KERNEL,  # numbers differ from numpy's by round-off only
    }
    values = {k: utf8(v) if isinstance(v, str) else v for k, v in values.items()}
    rec.send_property("ekfviz", _any_values(values))
    if info.parameters:
        rec.send_property(
            # a parameter left unset (no --gate) is left out: its column's type is the
            # set value's, and a later recording in the process (a notebook's) would clash
            "parameters",
            _any_values(
                {k: _property_value(v) for k, v in info.parameters.items() if v is not None}
            ),
        )
    rec.log(
        style.RUN_INFO,
        rr.TextDocument(utf8(info.markdown()), media_type=rr.MediaType.MARKDOWN),
        static=True,
    )
    if info.input_text is not None:
        rec.log(style.RUN_INPUT, rr.TextDocument(info.input_text), static=True)
    else:
        rec.log(
            style.RUN_INPUT,
            rr.TextDocument(
                f"The input {info.input_path.name} ({info.input_size} bytes, sha256"
                f" {info.input_sha256}) is {info.input_note}."
            ),
            static=True,
        )


def _any_values(values: Mapping[str, ComponentValueLike | None]) -> rr.AnyValues:
    bundle = rr.AnyValues()
    for name, value in values.items():  # a file name in it may not be UTF-8 (Rerun's is)
        bundle.with_component_from_data(name, utf8(value) if isinstance(value, str) else value)
    return bundle


def _property_value(value: object) -> str | int | float | bool | list[float]:
    """A parameter as a value the viewer shows well: scalars as is, the rest as JSON."""
    if isinstance(value, str):
        return utf8(value)  # (a filter's file name may not be UTF-8)
    if isinstance(value, (int, float, bool)):
        return value
    if isinstance(value, (list, tuple)) and all(
        isinstance(v, (int, float)) and not isinstance(v, bool) for v in value
    ):
        return [float(v) for v in value]
    return _json(value)
