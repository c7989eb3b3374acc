"""A course module of the handout's functions (``init_landmarks``, ``predict``,
``update``, column vectors) behind ekfviz's filter protocol, and the parameters a filter is
given."""

from __future__ import annotations

import traceback
from typing import Any, Callable, Dict, List, Optional, Tuple

import numpy as np

from .faults import FilterFault, UserError

COURSE_FUNCTIONS = ("init_landmarks", "predict", "update")

# -- what the filter is given ------------------------------------------------------------------


class Params:
    """ekfviz's filter parameters as plain attributes, with ``Q`` and ``R`` as arrays (as
    ekfviz made them: ``noise``)."""

    def __init__(self, values: Dict[str, Any], noise: Dict[str, Any]) -> None:
        self._values = dict(values)
        self._noise = noise
        for name, value in values.items():
            setattr(self, name, tuple(value) if isinstance(value, list) else value)

    @property
    def Q(self) -> Any:
        """Motion noise covariance (3x3) in the robot frame."""
        return np.array(self._noise["Q"], dtype=np.float64)

    @property
    def R(self) -> Any:
        """Measurement noise covariance (2x2) of (bearing, range)."""
        return np.array(self._noise["R"], dtype=np.float64)

    def as_dict(self) -> Dict[str, Any]:
        return dict(self._values)

    def __repr__(self) -> str:
        return "FilterParams(%s)" % ", ".join("%s=%r" % kv for kv in self._values.items())


def _shape(value: Any) -> str:
    shape = getattr(value, "shape", None)
    if shape is not None:
        return str(tuple(shape))
    if isinstance(value, (list, tuple)):
        return "a %s of %d" % (type(value).__name__, len(value))
    return "a %s" % type(value).__name__


def _floats(value: Any, function: str, name: str) -> Any:
    if np.iscomplexobj(value):
        raise FilterFault(
            "%s returned %s with complex numbers, expected real ones" % (function, name)
        )
    try:
        array = np.array(value, dtype=np.float64)
    except Exception as error:  # ragged lists, objects, complex values
        raise FilterFault(
            "%s returned %s that is not an array of numbers (%s: %s)"
            % (function, name, type(error).__name__, error)
        ) from None
    return array


class CourseModule:
    """A module of the handout's functions behind the filter protocol.

    The state is kept as a (3+2k, 1) column; k landmarks, all named by the first
    observation (the classic format). Each function is called with the shapes it takes
    (X a column (3+2k, 1) or flat (3+2k,), likewise the control, the measurements and the
    initial pose): the shapes it took last first, then the handout's, then the others, at
    every call. The adapter does no filter math: Q, R and the prior's covariance come
    from ekfviz (``noise``), and P after the first line is the handout's main()'s
    block_diag(pose_cov, landmark_cov) (with init_cross_covariance, where the module has
    it, in its off-diagonal blocks).
    """

    def __init__(self, module: Any, params: Params, noise: Dict[str, Any]) -> None:
        self.module = module
        self.X = np.array(params.init_pose, dtype=np.float64).reshape(3, 1)  # type: ignore[attr-defined]
        self.P = np.array(noise["prior"], dtype=np.float64)
        self.control_cov = np.array(noise["Q"], dtype=np.float64)
        self.measure_cov = np.array(noise["R"], dtype=np.float64)
        self.landmark_ids: List[int] = []
        # the shapes each function took at its last call (argument -> column?), and every
        # shape each argument was taken in (what check reports)
        self.last: Dict[str, Dict[str, bool]] = {}
        self.taken: Dict[str, List[bool]] = {"X": [], "control": [], "measure": []}

    # the protocol ------------------------------------------------------------------------

    @property
    def x(self) -> Any:
        return self.X.reshape(-1)

    @property
    def k(self) -> int:
        return len(self.landmark_ids)

    def convention(self) -> Dict[str, Any]:
        """The shapes taken so far, by argument: "column", "flat", "either" (both, by
        function or by call) or None."""
        said = {}
        for name, taken in self.taken.items():
            kinds = set(taken)
            said[name] = (
                None if not kinds else "either" if len(kinds) > 1
                else ("column" if taken[0] else "flat")
            )  # fmt: skip
        return said

    def predict(self, d: float, alpha: float) -> None:
        n = 3 + 2 * self.k

        def call(shape: Dict[str, bool]) -> Any:
            control = np.array([[d], [alpha]]) if shape["control"] else np.array([d, alpha])
            return self.module.predict(
                self._state_as(shape["X"]), self.P.copy(), control, self.control_cov.copy(), self.k
            )

        self.X, self.P = self._first_working("predict", ("X", "control"), call, n)

    def update(self, ids: Any, z: Any) -> None:
        ids_list = [int(i) for i in ids]
        z = np.asarray(z, dtype=np.float64).reshape(-1, 2)
        if not self.landmark_ids:
            self._initialise(ids_list, z)
            return
        if ids_list != self.landmark_ids:
            raise FilterFault(
                "a course module reads the classic format: every observation names the %d"
                " landmark%s of the first one, in the same order (ids %s); this one names %s"
                " (the handout's update takes the measurements of all k landmarks, in their"
                " order, and init_landmarks is called once, on the first line)"
                % (self.k, "" if self.k == 1 else "s", self.landmark_ids, ids_list)
            )
        n = 3 + 2 * self.k

        def call(shape: Dict[str, bool]) -> Any:
            measure = z.reshape(-1, 1) if shape["measure"] else z.reshape(-1)
            return self.module.update(
                self._state_as(shape["X"]), self.P.copy(), measure.copy(),
                self.measure_cov.copy(), self.k,
            )  # fmt: skip

        self.X, self.P = self._first_working("update", ("X", "measure"), call, n)

    # inside -------------------------------------------------------------------------------

    def _shapes(self, function: str, names: Tuple[str, ...]) -> List[Dict[str, bool]]:
        """The shapes to call ``function`` with, in order: those it took last, the
        handout's (every argument a column), then the others."""
        options = [{}]  # type: List[Dict[str, bool]]
        for name in names:
            options = [dict(o, **{name: column}) for o in options for column in (True, False)]
        last = self.last.get(function)
        if last is not None:
            options.sort(key=lambda option: option != last)
        return options

    def _state_as(self, column: bool) -> Any:
        """A copy of X as the functions take it: a (3+2k, 1) column or (3+2k,)."""
        X = self.X.reshape(-1, 1) if column else self.X.reshape(-1)
        return X.copy()

    def _took(self, function: str, shape: Dict[str, bool]) -> None:
        self.last[function] = shape
        for name, column in shape.items():
            taken = self.taken.setdefault("X" if name == "pose" else name, [])
            if column not in taken:
                taken.append(column)

    def _first_working(
        self, function: str, names: Tuple[str, ...], call: Callable[..., Any], n: int
    ) -> Tuple[Any, Any]:
        """X, P of the first of the shapes (see :meth:`_shapes`) ``function`` works with;
        the first failure is the one reported if none works."""
        first_error: Optional[BaseException] = None
        first_trace: Optional[str] = None
        for shape in self._shapes(function, names):
            try:
                X, P = self._checked(function, call(shape), n)
            except (SystemExit, KeyboardInterrupt):
                raise
            except BaseException as error:
                if first_error is None:
                    first_error = error
                    first_trace = traceback.format_exc()
                continue
            self._took(function, shape)
            return X, P
        assert first_error is not None
        if isinstance(first_error, FilterFault):
            raise first_error
        raise UserError(function, first_error, first_trace or "")

    def _checked(self, function: str, result: Any, n: int) -> Tuple[Any, Any]:
        """X and P as returned by ``function``, their shapes and values checked."""
        if not isinstance(result, (tuple, list)) or len(result) != 2:
            what = "None (no return statement?)" if result is None else _shape(result)
            raise FilterFault(
                "%s returned %s, expected (X, P): the state (%d, 1) and its covariance (%d, %d)"
                % (function, what, n, n, n)
            )
        X = _floats(result[0], function, "X")
        P = _floats(result[1], function, "P")
        if X.shape == (n, n) and P.shape in ((n, 1), (n,)):
            raise FilterFault(
                "%s returned (P, X), expected (X, P): its first value has shape %s, its"
                " second %s" % (function, X.shape, P.shape)
            )
        if X.shape not in ((n, 1), (n,), (1, n)):
            raise FilterFault(
                "%s returned X of shape %s, expected (%d, 1) or (%d,) (3 + 2k with k = %d)"
                % (function, X.shape, n, n, self.k)
            )
        if P.shape != (n, n):
            raise FilterFault(
                "%s returned P of shape %s, expected (%d, %d) to match X"
                % (function, P.shape, n, n)
            )
        return X.reshape(n, 1), P

    def _initialise(self, ids: List[int], z: Any) -> None:
        pose = self.X[:3].copy()
        pose_cov = self.P[:3, :3].copy()
        k = len(ids)

        def call(shape: Dict[str, bool]) -> Any:
            measure = z.reshape(-1, 1) if shape["measure"] else z.reshape(-1)
            init_pose = pose.reshape(3, 1) if shape["pose"] else pose.reshape(3)
            result = self.module.init_landmarks(
                measure.copy(), self.measure_cov.copy(), init_pose.copy(), pose_cov.copy()
            )
            landmark, landmark_cov = self._checked_init(result, k)
            cross = self._cross_covariance(measure, init_pose, pose_cov, k)
            return landmark, landmark_cov, cross

        errors: List[Tuple[BaseException, str]] = []
        for shape in self._shapes("init_landmarks", ("measure", "pose")):
            try:
                landmark, landmark_cov, cross = call(shape)
            except (SystemExit, KeyboardInterrupt):
                raise
            except BaseException as error:
                errors.append((error, traceback.format_exc()))
                continue
            n = 3 + 2 * k
            P = np.zeros((n, n))  # the handout's block_diag(pose_cov, landmark_cov)
            P[:3, :3] = pose_cov
            P[3:, 3:] = landmark_cov
            if cross is not None:
                P[3:, :3] = cross
                P[:3, 3:] = cross.T
            self.X = np.vstack([pose.reshape(3, 1), landmark.reshape(-1, 1)])
            self.P = P
            self.landmark_ids = list(ids)
            self._took("init_landmarks", shape)
            return
        first, trace = errors[0]
        if isinstance(first, FilterFault):
            raise first
        raise UserError("init_landmarks", first, trace)

    def _cross_covariance(self, measure: Any, init_pose: Any, pose_cov: Any, k: int) -> Any:
        """The module's own init_cross_covariance (2k, 3), where it has one; else None."""
        cross_of = getattr(self.module, "init_cross_covariance", None)
        if not callable(cross_of):
            return None
        cross = _floats(
            cross_of(measure.copy(), init_pose.copy(), pose_cov.copy()),
            "init_cross_covariance",
            "the cross-covariance",
        )
        if cross.shape != (2 * k, 3):
            raise FilterFault(
                "init_cross_covariance returned shape %s, expected (%d, 3)" % (cross.shape, 2 * k)
            )
        return cross

    def _checked_init(self, result: Any, k: int) -> Tuple[Any, Any]:
        if not isinstance(result, (tuple, list)) or len(result) != 3:
            raise FilterFault(
                "init_landmarks returned %s, expected (k, landmarks (%d, 1), landmark_cov"
                " (%d, %d))" % (_shape(result), 2 * k, 2 * k, 2 * k)
            )
        count, landmark, landmark_cov = result
        try:
            count_ok = int(count) == k
        except (TypeError, ValueError):
            count_ok = False
        if not count_ok:
            raise FilterFault(
                "init_landmarks returned k = %r, expected %d (the landmarks of the first line)"
                % (count, k)
            )
        landmark = _floats(landmark, "init_landmarks", "the landmarks")
        landmark_cov = _floats(landmark_cov, "init_landmarks", "landmark_cov")
        if landmark.shape not in ((2 * k, 1), (2 * k,), (1, 2 * k)):
            raise FilterFault(
                "init_landmarks returned the landmarks with shape %s, expected (%d, 1) or (%d,)"
                % (landmark.shape, 2 * k, 2 * k)
            )
        if landmark_cov.shape != (2 * k, 2 * k):
            raise FilterFault(
                "init_landmarks returned landmark_cov with shape %s, expected (%d, %d)"
                % (landmark_cov.shape, 2 * k, 2 * k)
            )
        return landmark, landmark_cov
