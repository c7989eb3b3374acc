"""``simulate``: a simulated run with known truth, written as a log and its truth (or as a
UTIAS MRCLAM dataset directory), with the replay line that tells the filter the true
noise. Deterministic: the same request writes the same bytes.
"""

from __future__ import annotations

import enum
import math
import shlex
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

from ekfviz.app.outputs import command_hint
from ekfviz.app.scenarios import (
    LoopSettings,
    ScenarioName,
    SensingSettings,
    TrueNoiseSettings,
    refuse_too_long,
)
from ekfviz.app.settings import Triple
from ekfviz.core.errors import UsageError
from ekfviz.core.params import FilterParams
from ekfviz.core.truth import GroundTruth
from ekfviz.io.files import check_output_folder, check_outputs, refuse_overwrite, write_files_atomic
from ekfviz.sim.mrclam import MrclamNoise, MrclamWorld

if TYPE_CHECKING:
    from ekfviz.sim.scenarios import Scenario
    from ekfviz.sim.simulate import Noise, Simulation

DEFAULT_DURATION = MrclamWorld().duration_s


class Layout(str, enum.Enum):
    """One log (and its truth file), or a UTIAS MRCLAM dataset directory."""

    FILE = "file"
    MRCLAM = "mrclam"


class LogFormat(str, enum.Enum):
    """The format a log is written in."""

    CLASSIC = "classic"
    EXTENDED = "extended"


# what only one layout uses: (the request's name, the option's flag)
FILE_ONLY = (
    ("scenario", "--scenario"), ("log_format", "--format"), ("precision", "--precision"),
    ("laps", "--laps"), ("init_pose_sigma", "--init-pose-sigma"), ("steps", "--steps"),
    ("landmarks", "--landmarks"), ("max_range", "--max-range"), ("fov", "--fov"),
    ("unknown_ids", "--unknown-ids"), ("clutter", "--clutter"),
    ("detection_probability", "--detection-probability"),
)  # fmt: skip
MRCLAM_ONLY = (("duration", "--duration"),)


@dataclass(frozen=True, slots=True)
class SimulateRequest:
    """A simulation as asked.

    :param output: the log (``Layout.MRCLAM``: the dataset directory)
    :param truth_out: the truth file (a log's only: a dataset holds its own)
    :param log_format: None: classic for the classic scenarios, extended otherwise
    :param init_pose_sigma: the prior the true start is drawn from (None: the scenario's)
    :param force: replace existing files
    :param given: the names of the options the user gave: one the layout does not use
        is refused, not ignored
    """

    output: Path
    truth_out: Path | None = None
    layout: Layout = Layout.FILE
    duration: float = DEFAULT_DURATION
    scenario: ScenarioName = ScenarioName.CLASSIC
    seed: int = 0
    log_format: LogFormat | None = None
    loop: LoopSettings = field(default_factory=LoopSettings)
    true_noise: TrueNoiseSettings = field(default_factory=TrueNoiseSettings)
    init_pose_sigma: Triple | None = None
    precision: int = 6
    sensing: SensingSettings = field(default_factory=SensingSettings)
    laps: int = 1
    force: bool = False
    given: frozenset[str] = frozenset()


@dataclass(frozen=True, slots=True)
class Simulated:
    """What was written (``lines``: what to tell the user, the replay line last)."""

    files: list[Path]
    events: int
    lines: list[str]


def simulate(request: SimulateRequest) -> Simulated:
    """Write the simulated run as asked.

    :raises UsageError: an option the layout does not use, a run that cannot be
    :raises OutputError: an output that cannot be written (nothing is then)
    """
    for name, flag in FILE_ONLY if request.layout is Layout.MRCLAM else MRCLAM_ONLY:
        if name in request.given:
            raise UsageError(f"{flag}: not for --layout {request.layout.value}")
    if request.layout is Layout.MRCLAM:
        return _simulate_mrclam(request)
    return _simulate_log(request)


def _simulate_log(request: SimulateRequest) -> Simulated:
    """Write the simulated log and its truth, and say how to replay it."""
    from ekfviz.io.truth import truth_json

    output, truth_out = request.output, request.truth_out
    if truth_out is None:
        raise UsageError("--truth-out FILE is needed (except with --layout mrclam)")
    check_outputs(("--output", output), ("--truth-out", truth_out))
    refuse_overwrite(request.force, ("--output", output), ("--truth-out", truth_out))
    world = request.loop.world(request.scenario, request.seed)
    refuse_too_long(len(world.controls), request.laps)
    noise = request.true_noise.of(world)
    init_pose_sigma = request.init_pose_sigma or world.init_pose_sigma
    if request.sensing.unknown_ids and request.log_format is LogFormat.CLASSIC:
        raise UsageError(
            "--unknown-ids: the classic format has no id-less scans; use --format extended"
        )
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
    return Simulated(
        files=[output, truth_out],
        events=len(run.events),
        lines=[
            f"Wrote {output} ({len(run.events)} events) and {truth_out}",
            _replay_hint(request, world, noise, init_pose_sigma, log_format),
        ],
    )


def _log_text(
    run: Simulation, log_format: LogFormat, precision: int, noise: Noise, init_pose_sigma: Triple
) -> str:
    """The log in its format.

    :raises UsageError: a run the classic format cannot hold
    """
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
        raise UsageError(f"--format classic: {error}") from None


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
) -> str:
    """The replay line of the simulated log with the filter told the true noise."""
    defaults = FilterParams()
    replay_noise = [
        f"--sigma-{name.removeprefix('sigma_').replace('_', '-')} {value:g}"
        for name, value in asdict(noise).items()
        if value != getattr(defaults, name)
    ]
    if request.sensing.unknown_ids:
        replay_noise.append("--association jcbb")
    if any(world.start_xytheta):
        replay_noise.append("--init-pose " + " ".join(f"{v:.17g}" for v in world.start_xytheta))
    if tuple(init_pose_sigma) != defaults.init_pose_sigma:
        replay_noise.append("--init-pose-sigma " + " ".join(f"{v:g}" for v in init_pose_sigma))
    stated = (
        " (its header states it, and a replay takes it unless told otherwise)"
        if log_format is LogFormat.EXTENDED
        else ""
    )
    command = [
        shlex.quote(command_hint("ekfviz")), "replay", shlex.quote(str(request.output)),
        "--truth", shlex.quote(str(request.truth_out)), *replay_noise,
    ]  # fmt: skip
    return f"Replay it with the filter told the true noise{stated}:\n  " + " ".join(command)


def _simulate_mrclam(request: SimulateRequest) -> Simulated:
    """Write a simulated MRCLAM dataset directory (see :mod:`ekfviz.sim.mrclam`)."""
    from ekfviz.core.errors import OutputError
    from ekfviz.sim.mrclam import simulate_mrclam

    output = request.output
    if request.truth_out is not None:
        raise UsageError("--truth-out: with --layout mrclam the truth is in the dataset directory")
    check_output_folder(output, "--output")
    d = MrclamNoise()
    x, y, a, b, r = (
        default if g is None else g
        for default, g in zip(
            (d.sigma_x, d.sigma_y, d.sigma_alpha, d.sigma_bearing, d.sigma_range),
            request.true_noise.given, strict=True,
        )
    )  # fmt: skip
    noise = replace(d, sigma_x=x, sigma_y=y, sigma_alpha=a, sigma_bearing=b, sigma_range=r)
    world = MrclamWorld(duration_s=request.duration)
    files = simulate_mrclam(seed=request.seed, world=world, noise=noise)
    refuse_overwrite(request.force, *(("--output", output / name) for name in files))
    try:
        output.mkdir(exist_ok=True)  # its parent was checked: no folders made above it
    except OSError as error:
        raise OutputError(f"{output}: cannot make the directory ({error.strerror})") from None
    write_files_atomic({output / name: text.encode("utf-8") for name, text in files.items()})
    flags = " ".join(f"--sigma-{n.removeprefix('sigma_').replace('_', '-')} {v:g}"
                     for n, v in asdict(noise).items() if n.startswith("sigma_"))  # fmt: skip
    return Simulated(
        files=[output / name for name in files],
        events=0,
        lines=[
            f"Wrote the MRCLAM-layout dataset {output} ({len(files)} files, robot 1)",
            "Replay it with the filter told the true noise:\n  "
            f"{shlex.quote(command_hint('ekfviz'))} replay {shlex.quote(str(output))}"
            f" --motion-noise per-sqrt-second {flags}",
        ],
    )
