"""``ekfviz check``: a protocol filter in lockstep with the reference, event by event.

Before every event the reference (the built-in :class:`~ekfviz.filters.ekf.EkfSlam`)
starts from the checked filter's **own** state (x, P, landmark ids) and applies the same
event with the same parameters; the two results are compared by landmark id. Every
difference found is therefore that event's own: errors do not pile up, and every event
that differs by more than the tolerance is a place where the filter's algebra differs.

A difference is scaled as |got - expected| / max(1, |expected|): absolute for the small
entries of a covariance, relative for large ones. A divergent event's cause is found by
re-running it from the same state with the mistakes of the catalogue
(:mod:`ekfviz.check.mistakes`), combined with those already found: a set that reproduces
what the filter did is named; otherwise the hint says which part of the algebra produces
the quantity that differs.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, replace

import numpy as np

from ekfviz.check.mistakes import (
    RERUN_ERRORS,
    UNKNOWN,
    Explanation,
    State,
    describe,
    explain_predict,
    explain_update,
)
from ekfviz.core.batch import KIND_CODES, BatchBuilder, EventBatch
from ekfviz.core.errors import FilterError
from ekfviz.core.params import FilterParams
from ekfviz.core.records import Control, EventKind, LogEvent, Sighting
from ekfviz.core.steps import StepCounter
from ekfviz.core.tables import Cell, Styled, TextTable
from ekfviz.core.types import FloatArray, IntArray
from ekfviz.filters.ekf import EkfSlam
from ekfviz.filters.plugged import FilterFactory, Plugged, PluginError
from ekfviz.models.angles import wrap_angle
from ekfviz.runner.replay import plugged

DEFAULT_TOLERANCE = 1e-6
# the mistakes are re-run (dense algebra) only up to this state dimension
HYPOTHESIS_MAX_DIM = 400
# without --all, how many divergent events after the first are re-run to find the next
# one with a cause of its own (each costs the catalogue's re-runs)
NEXT_SEARCH_LIMIT = 25
# how many unexplained updates of a run get the deep search of the catalogue (any three
# more mistakes at once; after them, the later mistakes one at a time: see
# mistakes.explain_update); a run's mistakes, once found, are tried at every event
DEEP_SEARCHES = 3


class Quantity(str, enum.Enum):
    """The part of the state a difference is in."""

    LANDMARK_IDS = "landmark ids"
    POSE_MEAN = "pose mean"
    POSE_COVARIANCE = "pose covariance"
    POSE_LANDMARK = "pose-landmark cross-covariance"
    LANDMARK_MEAN = "landmark mean"
    LANDMARK_COVARIANCE = "landmark covariance"
    LANDMARK_LANDMARK = "landmark-landmark cross-covariance"


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
    :param alternatives: other sets of causes that reproduce it equally (the event
        cannot tell them apart; ``causes`` is then not named)
    """

    event: int
    step: int
    line: int
    kind: EventKind
    worst: Difference
    hint: str
    causes: tuple[str, ...] = ()
    alternatives: tuple[tuple[str, ...], ...] = ()

    @property
    def cause(self) -> str:
        """The cause as one id (``a+b`` for two combined), or ``unknown``."""
        return "+".join(self.causes) if self.causes and not self.alternatives else UNKNOWN

    def to_json(self) -> dict[str, object]:
        worst = self.worst
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
            "hint": self.hint,
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
        return {
            "kind": self.kind,
            "quantity": self.quantity,
            "count": self.count,
            "first_event": self.first.event,
            "first_step": self.first.step,
            "first_line": self.first.line,
            "cause": self.cause,
            "hint": self.first.hint,
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
        if self.convention:
            said = [
                (_SHAPES if how == "column" else _FLAT)[what]
                for what, how in self.convention.items()
                if how is not None
            ]
            lines.append(Styled(f"course module, shapes detected: {', '.join(said)}"))
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
        if self.convention and first.causes == ("independent_landmark_init",):
            lines.append(Styled(f"  ({_HANDOUT_NOTE})"))
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
            if group.cause == "unknown":
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
            "error": None
            if self.error is None
            else {"message": self.error, "line": self.error_line, "kind": self.error_kind},
        }


_HANDOUT_NOTE = (
    "a course module's P starts as the handout's main() builds it, block_diag(pose_cov,"
    " landmark_cov), so every one shows this; init_cross_covariance in the module (README)"
    " fills in the cross-covariances"
)


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


def reference_params(params: FilterParams, slam: object) -> FilterParams:
    """The run's parameters with the noise the filter exposes as its own
    (``measurement_noise`` 2x2, ``motion_noise`` 3x3, both diagonal), which the reference
    then uses: the check is of the filter's algebra, not of its noise levels."""
    changes: dict[str, float] = {}
    for name, fields in (
        ("measurement_noise", ("sigma_bearing", "sigma_range")),
        ("motion_noise", ("sigma_x", "sigma_y", "sigma_alpha")),
    ):
        try:
            value = getattr(slam, name, None)
        except Exception:  # the user's property: Plugged reports it
            value = None
        if value is None:
            continue
        matrix = np.array(value, dtype=np.float64)
        size = len(fields)
        if matrix.shape != (size, size) or not np.isfinite(matrix).all():
            continue
        if np.abs(matrix - np.diag(np.diag(matrix))).max() > 0 or np.diag(matrix).min() <= 0:
            continue
        changes.update(zip(fields, np.sqrt(np.diag(matrix)).tolist(), strict=True))
    return replace(params, **changes) if changes else params  # type: ignore[arg-type]


def lockstep(
    events: Iterable[LogEvent],
    params: FilterParams,
    make_filter: FilterFactory,
    *,
    name: str,
    tolerance: float = DEFAULT_TOLERANCE,
    every: bool = False,
) -> CheckResult:
    """Run ``make_filter(params)`` and the reference in lockstep over ``events``, to the
    end (or to the event where the filter fails, which ``error`` then says).

    :param every: look for the causes of every divergent event (``--all``), not only
        of the first
    :raises FilterLineError: the checked filter cannot even be constructed
    """
    slam = plugged(make_filter, params, name)
    params = reference_params(params, slam.slam)
    records = BatchBuilder()
    reference = BatchBuilder()
    differences: list[float] = []
    divergences: list[Divergence] = []
    found: set[str] = set()
    stopped: tuple[str, int, str] | None = None
    user_traceback = ""
    # without every: the first divergence's causes, and the next one not explained by them
    first_causes: frozenset[str] | None = None
    next_at: int | None = None
    searched = 0
    # the first updates that nothing explains get the deep search (see explain_update)
    deep_left = DEEP_SEARCHES

    # the prior itself: the filter must start where the parameters say
    prior = EkfSlam(params)
    before = _state(slam)
    worst = compare(_state(prior), before)
    if worst is not None and worst.difference > tolerance:
        divergences.append(Divergence(0, 0, 0, EventKind.INIT, worst, _PRIOR_HINT))

    for event, step, kind, log_event in numbered(events):
        before = _state(slam)
        ekf = EkfSlam.from_state(params, before.x, before.P, before.ids, compiled=False)
        line, time = log_event.line, log_event.time
        try:
            if isinstance(log_event, Control):
                control = (log_event.d, log_event.alpha)
                ekf.predict(*control)
                slam.predict(*control)
                for target, source in ((reference, ekf), (records, slam)):
                    target.add(source.state_parts(), event=event, step=step, kind=KIND_CODES[kind],
                               line=line, time=time, control=control)  # fmt: skip
            else:
                expected = ekf.observe(log_event.ids, log_event.z)
                got = slam.observe(log_event.ids, log_event.z)
                for target, source, seen in ((reference, ekf, expected), (records, slam, got)):
                    target.add(source.state_parts(), event=event, step=step, kind=KIND_CODES[kind],
                               line=line, time=time, observations=seen)  # fmt: skip
        except PluginError as failure:
            message = f"event {event} ({kind.value}): {failure}"
            stopped = (message, log_event.line, str(getattr(failure, "kind", "raised")))
            user_traceback = str(getattr(failure, "user_traceback", "") or "")
            break
        except FilterError as failure:  # the reference, started from the filter's state
            largest = float(np.max(np.abs(before.x))) if before.x.size else 0.0
            message = (
                f"event {event} ({kind.value}): the reference cannot {kind.value} from the"
                f" state filter {name} gave before it: {failure} (the largest |x| is"
                f" {largest:.3g}: a value set as a placeholder, or one not set)"
            )
            stopped = (message, log_event.line, "raised")
            break
        after = _state(slam)
        worst = compare(_state(ekf), after)
        differences.append(0.0 if worst is None else worst.difference)
        if worst is None or worst.difference <= tolerance:
            continue
        searching = first_causes is not None and next_at is None and searched < NEXT_SEARCH_LIMIT
        if every or not divergences or searching:
            found_now = frozenset(found)
            explanation = explain(params, before, after, log_event, worst, tolerance, found_now,
                                  deep=deep_left > 0)  # fmt: skip
            found.update(explanation.causes if explanation.known else ())
            if isinstance(log_event, Sighting) and not explanation.causes:
                deep_left -= 1
            hint = _hint(explanation, kind, worst, before, log_event, _state(ekf), after,
                         tolerance)  # fmt: skip
            causes, alternatives = explanation.causes, explanation.alternatives
            if not every and not divergences and explanation.known:
                first_causes = frozenset(causes)
            elif searching:
                searched += 1
                if not (explanation.known and first_causes and set(causes) <= first_causes):
                    next_at = len(divergences)
            divergences.append(
                Divergence(event, step, log_event.line, kind, worst, hint, causes, alternatives)
            )
        else:
            divergences.append(Divergence(event, step, log_event.line, kind, worst, ""))
    return CheckResult(
        events_checked=len(differences),
        max_difference=max(differences, default=0.0),
        tolerance=tolerance,
        first_divergence=divergences[0] if divergences else None,
        records=records.build(),
        reference=reference.build(),
        differences=tuple(differences),
        divergences=tuple(divergences),
        every=every,
        error=None if stopped is None else stopped[0],
        error_line=0 if stopped is None else stopped[1],
        error_kind="" if stopped is None else stopped[2],
        error_traceback=user_traceback,
        convention=getattr(slam.slam, "convention", None) or None,
        next_divergence=None if next_at is None else divergences[next_at],
    )


def numbered(events: Iterable[LogEvent]) -> Iterator[tuple[int, int, EventKind, LogEvent]]:
    """Each event with its event number, step and kind, as the runner numbers them.

    The first line, when it is an observation, is event 0 (``init``); every control
    starts a step; an observation is the update of its step, or starts a step of its own
    when the step already had one.
    """
    counter = StepCounter()
    for index, log_event in enumerate(events):
        if index == 0 and isinstance(log_event, Sighting):
            yield (*counter.initialise(), EventKind.INIT, log_event)
        elif isinstance(log_event, Control):
            yield (*counter.predict(), EventKind.PREDICT, log_event)
        else:
            yield (*counter.update(), EventKind.UPDATE, log_event)


def compare(expected: State, got: State) -> Difference | None:
    """The worst scaled difference between two states, matched by landmark id.

    :return: None when both are empty of differences (exactly equal or both empty)
    """
    if sorted(expected.ids.tolist()) != sorted(got.ids.tolist()):
        extra = sorted(set(got.ids.tolist()) - set(expected.ids.tolist()))
        missing = sorted(set(expected.ids.tolist()) - set(got.ids.tolist()))
        what = f"extra {extra}" if extra else f"missing {missing}"
        landmark = (extra or missing or [None])[0]
        count = float(len(got.ids))
        return Difference(Quantity.LANDMARK_IDS, landmark, what, float(len(expected.ids)),
                          count, math.inf)  # fmt: skip
    x, P, scaled_x, scaled_P = _scaled(expected, got)
    worst: Difference | None = None
    names = _names(expected.ids)
    for index in np.argsort(-scaled_x)[:1]:
        i = int(index)
        quantity = Quantity.POSE_MEAN if i < 3 else Quantity.LANDMARK_MEAN
        worst = Difference(quantity, _landmark(expected.ids, i), f"x[{names[i]}]",
                           float(expected.x[i]), float(x[i]), float(scaled_x[i]))  # fmt: skip
    if P.size:
        i, j = (int(v) for v in np.unravel_index(int(np.argmax(scaled_P)), P.shape))
        if worst is None or scaled_P[i, j] > worst.difference:
            i, j = min(i, j), max(i, j)
            worst = Difference(_block(i, j), _landmark(expected.ids, j if j >= 3 else i),
                               f"P[{names[i]}, {names[j]}]", float(expected.P[i, j]),
                               float(P[i, j]), float(scaled_P[i, j]))  # fmt: skip
    return worst


def _scaled(expected: State, got: State) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """The filter's x and P in the reference's landmark order (the same ids), and their
    scaled differences from the reference's (the heading's wrapped)."""
    x, P = got.in_order_of(expected.ids)
    dx = x - expected.x
    dx[2] = wrap_angle(float(dx[2]))
    scaled_x = np.abs(dx) / np.maximum(1.0, np.abs(expected.x))
    scaled_P = np.abs(P - expected.P) / np.maximum(1.0, np.abs(expected.P))
    return x, P, scaled_x, scaled_P


def differing_blocks(expected: State, got: State, tolerance: float) -> str:
    """Every part of the state that differs beyond ``tolerance``: its largest difference
    and the landmarks it is at (at most four named), e.g. ``pose mean (up to 0.31);
    landmark mean of landmarks 1, 3 (up to 0.12)``; empty when the ids differ."""
    worst = _differing(expected, got, tolerance)
    ids = expected.ids.tolist()
    parts = []
    for quantity in Quantity:
        if quantity not in worst:
            continue
        largest, where = worst[quantity]
        named = sorted(where, key=ids.index)
        at = ""
        if named:
            listed = ", ".join(str(i) for i in named[:4]) + (", ..." if len(named) > 4 else "")
            at = f" at landmark{'s' if len(named) > 1 else ''} {listed}"
        parts.append(f"{quantity.value}{at} (up to {largest:.3g})")
    return "; ".join(parts)


def _differing(
    expected: State, got: State, tolerance: float
) -> dict[Quantity, tuple[float, set[int]]]:
    """The parts of the state that differ beyond ``tolerance``: the largest difference of
    each and the landmarks it is at; empty when the ids differ."""
    if sorted(expected.ids.tolist()) != sorted(got.ids.tolist()):
        return {}
    _, _, scaled_x, scaled_P = _scaled(expected, got)
    worst: dict[Quantity, tuple[float, set[int]]] = {}

    def note(quantity: Quantity, difference: float, landmarks: Iterable[int | None]) -> None:
        largest, where = worst.get(quantity, (0.0, set()))
        where.update(i for i in landmarks if i is not None)
        worst[quantity] = (max(largest, difference), where)

    for i in np.flatnonzero(scaled_x > tolerance).tolist():
        quantity = Quantity.POSE_MEAN if i < 3 else Quantity.LANDMARK_MEAN
        note(quantity, float(scaled_x[i]), [_landmark(expected.ids, i)])
    rows, columns = np.nonzero(np.triu(scaled_P > tolerance))
    for i, j in zip(rows.tolist(), columns.tolist(), strict=True):
        note(_block(i, j), float(scaled_P[i, j]),
             [_landmark(expected.ids, i), _landmark(expected.ids, j)])  # fmt: skip
    return worst


def whole_numbers(expected: State, got: State, tolerance: float) -> list[str]:
    """The entries of the filter's x that differ and are whole numbers where the
    reference's are not, less than 1 away (truncated): what an integer array does."""
    if sorted(expected.ids.tolist()) != sorted(got.ids.tolist()):
        return []
    x, _, scaled_x, _ = _scaled(expected, got)
    names = _names(expected.ids)
    found = []
    for i in np.flatnonzero(scaled_x > tolerance).tolist():
        value, reference = float(x[i]), float(expected.x[i])
        if value == round(value) and reference != round(reference) and abs(value - reference) < 1:
            found.append(f"x[{names[i]}] = {value:g} (expected {reference:.6g})")
    return found


def _block(i: int, j: int) -> Quantity:
    if j < 3:
        return Quantity.POSE_COVARIANCE
    if i < 3:
        return Quantity.POSE_LANDMARK
    if (i - 3) // 2 == (j - 3) // 2:
        return Quantity.LANDMARK_COVARIANCE
    return Quantity.LANDMARK_LANDMARK


def _landmark(ids: IntArray, index: int) -> int | None:
    return None if index < 3 else int(ids[(index - 3) // 2])


def _names(ids: IntArray) -> list[str]:
    return ["x", "y", "theta"] + [f"L{i}.{c}" for i in ids.tolist() for c in "xy"]


def _state(slam: EkfSlam | Plugged) -> State:
    return State(np.array(slam.x), np.array(slam.P), np.array(slam.landmark_ids, dtype=np.int64))


# -- hints ---------------------------------------------------------------------------------

_PRIOR_HINT = (
    "the filter does not start from the prior: x = init_pose, P = diag(init_pose_sigma^2)"
    " (FilterParams.init_pose, init_pose_sigma)"
)


_PATTERN_HINTS: dict[tuple[str, Quantity], str] = {
    ("predict", Quantity.POSE_MEAN): "the motion model: x' = x + d cos(theta),"
    " y' = y + d sin(theta), theta' = wrap(theta + alpha)",
    ("predict", Quantity.POSE_COVARIANCE): "the pose covariance of the predict:"
    " G P_rr G^T + W Q W^T (G's heading column, W the rotation of the robot frame)",
    ("predict", Quantity.POSE_LANDMARK): "the pose-landmark cross-covariances of the"
    " predict: P_rm' = G P_rm",
    ("predict", Quantity.LANDMARK_MEAN): "a predict must not move the landmarks",
    ("predict", Quantity.LANDMARK_COVARIANCE): "a predict must not change the landmark"
    " covariances (only the robot's rows and columns of P)",
    ("predict", Quantity.LANDMARK_LANDMARK): "a predict must not change the landmark"
    " covariances (only the robot's rows and columns of P)",
}


def explain(
    params: FilterParams,
    before: State,
    after: State,
    event: LogEvent,
    worst: Difference,
    tolerance: float,
    found: frozenset[str] = frozenset(),
    *,
    deep: bool = False,
) -> Explanation:
    """The causes of a divergence at ``event`` (see :mod:`ekfviz.check.mistakes`), combined
    with the causes already ``found``; none where the state is too large to re-run.

    :param deep: an update's search tries three more mistakes at once of all the catalogue
    """
    if worst.quantity is Quantity.LANDMARK_IDS or len(before.x) > HYPOTHESIS_MAX_DIM:
        return Explanation(())
    divergence = worst.difference if math.isfinite(worst.difference) else 0.0
    try:
        if isinstance(event, Control):
            return explain_predict(
                params.Q, before, after, event.d, event.alpha, found, tolerance, divergence
            )
        assert isinstance(event, Sighting)
        ids = np.asarray(event.ids, dtype=np.int64)
        z = np.asarray(event.z, dtype=np.float64).reshape(-1, 2)
        return explain_update(params.R, before, after, ids, z, found, tolerance, divergence,
                              deep=deep)  # fmt: skip
    except RERUN_ERRORS:
        return Explanation(())


def _hint(
    explanation: Explanation,
    kind: EventKind,
    worst: Difference,
    before: State,
    event: LogEvent,
    expected: State | None = None,
    after: State | None = None,
    tolerance: float = DEFAULT_TOLERANCE,
) -> str:
    """What to tell the user: the causes found, else where the quantity comes from (and,
    given the reference's and the filter's results, which parts of the state differ)."""
    if explanation.alternatives:
        options = " OR ".join("+".join(option) for option in explanation.alternatives)
        return (
            f"this event is reproduced equally by {options}: it cannot tell them apart"
            " (check --all on a longer log may)"
        )
    if explanation.causes:
        text = describe(explanation.causes)
        return f"{text} ({explanation.detail})" if explanation.detail else text
    hint = pattern_hint("predict" if isinstance(event, Control) else "update", worst, before,
                        event)  # fmt: skip
    if expected is None or after is None:
        return hint
    truncated = whole_numbers(expected, after, tolerance)
    if truncated:
        listed = ", ".join(truncated[:3]) + (", ..." if len(truncated) > 3 else "")
        hint = (
            f"{listed}: whole numbers where the reference's are not, as an integer array"
            " (np.zeros(..., dtype=int), np.array([[1, 0], ...]) of ints) truncates what is"
            f" stored in it: make it float. Otherwise: {hint}"
        )
    elif isinstance(event, Sighting) and worst.quantity is not Quantity.LANDMARK_IDS:
        hint = _update_hint(set(_differing(expected, after, tolerance)), before, event) or hint
    blocks = differing_blocks(expected, after, tolerance)
    return f"{hint}. Differs: {blocks}" if blocks else hint


_MEANS = frozenset({Quantity.POSE_MEAN, Quantity.LANDMARK_MEAN})


def _update_hint(differ: set[Quantity], before: State, event: Sighting) -> str:
    """What an update's differing parts say of where its mistake is: only the mean (H, S
    and K agree, as the covariance does: the innovation), only the covariance (the mean,
    hence K (z - h(x)), agrees: the covariance's own formula), both (what they share: H,
    S, K); empty when the update initialises a landmark (whose mean and covariance come
    from elsewhere)."""
    if not differ or any(int(i) not in before.ids.tolist() for i in event.ids):
        return ""
    if differ <= _MEANS:
        return (
            "only the mean differs: the covariance agrees, so H, S and K do; look at the"
            " innovation z - h(x): h = (wrap(atan2(dy, dx) - theta), sqrt(dx^2 + dy^2)),"
            " bearing first, its bearing wrapped to [-pi, pi), and at x + K (z - h(x))"
        )
    if not differ & _MEANS:
        return (
            "only the covariance differs: the mean agrees, so K (z - h(x)) does; look at"
            " the covariance's own update: P = (I - K H) P, or (I - K H) P (I - K H)^T +"
            " K R K^T (Joseph's form), with the same K and H as the mean's"
        )
    return (
        "the mean and the covariance both differ: look first at what they share, H (its"
        " rows bearing then range, the landmark's columns at 3 + 2j), S = H P H^T + R and"
        " K = P H^T S^-1 (S inverted); a wrong covariance formula alone leaves the mean"
        " as it is"
    )


def pattern_hint(kind: str, worst: Difference, before: State, event: LogEvent) -> str:
    """Where the quantity that differs comes from, when no known mistake reproduces it."""
    if worst.quantity is Quantity.LANDMARK_IDS:
        return (
            "the filter's landmark_ids differ from the observed landmarks: every id of an"
            " update must be in the state afterwards, new ones appended in the order seen"
        )
    pattern = _PATTERN_HINTS.get((kind, worst.quantity))
    if pattern is not None:
        return pattern
    # a new landmark's mean or covariance comes from its initialisation, not a correction
    newly = (
        isinstance(event, Sighting)
        and worst.landmark_id is not None
        and (worst.landmark_id not in before.ids.tolist())
    )
    if newly:
        return (
            "the initialisation of a new landmark: l = pose + r (cos(theta + beta),"
            " sin(theta + beta)) with (beta, r) the measurement (bearing first),"
            " P_ll = J_p P_pp J_p^T + J_z R J_z^T, P_lx = J_p P_px"
        )
    if worst.quantity in (Quantity.POSE_MEAN, Quantity.LANDMARK_MEAN):
        return (
            "the corrected mean: the innovation z - h(x) (bearing first, wrapped), the"
            " measurement Jacobian H and the gain K = P H^T S^-1"
        )
    return (
        "the covariance update: P - K S K^T (or Joseph's form) with S = H P H^T + R and"
        " H's five non-zero columns (pose, and the landmark's two)"
    )
