"""``ekfviz check``: a protocol filter in lockstep with the reference, event by event.

Before every event the reference (the built-in :class:`~ekfviz.filters.ekf.EkfSlam`)
starts from the checked filter's **own** state (x, P, landmark ids) and applies the same
event with the run's parameters; the two results are compared by landmark id. Every
difference found is therefore that event's own: errors do not pile up, and every event
that differs by more than the tolerance is a place where the filter's algebra differs.

A difference is scaled as |got - expected| / max(1, |expected|): absolute for the small
entries of a covariance, relative for large ones. A filter that computes in float32
(every number of its state a float32) is held to its own precision: the tolerance grows
to :data:`FLOAT32_TOLERANCE`, and a difference within it is said to be the precision's.
A divergent event's cause is found by the search of :mod:`ekfviz.check.search`: the
smallest set of mutations of the named operations that reproduces what the filter did.

The noise a filter declares as its own (``motion_noise`` 3x3, ``measurement_noise``
2x2) is compared with the run's (the options, or the log's header) and a difference is
named as a cause at the start; the reference never adopts it.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ekfviz.check.hints import IDS_HINT, PRIOR_HINT, hint, named
from ekfviz.check.mutations import MUTATION
from ekfviz.check.rerun import Form, Noise, State, Step
from ekfviz.check.result import CheckResult, Difference, Divergence, Quantity
from ekfviz.check.search import Diagnosis, Finding, Seen
from ekfviz.check.source import Source
from ekfviz.check.unknown import unexplained
from ekfviz.core.batch import KIND_CODES, BatchBuilder
from ekfviz.core.errors import FilterError
from ekfviz.core.params import FilterParams, UpdateMode
from ekfviz.core.records import Control, EventKind, LogEvent, Sighting
from ekfviz.core.steps import StepCounter
from ekfviz.core.types import FloatArray, IntArray
from ekfviz.filters.ekf import EkfSlam
from ekfviz.filters.plugged import FilterFactory, Plugged, PluginError
from ekfviz.models.angles import wrap_angle
from ekfviz.models.kalman import measurement_noise, motion_noise
from ekfviz.runner.replay import plugged

__all__ = [
    "DEFAULT_TOLERANCE", "CheckResult", "Difference", "Divergence", "Quantity", "compare",
    "course_cannot_read", "lockstep", "numbered", "skipped",
]  # fmt: skip

DEFAULT_TOLERANCE = 1e-6
# the tolerance of a filter that computes in float32 (about 2^-23 = 1.2e-7 per operation):
# the largest difference a correct float32 module showed on the battery's logs, 3.5e-6,
# times 30 (a margin for longer runs and worse-conditioned updates)
FLOAT32_TOLERANCE = 1e-4
# the mutations are re-run (dense algebra) only up to this state dimension
HYPOTHESIS_MAX_DIM = 400
# without --all, how many divergent events after the first are searched to find the next
# one with a cause of its own (each costs the search's re-runs)
NEXT_SEARCH_LIMIT = 25
# the events kept for the search to look back at (their states, for a state of a few
# hundred entries a few MB each): the divergent ones, and this many matching ones
SEEN_MATCHED = 200


def declared_noise(slam: object) -> tuple[FloatArray | None, FloatArray | None]:
    """The motion noise (3x3) and measurement noise (2x2) the filter declares as its own
    (``motion_noise``, ``measurement_noise``), each None where it declares none that is a
    finite matrix of that shape."""
    declared: list[FloatArray | None] = []
    for attribute, size in (("motion_noise", 3), ("measurement_noise", 2)):
        try:
            value = getattr(slam, attribute, None)
        except Exception:  # the user's property: Plugged reports it
            value = None
        matrix = None if value is None else np.array(value, dtype=np.float64)
        ok = matrix is not None and matrix.shape == (size, size) and np.isfinite(matrix).all()
        declared.append(matrix if ok else None)
    return declared[0], declared[1]


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
    run = _Lockstep(params, slam, name, tolerance, every, Source.read(_source_of(make_filter)))
    run.prior()
    for event, step, kind, log_event in numbered(events):
        if not run.event(event, step, kind, log_event):
            break
    return run.result()


def course_cannot_read(events: Sequence[LogEvent]) -> str:
    """Why a course module cannot read ``events`` (empty: it can): its functions read the
    classic format, every line naming the landmarks of the first in the same order."""
    lines = [event for event in events if isinstance(event, Sighting)]
    if not lines:
        return ""
    first = [int(i) for i in lines[0].ids]
    for line in lines[1:]:
        ids = [int(i) for i in line.ids]
        if ids != first:
            return (
                f"a course module cannot read this log: its line {line.line} names landmarks"
                f" {ids[:6]}{' ...' if len(ids) > 6 else ''}, not the {len(first)} of its first"
                " line in their order; the handout's update(X, P, measure, measure_cov, k)"
                " takes the measurements of all k landmarks, in order, and init_landmarks is"
                " called once, on the first line, so a landmark first seen later has no"
                " function to initialise it"
            )
    return ""


def skipped(why: str, tolerance: float) -> CheckResult:
    """The result of a log the filter was not run on, and why."""
    empty = BatchBuilder().build()
    return CheckResult(0, 0.0, tolerance, None, empty, empty, (), skipped=why)


def _source_of(make_filter: FilterFactory) -> str | None:
    """The file of a user's filter (a worker's target), if it is one."""
    target = getattr(make_filter, "target", None)
    path = getattr(target, "path", None)
    return path if isinstance(path, str) else None


@dataclass(slots=True)
class _Records:
    """The batches of both filters, event by event (what the recording of a check shows)."""

    filter: BatchBuilder = field(default_factory=BatchBuilder)
    reference: BatchBuilder = field(default_factory=BatchBuilder)

    def add(self, ekf: EkfSlam, slam: Plugged, kind: EventKind, **what: Any) -> None:
        """Both filters' states after one event (``what``: as :meth:`BatchBuilder.add`)."""
        for target, source in ((self.reference, ekf), (self.filter, slam)):
            target.add(source.state_parts(), kind=KIND_CODES[kind], **what)


class _Lockstep:
    """One check's run: both filters event by event, the divergences and their causes."""

    def __init__(
        self,
        params: FilterParams,
        slam: Plugged,
        name: str,
        tolerance: float,
        every: bool,
        source: Source | None,
    ) -> None:
        self.params, self.slam, self.name = params, slam, name
        self.every, self.source = every, source
        self.tolerance = self.asked = tolerance
        declared_Q, declared_R = declared_noise(slam.slam)
        self.noise = Noise(motion_noise(params.sigma_x, params.sigma_y, params.sigma_alpha),
                           measurement_noise(params.sigma_bearing, params.sigma_range),
                           declared_Q, declared_R)  # fmt: skip
        joint = params.update is UpdateMode.JOINT
        self.diagnosis = Diagnosis(self.noise, Form(joint), tolerance)
        self.records = _Records()
        self.differences: list[float] = []
        self.divergences: list[Divergence] = []
        self.findings: list[Finding | None] = []
        self.seen: list[Seen] = []
        self.stopped: tuple[str, int, str] | None = None
        self.user_traceback = ""
        self.precision, self.within_precision = "float64", 0.0
        self.notes: list[str] = []
        self.first_searched = False
        # without every: the first divergence's causes, and the next one not explained by them
        self.first_causes: frozenset[str] | None = None
        self.next_at: int | None = None
        self.searched = 0

    def prior(self) -> None:
        """The filter must start where the parameters say, with the run's noise."""
        before = _state(self.slam)
        worst = compare(_state(EkfSlam(self.params)), before)
        if worst is not None and worst.difference > self.tolerance:
            self._add(Divergence(0, 0, 0, EventKind.INIT, worst, PRIOR_HINT), None)
        for declared, run, what in ((self.noise.declared_motion, self.noise.Q, "motion"),
                                    (self.noise.declared_measurement, self.noise.R,
                                     "measurement")):  # fmt: skip
            if declared is not None and not np.allclose(declared, run, rtol=1e-9, atol=0.0):
                self._declared(declared, run, what)

    def _declared(self, declared: FloatArray, run: FloatArray, what: str) -> None:
        """A declared noise other than the run's: named as a cause, kept for the search."""
        operation = f"{what}_noise"
        scales: tuple[tuple[str, float], ...] = ()
        k = float(np.sum(declared * run) / np.sum(run * run))  # (a multiple of it, if any)
        if np.allclose(declared, np.sqrt(run), rtol=1e-9, atol=0.0):
            mutation = MUTATION[f"{operation}.sigmas"]
        elif np.allclose(declared, np.square(run), rtol=1e-9, atol=0.0):
            mutation = MUTATION[f"{operation}.squared"]
        elif k > 0.0 and np.allclose(declared, k * run, rtol=1e-9, atol=0.0):
            mutation = MUTATION[f"{operation}.scaled"]
            scales = ((mutation.id, k),)
            self.diagnosis.scales[mutation.id] = k
        else:
            mutation = MUTATION[f"{operation}.declared"]
        self.diagnosis.found[mutation.id] = mutation
        attribute = "motion_noise" if what == "motion" else "measurement_noise"
        self.notes.append(
            f"the filter declares {attribute} = {np.round(declared, 9).tolist()}; the run's is"
            f" {np.round(run, 9).tolist()} (the reference keeps the run's)"
        )
        i = int(np.argmax(np.abs(declared - run)))
        r, c = divmod(i, len(run))
        expected, got = float(run[r, c]), float(declared[r, c])
        worst = Difference(Quantity.DECLARED_NOISE, None, f"{attribute}[{r}, {c}]", expected,
                           got, abs(got - expected) / max(1.0, abs(expected)))  # fmt: skip
        finding = Finding((mutation.id,), scales=scales)
        causes = named(finding.causes, self.source, scales)
        text = hint(finding, causes, None, self._file(), "")
        self._add(Divergence(0, 0, 0, EventKind.INIT, worst, text, finding.causes, (), causes),
                  finding)  # fmt: skip

    def event(self, event: int, step: int, kind: EventKind, log_event: LogEvent) -> bool:
        """Run one event in both filters and compare; False where the run stops."""
        before = _state(self.slam)
        ekf = EkfSlam.from_state(self.params, before.x, before.P, before.ids, compiled=False)
        what: dict[str, Any] = dict(event=event, step=step, line=log_event.line,
                                    time=log_event.time)  # fmt: skip
        try:
            if isinstance(log_event, Control):
                control = (log_event.d, log_event.alpha)
                ekf.predict(*control)
                self.slam.predict(*control)
                self.records.add(ekf, self.slam, kind, control=control, **what)
            else:
                expected_seen = ekf.observe(log_event.ids, log_event.z)
                got_seen = self.slam.observe(log_event.ids, log_event.z)
                for target, source, seen in (
                    (self.records.reference, ekf, expected_seen),
                    (self.records.filter, self.slam, got_seen),
                ):
                    target.add(source.state_parts(), kind=KIND_CODES[kind], observations=seen,
                               **what)  # fmt: skip
        except PluginError as failure:
            message = f"event {event} ({kind.value}): {failure}"
            self.stopped = (message, log_event.line, str(getattr(failure, "kind", "raised")))
            self.user_traceback = str(getattr(failure, "user_traceback", "") or "")
            return False
        except FilterError as failure:  # the reference, started from the filter's state
            largest = float(np.max(np.abs(before.x))) if before.x.size else 0.0
            message = (
                f"event {event} ({kind.value}): the reference cannot {kind.value} from the"
                f" state filter {self.name} gave before it: {failure} (the largest |x| is"
                f" {largest:.3g}: a value set as a placeholder, or one not set)"
            )
            self.stopped = (message, log_event.line, "raised")
            return False
        self._compare(event, step, kind, log_event, before, _state(ekf), _state(self.slam))
        return True

    def _compare(
        self,
        event: int,
        step: int,
        kind: EventKind,
        log_event: LogEvent,
        before: State,
        expected: State,
        after: State,
    ) -> None:
        """Compare one event's results; search a divergence's cause where asked."""
        self._precision_of(expected, after)
        worst = compare(expected, after)
        self.differences.append(0.0 if worst is None else worst.difference)
        rerun_step = step_of(log_event)
        if worst is None or worst.difference <= self.tolerance:
            if worst is not None and worst.difference > self.asked:
                self.within_precision = max(self.within_precision, worst.difference)
            self._seen(Seen(rerun_step, before, after))
            return
        searching = (
            self.first_causes is not None and self.next_at is None
            and self.searched < NEXT_SEARCH_LIMIT
        )  # fmt: skip
        if not (self.every or not self.first_searched or searching):
            self._add(Divergence(event, step, log_event.line, kind, worst, ""), None)
            return
        finding = self._explain(before, after, rerun_step, worst)
        divergence = self._divergence(event, step, kind, log_event, worst, finding,
                                      before, expected, after, rerun_step)  # fmt: skip
        if not self.first_searched:
            self.first_searched = True
            if not self.every and finding.known:
                self.first_causes = frozenset(finding.causes)
        elif searching:
            self.searched += 1
            named_ok = finding.known and self.first_causes
            if not (named_ok and set(finding.causes) <= (self.first_causes or frozenset())):
                self.next_at = len(self.divergences)
        self._add(divergence, finding)
        if finding.known:
            self._seen(Seen(rerun_step, before, after, finding.causes), divergent=True)

    def _explain(self, before: State, after: State, step: Step, worst: Difference) -> Finding:
        if worst.quantity is Quantity.LANDMARK_IDS or len(before.x) > HYPOTHESIS_MAX_DIM:
            return Finding()
        self.diagnosis.tolerance = self.tolerance
        divergence = worst.difference if math.isfinite(worst.difference) else 0.0
        return self.diagnosis.explain(before, after, step, divergence, self.seen)

    def _divergence(
        self,
        event: int,
        step: int,
        kind: EventKind,
        log_event: LogEvent,
        worst: Difference,
        finding: Finding,
        before: State,
        expected: State,
        after: State,
        rerun_step: Step,
    ) -> Divergence:
        """The divergent event with its causes, their lines, and its hint."""
        causes = named(finding.causes, self.source, finding.scales) if finding.known else ()
        numbers = None
        if (
            not finding.causes
            and worst.quantity is not Quantity.LANDMARK_IDS
            and (len(before.x) <= HYPOTHESIS_MAX_DIM)
        ):
            numbers = unexplained(self.noise, before, after, rerun_step, self.tolerance)
        fallback = self._fallback(worst, expected, after)
        text = hint(finding, causes, numbers, self._file(), fallback)
        if numbers is not None and fallback and not causes and not finding.alternatives:
            text = f"{text}. {fallback}"
        return Divergence(event, step, log_event.line, kind, worst, text, finding.causes,
                          finding.alternatives, causes, numbers, finding.inherited)  # fmt: skip

    def _fallback(self, worst: Difference, expected: State, after: State) -> str:
        """What is said of a divergence nothing explains, beside its numbers: the ids, or
        whole numbers where the reference's are not (an integer array), or the parts that
        differ."""
        if worst.quantity is Quantity.LANDMARK_IDS:
            return IDS_HINT
        said = []
        truncated = whole_numbers(expected, after, self.tolerance)
        if truncated:
            listed = ", ".join(truncated[:3]) + (", ..." if len(truncated) > 3 else "")
            said.append(
                f"{listed}: whole numbers where the reference's are not, as an integer array"
                " (np.zeros(..., dtype=int), np.array([[1, 0], ...]) of ints) truncates what"
                " is stored in it: make it float"
            )
        blocks = differing_blocks(expected, after, self.tolerance)
        if blocks:
            said.append(f"Differs: {blocks}")
        return ". ".join(said)

    def _precision_of(self, expected: State, after: State) -> None:
        """Whether the filter computes in float32: every number of its state a float32,
        where the float64 reference's are not (its tolerance grows from then on)."""
        if self.precision == "float32" or not (_float32(after) and not _float32(expected)):
            return
        self.precision = "float32"
        self.tolerance = max(self.asked, FLOAT32_TOLERANCE)

    def _seen(self, seen: Seen, divergent: bool = False) -> None:
        if len(seen.before.x) > HYPOTHESIS_MAX_DIM:
            return
        self.seen.append(seen)
        matched = [k for k, s in enumerate(self.seen) if not s.explained_by]
        if not divergent and len(matched) > SEEN_MATCHED:
            del self.seen[matched[0]]

    def _add(self, divergence: Divergence, finding: Finding | None) -> None:
        self.divergences.append(divergence)
        self.findings.append(finding)

    def _file(self) -> str:
        return self.source.name if self.source is not None else "the filter"

    def result(self) -> CheckResult:
        """The check's result, the alternatives the whole run tells apart resolved."""
        divergences = [self._resolved(d, f) for d, f in zip(self.divergences, self.findings,
                                                            strict=True)]  # fmt: skip
        stopped = self.stopped
        first = next((d for d in divergences), None)
        return CheckResult(
            events_checked=len(self.differences),
            max_difference=max(self.differences, default=0.0),
            tolerance=self.tolerance,
            first_divergence=first,
            records=self.records.filter.build(),
            reference=self.records.reference.build(),
            differences=tuple(self.differences),
            divergences=tuple(divergences),
            every=self.every,
            error=None if stopped is None else stopped[0],
            error_line=0 if stopped is None else stopped[1],
            error_kind="" if stopped is None else stopped[2],
            error_traceback=self.user_traceback,
            convention=getattr(self.slam.slam, "convention", None) or None,
            next_divergence=None if self.next_at is None else divergences[self.next_at],
            precision=self.precision,
            within_precision=self.within_precision,
            notes=tuple(self.notes),
        )

    def _resolved(self, divergence: Divergence, finding: Finding | None) -> Divergence:
        if finding is None or not finding.indistinct:
            return divergence
        resolved = self.diagnosis.resolve(finding, self.seen)
        causes = named(resolved.causes, self.source, resolved.scales) if resolved.known else ()
        text = hint(resolved, causes, divergence.unexplained, self._file(), divergence.hint)
        return Divergence(divergence.event, divergence.step, divergence.line, divergence.kind,
                          divergence.worst, text, resolved.causes, resolved.alternatives,
                          causes, divergence.unexplained, resolved.inherited)  # fmt: skip


def step_of(event: LogEvent) -> Step:
    if isinstance(event, Control):
        return Step(d=float(event.d), alpha=float(event.alpha))
    assert isinstance(event, Sighting)
    ids = np.asarray(event.ids, dtype=np.int64)
    return Step(ids=ids, z=np.asarray(event.z, dtype=np.float64).reshape(-1, 2))


def _float32(s: State) -> bool:
    """Whether every number of a state is a float32 (and some is not a small dyadic
    fraction, which both precisions hold alike)."""
    values = np.concatenate([s.x, s.P.ravel()])
    if not values.size or float(np.max(np.abs(values))) > float(np.finfo(np.float32).max):
        return False
    return bool(np.array_equal(values.astype(np.float32).astype(np.float64), values)) and bool(
        np.any(values * 2.0**20 != np.round(values * 2.0**20))
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
    """Every part of the state that differs beyond ``tolerance`` and the landmarks it is
    at (at most four named), e.g. ``pose mean; landmark mean at landmarks 1, 3``; empty
    when the ids differ."""
    worst = _differing(expected, got, tolerance)
    ids = expected.ids.tolist()
    parts = []
    for quantity in Quantity:
        if quantity not in worst:
            continue
        _, where = worst[quantity]
        named_ids = sorted(where, key=ids.index)
        at = ""
        if named_ids:
            listed = ", ".join(str(i) for i in named_ids[:4]) + (
                ", ..." if len(named_ids) > 4 else ""
            )
            at = f" at landmark{'s' if len(named_ids) > 1 else ''} {listed}"
        parts.append(f"{quantity.value}{at}")
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
