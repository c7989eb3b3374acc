"""The Rerun viewer a recording is sent to: whether one answers at a URL, whether a display
can show one, where its program is, and the web viewer served on an address of the
user's choice. Nothing here imports rerun: a viewer is a program and a port.
"""

from __future__ import annotations

import contextlib
import ipaddress
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from urllib.parse import quote, urlsplit

from ekfviz import signals
from ekfviz.core.errors import OutputError

GRPC_PORT = 9876
WEB_PORT = 9090
LOOPBACK = "127.0.0.1"
SERVE_START_S = 15.0  # how long --serve waits for its viewer program to listen


CONNECT_TIMEOUT_S = 3.0  # how long --connect waits for a viewer to answer


class SinkError(OutputError):
    """A Rerun output that cannot be used (a viewer, a served one, a recording's file),
    with a one-line reason and what to do instead."""


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


def rerun_executable() -> str | None:
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
        executable = _viewer_binary() or rerun_executable()
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

    def wait_until_interrupted(self) -> None:
        """Block until Ctrl-C (the user is done looking), then return."""
        try:
            while self.process.poll() is None:
                time.sleep(1.0)
        except KeyboardInterrupt:
            return

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


def no_viewer(url: str) -> str:
    """What to say of a ``--connect`` URL where no viewer answers."""
    return f"no Rerun viewer at {url} (start one with: {rerun_hint()}; or use --save PATH)"
