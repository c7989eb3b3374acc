"""The extended log format: reading, writing, detection, and what the filter makes of it."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ekfviz.core.errors import InputError
from ekfviz.core.records import Control, EventKind, Scan, Sighting
from ekfviz.io.classic import format_classic
from ekfviz.io.extended import format_extended, is_extended, read_extended, read_log
from ekfviz.runner.replay import replay
from ekfviz.runner.run import every_event
from ekfviz.sim.scenarios import classic

LOG = """# a log
observe 17 0.1 5.0 4 -0.2 6.0
control 3.0 0.0
observe
1.5 control 3.0 0.1   # with a timestamp
2.0 observe 4 0.3 4.0 9 1.0 2.0
"""


def write(tmp_path: Path, content: str, name: str = "log.txt") -> Path:
    path = tmp_path / name
    path.write_text(content)
    return path


def test_reads_ids_subsets_empty_observations_and_timestamps(tmp_path: Path) -> None:
    events = list(read_extended(write(tmp_path, LOG)))
    assert [type(e).__name__ for e in events] == [
        "Sighting",
        "Control",
        "Sighting",
        "Control",
        "Sighting",
    ]
    first, empty, last = events[0], events[2], events[4]
    assert isinstance(first, Sighting) and isinstance(empty, Sighting)
    assert isinstance(last, Sighting)
    np.testing.assert_array_equal(first.ids, [17, 4])
    np.testing.assert_array_equal(first.z, [[0.1, 5.0], [-0.2, 6.0]])
    assert len(empty.ids) == 0 and empty.z.shape == (0, 2)
    assert [e.time for e in events] == [None, None, None, 1.5, 2.0]
    assert [e.line for e in events] == [2, 3, 4, 5, 6]


def test_detection_tells_the_formats_apart(tmp_path: Path) -> None:
    extended = write(tmp_path, LOG, "e.txt")
    classic = write(tmp_path, "0.1 5 0.2 6\n3 0\n", "c.txt")
    timed = write(tmp_path, "# t\n0.0 control 1 0\n", "t.txt")
    assert is_extended(extended) and is_extended(timed) and not is_extended(classic)
    assert isinstance(next(read_log(timed)), Control)
    assert isinstance(next(read_log(classic)), Sighting)


def test_writer_round_trips_both_formats(tmp_path: Path) -> None:
    events = classic().run(seed=2).events
    for text in (format_extended(events, precision=17), format_classic(events, precision=17)):
        read = list(read_log(write(tmp_path, text)))
        assert len(read) == len(events)
        for a, b in zip(read, events, strict=True):
            assert type(a) is type(b)
            if isinstance(a, Sighting) and isinstance(b, Sighting):
                np.testing.assert_array_equal(a.ids, b.ids)
                np.testing.assert_allclose(a.z, b.z, rtol=1e-15)


def test_filter_grows_on_sparse_ids_and_skips_empty_steps(tmp_path: Path) -> None:
    records = every_event(replay(read_extended(write(tmp_path, LOG))))
    assert [r.kind for r in records] == [
        EventKind.INIT,
        EventKind.PREDICT,
        EventKind.UPDATE,
        EventKind.PREDICT,
        EventKind.UPDATE,
    ]
    np.testing.assert_array_equal(records[-1].landmark_ids, [17, 4, 9])
    assert records[2].landmarks_xy.shape == (2, 2)
    assert records[-1].time == 2.0


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("contrl 1 0\n", "log.txt:1: found 'contrl', expected a keyword"),
        ("control 1\n", "log.txt:1: found 1 values after 'control', expected 2"),
        (
            "control 1 0\nobserve 1 0.1\n",
            "log.txt:2: found 2 values after 'observe', expected a multiple of 3",
        ),
        ("observe a 0.1 2\n", "found landmark id 'a', expected an integer >= 0"),
        ("observe -1 0.1 2\n", "found landmark id '-1', expected an integer >= 0"),
        ("observe 1 0.1 2 1 0.2 3\n", "found landmark 1 twice"),
        ("observe 1 0.1 0\n", "found range 0 for landmark 1, expected a positive range"),
        ("observe 1 0.1 nan\n", "found 'nan', expected a finite number"),
        ("2.0 control 1 0\n1.0 control 1 0\n", "log.txt:2: found time 1 after 2"),
        # a non-finite time is all letters: still a time where a keyword follows it
        ("control 1 0\nnan control 1 0\n", "log.txt:2: found 'nan', expected a finite number"),
        (
            "1.0 control 1 0\nInfinity observe 1 0.1 2\n",
            "log.txt:2: found 'Infinity', expected a finite number",
        ),
        ("control 1 0\n3.0\n", "log.txt:2: found only a timestamp"),
        (
            "observe 1 0.1 2\nobserve\nscan\nscan 0.1 2\n",
            "log.txt:4: found a scan after observations by landmark id (from line 1), expected"
            " observations of one kind in a log: by id ('observe') or id-less ('scan')",
        ),
        (
            "observe\nscan 0.1 2\ncontrol 1 0\nobserve 4 0.1 2\n",
            "log.txt:4: found an observation by landmark id after id-less scans (from line 2)",
        ),
    ],
)
def test_errors_name_the_line(tmp_path: Path, content: str, message: str) -> None:
    with pytest.raises(InputError) as caught:
        list(read_extended(write(tmp_path, content)))
    assert message in str(caught.value)


def test_noise_header_round_trips_and_replay_takes_it_unless_told(tmp_path: Path) -> None:
    import json

    from typer.testing import CliRunner

    from ekfviz.cli import app
    from ekfviz.io.extended import read_log_noise

    noise: dict[str, float | tuple[float, float, float]] = {
        "sigma_x": 0.0125,
        "sigma_alpha": 0.003,
        "init_pose_sigma": (0.01, 0.02, 0.005),
    }
    text = format_extended(list(read_extended(write(tmp_path, LOG))), None, noise=noise)
    log = write(tmp_path, text, "noisy.txt")
    assert read_log_noise(log) == noise
    assert read_log_noise(write(tmp_path, LOG)) == {}  # no header
    # a header after the first event is just a comment
    assert read_log_noise(write(tmp_path, "control 1 0\n# noise: sigma_x=1\n", "late.txt")) == {}

    runner = CliRunner()

    def parameters(*options: str) -> dict[str, object]:
        report = tmp_path / "report.json"
        done = runner.invoke(
            app, ["replay", str(log), "--save", str(tmp_path / "r.rrd"), "--report",
                  str(report), *options],
        )  # fmt: skip
        assert done.exit_code == 0, done.output
        assert "the noise its header states" in done.output
        params: dict[str, object] = json.loads(report.read_text())["parameters"]
        return params

    taken = parameters()
    assert (taken["sigma_x"], taken["sigma_alpha"]) == (0.0125, 0.003)
    assert taken["sigma_y"] == 0.1  # not stated: the classic default
    assert taken["init_pose_sigma"] == [0.01, 0.02, 0.005]
    told = parameters("--sigma-x", "0.5", "--init-pose-sigma", "0.1", "0.1", "0.1")
    assert (told["sigma_x"], told["sigma_alpha"]) == (0.5, 0.003)
    assert told["init_pose_sigma"] == [0.1, 0.1, 0.1]


@pytest.mark.parametrize(
    "header",
    ["# noise: sigma_x=abc", "# noise: sigma_q=1", "# noise: sigma_x=-1",
     "# noise: init_pose_sigma=1,2", "# noise: sigma_x"],
)  # fmt: skip
def test_a_bad_noise_header_is_one_line_naming_it(tmp_path: Path, header: str) -> None:
    from typer.testing import CliRunner

    from ekfviz.cli import app

    log = write(tmp_path, f"# an extended log\n{header}\n{LOG}", "bad.txt")
    done = CliRunner().invoke(app, ["replay", str(log), "--save", str(tmp_path / "r.rrd")])
    assert done.exit_code == 2
    lines = done.output.strip().splitlines()
    assert len(lines) == 1 and f"{log}:2:" in lines[0], done.output
    assert not (tmp_path / "r.rrd").exists()


# -- the reader's blocks read at once against line by line ---------------------------------

_TIME_BACK = "0.5 control 1 0"  # before the times of _odd_log
# lines that read, some as no writer of ours would write them, and lines that do not; in
# a log of observations by id, and in one of id-less scans
_ODD_BUT_READ = [
    "control 3e0 -.5", "control\t3.0\t0.0  ", "# a comment: é", "scan", "observe", "",
    "control 1E+2 0",
]  # fmt: skip
_ODD_BY_IDS = [
    "observe 007 0.1 5.0", "observe +5 0.1 5.0", "   observe 3 0.2 4.0   # seen",
    "observe 123456789012345678 0.1 2.0", "observe 2 4.0 1.0 3 -3.5 2.0",
    "observe 9007199254740993 0.1 2.0", "observe 4 1e-3 .5",
]  # fmt: skip
_ODD_SCANS = ["scan 3.2 1.0 -0.5 2.0", "  scan\t1e-3 .5 # seen", "scan -3.5 2 +1 1"]
_NOT_READ = [
    "control 3.0", "control nan 0", "control 1_0 0", "Control 3 0", "controls 3 0", "12.5",
    "1e10 control 1 0", "control 3.0 0.0 observe", "\xff control 1 0", _TIME_BACK,
]  # fmt: skip
_NOT_READ_BY_IDS = [
    "observe 5.0 0.1 5.0", "observe 1e1 0.1 5.0", "observe -1 0.1 5.0", "observe 3 0.1 0",
    "observe 3 0.1 -2", "observe 3 0.1 5.0 3 0.2 4.0", "observe 1 2", "observe 3 0.1 1e19",
    "scan 1.0 2.0",  # (a scan among observations by id)
]  # fmt: skip
_NOT_READ_SCANS = ["scan 1.0", "scan 1 -1", "scan 1 nan", "observe 3 0.1 2.0"]


def _odd_log(
    rng: np.random.Generator, lines: int, bad: str | None, timed: bool, scans: bool
) -> bytes:
    """A log of plain lines with odd ones among them, and ``bad`` somewhere after the
    first few blocks; with timestamps (at some lines) where ``timed``, its observations
    id-less scans where ``scans``."""
    odd = _ODD_BUT_READ + (_ODD_SCANS if scans else _ODD_BY_IDS)
    out: list[str] = []
    time = 1.0
    for _ in range(lines):
        pick = rng.uniform()
        if pick < 0.1:
            line = str(rng.choice(odd))
        elif pick < 0.55:
            line = f"control {rng.normal():.4f} {rng.normal(0, 0.1):.5f}"
        else:
            seen = int(rng.integers(0, 6))
            cells = [f"{rng.uniform(-3.3, 3.3):.4f} {rng.uniform(0.1, 9):.3f}" for _ in range(seen)]
            if scans:
                line = " ".join(["scan", *cells])
            else:
                ids = rng.choice(40, size=seen, replace=False)
                line = " ".join(
                    ["observe"] + [f"{i} {cell}" for i, cell in zip(ids, cells, strict=True)]
                )
        if timed and rng.uniform() < 0.7 and line.strip() and not line.lstrip().startswith("#"):
            time += float(rng.uniform(0.0, 0.3))
            line = f"{time:.3f} {line.lstrip()}"
        out.append(line)
    if bad is not None:
        out[int(rng.integers(lines // 2, lines))] = bad
    text = "\n".join(out) + "\n"
    return text.encode("utf-8", errors="surrogateescape").replace(b"\xc3\xbf", b"\xff")


def _read(
    path: Path, whole: bool, monkeypatch: pytest.MonkeyPatch
) -> tuple[list[tuple[object, ...]], str | None, list[str]]:
    """The events of ``path`` (blocks read at once where ``whole``, else line by line),
    the error that ended them and the warnings, as comparable values."""
    from ekfviz.io import extended

    warnings: list[str] = []
    events: list[tuple[object, ...]] = []
    with monkeypatch.context() as patch:
        if not whole:
            patch.setattr(extended, "_plain_events", lambda *_: None)
        try:
            for event in read_extended(path, warn=warnings.append):
                if isinstance(event, Control):
                    events.append(("control", event.line, event.d, event.alpha, event.time,
                                   event.dt))  # fmt: skip
                elif isinstance(event, Sighting):
                    assert event.ids.dtype == np.int64 and event.z.shape == (len(event.ids), 2)
                    events.append(("observe", event.line, event.ids.tolist(), event.z.tolist(),
                                   event.time))  # fmt: skip
                else:
                    assert isinstance(event, Scan)
                    events.append(("scan", event.line, event.z.shape, event.z.tolist(),
                                   event.time))  # fmt: skip
        except InputError as error:
            return events, str(error), warnings
    return events, None, warnings


def _blocks_read_at_once(monkeypatch: pytest.MonkeyPatch) -> list[bool]:
    """Whether each block the reader meets from now on is read at once (plain), in order."""
    from ekfviz.io import extended

    read_at_once: list[bool] = []
    plain = extended._plain_events

    def counted(*args: Any) -> Any:
        made = plain(*args)
        read_at_once.append(made is not None)
        return made

    monkeypatch.setattr(extended, "_plain_events", counted)
    return read_at_once


# seeds 0, 1, 2 and 5 are the four kinds (timed or not, scans or observations by id)
_SEEDS = [
    *(pytest.param(seed) for seed in (0, 1, 2, 5)),
    *(pytest.param(seed, marks=pytest.mark.slow) for seed in (3, 4, *range(6, 12))),
]


@pytest.mark.parametrize("seed", _SEEDS)
def test_blocks_read_at_once_read_as_line_by_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, seed: int
) -> None:
    """A block of plain lines is converted at once, any other read line by line; the
    events, the first error (its line and words) and the warnings are the same as line
    by line throughout, in blocks of every kind: odd lines that read (ids with leading
    zeros or a sign, exponents, tabs, comments, empty steps and scans, ids past 2^53),
    lines that do not, timestamps (a control spans the time since the last), logs of
    id-less scans, a scan among observations by id and the other way round."""
    from ekfviz.io import text as text_io

    monkeypatch.setattr(text_io, "BLOCK_BYTES", 600)  # some 20 lines a block
    read_at_once = _blocks_read_at_once(monkeypatch)
    rng = np.random.default_rng(seed)
    timed, scans = seed % 2 == 1, seed % 3 == 2
    for case in range(6):
        bad = (
            None
            if case == 0
            else str(rng.choice(_NOT_READ + (_NOT_READ_SCANS if scans else _NOT_READ_BY_IDS)))
        )
        path = tmp_path / f"log{case}.txt"
        path.write_bytes(_odd_log(rng, 400, bad, timed, scans))
        at_once = _read(path, True, monkeypatch)
        assert at_once == _read(path, False, monkeypatch), (seed, case, bad)
        assert len(at_once[0]) > 150
        # (a time before the last is no fault in a log without times)
        assert (at_once[1] is None) == (bad is None or (bad == _TIME_BACK and not timed))
    assert read_at_once.count(True) > 30 and read_at_once.count(False) > 10


def test_a_long_plain_log_is_read_in_blocks(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The lines of a simulated run's log are plain: every block is read at once."""
    from ekfviz.io import text as text_io

    monkeypatch.setattr(text_io, "BLOCK_BYTES", 4096)
    path = write(tmp_path, format_extended(classic().run(seed=3, laps=40).events))
    read_at_once = _blocks_read_at_once(monkeypatch)
    assert _read(path, True, monkeypatch) == _read(path, False, monkeypatch)
    assert len(read_at_once) > 3 and all(read_at_once)


_MUTATION_BYTES = b"0123456789+-.eE \t\n#xa\xc3\xff\x0b\r"
_MUTATION_WORDS = [
    b"control ", b"observe ", b"scan ", b"12.5 ", b"0.5 ", b"nan ", b"1e400 ", b"-", b"-0 ", b"0 ",
    b"5.0 ", b"+3 ", b"7 ", b"\r\n", b"\n",
]  # fmt: skip


_MUTATIONS = {
    "scans": st.booleans(),
    "timed": st.booleans(),
    "edits": st.lists(
        st.tuples(st.integers(0, 4), st.floats(0, 1), st.integers(0, 255)), min_size=1, max_size=8
    ),
}
_MUTATED = settings(
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
    derandomize=True,  # the same examples on every run: a failure is reproducible
)


@settings(_MUTATED, max_examples=150)
@given(**_MUTATIONS)
def test_mutated_logs_read_at_once_as_line_by_line(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    scans: bool,
    timed: bool,
    edits: list[tuple[int, float, int]],
) -> None:
    """See :func:`_mutated_log_reads_at_once_as_line_by_line`."""
    _mutated_log_reads_at_once_as_line_by_line(tmp_path, monkeypatch, scans, timed, edits)


@pytest.mark.slow
@settings(_MUTATED, max_examples=1000)
@given(**_MUTATIONS)
def test_many_mutated_logs_read_at_once_as_line_by_line(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    scans: bool,
    timed: bool,
    edits: list[tuple[int, float, int]],
) -> None:
    """See :func:`_mutated_log_reads_at_once_as_line_by_line`."""
    _mutated_log_reads_at_once_as_line_by_line(tmp_path, monkeypatch, scans, timed, edits)


def _mutated_log_reads_at_once_as_line_by_line(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    scans: bool,
    timed: bool,
    edits: list[tuple[int, float, int]],
) -> None:
    """A plain log with bytes replaced, dropped or put in (digits, signs, separators,
    comments, keywords, a CR, bytes that are not UTF-8), and words put in or put for a
    token (times, ids, numbers of all forms), reads the same at once as line by line: the
    same events, first error and warnings."""
    from ekfviz.io import text as text_io

    monkeypatch.setattr(text_io, "BLOCK_BYTES", 97)
    rng = np.random.default_rng(11)
    data = bytearray(_odd_log(rng, 60, None, timed=timed, scans=scans))
    for op, where, pick in edits:
        at = int(where * len(data))
        if op >= 3:  # at the start of a token
            at = data.find(b" ", at) + 1
        if op == 0:
            data[at : at + 1] = _MUTATION_BYTES[pick % len(_MUTATION_BYTES) :][:1]
        elif op == 1:
            del data[at : at + 1 + pick % 3]
        elif op == 2:
            data[at:at] = _MUTATION_BYTES[pick % len(_MUTATION_BYTES) :][:1]
        elif op == 3:  # a word put in
            data[at:at] = _MUTATION_WORDS[pick % len(_MUTATION_WORDS)]
        else:  # the token replaced by a word
            end = min(i for i in (data.find(b" ", at), data.find(b"\n", at), len(data)) if i >= 0)
            data[at:end] = _MUTATION_WORDS[pick % len(_MUTATION_WORDS)].rstrip(b" ")
    path = tmp_path / "mutated.txt"
    path.write_bytes(bytes(data))
    assert _read(path, True, monkeypatch) == _read(path, False, monkeypatch)
