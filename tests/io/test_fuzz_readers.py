"""Random mutations of a valid input, per reader, never give a
traceback (an exception other than the reader's one-line error), a hang or a silent
success with input lost.

Mutations: truncation, byte flips, duplicated and swapped lines, huge and non-finite
numbers, other encodings, a byte-order mark, CR or CRLF line ends; for recordings read
back (``info``, ``export``), truncation and byte flips.
"""

from __future__ import annotations

import contextlib
import shutil
from collections.abc import Callable, Iterable
from pathlib import Path

import pytest
from conftest import few_by_default
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from parks import make_park
from typer.testing import CliRunner

from ekfviz.cli import app
from ekfviz.core.errors import InputError
from ekfviz.io.classic import read_classic
from ekfviz.io.extended import read_extended, read_log_noise
from ekfviz.io.text import token_lines
from ekfviz.io.truth import read_truth
from ekfviz.io.victoria import read_gps
from ekfviz.sources import open_source

runner = CliRunner()
FUZZ = settings(
    max_examples=60,
    deadline=5000,  # milliseconds: a hang fails the test
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
    derandomize=True,  # the same examples on every run: a failure is reproducible
)
NUMBERS = ["1e400", "-1e400", "nan", "NaN", "inf", "-Infinity", "1e300", "9" * 400, "1e19", "-0"]


@st.composite
def mutated(draw: st.DrawFn, valid: bytes) -> bytes:
    """``valid`` with one to three mutations."""
    data = valid
    for _ in range(draw(st.integers(1, 3))):
        kind = draw(
            st.sampled_from(
                ["truncate", "flip", "duplicate", "swap", "number", "encoding", "ends", "bom"]
            )
        )
        lines = data.split(b"\n")
        if kind == "truncate" and data:
            data = data[: draw(st.integers(0, len(data) - 1))]
        elif kind == "flip" and data:
            at = draw(st.integers(0, len(data) - 1))
            data = data[:at] + bytes([data[at] ^ draw(st.integers(1, 255))]) + data[at + 1 :]
        elif kind == "duplicate" and lines:
            k = draw(st.integers(0, len(lines) - 1))
            data = b"\n".join(lines[: k + 1] + lines[k:])
        elif kind == "swap" and len(lines) > 1:
            i, j = draw(st.integers(0, len(lines) - 1)), draw(st.integers(0, len(lines) - 1))
            lines[i], lines[j] = lines[j], lines[i]
            data = b"\n".join(lines)
        elif kind == "number" and lines:
            k = draw(st.integers(0, len(lines) - 1))
            tokens = lines[k].split()
            if tokens:
                t = draw(st.integers(0, len(tokens) - 1))
                tokens[t] = draw(st.sampled_from(NUMBERS)).encode()
                lines[k] = b" ".join(tokens)
                data = b"\n".join(lines)
        elif kind == "encoding":
            text = data.decode("utf-8", errors="replace")
            codec = draw(st.sampled_from(["utf-16", "utf-16-le", "latin-1", "cp1252"]))
            data = (text + "\n# café\n").encode(codec, errors="replace")
        elif kind == "ends":
            data = data.replace(b"\n", draw(st.sampled_from([b"\r", b"\r\n"])))
        elif kind == "bom":
            data = b"\xef\xbb\xbf" + data
    return data


def data_lines(path: Path) -> list[int]:
    """The numbers of the lines holding data, under the shared line policy."""
    return [number for number, _ in token_lines(path)]


def read_all(events: Iterable[object]) -> list[object]:
    return list(events)


@pytest.fixture(scope="module")
def valid(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("fuzz")
    made = {
        "classic": root / "classic.txt",
        "ext": root / "ext.txt",
        "truth": root / "truth.json",
        "scan": root / "scan.txt",
        "mrclam": root / "MRCLAM",
        "park": root / "park",
    }
    loop = ["--scenario", "loop", "--steps", "30", "--landmarks", "8"]
    for args in (
        ["-o", str(made["classic"]), "--truth-out", str(root / "classic.json")],
        [*loop, "-o", str(made["ext"]), "--truth-out", str(made["truth"])],
        [*loop, "--unknown-ids", "-o", str(made["scan"]), "--truth-out", str(root / "s.json")],
        ["--layout", "mrclam", "-o", str(made["mrclam"]), "--duration", "4"],
    ):
        result = runner.invoke(app, ["simulate", *args])
        assert result.exit_code == 0, result.output
    made["park"].mkdir()
    make_park(made["park"], seconds=4.0)
    text = root / "truth.txt"
    text.write_text("# x y\n1.5 2.0\n-3 4e1\n0 0\n")
    made["truth_text"] = text
    return made


def _one_file(valid: dict[str, Path], tmp: Path, key: str, data: bytes) -> Path:
    path = tmp / valid[key].name
    path.write_bytes(data)
    return path


def _check_log(path: Path, reader: Callable[[Path], Iterable[object]]) -> None:
    """Read, or refuse with InputError; when read, one event per data line."""
    try:
        events = read_all(reader(path))
    except InputError:
        return
    assert len(events) == len(data_lines(path)), "a data line was read as no event"


@pytest.mark.parametrize("key", ["classic", "ext", "scan"])
@FUZZ
@given(data=st.data())
def test_log_readers_never_crash_nor_lose_lines(
    valid: dict[str, Path], tmp_path_factory: pytest.TempPathFactory, key: str, data: st.DataObject
) -> None:
    content = data.draw(mutated(valid[key].read_bytes()))
    path = _one_file(valid, tmp_path_factory.mktemp("m"), key, content)
    reader = read_classic if key == "classic" else read_extended
    try:
        kind = open_source(path).kind
    except InputError:
        return
    _check_log(path, read_classic if kind == "classic" else read_extended)
    _check_log(path, reader)  # the other reader, given the wrong format, refuses cleanly
    with contextlib.suppress(InputError):
        read_log_noise(path)


@pytest.mark.parametrize("key", ["truth", "truth_text"])
@FUZZ
@given(data=st.data())
def test_truth_readers_never_crash(
    valid: dict[str, Path], tmp_path_factory: pytest.TempPathFactory, key: str, data: st.DataObject
) -> None:
    content = data.draw(mutated(valid[key].read_bytes()))
    path = _one_file(valid, tmp_path_factory.mktemp("m"), key, content)
    try:
        truth = read_truth(path)
    except InputError:
        return
    assert len(truth.ids) >= 1


def _directory(valid: dict[str, Path], tmp: Path, key: str, name: str, content: bytes) -> Path:
    folder = tmp / valid[key].name
    shutil.copytree(valid[key], folder)
    (folder / name).write_bytes(content)
    return folder


@pytest.mark.parametrize(
    "name",
    few_by_default(["Robot1_Odometry.dat", "Robot1_Measurement.dat", "Barcodes.dat",
                    "Landmark_Groundtruth.dat", "Robot1_Groundtruth.dat"], 2),
)  # fmt: skip
@FUZZ
@given(data=st.data())
def test_the_mrclam_reader_never_crashes(
    valid: dict[str, Path], tmp_path_factory: pytest.TempPathFactory, name: str, data: st.DataObject
) -> None:
    content = data.draw(mutated((valid["mrclam"] / name).read_bytes()))
    folder = _directory(valid, tmp_path_factory.mktemp("m"), "mrclam", name, content)
    try:
        source = open_source(folder)
        events = read_all(source.events())
        source.own_truth(lambda _: None)
    except InputError:
        return
    if name == "Robot1_Odometry.dat":  # one control per odometry line after the first
        assert events and len(data_lines(folder / name)) >= 1


@pytest.mark.parametrize("name", ["inputs.dat", "measurements.dat", "gps.dat"])
@FUZZ
@given(data=st.data())
def test_the_victoria_reader_never_crashes(
    valid: dict[str, Path], tmp_path_factory: pytest.TempPathFactory, name: str, data: st.DataObject
) -> None:
    content = data.draw(mutated((valid["park"] / name).read_bytes()))
    folder = _directory(valid, tmp_path_factory.mktemp("m"), "park", name, content)
    try:
        events = read_all(open_source(folder).events())
        times, xy = read_gps(folder)
    except InputError:
        return
    assert events and len(times) == len(xy) == len(data_lines(folder / "gps.dat"))


@st.composite
def damaged(draw: st.DrawFn, valid: bytes) -> bytes:
    """A recording cut short or with a few bytes flipped."""
    data = bytearray(valid)
    if draw(st.booleans()):
        data = data[: draw(st.integers(0, len(data) - 1))]
    for _ in range(draw(st.integers(0 if len(data) < len(valid) else 1, 4))):
        if data:
            at = draw(st.integers(0, len(data) - 1))
            data[at] ^= draw(st.integers(1, 255))
    return bytes(data)


@pytest.fixture(scope="module")
def recording(valid: dict[str, Path]) -> bytes:
    path = valid["classic"].with_suffix(".rrd")
    result = runner.invoke(app, ["replay", str(valid["classic"]), "--save", str(path)])
    assert result.exit_code == 0, result.output
    return path.read_bytes()


@pytest.mark.slow
@settings(FUZZ, max_examples=25, deadline=20_000)
@given(data=st.data())
def test_reading_a_damaged_recording_back_never_crashes(
    recording: bytes, tmp_path_factory: pytest.TempPathFactory, data: st.DataObject
) -> None:
    from ekfviz import readback

    path = tmp_path_factory.mktemp("rrd") / "damaged.rrd"
    path.write_bytes(data.draw(damaged(recording)))
    for read in (readback.read_recording_info, readback.read_recorded_run):
        try:
            read(path)
        except readback.NotARecordingError as error:
            assert str(error).startswith(str(path)) and "\n" not in str(error)
