"""Run any :class:`~ekfviz.filters.protocol.SlamFilter` as the runner runs the built-in EKF.

A protocol filter only shows its state. :class:`Plugged` wraps it, checks what it shows
after every event (shapes, finiteness, symmetry, landmark ids) and derives what the
built-in filter reports itself: for every observation of an update, the prediction,
innovation, innovation covariance S = H P H^T + R and NIS, by running ekfviz's own update
(:class:`~ekfviz.filters.ekf.EkfSlam`, with the run's parameters: sequential or joint)
from the filter's state just before the update. A correct filter thus gets the very
numbers the built-in one reports, and a wrong one the numbers its prior state implies.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np

from ekfviz.core.batch import MapParts, StateParts
from ekfviz.core.errors import FilterError
from ekfviz.core.params import FilterParams
from ekfviz.core.records import Observations, frozen
from ekfviz.core.types import FloatArray, IntArray
from ekfviz.filters.ekf import EkfSlam
from ekfviz.filters.ekf_update import nan_table
from ekfviz.filters.protocol import DeclaresCapabilities, SlamFilter, state_of

# P counts as symmetric when |P - P^T| <= SYMMETRY_TOLERANCE * max |P|. A filter that
# never symmetrises P (a Joseph form, G P G^T) drifts from it by rounding that adds up,
# and grows, event after event (1e-8 after 60 updates of a loop): a drift is let be up to
# SYMMETRY_DRIFT_LIMIT (where the filter's numbers start to differ by the check's
# tolerance), and said once; a P symmetric before the event that is asymmetric by more
# than SYMMETRY_STEP_TOLERANCE after it is a wrong formula (K of another P, G on one side)
SYMMETRY_TOLERANCE = 1e-9
SYMMETRY_STEP_TOLERANCE = 1e-7
SYMMETRY_DRIFT_LIMIT = 1e-6

FilterFactory = Callable[[FilterParams], SlamFilter]


class PluginError(FilterError):
    """A protocol filter raised, or showed a state that is not one; says which and why."""


class Plugged:
    """A protocol filter behind the interface the runner uses for the built-in EKF.

    :param slam: the filter, already constructed
    :param name: how messages name it (``--filter`` as given)
    :param params: its parameters (R for the derived innovation covariances)
    """

    def __init__(self, slam: SlamFilter, name: str, params: FilterParams) -> None:
        self.slam = slam
        self.name = name
        self._warnings: tuple[str, ...] = ()
        self._asymmetry = 0.0  # |P - P^T| / max |P| of the filter's last state
        self._drift_said = False  # that P drifts from symmetric: said once, at an update
        if isinstance(slam, DeclaresCapabilities):
            capabilities = slam.capabilities
            self._predict_takes_dt = capabilities.takes_dt
            self._removes = capabilities.removes_landmarks
            self._offline = capabilities.offline
        else:
            self._predict_takes_dt = _takes_dt(getattr(slam, "predict", None))
            self._removes = callable(getattr(slam, "remove_landmarks", None))
            self._offline = callable(getattr(slam, "finish", None))
        self._params, self.own_noise = _with_own_noise(slam, name, params)
        self._x, self._P, self._ids = self._state("construction")
        self._last_map: MapParts | None = None  # the map state_parts gave last

    # -- what the runner reads ----------------------------------------------------------

    @property
    def x(self) -> FloatArray:
        return self._x

    @property
    def P(self) -> FloatArray:
        return self._P

    @property
    def dim(self) -> int:
        return int(self._x.shape[0])

    @property
    def landmark_ids(self) -> list[int]:
        return [int(i) for i in self._ids]

    def landmark_ids_array(self) -> IntArray:
        """The landmark ids in state order, as the filter showed them last (checked)."""
        return self._ids

    @property
    def warnings(self) -> tuple[str, ...]:
        """Why ekfviz's own update from the filter's prior state skipped observations (a
        landmark at zero range, an S not positive definite), one sentence each."""
        return self._warnings

    def _derive(self, ids: IntArray, z: FloatArray) -> Observations:
        """The observations as ekfviz's update sees them from the filter's prior state."""
        reference = EkfSlam.from_state(self._params, self._x, self._P, self._ids)
        try:
            observations = reference.observe(ids, z)
        except FilterError:  # the filter's own update is judged after it runs
            self._warnings = ()
            return _unjudged(ids, z, self._ids)
        self._warnings = reference.warnings
        return observations

    def _drift_warning(self) -> tuple[str, ...]:
        """Once a run, at an update: that the filter's P drifts from symmetric."""
        if self._drift_said or self._asymmetry <= SYMMETRY_TOLERANCE:
            return ()
        self._drift_said = True
        return (
            f"filter {self.name}: P drifts from symmetric by rounding that adds up event after"
            f" event (|P - P^T| now {self._asymmetry:.2g} of its largest entry): ekfviz uses"
            f" (P + P^T) / 2, and stops the run past {SYMMETRY_DRIFT_LIMIT:g}; symmetrise P"
            " after each update and predict (P = (P + P.T) / 2)",
        )

    # -- events -------------------------------------------------------------------------

    def predict(self, d: float, alpha: float, dt: float | None = None) -> None:
        """The filter's predict, its state checked after it."""
        if self._predict_takes_dt:
            self._call("predict", lambda: self.slam.predict(d, alpha, dt))  # type: ignore[call-arg]
        else:
            self._call("predict", lambda: self.slam.predict(d, alpha))
        self._x, self._P, self._ids = self._state("predict")

    def observe(self, ids: Sequence[int] | IntArray, z: FloatArray) -> Observations:
        """The filter's update; what it saw derived from the state before it."""
        ids_arr = np.array(ids, dtype=np.int64).reshape(-1)
        z = np.array(z, dtype=np.float64).reshape(-1, 2)
        if len(set(ids_arr.tolist())) != len(ids_arr):
            raise FilterError("an observation names the same landmark twice")
        observations = (
            _unjudged(ids_arr, z, self._ids) if self.offline else self._derive(ids_arr, z)
        )
        self._call("update", lambda: self.slam.update(ids_arr.copy(), z.copy()))
        x, P, state_ids = self._state("update")
        missing = set(ids_arr.tolist()) - set(state_ids.tolist())
        if missing:
            raise PluginError(
                f"filter {self.name}: after update, landmark_ids lacks the observed"
                f" landmark(s) {sorted(missing)}"
            )
        self._x, self._P, self._ids = x, P, state_ids
        self._warnings += self._drift_warning()
        return observations

    @property
    def removes_landmarks(self) -> bool:
        """Whether the filter has a ``remove_landmarks(ids)``, which an association with
        tentative landmarks needs (see :mod:`ekfviz.association`)."""
        return self._removes

    def remove_landmarks(self, ids: Sequence[int]) -> None:
        """The filter's ``remove_landmarks(ids)``; its state after it checked, the ids
        gone from it."""
        drop = [int(i) for i in ids]
        self._call(
            "remove_landmarks",
            lambda: self.slam.remove_landmarks(list(drop)),  # type: ignore[attr-defined]
        )
        x, P, state_ids = self._state("remove_landmarks")
        kept = sorted(set(drop) & set(state_ids.tolist()))
        if kept:
            raise PluginError(
                f"filter {self.name}: after remove_landmarks, landmark_ids still holds {kept}"
            )
        self._x, self._P, self._ids = x, P, state_ids

    @property
    def offline(self) -> bool:
        """Whether the filter has a ``finish()``: it estimates the whole run at the end
        (a batch smoother), so its state before then is not an estimate to record."""
        return self._offline

    def finish(self) -> None:
        """Call the filter's ``finish()`` and take its state after it."""
        self._call("finish", self.slam.finish)  # type: ignore[attr-defined]
        self._x, self._P, self._ids = self._state("finish")

    def path(self) -> FloatArray | None:
        """An offline filter's ``poses_xytheta`` after ``finish()``, when it has one: its
        estimate of every pose of the run, the start's first (K, 3), checked.

        :raises PluginError: a path of the wrong shape, not finite, or not ending on x
        """
        try:
            path = getattr(self.slam, "poses_xytheta", None)
        except Exception as error:  # the user's property
            raise PluginError(
                f"filter {self.name}: reading poses_xytheta failed: {error}"
            ) from error
        if path is None:
            return None
        path = np.array(path, dtype=np.float64)
        where = f"filter {self.name}: after finish, poses_xytheta"
        if path.ndim != 2 or path.shape[1] != 3 or len(path) < 1:
            raise PluginError(f"{where} has shape {path.shape}, expected (K, 3)")
        if not np.isfinite(path).all():
            raise PluginError(f"{where} is not finite")
        if np.abs(path[-1, :2] - self._x[:2]).max() > 1e-6 * max(1.0, float(np.abs(path).max())):
            raise PluginError(f"{where} does not end on the pose of x")
        return frozen(path)

    def state_parts(self, full_cov: bool = False) -> StateParts:
        """The filter's state as a batch keeps it (:class:`~ekfviz.core.batch.StateParts`),
        copied; its map as the last call's arrays where it is the same to the bit (a
        predict), so that a batch stores it once."""
        parts = StateParts.of(self._x, self._P, self._ids, full_cov)
        last = self._last_map
        if last is not None and all(
            new.tobytes() == old.tobytes() and new.shape == old.shape
            for new, old in zip(parts[2:5], last, strict=True)
        ):
            parts = parts._replace(
                landmark_ids=last[0], landmarks_xy=last[1], landmark_covs=last[2]
            )
        else:
            self._last_map = (parts.landmark_ids, parts.landmarks_xy, parts.landmark_covs)
        return parts

    def pose_block(self) -> tuple[FloatArray, FloatArray]:
        """The pose (3,) and its covariance (3, 3), as the filter showed them last."""
        return self._x[:3], self._P[:3, :3]

    def map_parts(self) -> MapParts:
        """The map as a batch keeps it (see :meth:`state_parts`): one tuple while it is
        the same to the bit."""
        self.state_parts()
        assert self._last_map is not None  # (set there)
        return self._last_map

    # -- checks -------------------------------------------------------------------------

    def _call(self, what: str, action: Callable[[], object]) -> None:
        try:
            action()
        except PluginError as error:  # a filter in a worker says what went wrong itself
            raise type(error)(*_prefixed(error, self.name)) from error
        except Exception as error:  # the user's code: any exception is its fault
            raise PluginError(
                f"filter {self.name}: {what} raised {type(error).__name__}: {error}"
            ) from error

    def _state(self, after: str) -> tuple[FloatArray, FloatArray, IntArray]:
        """The filter's x, P, landmark ids after ``after``, checked."""
        where = f"filter {self.name}: after {after},"
        try:
            x, P, ids = state_of(self.slam)
        except Exception as error:
            raise PluginError(
                f"{where} reading x, P and landmark_ids failed ({type(error).__name__}: {error})"
            ) from error
        x, P, self._asymmetry = check_state(
            x, P, ids, where, _ASYMMETRY_HINTS.get(after, ""), self._asymmetry
        )
        return x, P, ids


# where an asymmetric P of a predict or an update comes from, in students' code
_ASYMMETRY_HINTS = {
    "update": "the corrected covariance (I - K H) P (or P - K S K^T, or Joseph's form) is"
    " symmetric only with K = P H^T S^-1 of that same P and H: is a factor missing"
    " (P - K H, or K without S^-1), or K made from another P (P_pre inside a loop over the"
    " landmarks)?",
    "predict": "G P G^T + Q is symmetric when Q is: is the noise added not symmetric, or P"
    " multiplied by G on one side only?",
}


def _prefixed(error: PluginError, name: str) -> tuple[object, ...]:
    """The arguments that rebuild ``error`` with its message naming the filter."""
    rebuilt = error.__reduce__()[1]
    message = f"filter {name}: {error}"
    return (message, *tuple(rebuilt)[1:]) if isinstance(rebuilt, tuple) else (message,)


def _with_own_noise(slam: object, name: str, params: FilterParams) -> tuple[FilterParams, bool]:
    """The parameters ekfviz derives NIS with: the run's, or the filter's own R where it
    exposes one as ``measurement_noise`` (2x2, bearing first, diagonal).

    :raises PluginError: a ``measurement_noise`` that is not such a matrix
    """
    try:
        noise = getattr(slam, "measurement_noise", None)
    except Exception as error:  # the user's property
        raise PluginError(f"filter {name}: reading measurement_noise failed: {error}") from error
    if noise is None:
        return params, False
    R = np.array(noise, dtype=np.float64)
    ok = R.shape == (2, 2) and bool(np.isfinite(R).all())
    if ok and (R[0, 1] != 0.0 or R[1, 0] != 0.0 or R[0, 0] <= 0.0 or R[1, 1] <= 0.0):
        ok = False
    if not ok:
        raise PluginError(
            f"filter {name}: measurement_noise is {R.tolist()}, expected a diagonal 2x2"
            " covariance of (bearing, range) with positive variances"
        )
    sigmas = np.sqrt(np.diag(R))
    own = replace(params, sigma_bearing=float(sigmas[0]), sigma_range=float(sigmas[1]))
    return own, True


def check_state(
    x: FloatArray,
    P: FloatArray,
    ids: IntArray,
    where: str,
    asymmetry_hint: str = "",
    asymmetry_before: float = 0.0,
) -> tuple[FloatArray, FloatArray, float]:
    """Refuse a state that is not one: wrong shapes, non-finite, P not symmetric (see
    :data:`SYMMETRY_TOLERANCE`: a jump from a symmetric P, or a drift grown too far), ids
    off.

    :param where: how the message starts (which filter, after what)
    :param asymmetry_hint: said after the message of an asymmetric P
    :param asymmetry_before: |P - P^T| / max |P| of the state before the event
    :return: x and P, P made exactly symmetric (its rounding is not the filter's fault),
        and |P - P^T| / max |P| of the P given
    :raises PluginError: naming the first problem found
    """
    n = x.shape[0]
    if n < 3 or (n - 3) % 2:
        raise PluginError(f"{where} x has {n} entries, expected 3 + 2N")
    if P.shape != (n, n):
        raise PluginError(f"{where} P has shape {P.shape}, expected ({n}, {n}) to match x")
    if len(ids) != (n - 3) // 2:
        raise PluginError(
            f"{where} landmark_ids has {len(ids)} ids but x holds {(n - 3) // 2} landmarks"
        )
    if len(set(ids.tolist())) != len(ids):
        raise PluginError(f"{where} landmark_ids names a landmark twice")
    if not np.isfinite(x).all():
        raise PluginError(f"{where} x is not finite (entry {int(np.argmin(np.isfinite(x)))})")
    if not np.isfinite(P).all():
        raise PluginError(f"{where} P is not finite")
    scale = float(np.abs(P).max()) if n else 0.0
    asymmetry = float(np.abs(P - P.T).max())
    relative = asymmetry / scale if asymmetry else 0.0  # (a zero P is symmetric)
    drifting = asymmetry_before > SYMMETRY_TOLERANCE
    if drifting and relative > SYMMETRY_DRIFT_LIMIT:
        raise PluginError(
            f"{where} P is not symmetric (|P - P^T| up to {asymmetry:.3g}, {relative:.3g} of"
            f" its largest entry; at most {SYMMETRY_DRIFT_LIMIT:g}): its asymmetry has grown"
            f" event after event ({asymmetry_before:.2g} before this one), the rounding of a P"
            " that is never made symmetric again; symmetrise P after each update and"
            " predict (P = (P + P.T) / 2)"
        )
    if not drifting and relative - asymmetry_before > SYMMETRY_STEP_TOLERANCE:
        raise PluginError(
            f"{where} P is not symmetric (|P - P^T| up to {asymmetry:.3g},"
            f" {relative:.3g} of its largest entry; at most {SYMMETRY_TOLERANCE:g})"
            + (f": {asymmetry_hint}" if asymmetry_hint else "")
        )
    return x, 0.5 * (P + P.T) if asymmetry else P, relative


def _unjudged(ids: IntArray, z: FloatArray, state_ids: IntArray) -> Observations:
    """Observations with no prediction (NaN rows), new landmarks flagged."""
    new = ~np.isin(ids, state_ids)
    return Observations(
        ids=frozen(ids.copy()), z=frozen(z.copy()),
        table=frozen(nan_table(len(ids))),
        initialised=frozen(new), skipped=frozen(~new),
    )  # fmt: skip


def _takes_dt(predict: object) -> bool:
    """Whether a filter's ``predict`` takes a third argument (the time the control spans)."""
    if not callable(predict):
        return False
    try:
        parameters = inspect.signature(predict).parameters.values()
    except (TypeError, ValueError):
        return False
    positional = [p for p in parameters if p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD)]
    return len(positional) >= 3 or any(p.kind is p.VAR_POSITIONAL for p in parameters)
