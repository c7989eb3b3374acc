"""One event re-run from a filter's state over the named operations, with mutations.

:class:`Rerun` applies a predict or an update (a new landmark's initialisation is part of
an update) the way the reference does, dense and step by step: every operation of
:mod:`ekfviz.check.operations` is one :meth:`Rerun.call` of a named operation of
:mod:`ekfviz.models`. A mutation (:mod:`ekfviz.check.mutations`) replaces one call with
what a mistaken line of code computes; a re-run with no mutation is the reference.

The dense algebra is for the states ``check`` re-runs (up to a few hundred entries).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from ekfviz.core.types import FloatArray, IntArray
from ekfviz.models.angles import wrap_angle
from ekfviz.models.classic import (
    expected_measurement,
    init_jacobian_measurement,
    init_jacobian_pose,
    innovation,
    landmark_from_measurement,
    landmark_offset,
    measurement_jacobian_landmark,
    measurement_jacobian_pose,
    motion,
    motion_jacobian,
    noise_jacobian,
)
from ekfviz.models.kalman import (
    corrected_covariance,
    corrected_mean,
    innovation_covariance,
    kalman_gain,
    new_landmark_covariance,
    new_landmark_cross_covariance,
    predicted_cross_covariance,
    predicted_pose_covariance,
)


class Mutation(Protocol):
    """What a re-run asks of a mutation (see :class:`ekfviz.check.operators.Mutation`):
    the operation it replaces, its name, and what it makes of the operation's call."""

    @property
    def operation(self) -> str: ...

    @property
    def name(self) -> str: ...

    def apply(
        self, rerun: Rerun, function: Callable[..., Any], operands: tuple[Any, ...]
    ) -> Any: ...


# the factor of a scaled noise (see ekfviz.check.scaling) where the search has fitted none:
# the probes' and a bare re-run's, far from 1 as the mistakes are (10 R, R / 10)
PROBE_SCALE = 10.0

# what a re-run may raise on a state it does not fit (a singular S, a landmark at the
# robot, an index past the state): that mutation does not reproduce the event
RERUN_ERRORS = (ValueError, IndexError, ArithmeticError, np.linalg.LinAlgError)


@dataclass(frozen=True, slots=True)
class State:
    """A filter state: x (3+2N,), P (3+2N, 3+2N), landmark ids (N,) in state order."""

    x: FloatArray
    P: FloatArray
    ids: IntArray

    def in_order_of(self, ids: IntArray) -> tuple[FloatArray, FloatArray]:
        """x and P with the landmarks in the order of ``ids`` (the same landmarks, e.g.
        another state's), to compare entry by entry.

        :raises KeyError: an id of ``ids`` that this state has not
        """
        where = {int(i): k for k, i in enumerate(self.ids.tolist())}
        index = [0, 1, 2]
        for landmark_id in ids.tolist():
            k = 3 + 2 * where[int(landmark_id)]
            index += [k, k + 1]
        return self.x[index], self.P[np.ix_(index, index)]


@dataclass(frozen=True, slots=True)
class Step:
    """An event as a re-run applies it: a control (d, alpha), or a line of landmarks
    ``ids`` (m,) seen at ``z`` (m, 2) (bearing, range)."""

    d: float = 0.0
    alpha: float = 0.0
    ids: IntArray | None = None
    z: FloatArray | None = None

    @property
    def is_predict(self) -> bool:
        return self.ids is None


@dataclass(frozen=True, slots=True)
class Noise:
    """The run's noise (Q 3x3, R 2x2), and the Q and R the filter declares as its own
    (``motion_noise``, ``measurement_noise``; None where it declares none)."""

    Q: FloatArray
    R: FloatArray
    declared_motion: FloatArray | None = None
    declared_measurement: FloatArray | None = None


@dataclass(frozen=True, slots=True)
class Form:
    """How a filter may write what is one update of a right gain: not a mistake.

    :param joint: every known landmark of a line at once (one stacked H, S, K)
    :param covariance: ``ikh`` ((I - K H) P), ``sks`` (P - K S K^T) or ``joseph``
        ((I - K H) P (I - K H)^T + K R K^T): equal for a right K, not for a wrong one
    :param wrap_h: h(x)'s bearing wrapped (or left atan2(dy, dx) - theta), and
    :param wrap_heading: the corrected heading wrapped (or left theta + (K nu)_theta): the
        innovation's wrap makes them the same, unless a mistake moves an unwrapped angle
        where no wrap meets it
    :param symmetric: P made symmetric after each landmark's correction (or left as the
        correction makes it: the same, unless a mistake makes it asymmetric)
    """

    joint: bool = False
    covariance: str = "ikh"
    wrap_h: bool = True
    wrap_heading: bool = True
    symmetric: bool = True


FORMS = (Form(False, "ikh"), Form(False, "sks"), Form(False, "joseph"))


@dataclass(slots=True)
class Rerun:
    """A re-run of one event with ``mutations`` (at most one per operation).

    :param target: the filter's own state after the event, which a mutation that reads
        a quantity off the filter's result (its own Q, a constant landmark covariance)
        needs
    :param scale: the factor k of a scaled-noise mutation (k R, k Q)
    """

    noise: Noise
    mutations: dict[str, Mutation] = field(default_factory=dict)
    form: Form = field(default_factory=Form)
    target: State | None = None
    scale: float = PROBE_SCALE
    # the event's context, which mutations read (stale operands, fitted quantities)
    before: State | None = None
    control: tuple[float, float] = (0.0, 0.0)
    moved: FloatArray = field(default_factory=lambda: np.zeros(3))
    G: FloatArray = field(default_factory=lambda: np.eye(3))
    W: FloatArray = field(default_factory=lambda: np.eye(3))
    x_line: FloatArray = field(default_factory=lambda: np.zeros(3))
    P_line: FloatArray = field(default_factory=lambda: np.zeros((3, 3)))
    line_size: int = 3
    new_ids: list[int] = field(default_factory=list)

    @classmethod
    def with_mutations(
        cls,
        noise: Noise,
        mutations: Iterable[Mutation],
        form: Form,
        target: State | None,
        scale: float = PROBE_SCALE,
    ) -> Rerun:
        return cls(noise, {m.operation: m for m in mutations}, form, target, scale)

    def call(self, operation: str, function: Callable[..., Any], *operands: Any) -> Any:
        """``function(*operands)``, or what the mutation of ``operation`` makes of it."""
        mutation = self.mutations.get(operation)
        if mutation is None:
            return function(*operands)
        return mutation.apply(self, function, operands)

    def run(self, s: State, step: Step) -> State:
        """The event ``step`` from ``s``."""
        if step.ids is None or step.z is None:
            return self.predict(s, step.d, step.alpha)
        return self.update(s, step.ids, step.z)

    def mutated(self, operation: str, name: str) -> bool:
        mutation = self.mutations.get(operation)
        return mutation is not None and mutation.name == name

    # -- predict -----------------------------------------------------------------------------

    def predict(self, s: State, d: float, alpha: float) -> State:
        """Drive ``d``, turn ``alpha`` from ``s``: P_rr' = G P_rr G^T + W Q W^T,
        P_rm' = G P_rm, the pose by the motion model."""
        self.before = s
        d, alpha = self.call("control", _control, d, alpha)
        self.control = (d, alpha)
        x, P = s.x.copy(), s.P.copy()
        pose = s.x[:3].copy()
        self.moved = motion(pose, d, alpha)
        at = self.call("linearisation_pose", _same, pose)
        G = self.G = self.call("motion_jacobian", motion_jacobian, at, d)
        W = self.W = self.call("noise_jacobian", noise_jacobian, at)
        Q = self.call("motion_noise", _same, self.noise.Q)
        x[:3] = self.call("motion", motion, pose, d, alpha)
        if len(x) > 3:
            P_rm = self.call("cross_covariance", predicted_cross_covariance, G, s.P[:3, 3:])
            P[:3, 3:] = P_rm
            P[3:, :3] = P_rm.T
        P[:3, :3] = self.call("pose_covariance", predicted_pose_covariance, s.P[:3, :3], G, W, Q)
        return State(x, _symmetric(P), s.ids)

    # -- update ------------------------------------------------------------------------------

    def update(self, s: State, ids: IntArray, z: FloatArray) -> State:
        """Fold the line ``ids``/``z`` ((m, 2) bearing, range) into ``s``: the known
        landmarks one after another in line order (or jointly), then the new ones
        initialised from the corrected pose, in line order."""
        self.before = s
        flat = np.asarray(z, dtype=np.float64).reshape(-1)
        pairs = self.call("measurement", _pairs, flat)
        first = self.call("init_measurement", _pairs, flat)
        x, P = s.x.copy(), s.P.copy()
        state_ids = [int(i) for i in s.ids.tolist()]
        self.x_line, self.P_line, self.line_size = x.copy(), P.copy(), len(x)
        line = [int(i) for i in ids.tolist()]
        slot = {landmark_id: 3 + 2 * k for k, landmark_id in enumerate(state_ids)}
        known = self.call("update_loop", _same, [k for k, i in enumerate(line) if i in slot])
        new = [k for k, i in enumerate(line) if i not in slot]
        self.new_ids = [line[k] for k in new]
        if self.form.joint:
            if known:
                x, P = self._correct(x, P, [(pairs[k], slot[line[k]]) for k in known])
            order = new
        elif self.mutated("update_loop", "init_in_line_order"):
            order = sorted(known + new)
        else:
            order = known + new
        for k in order:
            if k in new:
                x, P = self._add(x, P, first[k])
                state_ids.append(line[k])
                if self.mutated("update_loop", "update_at_init") and not self.form.joint:
                    x, P = self._correct(x, P, [(pairs[k], len(x) - 2)])
            elif not self.form.joint:
                x, P = self._correct(x, P, [(pairs[k], slot[line[k]])])
        if self.new_ids and self.mutated("landmark_cross_covariance", "pose_part_skipped"):
            start = len(s.x)  # the new landmarks keep their covariances among themselves
            P[start:, :start] = 0.0
            P[:start, start:] = 0.0
        return State(x, _symmetric(P), np.array(state_ids, dtype=np.int64))

    def _correct(
        self, x: FloatArray, P: FloatArray, rows: Sequence[tuple[FloatArray, int]]
    ) -> tuple[FloatArray, FloatArray]:
        """One correction with the landmarks of ``rows`` ((bearing, range), the slot of its
        x): one landmark, or all of a joint line stacked."""
        n = len(x)
        stale = self.mutated("update_loop", "stale_linearisation")
        # (a landmark initialised in this line is linearised where it was put)
        at = np.concatenate([self.x_line, x[self.line_size :]]) if stale else x
        H_rows, nu_rows = [], []
        for z_i, j in rows:
            offset = self.call("landmark_offset", _offset_at, at, j)
            h = self.call("expected_measurement", self._expected, offset, float(at[2]))
            H_p = self.call("measurement_jacobian_pose", measurement_jacobian_pose, offset)
            H_l = self.call("measurement_jacobian_landmark", measurement_jacobian_landmark, offset)
            H_rows.append(self.call("measurement_jacobian", _full_jacobian, H_p, H_l, j, n))
            nu_rows.append(self.call("innovation", innovation, z_i, h))
        H = H_rows[0] if len(rows) == 1 else np.vstack(H_rows)
        nu = nu_rows[0] if len(rows) == 1 else np.concatenate(nu_rows)
        R = self.call("measurement_noise", _same, self.noise.R)
        R_all = R if len(rows) == 1 else _block_diagonal(R, len(rows))
        P_gain = P
        if self.mutated("update_loop", "stale_covariance"):
            if self.P_line.shape != P.shape:
                raise IndexError("the state grew within the line")
            P_gain = self.P_line
        S = self.call("innovation_covariance", self._innovation_covariance, H, P_gain, R_all)
        K = self.call("kalman_gain", _gain, P_gain, H, S)
        heading = float(x[2])
        x = self.call("corrected_mean", corrected_mean, x, K, nu)
        if not self.form.wrap_heading:  # theta + (K nu)_theta as it is, however far
            turn = float((K @ nu)[2])
            x[2] = heading + turn + wrap_angle(float(x[2]) - heading - turn)
        P = self.call("corrected_covariance", self._covariance_update, P, K, S, H, R_all)
        return x, _symmetric(P) if self.form.symmetric else P

    def _innovation_covariance(self, H: FloatArray, P: FloatArray, R: FloatArray) -> FloatArray:
        """S, symmetrised where the filter keeps P symmetric (see :class:`Form`)."""
        return innovation_covariance(H, P, R, symmetrised=self.form.symmetric)

    def _expected(self, offset: FloatArray, theta: float) -> FloatArray:
        """h(x), its bearing wrapped or not as the filter's form has it."""
        h = expected_measurement(offset, theta)
        if not self.form.wrap_h:
            h[..., 0] = np.arctan2(offset[..., 1], offset[..., 0]) - theta
        return h

    def _covariance_update(
        self, P: FloatArray, K: FloatArray, S: FloatArray, H: FloatArray, R: FloatArray
    ) -> FloatArray:
        """P after an update, in the form the filter writes it (see :class:`Form`)."""
        if self.form.covariance == "sks":
            return corrected_covariance(P, K, S)
        IKH = np.eye(len(P)) - K @ H
        if self.form.covariance == "joseph":
            return _symmetric(IKH @ P @ IKH.T + K @ R @ K.T)
        return _symmetric(IKH @ P)

    def _add(self, x: FloatArray, P: FloatArray, z_i: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Append a landmark first seen at ``z_i`` = (bearing, range)."""
        n = len(x)
        pose = self.call("init_pose", _same, x[:3])
        landmark = self.call("landmark_position", landmark_from_measurement, pose, z_i)
        J_p = self.call("init_jacobian_pose", init_jacobian_pose, pose, z_i)
        J_z = self.call("init_jacobian_measurement", init_jacobian_measurement, pose, z_i)
        R = self.call("measurement_noise", _same, self.noise.R)
        grown = np.zeros((n + 2, n + 2))
        grown[:n, :n] = P
        grown[n:, :n] = self.call(
            "landmark_cross_covariance", new_landmark_cross_covariance, J_p, P[:3, :]
        )
        grown[:n, n:] = grown[n:, :n].T
        grown[n:, n:] = self.call(
            "landmark_covariance", new_landmark_covariance, J_p, P[:3, :3], J_z, R
        )
        return np.concatenate([x, landmark]), grown


def _same(value: Any) -> Any:
    return value


def _control(d: float, alpha: float) -> tuple[float, float]:
    return d, alpha


def _pairs(flat: FloatArray) -> FloatArray:
    """The (bearing, range) pairs (m, 2) of a line as a log holds them, interleaved."""
    return flat.reshape(-1, 2)


def _offset_at(x: FloatArray, j: int) -> FloatArray:
    """The offset of the landmark whose x is at ``j`` in the state ``x`` from its pose."""
    if not 3 <= j <= len(x) - 2:
        raise IndexError(f"no landmark at {j} in a state of {len(x)}")
    return landmark_offset(x[:3], x[j : j + 2])


def _gain(P: FloatArray, H: FloatArray, S: FloatArray) -> FloatArray:
    return kalman_gain(P @ H.T, S)


def _full_jacobian(H_p: FloatArray, H_l: FloatArray, j: int, n: int) -> FloatArray:
    """H (2, n): H_p over the pose's columns and H_l over the landmark's (j, j + 1)."""
    H = np.zeros((2, n))
    H[:, :3] = H_p
    H[:, j : j + 2] = H_l
    return H


def _block_diagonal(R: FloatArray, m: int) -> FloatArray:
    """R (2, 2) ``m`` times on the diagonal of a (2 m, 2 m) matrix."""
    blocks = np.zeros((2 * m, 2 * m))
    for k in range(m):
        blocks[2 * k : 2 * k + 2, 2 * k : 2 * k + 2] = R
    return blocks


def _symmetric(P: FloatArray) -> FloatArray:
    symmetric: FloatArray = 0.5 * (P + P.T)
    return symmetric
