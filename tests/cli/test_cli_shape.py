"""The shape of the command line: thin commands, shared options declared once, tables
printed from beside the data they show."""

from __future__ import annotations

import ast
import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import pytest
import typer
from typer.testing import CliRunner

from ekfviz.app.grade_rows import GradeRow, grades_table
from ekfviz.cli import app
from ekfviz.cli.options import (
    Association,
    Execution,
    FilterForm,
    FilterNoise,
    LoopShape,
    OptionGroup,
    Sensing,
    TrueNoise,
    UserFilter,
    expands_options,
)
from ekfviz.core.tables import Styled
from ekfviz.core.truth import GroundTruth
from ekfviz.evaluation.consistency import BoundCount
from ekfviz.evaluation.errors import Evaluation, LandmarkResult
from ekfviz.studies.montecarlo import MonteCarlo

CLI = Path(__file__).parents[2] / "ekfviz" / "cli"
MAX_COMMAND_LINES = 60

# which commands take which group: a group dropped from a command (or a command that
# declares the options again by hand) fails here
TAKES: dict[type[OptionGroup], set[str]] = {
    FilterNoise: {"replay", "check", "compare", "sweep", "consistency", "grade", "watch"},
    FilterForm: {"replay", "check", "compare", "sweep", "consistency", "grade", "watch"},
    UserFilter: {"replay", "check", "compare", "sweep", "watch"},
    Association: {"replay", "compare", "sweep", "consistency"},
    Execution: {"compare", "sweep", "consistency", "grade"},
    TrueNoise: {"consistency", "simulate"},
    LoopShape: {"consistency", "simulate"},
    Sensing: {"consistency", "simulate"},
}


@dataclass(frozen=True, slots=True)
class Noise(FilterNoise):
    """The filter's noise with one option more, as one edit of the group would add it."""

    sigma_extra: Annotated[float, typer.Option(help="A new sigma.", min=0.0)] = 0.5


def _commands() -> dict[str, Any]:
    """The click commands typer builds (its own vendored click: typed loosely here)."""
    group: Any = typer.main.get_command(app)
    return dict(group.commands)


def _options(command: Any) -> dict[str, Any]:
    return {opt: p for p in command.params for opt in p.opts if opt.startswith("--")}


def test_no_command_function_is_over_60_lines() -> None:
    """Each command parses its options and calls one function (counted with ast, from
    the first decorator to the last line)."""
    found = {}
    for path in sorted(CLI.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if not isinstance(node, ast.FunctionDef):
                continue
            decorators = [ast.unparse(d) for d in node.decorator_list]
            if any(d.startswith("app.command") for d in decorators):
                start = min(d.lineno for d in node.decorator_list)
                assert node.end_lineno is not None
                found[f"{path.name}:{node.name}"] = node.end_lineno - start + 1
    assert len(found) == len(_commands()), sorted(found)  # every command was counted
    too_long = {name: lines for name, lines in found.items() if lines > MAX_COMMAND_LINES}
    assert not too_long, too_long


@pytest.mark.parametrize("group", list(TAKES), ids=lambda g: g.__name__)
def test_a_shared_group_is_the_same_options_on_every_command_that_takes_it(
    group: type[OptionGroup],
) -> None:
    commands = _commands()
    flags = group.option_names()
    assert flags and all(flag.startswith("--") for flag in flags)
    takers = {name for name, command in commands.items() if group in _groups_of(command)}
    assert takers == TAKES[group]
    first: dict[str, tuple[Any, ...]] = {}
    for name in sorted(takers):
        options = _options(commands[name])
        for flag in flags:
            assert flag in options, f"{name} lacks {flag}"
            param = options[flag]
            shown = (
                param.help,
                param.default,
                _bound(param, "min"),
                _bound(param, "max"),
                param.metavar,
                param.rich_help_panel,
            )
            assert first.setdefault(flag, shown) == shown, f"{name} {flag} differs"


def _bound(param: Any, which: str) -> Any:
    """An option's ``min`` or ``max``: on the option (typer 0.29) or its click type
    (typer 0.26-0.28, an IntRange or FloatRange)."""
    if hasattr(param, which):
        return getattr(param, which)
    return getattr(getattr(param, "type", None), which, None)


def _groups_of(command: Any) -> set[type[OptionGroup]]:
    """The groups a command's function takes (typer's callback wraps it, keeping the
    attributes :func:`expands_options` set)."""
    return set(getattr(command.callback, "__option_groups__", {}).values())


def test_an_option_added_to_a_group_appears_on_every_command_that_takes_it() -> None:
    """The one edit: a field added to the group shows on both commands, and each gets
    it back in its group with the value given."""

    seen: dict[str, Any] = {}
    demo = typer.Typer()

    @demo.command()
    @expands_options
    def one(*, noise: Noise, flag: Annotated[bool, typer.Option("--flag")] = False) -> None:
        seen["one"] = (noise, flag)

    @demo.command()
    @expands_options
    def two(*, noise: Noise) -> None:
        seen["two"] = noise

    runner = CliRunner()
    for argv in (["one", "--sigma-extra", "2", "--sigma-x", "0.3", "--flag"], ["two"]):
        result = runner.invoke(demo, argv)
        assert result.exit_code == 0, result.output
    noise, flag = seen["one"]
    assert (noise.sigma_extra, noise.sigma_x, noise.sigma_y, flag) == (2.0, 0.3, 0.1, True)
    assert seen["two"] == Noise()
    help_two = runner.invoke(demo, ["two", "--help"], env={"COLUMNS": "200"}).output
    assert "--sigma-extra" in help_two and "A new sigma." in help_two


def test_an_option_given_twice_is_refused_when_the_command_is_declared() -> None:
    with pytest.raises(TypeError, match="given twice"):

        @expands_options
        def clash(*, noise: FilterNoise, sigma_x: float = 0.0) -> None:
            del noise, sigma_x


def test_the_group_fields_are_the_options_of_the_filter_commands() -> None:
    """The replay's noise options come from the group: its defaults are the group's."""
    options = _options(_commands()["replay"])
    for field in dataclasses.fields(FilterNoise):
        flag = "--" + field.name.replace("_", "-")
        assert options[flag].default == field.default


def test_the_evaluation_table_and_lines_are_beside_the_evaluation() -> None:
    cov = np.diag([0.04, 0.09])
    landmarks = (
        LandmarkResult(1, np.array([1.0, 2.0]), cov, np.array([1.0, 2.1]), 0.1, 0.5, 0.05),
        LandmarkResult(2, np.array([3.0, 4.0]), cov, np.array([9.0, 9.0]), 7.8, 40.0, 7.0),
    )
    evaluation = Evaluation(np.array([0.5, 0.25, 0.1]), np.eye(3) * 0.01, landmarks, True)
    truth = GroundTruth(np.array([1, 2, 3]), np.array([[1.0, 2.1], [9.0, 9.0], [5.0, 5.0]]))
    table = evaluation.table(truth)
    assert table.columns[-1] == "in 3σ" and len(table.columns) == 9
    assert table.rows[0][:5] == ("1", "1.0000", "2.0000", "0.2000", "0.3000")
    assert table.rows[0][-1] == Styled("yes", "green")
    assert table.rows[1][-1] == Styled("no", "bold red")
    lines = evaluation.lines(truth)
    assert lines[0] == (
        "Final pose: x 0.5000 ± 0.1000 m, y 0.2500 ± 0.1000 m, theta 0.1000 ± 0.1000 rad"
        " (± one sigma)"
    )
    assert lines[1] == "1 of 2 landmarks inside their 3-sigma ellipse"
    assert lines[-1] == Styled("never observed: landmarks [3]", "yellow")
    assert len(evaluation.table(None).columns) == 5
    assert evaluation.lines(None) == lines[:1]


def test_the_monte_carlo_table_says_each_verdict() -> None:
    empty = np.zeros(0)
    result = MonteCarlo(
        runs=3, mean_nees=empty, nees_bounds=empty.reshape(0, 2), mean_nis=empty,
        nis_bounds=empty.reshape(0, 2), nees=BoundCount(below=0, inside=95, above=5),
        nis=BoundCount(),
    )  # fmt: skip
    table = result.table("Consistency")
    assert table.left == {"statistic", "verdict"}
    nees, nis = table.rows
    assert nees[:4] == ("mean NEES per step", "95/100 (95.0%)", "5", "0")
    assert isinstance(nees[4], Styled) and nees[4].text == result.nees.verdict.value  # type: ignore[union-attr]
    assert nis == ("mean NIS per step", "-", "0", "0", "-")


def test_a_submission_named_like_markup_is_printed_as_it_is() -> None:
    row = GradeRow("[bold]x[/bold]", "error", (), "", 1.25, detail="SyntaxError")
    table = grades_table([row])
    assert table.rows == (
        (Styled("[bold]x[/bold]"), Styled("error"), Styled(""), Styled("SyntaxError"),
         Styled("1.2")),
    )  # fmt: skip
    assert table.left == {"submission", "status", "causes", "first divergence"}


@pytest.mark.parametrize("width", [100, 60, 45])
def test_a_table_on_a_narrow_terminal_folds_its_numbers_and_never_cuts_them(
    width: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    """At 80 columns the landmarks' x and y were cut to "13.71..." (rich's ellipsis): a
    table now folds a cell onto more lines where it must, and drops its lines first."""
    import io

    from rich.console import Console

    from ekfviz.cli import console
    from ekfviz.core.tables import TextTable

    values = [f"{v:.4f}" for v in np.linspace(-58.7021, 74.2133, 9)]
    columns = ("id", "x", "y", "σ x", "σ y", "error (m)", "aligned (m)", "Mahalanobis", "in 3σ")
    table = TextTable("Landmarks", columns, tuple((str(k), *values[:8]) for k in range(3)))
    buffer = io.StringIO()
    monkeypatch.setattr(console, "out", Console(file=buffer, width=width, color_system=None))
    console.show(table)
    text = buffer.getvalue()
    assert "…" not in text and max(len(line) for line in text.splitlines()) <= width, text
    # no character of a cell is lost, folded or not (the digits: the cells' and the "3"
    # of "in 3σ")
    cells = [cell for row in table.rows for cell in row]
    digits = sum(ch.isdigit() for cell in cells for ch in str(cell)) + 1
    assert sum(ch.isdigit() for ch in text) == digits, text
    if width >= 100:  # room enough without the table's lines: every number on one line
        assert all(str(cell) in text for cell in cells), text
