"""``ekfviz calibrate``: estimate a log's noise and odometry errors from its ground truth,
judge the candidate settings on held-out time, print the replay line of the best."""

from __future__ import annotations

import shlex
from pathlib import Path
from typing import Annotated

import numpy as np
import typer

from ekfviz.association.gating import CHI2_2_999
from ekfviz.calibrate.fit import (
    WINDOW_S,
)
from ekfviz.calibrate.recommend import (
    FIT_SHARE,
    Candidate,
    Recommendation,
    recommend,
)
from ekfviz.calibrate.text import (
    calibration_json,
    candidates_table,
    choice_lines,
    estimates_table,
    method_lines,
    scaling_lines,
    tail_warnings,
)
from ekfviz.cli.common import (
    DEFAULT,
    app,
    check_outputs,
    command_hint,
    fail,
    not_nan,
    out,
    refuse_output_over_input,
    say,
    show,
    warn,
    write_json,
)
from ekfviz.cli.options import FilterForm, FilterNoise, StudyLogArgument, TruthOption
from ekfviz.cli.sources import (
    NO_SOURCE_ARGS,
    MotionNoiseChoice,
    first_time,
    open_log,
    resolve,
    with_source_options,
)
from ekfviz.core.errors import InputError
from ekfviz.core.records import NeedsIds, with_ids
from ekfviz.sources import SourceArgs

Window = Annotated[
    float,
    typer.Option(
        help="Seconds of odometry per motion window of a timestamped log.",
        min=0.01,
        max=3600.0,
        callback=not_nan,
    ),
]
FitShare = Annotated[
    float,
    typer.Option(
        help="The share of the run (by time, untimed: by events) the noise is fitted on;"
        " the rest judges the candidate settings.",
        min=0.2,
        max=0.9,
        callback=not_nan,
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
@with_source_options
def calibrate_command(
    data: StudyLogArgument,
    truth: TruthOption = None,
    source_args: SourceArgs = NO_SOURCE_ARGS,  # every format's options (--robot, --odom...)
    window: Window = WINDOW_S,
    fit_share: FitShare = FIT_SHARE,
    report: CalibrationReport = None,
) -> None:
    """Estimate the measurement noise, the motion noise and the systematic odometry errors
    from ground truth on the first part of the run, judge the candidates (the defaults, the
    estimates, the estimates scaled) on the rest, and print the replay line of the best.

    The truth is --truth (with true poses: a JSON file with "poses") or a dataset's own.
    """
    check_outputs(("--report", report), inputs=[data, truth])
    result, command = run_calibrate(data, truth, source_args, window, fit_share, report)
    if report is not None:
        try:
            write_json(report, calibration_json(result, data, command))
        except OSError as error:
            fail(f"{report}: cannot write the report: {error.strerror or error}")
    out.print(f"Replay with the recommended setting ({result.best.name}):")
    program = command_hint("ekfviz")
    if program != "ekfviz":
        out.print(f"(ekfviz is not on your PATH: run it as {program})", markup=False)
    # the line starts with "ekfviz replay", whatever runs here: scripts look for it
    out.print(shlex.join(command), soft_wrap=True, markup=False, highlight=False)


def run_calibrate(
    data: Path,
    truth: Path | None,
    source_args: SourceArgs,
    window: float,
    fit_share: float,
    report: Path | None = None,
) -> tuple[Recommendation, list[str]]:
    """The noise estimated and the candidates judged, printed; the best's replay line
    (``report``: where it goes, which may be none of a dataset directory's files)."""
    defaults_given = FilterForm().params(FilterNoise(), DEFAULT.init_pose_sigma, log=data)
    try:
        opened = open_log(data, source_args, truth, no_truth=False)
        refuse_output_over_input(("--report", report),
                                 inputs=[*opened.source.files, *opened.truth_files])  # fmt: skip
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
    except np.linalg.LinAlgError:  # (a ValueError: before it) a fit of too few samples
        fail(f"{data}: too short a run to calibrate on: its samples do not determine the"
             f" noise (fitted on the first {fit_share:.0%}); give a longer run")  # fmt: skip
    except ValueError as error:  # an id-less scan, a vehicle's controls, nothing to fit
        fail(f"{data}: {error}")
    show(estimates_table(result.calibration))
    say(method_lines(result.calibration))
    for text in tail_warnings(result.calibration):
        warn(text)
    say(scaling_lines(result))
    show(candidates_table(result))
    say(choice_lines(result))
    for note in result.notes:
        warn(note)
    command_options = opened.source.command_options(source_args)
    return result, _replay_line(result.best, data, command_options, truth)


def _replay_line(
    best: Candidate, data: Path, source_options: list[str], truth: Path | None
) -> list[str]:
    """The replay command of a candidate: only the options that differ from a plain
    replay's, sigmas with 6 significant digits; ``source_options`` open the source."""
    command = ["ekfviz", "replay", str(data), *source_options]
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
