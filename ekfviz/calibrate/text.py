"""The text of ``ekfviz calibrate``: the estimates, the scaling, the candidates and the
choice as tables and lines (see :mod:`ekfviz.core.tables`), and the JSON report, beside the
calibration's result types."""

from __future__ import annotations

import math
import shlex
from pathlib import Path

from ekfviz.calibrate.fit import HEAVY_TAIL_SHARE, OUTLIER_SIGMAS, Calibration, ResidualStats
from ekfviz.calibrate.recommend import LARGE_SCALE, MAP_CREDIBLE, Recommendation
from ekfviz.core.params import MotionNoise
from ekfviz.core.tables import Cell, Styled, TextTable


def estimates_table(result: Calibration) -> TextTable:
    """The noise estimated from the ground truth: a row a measurement and motion sigma."""
    motion = result.motion
    assert motion is not None
    unit = "per sqrt(s)" if motion.model is MotionNoise.PER_SQRT_SECOND else "per step"
    rows: list[tuple[Cell, ...]] = []
    for stats in (result.bearing, result.range):
        rows.append(
            (
                f"{stats.name} ({stats.unit})",
                f"{stats.sigma:.5g}",
                f"{stats.bias:+.5g}",
                str(stats.count),
                str(stats.outliers),
                f"{100 * stats.tail_share:.2f} %",
            )
        )
    units = ("m", "m", "rad")
    for name, sigma, stats, u, key in zip(
        ("x (along)", "y (sideways)", "alpha (turn)"), motion.sigmas, motion.components, units,
        ("x", "y", "alpha"), strict=True,
    ):  # fmt: skip
        rows.append(
            (
                f"motion {name} ({u} {unit})",
                "at limit (0)" if key in motion.at_limit else f"{sigma:.5g}",
                "",
                str(motion.windows),
                str(motion.outliers) if name.startswith("x") else "",
                f"{100 * stats.tail_share:.2f} %",
            )
        )
    columns = ("noise", "sigma", "bias", "used", "outliers", "beyond 3σ")
    return TextTable("Noise estimated from the ground truth", columns, tuple(rows))


def method_lines(result: Calibration) -> list[Cell]:
    """How the estimates were made, and the systematic odometry errors found."""
    motion = result.motion
    assert motion is not None
    window = f"{motion.window_s:g} s windows" if motion.window_s is not None else "one control each"
    standing = f", {motion.standing} standing still" if motion.standing else ""
    lines: list[Cell] = []
    lines.append(
        Styled(
            f"Measurement sigma: 1.4826 x median absolute deviation, bias: median, outliers: over"
            f" {OUTLIER_SIGMAS:g} sigma from it. Motion: {motion.windows} windows ({window}),"
            f" {motion.outliers} left out beyond the 99.9 % chi-square bound{standing}; a control"
            " that reads no motion adds no noise.",
            wrap=False,
        )
    )
    odometry = result.odometry
    if odometry is not None:
        k_d, k_a, b = odometry.applied
        lines.append(
            Styled(
                f"Systematic odometry errors ({odometry.windows} windows): distance scale"
                f" {odometry.scale_d:.4f} ± {odometry.se_d:.4f}, turn scale"
                f" {odometry.scale_alpha:.4f} ± {odometry.se_alpha:.4f}, turn bias"
                f" {odometry.bias:+.4f} ± {odometry.se_bias:.4f} rad/m (± one standard error);"
                f" applied: --odometry-scale {k_d:.4g} {k_a:.4g}, --odometry-bias {b:.4g} (a term"
                " within 3 standard errors of no error is left at it).",
                wrap=False,
            )
        )
    return lines


def scaling_lines(result: Recommendation) -> list[Cell]:
    """How consistent the estimates are on the fitted part, and the factors that make
    them so."""
    apart, together = result.scaling, result.together
    before = apart.before
    if apart.motion == 1.0 and apart.measurement == 1.0:
        return [
            Styled(
                f"On the fitted part, a filter told these estimates is consistent with the truth:"
                f" mean pose NEES {before.nees:.3g} (3 expected), NIS per dof {before.nis:.3g}"
                " (1 expected).",
                wrap=False,
            )
        ]
    return [
        Styled(
            f"On the fitted part, a filter told these estimates has a mean pose NEES of"
            f" {before.nees:.3g} (3 expected) and an NIS per dof of {before.nis:.3g} (1"
            f" expected). Scaled apart, the measurement sigmas by {apart.measurement:.3g} (from"
            f" the NIS) and the motion sigmas by {apart.motion:.3g} (from the NEES), it has"
            f" {apart.after.nees:.3g} and {apart.after.nis:.3g}"
            + (" (the search stopped at its limit)" if apart.at_limit else "")
            + f"; with one factor {together.motion:.3g} on all sigmas, {together.after.nees:.3g}"
            f" and {together.after.nis:.3g}.",
            wrap=False,
        )
    ]


def candidates_table(result: Recommendation) -> TextTable:
    """Every candidate setting judged on the held-out part, the chosen one marked."""
    title = (
        f"Candidates (fitted on the first {result.fit_share:.0%} of the run), each"
        f" replayed whole: NEES and NIS over the held-out {1 - result.fit_share:.0%},"
        " the map at the end"
    )
    columns = (
        "setting", "factors (motion, meas.)", "mean err m", "worst m", "aligned m",
        "in 3σ", "3σ semi-major m", "NEES", "NIS/dof", "reading",
    )  # fmt: skip
    rows: list[tuple[Cell, ...]] = []
    for k, candidate in enumerate(result.candidates):
        h = candidate.held_out
        m = h.map
        factors = "" if candidate.factors is None else "{:.3g}, {:.3g}".format(*candidate.factors)
        mark = " ←" if k == result.chosen else ""
        if m is None:
            rows.append((candidate.name + mark, factors, *(["-"] * 7), h.verdict))
            continue
        rows.append((
            candidate.name + mark, factors, f"{m.mean_error:.3f}", f"{m.worst_error:.3f}",
            f"{m.aligned_mean_error:.3f}", f"{m.inside}/{m.landmarks}",
            f"{m.mean_semi_major:.3f}", _number(h.nees), _number(h.nis), h.verdict,
        ))  # fmt: skip
    return TextTable(title, columns, tuple(rows))


def choice_lines(result: Recommendation) -> list[Cell]:
    """Which candidate is recommended and why, or why none is; a warning of a large factor."""
    best = result.best
    if best is None:
        readings = ", ".join(f"{c.name} {c.held_out.verdict}" for c in result.candidates)
        return [
            Styled(
                "No setting is recommended: every candidate's held-out reading is over-confident"
                f" or unread ({readings}). A replay with any of them would claim more certainty"
                " than its errors bear out: the model misses errors of this run (look at the"
                " estimates' tails and the odometry), so inflate the noise by hand or model them.",
                wrap=False,
            )
        ]
    lines: list[Cell] = [
        Styled(
            f"Recommended: {best.name}, the lowest held-out mean landmark error among the"
            " settings its held-out reading does not call over-confident, maps with at least"
            f" {MAP_CREDIBLE:.0%} of their landmarks inside 3σ first. Expected: NEES 3, NIS per"
            " dof 1.",
            wrap=False,
        )
    ]
    if best.factors is not None and max(best.factors) > LARGE_SCALE:
        lines.append(
            Styled(
                f"Its factor {max(best.factors):.3g} is over {LARGE_SCALE:g}: errors the model"
                " does not describe are covered by inflating the covariance.",
                wrap=False,
            )
        )
    return lines


def _number(value: float) -> str:
    return f"{value:.3g}" if math.isfinite(value) else "-"


def calibration_json(result: Recommendation, data: Path, command: list[str]) -> dict[str, object]:
    """Every estimate, candidate and held-out figure, and the replay line, as JSON."""
    calibration = result.calibration
    motion = calibration.motion
    assert motion is not None

    def stats(s: ResidualStats) -> dict[str, object]:
        return {
            "sigma": s.sigma, "bias": s.bias, "count": s.count, "outliers": s.outliers,
            "tail_share": s.tail_share,
        }  # fmt: skip

    return {
        "input": str(data),
        "fit_share": result.fit_share,
        "split_at": result.split_at,
        "estimates": {
            "bearing": stats(calibration.bearing),
            "range": stats(calibration.range),
            "motion": {
                "model": motion.model.value,
                "sigmas": list(motion.sigmas),
                "at_limit": list(motion.at_limit),
                "windows": motion.windows,
                "left_out": motion.outliers,
                "left_out_share": motion.left_out_share,
                "standing": motion.standing,
                "window_s": motion.window_s,
            },
            "odometry": None if calibration.odometry is None else calibration.odometry.to_json(),
            "sightings": calibration.sightings,
        },
        "scaling": {"apart": result.scaling.to_json(), "together": result.together.to_json()},
        "candidates": [c.to_json() for c in result.candidates],
        "recommended": None if result.best is None else result.best.name,
        "notes": list(result.notes),
        "command": shlex.join(command) if command else None,
    }


def tail_warnings(result: Calibration) -> list[str]:
    """A warning for each residual far from Gaussian."""
    motion = result.motion
    assert motion is not None
    return [
        _tail_warning(stats, what)
        for stats, what in [
            (result.bearing, "bearing residuals"),
            (result.range, "range residuals"),
            *((s, f"motion residuals in {s.name} (whitened)") for s in motion.components),
        ]
        if not stats.gaussian
    ]


def _tail_warning(stats: ResidualStats, what: str) -> str:
    return (
        f"the {what} are far from Gaussian: {100 * stats.tail_share:.1f} % lie beyond 3"
        f" sigma of the median (a Gaussian: 0.27 %, warned above"
        f" {100 * HEAVY_TAIL_SHARE:g} %); the filter will meet more large innovations than"
        " it expects"
    )
