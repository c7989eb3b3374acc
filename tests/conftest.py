"""Shared fixtures: keep Rerun's analytics and config out of tests; read recordings back."""

from __future__ import annotations

import subprocess
import sys
import time
from collections import defaultdict
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import pytest
import typer
import typer.testing
from _pytest.mark import ParameterSet

# typer's test runner turns the app into click's commands at every invoke (some 40 ms for
# ekfviz's 13 commands and 270 options, a minute over the suite): built once per app and
# set of commands instead (the commands do not change once registered)
_CLICK_COMMANDS: dict[tuple[int, int, int], Any] = {}
_click_command_of = typer.testing._get_command


def _click_command(app: typer.Typer) -> Any:
    """click's command of ``app``, made once for each set of its registered commands."""
    key = (id(app), len(app.registered_commands), len(app.registered_groups))
    if key not in _CLICK_COMMANDS:
        _CLICK_COMMANDS[key] = _click_command_of(app)
    return _CLICK_COMMANDS[key]


typer.testing._get_command = _click_command


def rrd_verify(path: Path) -> None:
    """``rerun rrd verify`` finds nothing wrong with a recording (footer included)."""
    rerun = str(Path(sys.executable).with_name("rerun"))
    verify = subprocess.run(
        [rerun, "rrd", "verify", str(path)], capture_output=True, text=True, timeout=120
    )
    assert verify.returncode == 0, verify.stderr


def catches_signal(pid: int, signum: int) -> bool:
    """Whether a process has a handler for ``signum`` (Linux: SigCgt in /proc)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("SigCgt:"):
            return bool(int(line.split()[1], 16) >> (signum - 1) & 1)
    return False


@pytest.fixture(autouse=True, scope="session")
def _quiet_rerun(tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    """A throw-away config/data home, and no analytics, for this process and its children.

    Rerun 0.41 reads no opt-out variable (``RERUN_ANALYTICS`` does nothing); it skips
    analytics, its first-run banner and its analytics.json on CI, detected by ``CI``.
    """
    home = tmp_path_factory.mktemp("home")
    patch = pytest.MonkeyPatch()
    patch.setenv("XDG_CONFIG_HOME", str(home / "config"))
    patch.setenv("XDG_DATA_HOME", str(home / "data"))
    patch.setenv("CI", "1")
    yield
    patch.undo()


@pytest.fixture(scope="session")
def slow_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A log whose replay is still running seconds after its recording started: 5,000
    steps among 300 landmarks (about 3 s on a quiet machine; its map, not its length,
    makes it slow; the tests signal it once its recording holds its first events).

    A test that signals a replay must not race its end: a 12,000-step log of 40
    landmarks is replayed within 0.7 s of its recording's start now, and a signal that
    lands while the recording is finished is acted on after it (the recording is kept
    whole, replacing the file at its path)."""
    from typer.testing import CliRunner

    from ekfviz.cli import app

    folder = tmp_path_factory.mktemp("slow")
    log = folder / "slow.txt"
    result = CliRunner().invoke(
        app, ["simulate", "--scenario", "loop", "--steps", "5000", "--landmarks", "300",
              "-o", str(log), "--truth-out", str(folder / "slow.json")],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    return log


def recording_started(folder: Path, name: str, timeout: float = 60.0, *, holding: int = 0) -> None:
    """Wait until a run saving ``folder/name`` has opened its recording (its temporary
    file is there) and written more than ``holding`` bytes to it; a loaded machine takes
    seconds to import."""
    deadline = time.monotonic() + timeout
    while not recording_holds(folder, name, holding):
        assert time.monotonic() < deadline, f"no recording of {name} started in {timeout} s"
        time.sleep(0.02)


def recording_holds(folder: Path, name: str, size: int = 0) -> bool:
    """Whether the temporary file of a run saving ``folder/name`` holds more than
    ``size`` bytes."""
    for part in folder.glob(f".{name}.*.part"):
        try:
            if part.stat().st_size > size:
                return True
        except FileNotFoundError:  # renamed into place meanwhile
            continue
    return False


def entity_rows(path: Path, entity: str, *, static: bool = False) -> list[dict[str, object]]:
    """Every row logged to one entity of an .rrd, as {column name: value}, by event.

    Temporal rows carry their "event" and "step"; with ``static`` only static rows.
    """
    from rerun.chunk import RrdReader

    chunks = RrdReader(path).stream().filter(content=entity, is_static=static)
    return _rows([chunk for chunk in chunks if chunk.entity_path == entity], static)


def every_entity_rows(path: Path, *, static: bool = False) -> dict[str, list[dict[str, object]]]:
    """:func:`entity_rows` of every entity of an .rrd, the file read once."""
    from rerun.chunk import RrdReader

    chunks: dict[str, list[Any]] = defaultdict(list)
    for chunk in RrdReader(path).stream().filter(is_static=static):
        chunks[chunk.entity_path].append(chunk)
    return {entity: _rows(found, static) for entity, found in chunks.items()}


def _rows(chunks: list[Any], static: bool) -> list[dict[str, object]]:
    """The rows of ``chunks`` as {column name: value}; temporal ones by event."""
    rows: list[dict[str, object]] = []
    for chunk in chunks:
        batch = chunk.to_record_batch()
        table = {
            name: column.to_pylist()
            for name, column in zip(batch.schema.names, batch.columns, strict=True)
            if name != "rerun.controls.RowId" and not str(column.type).startswith("timestamp")
        }
        rows += [
            dict(zip(table, values, strict=True)) for values in zip(*table.values(), strict=True)
        ]
    return (
        rows
        if static
        else sorted(rows, key=lambda row: int(str(row.get("event", row.get("step")))))
    )


@pytest.fixture(params=[True, False], ids=["kernel", "numpy"])
def compiled(request: pytest.FixtureRequest) -> bool:
    """Both ways the filter runs: the compiled kernel of small maps, and the numpy code
    that stands in where it is not built."""
    return bool(request.param)


def few_by_default(cases: Iterable[Any], keep: int = 1, *, multi: bool = False) -> list[Any]:
    """Parametrize ``cases`` with the first ``keep`` run by ``make test`` and the rest marked
    slow (``make test-all`` runs them); ``multi``: each case is a tuple of several values."""
    found = []
    for k, case in enumerate(cases):
        if k < keep:
            found.append(case)
        elif isinstance(case, ParameterSet):
            found.append(
                pytest.param(*case.values, marks=[*case.marks, pytest.mark.slow], id=case.id)
            )
        else:
            values = tuple(case) if multi else (case,)
            found.append(pytest.param(*values, marks=pytest.mark.slow))
    return found
