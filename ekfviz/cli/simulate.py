"""``ekfviz simulate``: simulated runs with known truth."""

from __future__ import annotations

import enum
import math
import shlex
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from ekfviz.cli.common import (
    ForceOption,
    LogFormat,
    _option,
    app,
    check_outputs,
    command_hint,
    fail,
    given,
    not_nan,
    out,
    refuse_overwrite,
    write_files_atomic,
)
from ekfviz.cli.options import (
    MAX_TRUE_SIGMA,
    Laps,
    LoopShape,
    ScenarioOption,
    Sensing,
    TrueNoise,
    expands_options,
    refuse_too_long,
)
from ekfviz.core.params import FilterParams
from ekfviz.core.truth import GroundTruth
from ekfviz.io.paths import OutputPathError, check_output_folder
from ekfviz.sim.mrclam import MrclamNoise, MrclamWorld
from ekfviz.sim.scenarios import ScenarioName

if TYPE_CHECKING:
    from ekfviz.cli.common import Triple
    from ekfviz.sim.scenarios import Scenario
    from ekfviz.sim.simulate import Noise, Simulation


class Layout(str, enum.Enum):
    FILE = "file"
    MRCLAM = "mrclam"


OutputOption = Annotated[
    Path,
    typer.Option(
        "-o",
        "--output",
        help="Where to write the log (with --layout mrclam: the dataset directory).",
        show_default=False,
    ),
]
TruthOut = Annotated[
    Path | None,
    typer.Option(
        help="Where to write the truth (JSON: landmarks, poses); not for --layout mrclam.",
        show_default=False,
    ),
]
LayoutOption = Annotated[
    Layout,
    typer.Option(
        help="file: one log (and --truth-out); mrclam: a UTIAS MRCLAM dataset directory"
        " (robot 1, odometry at 50 Hz, camera at 5 Hz, Vicon-like truth), noise per"
        " sqrt(s) for the motion.",
    ),
]
DEFAULT_DURATION = MrclamWorld().duration_s
Duration = Annotated[
    float, _option("mrclam: seconds of the run.", min=1.0, max=1e6)  # (11 days)
]
NoiseSeed = Annotated[int, _option("Seed of the noise (and of the loop's landmark field).", min=0)]
FormatOption = Annotated[
    LogFormat | None,
    typer.Option(
        "--format",
        help="Log format; default classic for classic, extended for loop.",
        show_default=False,
    ),
]
TrueInitPoseSigma = Annotated[
    tuple[float, float, float] | None,
    typer.Option(
        min=0.0,
        max=MAX_TRUE_SIGMA,
        callback=not_nan,
        metavar="SX SY STHETA",
        help="The true start is drawn from N(0, diag(sigma^2)), the prior a filter should"
        " assume \\[default: classic 0.02 0.02 0.1, loop 0.01 0.01 0.005].",
        show_default=False,
    ),
]
Precision = Annotated[int, typer.Option(min=1, max=17, help="Decimals written.")]


@dataclass(frozen=True, slots=True)
class SimulateRequest:
    """A simulation as the command line asks for it."""

    output: Path
    truth_out: Path | None
    layout: Layout
    duration: float
    scenario: ScenarioName
    seed: int
    log_format: LogFormat | None
    loop: LoopShape
    true_noise: TrueNoise
    init_pose_sigma: tuple[float, float, float] | None
    precision: int
    sensing: Sensing
    laps: int
    force: bool


@app.command()
@expands_options
def simulate(
    *,
    output: OutputOption,
    truth_out: TruthOut = None,
    layout: LayoutOption = Layout.FILE,
    duration: Duration = DEFAULT_DURATION,
    scenario: ScenarioOption = ScenarioName.CLASSIC,
    seed: NoiseSeed = 0,
    log_format: FormatOption = None,
    loop: LoopShape,
    true_noise: TrueNoise,
    init_pose_sigma: TrueInitPoseSigma = None,
    precision: Precision = 6,
    sensing: Sensing,
    laps: Laps = 1,
    force: ForceOption = False,
) -> None:
    """Simulate a run with known truth and write its log and truth files (deterministic)."""
    request = SimulateRequest(
        output=output, truth_out=truth_out, layout=layout, duration=duration, scenario=scenario,
        seed=seed, log_format=log_format, loop=loop, true_noise=true_noise,
        init_pose_sigma=init_pose_sigma, precision=precision, sensing=sensing, laps=laps,
        force=force,
    )  # fmt: skip
    # an option the layout does not use is refused, not ignored without a word
    for name, flag in _FILE_ONLY if layout is Layout.MRCLAM else _MRCLAM_ONLY:
        if given(name):
            fail(f"{flag}: not for --layout {layout.value}")
    if layout is Layout.MRCLAM:
        _simulate_mrclam(output, seed, duration, truth_out, true_noise.given, force)
    else:
        run_simulate(request)


_FILE_ONLY = (
    ("scenario", "--scenario"), ("log_format", "--format"), ("precision", "--precision"),
    ("laps", "--laps"), ("init_pose_sigma", "--init-pose-sigma"), ("steps", "--steps"),
    ("landmarks", "--landmarks"), ("max_range", "--max-range"), ("fov", "--fov"),
    ("unknown_ids", "--unknown-ids"), ("clutter", "--clutter"),
    ("detection_probability", "--detection-probability"),
)  # fmt: skip
_MRCLAM_ONLY = (("duration", "--duration"),)


def run_simulate(request: SimulateRequest) -> None:
    """Write the simulated log and its truth, and say how to replay it."""
    output, truth_out = request.output, request.truth_out
    if truth_out is None:
        fail("--truth-out FILE is needed (except with --layout mrclam)")
    from ekfviz.io.truth import truth_json

    check_outputs(("--output", output), ("--truth-out", truth_out))
    refuse_overwrite(request.force, ("--output", output), ("--truth-out", truth_out))
    world = request.loop.world(request.scenario, request.seed)
    refuse_too_long(len(world.controls), request.laps)
    noise = request.true_noise.of(world)
    init_pose_sigma = request.init_pose_sigma
    if init_pose_sigma is None:
        init_pose_sigma = world.init_pose_sigma
    if request.sensing.unknown_ids and request.log_format is LogFormat.CLASSIC:
        fail("--unknown-ids: the classic format has no id-less scans; use --format extended")
    detection = request.sensing.detection()
    run = world.run(
        noise, seed=request.seed, init_pose_sigma=init_pose_sigma, detection=detection,
        laps=request.laps,
    )  # fmt: skip
    log_format = request.log_format
    if log_format is None:
        classic = request.scenario in (ScenarioName.CLASSIC, ScenarioName.EDGE)
        classic = classic and not request.sensing.unknown_ids
        log_format = LogFormat.CLASSIC if classic else LogFormat.EXTENDED
    text = _log_text(run, log_format, request.precision, noise, init_pose_sigma)
    extra = _truth_extra(request, world, run, noise, init_pose_sigma)
    truth = GroundTruth(run.landmark_ids, run.landmarks_xy, run.poses_xytheta)
    write_files_atomic(  # the pair together, or neither
        {output: text.encode("utf-8"), truth_out: truth_json(truth, **extra).encode("utf-8")}
    )
    out.print(f"Wrote {output} ({len(run.events)} events) and {truth_out}")
    _replay_hint(request, world, noise, init_pose_sigma, log_format)


def _log_text(
    run: Simulation, log_format: LogFormat, precision: int, noise: Noise, init_pose_sigma: Triple
) -> str:
    """The log in its format; one line for a run the classic format cannot hold."""
    from ekfviz.io.classic import format_classic
    from ekfviz.io.extended import format_extended

    try:
        if log_format is LogFormat.CLASSIC:
            return format_classic(run.events, precision)
        return format_extended(
            run.scan_events or run.events,
            precision,
            noise={**asdict(noise), "init_pose_sigma": (*init_pose_sigma,)},
        )
    except ValueError as error:
        fail(f"--format classic: {error}")


def _truth_extra(
    request: SimulateRequest,
    world: Scenario,
    run: Simulation,
    noise: Noise,
    init_pose_sigma: Triple,
) -> dict[str, object]:
    """What the truth file says of the simulation besides the truth."""
    extra: dict[str, object] = {
        "scenario": request.scenario.value,
        "seed": request.seed,
        "noise": asdict(noise),
        "init_pose_sigma": list(init_pose_sigma),
        "sensor": {
            "max_range": world.sensor.max_range if math.isfinite(world.sensor.max_range) else None,
            "fov_deg": math.degrees(world.sensor.fov),
        },
        "steps": len(world.controls) * request.laps,
    }
    if any(world.start_xytheta):
        extra["init_pose"] = list(world.start_xytheta)
    if request.laps > 1:
        extra["laps"] = request.laps
    sensing = request.sensing
    if sensing.unknown_ids or sensing.detection_probability < 1.0:
        extra["detection"] = {
            "clutter": sensing.clutter, "probability": sensing.detection_probability
        }  # fmt: skip
    if run.scan_ids is not None:
        extra["scan_ids"] = [list(ids) for ids in run.scan_ids]
    return extra


def _replay_hint(
    request: SimulateRequest,
    world: Scenario,
    noise: Noise,
    init_pose_sigma: Triple,
    log_format: LogFormat,
) -> None:
    """The replay line of the simulated log with the filter told the true noise."""
    output, truth_out, unknown_ids = request.output, request.truth_out, request.sensing.unknown_ids
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
                shlex.quote(command_hint("ekfviz")),
                "replay",
                shlex.quote(str(output)),
                "--truth",
                shlex.quote(str(truth_out)),
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
    write_files_atomic({output / name: text.encode("utf-8") for name, text in files.items()})
    out.print(f"Wrote the MRCLAM-layout dataset {output} ({len(files)} files, robot 1)")
    flags = " ".join(f"--sigma-{n.removeprefix('sigma_').replace('_', '-')} {v:g}"
                     for n, v in asdict(noise).items() if n.startswith("sigma_"))  # fmt: skip
    out.print(
        "Replay it with the filter told the true noise:\n  "
        + f"{shlex.quote(command_hint('ekfviz'))} replay {shlex.quote(str(output))}"
        f" --motion-noise per-sqrt-second {flags}",
        soft_wrap=True,
    )
