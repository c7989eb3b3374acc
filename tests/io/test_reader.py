"""The classic reader on every accepted variant and every error, and the truth reader."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ekfviz.core.errors import InputError
from ekfviz.core.records import Control, Sighting
from ekfviz.io.classic import format_classic, read_classic
from ekfviz.io.truth import read_truth
from ekfviz.sim.scenarios import classic

OBS = "0.1 5.0 0.2 6.0"
LOG = f"{OBS}\n3.0 0.0\n{OBS}\n"


def write(tmp_path: Path, content: str | bytes, name: str = "log.txt") -> Path:
    path = tmp_path / name
    if isinstance(content, str):
        content = content.encode("utf-8")
    path.write_bytes(content)
    return path


def kinds(path: Path) -> list[str]:
    return [type(event).__name__ for event in read_classic(path)]


@pytest.mark.parametrize(
    "content",
    [
        LOG,
        LOG.replace(" ", "\t"),
        LOG.replace("\n", "\r\n"),
        LOG.replace("\n", "\t\r\n"),
        LOG.replace("\n", "  \n"),
        "# a comment\n\n" + LOG.replace("3.0 0.0", "3.0 0.0   # drive") + "\n\n",
        LOG.rstrip("\n"),  # no final newline
        LOG.replace("3.0", "+3e0").replace("0.1", ".1"),
        "\ufeff" + LOG,  # a UTF-8 byte-order mark, as Windows editors write
        LOG.replace("\n", "\r"),  # classic Mac line ends
        LOG.replace("\n", "\f\n"),  # a form feed is white space
    ],
    ids=[
        "spaces",
        "tabs",
        "crlf",
        "trailing-tab-crlf",
        "trailing-spaces",
        "comments-blank",
        "no-final-newline",
        "number-forms",
        "byte-order-mark",
        "cr-only",
        "form-feed",
    ],
)
def test_accepted_variants_read_the_same(tmp_path: Path, content: str) -> None:
    events = list(read_classic(write(tmp_path, content)))
    assert [type(e).__name__ for e in events] == ["Sighting", "Control", "Sighting"]
    first, control = events[0], events[1]
    assert isinstance(first, Sighting) and isinstance(control, Control)
    np.testing.assert_array_equal(first.ids, [1, 2])
    np.testing.assert_allclose(first.z, [[0.1, 5.0], [0.2, 6.0]])
    assert (control.d, control.alpha) == (3.0, 0.0)


def test_line_numbers_count_blank_and_comment_lines(tmp_path: Path) -> None:
    events = list(read_classic(write(tmp_path, "# header\n" + OBS + "\n\n3 0\n")))
    assert [e.line for e in events] == [2, 4]


@pytest.mark.parametrize("end", ["\n", "\r\n", "\r"])
def test_line_numbers_with_any_line_end(tmp_path: Path, end: str) -> None:
    content = end.join(["# header", OBS, "", "3 0", "1 2 3", ""])
    with pytest.raises(InputError, match=r"log\.txt:5: found 3 numbers"):
        list(read_classic(write(tmp_path, content)))


def test_alternation_is_not_required(tmp_path: Path) -> None:
    path = write(tmp_path, f"{OBS}\n1 0\n1 0\n{OBS}\n{OBS}\n")
    assert kinds(path) == ["Sighting", "Control", "Control", "Sighting", "Sighting"]


def test_writer_round_trips_a_simulated_run(tmp_path: Path) -> None:
    run = classic().run(seed=2)
    path = write(tmp_path, format_classic(run.events, precision=17))
    for read, made in zip(read_classic(path), run.events, strict=True):
        assert type(read) is type(made) and read.line == made.line
        if isinstance(read, Sighting) and isinstance(made, Sighting):
            np.testing.assert_allclose(read.z, made.z, rtol=1e-15)


@pytest.mark.parametrize(
    ("content", "line", "message"),
    [
        ("", 1, "found no data, expected a first line"),
        ("\n# only a comment\n\n", 1, "found no data"),
        ("3.0 0.0\n", 1, "found 2 numbers on the first line"),
        ("0.1 5 0.2\n", 1, "found 3 numbers on the first line, expected the initial observation"),
        (f"{OBS}\n3.0 0.0 1.0\n", 2, "found 3 numbers, expected 2 (a control: d alpha) or 4"),
        (f"{OBS}\n3.0\n", 2, "found 1 number, expected 2"),
        (f"{OBS}\n3.0 abc\n", 2, "found 'abc', expected a decimal number"),
        (f"{OBS}\n3.0 1,5\n", 2, "found '1,5', expected a decimal number"),
        (f"{OBS}\n3.0 nan\n", 2, "found 'nan', expected a finite number"),
        (f"{OBS}\n3.0 -inf\n", 2, "found '-inf', expected a finite number"),
        (f"{OBS}\n3.0 Infinity\n", 2, "found 'Infinity', expected a finite number"),
        (f"{OBS}\n3.0 1e999\n", 2, "found '1e999', which overflows"),
        (f"{OBS}\n3 0\n0.1 5 0.2 -6\n", 3, "found range -6 for landmark 2, expected a positive"),
        ("0.1 0 0.2 6\n", 1, "found range 0 for landmark 1"),
    ],
)
def test_errors_name_the_line_and_what_was_expected(
    tmp_path: Path, content: str, line: int, message: str
) -> None:
    path = write(tmp_path, content)
    with pytest.raises(InputError) as caught:
        list(read_classic(path))
    assert caught.value.line == line
    assert message in str(caught.value)
    assert str(caught.value).startswith(f"{path}:{line}: ")
    assert "\n" not in str(caught.value)


def test_one_landmark_is_rejected_as_ambiguous(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="could not be told from controls"):
        list(read_classic(write(tmp_path, "0.1 5\n3 0\n")))


def test_missing_file_and_directory_and_binary(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="no such file"):
        list(read_classic(tmp_path / "missing.txt"))
    with pytest.raises(InputError, match="is a directory"):
        list(read_classic(tmp_path))
    with pytest.raises(InputError, match=r":1: found bytes that are not UTF-8"):
        list(read_classic(write(tmp_path, b"\xff\xfe\x00garbage")))


def test_reader_streams_lazily(tmp_path: Path) -> None:
    """An error far down the file surfaces only when the reader gets there."""
    path = write(tmp_path, LOG + "oops\n")
    events = read_classic(path)
    assert isinstance(next(events), Sighting)
    assert isinstance(next(events), Control)
    assert isinstance(next(events), Sighting)
    with pytest.raises(InputError, match=":4:"):
        next(events)


@settings(max_examples=200, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    st.one_of(
        st.binary(max_size=300), st.text(alphabet="0123456789.-+eE \t\r\n#xnaif", max_size=300)
    )
)
def test_any_input_gives_events_or_a_clean_error(tmp_path: Path, content: bytes | str) -> None:
    path = write(tmp_path, content, "fuzz.txt")
    try:
        events = list(read_classic(path))
    except InputError as error:
        assert str(error).startswith(str(path)) and "\n" not in str(error)
    else:
        assert events and isinstance(events[0], Sighting)
        assert all(np.isfinite(e.z).all() for e in events if isinstance(e, Sighting))


def test_truth_text_and_json(tmp_path: Path) -> None:
    text = read_truth(write(tmp_path, "# x y\n3 6\r\n3\t12\n", "truth.txt"))
    as_json = read_truth(write(tmp_path, '{"landmarks": [[3, 6], [3.0, 12]]}', "truth.json"))
    for truth in (text, as_json):
        np.testing.assert_array_equal(truth.ids, [1, 2])
        np.testing.assert_array_equal(truth.landmarks_xy, [[3, 6], [3, 12]])


@pytest.mark.parametrize(
    ("name", "content", "message"),
    [
        ("t.txt", "3 6\n3 12 1\n", "t.txt:2: found 3 numbers, expected 2"),
        ("t.txt", "", "t.txt:1: found no data"),
        ("t.json", "{", "t.json:1: invalid JSON"),
        ("t.json", '{"poses": []}', 'expected an object {"landmarks"'),
        ("t.json", '{"landmarks": [[1, "a"]]}', 'landmark 1 is [1, "a"], expected [x, y]'),
    ],
)
def test_truth_errors(tmp_path: Path, name: str, content: str, message: str) -> None:
    with pytest.raises(InputError) as caught:
        read_truth(write(tmp_path, content, name))
    assert message in str(caught.value)


def test_truth_lookup_by_id_with_gaps_and_unknown_ids() -> None:
    from ekfviz.core.truth import GroundTruth

    truth = GroundTruth(np.array([5, 2, 9]), np.array([[5.0, 5.0], [2.0, 2.0], [9.0, 9.0]]))
    found = truth.lookup(np.array([9, 3, 2, 5, 10]))
    np.testing.assert_array_equal(found[[0, 2, 3]], [[9, 9], [2, 2], [5, 5]])
    assert np.isnan(found[[1, 4]]).all()


_NOT_NUMBERS = [
    b"nan", b"1_0", b"1e400", b"x", b"\xff\xfe", b"1.5e19", b"--1", b"# \xff", b"1.2.3", b"3e",
    b"1e-400", b"-0.05e-330",
]  # fmt: skip


@pytest.mark.parametrize("bad", _NOT_NUMBERS)
def test_block_reader_reads_as_line_by_line(
    tmp_path: Path, bad: bytes, monkeypatch: pytest.MonkeyPatch
) -> None:
    """number_blocks converts a block at once but gives the lines, numbers and first
    error numeric_lines gives, even in a later block, after a comment or a blank line
    (blocks of 4 kB: some 50 of them)."""
    from ekfviz.io import text as text_io

    monkeypatch.setattr(text_io, "BLOCK_BYTES", 4096)
    _block_reader_reads_as_line_by_line(tmp_path, bad, repeats=2000)


@pytest.mark.slow
@pytest.mark.parametrize("bad", _NOT_NUMBERS)
def test_block_reader_reads_a_long_file_as_line_by_line(tmp_path: Path, bad: bytes) -> None:
    """As above, in blocks of the size the readers read (100,000 lines: 8 blocks)."""
    _block_reader_reads_as_line_by_line(tmp_path, bad, repeats=20000)


def _block_reader_reads_as_line_by_line(tmp_path: Path, bad: bytes, repeats: int) -> None:
    """number_blocks against numeric_lines on ``5 * repeats`` lines, ``bad`` in a line of
    its last quarter."""
    from ekfviz.io import text as text_io

    lines = [b"1.5 -2 3e-2 # c", b"", b"\t4 5  ", b"# only a comment", b"-0.5 .5 +1."] * repeats
    wrong = repeats * 5 * 7 // 9  # the 77,778th line of 100,000
    lines[wrong] = b"7 " + bad + b" 8"
    path = tmp_path / "numbers.txt"
    path.write_bytes(b"\r\n".join(lines) + b"\n")
    expected: list[tuple[int, list[float]]] = []
    with pytest.raises(InputError) as line_by_line:
        expected.extend(text_io.numeric_lines(path))
    got: list[tuple[int, list[float]]] = []
    fault = None
    for block in text_io.number_blocks(path):
        for line, start, count in zip(block.lines, block.starts, block.counts, strict=True):
            got.append((line, block.values[start : start + count].tolist()))
        fault = block.fault
    assert len(got) == len(expected) > 2 * repeats
    assert got == expected
    assert fault is not None and str(fault) == str(line_by_line.value)
    assert fault.line == wrong + 1


_TOKEN = st.one_of(
    st.floats(allow_nan=False, allow_infinity=False).map(repr),
    st.floats(-1e6, 1e6).flatmap(
        lambda v: st.sampled_from(["%.0f", "%.3f", "%.17g", "%.25e", "%.1E", "%g"]).map(
            lambda form: form % v
        )
    ),
    st.from_regex(r"\A[-+]?([0-9]{1,40}\.?[0-9]{0,40}|\.[0-9]{1,40})([eE][-+]?[0-9]{1,3})?\Z"),
)


_TOKEN_LINES = st.lists(st.lists(_TOKEN, max_size=6), min_size=1, max_size=8)
_GAPS = st.sampled_from([" ", "\t", "  "])


@settings(max_examples=30, deadline=None)
@given(_TOKEN_LINES, _GAPS)
def test_a_block_gives_the_bits_float_gives(lines: list[list[str]], gap: str) -> None:
    """See :func:`_a_block_gives_the_bits_float_gives`."""
    _a_block_gives_the_bits_float_gives(lines, gap)


@pytest.mark.slow
@settings(max_examples=300, deadline=None)
@given(_TOKEN_LINES, _GAPS)
def test_a_block_gives_the_bits_float_gives_on_many_examples(
    lines: list[list[str]], gap: str
) -> None:
    """See :func:`_a_block_gives_the_bits_float_gives`."""
    _a_block_gives_the_bits_float_gives(lines, gap)


def _a_block_gives_the_bits_float_gives(lines: list[list[str]], gap: str) -> None:
    """A block converted at once gives the float64 bits float() gives each token alone
    (halfway cases, subnormals, overflow to inf, 40 digits), the count of tokens of
    each line, and which tokens are digits alone (an id as written)."""
    from ekfviz.io import text as text_io

    joined = "\n".join(gap.join(tokens) for tokens in lines).encode()
    converted = text_io._converted(joined, len(lines), digits=True)
    if any(float(t) == 0.0 and text_io.underflows(t) for tokens in lines for t in tokens):
        assert converted is None  # 1e-400: line by line, to be named (it reads as 0)
        return
    assert converted is not None
    values, counts, digits = converted
    expected = np.array([float(t) for tokens in lines for t in tokens], dtype=np.float64)
    np.testing.assert_array_equal(values.view(np.int64), expected.view(np.int64))
    assert counts.tolist() == [len(tokens) for tokens in lines]
    assert digits is not None
    assert digits.tolist() == [t.isascii() and t.isdigit() for tokens in lines for t in tokens]


@pytest.mark.parametrize("bad", [b"1.2.3", b"e5", b"-", b"1e", b".", b"+-1", b"1e+", b"2 3\n4 e"])
def test_a_block_with_what_is_not_a_number_is_refused_whole(bad: bytes) -> None:
    """A token that is a number only in part is refused, and the block goes line by line."""
    from ekfviz.io import text as text_io

    assert text_io._converted(bad, bad.count(b"\n") + 1) is None


@pytest.mark.parametrize("bad", [None, b"0x10", b"1e400", b"nan", b"1.2.3", b"1_000", b"4 5"])
def test_table_blocks_read_every_row_up_to_the_first_bad_one(
    tmp_path: Path, bad: bytes | None
) -> None:
    """numeric_blocks (MRCLAM's and Victoria Park's tables) gives every row, each as
    float() reads it, up to the first bad one, and names that one's line: hexadecimal,
    "1_000" (float()'s, no log's) and a short row included."""
    from ekfviz.io import text as text_io

    rng = np.random.default_rng(3)
    rows = [f"{t:.3f} {float(v)!r} {w:.17g}" for t, v, w in zip(
        np.arange(30000) * 0.01, rng.normal(size=30000), rng.normal(size=30000), strict=True
    )]  # fmt: skip
    if bad is not None:
        rows[23456] = f"234.56 {bad.decode()} 1"
    path = tmp_path / "table.dat"
    path.write_text("# time v w\n" + "\n".join(rows) + "\n")

    def read() -> tuple[list[tuple[list[int], list[list[float]]]], str | None]:
        got: list[tuple[list[int], list[list[float]]]] = []
        try:
            for lines, table in text_io.numeric_blocks(path, 3, "time v w"):
                got.append((lines, table.tolist()))
        except InputError as error:
            return got, str(error)
        return got, None

    got, error = read()
    assert sum(len(lines) for lines, _ in got) == (30000 if bad is None else 23456)
    assert [row for _, table in got for row in table][:3] == [
        [float(v) for v in row.split()] for row in rows[:3]
    ]
    assert (error is None) == (bad is None)
    if error is not None:
        assert "23458" in error, error  # the header, then 1-based


def _with_poses(tmp_path: Path, poses: np.ndarray) -> tuple[list[Control | Sighting], Path]:
    """The classic sample's events and a truth file of its landmarks with ``poses``."""
    import json

    root = Path(__file__).resolve().parents[2] / "data"
    events = list(read_classic(root / "classic.txt"))
    document = json.loads((root / "classic_truth.json").read_text())
    document["poses"] = poses.tolist()
    path = tmp_path / "truth.json"
    path.write_text(json.dumps(document))
    return events, path


@pytest.mark.parametrize("fault", ["fewer", "longer", "shorter"])
def test_true_poses_of_another_run_are_refused_with_the_numbers(tmp_path: Path, fault: str) -> None:
    """Poses that cannot be this log's (too few for its steps, a path three times longer or
    shorter than its controls drive) are one line naming the truth file and both numbers;
    the poses of the run itself, or of a longer run it begins, pass."""
    from ekfviz.io.truth import checked_against

    events, _ = _with_poses(tmp_path, np.zeros((1, 3)))
    steps = sum(isinstance(e, Control) for e in events)
    driven = sum(abs(e.d) for e in events if isinstance(e, Control))
    x = np.concatenate([[0.0], np.cumsum([e.d for e in events if isinstance(e, Control)])])
    own = np.column_stack([x, np.zeros_like(x), np.zeros_like(x)])  # (steps + 1, 3)
    longer_run = np.vstack([own, own[-1] + [[1.0, 0.0, 0.0]]])
    for fine in (own, longer_run):
        _, path = _with_poses(tmp_path, fine)
        assert len(list(checked_against(events, read_truth(path), path, every_id=True))) == len(
            events
        )
    bad = {"fewer": own[:-2], "longer": own * [4.0, 1.0, 1.0], "shorter": own * [0.2, 1.0, 1.0]}
    _, path = _with_poses(tmp_path, bad[fault])
    said = {
        "fewer": f'has {steps - 1} "poses", expected one per step of the log and the start'
        f" ({steps + 1})",
        "longer": f"its poses walk {4 * driven:.3g} m where the log's controls drive"
        f" {driven:.3g} m",
        "shorter": f"its poses walk {0.2 * driven:.3g} m where the log's controls drive"
        f" {driven:.3g} m",
    }[fault]
    with pytest.raises(InputError, match=re.escape(said)):
        list(checked_against(events, read_truth(path), path, every_id=True))
