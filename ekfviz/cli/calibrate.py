"""``ekfviz calibrate``: estimate a log's noise from its ground truth, print the replay."""

from __future__ import annotations

import shlex
from typing import Annotated

import typer
from rich.table import Table

from ekfviz.cli.common import StudyLogArgument, TruthOption, app, command_hint, fail, out, warn
from ekfviz.cli.sources import MotionNoiseChoice, RobotOption, first_time, open_log, resolve
from ekfviz.core.calibrate import (
    HEAVY_TAIL_SHARE,
    OUTLIER_SIGMAS,
    WINDOW_S,
    Calibration,
    ResidualStats,
    Scaling,
    calibrate,
    consistent_scale,
)
from ekfviz.core.filter import FilterParams, MotionNoise
from ekfviz.core.gating import CHI2_2_999
from ekfviz.core.records import NeedsIds, with_ids
from ekfviz.io.errors import InputError


@app.command(name="calibrate")
def calibrate_command(
    data: StudyLogArgument,
    truth: TruthOption = None,
    robot: RobotOption = None,
    window: Annotated[
        float,
        typer.Option(help="Seconds of odometry per motion window of a timestamped log.", min=0.01),
    ] = WINDOW_S,
) -> None:
    """Estimate the measurement and motion noise from ground truth; print the replay
    command that uses them.

    The truth is --truth (with true poses: a JSON file with "poses") or a dataset's own.
    """
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
        result = calibrate(events, opened.truth, window_s=window)
        if result.sightings == 0 or result.motion is None:
            fail(f"{data}: no sightings or no controls with a true pose to calibrate from")
        _print_table(result)
        _warn_non_gaussian(result)
        motion = result.motion
        # heavy tails: outliers a Gaussian filter cannot absorb, so the replay gates them
        heavy = not (result.bearing.gaussian and result.range.gaussian)
        gate = CHI2_2_999 if heavy else None
        start, _ = first_time(iter(events))
        estimated = FilterParams(
            *motion.sigmas,
            sigma_bearing=result.bearing.sigma,
            sigma_range=result.range.sigma,
            motion_noise=motion.model,
            gate=gate,
        )
        params, _notes = resolve(
            estimated, opened, start, None, MotionNoiseChoice(motion.model.value)
        )
        scaling = consistent_scale(events, opened.truth, params)
    except InputError as error:
        fail(str(error))
    except ValueError as error:  # an id-less scan or a vehicle's controls
        fail(f"{data}: {error}")
    _print_scaling(scaling, gate)
    # the line starts with "ekfviz replay", whatever runs here: scripts look for it
    command = ["ekfviz", "replay", str(data)]
    if opened.source.dataset is not None and robot is not None:
        command += ["--robot", str(robot)]
    if truth is not None:
        command += ["--truth", str(truth)]
    command += ["--motion-noise", motion.model.value]
    k = scaling.factor
    for name, value in zip(("x", "y", "alpha"), motion.sigmas, strict=True):
        command += [f"--sigma-{name}", f"{k * value:.6g}"]
    command += ["--sigma-bearing", f"{k * result.bearing.sigma:.6g}"]
    command += ["--sigma-range", f"{k * result.range.sigma:.6g}"]
    if gate is not None:
        command += ["--gate", f"{gate:g}"]
    out.print("Replay with these estimates:")
    program = command_hint("ekfviz")
    if program != "ekfviz":
        out.print(f"(ekfviz is not on your PATH: run it as {program})", markup=False)
    out.print(shlex.join(command), soft_wrap=True, markup=False, highlight=False)


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
    for name, sigma, stats, u in zip(
        ("x (along)", "y (sideways)", "alpha (turn)"), motion.sigmas, motion.components, units,
        strict=True,
    ):  # fmt: skip
        table.add_row(
            f"motion {name} ({u} {unit})",
            f"{sigma:.5g}",
            "",
            str(motion.windows),
            str(motion.outliers) if name.startswith("x") else "",
            f"{100 * stats.tail_share:.2f} %",
        )
    out.print(table)
    window = f"{motion.window_s:g} s windows" if motion.window_s is not None else "one control each"
    out.print(
        f"Measurement sigma: 1.4826 x median absolute deviation, bias: median, outliers: over"
        f" {OUTLIER_SIGMAS:g} sigma from it. Motion: {motion.windows} windows ({window}),"
        f" {motion.outliers} left out beyond the 99.9 % chi-square bound.",
        soft_wrap=True,
    )


def _print_scaling(scaling: Scaling, gate: float | None) -> None:
    if gate is not None:
        out.print(
            f"The measurements have heavy tails: the replay rejects those beyond an NIS of"
            f" {gate:g} (--gate, the 99.9 % bound of 2 dof).",
            soft_wrap=True,
        )
    if scaling.factor == 1.0:
        out.print(
            f"A filter told these sigmas is consistent with the truth: mean pose NEES"
            f" {scaling.nees_before:.2f} (3 expected).",
            soft_wrap=True,
        )
        return
    out.print(
        f"A filter told these sigmas is over-confident: mean pose NEES"
        f" {scaling.nees_before:.3g} (3 expected), from errors the windows do not see"
        f" (correlated over longer times, biases, heavy tails). The replay line scales every"
        f" sigma by {scaling.factor:.3g}, which brings it to {scaling.nees_after:.3g}"
        f" ({scaling.replays} replays).",
        soft_wrap=True,
    )


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
