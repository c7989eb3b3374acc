"""What ``sweep`` and ``compare`` print: a study's notes, its table, the runs that used
their own R, those that stopped or failed, and where its recording is."""

from __future__ import annotations

from rich.text import Text

from ekfviz.app.study import StudyOutcome
from ekfviz.cli.console import err, note, out, plain, show


def print_study(outcome: StudyOutcome) -> None:
    """Print a study's outcome (see the module)."""
    for text in outcome.notes:
        note(text)
    show(outcome.table)
    if outcome.own_noise:
        out.print(
            Text(
                "* NIS derived with the filter's own R (measurement_noise): "
                + ", ".join(outcome.own_noise)
            )
        )
    for line in outcome.stopped:
        err.print(Text.assemble(("stopped: ", "bold red"), line))
    for line in outcome.failed:
        err.print(Text.assemble(("failed: ", "bold red"), line))
    out.print(plain(outcome.saved))
