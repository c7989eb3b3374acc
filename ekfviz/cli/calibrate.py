"""``ekfviz calibrate``: estimate a log's noise and odometry errors from its ground truth,
judge the candidate settings on held-out time, print the replay line of the best."""

from __future__ import annotations

import math
import shlex
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from ekfviz.cli.common import (
    app,
    check_outputs,
    command_hint,
    fail,
    out,
    warn,
    write_json,
)
from ekfviz.cli.options import FilterForm, FilterNoise, StudyLogArgument, TruthOption
from ekfviz.cli.sources import MotionNoiseChoice, RobotOption, first_time, open_log, resolve
from ekfviz.core.calibrate import (
    FIT_SHARE,
    HEAVY_TAIL_SHARE,
    LARGE_SCALE,
    MAP_CREDIBLE,
    OUTLIER_SIGMAS,
    WINDOW_S,
    Calibration,
    Candidate,
    Recommendation,
    ResidualStats,
    recommend,
)
from ekfviz.core.filter import MotionNoise
from ekfviz.core.gating import CHI2_2_999
from ekfviz.core.records import NeedsIds, with_ids
from ekfviz.io.errors import InputError

Window = Annotated[
    float,
    typer.Option(help="Seconds of odometry per motion window of a timestamped log.", min=0.01),
]
FitShare = Annotated[
    float,
    typer.Option(
        help="The share of the run (by time, untimed: by events) the noise is fitted on;"
        " the rest judges the candidate settings.",
        min=0.2,
        max=0.9,
    ),
]
CalibrationReport = Annotated[
    Path | None,
    typer.Option(
        help="Write every estimate, candidate and held-out figure as JSON here.",
        show_default=False,
    ),
]


@app.command(name="calibrate")
def calibrate_command(
    data: StudyLogArgument,
    truth: TruthOption = None,
    robot: RobotOption = None,
    window: Window = WINDOW_S,
    fit_share: FitShare = FIT_SHARE,
    report: CalibrationReport = None,
) -> None:
    """Estimate the measurement noise, the motion noise and the systematic odometry errors
    from ground truth on the first part of the run, judge the candidates (the defaults, the
    estimates, the estimates scaled) on the rest, and print the replay line of the best.

    The truth is --truth (with true poses: a JSON file with "poses") or a dataset's own.
    """
    check_outputs(("--report", report))
    result, command = run_calibrate(data, truth, robot, window, fit_share)
    if report is not None:
        try:
            write_json(report, _report(result, data, command))
        except OSError as error:
            fail(f"{report}: cannot write the report: {error.strerror or error}")
    out.print(f"Replay with the recommended setting ({result.best.name}):")
    program = command_hint("ekfviz")
    if program != "ekfviz":
        out.print(f"(ekfviz is not on your PATH: run it as {program})", markup=False)
    # the line starts with "ekfviz replay", whatever runs here: scripts look for it
    out.print(shlex.join(command), soft_wrap=True, markup=False, highlight=False)


def run_calibrate(
    data: Path, truth: Path | None, robot: int | None, window: float, fit_share: float
) -> tuple[Recommendation, list[str]]:
    """The noise estimated and the candidates judged, printed; the best's replay line."""
    defaults_given = FilterForm().params(FilterNoise(), log=data)
    try:
        opened = open_log(data, robot, truth, no_truth=False)
        if opened.truth is None or not opened.truth.has_poses:
            fail(
                f"{truth or data}: calibrate needs true poses: --truth FILE.json with"
                ' "poses", or a dataset directory with its ground-truth files'
            )
        try:
            events = list(with_ids(opened.events()))
        except NeedsIds as error:
            raise InputError(
                data, error.line, f"found {error.what}: calibrate needs landmark ids and d alpha"
                " controls",
            ) from None  # fmt: skip
        start, _ = first_time(iter(events))
        # what `ekfviz replay DATA` does without options: the defaults' candidate
        defaults, _notes = resolve(defaults_given, opened, start, None, MotionNoiseChoice.AUTO)
        result = recommend(
            events, opened.truth, defaults, defaults, window_s=window, fit_share=fit_share,
            heavy_tail_gate=CHI2_2_999,
        )  # fmt: skip
    except InputError as error:
        fail(str(error))
    except ValueError as error:  # an id-less scan, a vehicle's controls, nothing to fit
        fail(f"{data}: {error}")
    _print_table(result.calibration)
    _warn_non_gaussian(result.calibration)
    _print_scaling(result)
    _print_candidates(result)
    for note in result.notes:
        warn(note)
    dataset_robot = robot if opened.source.dataset is not None else None
    return result, _replay_line(result.best, data, dataset_robot, truth)


def _replay_line(best: Candidate, data: Path, robot: int | None, truth: Path | None) -> list[str]:
    """The replay command of a candidate: only the options that differ from a plain
    replay's, sigmas with 6 significant digits."""
    command = ["ekfviz", "replay", str(data)]
    if robot is not None:
        command += ["--robot", str(robot)]
    if truth is not None:
        command += ["--truth", str(truth)]
    p = best.params
    if best.factors is not None:  # the estimates: every sigma and the model
        command += ["--motion-noise", p.motion_noise.value]
        for name, value in (
            ("x", p.sigma_x), ("y", p.sigma_y), ("alpha", p.sigma_alpha),
            ("bearing", p.sigma_bearing), ("range", p.sigma_range),
        ):  # fmt: skip
            command += [f"--sigma-{name}", f"{value:.6g}"]
        if p.gate is not None:
            command += ["--gate", f"{p.gate:g}"]
    if p.odometry_scale != (1.0, 1.0):
        command += ["--odometry-scale", *(f"{k:.6g}" for k in p.odometry_scale)]
    if p.odometry_bias != 0.0:
        command += [f"--odometry-bias={p.odometry_bias:.6g}"]  # "=": a negative value
    return command


def _print_table(result: Calibration) -> None:
    motion = result.motion
    assert motion is not None
    unit = "per sqrt(s)" if motion.model is MotionNoise.PER_SQRT_SECOND else "per step"
    table = Table(title="Noise estimated from the ground truth", title_justify="left")
    for column in ("noise", "sigma", "bias", "used", "outliers", "beyond 3σ"):
        table.add_column(column, justify="right")
    for stats in (result.bearing, result.range):
        table.add_row(
            f"{stats.name} ({stats.unit})",
            f"{stats.sigma:.5g}",
            f"{stats.bias:+.5g}",
            str(stats.count),
            str(stats.outliers),
            f"{100 * stats.tail_share:.2f} %",
        )
    units = ("m", "m", "rad")
    for name, sigma, stats, u, key in zip(
        ("x (along)", "y (sideways)", "alpha (turn)"), motion.sigmas, motion.components, units,
        ("x", "y", "alpha"), strict=True,
    ):  # fmt: skip
        table.add_row(
            f"motion {name} ({u} {unit})",
            "at limit (0)" if key in motion.at_limit else f"{sigma:.5g}",
            "",
            str(motion.windows),
            str(motion.outliers) if name.startswith("x") else "",
            f"{100 * stats.tail_share:.2f} %",
        )
    out.print(table)
    window = f"{motion.window_s:g} s windows" if motion.window_s is not None else "one control each"
    standing = f", {motion.standing} standing still" if motion.standing else ""
    out.print(
        f"Measurement sigma: 1.4826 x median absolute deviation, bias: median, outliers: over"
        f" {OUTLIER_SIGMAS:g} sigma from it. Motion: {motion.windows} windows ({window}),"
        f" {motion.outliers} left out beyond the 99.9 % chi-square bound{standing}; a control"
        " that reads no motion adds no noise.",
        soft_wrap=True,
    )
    odometry = result.odometry
    if odometry is not None:
        k_d, k_a, b = odometry.applied
        out.print(
            f"Systematic odometry errors ({odometry.windows} windows): distance scale"
            f" {odometry.scale_d:.4f} ± {odometry.se_d:.4f}, turn scale"
            f" {odometry.scale_alpha:.4f} ± {odometry.se_alpha:.4f}, turn bias"
            f" {odometry.bias:+.4f} ± {odometry.se_bias:.4f} rad/m (± one standard error);"
            f" applied: --odometry-scale {k_d:.4g} {k_a:.4g}, --odometry-bias {b:.4g} (a term"
            " within 3 standard errors of no error is left at it).",
            soft_wrap=True,
        )


def _print_scaling(result: Recommendation) -> None:
    apart, together = result.scaling, result.together
    before = apart.before
    if apart.motion == 1.0 and apart.measurement == 1.0:
        out.print(
            f"On the fitted part, a filter told these estimates is consistent with the truth:"
            f" mean pose NEES {before.nees:.3g} (3 expected), NIS per dof {before.nis:.3g}"
            " (1 expected).",
            soft_wrap=True,
        )
        return
    out.print(
        f"On the fitted part, a filter told these estimates has a mean pose NEES of"
        f" {before.nees:.3g} (3 expected) and an NIS per dof of {before.nis:.3g} (1"
        f" expected). Scaled apart, the measurement sigmas by {apart.measurement:.3g} (from"
        f" the NIS) and the motion sigmas by {apart.motion:.3g} (from the NEES), it has"
        f" {apart.after.nees:.3g} and {apart.after.nis:.3g}"
        + (" (the search stopped at its limit)" if apart.at_limit else "")
        + f"; with one factor {together.motion:.3g} on all sigmas, {together.after.nees:.3g}"
        f" and {together.after.nis:.3g}.",
        soft_wrap=True,
    )


def _print_candidates(result: Recommendation) -> None:
    table = Table(
        title=(
            f"Candidates (fitted on the first {result.fit_share:.0%} of the run), each"
            f" replayed whole: NEES and NIS over the held-out {1 - result.fit_share:.0%},"
            " the map at the end"
        ),
        title_justify="left",
    )
    for column in (
        "setting", "factors (motion, meas.)", "mean err m", "worst m", "aligned m",
        "in 3σ", "3σ semi-major m", "NEES", "NIS/dof", "reading",
    ):  # fmt: skip
        table.add_column(column, justify="right")
    for k, candidate in enumerate(result.candidates):
        h = candidate.held_out
        m = h.map
        factors = "" if candidate.factors is None else "{:.3g}, {:.3g}".format(*candidate.factors)
        mark = " ←" if k == result.chosen else ""
        if m is None:
            table.add_row(candidate.name + mark, factors, *(["-"] * 7), h.verdict)
            continue
        table.add_row(
            candidate.name + mark, factors, f"{m.mean_error:.3f}", f"{m.worst_error:.3f}",
            f"{m.aligned_mean_error:.3f}", f"{m.inside}/{m.landmarks}",
            f"{m.mean_semi_major:.3f}", _number(h.nees), _number(h.nis), h.verdict,
        )  # fmt: skip
    out.print(table)
    best = result.best
    out.print(
        f"Recommended: {best.name}, the lowest held-out mean landmark error among the maps"
        f" with at least {MAP_CREDIBLE:.0%} of their landmarks inside 3σ (the defaults are a"
        " candidate: nothing worse than them is recommended). Expected: NEES 3, NIS per"
        " dof 1.",
        soft_wrap=True,
    )
    if best.factors is not None and max(best.factors) > LARGE_SCALE:
        out.print(
            f"Its factor {max(best.factors):.3g} is over {LARGE_SCALE:g}: errors the model"
            " does not describe are covered by inflating the covariance.",
            soft_wrap=True,
        )


def _number(value: float) -> str:
    return f"{value:.3g}" if math.isfinite(value) else "-"


def _report(result: Recommendation, data: Path, command: list[str]) -> dict[str, object]:
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
        "recommended": result.best.name,
        "notes": list(result.notes),
        "command": shlex.join(command),
    }


def _warn_non_gaussian(result: Calibration) -> None:
    motion = result.motion
    assert motion is not None
    for stats, what in [
        (result.bearing, "bearing residuals"),
        (result.range, "range residuals"),
        *((s, f"motion residuals in {s.name} (whitened)") for s in motion.components),
    ]:
        if not stats.gaussian:
            warn(_tail_warning(stats, what))


def _tail_warning(stats: ResidualStats, what: str) -> str:
    return (
        f"the {what} are far from Gaussian: {100 * stats.tail_share:.1f} % lie beyond 3"
        f" sigma of the median (a Gaussian: 0.27 %, warned above"
        f" {100 * HEAVY_TAIL_SHARE:g} %); the filter will meet more large innovations than"
        " it expects"
    )
