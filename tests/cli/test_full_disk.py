"""A disk that fills up (or a file-size limit) while a file is written: the file is written
whole or not at all, nothing at its path is replaced, a flush stops at once.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from commands import one_error_line

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "data"


def _limited(size: int) -> None:  # (in the child, before exec)
    import resource
    import signal

    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # writes past the limit fail (EFBIG)
    resource.setrlimit(resource.RLIMIT_FSIZE, (size, size))


def test_a_recording_that_cannot_be_written_whole_replaces_nothing(tmp_path: Path) -> None:
    """Rerun's file writer stops; its flush raised, which was taken for a viewer that did
    not answer: the truncated file then replaced the finished one at --save."""
    target = tmp_path / "run.rrd"
    target.write_bytes(b"an earlier finished recording")
    command = [sys.executable, "-m", "ekfviz", "replay", str(DATA / "classic.txt")]
    result = subprocess.run(
        [*command, "--save", str(target)], capture_output=True, text=True, timeout=60,
        preexec_fn=lambda: _limited(100_000),
    )  # fmt: skip
    assert result.returncode == 2
    one_error_line(result.stderr, f"--save {target}: the recording could not be written whole")
    assert target.read_bytes() == b"an earlier finished recording"
    assert [p.name for p in tmp_path.iterdir()] == ["run.rrd"]  # no temporary file left


def test_a_full_disk_stops_a_flush_at_once(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A flush whose file's disk is full stops waiting (Rerun's would wait out its timeout
    for a writer that has stopped)."""
    import threading

    from ekfviz.viz import flush

    class Stuck:
        def flush(self, timeout_sec: float) -> None:
            threading.Event().wait(timeout_sec)

    stuck = Stuck()
    monkeypatch.setattr(flush, "_FILES", {stuck: tmp_path / "x.rrd"})
    monkeypatch.setattr(flush, "disk_full", lambda path: True)
    with pytest.raises(flush.DiskFull, match="no space left"):
        flush.flush_interruptibly(stuck, 30.0)  # type: ignore[arg-type]


def test_a_writer_is_taken_for_stopped_only_where_it_was_seen_running(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A flush stops at once when the stream's file writer, seen running, is gone; where
    it was never seen (another version of Rerun naming its thread otherwise) its absence
    says nothing, and the flush waits as Rerun's does."""
    import threading
    import weakref

    from ekfviz.viz import flush

    class Stuck:
        def flush(self, timeout_sec: float) -> None:
            threading.Event().wait(timeout_sec)

    stuck = Stuck()
    monkeypatch.setattr(flush, "_FILES", {stuck: tmp_path / "x.rrd"})
    monkeypatch.setattr(flush, "_WRITERS", weakref.WeakSet())
    monkeypatch.setattr(flush, "disk_full", lambda path: False)
    monkeypatch.setattr(flush, "writer_running", lambda: False)
    flush.note_writer(stuck)  # type: ignore[arg-type]  # not running: not seen
    flush.flush_interruptibly(stuck, 0.8)  # type: ignore[arg-type]  # waited out, no error
    monkeypatch.setattr(flush, "writer_running", lambda: True)
    flush.note_writer(stuck)  # type: ignore[arg-type]
    monkeypatch.setattr(flush, "writer_running", lambda: False)
    with pytest.raises(flush.DiskFull, match="file writer stopped"):
        flush.flush_interruptibly(stuck, 30.0)  # type: ignore[arg-type]


def test_a_file_written_whole_or_not_at_all_on_a_full_disk(tmp_path: Path) -> None:
    """convert, --report, export: their files are written beside and renamed; a write
    that fails (here past a file-size limit) was a traceback."""
    target = tmp_path / "ext.txt"
    target.write_text("an earlier file\n")
    result = subprocess.run(
        [sys.executable, "-m", "ekfviz", "convert", str(DATA / "classic.txt"), str(target),
         "--force"],
        capture_output=True, text=True, timeout=60, preexec_fn=lambda: _limited(1_000),
    )  # fmt: skip
    assert result.returncode == 2
    one_error_line(result.stderr, f"{target}: cannot write (File too large); nothing was replaced")
    assert target.read_text() == "an earlier file\n"
    assert [p.name for p in tmp_path.iterdir()] == ["ext.txt"]
