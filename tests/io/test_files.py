"""Every file ekfviz writes (ekfviz.io.files): whole or not at all, together or none, a
recording's commit, and what cannot be written said as an OutputError."""

from __future__ import annotations

import json
import math
import os
import signal
from pathlib import Path

import pytest

from ekfviz.core.errors import OutputError
from ekfviz.io.files import (
    OutputPathError,
    check_output_path,
    check_outputs,
    commit_recording,
    json_text,
    partial_path,
    refuse_overwrite,
    remove_stale_parts,
    temporary_beside,
    unused_path,
    write_files_atomic,
)


def test_files_that_cannot_all_be_written_replace_none(tmp_path: Path) -> None:
    kept = tmp_path / "kept.csv"
    kept.write_text("OLD")
    with pytest.raises(OutputError, match=r"missing/x\.tum: cannot write .*nothing was replaced"):
        write_files_atomic({kept: b"NEW", tmp_path / "missing" / "x.tum": b"NEW"})
    assert kept.read_text() == "OLD"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["kept.csv"]  # no temporary left


def test_a_link_is_written_through_and_kept(tmp_path: Path) -> None:
    target = tmp_path / "target.json"
    target.write_text("{}")
    link = tmp_path / "link.json"
    link.symlink_to(target)
    write_files_atomic({link: json_text({"x": math.nan}).encode()})
    assert link.is_symlink() and json.loads(target.read_text()) == {"x": None}


def test_output_paths_are_refused_as_output_errors(tmp_path: Path) -> None:
    existing = tmp_path / "report.json"
    existing.write_text("{}")
    with pytest.raises(OutputPathError, match="is a folder") as folder:
        check_outputs(("--report", tmp_path))
    assert isinstance(folder.value, OutputError)
    with pytest.raises(OutputPathError, match="are the same file"):
        check_outputs(("--save", existing), ("--report", existing))
    with pytest.raises(OutputPathError, match="add --force"):
        refuse_overwrite(False, ("--output", existing))
    refuse_overwrite(True, ("--output", existing))


@pytest.mark.parametrize("partial", [False, True])
def test_a_recording_is_committed_whole_and_a_partial_one_beside_an_existing_file(
    tmp_path: Path, partial: bool
) -> None:
    target = tmp_path / "run.rrd"
    target.write_bytes(b"earlier")
    temporary = temporary_beside(target)
    temporary.write_bytes(b"new")
    saved = commit_recording(temporary, target, target, complete=True, partial=partial)
    if partial:  # a run cut short never replaces a file
        assert saved == partial_path(target) == tmp_path / "run.partial.rrd"
        assert target.read_bytes() == b"earlier" and saved.read_bytes() == b"new"
    else:
        assert saved == target and target.read_bytes() == b"new"
    assert not temporary.exists()


def test_an_incomplete_recording_is_dropped_and_a_dead_runs_parts_removed(tmp_path: Path) -> None:
    target = tmp_path / "run.rrd"
    temporary = temporary_beside(target)
    temporary.write_bytes(b"half")
    assert commit_recording(temporary, target, target, complete=False, partial=False) is None
    assert list(tmp_path.iterdir()) == []
    dead = tmp_path / ".run.rrd.999999999.0badcafe.part"  # no such process
    dead.write_bytes(b"left by a run killed outright")
    mine = temporary_beside(target)  # removes the dead run's first
    mine.write_bytes(b"being written")
    assert not dead.exists() and remove_stale_parts(target) == [] and mine.exists()


def test_check_output_path_accepts_a_new_or_existing_file_and_creates_nothing(
    tmp_path: Path,
) -> None:
    (tmp_path / "old.rrd").write_text("x")
    assert check_output_path(tmp_path / "new.rrd", "--save") == tmp_path / "new.rrd"
    assert check_output_path(tmp_path / "old.rrd", "--save") == tmp_path / "old.rrd"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["old.rrd"]
    with pytest.raises(
        OutputPathError, match=r"^--report .*r.json: the folder .*missing does not exist$"
    ):
        check_output_path(tmp_path / "missing" / "r.json", "--report")
    assert not (tmp_path / "missing").exists()


def test_a_default_name_never_replaces_an_earlier_file(tmp_path: Path) -> None:
    first = tmp_path / "run.rrd"
    assert unused_path(first) == first
    first.write_text("x")
    (tmp_path / "run-2.rrd").write_text("x")
    assert unused_path(first) == tmp_path / "run-3.rrd"


def test_files_written_together_are_all_replaced_or_none_whatever_the_signal(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``export`` wrote its files one after another: a SIGINT among them left the new
    TUM beside the old CSV, and said "nothing was written". Now a signal among the renames
    waits for the last, and the line says what was written."""
    from ekfviz import signals

    first, second = tmp_path / "e.tum", tmp_path / "p.csv"
    first.write_text("OLD")
    second.write_text("OLD")
    replace = os.replace

    def replace_then_signal(source: str, target: Path) -> None:
        replace(source, target)
        if Path(target) == first:
            os.kill(os.getpid(), signal.SIGINT)  # after the first rename, before the second

    before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    monkeypatch.setattr(os, "replace", replace_then_signal)
    try:
        signals.as_interrupts()
        with pytest.raises(signals.Interrupted) as stopped:
            write_files_atomic({first: b"NEW", second: b"NEW"})
    finally:
        signal.signal(signal.SIGINT, before[0])
        signal.signal(signal.SIGTERM, before[1])
    assert (first.read_text(), second.read_text()) == ("NEW", "NEW")
    assert stopped.value.written == (first, second)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["e.tum", "p.csv"]
