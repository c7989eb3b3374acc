"""The ``ekfviz`` command line: parse options, wire reader, filter and logger, print tables."""

from __future__ import annotations

import enum
import json
import math
import os
import shlex
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict, astuple
from pathlib import Path
from typing import Annotated, Any, NoReturn

import numpy as np
import typer
from rich import box
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, DownloadColumn, Progress, TimeRemainingColumn
from rich.table import Table

from ekfviz import __version__, signals
from ekfviz.core.consistency import Consistency, Verdict
from ekfviz.core.evaluation import Evaluation, evaluate
from ekfviz.core.filter import HAVE_KERNEL, FilterError, FilterParams, LandmarkInit, UpdateMode
from ekfviz.core.records import EventRecord, LogEvent
from ekfviz.core.replay import FilterLineError
from ekfviz.core.replay import replay as run_filter
from ekfviz.core.truth import GroundTruth
from ekfviz.io.errors import InputError
from ekfviz.io.extended import is_extended, read_log
from ekfviz.io.text import ProgressCallback
from ekfviz.io.truth import checked_against, read_truth
from ekfviz.sim.scenarios import Scenario, ScenarioName
from ekfviz.sim.simulate import Noise


class LogFormat(str, enum.Enum):
    CLASSIC = "classic"
    EXTENDED = "extended"


app = typer.Typer(
    help="Replay a 2-D EKF-SLAM run and explore it in Rerun.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
out = Console(highlight=False)
err = Console(stderr=True, highlight=False)

PROGRESS_MIN_BYTES = 1 << 20  # files under 1 MiB replay in well under a second
RECORDINGS_DIR = Path("recordings")


def fail(message: str, code: int = 2) -> NoReturn:
    """Print one line on stderr and exit: no traceback for a user's mistake (unless
    ``--debug``, and then only when called while handling an exception)."""
    if DEBUG["traceback"] and sys.exc_info()[1] is not None:
        raise
    err.print(f"[bold red]error:[/] {escape(message)}", soft_wrap=True)
    raise typer.Exit(code)


def _version(value: bool) -> None:
    if value:
        kernel = "compiled" if HAVE_KERNEL else "numpy (the compiled kernel was not built)"
        out.print(f"ekfviz {__version__}, filter kernel for small maps: {kernel}")
        raise typer.Exit()


DEBUG = {"traceback": False}


@app.callback()
def main(
    ctx: typer.Context,
    version: Annotated[
        bool,
        typer.Option("--version", callback=_version, is_eager=True, help="Print the version."),
    ] = False,
    debug: Annotated[
        bool, typer.Option("--debug", help="Show the traceback of an error, not one line.")
    ] = False,
) -> None:
    """Replay a 2-D EKF-SLAM run and explore it in Rerun."""
    DEBUG["traceback"] = debug
    if ctx.invoked_subcommand != "replay":  # only a replay keeps signals for later
        signals.restore()


def warn(message: str) -> None:
    """One line on stderr that does not stop the run."""
    err.print(f"[yellow]warning:[/] {message}", soft_wrap=True, markup=True, highlight=False)


# -- options shared by several commands ------------------------------------------------

FILTER_NOISE = "Filter noise"
FILTER_OPTIONS = "Filter options"
TRUE_NOISE = "True noise (default: the scenario's)"
LOOP = "Loop scenario"


def _option(help: str, panel: str | None = None, **kwargs: Any) -> Any:
    return typer.Option(help=help, rich_help_panel=panel, **kwargs)


SigmaX = Annotated[
    float, _option("Motion noise sigma along the heading (m).", FILTER_NOISE, min=0.0)
]
SigmaY = Annotated[float, _option("Motion noise sigma sideways (m).", FILTER_NOISE, min=0.0)]
SigmaAlpha = Annotated[
    float, _option("Motion noise sigma of the turn (rad).", FILTER_NOISE, min=0.0)
]
SigmaBearing = Annotated[
    float, _option("Measurement noise sigma of the bearing (rad); positive.", FILTER_NOISE)
]
SigmaRange = Annotated[
    float, _option("Measurement noise sigma of the range (m); positive.", FILTER_NOISE)
]
LandmarkInitOption = Annotated[
    LandmarkInit,
    _option("Keep the new landmark's cross-covariances (correlated) or drop them.", FILTER_OPTIONS),
]
UpdateOption = Annotated[
    UpdateMode,
    _option("Fold a line's landmarks one after another, or all at once.", FILTER_OPTIONS),
]
Triple = tuple[float, float, float]
DEFAULT = FilterParams()  # the classic defaults, stated once
InitPoseSigma = Annotated[
    Triple,
    _option(
        "Sigma of the initial pose prior at (0, 0, 0).", FILTER_OPTIONS, metavar="SX SY STHETA"
    ),
]
LogArgument = Annotated[
    Path, typer.Argument(help="Log in the classic or the extended format.", show_default=False)
]
TruthOption = Annotated[
    Path | None, _option("True landmark positions: 'x y' per line, or JSON.", show_default=False)
]


def _true(what: str) -> Any:
    return _option(f"True {what}.", TRUE_NOISE, min=0.0, show_default=False)


TrueSigmaX = Annotated[float | None, _true("motion noise sigma along the heading")]
TrueSigmaY = Annotated[float | None, _true("motion noise sigma sideways")]
TrueSigmaAlpha = Annotated[float | None, _true("motion noise sigma of the turn")]
TrueSigmaBearing = Annotated[float | None, _true("bearing noise sigma")]
TrueSigmaRange = Annotated[float | None, _true("range noise sigma")]
ScenarioOption = Annotated[ScenarioName, _option("The world and route.")]
Steps = Annotated[
    int | None,
    _option("loop: controls in one lap [default: 1000].", LOOP, min=4, show_default=False),
]
Landmarks = Annotated[
    int | None,
    _option("loop: number of landmarks [default: 200].", LOOP, min=1, show_default=False),
]
MaxRange = Annotated[
    float | None,
    _option("loop: sensor range in metres [default: 15].", LOOP, min=0.0, show_default=False),
]
Fov = Annotated[
    float | None,
    _option(
        "loop: sensor field of view in degrees [default: 180].",
        LOOP,
        min=0.0,
        max=360.0,
        show_default=False,
    ),
]


def filter_params(
    sigmas: tuple[float, float, float, float, float],
    init_pose_sigma: Triple,
    landmark_init: LandmarkInit,
    update: UpdateMode,
) -> FilterParams:
    """The filter's parameters from the command line, refusing what cannot work."""
    sigma_x, sigma_y, sigma_alpha, sigma_bearing, sigma_range = sigmas
    if sigma_bearing <= 0 or sigma_range <= 0:
        fail("--sigma-bearing and --sigma-range must be positive: R must be invertible")
    if min(init_pose_sigma) < 0:
        fail("--init-pose-sigma values must not be negative")
    return FilterParams(
        sigma_x=sigma_x,
        sigma_y=sigma_y,
        sigma_alpha=sigma_alpha,
        sigma_bearing=sigma_bearing,
        sigma_range=sigma_range,
        init_pose_sigma=init_pose_sigma,
        landmark_init=landmark_init,
        update=update,
    )


def scenario_world(
    scenario: ScenarioName,
    seed: int,
    steps: int | None,
    landmarks: int | None,
    max_range: float | None,
    fov: float | None,
) -> Scenario:
    """The scenario asked for; the loop options are refused for the classic one."""
    from ekfviz.sim import scenarios

    options: dict[str, Any] = {
        "steps": steps, "landmarks": landmarks, "max_range": max_range, "fov_deg": fov
    }  # fmt: skip
    given = {name: value for name, value in options.items() if value is not None}
    if scenario is ScenarioName.CLASSIC:
        if given:
            flags = (f"--{name.removesuffix('_deg').replace('_', '-')}" for name in given)
            fail(f"{', '.join(flags)}: only for --scenario loop")
        return scenarios.classic()
    return scenarios.loop(seed=seed, **given)


def true_noise(world: Scenario, *given: float | None) -> Noise:
    """The scenario's own noise, with the values given on the command line instead."""
    return Noise(*(d if g is None else g for g, d in zip(given, astuple(world.noise), strict=True)))


@app.command()
def replay(
    data: LogArgument,
    truth: TruthOption = None,
    report: Annotated[
        Path | None, typer.Option(help="Write the evaluation as JSON here.", show_default=False)
    ] = None,
    sigma_x: SigmaX = DEFAULT.sigma_x,
    sigma_y: SigmaY = DEFAULT.sigma_y,
    sigma_alpha: SigmaAlpha = DEFAULT.sigma_alpha,
    sigma_bearing: SigmaBearing = DEFAULT.sigma_bearing,
    sigma_range: SigmaRange = DEFAULT.sigma_range,
    init_pose_sigma: InitPoseSigma = DEFAULT.init_pose_sigma,
    landmark_init: LandmarkInitOption = DEFAULT.landmark_init,
    update: UpdateOption = DEFAULT.update,
    save: Annotated[
        Path | None,
        typer.Option(
            help="Write the recording to this .rrd file.",
            show_default=False,
            rich_help_panel="Rerun output",
        ),
    ] = None,
    spawn: Annotated[
        bool,
        typer.Option(
            "--spawn", help="Open the native Rerun viewer.", rich_help_panel="Rerun output"
        ),
    ] = False,
    serve: Annotated[
        bool,
        typer.Option(
            "--serve",
            help="Serve the web viewer on localhost until Ctrl-C.",
            rich_help_panel="Rerun output",
        ),
    ] = False,
    connect: Annotated[
        str | None,
        typer.Option(
            help="Stream to a running viewer at this gRPC URL.",
            show_default=False,
            rich_help_panel="Rerun output",
        ),
    ] = None,
    detail: Annotated[
        bool,
        typer.Option(
            "--detail",
            help="Log every landmark's ellipse at every update, even in a large map"
            " (by default a map of over 32 landmarks is logged whole every 25 steps).",
            rich_help_panel="Rerun output",
        ),
    ] = False,
) -> None:
    """Replay a log through EKF-SLAM, record it for Rerun and print the evaluation.

    With no Rerun output option, the native viewer opens where a display exists;
    otherwise the recording is saved to recordings/<input name>.rrd.
    """
    from ekfviz import viz  # rerun loads only for commands that record

    params = filter_params(
        (sigma_x, sigma_y, sigma_alpha, sigma_bearing, sigma_range),
        init_pose_sigma,
        landmark_init,
        update,
    )
    try:
        truth_xy = read_truth(truth) if truth is not None else None
        sinks, note = viz.resolve_default_sinks(
            viz.Sinks(save=save, spawn=spawn, serve=serve, connect=connect),
            data,
            RECORDINGS_DIR,
        )
        info = viz.run_info(
            name=data.stem,
            command=shlex.join(["ekfviz", *sys.argv[1:]]),
            parameters=params.as_dict(),
            input_path=data,
            truth=truth_xy,
            truth_path=truth,
        )
        with (
            open_progress(data) as progress,
            viz.open_run(info, sinks, detail=detail) as logger,
            signals.as_exceptions(),
        ):
            last: EventRecord | None = None
            consistency = Consistency(truth_xy)
            warnings = FilterWarnings(data)
            try:
                for record in run_filter(log_events(data, truth_xy, truth, progress), params):
                    logger.log(record)
                    consistency.add(record)
                    if record.warnings:
                        warnings.add(record)
                    last = record
                    if record.event == 0:  # a signal during start-up: stop, with a recording
                        signals.raise_pending()
            except (InputError, FilterLineError, KeyboardInterrupt, signals.Terminated) as cause:
                final = None if last is None else evaluate(last, truth_xy, consistency)
                reason = stop_reason(cause, data, last)
                kept = logger.stop(reason, final)
                raise RunStopped(reason, cause, kept) from cause
            assert last is not None  # replay always yields the initialisation
            evaluation = evaluate(last, truth_xy, consistency)
            logger.finish(evaluation)
            warnings.summarise()
            print_evaluation(evaluation, truth_xy)
            if report is not None:
                write_json(report, report_json(evaluation, params, data, info.input_sha256))
            if truth_xy is not None:
                mismatch_note(params, truth_xy)
            if note:
                out.print(note)
            if logger.url:
                out.print(f"Serving the web viewer at [bold]{logger.url}[/] (Ctrl-C to stop)")
            logger.wait_while_serving()
    except RunStopped as stopped:
        where = ""
        if stopped.kept and sinks.save is not None:
            where = f"; the recording of everything before it is saved in {sinks.save}"
        fail(f"{stopped.reason}{where}", code=stopped.exit_code)
    except (InputError, FilterError, viz.SinkError) as error:
        fail(str(error))
    except (KeyboardInterrupt, signals.Terminated) as signal_error:
        raise typer.Exit(143 if isinstance(signal_error, signals.Terminated) else 130) from None


@app.command()
def info(
    recording: Annotated[
        Path, typer.Argument(help="A recording written by ekfviz.", show_default=False)
    ],
    extract_input: Annotated[
        Path | None,
        typer.Option(help="Write the embedded input log here, byte for byte.", show_default=False),
    ] = None,
) -> None:
    """Print how a recording was made (version, command, parameters, input) and its result."""
    from ekfviz import viz

    try:
        found = viz.read_recording_info(recording)
    except viz.NotARecordingError as error:
        fail(str(error))
    table = Table(show_header=False, box=None, pad_edge=False)
    table.add_column(style="bold")
    table.add_column(overflow="fold")
    for key, value in found.summary():
        table.add_row(key, value)
    out.print(table)
    if found.evaluation_markdown:
        from rich.markdown import Markdown

        out.print(Markdown(found.evaluation_markdown))
    if extract_input is not None:
        if found.input_text is None:
            fail(f"{recording}: the input is not embedded (it was over the size cap)")
        write_bytes_atomic(extract_input, found.input_text.encode("utf-8"))
        out.print(f"Wrote the input to {extract_input}")


@app.command()
def simulate(
    output: Annotated[
        Path, typer.Option("-o", "--output", help="Where to write the log.", show_default=False)
    ],
    truth_out: Annotated[
        Path,
        typer.Option(help="Where to write the truth (JSON: landmarks, poses).", show_default=False),
    ],
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
            " assume [default: classic 0.02 0.02 0.1, loop 0.01 0.01 0.005].",
            show_default=False,
        ),
    ] = None,
    precision: Annotated[int, typer.Option(min=1, max=17, help="Decimals written.")] = 6,
) -> None:
    """Simulate a run with known truth and write its log and truth files (deterministic)."""
    from ekfviz.io.classic import format_classic
    from ekfviz.io.extended import format_extended
    from ekfviz.io.truth import truth_json

    world = scenario_world(scenario, seed, steps, landmarks, max_range, fov)
    noise = true_noise(
        world, true_sigma_x, true_sigma_y, true_sigma_alpha, true_sigma_bearing, true_sigma_range
    )
    if init_pose_sigma is None:
        init_pose_sigma = world.init_pose_sigma
    run = world.run(noise, seed=seed, init_pose_sigma=init_pose_sigma)
    if log_format is None:
        log_format = LogFormat.CLASSIC if scenario is ScenarioName.CLASSIC else LogFormat.EXTENDED
    try:
        text = (
            format_classic(run.events, precision)
            if log_format is LogFormat.CLASSIC
            else format_extended(run.events, precision)
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
        "steps": len(world.controls),
    }
    write_bytes_atomic(output, text.encode("utf-8"))
    write_bytes_atomic(truth_out, truth_json(truth, **extra).encode("utf-8"))
    out.print(f"Wrote {output} ({len(run.events)} events) and {truth_out}")
    replay_noise = [
        f"--sigma-{name.removeprefix('sigma_').replace('_', '-')} {value:g}"
        for name, value in asdict(noise).items()
        if value != getattr(FilterParams(), name)
    ]
    if tuple(init_pose_sigma) != FilterParams().init_pose_sigma:
        replay_noise.append("--init-pose-sigma " + " ".join(f"{v:g}" for v in init_pose_sigma))
    out.print(
        "Replay it with the filter told the true noise:\n  "
        + " ".join(["ekfviz replay", str(output), "--truth", str(truth_out), *replay_noise]),
        soft_wrap=True,
    )


@app.command()
def consistency(
    scenario: ScenarioOption = ScenarioName.CLASSIC,
    runs: Annotated[int, _option("Number of Monte-Carlo runs.", min=1)] = 50,
    seed: Annotated[int, _option("Seed of the first run; run k uses seed + k.")] = 0,
    sigma_x: SigmaX = DEFAULT.sigma_x,
    sigma_y: SigmaY = DEFAULT.sigma_y,
    sigma_alpha: SigmaAlpha = DEFAULT.sigma_alpha,
    sigma_bearing: SigmaBearing = DEFAULT.sigma_bearing,
    sigma_range: SigmaRange = DEFAULT.sigma_range,
    init_pose_sigma: Annotated[
        Triple | None,
        _option(
            "The prior the true start is drawn from AND the filter's initial covariance"
            " [default: the scenario's: classic 0.02 0.02 0.1, loop 0.01 0.01 0.005].",
            FILTER_OPTIONS,
            metavar="SX SY STHETA",
            show_default=False,
        ),
    ] = None,
    landmark_init: LandmarkInitOption = DEFAULT.landmark_init,
    update: UpdateOption = DEFAULT.update,
    true_sigma_x: TrueSigmaX = None,
    true_sigma_y: TrueSigmaY = None,
    true_sigma_alpha: TrueSigmaAlpha = None,
    true_sigma_bearing: TrueSigmaBearing = None,
    true_sigma_range: TrueSigmaRange = None,
    steps: Steps = None,
    landmarks: Landmarks = None,
    max_range: MaxRange = None,
    fov: Fov = None,
    report: Annotated[
        Path | None,
        _option("Write the averaged curves and verdict as JSON here.", show_default=False),
    ] = None,
    save: Annotated[
        Path | None, _option("Write the averaged curves to this .rrd file.", show_default=False)
    ] = None,
    workers: Annotated[
        int | None, _option("Processes to use [default: one per core].", min=1, show_default=False)
    ] = None,
) -> None:
    """Monte-Carlo consistency: average NEES and NIS over many simulated runs, per step.

    A consistent filter keeps the averaged NEES inside its 95% chi-square bounds; above
    them it is over-confident, below them too cautious.
    """
    from ekfviz.sim.montecarlo import Trials, monte_carlo

    world = scenario_world(scenario, seed, steps, landmarks, max_range, fov)
    prior = world.init_pose_sigma if init_pose_sigma is None else init_pose_sigma
    params = filter_params(
        (sigma_x, sigma_y, sigma_alpha, sigma_bearing, sigma_range), prior, landmark_init, update
    )
    noise = true_noise(
        world, true_sigma_x, true_sigma_y, true_sigma_alpha, true_sigma_bearing, true_sigma_range
    )
    trials = Trials(scenario=world, true_noise=noise, init_pose_sigma=prior, params=params)
    with err.status(f"{runs} runs of the {scenario.value} scenario..."):
        result = monte_carlo(trials, runs, seed=seed, workers=workers)

    table = Table(title=f"Consistency over {runs} runs ({scenario.value})", title_justify="left")
    for column in ("statistic", "inside 95%", "above", "below", "verdict"):
        table.add_column(column, justify="left" if column in ("statistic", "verdict") else "right")
    for name, count in (("mean NEES per step", result.nees), ("mean NIS per step", result.nis)):
        verdict = count.verdict
        colour = "green" if verdict is Verdict.CONSISTENT else "bold red"
        table.add_row(
            name,
            f"{count.inside}/{count.total} ({count.fraction_inside:.1%})" if count.total else "-",
            str(count.above),
            str(count.below),
            "-" if verdict is None else f"[{colour}]{verdict.value}[/]",
        )
    out.print(table)
    verdict = result.nees.verdict
    if verdict is not None:
        out.print(f"The filter looks [bold]{verdict.value}[/] on this scenario (by its NEES).")
    settings = {
        "scenario": scenario.value,
        "runs": runs,
        "seed": seed,
        "filter": params.as_dict(),
        "true_noise": asdict(noise),
        "init_pose_sigma": list(prior),
    }
    if report is not None:
        write_json(report, {"ekfviz_version": __version__, **settings, **result.to_json()})
    if save is not None:
        from ekfviz.viz.montecarlo import save_monte_carlo

        lines = [f"# Consistency: {scenario.value}, {runs} runs", ""]
        lines += [f"- **{key}** `{json.dumps(value)}`" for key, value in settings.items()]
        if verdict is not None:
            lines += ["", f"**Verdict (NEES):** {verdict.value}"]
        save_monte_carlo(save, result, f"consistency-{scenario.value}", "\n".join(lines) + "\n")
        out.print(f"Saved {save}; open it with: rerun {save}")


class Preset(str, enum.Enum):
    TUNING = "tuning"


@app.command()
def sweep(
    data: LogArgument,
    truth: TruthOption = None,
    save: Annotated[
        Path | None,
        _option(
            "Write the recording here [default: recordings/<input>-sweep.rrd].", show_default=False
        ),
    ] = None,
    report: Annotated[
        Path | None, _option("Write the summary as JSON here.", show_default=False)
    ] = None,
    vary: Annotated[
        list[str] | None,
        _option(
            "NAME=V1,V2,...: values absolute (0.5) or factors of the baseline (x10, /10);"
            " repeat to vary several.",
            metavar="NAME=VALUES",
            show_default=False,
        ),
    ] = None,
    one_at_a_time: Annotated[
        bool, _option("Vary each --vary on its own around the baseline, not as a grid.")
    ] = False,
    preset: Annotated[
        Preset | None,
        _option(
            "tuning: each noise sigma x10 and /10, one at a time (11 variants).", show_default=False
        ),
    ] = None,
    sigma_x: SigmaX = DEFAULT.sigma_x,
    sigma_y: SigmaY = DEFAULT.sigma_y,
    sigma_alpha: SigmaAlpha = DEFAULT.sigma_alpha,
    sigma_bearing: SigmaBearing = DEFAULT.sigma_bearing,
    sigma_range: SigmaRange = DEFAULT.sigma_range,
    init_pose_sigma: InitPoseSigma = DEFAULT.init_pose_sigma,
    landmark_init: LandmarkInitOption = DEFAULT.landmark_init,
    update: UpdateOption = DEFAULT.update,
    workers: Annotated[
        int | None, _option("Processes to use [default: one per core].", min=1, show_default=False)
    ] = None,
) -> None:
    """Replay one log with filter parameters varied around a baseline, side by side.

    Every variant lands in one recording under variants/<name>/ on shared timelines, so
    that scrubbing moves them all together; a table compares them.
    """
    from ekfviz import viz
    from ekfviz.sweep import (
        SweepError,
        build_variants,
        parse_vary,
        run_variants,
        summarise,
        tuning_preset,
    )
    from ekfviz.viz.sweep import record_sweep

    baseline = filter_params(
        (sigma_x, sigma_y, sigma_alpha, sigma_bearing, sigma_range),
        init_pose_sigma,
        landmark_init,
        update,
    )
    try:
        if preset is Preset.TUNING:
            if vary:
                raise SweepError("--preset tuning and --vary: give one or the other")
            variants = tuning_preset(baseline)
        elif vary:
            variants = build_variants(
                baseline, [parse_vary(text) for text in vary], one_at_a_time=one_at_a_time
            )
        else:
            raise SweepError("nothing to vary: give --vary NAME=VALUES or --preset tuning")
    except SweepError as error:
        fail(str(error))
    target = save if save is not None else RECORDINGS_DIR / f"{data.stem}-sweep.rrd"
    try:
        truth_xy = read_truth(truth) if truth is not None else None
        for _ in log_events(data, truth_xy, truth):
            pass  # read the whole log once here: bad input stops the sweep before any work
        with Progress(console=err, transient=True) as bar:
            task = bar.add_task(f"{len(variants)} variants", total=len(variants))
            runs = run_variants(data, variants, truth_xy, workers, done=lambda _: bar.advance(task))
        summaries = [summarise(run, runs[0]) for run in runs]
        info = viz.run_info(
            name=f"{data.stem}-sweep",
            command=shlex.join(["ekfviz", *sys.argv[1:]]),
            parameters={
                "baseline": baseline.as_dict(),
                "variants": [variant.label for variant in variants],
            },
            input_path=data,
            truth=truth_xy,
            truth_path=truth,
        )
        table = sweep_table(summaries, truth_xy is not None)
        with viz.open_recording(info, viz.Sinks(save=target)) as recording:
            record_sweep(recording, runs, truth_xy, sweep_markdown(summaries))
    except (InputError, FilterError, viz.SinkError) as error:
        fail(str(error))
    out.print(table)
    if report is not None:
        write_json(
            report,
            {
                "ekfviz_version": __version__,
                "input": {"name": data.name, "sha256": info.input_sha256},
                "baseline": baseline.as_dict(),
                "variants": [
                    {**asdict(summary), **run.evaluation.to_json()}
                    for summary, run in zip(summaries, runs, strict=True)
                ],
            },
        )
    out.print(f"Saved {target}; open it with: rerun {target}")


def sweep_table(summaries: list[Any], has_truth: bool) -> Table:
    """The sweep's comparison table for the terminal (the report has every column)."""
    table = Table(title="Variants", title_justify="left", box=box.SIMPLE_HEAD, padding=(0, 1))
    columns = ["variant"]
    if has_truth:
        columns += ["mean err", "Mahal.", "in 3σ"]
    columns += ["Δ base", "NIS in", "reading"]
    for column in columns:
        table.add_column(column, justify="left" if column in ("variant", "reading") else "right")
    for s in summaries:
        cells = [s.label]
        if has_truth:
            inside = "-" if s.inside is None else f"{s.inside}/{s.landmarks}"
            cells += [_num(s.mean_error, 3), _num(s.mean_mahalanobis, 2), inside]
        nis_inside = "-" if s.nis_inside is None else f"{s.nis_inside:.0%}"
        cells += [f"{s.from_baseline:.3f}", nis_inside, s.reading]
        table.add_row(*(escape(c) for c in cells))
    return table


def sweep_markdown(summaries: list[Any]) -> str:
    """The sweep's comparison table as markdown, for the recording."""
    columns = ["variant", "mean error", "max error", "mean Mahalanobis", "in 3σ", "final pose",
               "Δ baseline", "mean NIS", "NIS in 95%", "reading"]  # fmt: skip
    rows = ["# Sweep", "", "| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    for s in summaries:
        pose = ", ".join(f"{v:.3f}" for v in s.final_pose)
        inside = "-" if s.inside is None else f"{s.inside}/{s.landmarks}"
        nis_inside = "-" if s.nis_inside is None else f"{s.nis_inside:.0%}"
        rows.append(
            f"| {s.label} | {_num(s.mean_error, 3)} | {_num(s.max_error, 3)} |"
            f" {_num(s.mean_mahalanobis, 2)} | {inside} | {pose} | {s.from_baseline:.3f} |"
            f" {_num(s.mean_nis, 2)} | {nis_inside} | {s.reading} |"
        )
    return "\n".join(rows) + "\n"


def _num(value: float | None, digits: int) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


@app.command()
def convert(
    source: Annotated[
        Path, typer.Argument(help="A log in the classic format.", show_default=False)
    ],
    target: Annotated[
        Path, typer.Argument(help="Where to write the extended log.", show_default=False)
    ],
) -> None:
    """Rewrite a classic log in the extended format, every number exactly as read."""
    from ekfviz.io.classic import read_classic
    from ekfviz.io.extended import format_extended

    try:
        events = list(read_classic(source))
    except InputError as error:
        fail(str(error))
    write_bytes_atomic(target, format_extended(events, precision=None).encode("utf-8"))
    out.print(f"Wrote {target} ({len(events)} events)")


# -- helpers ---------------------------------------------------------------------------


def log_events(
    data: Path,
    truth: GroundTruth | None,
    truth_path: Path | None,
    progress: ProgressCallback | None = None,
) -> Iterator[LogEvent]:
    """The log's events, checked against the truth's landmarks when there is one."""
    events = read_log(data, progress, warn)
    if truth is not None and truth_path is not None:
        events = checked_against(events, truth, truth_path, every_id=not is_extended(data))
    return events


class FilterWarnings:
    """Print the filter's warnings as ``FILE:LINE: warning: ...``, the first few only:
    the recording's log holds all of them."""

    PRINTED = 10

    def __init__(self, data: Path) -> None:
        self._data = data
        self.count = 0

    def add(self, record: EventRecord) -> None:
        for text in record.warnings:
            self.count += 1
            if self.count <= self.PRINTED:
                where = f"{self._data}:{record.line}" if record.line else str(self._data)
                warn(escape(f"{where}: {text}"))

    def summarise(self) -> None:
        if self.count > self.PRINTED:
            warn(
                f"{self.count - self.PRINTED} more filter warnings"
                f" ({self.count} in all) are in the recording's log"
            )


class RunStopped(Exception):
    """A replay cut short; ``kept`` says whether its recording was kept."""

    def __init__(self, reason: str, cause: BaseException, kept: bool) -> None:
        super().__init__(reason)
        self.reason = reason
        self.kept = kept
        if isinstance(cause, KeyboardInterrupt):
            self.exit_code = 130  # 128 + SIGINT, as a shell reports it
        elif isinstance(cause, signals.Terminated):
            self.exit_code = 143  # 128 + SIGTERM
        else:
            self.exit_code = 2


def stop_reason(cause: BaseException, data: Path, last: EventRecord | None) -> str:
    """One line saying why and where a replay stopped."""
    after = f"after input line {last.line}" if last is not None and last.line else "at the start"
    if isinstance(cause, KeyboardInterrupt):
        return f"{data}: interrupted (SIGINT) {after}"
    if isinstance(cause, signals.Terminated):
        return f"{data}: terminated (SIGTERM) {after}"
    if isinstance(cause, FilterLineError):
        return f"{data}:{cause.line}: {cause}"
    return str(cause)


@contextmanager
def open_progress(path: Path) -> Iterator[ProgressCallback | None]:
    """A progress bar over the bytes of ``path`` when it is long, else nothing."""
    try:
        size = path.stat().st_size
    except OSError:
        size = 0  # the reader reports a missing file
    if size < PROGRESS_MIN_BYTES:
        yield None
        return
    with Progress(
        "[progress.description]{task.description}",
        BarColumn(),
        DownloadColumn(),
        TimeRemainingColumn(),
        console=err,
        transient=True,
    ) as bar:
        task = bar.add_task(f"replaying {path.name}", total=size)
        yield lambda done: bar.update(task, completed=done)


def print_evaluation(evaluation: Evaluation, truth: GroundTruth | None) -> None:
    """The final landmark table and pose, with errors when the truth is known."""
    table = Table(title="Landmarks at the end of the run", title_justify="left")
    for column in ("id", "x", "y", "σ x", "σ y"):
        table.add_column(column, justify="right")
    if truth is not None:
        for column in ("error (m)", "Mahalanobis", "in 3σ"):
            table.add_column(column, justify="right")
    for r in evaluation.landmarks:
        cells = [str(r.id), *(f"{v:.4f}" for v in (*r.estimate, *r.sigma))]
        if truth is not None:
            if r.mahalanobis is None or r.euclidean is None:
                cells += ["-", "-", "no truth"]
            else:
                verdict = "[green]yes[/]" if r.inside_3sigma else "[bold red]no[/]"
                cells += [f"{r.euclidean:.4f}", f"{r.mahalanobis:.3f}", verdict]
        table.add_row(*cells)
    out.print(table)
    x, y, theta = evaluation.pose
    sx, sy, st = evaluation.pose_sigma
    out.print(
        f"Final pose: x {x:.4f} ± {sx:.4f} m, y {y:.4f} ± {sy:.4f} m, "
        f"theta {theta:.4f} ± {st:.4f} rad (± one sigma)"
    )
    if truth is not None:
        inside = sum(bool(r.inside_3sigma) for r in evaluation.landmarks)
        out.print(f"{inside} of {len(evaluation.landmarks)} landmarks inside their 3-sigma ellipse")
        missing = set(truth.ids.tolist()) - {r.id for r in evaluation.landmarks}
        if missing:
            out.print(f"[yellow]never observed: landmarks {sorted(missing)}[/]")
    if evaluation.consistency is not None:
        for line in evaluation.consistency.summary():
            out.print(line)


def mismatch_note(params: FilterParams, truth: GroundTruth) -> None:
    """Say so when the filter was told other noise levels than the simulator used."""
    told = params.as_dict()
    flags = [
        f"--{name.replace('_', '-')} " + " ".join(f"{v:g}" for v in np.atleast_1d(value))
        for name, value in (truth.simulated_with or {}).items()
        if name in told and not np.allclose(np.asarray(told[name], dtype=float), value)
    ]
    if flags:
        out.print(
            "[yellow]note:[/] the truth file says the log was simulated with other noise"
            f" levels than the filter was told; to match them: {' '.join(flags)}",
            soft_wrap=True,
        )


def report_json(
    evaluation: Evaluation, params: FilterParams, data: Path, sha256: str
) -> dict[str, object]:
    return {
        "ekfviz_version": __version__,
        "input": {"name": data.name, "sha256": sha256},
        "parameters": params.as_dict(),
        **evaluation.to_json(),
    }


def write_json(path: Path, document: dict[str, object]) -> None:
    write_bytes_atomic(path, (json.dumps(document, indent=2) + "\n").encode("utf-8"))


def write_bytes_atomic(path: Path, content: bytes) -> None:
    """Write beside ``path`` and rename, so an existing file is never left half-written."""
    path = path.resolve()
    try:
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    except OSError as error:
        fail(f"{path}: cannot write ({error.strerror})")
    try:
        with os.fdopen(fd, "wb") as handle:
            handle.write(content)
        os.chmod(tmp, _file_mode(path))
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _file_mode(path: Path) -> int:
    """The mode a file written at ``path`` should get: the old file's, else the umask's."""
    try:
        return path.stat().st_mode & 0o777
    except OSError:
        umask = os.umask(0)
        os.umask(umask)
        return 0o666 & ~umask
