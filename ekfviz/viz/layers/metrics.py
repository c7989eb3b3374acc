"""The plots of a run without truth: the pose's sigmas, the NIS with its chi-square
bounds, and the numerical health of the covariance (``metrics/...``)."""

from __future__ import annotations

import math

import numpy as np
import pyarrow as pa  # type: ignore[import-untyped]
import rerun as rr

from ekfviz.core.health import CovarianceCheck, landmark_min_eigenvalues, pose_min_eigenvalues
from ekfviz.evaluation.consistency import chi2_bounds
from ekfviz.viz import style
from ekfviz.viz.layers.arrow import column, run_ends, scalars
from ekfviz.viz.layers.batch import Batch
from ekfviz.viz.layers.canvas import Canvas, Rows


class MetricsLayer:
    """The per-update series: pose sigma, NIS and health."""

    def __init__(self, canvas: Canvas) -> None:
        self._canvas = canvas

    def log_styling(self) -> None:
        entities = self._canvas.entities
        for path, name in ((style.NIS, "NIS"), (style.NEES, "NEES")):
            entities.style(path, rr.SeriesLines(colors=style.STATISTIC_COLOR, names=name))
            for bound, label in ((style.LOWER, "95% lower"), (style.UPPER, "95% upper")):
                entities.style(
                    f"{path}/{bound}",
                    rr.SeriesLines(colors=style.BOUND_COLOR, names=label, widths=1.0),
                )
        entities.style(  # one entity, three series: one colour each, the unit in the name
            style.POSE_SIGMA,
            rr.SeriesLines(
                colors=list(style.POSE_SIGMA_COLORS.values()),
                names=[
                    f"{axis} ({'rad' if axis == 'theta' else 'm'})"
                    for axis in style.POSE_SIGMA_COLORS
                ],
            ),
        )
        for path, name in (
            (style.HEALTH_POSE_MIN_EIG, "pose block"),
            (style.HEALTH_LANDMARK_MIN_EIG, "landmark blocks"),
            (style.HEALTH_P_MIN_EIG, "whole P"),
            (style.HEALTH_P_ASYMMETRY, "max |P - P^T|"),
            (style.HEALTH_P_LOG10_CONDITION, "log10 cond(P)"),
            (style.HEALTH_SKIPPED, "skipped observations"),
        ):
            entities.style(path, rr.SeriesLines(names=name))

    def send(self, batch: Batch) -> None:
        """The pose's sigmas and the NIS of every update."""
        rows, corrected, observed = batch.rows, batch.corrected, batch.observed
        send = self._canvas.send
        sigma = np.sqrt(np.diagonal(batch.pose_covs, axis1=1, axis2=2))
        if corrected.size:  # x, y, theta: three series of one entity, a row a step
            send(
                style.POSE_SIGMA,
                rows.pick(corrected),
                [
                    column(
                        rr.Scalars.descriptor_scalars(),
                        pa.array(sigma[corrected].reshape(-1)),
                        np.full(corrected.size, 3, dtype=np.int64),
                    )
                ],
            )
        with_nis = np.flatnonzero(observed.nis_used)
        if with_nis.size:  # with the chi-square bounds of 2 dof per landmark used
            used, which = np.unique(observed.nis_used[with_nis], return_inverse=True)
            bounds = np.array([chi2_bounds(2 * int(n)) for n in used])[which]
            send(style.NIS, rows.pick(with_nis), scalars(observed.nis_sum[with_nis]))
            self._canvas.extent(style.NIS, observed.nis_sum[with_nis], bounds[:, 0], bounds[:, 1])
            ends = run_ends(bounds[:, 0])
            at = rows.pick(with_nis[ends])
            for path, values in (
                (f"{style.NIS}/{style.LOWER}", bounds[ends, 0]),
                (f"{style.NIS}/{style.UPPER}", bounds[ends, 1]),
            ):
                send(path, at, scalars(values))

    def send_health(self, batch: Batch) -> None:
        """The numerical health series (see ``ekfviz.core.health``)."""
        rows, corrected = batch.rows, batch.corrected
        send = self._canvas.send
        if corrected.size:  # a predict adds Q: only an update can lose definiteness
            send(
                style.HEALTH_POSE_MIN_EIG,
                rows.pick(corrected),
                scalars(pose_min_eigenvalues(batch.pose_covs[corrected])),
            )
        maps = batch.maps  # the updates' maps, joined: an empty one adds no landmark
        with_map = maps.counts > 0
        if with_map.any():
            smallest = np.minimum.reduceat(
                landmark_min_eigenvalues(maps.covs), maps.starts[:-1][with_map]
            )
            send(style.HEALTH_LANDMARK_MIN_EIG, rows.pick(corrected[with_map]), scalars(smallest))
        observed = batch.observed
        if observed.rows.size:
            skipped = observed.skipped[observed.rows]
            ends = run_ends(skipped)
            send(style.HEALTH_SKIPPED, rows.pick(observed.rows[ends]), scalars(skipped[ends]))
        checked = [
            (k, check)
            for k, extra in sorted(batch.extras.items())
            if (check := extra.covariance) is not None
        ]
        if checked:
            self._send_checks(rows, checked)

    def _send_checks(self, rows: Rows, checked: list[tuple[int, CovarianceCheck]]) -> None:
        """The checks of the whole covariance; a condition number only where P is definite."""
        send = self._canvas.send
        at = rows.pick([k for k, _ in checked])
        for path, values in (
            (style.HEALTH_P_MIN_EIG, [check.min_eigenvalue for _, check in checked]),
            (style.HEALTH_P_ASYMMETRY, [check.asymmetry for _, check in checked]),
        ):
            send(path, at, scalars(values))
        definite = [(k, check) for k, check in checked if math.isfinite(check.condition)]
        if definite:
            send(
                style.HEALTH_P_LOG10_CONDITION,
                rows.pick([k for k, _ in definite]),
                scalars([math.log10(check.condition) for _, check in definite]),
            )
