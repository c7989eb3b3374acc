"""A class's grades: one row a submission, as a table, a CSV file and a JSON document.

Every text of a row that came from a submission (its name, a message, a hint quoting its
numbers) is escaped (:func:`~ekfviz.sandbox.text.printable`): one line, no control
character, no bidirectional override. A CSV cell that a spreadsheet would run is
neutralised (:func:`~ekfviz.sandbox.text.spreadsheet_cell`). Rows cross from the process
that graded them as JSON text, parsed and checked here (:meth:`GradeRow.from_json`),
never as pickled objects. Numpy only.
"""

from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import dataclass
from typing import Any

from ekfviz.core.tables import Styled, TextTable
from ekfviz.sandbox.text import printable, spreadsheet_cell

NOT_GRADED = "not graded"
# match and diverged: the filter ran; error, timeout, memory, crashed: the submission's
# doing; grader_error: ekfviz's own machinery failed (a worker that could not start, a
# grading process that died); not graded: a grade stopped (SIGINT, SIGTERM) before it
STATUSES = ("match", "diverged", "error", "timeout", "memory", "crashed", "grader_error",
            NOT_GRADED)  # fmt: skip
# what of the first divergence a row carries (``Divergence.to_json``'s, where it has them)
DIAGNOSIS = ("cause", "sentence", "hint", "operation", "mutation", "source_line", "numbers")
CSV_COLUMNS = ("submission", "status", "causes", "first_divergence", "seconds", "detail",
               *DIAGNOSIS, "sandbox", "complete")  # fmt: skip
MAX_TEXT = 2000  # characters of one field a row keeps


def shown(value: object) -> str:
    """A field of a row as text: escaped, on one line, at most :data:`MAX_TEXT` long."""
    text = value if isinstance(value, str) else json.dumps(value, default=str)
    text = printable(text)
    return text if len(text) <= MAX_TEXT else text[:MAX_TEXT] + " ..."


@dataclass(frozen=True, slots=True)
class GradeRow:
    """One submission's result.

    :param first: the first divergence, ``LOG:LINE event E (kind): quantity``
    :param causes: the mistakes found, ``unknown`` last where some divergence is of no
        known cause (a correct course module's row is ``independent_landmark_init`` alone:
        the handout's block-diagonal P)
    :param detail: why it failed, for ``error``, ``timeout``, ``memory``, ``crashed``,
        ``grader_error``; for ``diverged``, how many divergent events no known mistake
        reproduces and the first
    :param diagnosis: the first divergence's cause, sentence, hint (and what else the
        check says of it, :data:`DIAGNOSIS`), as (field, text)
    """

    submission: str
    status: str
    causes: tuple[str, ...]
    first: str
    seconds: float
    detail: str = ""
    module: str = ""
    diagnosis: tuple[tuple[str, str], ...] = ()

    def __post_init__(self) -> None:
        for name in ("submission", "first", "detail", "module"):
            object.__setattr__(self, name, shown(getattr(self, name)))
        object.__setattr__(self, "causes", tuple(shown(c) for c in self.causes))
        kept = tuple((k, shown(v)) for k, v in self.diagnosis if k in DIAGNOSIS)
        object.__setattr__(self, "diagnosis", kept)
        if self.status not in STATUSES:
            raise ValueError(f"not a status: {self.status!r}")

    def cells(self) -> tuple[Styled, ...]:
        """The row in the table of grades (no markup read in a submission's name)."""
        # a failure's reason before its first divergence, which says less
        failed = self.status not in ("match", "diverged") and self.detail
        said = self.detail if failed else "; ".join(t for t in (self.first, self.detail) if t)
        texts = (self.submission, self.status, ", ".join(self.causes), said,
                 f"{self.seconds:.1f}")  # fmt: skip
        return tuple(Styled(text) for text in texts)

    def to_json(self) -> dict[str, object]:
        return {
            "submission": self.submission,
            "status": self.status,
            "causes": list(self.causes),
            "first_divergence": self.first,
            "seconds": round(self.seconds, 3),
            "detail": self.detail,
            "module": self.module,
            "diagnosis": dict(self.diagnosis),
        }

    @classmethod
    def from_json(cls, text: str) -> GradeRow:
        """A row from :meth:`to_json`'s JSON text, every field checked.

        :raises ValueError: not a row
        """
        found: Any = json.loads(text)
        if not isinstance(found, dict):
            raise ValueError("a row is a JSON object")
        causes, diagnosis = found.get("causes"), found.get("diagnosis")
        seconds = found.get("seconds")
        if not isinstance(causes, list) or not isinstance(diagnosis, dict):
            raise ValueError("a row's causes are a list, its diagnosis an object")
        if not isinstance(seconds, int | float) or not math.isfinite(seconds):
            raise ValueError("a row's seconds are a number")
        texts = [found.get(k) for k in ("submission", "status", "first_divergence", "detail",
                                        "module")]  # fmt: skip
        if not all(isinstance(t, str) for t in texts):
            raise ValueError("a row's fields are text")
        submission, status, first, detail, module = (str(t) for t in texts)
        said = tuple((str(k), shown(v)) for k, v in diagnosis.items())
        return cls(submission, status, tuple(str(c) for c in causes), first, float(seconds),
                   detail, module, said)  # fmt: skip

    def csv_cells(self, sandbox: str, complete: bool) -> list[str]:
        """The row as CSV cells, none a spreadsheet formula."""
        diagnosis = dict(self.diagnosis)
        cells = [self.submission, self.status, ";".join(self.causes), self.first,
                 f"{self.seconds:.3f}", self.detail, *(diagnosis.get(k, "") for k in DIAGNOSIS),
                 sandbox, "yes" if complete else "no"]  # fmt: skip
        return [spreadsheet_cell(cell) for cell in cells]


def not_graded(name: str) -> GradeRow:
    """The row of a submission a stopped grade never checked."""
    return GradeRow(name, NOT_GRADED, (), "", 0.0, "the grade was stopped before it")


def grades_table(rows: list[GradeRow]) -> TextTable:
    """The table of grades, a row a submission."""
    columns = ("submission", "status", "causes", "first divergence", "s")
    left = frozenset(columns) - {"s"}
    return TextTable("grades", columns, tuple(row.cells() for row in rows), left=left)


def to_csv(rows: list[GradeRow], sandbox: str = "", complete: bool = True) -> str:
    """The grades as CSV: a row a submission; ``sandbox`` (how submissions ran) and
    ``complete`` (``no``: a grade stopped before its end) on every row."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(CSV_COLUMNS)
    for row in rows:
        writer.writerow(row.csv_cells(printable(sandbox), complete))
    return buffer.getvalue()


def to_document(rows: list[GradeRow], sandbox: str, stopped_by: str | None) -> dict[str, object]:
    """The grades as a JSON document: how submissions ran, whether the grade is partial
    (``stopped_by``: the signal that stopped it), a row a submission."""
    return {
        "sandbox": sandbox,
        "partial": stopped_by is not None,
        "stopped_by": stopped_by,
        "submissions": [row.to_json() for row in rows],
    }


def counts(rows: list[GradeRow]) -> dict[str, int]:
    """How many rows of each status, in the order first met."""
    found: dict[str, int] = {}
    for row in rows:
        found[row.status] = found.get(row.status, 0) + 1
    return found
