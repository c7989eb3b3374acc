"""What the sandbox of a user's filter holds, each statement of the README's "What the
sandbox protects" seen from inside a worker: a filter that looks around at its
construction and prints what it saw, read back here."""

from __future__ import annotations

import json
import os
import socket
import sys
import textwrap
from pathlib import Path

import pytest

from ekfviz.core.params import FilterParams
from ekfviz.sandbox import bwrap
from ekfviz.sandbox.host import WorkerFault
from ekfviz.sandbox.options import WorkerOptions
from ekfviz.sandbox.remote import Target, WorkerFactory
from ekfviz.sandbox.submission import MAX_BYTES, MAX_DEPTH, MAX_FILES, Submission

ROOT = Path(__file__).parents[2]
SECRET = "ekfviz-test-secret-7d1f"


def looks(folder: Path, code: str, **options: object) -> dict[str, object]:
    """What a filter whose construction runs ``code`` (filling ``seen``) printed of it."""
    module = folder / "probe.py"
    module.write_text(
        "import json, os, sys\nimport numpy as np\n\n\nclass Probe:\n"
        "    def __init__(self, params):\n        seen = {}\n"
        + textwrap.indent(textwrap.dedent(code), "        ")
        + "\n        print('SEEN ' + json.dumps(seen), flush=True)\n"
        "        self.x, self.P, self.landmark_ids = np.zeros(3), np.eye(3), []\n"
        "    def predict(self, d, alpha):\n        pass\n"
        "    def update(self, ids, z):\n        pass\n"
    )
    worker = WorkerOptions(echo=False, **options)  # type: ignore[arg-type]
    factory = WorkerFactory(Target(str(module), None, "Probe"), worker, "filter probe.py")
    try:
        remote = factory(FilterParams())
    finally:
        factory.close()
    lines = [line for line in remote.output.lines if line.startswith("SEEN ")]
    assert lines, list(remote.output.lines)
    return dict(json.loads(lines[-1][5:]))


def test_it_sees_no_file_of_the_caller_s_but_its_copy_the_interpreter_and_numpy(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    folder = tmp_path / "mine"
    folder.mkdir()
    (tmp_path / "neighbour.py").write_text(f"# {SECRET}\n")
    (folder / "helper.py").write_text("VALUE = 42\n")
    (folder / "notes.txt").write_text("not python: not shown for --filter\n")
    seen = looks(
        folder,
        f"""
        import importlib.util
        seen["root"] = sorted(os.listdir("/"))
        seen["here"] = sorted(os.listdir({str(folder)!r}))
        seen["parent"] = sorted(os.listdir({str(tmp_path)!r}))
        seen["home"] = os.path.exists({os.path.expanduser("~")!r} + "/.bashrc")
        seen["ekfviz"] = importlib.util.find_spec("ekfviz") is not None
        seen["cwd"], seen["tmp"] = os.getcwd(), os.listdir("/tmp")
        import helper
        seen["helper"] = helper.VALUE
        seen["numpy"] = np.__version__
    """,
    )
    assert seen["here"] == ["helper.py", "probe.py"]  # a private copy: its Python files
    assert seen["parent"] == ["mine"]  # no neighbour
    assert seen["home"] is False and seen["ekfviz"] is False
    # its own /tmp: empty but for the way to its copy and to the interpreter (a clone's
    # virtual environment), where those are under the caller's /tmp
    shown = (folder, Path(sys.prefix).resolve())
    on_the_way = sorted({p.parts[2] for p in shown if len(p.parts) > 2 and p.parts[1] == "tmp"})
    assert seen["cwd"] == "/tmp" and sorted(seen["tmp"]) == on_the_way
    assert seen["helper"] == 42 and seen["numpy"]
    assert "work" not in seen["root"] or str(ROOT).startswith("/work")  # (ekfviz's own path)


def test_it_writes_nothing_but_its_own_tmp(tmp_path: Path) -> None:
    seen = looks(
        tmp_path,
        f"""
        seen["descriptors"] = []
        for fd in os.listdir("/proc/self/fd"):
            try:
                seen["descriptors"].append(os.readlink("/proc/self/fd/" + fd).split(":")[0])
            except OSError:  # (the listing's own, closed since)
                pass
        try:
            os.open("/dev/tty", os.O_RDWR)
            seen["terminal"] = "opened"
        except OSError as error:
            seen["terminal"] = error.strerror
        for place in ({str(tmp_path)!r}, {str(tmp_path / "probe.py")!r}, np.__file__,
                      os.path.dirname(np.__file__), "/", "/usr", "/dev/shm"):
            try:
                with open(os.path.join(place, "x") if os.path.isdir(place) else place, "a"):
                    pass
                seen[place] = "written"
            except OSError as error:
                seen[place] = error.strerror
        with open("/tmp/mine.txt", "w") as handle:
            handle.write("x" * 1000)
        seen["tmp"] = os.path.getsize("/tmp/mine.txt")
    """,
    )
    assert seen.pop("tmp") == 1000
    # no descriptor of ekfviz's: /dev/null and the pipes of its channel
    assert set(seen.pop("descriptors")) == {"/dev/null", "pipe"}
    assert seen.pop("terminal") == "No such device or address"  # a session of its own
    assert "written" not in seen.values(), seen
    assert (tmp_path / "probe.py").read_text().startswith("import json")  # unchanged


def test_it_has_none_of_the_caller_s_environment(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("TA_TOKEN", SECRET)
    seen = looks(
        tmp_path,
        """
        seen["env"] = dict(os.environ)
        for pid in ("1", "self"):
            try:
                seen[pid] = open("/proc/%s/environ" % pid, "rb").read().decode()
            except OSError as error:
                seen[pid] = error.strerror
    """,
    )
    assert seen["env"] == bwrap.ENVIRONMENT
    assert SECRET not in json.dumps(seen)
    assert seen["1"] == "Permission denied"  # its guard, PID 1, cannot be read


def test_it_has_no_network_not_even_loopback(tmp_path: Path) -> None:
    with socket.socket() as listening:
        listening.bind(("127.0.0.1", 0))
        listening.listen()
        port = listening.getsockname()[1]
        seen = looks(
            tmp_path,
            f"""
            import socket
            for name, family in (("ipv4", socket.AF_INET), ("ipv6", socket.AF_INET6),
                                 ("netlink", socket.AF_NETLINK), ("packet", socket.AF_PACKET)):
                try:
                    socket.socket(family, socket.SOCK_DGRAM if name == "netlink" else
                                  socket.SOCK_STREAM if family != socket.AF_PACKET else
                                  socket.SOCK_RAW).close()
                    seen[name] = "made"
                except OSError as error:
                    seen[name] = error.strerror
            try:
                socket.create_connection(("127.0.0.1", {port}), timeout=2)
                seen["loopback"] = "connected"
            except OSError as error:
                seen["loopback"] = error.strerror
            local = socket.socket(socket.AF_UNIX)  # (its own, in its own /tmp)
            local.bind("/tmp/mine.sock")
            seen["unix"] = "bound"
        """,
        )
    assert seen.pop("unix") == "bound"
    assert set(seen.values()) == {"Operation not permitted"}, seen


def test_it_starts_no_process_sees_none_of_the_caller_s_and_signals_none(
    tmp_path: Path,
) -> None:
    seen = looks(
        tmp_path,
        """
        import signal, subprocess, threading
        for name, start in (("fork", os.fork),
                            ("subprocess", lambda: subprocess.Popen(["/bin/true"]))):
            try:
                start()
                seen[name] = "started"
            except OSError as error:
                seen[name] = error.strerror
        ran = []
        thread = threading.Thread(target=lambda: ran.append(1))
        thread.start()
        thread.join()
        seen["thread"] = ran
        seen["pids"] = sorted(p for p in os.listdir("/proc") if p.isdigit())
        seen["parent"] = os.getppid()
        os.kill(os.getppid(), signal.SIGKILL)  # its guard: nothing happens
        seen["after"] = os.getpid()
    """,
    )
    assert seen["fork"] == seen["subprocess"] == "Operation not permitted"
    assert seen["thread"] == [1]
    assert seen["pids"] == ["1", "2"] and seen["parent"] == 1
    assert seen["after"] == 2


def test_its_links_that_lead_out_are_refused_and_never_followed(tmp_path: Path) -> None:
    secret = tmp_path / "secret.txt"
    secret.write_text(SECRET)
    folder = tmp_path / "submission"
    folder.mkdir()
    (folder / "ekf.py").write_text("x = 1\n")
    (folder / "data.txt").symlink_to(secret)
    options = WorkerOptions(echo=False, submission=Submission(str(folder)))
    with pytest.raises(WorkerFault, match=r"data\.txt is a symbolic link that leads out") as raised:
        WorkerFactory(Target(str(folder / "ekf.py"), None, "F"), options, "f")
    assert raised.value.kind == "refused"
    (folder / "data.txt").unlink()
    os.link(secret, folder / "data.txt")  # a hard link: another's content
    with pytest.raises(WorkerFault, match=r"data\.txt has hard links outside"):
        WorkerFactory(Target(str(folder / "ekf.py"), None, "F"), options, "f")


@pytest.mark.parametrize("shape", ["files", "bytes", "depth"])
def test_a_submission_over_a_bound_is_refused_without_being_read(
    tmp_path: Path, shape: str
) -> None:
    folder = tmp_path / "submission"
    folder.mkdir()
    (folder / "ekf.py").write_text("x = 1\n")
    if shape == "files":
        for index in range(MAX_FILES + 1):
            (folder / f"f{index}.py").touch()
    elif shape == "bytes":
        with open(folder / "big.py", "wb") as handle:  # sparse: nothing on disk
            handle.truncate(1500 << 20)
    else:
        deep = folder
        for _ in range(MAX_DEPTH + 1):
            deep = deep / "d"
        deep.mkdir(parents=True)
    said = {"files": f"more than {MAX_FILES} files", "bytes": f"more than {MAX_BYTES >> 20} MiB",
            "depth": f"more than {MAX_DEPTH} deep"}[shape]  # fmt: skip
    options = WorkerOptions(echo=False, submission=Submission(str(folder)))
    with pytest.raises(WorkerFault, match=said):
        WorkerFactory(Target(str(folder / "ekf.py"), None, "F"), options, "f")


def test_a_sandbox_that_cannot_start_is_one_line_naming_what_to_check(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """As where user namespaces are off: bwrap says so, ekfviz says what to look at."""
    fake = tmp_path / "bin" / "bwrap"
    fake.parent.mkdir()
    options = " ".join(bwrap.NEEDED_OPTIONS)
    fake.write_text(
        "#!/bin/sh\n"
        f'if [ "$1" = --help ]; then echo "{options}"; exit 0; fi\n'
        'if [ "$1" = --version ]; then echo "bubblewrap 0.0"; exit 0; fi\n'
        "echo 'bwrap: No permissions to create a new namespace' >&2\nexit 1\n"
    )
    fake.chmod(0o755)
    monkeypatch.setenv("PATH", f"{fake.parent}:{os.environ['PATH']}")
    for cached in (bwrap.find_bwrap, bwrap.check):
        cached.cache_clear()
    try:
        with pytest.raises(bwrap.SandboxUnavailable) as raised:
            bwrap.check(None)
    finally:
        for cached in (bwrap.find_bwrap, bwrap.check):
            cached.cache_clear()
    said = str(raised.value)
    assert "\n" not in said and "No permissions to create a new namespace" in said
    assert "user.max_user_namespaces" in said and "--no-sandbox" in said
    # as the commands say it: one line, exit 2; --no-sandbox runs the class as before
    from typer.testing import CliRunner

    from ekfviz.cli import app

    folder = tmp_path / "class"
    folder.mkdir()
    (folder / "alice.py").write_text((ROOT / "examples/course_skeleton/ekf_slam.py").read_text())
    log = str(ROOT / "data" / "classic.txt")
    runner = CliRunner()
    try:
        refused = runner.invoke(app, ["grade", str(folder), "--log", log, "--workers", "1"])
        checked = runner.invoke(app, ["check", log, "--filter", str(folder / "alice.py")])
        graded = runner.invoke(app, ["grade", str(folder), "--log", log, "--workers", "1",
                                     "--no-sandbox"])  # fmt: skip
    finally:
        for cached in (bwrap.find_bwrap, bwrap.check):
            cached.cache_clear()
    for result in (refused, checked):
        assert result.exit_code == 2, result.output
        (line,) = result.output.strip().splitlines()
        assert line.startswith("error: ") and "user.max_user_namespaces" in line, line
    assert graded.exit_code == 0, graded.output
    assert "each in a sandbox: none (--no-sandbox)" in graded.output
    assert "1 match" in graded.output


def _dead_pid() -> int:
    """The number of a process that has ended."""
    import subprocess

    done = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)  # fmt: skip
    return int(done.stdout)


def _age(folder: Path, seconds: float) -> None:
    """Set ``folder``'s times ``seconds`` back."""
    import time

    then = time.time() - seconds
    os.utime(folder, (then, then))


def test_copies_of_processes_no_longer_running_are_removed_and_no_other(tmp_path: Path) -> None:
    from ekfviz.sandbox.submission import COPY_PREFIX, ORPHAN_AGE_S, remove_orphans

    dead, alive = _dead_pid(), os.getpid()
    orphan = tmp_path / f"{COPY_PREFIX}{dead}-a1b2"
    (orphan / "pkg").mkdir(parents=True)
    (orphan / "pkg" / "mod.py").write_text("x = 1\n")
    for folder in (orphan / "pkg", orphan):  # read-only, as a copy is
        for entry in folder.iterdir():
            entry.chmod(0o444 if entry.is_file() else 0o555)
        folder.chmod(0o555)
    kept = [
        tmp_path / f"{COPY_PREFIX}{alive}-c3d4",  # its process runs
        tmp_path / f"{COPY_PREFIX}x9y8z7w6",  # named without a process
        tmp_path / f"{dead}-e5f6",  # not a copy
    ]
    for folder in kept:
        folder.mkdir()
    (tmp_path / f"{COPY_PREFIX}{dead}-file").write_text("")  # not a folder
    (tmp_path / f"{COPY_PREFIX}{dead}-link").symlink_to(kept[0])  # a link: never followed
    assert remove_orphans(str(tmp_path)) == []  # just made: taken for no one's yet
    for folder in (orphan, *kept):
        _age(folder, ORPHAN_AGE_S + 1.0)
    assert remove_orphans(str(tmp_path)) == [str(orphan)]
    assert not orphan.exists() and all(folder.is_dir() for folder in kept)
    assert (tmp_path / f"{COPY_PREFIX}{dead}-file").exists()


@pytest.mark.slow
def test_a_copy_left_by_a_killed_check_goes_with_the_next_run(tmp_path: Path) -> None:
    """SIGKILL leaves a check no time to remove its submission's private copy: the next
    command that copies a submission removes it."""
    import contextlib
    import signal
    import subprocess
    import time

    from ekfviz.sandbox.submission import COPY_PREFIX, ORPHAN_AGE_S

    temporary = tmp_path / "tmp"
    temporary.mkdir()
    env = dict(os.environ, TMPDIR=str(temporary))
    stuck = tmp_path / "stuck.py"
    stuck.write_text(
        "import time\nimport numpy as np\n\n\nclass Stuck:\n"
        "    def __init__(self, params):\n"
        "        self.x, self.P, self.landmark_ids = np.zeros(3), np.eye(3), []\n"
        "    def predict(self, d, alpha):\n        time.sleep(600)\n"
        "    def update(self, ids, z):\n        pass\n"
    )
    check = subprocess.Popen(
        [sys.executable, "-m", "ekfviz", "check", "--filter", f"{stuck}:Stuck",
         "--filter-timeout", "600"],
        env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 60
        while not list(temporary.glob(f"{COPY_PREFIX}{check.pid}-*")):
            assert check.poll() is None and time.monotonic() < deadline
            time.sleep(0.05)
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(check.pid, signal.SIGKILL)
        check.wait()
    (left,) = temporary.glob(f"{COPY_PREFIX}*")
    _age(left, ORPHAN_AGE_S + 1.0)  # left a while ago
    example = ROOT / "examples" / "my_filter.py"
    done = subprocess.run(
        [sys.executable, "-m", "ekfviz", "check", "--filter", f"{example}:MyFilter"],
        env=env, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert not left.exists() and list(temporary.glob(f"{COPY_PREFIX}*")) == []
