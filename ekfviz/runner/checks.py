"""When a replay checks the whole covariance and takes its correlation, and where.

The whole covariance P is checked (:func:`~ekfviz.core.health.check_covariance`) at the
first and the last event, every :func:`~ekfviz.core.health.check_interval` steps and
wherever an event raised a warning; its problems join the event's warnings, and a P
that is not finite stops the run at the event's line. Its correlation matrix is taken
at the initialisation, the updates and the last event where
:class:`~ekfviz.core.correlation.CorrelationCadence` says it is due. On a large map both
are done beside the filter (:mod:`ekfviz.runner.beside`), the built-in filter's pending
changes taken off there too, the check's finiteness at once.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ekfviz.core.correlation import Correlation, CorrelationCadence, correlation_of
from ekfviz.core.health import NOT_FINITE, CovarianceCheck, check_covariance, check_interval
from ekfviz.core.types import FloatArray, IntArray
from ekfviz.filters.ekf import EkfSlam
from ekfviz.runner.beside import Beside, Results, pending_taken_off
from ekfviz.runner.errors import FilterLineError

if TYPE_CHECKING:
    from concurrent.futures import Future

    from ekfviz.filters.plugged import Plugged

# what an event's whole-P work gives at once: the check, the warnings with its problems,
# the correlation, and the work handed to the thread (None: none)
Work = tuple[CovarianceCheck | None, tuple[str, ...], Correlation | None, "Future[Results] | None"]


class WholeCovariance:
    """The checks and correlations of one replay's covariance (see the module).

    :param ekf: the filter whose P is read
    """

    def __init__(self, ekf: EkfSlam | Plugged) -> None:
        self._ekf = ekf
        self.next_check = 0  # the step from which the next check is due
        self._cadence = CorrelationCadence()
        self._beside = Beside()

    def due(
        self,
        step: int,
        n_landmarks: int,
        time: float | None,
        warnings: tuple[str, ...],
        corrected: bool,
        last: bool,
        now: bool = False,
    ) -> tuple[bool, bool]:
        """Whether the check and the correlation are due at an event of ``step`` (an
        initialisation or an update where ``corrected``; the run's last where ``last``;
        the check at once where ``now``): ask once an event, the correlation's cadence
        counts what it says is due as taken."""
        check = now or step >= self.next_check or last or bool(warnings)
        correlate = (corrected or last) and self._cadence.due(step, n_landmarks, last, time)
        return check, correlate

    def work(
        self,
        line: int,
        step: int,
        ids: IntArray,
        check: bool,
        correlate: bool,
        warnings: tuple[str, ...],
        now: bool,
    ) -> Work:
        """The check of P (where ``check``: at once where ``now``) and its correlation
        (where ``correlate``: of the landmark ``ids``), as :meth:`due` said.

        :raises FilterLineError: (at ``line``) P is not finite
        """
        if not check and not correlate:
            return None, warnings, None, None
        if check:
            self.next_check = step + check_interval(self._ekf.dim)
        if not Beside.takes(self._ekf.dim):
            P, _ = current_covariance(self._ekf)
            covariance, warnings = _checked(P, line, warnings) if check else (None, warnings)
            return covariance, warnings, correlation_of(P, ids) if correlate else None, None
        self._beside.wait()  # one copy of P at a time beside the filter's own
        if check and now:
            P, own = current_covariance(self._ekf)
            covariance, warnings = _checked(P, line, warnings)
            if not correlate:
                return covariance, warnings, None, None
            work = self._beside.submit(P, False, ids, copy=not own)
            return covariance, warnings, None, work
        # the pending changes are taken off in the thread; P_s and U finite (at once)
        # make P finite (an overflow of U^T U aside, which the check names later)
        P_s, U = deferred_covariance(self._ekf)
        if check and not (Beside.finite(P_s) and (U is None or Beside.finite(U))):
            raise FilterLineError(line, NOT_FINITE)
        work = self._beside.submit(P_s, check, ids if correlate else None, pending=U)
        return None, warnings, None, work

    def close(self) -> None:
        """End the thread beside the filter, if one was started."""
        self._beside.close()


def deferred_covariance(ekf: EkfSlam | Plugged) -> tuple[FloatArray, FloatArray | None]:
    """The filter's covariance as stored and the rows U of its pending changes (None
    where none: a filter of the protocol's, or nothing pending), the current one P_s -
    U^T U (see :meth:`~ekfviz.filters.ekf_pending.PendingCovariance.deferred_covariance`)."""
    if not isinstance(ekf, EkfSlam):
        return ekf.P, None
    return ekf.deferred_covariance()


def current_covariance(ekf: EkfSlam | Plugged) -> tuple[FloatArray, bool]:
    """The filter's whole covariance as it is now, and whether the array is a new one
    (else the filter's own, to be copied before the filter changes it).

    The built-in filter's pending changes (P - U^T U, see :mod:`ekfviz.filters.ekf`) are
    taken off a copy rather than folded into its P: a fold rounds otherwise than the
    filter's own later one, and the run's floats would depend on where a check or a
    correlation happened to read P (a warning's check, a consumer's).
    """
    P_s, U = deferred_covariance(ekf)
    if U is None:
        return P_s, False
    return pending_taken_off(P_s, U), True


def _checked(
    P: FloatArray, line: int, warnings: tuple[str, ...]
) -> tuple[CovarianceCheck, tuple[str, ...]]:
    """The check of ``P`` now, and ``warnings`` with its problems.

    :raises FilterLineError: (at ``line``) P is not finite
    """
    check = check_covariance(P)
    if not check.finite:
        raise FilterLineError(line, check.problems()[0])
    return check, warnings + tuple(check.problems())
