"""The bookkeeping of the recorder's array API: a filter of the user's own hands in x,
P and what it observed; this turns them into the batches a replay would make, numbered
as a replay numbers its events (:class:`~ekfviz.core.steps.StepCounter`)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ekfviz.core.batch import INIT, PREDICT, BatchBuilder, Extras
from ekfviz.core.correlation import Correlation, CorrelationCadence, correlation_of
from ekfviz.core.health import CovarianceCheck, check_covariance, check_interval
from ekfviz.core.records import Observations
from ekfviz.core.steps import StepCounter
from ekfviz.core.types import FloatArray, IntArray
from ekfviz.models.angles import wrap_angles

CHECK_ALL_DIM = 64  # the array API checks a covariance up to this size at every call


def state_arrays(x: object, P: object) -> tuple[FloatArray, FloatArray]:
    """``x`` (3+2N,) and ``P`` (3+2N, 3+2N) as float arrays; a column x (3+2N, 1) is taken.

    :raises ValueError: naming the array, its shape and what was expected
    """
    try:
        x_arr = np.asarray(x, dtype=np.float64)
        P_arr = np.asarray(P, dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise ValueError(f"x and P: expected arrays of numbers ({error})") from None
    if x_arr.ndim == 2 and x_arr.shape[1] == 1:
        x_arr = x_arr[:, 0]
    n = x_arr.shape[0] if x_arr.ndim == 1 else 0
    if x_arr.ndim != 1 or n < 3 or (n - 3) % 2:
        raise ValueError(
            f"x has shape {x_arr.shape}, expected (3+2N,): x, y, theta, then the landmarks"
        )
    if P_arr.shape != (n, n):
        raise ValueError(f"P has shape {P_arr.shape}, expected ({n}, {n}) to match x")
    if not np.isfinite(x_arr).all():
        raise ValueError(f"x is not finite (entry {int(np.argmin(np.isfinite(x_arr)))})")
    if not np.isfinite(P_arr).all():
        raise ValueError("P is not finite")
    return x_arr, P_arr


class ArrayInput:
    """Landmark ids, observations, covariance checks and correlations from plain arrays.

    :param landmark_ids: (N,) ids of the state's landmarks in state order, if known up
        front; otherwise the order of first sighting, and 1..N when no ids are given
    """

    def __init__(self, landmark_ids: Sequence[int] | IntArray | None) -> None:
        # (not "if landmark_ids": an array's truth is ambiguous)
        self.order: list[int] = [] if landmark_ids is None else [int(i) for i in landmark_ids]
        self._in_order: set[int] = set(self.order)
        self._seen: set[int] = set()  # ids observed so far through the array API
        self._correlation = CorrelationCadence()  # (a replay's batches own theirs)
        self.checked_step: int | None = None  # of the last covariance check
        self._round_off_said = False  # a round-off asymmetry of P is a warning once a run
        self.counter = StepCounter()
        self.builder = BatchBuilder()  # the states handed in, not logged yet

    def state_ids(self, x: FloatArray) -> IntArray:
        """The ids of the landmarks of ``x``, in state order."""
        n = (len(x) - 3) // 2
        if len(self.order) < n:
            start = max(self.order, default=0) + 1
            self.order += range(start, start + n - len(self.order))
            self._in_order.update(self.order)
        return np.asarray(self.order[:n], dtype=np.int64)

    def add(
        self,
        x: object,
        P: object,
        kind: int,
        line: int,
        observations: Observations | None = None,
        control: FloatArray | None = None,
    ) -> None:
        """Append a state handed in to :attr:`builder`, numbered as the next event of
        ``kind`` (``INIT`` starts over), its covariance checked as a replay checks its
        own, with the correlation matrix where due (at an initialisation or update).

        :raises ValueError: ``x`` or ``P`` of the wrong shape or not finite, a control that
            is not (d, alpha): said here, not later where the recording is finished
        """
        x, P = state_arrays(x, P)
        if control is not None and control.shape != (2,):
            raise ValueError(f"control has shape {control.shape}, expected (2,): (d, alpha)")
        if kind == INIT:
            self.checked_step = None
            event, step = self.counter.initialise()
        else:
            event, step = self.counter.count(kind == PREDICT)
        ids = self.state_ids(x)
        covariance, warnings = self.check(P, step)
        correlation: Correlation | None = None
        if kind != PREDICT and self._correlation.due(step, len(ids), last=False):
            correlation = correlation_of(P, ids)
        extras = None
        if warnings or covariance is not None or correlation is not None:
            extras = Extras(warnings, covariance, correlation)
        self.builder.add_state(
            x, P, landmark_ids=ids, event=event, step=step, kind=kind, line=line,
            control=None if control is None else (float(control[0]), float(control[1])),
            observations=observations, extras=extras,
        )  # fmt: skip

    def check(self, P: FloatArray, step: int) -> tuple[CovarianceCheck | None, tuple[str, ...]]:
        """The check of a whole covariance handed in through the array API and the
        problems it found: at every call while it is small (``CHECK_ALL_DIM``), else as
        often as a replay checks its own."""
        P = np.asarray(P, dtype=np.float64)
        dim = P.shape[0]
        if (
            dim > CHECK_ALL_DIM
            and self.checked_step is not None
            and step - self.checked_step < check_interval(dim)
        ):
            return None, ()
        self.checked_step = step
        check = check_covariance(P)
        problems = check.problems(round_off=not self._round_off_said)
        self._round_off_said |= check.round_off_asymmetry
        return check, tuple(problems)

    def observations(
        self,
        landmark_ids: Sequence[int] | IntArray | None,
        z: FloatArray | None,
        z_pred: FloatArray | None,
        S: FloatArray | None,
    ) -> Observations | None:
        """Build what an update did from plain arrays; ids not met before are new."""
        if landmark_ids is None or z is None:
            return None
        try:
            ids = np.asarray(landmark_ids, dtype=np.int64).reshape(-1)
        except (OverflowError, ValueError, TypeError) as error:
            raise ValueError(f"landmark_ids: expected 64-bit integers ({error})") from None
        m = len(ids)
        z = np.asarray(z, dtype=np.float64)
        if z.size != 2 * m:
            raise ValueError(
                f"z has {z.size} numbers, expected {m} (bearing, range) pairs, one for each of"
                f" the {m} landmark ids"
            )
        z = z.reshape(m, 2)
        for name, given, size in (("z_pred", z_pred, 2 * m), ("S", S, 4 * m)):
            if given is not None and np.asarray(given).size != size:
                raise ValueError(
                    f"{name} has {np.asarray(given).size} numbers, expected {size} for the"
                    f" {m} landmark ids"
                )
        initialised = np.array([i not in self._seen for i in ids.tolist()], dtype=bool)
        for landmark_id in ids[initialised].tolist():
            self._seen.add(landmark_id)
            if landmark_id not in self._in_order:
                self.order.append(landmark_id)
                self._in_order.add(landmark_id)
        nan2 = np.full((m, 2), np.nan)
        z_pred = nan2.copy() if z_pred is None else np.asarray(z_pred, np.float64).reshape(m, 2)
        innovation = z - z_pred
        innovation[:, 0] = wrap_angles(innovation[:, 0])
        S = np.full((m, 2, 2), np.nan) if S is None else np.asarray(S, np.float64).reshape(m, 2, 2)
        nis = np.full(m, np.nan)
        known = ~initialised & np.isfinite(innovation).all(axis=1) & np.isfinite(S).all(axis=(1, 2))
        if known.any():
            whitened = np.linalg.solve(S[known], innovation[known][:, :, None])[:, :, 0]
            nis[known] = np.einsum("ij,ij->i", innovation[known], whitened)
        z_pred[initialised] = innovation[initialised] = np.nan
        S[initialised] = np.nan
        return Observations.of(
            ids=ids, z=z, z_pred=z_pred, innovation=innovation, S=S, nis=nis,
            initialised=initialised, skipped=np.zeros(m, dtype=bool),
        )  # fmt: skip
