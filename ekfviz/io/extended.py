"""Reader and writer of the extended log format, and detection of a log's format.

One event a line, a keyword first, ``#`` comments, an optional leading timestamp::

    # time  keyword  values
    control 3.0 0.0
    observe 4 1.1072 6.7060 17 1.3257 12.3812     # id bearing range, any number of them
    observe                                       # a step with nothing in view
    12.5 control 3.0 0.0                          # with a timestamp in seconds
    scan 1.1072 6.7060 1.3257 12.3812             # bearing range, landmarks unknown

A ``scan`` line is an observation whose landmarks are unknown (any number of pairs,
none included): ``--association nn|jcbb`` decides which landmark each one is.
Landmark ids are non-negative integers; they need not be dense or ordered. A log's
observations are of one kind, by id or id-less (the association numbers the landmarks it
finds itself: they would take the ids of the log's own); an empty line of either is
neither.

A log may state the noise of its odometry and sensor (and the prior of its start) in a
comment before its first event, as ``ekfviz simulate`` does::

    # noise: sigma_x=0.01935 sigma_y=0.009675 sigma_alpha=0.001935 sigma_bearing=0.01
    #   sigma_range=0.08 init_pose_sigma=0.01,0.01,0.005   (one line in the file)

The commands that replay a log take these as the filter's defaults (an option given on
the command line wins); :func:`read_log_noise` reads them.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np

from ekfviz.core.errors import InputError
from ekfviz.core.records import (
    AnyEvent,
    Control,
    Drive,
    Scan,
    Sighting,
)
from ekfviz.core.types import FloatArray, IntArray
from ekfviz.io.classic import read_classic
from ekfviz.io.text import (
    BearingWrapper,
    ProgressCallback,
    WarningCallback,
    block_tokens,
    check_time,
    first_bad_time,
    format_number,
    line_blocks,
    open_input,
    parse_number,
    plain_numbers,
    plain_table,
    token_lines,
)

KEYWORDS = ("control", "observe", "scan")
NOISE_HEADER = "# noise:"
_NOISE_COMMENT = re.compile(r"#[ \t]*noise[ \t]*:(.*)", re.ASCII | re.IGNORECASE)  # however spaced
NOISE_NAMES = ("sigma_x", "sigma_y", "sigma_alpha", "sigma_bearing", "sigma_range")
LogNoise = dict[str, float | tuple[float, float, float]]
_ID = re.compile(r"\+?\d+", re.ASCII)  # as int() reads it, less other scripts' digits
MAX_ID = 2**63 - 1  # ids are int64


def read_log(
    path: Path | str,
    progress: ProgressCallback | None = None,
    warn: WarningCallback | None = None,
) -> Iterator[AnyEvent]:
    """Stream the events of a log file in either format, told apart by its first data
    line (:func:`ekfviz.sources.read_log` takes any input: a dataset directory, a bag).

    :param progress: called now and then with the number of bytes read so far
    :param warn: told once when bearings outside (-pi, pi] are wrapped into range
    """
    path = Path(path)  # (a str from a notebook)
    if is_extended(path):
        return read_extended(path, progress, warn)
    return read_classic(path, progress, warn)


def is_extended(path: Path) -> bool:
    """Whether the first data line of ``path`` is a keyword line (maybe after a timestamp)."""
    try:
        for _, tokens in token_lines(path):
            return tokens[0] in KEYWORDS or (len(tokens) > 1 and tokens[1] in KEYWORDS)
    except InputError:
        return False  # let the classic reader report the problem
    return False


def read_extended(
    path: Path,
    progress: ProgressCallback | None = None,
    warn: WarningCallback | None = None,
) -> Iterator[AnyEvent]:
    """Stream the events of an extended log (``warn`` as for :func:`read_log`).

    The file is read in blocks (:func:`~ekfviz.io.text.line_blocks`). A block whose every
    line is plain (a keyword after an optional timestamp, then decimal numbers, ids of
    plain digits, each once a line, positive ranges, times in order) is converted in one
    go (:func:`_plain_events`); any other is read line by line (:func:`_line_events`),
    to name its first bad line after yielding the events before it. Both give the same
    events: a long log's lines would each cost a regular expression and some lists.

    :raises InputError: for the first bad line met, naming it and what was expected
    """
    read = _Read()
    wrap = BearingWrapper(path, warn)
    with open_input(path) as handle:
        for first, raw in line_blocks(path, handle):
            events = _plain_events(first, raw, read, wrap)
            if events is None:
                events = _line_events(path, block_tokens(path, first, raw), read, wrap)
            yield from events
            if progress is not None:
                progress(handle.tell())


class _Read:
    """What the lines read so far set for the next: the latest timestamp (-inf before
    any), which the next may not precede, and the latest line's that had one (None before
    any), which a timed control spans from; the first observation by landmark ids and
    the first id-less scan (their lines, None before any): a log has one kind or the
    other (see :func:`_one_kind`)."""

    __slots__ = ("by_ids", "last", "previous", "scans")

    def __init__(self) -> None:
        self.last = -math.inf
        self.previous: float | None = None
        self.by_ids: int | None = None
        self.scans: int | None = None

    def passed(self, time: float) -> None:
        self.last = self.previous = time


def _one_kind(path: Path, line: int, scan: bool, read: _Read) -> None:
    """Note an observation with landmarks in it (a scan, or by ids) at ``line``.

    :raises InputError: where the log had observations of the other kind: the
        association numbers its landmarks 1, 2, ... whatever ids the log's own have, so
        a landmark found in a scan would take the id of another one of the log
    """
    first = read.by_ids if scan else read.scans
    if first is not None:
        found, before = (
            ("a scan", "observations by landmark id")
            if scan
            else ("an observation by landmark id", "id-less scans")
        )
        raise InputError(
            path, line, f"found {found} after {before} (from line {first}), expected"
            " observations of one kind in a log: by id ('observe') or id-less ('scan')",
        )  # fmt: skip
    if scan and read.scans is None:
        read.scans = line
    elif not scan and read.by_ids is None:
        read.by_ids = line


def _line_events(
    path: Path, lines: Iterable[tuple[int, list[str]]], read: _Read, wrap: BearingWrapper
) -> Iterator[AnyEvent]:
    """The events of ``lines`` (number, tokens) read one by one, up to the first bad line,
    whose error is raised."""
    for line, tokens in lines:
        time: float | None = None
        # a timestamp leads, unless the line begins with its keyword (a non-finite time,
        # "nan" or "inf", is all letters: it is one where a keyword follows it)
        if not tokens[0].isalpha() or (
            tokens[0] not in KEYWORDS and len(tokens) > 1 and tokens[1] in KEYWORDS
        ):
            time = check_time(path, line, parse_number(path, line, tokens[0]))
            if time < read.last:
                raise InputError(
                    path,
                    line,
                    f"found time {time:g} after {read.last:g},"
                    " expected timestamps that never decrease",
                )
            read.last = time
            tokens = tokens[1:]
            if not tokens:
                raise InputError(path, line, "found only a timestamp, expected a keyword after it")
        keyword, values = tokens[0], tokens[1:]
        if keyword == "control":
            if len(values) != 2:
                raise InputError(
                    path, line, f"found {len(values)} values after 'control', expected 2: d alpha"
                )
            d, alpha = (parse_number(path, line, token) for token in values)
            # a timed control spans the time since the previous timestamp, when there is one
            dt = None if time is None or read.previous is None else time - read.previous
            yield Control(line, d, alpha, time, dt)
        elif keyword == "observe":
            sighting = _observation(path, line, values, time, wrap)
            if len(sighting.ids):
                _one_kind(path, line, False, read)
            yield sighting
        elif keyword == "scan":
            scan = _scan(path, line, values, time, wrap)
            if len(scan.z):
                _one_kind(path, line, True, read)
            yield scan
        else:
            shown = keyword if len(keyword) <= 20 else keyword[:20] + "..."
            raise InputError(
                path,
                line,
                f"found {shown!r}, expected a keyword: control, observe or scan"
                " (after an optional timestamp)",
            )
        if time is not None:
            read.previous = time


_CONTROL, _OBSERVE, _SCAN = 0, 1, 2
_BLANK, _NONE = -2, -1  # a line without tokens, one whose first token is no keyword
_KEYWORD_BYTES = {b"control": _CONTROL, b"observe": _OBSERVE, b"scan": _SCAN}
_NUMBERS_AFTER = {_OBSERVE: 3, _SCAN: 2}  # per landmark (id, bearing, range), per measurement
_EXACT_IDS = 2.0**53  # ids from it on are read line by line (a float may round them)


def _plain_events(
    first: int, raw: list[bytes], read: _Read, wrap: BearingWrapper
) -> Iterator[AnyEvent] | None:
    """The events of a block (``first``: its first line's number) converted at once, or
    None where a line is not plain (see :func:`read_extended`): nothing is read then, and
    the block is read line by line."""
    split = _keyword_lines(first, raw)
    if split is None:
        return None
    lines, kinds, timed, numbers = split
    if not lines:
        return iter(())
    data = b"\n".join(numbers)
    converted = plain_table(data, len(lines), digits=True)
    if converted is None:
        return None
    values, counts, digits = converted
    assert digits is not None
    kind_of = np.array(kinds, dtype=np.int64)
    has_time = np.array(timed, dtype=bool)
    starts = np.zeros(len(lines), dtype=np.int64)
    np.cumsum(counts[:-1], out=starts[1:])
    after = starts + has_time  # where a line's numbers after its keyword start
    sizes = counts - has_time
    per_item = np.where(kind_of == _OBSERVE, 3, 2)
    if not np.where(kind_of == _CONTROL, sizes == 2, sizes % per_item == 0).all():
        return None
    times = values[starts[has_time]]
    if times.size and first_bad_time(times, read.last) is not None:
        return None
    sighted, scanned = (
        _Items.of(kind_of, after, sizes, _OBSERVE),
        _Items.of(kind_of, after, sizes, _SCAN),
    )
    id_values = values[sighted.at]
    if not (digits[sighted.at].all() and (id_values < _EXACT_IDS).all()):
        return None
    ids = id_values.astype(np.int64)
    if _repeated(sighted.owner, ids):
        return None
    z = np.stack((values[sighted.at + 1], values[sighted.at + 2]), axis=1)
    z_scans = np.stack((values[scanned.at], values[scanned.at + 1]), axis=1)
    if not ((z[:, 1] > 0.0).all() and (z_scans[:, 1] > 0.0).all()):
        return None
    by_ids = sighted.rows[np.diff(sighted.bounds) > 0]
    scans = scanned.rows[np.diff(scanned.bounds) > 0]
    if (by_ids.size and (scans.size or read.scans is not None)) or (
        scans.size and read.by_ids is not None
    ):
        return None  # observations of both kinds: the line by line reading names the line
    if by_ids.size and read.by_ids is None:
        read.by_ids = lines[int(by_ids[0])]
    if scans.size and read.scans is None:
        read.scans = lines[int(scans[0])]
    # plain: the timestamps go on, and the events are made as they are asked for
    line_times: list[float | None] = [None] * len(lines)
    spans: list[float | None] = [None] * len(lines)
    if times.size:
        previous = math.nan if read.previous is None else read.previous
        since = times - np.concatenate(([previous], times[:-1]))
        for row, time, span in zip(
            np.flatnonzero(has_time).tolist(), times.tolist(), since.tolist(), strict=True
        ):
            line_times[row] = time
            spans[row] = None if math.isnan(span) else span
        read.passed(float(times[-1]))
    outside = np.zeros(len(lines), dtype=bool)
    for items, measured in ((sighted, z), (scanned, z_scans)):
        bearings = measured[:, 0]
        outside[items.owner[(bearings > math.pi) | (bearings <= -math.pi)]] = True
    controls = values[after[kind_of == _CONTROL, None] + np.arange(2)].tolist()
    return _made(
        lines, kinds, line_times, spans, controls, _Items.spans(len(lines), sighted, scanned),
        ids, z, z_scans, outside.tolist(), wrap,
    )  # fmt: skip


def _keyword_lines(
    first: int, raw: list[bytes]
) -> tuple[list[int], list[int], list[bool], list[bytes]] | None:
    """The non-blank lines of a block (``first``: its first line's number): their
    numbers, keywords, whether each has a timestamp and its numbers (the timestamp first),
    a split or two a line; None where a line is not ASCII, or its first token is neither
    a keyword nor followed by one (read line by line, to name it)."""
    joined = b"\n".join(raw)
    if not joined.isascii():  # comments too: one policy for text (UTF-8, line by line)
        return None
    if b"#" in joined:
        raw = [text.split(b"#", 1)[0] for text in raw]
    heads = [text.split(None, 1) for text in raw]
    keyword = _KEYWORD_BYTES.get
    kinds = [keyword(head[0], _NONE) if head else _BLANK for head in heads]
    if _NONE in kinds:
        return _timed_lines(first, heads)
    # no timestamps (nor anything to name): one comprehension each
    lines = [k for k, kind in enumerate(kinds, start=first) if kind != _BLANK]
    numbers = [head[1] if len(head) > 1 else b"" for head in heads if head]
    if len(lines) != len(kinds):
        kinds = [kind for kind in kinds if kind != _BLANK]
    return lines, kinds, [False] * len(lines), numbers


def _timed_lines(
    first: int, heads: list[list[bytes]]
) -> tuple[list[int], list[int], list[bool], list[bytes]] | None:
    """:func:`_keyword_lines` of a block where some line's first token is no keyword
    (``heads``: each line's first token and the rest)."""
    lines: list[int] = []
    kinds: list[int] = []
    timed: list[bool] = []
    numbers: list[bytes] = []
    for number, head in enumerate(heads, start=first):
        if not head:
            continue
        kind = _KEYWORD_BYTES.get(head[0])
        if kind is not None:
            numbers.append(head[1] if len(head) > 1 else b"")
            timed.append(False)
        else:  # a timestamp, then a keyword; or something for the line's reading to name
            rest = head[1].split(None, 1) if len(head) > 1 else []
            kind = _KEYWORD_BYTES.get(rest[0]) if rest else None
            if kind is None:
                return None
            numbers.append(head[0] + b" " + rest[1] if len(rest) > 1 else head[0])
            timed.append(True)
        lines.append(number)
        kinds.append(kind)
    return lines, kinds, timed, numbers


class _Items:
    """The landmarks (or measurements) of a block's observation (or scan) lines: their
    lines' rows in the block, where each line's start among them (len + 1), the row of
    each one's line, and where its numbers start in the block's values."""

    __slots__ = ("at", "bounds", "owner", "rows")

    def __init__(self, rows: IntArray, bounds: IntArray, owner: IntArray, at: IntArray) -> None:
        self.rows, self.bounds, self.owner, self.at = rows, bounds, owner, at

    @staticmethod
    def of(kind_of: IntArray, after: IntArray, sizes: IntArray, kind: int) -> _Items:
        rows = np.flatnonzero(kind_of == kind)
        per_line = sizes[rows] // _NUMBERS_AFTER[kind]
        bounds = np.zeros(len(rows) + 1, dtype=np.int64)
        np.cumsum(per_line, out=bounds[1:])
        owner = np.repeat(rows, per_line)
        within = np.arange(bounds[-1]) - np.repeat(bounds[:-1], per_line)
        return _Items(rows, bounds, owner, after[owner] + _NUMBERS_AFTER[kind] * within)

    @staticmethod
    def spans(count: int, *kinds: _Items) -> list[tuple[int, int]]:
        """Each of ``count`` lines' (start, end) among the items of its kind."""
        spans = [(0, 0)] * count
        for items in kinds:
            bounds = items.bounds.tolist()
            for k, row in enumerate(items.rows.tolist()):
                spans[row] = (bounds[k], bounds[k + 1])
        return spans


def _repeated(owner: IntArray, ids: IntArray) -> bool:
    """Whether a line names a landmark twice (``owner``: the line of each id)."""
    if len(ids) < 2:
        return False
    order = np.lexsort((ids, owner))
    owner, ids = owner[order], ids[order]
    return bool(((owner[1:] == owner[:-1]) & (ids[1:] == ids[:-1])).any())


def _made(
    lines: list[int],
    kinds: list[int],
    times: list[float | None],
    spans: list[float | None],
    controls: list[list[float]],
    items: list[tuple[int, int]],
    ids: IntArray,
    z: FloatArray,
    z_scans: FloatArray,
    outside: list[bool],
    wrap: BearingWrapper,
) -> Iterator[AnyEvent]:
    """The events of a plain block, as :func:`_line_events` makes them (``controls``:
    the (d, alpha) of each control line, in order)."""
    each_control = iter(controls)
    for j, line in enumerate(lines):
        kind = kinds[j]
        if kind == _CONTROL:
            d, alpha = next(each_control)
            yield Control(line, d, alpha, times[j], spans[j])
            continue
        start, end = items[j]
        measured = z[start:end] if kind == _OBSERVE else z_scans[start:end]
        if outside[j]:
            measured[:, 0] = wrap(line, measured[:, 0])
        if kind == _OBSERVE:
            yield Sighting(line, ids[start:end], measured, times[j])
        else:
            yield Scan(line=line, z=measured, time=times[j])


def _observation(
    path: Path, line: int, values: list[str], time: float | None, wrap: BearingWrapper
) -> Sighting:
    plain = _plain_observation(values)
    if plain is not None:
        ids_array, z = plain
        z[:, 0] = wrap(line, z[:, 0])
        return Sighting(line, ids_array, z, time)
    # token by token, to name what is wrong
    if len(values) % 3:
        raise InputError(
            path,
            line,
            f"found {len(values)} values after 'observe', expected a multiple of 3:"
            " id bearing range per landmark",
        )
    ids: list[int] = []
    z = np.empty((len(values) // 3, 2))
    for k in range(len(values) // 3):
        token = values[3 * k]
        if not _ID.fullmatch(token):
            shown = token if len(token) <= 20 else token[:20] + "..."
            raise InputError(path, line, f"found landmark id {shown!r}, expected an integer >= 0")
        # int() refuses over 4,300 digits: a long one is too large before it is converted
        digits = token.lstrip("+").lstrip("0")
        landmark_id = int(token) if len(digits) <= len(str(MAX_ID)) else MAX_ID + 1
        if landmark_id > MAX_ID:
            raise InputError(
                path,
                line,
                f"found landmark id {token[:25]}{'...' if len(token) > 25 else ''},"
                f" expected an integer up to {MAX_ID}",
            )
        if landmark_id in ids:
            raise InputError(
                path, line, f"found landmark {landmark_id} twice, expected each id once a line"
            )
        ids.append(landmark_id)
        z[k] = [
            parse_number(path, line, values[3 * k + 1]),
            parse_number(path, line, values[3 * k + 2]),
        ]
        if not z[k, 1] > 0:
            raise InputError(
                path,
                line,
                f"found range {values[3 * k + 2]} for landmark {landmark_id},"
                " expected a positive range",
            )
    z[:, 0] = wrap(line, z[:, 0])
    return Sighting(line=line, ids=np.array(ids, dtype=np.int64), z=z, time=time)


def _plain_observation(values: list[str]) -> tuple[IntArray, FloatArray] | None:
    """The ids and (bearing, range) of an observation line whose every token is plain (ids
    of ASCII digits too short to pass MAX_ID, each once; numbers as
    :func:`~ekfviz.io.text.plain_numbers` takes them; positive ranges), read in one go;
    else None, for :func:`_observation` to go token by token and name the fault."""
    m, rest = divmod(len(values), 3)
    id_tokens = values[0::3]
    if rest or not m or not all(t.isascii() and t.isdigit() and len(t) <= 18 for t in id_tokens):
        return None
    numbers = plain_numbers([*values[1::3], *values[2::3]])  # the bearings, then the ranges
    if numbers is None or min(numbers[m:]) <= 0.0:
        return None
    ids = list(map(int, id_tokens))
    if len(set(ids)) != m:
        return None
    z = np.empty((m, 2))
    z[:, 0] = numbers[:m]
    z[:, 1] = numbers[m:]
    return np.array(ids, dtype=np.int64), z


def _scan(
    path: Path, line: int, values: list[str], time: float | None, wrap: BearingWrapper
) -> Scan:
    if len(values) % 2:
        raise InputError(
            path,
            line,
            f"found {len(values)} values after 'scan', expected an even number:"
            " bearing range per measurement",
        )
    z = np.array([parse_number(path, line, token) for token in values]).reshape(-1, 2)
    bad = np.flatnonzero(~(z[:, 1] > 0))
    if bad.size:
        raise InputError(
            path,
            line,
            f"found range {values[2 * int(bad[0]) + 1]} in measurement {int(bad[0]) + 1},"
            " expected a positive range",
        )
    z[:, 0] = wrap(line, z[:, 0])
    return Scan(line=line, z=z, time=time)


def read_log_noise(path: Path) -> LogNoise:
    """The noise a log states in its ``# noise:`` comment before the first event
    (empty when it states none): sigma names to values, ``init_pose_sigma`` a triple.

    :raises InputError: a ``# noise:`` line that does not read, naming the line
    """
    try:
        handle = open_input(path)
    except InputError:
        return {}  # the reader of the events says what is wrong with the file
    noise: LogNoise = {}
    header_line = 0
    with handle:
        for first, lines in line_blocks(path, handle):  # the readers' line ends and BOM
            for number, raw in enumerate(lines, start=first):
                text = raw.decode("utf-8", errors="replace").strip()
                if not text:
                    continue
                if not text.startswith("#"):
                    return noise  # the first event: no header after it counts
                header = _NOISE_COMMENT.match(text)  # "# noise:", "#noise:", "#\tnoise:"
                if header is None:
                    continue
                if header_line:
                    raise InputError(
                        path, number, f"found a second noise header (the first is on line"
                        f" {header_line}), expected one",
                    )  # fmt: skip
                noise, header_line = _parse_noise(path, number, header.group(1).split()), number
    return noise


def _parse_noise(path: Path, line: int, cells: list[str]) -> LogNoise:
    expected = f"expected name=value pairs of {', '.join(NOISE_NAMES)}, init_pose_sigma=SX,SY,ST"
    noise: LogNoise = {}
    for cell in cells:
        name, sep, value = cell.partition("=")
        if not sep or name not in (*NOISE_NAMES, "init_pose_sigma"):
            raise InputError(path, line, f"found {cell!r} in the noise header, {expected}")
        if name in noise:
            raise InputError(path, line, f"found {name} twice in the noise header, {expected}")
        parts = value.split(",")
        numbers = [parse_number(path, line, part) for part in parts]
        if any(not math.isfinite(v) or v < 0 for v in numbers) or (
            name != "init_pose_sigma" and len(numbers) != 1
        ):
            raise InputError(path, line, f"found {cell!r} in the noise header, {expected}")
        if name == "init_pose_sigma":
            if len(numbers) != 3:
                raise InputError(path, line, f"found {cell!r} in the noise header, {expected}")
            noise[name] = (numbers[0], numbers[1], numbers[2])
        else:
            noise[name] = numbers[0]
    for name in ("sigma_bearing", "sigma_range"):
        if noise.get(name) == 0.0:
            raise InputError(
                path, line, f"found {name}=0 in the noise header, expected a positive"
                " sigma_bearing and sigma_range (the filter's R must be invertible)",
            )  # fmt: skip
    return noise


def format_noise_header(noise: LogNoise) -> str:
    """The ``# noise:`` comment of :func:`read_log_noise` (values written exactly)."""
    cells = []
    for name, value in noise.items():
        text = (
            ",".join(repr(float(v)) for v in value)
            if isinstance(value, tuple)
            else repr(float(value))
        )
        cells.append(f"{name}={text}")
    return " ".join([NOISE_HEADER, *cells])


def format_extended(
    events: Iterable[AnyEvent], precision: int | None = 6, noise: LogNoise | None = None
) -> str:
    """Write events in the extended format, one event a line, with timestamps if given.

    :param precision: decimals, or None for the shortest text that reads back exactly
    :param noise: the noise to state in the header (see :func:`read_log_noise`)
    """

    def num(value: float) -> str:
        return format_number(value, precision)

    lines = [
        "# ekfviz extended log: control d alpha | observe id bearing range ..."
        " | scan bearing range ..."
    ]
    if noise:
        lines.append(format_noise_header(noise))
    for event in events:
        head = "" if event.time is None else f"{num(event.time)} "
        if isinstance(event, Control):
            lines.append(f"{head}control {num(event.d)} {num(event.alpha)}")
        elif isinstance(event, Scan):
            cells = [f"{num(b)} {num(r)}" for b, r in event.z]
            lines.append(" ".join([f"{head}scan", *cells]))
        elif isinstance(event, Drive):
            raise ValueError("speed and steering controls have no line in the extended format")
        else:
            cells = [
                f"{int(i)} {num(b)} {num(r)}" for i, (b, r) in zip(event.ids, event.z, strict=True)
            ]
            lines.append(" ".join([f"{head}observe", *cells]))
    return "\n".join(lines) + "\n"
