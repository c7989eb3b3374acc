"""A recording's file: written beside its path and moved over it only once whole
(ekfviz.viz.recording)."""

from __future__ import annotations

from pathlib import Path

import pytest

SAMPLE = Path(__file__).parents[2] / "data" / "classic.txt"


def test_a_signal_in_the_final_flush_leaves_no_hidden_temporary_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """SIGINT while the recording's last chunks were flushed (its file about whole) left
    the hidden ``.RUN.rrd.<pid>.<hex>.part`` behind, for replay, sweep and compare: the
    exception left the clean-up before the temporary file was moved or removed. A file not
    known to be whole is dropped; the one at the path is left as it was."""
    from ekfviz import signals, viz
    from ekfviz.viz import recording as viz_recording

    target = tmp_path / "run.rrd"
    target.write_bytes(b"the previous recording")

    def interrupted_flush(rec: object, timeout: float) -> None:
        raise signals.Interrupted

    monkeypatch.setattr(viz_recording, "flush_interruptibly", interrupted_flush)
    info = viz.run_info("run", "", {}, SAMPLE)
    sinks = viz.Sinks(save=target)
    with pytest.raises(signals.Interrupted), viz.open_recording(info, sinks) as rec:
        rec.complete = True  # the run finished; the signal comes in the flush after it
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.rrd"]
    assert target.read_bytes() == b"the previous recording"
    assert rec.saved_to is None
