"""The layering of the package: the numpy-only core never loads rerun or typer."""

from __future__ import annotations

import subprocess
import sys


def test_core_io_and_sim_do_not_import_rerun_or_typer() -> None:
    code = (
        "import sys\n"
        "import ekfviz.core.filter, ekfviz.core.replay, ekfviz.core.evaluation\n"
        "import ekfviz.io.classic, ekfviz.io.truth, ekfviz.sim.sample\n"
        "bad = sorted(m for m in sys.modules if m.split('.')[0] in {'rerun', 'typer', 'rich'})\n"
        "print(','.join(bad))\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    )
    assert result.stdout.strip() == ""


def test_the_logging_layer_does_load_rerun() -> None:
    """The check above can fail: importing the logging layer does bring rerun in."""
    code = "import sys, ekfviz.viz; print('rerun' in sys.modules)"
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    )
    assert result.stdout.strip() == "True"


def test_bundled_sample_is_what_the_generator_writes() -> None:
    from pathlib import Path

    from ekfviz.sim.sample import sample_files

    data = Path(__file__).parents[1] / "data"
    for name, content in sample_files().items():
        assert (data / name).read_text(encoding="utf-8") == content, "regenerate with make sample"
