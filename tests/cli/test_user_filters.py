"""A user's filter that misbehaves (a huge message, a print, a signal to its parent, its own
death, a fork, a loop, an interpreter that is no Python): one line naming what it did,
exit code 2, and ekfviz unharmed.
"""

from __future__ import annotations

import subprocess
import textwrap
from pathlib import Path

import numpy as np
import pytest
from commands import one_error_line, run_ekfviz, run_ekfviz_process

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "data"


TEXTBOOK = Path(__file__).parents[1] / "plugins" / "textbook.py"


def _plugin(tmp_path: Path, body: str) -> str:
    """A filter class ``Evil`` (the textbook filter with ``body`` added); its --filter."""
    module = tmp_path / "evil.py"
    module.write_text(TEXTBOOK.read_text() + "\n\n" + textwrap.dedent(body))
    return f"{module}:Evil"


def _replay_with(
    tmp_path: Path, spec: str, *extra: str, process: bool = False
) -> subprocess.CompletedProcess[str]:
    """``replay`` of the sample with the filter ``spec``; with ``process``, in a process of
    its own (for what the filter does to the process that runs it)."""
    run = run_ekfviz_process if process else run_ekfviz
    return run("replay", DATA / "classic.txt", "--filter", spec,
               "--save", tmp_path / "r.rrd", *extra)  # fmt: skip


def test_a_filters_multi_line_or_huge_message_is_one_line(tmp_path: Path) -> None:
    spec = _plugin(
        tmp_path,
        """
        class Evil(Textbook):
            def __init__(self, params):
                raise ValueError("first\\nsecond\\r\\nthird" + "z" * 100_000)
    """,
    )
    result = _replay_with(tmp_path, spec)
    assert result.returncode == 2
    # its lines joined by spaces, its length cut (the whole of it with --debug)
    line = one_error_line(result.stderr, "construction raised ValueError: first second third")
    assert len(line) < 2_000 and "(100019 characters in all)" in line


def test_what_a_failing_filter_printed_comes_before_the_error(tmp_path: Path) -> None:
    spec = _plugin(
        tmp_path,
        """
        import sys

        class Evil(Textbook):
            def predict(self, d, alpha):
                sys.stdout.write("a prompt with no line end")
                raise RuntimeError("no")
    """,
    )
    result = _replay_with(tmp_path, spec)
    assert result.returncode == 2
    lines = result.stderr.splitlines()
    assert lines[-1].startswith("error: ") and "predict raised RuntimeError: no" in lines[-1]
    assert any("a prompt with no line end" in line for line in lines[:-1]), result.stderr


def test_a_filter_signalling_its_parent_does_not_stop_ekfviz(tmp_path: Path) -> None:
    spec = _plugin(
        tmp_path,
        """
        import os, signal

        class Evil(Textbook):
            def predict(self, d, alpha):
                os.kill(os.getppid(), signal.SIGTERM)
                os.kill(os.getppid(), signal.SIGINT)
                super().predict(d, alpha)
    """,
    )
    # the signals go to the filter's parent: ekfviz in a process of its own, not the tests'
    result = _replay_with(tmp_path, spec, process=True)
    assert result.returncode == 0, result.stderr
    assert (tmp_path / "r.rrd").stat().st_size > 0


def test_a_filter_killing_itself_is_said_as_such(tmp_path: Path) -> None:
    spec = _plugin(
        tmp_path,
        """
        import os, signal

        class Evil(Textbook):
            def predict(self, d, alpha):
                os.kill(os.getpid(), signal.SIGKILL)
    """,
    )
    result = _replay_with(tmp_path, spec)
    assert result.returncode == 2
    one_error_line(result.stderr, "the filter's process was killed by SIGKILL during predict")


@pytest.mark.slow
def test_a_process_the_filter_forked_does_not_hold_the_command(tmp_path: Path) -> None:
    spec = _plugin(
        tmp_path,
        """
        import os, time

        class Evil(Textbook):
            def predict(self, d, alpha):
                if not getattr(self, "forked", False):
                    self.forked = True
                    if os.fork() == 0:
                        time.sleep(60)
                        os._exit(0)
                super().predict(d, alpha)
    """,
    )
    # a process of its own: the fork (outside the sandbox) is of the process running the
    # filter, and what is held is that process's end
    result = run_ekfviz_process("replay", DATA / "classic.txt", "--filter", spec, "--save",
                                tmp_path / "r.rrd", "--no-sandbox", timeout=30)  # fmt: skip
    assert result.returncode == 0, result.stderr
    # in the sandbox a filter starts no process at all: its fork is the filter's error
    result = run_ekfviz_process("replay", DATA / "classic.txt", "--filter", spec,
                                "--save", tmp_path / "r.rrd", timeout=30)  # fmt: skip
    assert result.returncode == 2
    one_error_line(result.stderr, "predict raised PermissionError: [Errno 1] Operation not")


@pytest.mark.parametrize("where", ["import", "construction"])
def test_a_loop_at_import_or_construction_is_bounded_by_the_filter_timeout(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, where: str
) -> None:
    """Once bounded only by the 120 s of a worker's start, whatever --filter-timeout said."""
    from ekfviz.core.params import FilterParams
    from ekfviz.sandbox import host as worker
    from ekfviz.sandbox.host import WorkerFault
    from ekfviz.sandbox.options import WorkerOptions
    from ekfviz.sandbox.remote import Target, WorkerFactory

    monkeypatch.setattr(worker, "MIN_LOAD_TIMEOUT_S", 0.5)
    module = tmp_path / "slow.py"
    loop = "while True:\n    pass\n"
    if where == "import":
        module.write_text(loop + "class Slow:\n    pass\n")
    else:
        module.write_text(
            "class Slow:\n    def __init__(self, params):\n" + textwrap.indent(loop, "        ")
        )
    options = WorkerOptions(timeout_s=0.2, echo=False)
    with pytest.raises(WorkerFault, match=f"{where} did not return within 0.5 s") as raised:
        factory = WorkerFactory(Target(str(module), None, "Slow"), options, "filter slow.py")
        try:
            factory(FilterParams())
        finally:
            factory.close()
    assert raised.value.kind == "timeout"
    assert np.isclose(worker.load_timeout(WorkerOptions(timeout_s=30.0)), 30.0)


def test_filter_timeout_nan_is_refused_and_inf_is_no_bound(tmp_path: Path) -> None:
    spec = f"{TEXTBOOK}:Textbook"
    result = _replay_with(tmp_path, spec, "--filter-timeout", "nan")
    assert result.returncode == 2
    one_error_line(result.stderr, "--filter-timeout nan: expected a number of seconds")
    result = _replay_with(tmp_path, spec, "--filter-timeout", "inf", "--filter-memory", "10" * 9)
    assert result.returncode == 0, result.stderr  # (select() overflowed; setrlimit too)
    assert result.stderr == ""


@pytest.mark.parametrize("program", ["cat", "yes"])
def test_an_interpreter_that_is_no_python_is_one_line_at_once(tmp_path: Path, program: str) -> None:
    """``yes`` answered four bytes read as a length of 2 GB, which ekfviz allocated
    and then failed on as JSON (a traceback)."""
    import shutil

    found = shutil.which(program)
    if found is None:
        pytest.skip(f"no {program} here")
    result = _replay_with(tmp_path, f"{TEXTBOOK}:Textbook", "--python", found)
    assert result.returncode == 2
    # (cat may first say that it has no file '{}', yes answers at once)
    one_error_line(result.stderr, "the filter's worker did not start")
