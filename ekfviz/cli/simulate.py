"""``ekfviz simulate``: simulated runs with known truth."""

from __future__ import annotations

import enum
import math
from dataclasses import asdict, replace
from pathlib import Path
from typing import Annotated

import typer

from ekfviz.cli.common import (
    Clutter,
    DetectionProbability,
    ForceOption,
    Fov,
    Landmarks,
    Laps,
    LogFormat,
    MaxRange,
    ScenarioOption,
    Steps,
    TrueSigmaAlpha,
    TrueSigmaBearing,
    TrueSigmaRange,
    TrueSigmaX,
    TrueSigmaY,
    UnknownIds,
    _option,
    app,
    check_outputs,
    command_hint,
    detection_of,
    fail,
    out,
    refuse_overwrite,
    scenario_world,
    true_noise,
    write_bytes_atomic,
)
from ekfviz.core.truth import GroundTruth
from ekfviz.filters.ekf import FilterParams
from ekfviz.io.paths import OutputPathError, check_output_folder
from ekfviz.sim.mrclam import MrclamNoise, MrclamWorld
from ekfviz.sim.scenarios import ScenarioName


class Layout(str, enum.Enum):
    FILE = "file"
    MRCLAM = "mrclam"


@app.command()
def simulate(
    output: Annotated[
        Path,
        typer.Option(
            "-o",
            "--output",
            help="Where to write the log (with --layout mrclam: the dataset directory).",
            show_default=False,
        ),
    ],
    truth_out: Annotated[
        Path | None,
        typer.Option(
            help="Where to write the truth (JSON: landmarks, poses); not for --layout mrclam.",
            show_default=False,
        ),
    ] = None,
    layout: Annotated[
        Layout,
        typer.Option(
            help="file: one log (and --truth-out); mrclam: a UTIAS MRCLAM dataset directory"
            " (robot 1, odometry at 50 Hz, camera at 5 Hz, Vicon-like truth), noise per"
            " sqrt(s) for the motion.",
        ),
    ] = Layout.FILE,
    duration: Annotated[
        float, typer.Option(help="mrclam: seconds of the run.", min=1.0)
    ] = MrclamWorld().duration_s,
    scenario: ScenarioOption = ScenarioName.CLASSIC,
    seed: Annotated[int, _option("Seed of the noise (and of the loop's landmark field).")] = 0,
    log_format: Annotated[
        LogFormat | None,
        typer.Option(
            "--format",
            help="Log format; default classic for classic, extended for loop.",
            show_default=False,
        ),
    ] = None,
    steps: Steps = None,
    landmarks: Landmarks = None,
    max_range: MaxRange = None,
    fov: Fov = None,
    true_sigma_x: TrueSigmaX = None,
    true_sigma_y: TrueSigmaY = None,
    true_sigma_alpha: TrueSigmaAlpha = None,
    true_sigma_bearing: TrueSigmaBearing = None,
    true_sigma_range: TrueSigmaRange = None,
    init_pose_sigma: Annotated[
        tuple[float, float, float] | None,
        typer.Option(
            metavar="SX SY STHETA",
            help="The true start is drawn from N(0, diag(sigma^2)), the prior a filter should"
            " assume \\[default: classic 0.02 0.02 0.1, loop 0.01 0.01 0.005].",
            show_default=False,
        ),
    ] = None,
    precision: Annotated[int, typer.Option(min=1, max=17, help="Decimals written.")] = 6,
    unknown_ids: UnknownIds = False,
    clutter: Clutter = 0.0,
    detection_probability: DetectionProbability = 1.0,
    laps: Laps = 1,
    force: ForceOption = False,
) -> None:
    """Simulate a run with known truth and write its log and truth files (deterministic)."""
    if layout is Layout.MRCLAM:
        _simulate_mrclam(
            output, seed, duration, truth_out,
            (true_sigma_x, true_sigma_y, true_sigma_alpha, true_sigma_bearing, true_sigma_range),
            force,
        )  # fmt: skip
        return
    if truth_out is None:
        fail("--truth-out FILE is needed (except with --layout mrclam)")
    from ekfviz.io.classic import format_classic
    from ekfviz.io.extended import format_extended
    from ekfviz.io.truth import truth_json

    check_outputs(("--output", output), ("--truth-out", truth_out))
    refuse_overwrite(force, ("--output", output), ("--truth-out", truth_out))
    world = scenario_world(scenario, seed, steps, landmarks, max_range, fov)
    noise = true_noise(
        world, true_sigma_x, true_sigma_y, true_sigma_alpha, true_sigma_bearing, true_sigma_range
    )
    if init_pose_sigma is None:
        init_pose_sigma = world.init_pose_sigma
    if unknown_ids and log_format is LogFormat.CLASSIC:
        fail("--unknown-ids: the classic format has no id-less scans; use --format extended")
    detection = detection_of(unknown_ids, clutter, detection_probability)
    run = world.run(
        noise, seed=seed, init_pose_sigma=init_pose_sigma, detection=detection, laps=laps
    )
    if log_format is None:
        classic = scenario in (ScenarioName.CLASSIC, ScenarioName.EDGE) and not unknown_ids
        log_format = LogFormat.CLASSIC if classic else LogFormat.EXTENDED
    try:
        text = (
            format_classic(run.events, precision)
            if log_format is LogFormat.CLASSIC
            else format_extended(
                run.scan_events or run.events,
                precision,
                noise={**asdict(noise), "init_pose_sigma": (*init_pose_sigma,)},
            )
        )
    except ValueError as error:
        fail(f"--format classic: {error}")
    truth = GroundTruth(run.landmark_ids, run.landmarks_xy, run.poses_xytheta)
    extra: dict[str, object] = {
        "scenario": scenario.value,
        "seed": seed,
        "noise": asdict(noise),
        "init_pose_sigma": list(init_pose_sigma),
        "sensor": {
            "max_range": world.sensor.max_range if math.isfinite(world.sensor.max_range) else None,
            "fov_deg": math.degrees(world.sensor.fov),
        },
        "steps": len(world.controls) * laps,
    }
    if any(world.start_xytheta):
        extra["init_pose"] = list(world.start_xytheta)
    if laps > 1:
        extra["laps"] = laps
    if unknown_ids or detection_probability < 1.0:
        extra["detection"] = {"clutter": clutter, "probability": detection_probability}
    if run.scan_ids is not None:
        extra["scan_ids"] = [list(ids) for ids in run.scan_ids]
    write_bytes_atomic(output, text.encode("utf-8"))
    write_bytes_atomic(truth_out, truth_json(truth, **extra).encode("utf-8"))
    out.print(f"Wrote {output} ({len(run.events)} events) and {truth_out}")
    replay_noise = [
        f"--sigma-{name.removeprefix('sigma_').replace('_', '-')} {value:g}"
        for name, value in asdict(noise).items()
        if value != getattr(FilterParams(), name)
    ]
    if unknown_ids:
        replay_noise.append("--association jcbb")
    if any(world.start_xytheta):
        replay_noise.append("--init-pose " + " ".join(f"{v:.17g}" for v in world.start_xytheta))
    if tuple(init_pose_sigma) != FilterParams().init_pose_sigma:
        replay_noise.append("--init-pose-sigma " + " ".join(f"{v:g}" for v in init_pose_sigma))
    stated = (
        " (its header states it, and a replay takes it unless told otherwise)"
        if log_format is LogFormat.EXTENDED
        else ""
    )
    out.print(
        f"Replay it with the filter told the true noise{stated}:\n  "
        + " ".join(
            [
                command_hint("ekfviz"),
                "replay",
                str(output),
                "--truth",
                str(truth_out),
                *replay_noise,
            ]
        ),
        soft_wrap=True,
    )


def _simulate_mrclam(
    output: Path,
    seed: int,
    duration: float,
    truth_out: Path | None,
    sigmas: tuple[float | None, ...],
    force: bool,
) -> None:
    """Write a simulated MRCLAM dataset directory (see :mod:`ekfviz.sim.mrclam`)."""
    from ekfviz.sim.mrclam import simulate_mrclam

    if truth_out is not None:
        fail("--truth-out: with --layout mrclam the truth is in the dataset directory")
    try:
        check_output_folder(output, "--output")
    except OutputPathError as error:
        fail(str(error))
    d = MrclamNoise()
    x, y, a, b, r = (
        default if g is None else g
        for default, g in zip(
            (d.sigma_x, d.sigma_y, d.sigma_alpha, d.sigma_bearing, d.sigma_range), sigmas,
            strict=True,
        )
    )  # fmt: skip
    noise = replace(d, sigma_x=x, sigma_y=y, sigma_alpha=a, sigma_bearing=b, sigma_range=r)
    files = simulate_mrclam(seed=seed, world=MrclamWorld(duration_s=duration), noise=noise)
    refuse_overwrite(force, *(("--output", output / name) for name in files))
    try:
        output.mkdir(exist_ok=True)  # its parent was checked: no folders made above it
    except OSError as error:
        fail(f"{output}: cannot make the directory ({error.strerror})")
    for name, text in files.items():
        write_bytes_atomic(output / name, text.encode("utf-8"))
    out.print(f"Wrote the MRCLAM-layout dataset {output} ({len(files)} files, robot 1)")
    flags = " ".join(f"--sigma-{n.removeprefix('sigma_').replace('_', '-')} {v:g}"
                     for n, v in asdict(noise).items() if n.startswith("sigma_"))  # fmt: skip
    out.print(
        "Replay it with the filter told the true noise:\n  "
        + f"{command_hint('ekfviz')} replay {output} --motion-noise per-sqrt-second {flags}",
        soft_wrap=True,
    )
