"""``ekfviz check``: a protocol filter in lockstep with the reference, event by event.

Before every event the reference (the built-in :class:`~ekfviz.core.filter.EkfSlam`)
starts from the checked filter's **own** state (x, P, landmark ids) and applies the same
event with the same parameters; the two results are compared by landmark id. Every
difference found is therefore that event's own: errors do not pile up, and the first
event that differs by more than the tolerance is where the bug is.

A difference is scaled as |got - expected| / max(1, |expected|): absolute for the small
entries of a covariance, relative for large ones. At the first divergent event the
likely cause is found by re-running that event from the same state with each of a list
of classic mistakes (:data:`PREDICT_MISTAKES`, :data:`UPDATE_MISTAKES`): a mistake that
reproduces what the filter did is named; otherwise the hint says which part of the
algebra produces the quantity that differs.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, replace

import numpy as np

from ekfviz.core.filter import EkfSlam, FilterParams, LandmarkInit, UpdateMode
from ekfviz.core.plugged import FilterFactory, Plugged, PluginError
from ekfviz.core.records import Control, EventKind, EventRecord, LogEvent, Sighting
from ekfviz.core.replay import FilterLineError
from ekfviz.core.types import FloatArray, IntArray
from ekfviz.models.angles import wrap_angle

DEFAULT_TOLERANCE = 1e-6
# the mistakes are re-run (dense algebra) only up to this state dimension
HYPOTHESIS_MAX_DIM = 400


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
class State:
    """A filter state: x (3+2N,), P (3+2N, 3+2N), landmark ids (N,) in state order."""

    x: FloatArray
    P: FloatArray
    ids: IntArray


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
    """The first event where the filter leaves the reference, and the likely cause.

    :param worst: the worst entry of the event's comparison
    """

    event: int
    step: int
    line: int
    kind: EventKind
    worst: Difference
    hint: str

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
            "hint": self.hint,
        }


@dataclass(frozen=True, slots=True)
class CheckResult:
    """What a lockstep check found.

    :param records: the checked filter's record of every event up to the divergence
    :param reference: the reference's record of the same events (each from the
        filter's state before the event)
    :param differences: the largest scaled difference at every event, in order
    """

    events_checked: int
    max_difference: float
    tolerance: float
    first_divergence: Divergence | None
    records: tuple[EventRecord, ...]
    reference: tuple[EventRecord, ...]
    differences: tuple[float, ...]

    @property
    def match(self) -> bool:
        return self.first_divergence is None

    def to_json(self) -> dict[str, object]:
        return {
            "match": self.match,
            "events_checked": self.events_checked,
            "max_difference": self.max_difference,
            "tolerance": self.tolerance,
            "first_divergence": (
                None if self.first_divergence is None else self.first_divergence.to_json()
            ),
        }


def lockstep(
    events: Iterable[LogEvent],
    params: FilterParams,
    make_filter: FilterFactory,
    *,
    name: str,
    tolerance: float = DEFAULT_TOLERANCE,
    stop_at_divergence: bool = True,
) -> CheckResult:
    """Run ``make_filter(params)`` and the reference in lockstep over ``events``.

    :param stop_at_divergence: stop at the first divergent event (else go on to the end,
        still from the filter's own state, and report the first)
    :raises FilterLineError: the checked filter raised or showed a broken state
    """
    try:
        slam = Plugged(make_filter(params), name, params)
    except PluginError as error:
        raise FilterLineError(0, f"event 0 (init): {error}") from error
    except Exception as error:  # the user's constructor
        message = f"filter {name}: construction raised {type(error).__name__}: {error}"
        raise FilterLineError(0, message) from error
    records: list[EventRecord] = []
    reference: list[EventRecord] = []
    differences: list[float] = []
    first: Divergence | None = None

    # the prior itself: the filter must start where the parameters say
    prior = EkfSlam(params)
    before = _state(slam)
    worst = compare(_state(prior), before)
    if worst is not None and worst.difference > tolerance:
        first = Divergence(0, 0, 0, EventKind.INIT, worst, _PRIOR_HINT)

    for event, step, kind, log_event in numbered(events):
        if first is not None and stop_at_divergence:
            break
        before = _state(slam)
        ekf = EkfSlam.from_state(params, before.x, before.P, before.ids, compiled=False)
        line, time = log_event.line, log_event.time
        try:
            if isinstance(log_event, Control):
                control = (log_event.d, log_event.alpha)
                ekf.predict(*control)
                slam.predict(*control)
                for target, source in ((reference, ekf), (records, slam)):
                    target.append(source.record(event=event, step=step, kind=kind, line=line,
                                                time=time, control=control))  # fmt: skip
            else:
                expected = ekf.observe(log_event.ids, log_event.z)
                got = slam.observe(log_event.ids, log_event.z)
                for target, source, seen in ((reference, ekf, expected), (records, slam, got)):
                    target.append(source.record(event=event, step=step, kind=kind, line=line,
                                                time=time, observations=seen))  # fmt: skip
        except PluginError as error:
            raise FilterLineError(
                log_event.line, f"event {event} ({kind.value}): {error}"
            ) from error
        after = _state(slam)
        worst = compare(_state(ekf), after)
        differences.append(0.0 if worst is None else worst.difference)
        if first is None and worst is not None and worst.difference > tolerance:
            hint = explain(params, before, after, log_event, worst, tolerance)
            first = Divergence(event, step, log_event.line, kind, worst, hint)
    return CheckResult(
        events_checked=len(differences),
        max_difference=max(differences, default=0.0),
        tolerance=tolerance,
        first_divergence=first,
        records=tuple(records),
        reference=tuple(reference),
        differences=tuple(differences),
    )


def numbered(events: Iterable[LogEvent]) -> Iterator[tuple[int, int, EventKind, LogEvent]]:
    """Each event with its event number, step and kind, as the runner numbers them.

    The first line, when it is an observation, is event 0 (``init``); every control
    starts a step; an observation is the update of its step, or starts a step of its own
    when the step already had one.
    """
    step, event, step_has_update = 0, 0, True
    for index, log_event in enumerate(events):
        if index == 0 and isinstance(log_event, Sighting):
            yield 0, 0, EventKind.INIT, log_event
            continue
        event += 1
        if isinstance(log_event, Control):
            step += 1
            step_has_update = False
            yield event, step, EventKind.PREDICT, log_event
        else:
            if step_has_update:
                step += 1
            step_has_update = True
            yield event, step, EventKind.UPDATE, log_event


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
    # the filter's state reordered to the reference's landmark order
    where = {int(i): k for k, i in enumerate(got.ids.tolist())}
    order = [0, 1, 2]
    for landmark_id in expected.ids.tolist():
        k = 3 + 2 * where[int(landmark_id)]
        order += [k, k + 1]
    x, P = got.x[order], got.P[np.ix_(order, order)]
    dx = x - expected.x
    dx[2] = wrap_angle(float(dx[2]))
    scale_x = np.maximum(1.0, np.abs(expected.x))
    scale_P = np.maximum(1.0, np.abs(expected.P))
    scaled_x = np.abs(dx) / scale_x
    scaled_P = np.abs(P - expected.P) / scale_P
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


@dataclass(frozen=True, slots=True)
class Mistake:
    """A classic mistake, re-run from the same state to see if it explains a divergence.

    :param run: the event applied with the mistake: (params, before, event) -> after
    """

    hint: str
    run: Callable[[FilterParams, State, LogEvent], State]


def _dense_predict(
    params: FilterParams, s: State, d: float, alpha: float, *, heading: float = 1.0,
    rotate: bool = True, noise: bool = True, turn_first: bool = False,
) -> State:  # fmt: skip
    n = len(s.x)
    x, P = s.x.copy(), s.P.copy()
    theta = float(x[2])
    along = theta + alpha if turn_first else theta
    x[0] += d * math.cos(along)
    x[1] += d * math.sin(along)
    x[2] = wrap_angle(theta + alpha)
    G = np.eye(n)
    G[0, 2], G[1, 2] = -heading * d * math.sin(theta), heading * d * math.cos(theta)
    c, sn = math.cos(theta), math.sin(theta)
    W = np.array([[c, -sn, 0.0], [sn, c, 0.0], [0.0, 0.0, 1.0]])
    P = G @ P @ G.T
    if noise:
        P[:3, :3] += W @ params.Q @ W.T if rotate else params.Q
    return State(x, P, s.ids)


def _dense_update(
    params: FilterParams, s: State, ids: IntArray, z: FloatArray, *, add_R: bool = True,
    wrap: bool | str = True, init_R: bool = True, init_in_order: bool = False,
) -> State:  # fmt: skip
    x, P, state_ids = s.x.copy(), s.P.copy(), [int(i) for i in s.ids]
    R = params.R

    def add(landmark_id: int, bearing: float, rng: float) -> None:
        nonlocal x, P
        n = len(x)
        phi = x[2] + bearing
        J_p = np.array([[1.0, 0.0, -rng * math.sin(phi)], [0.0, 1.0, rng * math.cos(phi)]])
        J_z = np.array(
            [[-rng * math.sin(phi), math.cos(phi)], [rng * math.cos(phi), math.sin(phi)]]
        )
        grown = np.zeros((n + 2, n + 2))
        grown[:n, :n] = P
        grown[n:, n:] = J_p @ P[:3, :3] @ J_p.T + (J_z @ R @ J_z.T if init_R else 0.0)
        if params.landmark_init is LandmarkInit.CORRELATED:
            grown[n:, :n] = J_p @ P[:3, :]
            grown[:n, n:] = grown[n:, :n].T
        P = grown
        x = np.concatenate([x, [x[0] + rng * math.cos(phi), x[1] + rng * math.sin(phi)]])
        state_ids.append(landmark_id)

    new = []
    for landmark_id, (bearing, rng) in zip(ids.tolist(), z.tolist(), strict=True):
        if landmark_id not in state_ids:
            if init_in_order:
                add(landmark_id, bearing, rng)
            else:
                new.append((landmark_id, bearing, rng))
            continue
        j = 3 + 2 * state_ids.index(landmark_id)
        dx, dy = x[j] - x[0], x[j + 1] - x[1]
        q = dx * dx + dy * dy
        r = math.sqrt(q)
        H = np.zeros((2, len(x)))
        H[:, :3] = [[dy / q, -dx / q, -1.0], [-dx / r, -dy / r, 0.0]]
        H[:, j : j + 2] = [[-dy / q, dx / q], [dx / r, dy / r]]
        S = H @ P @ H.T + (R if add_R else 0.0)
        K = np.linalg.solve(S, H @ P).T
        nu = np.array([bearing - (math.atan2(dy, dx) - x[2]), rng - r])
        if wrap is True:
            nu[0] = wrap_angle(float(nu[0]))
        elif wrap == "prediction":  # the prediction wrapped, the innovation not
            nu[0] = bearing - wrap_angle(math.atan2(dy, dx) - x[2])
        x = x + K @ nu
        if wrap is not False:  # a filter that wraps nothing keeps its heading unwrapped too
            x[2] = wrap_angle(float(x[2]))
        I_KH = np.eye(len(x)) - K @ H
        P = I_KH @ P @ I_KH.T + K @ R @ K.T  # Joseph's form: what most course code writes
    for landmark_id, bearing, rng in new:
        add(landmark_id, bearing, rng)
    return State(x, P, np.array(state_ids, dtype=np.int64))


def _with(**changes: object) -> Callable[[FilterParams, State, LogEvent], State]:
    """The reference itself, with other parameters (update mode, landmark init)."""

    def run(base: FilterParams, s: State, event: LogEvent) -> State:
        ekf = EkfSlam.from_state(replace(base, **changes), s.x, s.P, s.ids, compiled=False)  # type: ignore[arg-type]
        assert isinstance(event, Sighting)
        ekf.observe(event.ids, event.z)
        return _state(ekf)

    return run


def _predict_with(**options: object) -> Callable[[FilterParams, State, LogEvent], State]:
    def run(params: FilterParams, s: State, event: LogEvent) -> State:
        assert isinstance(event, Control)
        return _dense_predict(params, s, event.d, event.alpha, **options)  # type: ignore[arg-type]

    return run


def _update_with(**options: object) -> Callable[[FilterParams, State, LogEvent], State]:
    def run(params: FilterParams, s: State, event: LogEvent) -> State:
        assert isinstance(event, Sighting)
        return _dense_update(params, s, event.ids, event.z, **options)  # type: ignore[arg-type]

    return run


PREDICT_MISTAKES: tuple[Mistake, ...] = (
    Mistake("the heading column of the motion Jacobian G has the wrong sign: it is"
            " [-d sin(theta), d cos(theta), 1]", _predict_with(heading=-1.0)),
    Mistake("the motion Jacobian G lacks its heading column (-d sin(theta), d cos(theta)):"
            " G is the identity", _predict_with(heading=0.0)),
    Mistake("the motion noise is not rotated into the world frame: add W Q W^T, not Q"
            " (Q is in the robot frame: along the heading, sideways, turn)",
            _predict_with(rotate=False)),
    Mistake("the motion noise is missing: P_rr' = G P_rr G^T + W Q W^T",
            _predict_with(noise=False)),
    Mistake("the robot turns before it drives: it drives d along the old heading, then"
            " turns alpha", _predict_with(turn_first=True)),
)  # fmt: skip

UPDATE_MISTAKES: tuple[Mistake, ...] = (
    Mistake("R is missing from the innovation covariance: S = H P H^T + R",
            _update_with(add_R=False)),
    Mistake("the bearing innovation is not wrapped: wrap z - z_pred to (-pi, pi] before"
            " using it", _update_with(wrap="prediction")),
    Mistake("the bearing innovation is not wrapped: wrap z - z_pred to (-pi, pi] before"
            " using it (here neither the predicted bearing nor the difference is)",
            _update_with(wrap=False)),
    Mistake("a new landmark is initialised without its cross-covariances to the pose and"
            " the map (P_lx = J_p P_px); --landmark-init independent reproduces this",
            _with(landmark_init=LandmarkInit.INDEPENDENT)),
    Mistake("a new landmark's covariance lacks the measurement noise: P_ll = J_p P_pp J_p^T"
            " + J_z R J_z^T", _update_with(init_R=False)),
    Mistake("the landmarks of the line are folded in all at once, the reference folds them"
            " one after another in file order; --update joint reproduces this",
            _with(update=UpdateMode.JOINT)),
    Mistake("a new landmark is initialised where it comes in the line, from the pose"
            " before the known landmarks after it corrected it; the reference initialises"
            " new landmarks after the known ones", _update_with(init_in_order=True)),
)  # fmt: skip

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
) -> str:
    """The likely cause of a divergence at ``event``: a classic mistake that reproduces
    the filter's result from the same state, else where the quantity comes from."""
    if worst.quantity is Quantity.LANDMARK_IDS:
        return (
            "the filter's landmark_ids differ from the observed landmarks: every id of an"
            " update must be in the state afterwards, new ones appended in the order seen"
        )
    kind = "predict" if isinstance(event, Control) else "update"
    if len(before.x) <= HYPOTHESIS_MAX_DIM:
        # a mistake explains the divergence when it reproduces the filter's whole state or,
        # where the mean differs, its mean (a covariance may differ by the form of its update)
        mean_differs = worst.quantity in (Quantity.POSE_MEAN, Quantity.LANDMARK_MEAN)
        close = max(tolerance, 1e-9) * 10
        mistakes = PREDICT_MISTAKES if kind == "predict" else UPDATE_MISTAKES
        for mistake in mistakes:
            try:
                candidate = mistake.run(params, before, event)
            except (ValueError, np.linalg.LinAlgError, ZeroDivisionError):
                continue
            found = compare(candidate, after)
            if found is None or found.difference <= close:
                return mistake.hint
            if mean_differs and len(candidate.x) == len(after.x):
                means = compare(State(candidate.x, after.P, candidate.ids), after)
                if means is None or means.difference <= close:
                    return mistake.hint
    pattern = _PATTERN_HINTS.get((kind, worst.quantity))
    if pattern is not None:
        return pattern
    if worst.quantity in (Quantity.POSE_MEAN, Quantity.LANDMARK_MEAN):
        return (
            "the corrected mean: the innovation z - h(x) (bearing first, wrapped), the"
            " measurement Jacobian H and the gain K = P H^T S^-1"
        )
    newly = (
        isinstance(event, Sighting)
        and worst.landmark_id is not None
        and (worst.landmark_id not in before.ids.tolist())
    )
    if newly:
        return (
            "the initialisation of a new landmark: l = pose + r (cos(theta + beta),"
            " sin(theta + beta)), P_ll = J_p P_pp J_p^T + J_z R J_z^T, P_lx = J_p P_px"
        )
    return (
        "the covariance update: P - K S K^T (or Joseph's form) with S = H P H^T + R and"
        " H's five non-zero columns (pose, and the landmark's two)"
    )
