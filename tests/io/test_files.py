"""Every file ekfviz writes (ekfviz.io.files): whole or not at all, together or none, a
recording's commit, and what cannot be written said as an OutputError."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from ekfviz.core.errors import OutputError
from ekfviz.io.files import (
    OutputPathError,
    check_outputs,
    commit_recording,
    json_text,
    partial_path,
    refuse_overwrite,
    remove_stale_parts,
    temporary_beside,
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
