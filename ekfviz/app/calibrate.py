"""``calibrate``: a log's noise and odometry errors estimated from its ground truth on the
first part of the run, the candidate settings judged on the rest, and the replay line of
the best."""

from __future__ import annotations

import shlex
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ekfviz.app.inputs import first_time, open_log, resolve
from ekfviz.app.outputs import command_hint
from ekfviz.app.reporting import Reporter
from ekfviz.app.settings import FilterSettings, MotionNoiseChoice, filter_params
from ekfviz.app.text import Block
from ekfviz.association.gating import CHI2_2_999
from ekfviz.calibrate.fit import WINDOW_S
from ekfviz.calibrate.recommend import FIT_SHARE, Candidate, Recommendation, recommend
from ekfviz.calibrate.text import (
    calibration_json,
    candidates_table,
    choice_lines,
    estimates_table,
    method_lines,
    scaling_lines,
    tail_warnings,
)
from ekfviz.core.errors import EkfvizError, InputError
from ekfviz.core.params import FilterParams
from ekfviz.core.records import NeedsIds, with_ids
from ekfviz.io.files import check_outputs, refuse_output_over_input, write_json
from ekfviz.sources import SourceArgs

__all__ = ["FIT_SHARE", "WINDOW_S", "CalibrateRequest", "Calibrated", "calibrate"]


@dataclass(frozen=True, slots=True)
class CalibrateRequest:
    """A calibration as asked: the log (``source_args``: its format's options) and its
    truth (None: the dataset's own), the seconds of odometry per motion window, the
    share of the run the noise is fitted on, the report, and whether every warning of
    the fit is said (else one line counts them)."""

    data: Path
    truth: Path | None = None
    source_args: SourceArgs = field(default_factory=SourceArgs)
    window: float = WINDOW_S
    fit_share: float = FIT_SHARE
    report: Path | None = None
    verbose: bool = False


@dataclass(frozen=True, slots=True)
class Calibrated:
    """What a calibration shows: its tables and lines in order, the best candidate's name
    and its replay line (``ekfviz replay ...``, whatever runs here: scripts look for it),
    and how ekfviz is run here where it is not on the user's PATH."""

    shown: list[Block]
    best: str
    command: list[str]
    program: str


def calibrate(request: CalibrateRequest, reporter: Reporter) -> Calibrated:
    """Estimate, judge, write the report.

    :raises InputError: a log without true poses or landmark ids, too short a run
    :raises OutputError: a report that cannot be written
    """
    data = request.data
    check_outputs(("--report", request.report), inputs=[data, request.truth])
    defaults_given = filter_params(FilterSettings(), log=data, note=reporter.note)
    try:
        result, replay_options = _recommend(request, defaults_given, reporter)
    except EkfvizError:
        raise
    except np.linalg.LinAlgError:  # (a ValueError: before it) a fit of too few samples
        raise InputError(data, 0, "too short a run to calibrate on: its samples do not determine"
                         f" the noise (fitted on the first {request.fit_share:.0%}); give a"
                         " longer run") from None  # fmt: skip
    except ValueError as error:  # an id-less scan, a vehicle's controls, nothing to fit
        raise InputError(data, 0, str(error)) from None
    shown: list[Block] = [
        estimates_table(result.calibration), method_lines(result.calibration),
        scaling_lines(result), candidates_table(result), choice_lines(result),
    ]  # fmt: skip
    _warn(reporter, [*tail_warnings(result.calibration), *result.notes], request.verbose)
    best = result.best
    command = [] if best is None else _replay_line(best, data, replay_options, request.truth)
    if request.report is not None:
        write_json(request.report, calibration_json(result, data, command))
    return Calibrated(shown, "" if best is None else best.name, command, command_hint("ekfviz"))


def _warn(reporter: Reporter, texts: list[str], verbose: bool) -> None:
    """The fit's warnings: each with ``verbose``, else one line that counts them."""
    if verbose:
        for text in texts:
            reporter.warn(text)
    elif texts:
        reporter.warn(f"{len(texts)} note(s) on the estimates and the choice: --verbose shows them")


def _recommend(
    request: CalibrateRequest, defaults_given: FilterParams, reporter: Reporter
) -> tuple[Recommendation, list[str]]:
    """The noise estimated and the candidates judged; the options that open the source."""
    data, truth = request.data, request.truth
    opened = open_log(data, request.source_args, truth, no_truth=False, warn=reporter.warn)
    refuse_output_over_input(("--report", request.report),
                             inputs=[*opened.source.files, *opened.truth_files])  # fmt: skip
    if opened.truth is None or not opened.truth.has_poses:
        raise InputError(
            truth or data, 0, "calibrate needs true poses: --truth FILE.json with"
            ' "poses", or a dataset directory with its ground-truth files',
        )  # fmt: skip
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
        events, opened.truth, defaults, defaults, window_s=request.window,
        fit_share=request.fit_share, heavy_tail_gate=CHI2_2_999,
    )  # fmt: skip
    return result, opened.source.command_options(request.source_args)


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


def replay_line(calibrated: Calibrated) -> str:
    """The replay command of the best candidate, quoted for a shell."""
    return shlex.join(calibrated.command)
