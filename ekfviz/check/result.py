"""What a lockstep check finds: every divergent event with its cause, and the verdict on a
log as the console and the report say it (see :mod:`ekfviz.check.lockstep`)."""

from __future__ import annotations

import enum
from dataclasses import dataclass

from ekfviz.check.hints import HANDOUT_NOTE, Named
from ekfviz.check.mistakes import UNKNOWN
from ekfviz.check.mutations import MUTATION
from ekfviz.check.unknown import Unexplained
from ekfviz.core.batch import EventBatch
from ekfviz.core.records import EventKind
from ekfviz.core.tables import Cell, Styled, TextTable


class Quantity(str, enum.Enum):
    """The part of the state a difference is in."""

    LANDMARK_IDS = "landmark ids"
    POSE_MEAN = "pose mean"
    POSE_COVARIANCE = "pose covariance"
    POSE_LANDMARK = "pose-landmark cross-covariance"
    LANDMARK_MEAN = "landmark mean"
    LANDMARK_COVARIANCE = "landmark covariance"
    LANDMARK_LANDMARK = "landmark-landmark cross-covariance"
    DECLARED_NOISE = "declared noise"


@dataclass(frozen=True, slots=True)
class Difference:
    """The worst entry of one comparison.

    :param entry: which entry, e.g. ``P[x, theta]`` or ``x[L3.y]``
    :param difference: |got - expected| / max(1, |expected|)
    """

    quantity: Quantity
    landmark_id: int | None
    entry: str
    expected: float
    got: float
    difference: float


@dataclass(frozen=True, slots=True)
class Divergence:
    """One event where the filter leaves the reference, and its cause.

    :param worst: the worst entry of the event's comparison
    :param causes: the catalogue's ids that reproduce the event (empty: not found, or
        not looked for)
    :param alternatives: other sets of causes that reproduce it equally (the log cannot
        tell them apart; ``causes`` is then not named)
    :param named: each cause with its sentence, fix and the line of the submitted file
        that computes its operation
    :param unexplained: where nothing reproduces it: the first operation whose value
        differs, and its numbers
    :param inherited: the state before it was already invalid: its causes are the
        earlier events' mistakes
    """

    event: int
    step: int
    line: int
    kind: EventKind
    worst: Difference
    hint: str
    causes: tuple[str, ...] = ()
    alternatives: tuple[tuple[str, ...], ...] = ()
    named: tuple[Named, ...] = ()
    unexplained: Unexplained | None = None
    inherited: bool = False

    @property
    def cause(self) -> str:
        """The cause as one id (``a+b`` for two combined), or ``unknown``."""
        return "+".join(self.causes) if self.causes and not self.alternatives else UNKNOWN

    def to_json(self) -> dict[str, object]:
        worst = self.worst
        first = self.named[0] if self.named and not self.alternatives else None
        operation = first.operation if first else (
            self.unexplained.operation if self.unexplained else None)  # fmt: skip
        return {
            "event": self.event,
            "step": self.step,
            "line": self.line,
            "kind": self.kind.value,
            "quantity": worst.quantity.value,
            "landmark_id": worst.landmark_id,
            "entry": worst.entry,
            "expected": worst.expected,
            "got": worst.got,
            "difference": worst.difference,
            "cause": self.cause,
            "sentence": " AND ".join(n.sentence for n in self.named) if first else None,
            "hint": self.hint,
            "operation": operation,
            "mutation": first.mutation if first else None,
            "source": first.source.to_json() if first and first.source else None,
            "causes": [n.to_json() for n in self.named] if first else [],
            "alternatives": [list(option) for option in self.alternatives],
            "inherited": self.inherited,
            "unknown": self.unexplained.to_json() if self.unexplained and not first else None,
        }


@dataclass(frozen=True, slots=True)
class DivergenceGroup:
    """Divergent events of one kind, quantity and cause: how many, and the first."""

    kind: str
    quantity: str
    cause: str
    count: int
    first: Divergence

    def to_json(self) -> dict[str, object]:
        first = self.first.to_json()
        return {
            "kind": self.kind,
            "quantity": self.quantity,
            "count": self.count,
            "first_event": self.first.event,
            "first_step": self.first.step,
            "first_line": self.first.line,
            "cause": self.cause,
            "hint": self.first.hint,
            "operation": first["operation"],
            "mutation": first["mutation"],
            "source": first["source"],
            "unknown": first["unknown"],
        }


@dataclass(frozen=True, slots=True)
class CheckResult:
    """What a lockstep check found.

    :param records: the checked filter's record of every event it ran
    :param reference: the reference's record of the same events (each from the
        filter's state before the event)
    :param differences: the largest scaled difference at every event, in order
    :param divergences: every divergent event, in order; causes looked for in all of
        them (``every``) or in the first only
    :param every: whether causes were looked for at every divergent event (``--all``)
    :param error: why the filter stopped early (it raised, crashed, timed out), if it did
    :param error_line: the input line of that event
    :param error_kind: as :class:`~ekfviz.sandbox.host.WorkerFault`'s kind
    :param next_divergence: without ``every``, when the first divergence's causes are
        named: the first later divergence not explained by them alone (a course module's
        first divergence is the handout's block-diagonal P; the student's own mistake
        comes after it)
    :param precision: ``float32`` where every number of the filter's state is one (its
        tolerance then :data:`FLOAT32_TOLERANCE`), else ``float64``
    :param within_precision: the largest difference, past the tolerance asked for, that
        the filter's own precision accounts for (0: none)
    :param notes: what the check says beside the verdict (the noise the filter declares)
    :param skipped: why the filter was not run on the log (a course module and a log of
        landmarks first seen after its first line), if it was not
    """

    events_checked: int
    max_difference: float
    tolerance: float
    first_divergence: Divergence | None
    records: EventBatch
    reference: EventBatch
    differences: tuple[float, ...]
    divergences: tuple[Divergence, ...] = ()
    every: bool = False
    error: str | None = None
    error_line: int = 0
    error_kind: str = ""
    error_traceback: str = ""  # the filter's own, from its worker (shown with --debug)
    # a course module's shapes as detected (argument -> "column" or "flat")
    convention: dict[str, str | None] | None = None
    next_divergence: Divergence | None = None
    precision: str = "float64"
    within_precision: float = 0.0
    notes: tuple[str, ...] = ()
    skipped: str = ""

    @property
    def match(self) -> bool:
        return self.first_divergence is None and self.error is None

    @property
    def groups(self) -> list[DivergenceGroup]:
        """The divergences grouped by kind, quantity and cause, in order of first event."""
        groups: dict[tuple[str, str, str], list[Divergence]] = {}
        for divergence in self.divergences:
            shown = (self.first_divergence, self.next_divergence)
            if not self.every and not any(divergence is d for d in shown):
                continue
            key = (divergence.kind.value, divergence.worst.quantity.value, divergence.cause)
            groups.setdefault(key, []).append(divergence)
        return [
            DivergenceGroup(kind, quantity, cause, len(found), found[0])
            for (kind, quantity, cause), found in groups.items()
        ]

    @property
    def causes(self) -> list[str]:
        """The distinct causes named, in the order first found."""
        seen: dict[str, None] = {}
        for divergence in self.divergences:
            if divergence.cause != UNKNOWN:
                for cause in divergence.causes:
                    seen.setdefault(cause, None)
        return list(seen)

    def verdict_lines(self, name: str, every: bool) -> list[Cell]:
        """The verdict on the log called ``name``: the shapes of a course module, the match
        or the first divergence with its cause and hint, how many more diverge."""
        lines: list[Cell] = []
        tolerance = self.tolerance
        if self.skipped:
            return [Styled(f"skipped: {self.skipped}")]
        if self.convention:
            said = [
                {"column": _SHAPES, "flat": _FLAT}.get(how, _EITHER)[what]
                for what, how in self.convention.items()
                if how is not None and what in _SHAPES
            ]
            if said:
                lines.append(Styled(f"course module, shapes detected: {', '.join(said)}"))
        lines += [Styled(note) for note in self.notes]
        if self.precision != "float64":
            lines.append(Styled(self._precision_line()))
        if self.match:
            lines.append((
                Styled("match:", "green"),
                Styled(f" all {self.events_checked} events agree with the reference (largest"
                       f" difference {self.max_difference:.3g}, tolerance {tolerance:g})"),
            ))  # fmt: skip
        first = self.first_divergence
        if first is None:
            return lines
        lines.append(_divergence_lines("divergence", first, name, tolerance))
        if (
            self.convention
            and all(MUTATION[c].family == "handout" for c in first.causes)
            and (first.causes and not first.alternatives)
        ):
            lines.append(Styled(f"  ({HANDOUT_NOTE})"))
        following = self.next_divergence
        if following is not None and not every:
            title = "next divergence (not explained by the first one's causes)"
            lines.append(_divergence_lines(title, following, name, tolerance))
        more = len(self.divergences) - 1 - (following is not None and not every)
        if more and not every:
            lines.append(
                Styled(f"  {more} more event(s) diverge; --all finds the cause of every one")
            )
        return lines

    def _precision_line(self) -> str:
        line = (
            f"the filter computes in {self.precision}: it is held to its own precision"
            f" (tolerance {self.tolerance:g})"
        )
        if self.within_precision:
            line += (
                f"; its largest difference from the float64 reference, {self.within_precision:.3g},"
                " is its precision's, not a mistake"
            )
        return line

    def groups_table(self) -> TextTable:
        """Every divergent event, grouped by kind, quantity and cause."""
        columns = ("kind", "quantity", "events", "first", "line", "cause")
        rows = []
        for group in self.groups:
            first = group.first
            values = (group.kind, group.quantity, group.count, first.event, first.line, group.cause)
            rows.append(tuple(Styled(str(value)) for value in values))
        left = frozenset({"kind", "quantity", "cause"})
        return TextTable("every divergent event, grouped", columns, tuple(rows), left=left)

    def group_lines(self) -> list[Cell]:
        """The causes found, and the hint of each group whose cause is unknown."""
        causes = self.causes
        lines: list[Cell] = [Styled("causes: " + (", ".join(causes) if causes else "none found"))]
        for group in self.groups:
            if group.cause == UNKNOWN:
                lines.append(Styled(
                    f"  unknown at event {group.first.event} ({group.quantity}):"
                    f" {group.first.hint}"
                ))  # fmt: skip
        return lines

    def to_json(self) -> dict[str, object]:
        return {
            "match": self.match,
            "events_checked": self.events_checked,
            "max_difference": self.max_difference,
            "tolerance": self.tolerance,
            "precision": self.precision,
            "divergent_events": len(self.divergences),
            "first_divergence": (
                None if self.first_divergence is None else self.first_divergence.to_json()
            ),
            "next_divergence": (
                None if self.next_divergence is None else self.next_divergence.to_json()
            ),
            "divergences": [group.to_json() for group in self.groups],
            "causes": self.causes,
            "all": self.every,
            "convention": self.convention,
            "notes": list(self.notes),
            "skipped": self.skipped or None,
            "error": None
            if self.error is None
            else {"message": self.error, "line": self.error_line, "kind": self.error_kind},
        }


def _divergence_lines(title: str, divergence: Divergence, name: str, tolerance: float) -> Cell:
    """One divergent event as the console says it: where, the worst entry, cause, hint."""
    worst = divergence.worst
    landmark = "" if worst.landmark_id is None else f" of landmark {worst.landmark_id}"
    return (
        Styled(title, "bold red"),
        Styled(
            f" at event {divergence.event} (step {divergence.step}, {divergence.kind.value},"
            f" {name}:{divergence.line}): the {worst.quantity.value}{landmark} differs\n  worst"
            f" entry {worst.entry}: expected {worst.expected:.9g}, got {worst.got:.9g}"
            f" (difference {worst.difference:.3g}, tolerance {tolerance:g})\n  cause:"
            f" {divergence.cause}\n  hint: {divergence.hint}"
        ),
    )


_SHAPES = {"X": "X (3+2k, 1)", "control": "control (2, 1)", "measure": "measure (2k, 1)"}
_FLAT = {"X": "X (3+2k,)", "control": "control (2,)", "measure": "measure (2k,)"}
_EITHER = {name: f"{name} (either shape, by function or call)" for name in _SHAPES}
