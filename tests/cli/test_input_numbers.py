"""Numbers and times the readers refuse or keep: digits of other scripts, a number that
reads as zero, times a recording cannot hold, JSON's limits, and the line a truth file's
error names.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from commands import one_error_line
from typer.testing import CliRunner

from ekfviz.cli import app
from ekfviz.core.errors import InputError
from ekfviz.io.extended import read_extended
from ekfviz.io.jsontext import load_json
from ekfviz.io.text import numeric_blocks, numeric_lines

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "data"
runner = CliRunner()


@pytest.mark.parametrize("token", ["\u0661", "\uff11", "1_000", "\u0661.5"])
def test_digits_of_other_scripts_and_underscores_are_no_numbers(tmp_path: Path, token: str) -> None:
    """float() takes them; a log's reader must not (the classic reader, the extended one's
    ids and numbers, and the blocks of a dataset's files)."""
    classic = tmp_path / "log.txt"
    classic.write_text(f"{token} 5 0.2 6\n3 0\n")
    with pytest.raises(InputError, match="expected a decimal number"):
        list(numeric_lines(classic))
    extended = tmp_path / "ext.txt"
    extended.write_text(f"observe {token} 0.1 5\n")
    with pytest.raises(InputError, match="expected an integer >= 0"):
        list(read_extended(extended))
    table = tmp_path / "table.dat"
    table.write_text("1.0 2.0 3.0\n" * 5 + f"2.0 {token} 3.0\n")
    with pytest.raises(InputError, match=r":6: found .*expected a decimal number"):
        list(numeric_blocks(table, 3, "time v omega"))


UNDERFLOW = "which reads as 0 (a float64 holds no magnitude below 4.9e-324)"


@pytest.mark.parametrize(
    ("name", "text", "where"),
    [
        ("classic.txt", "0.1 5 0.2 6\n1e-400 0\n0.1 5\n", "classic.txt:2: found '1e-400', "),
        (
            "ext.txt",
            "observe 1 0.1 5 2 0.2 6\ncontrol 1 0\nobserve 1 7e-500 5\n",
            "ext.txt:3: found ",
        ),
        ("ext.txt", "# noise: sigma_x=3e-401\nobserve 1 0.1 5\n", "ext.txt:1: found '3e-401', "),
        ("truth.json", '{"landmarks": {"1": [0, 0],\n "2": [1e-400, 0]}}', "truth.json:2: found "),
        ("truth.txt", "0 0\n5e-500 1\n", "truth.txt:2: found '5e-500', "),
    ],
)
def test_a_nonzero_number_that_reads_as_zero_is_refused(
    tmp_path: Path, name: str, text: str, where: str
) -> None:
    """1e-400 is 0.0 to float() and strtod: a value the file does not hold. A zero written
    any way (0, -0.0, 0e-999) and a subnormal (1e-310) still read."""
    path = tmp_path / name
    path.write_text(text)
    if name.startswith("truth"):
        args = ["replay", str(DATA / "classic.txt"), "--truth", str(path)]
    else:
        args = ["replay", str(path)]
    result = CliRunner().invoke(app, [*args, "--save", str(tmp_path / "x.rrd")])
    assert result.exit_code == 2, result.output
    assert where in result.output and UNDERFLOW in result.output, result.output
    zeros = tmp_path / "zeros.txt"
    zeros.write_text("0.1 5 0.2 6\n0 -0.0\n0.1 5 0.2 6\n0e-999 1e-310\n0.1 5 0.2 6\n")
    result = CliRunner().invoke(app, ["replay", str(zeros), "--save", str(tmp_path / "z.rrd")])
    assert result.exit_code == 0, result.output


# -- times ---------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "time",
    [
        "1e10",
        pytest.param("-9.3e9", marks=pytest.mark.slow),
        pytest.param("2e11", marks=pytest.mark.slow),
        "1e18",
    ],
)
def test_a_time_a_recording_cannot_hold_is_refused_on_its_line(tmp_path: Path, time: str) -> None:
    """Rerun's timeline counts nanoseconds in 64 bits: such a time overflowed (a
    traceback) once the run was recorded."""
    log = tmp_path / "log.txt"
    log.write_text(f"1.0 observe 1 0.1 5 2 0.2 6\n{time} control 1 0\n")
    result = runner.invoke(app, ["replay", str(log), "--save", str(tmp_path / "r.rrd")])
    assert result.exit_code == 2
    one_error_line(result.output, f"{log}:2: found time {float(time):g}, expected seconds within")


def test_a_time_at_the_edge_of_the_timeline_is_recorded(tmp_path: Path) -> None:
    from ekfviz.io.text import MAX_TIME_S

    log = tmp_path / "log.txt"
    log.write_text(f"{MAX_TIME_S} observe 1 0.1 5 2 0.2 6\n{MAX_TIME_S} control 1 0\n")
    result = runner.invoke(app, ["replay", str(log), "--save", str(tmp_path / "r.rrd")])
    assert result.exit_code == 0, result.output


def test_datasets_refuse_such_times_naming_file_and_line(tmp_path: Path) -> None:
    from ekfviz.sim.mrclam import MrclamWorld, simulate_mrclam

    mrclam = tmp_path / "mrclam"
    mrclam.mkdir()
    for name, text in simulate_mrclam(world=MrclamWorld(duration_s=3.0)).items():
        (mrclam / name).write_text(text)
    odometry = mrclam / "Robot1_Odometry.dat"
    odometry.write_text(odometry.read_text() + "1e12 0.1 0.1\n")
    lines = len(odometry.read_text().splitlines())
    result = runner.invoke(app, ["replay", str(mrclam), "--no-truth",
                                 "--save", str(tmp_path / "m.rrd")])  # fmt: skip
    assert result.exit_code == 2
    assert f"{odometry}:{lines}: found time 1e+12" in result.output
    park = tmp_path / "park"
    park.mkdir()
    (park / "inputs.dat").write_text("1000.0 3 0\n1000.1 3 0\n2e10 3 0\n")
    (park / "measurements.dat").write_text("1000.05 10 1.5 0.3\n")
    result = runner.invoke(app, ["replay", str(park), "--save", str(tmp_path / "p.rrd")])
    assert result.exit_code == 2
    assert f"{park / 'inputs.dat'}:3: found time 2e+10" in result.output


# -- JSON limits ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("text", "line", "words"),
    [
        ('{"a": [1, 2],\n "b": NaN}', 2, "found NaN"),
        ('{"a":\n\n -Infinity}', 3, "found -Infinity"),
        ('{"a": 1e400}', 1, "found 1e400"),
        ('{"a": "[[[[' + "[" * 100 + '"}', None, None),  # brackets in a string do not nest
        ("\ufeff" + '{"a": 123456789012345678}', None, None),
        ('{"a": 1}\n{', 2, "invalid JSON"),
        ('{"landmarks": {"1": [0, 0],\n "1": [5, 5]}}', 2, "found the key '1' twice"),
    ],
)
def test_json_limits(tmp_path: Path, text: str, line: int | None, words: str | None) -> None:
    path = tmp_path / "t.json"
    path.write_text(text, encoding="utf-8")
    if words is None:
        assert isinstance(load_json(path), dict)
        return
    with pytest.raises(InputError) as caught:
        load_json(path)
    assert caught.value.line == line and words in caught.value.message


@pytest.mark.parametrize(
    ("text", "line", "words"),
    [
        (
            '{"landmarks": {\n "1": [3, 6],\n "2": [3, 6, 1]}}',
            3,
            "landmark 2 is [3, 6, 1], expected",
        ),
        ('{"landmarks": {\n "1": [3, 6],\n "01": [9, 9]}}', 3, "found landmark id '01' after '1'"),
        ('{"landmarks": {\n "7": [1234567890123456789, 0]}}', 2, "expected [x, y] within +-1e18"),
        ('{"landmarks": {"1": [0, 0]},\n "poses": [[0, 0]]}', 2, '"poses" must be a list'),
        ('{"landmarks": {"1": [0, 0]},\n\n "noise": {"sigma_x": -1}}', 3, '"noise" is'),
        ('{"landmarks": {\n "x1": [0, 0]}}', 2, "found landmark id 'x1'"),
        # the readers' line ends, CR alone too
        ('{\r"landmarks": {\r"1": [3, NaN]}}\r', 3, "found NaN"),
        ('{\r\n"landmarks": {\r"1": [3, 6],\r\n"01": [3, 6]}}', 4, "found landmark id '01'"),
        # a sigma: the line of its own key
        ('{"landmarks": {"1": [0, 0]},\n "noise": {\n  "sigma_x": 0.2,\n  "sigma_range": -1}}',
         4, '"noise" is'),
    ],
)  # fmt: skip
def test_a_truth_file_error_names_the_line_of_its_key(
    tmp_path: Path, text: str, line: int, words: str
) -> None:
    from ekfviz.io.truth import read_truth

    path = tmp_path / "t.json"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(InputError) as caught:
        read_truth(path)
    assert (caught.value.line, words in caught.value.message) == (line, True), caught.value
