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
Landmark ids are non-negative integers; they need not be dense or ordered.

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

from ekfviz.core.records import (
    AnyEvent,
    Control,
    Drive,
    Scan,
    Sighting,
    read_control,
    read_sighting,
)
from ekfviz.core.types import FloatArray, IntArray
from ekfviz.io.classic import read_classic
from ekfviz.io.errors import InputError
from ekfviz.io.text import (
    BearingWrapper,
    ProgressCallback,
    WarningCallback,
    check_time,
    format_number,
    line_blocks,
    open_input,
    parse_number,
    plain_numbers,
    token_lines,
)

KEYWORDS = ("control", "observe", "scan")
NOISE_HEADER = "# noise:"
NOISE_NAMES = ("sigma_x", "sigma_y", "sigma_alpha", "sigma_bearing", "sigma_range")
LogNoise = dict[str, float | tuple[float, float, float]]
_ID = re.compile(r"\+?\d+", re.ASCII)  # as int() reads it, less other scripts' digits
MAX_ID = 2**63 - 1  # ids are int64


def read_log(
    path: Path,
    progress: ProgressCallback | None = None,
    warn: WarningCallback | None = None,
) -> Iterator[AnyEvent]:
    """Stream the events of a log file in either format, told apart by its first data
    line (:func:`ekfviz.sources.read_log` takes any input: a dataset directory, a bag).

    :param progress: called now and then with the number of bytes read so far
    :param warn: told once when bearings outside (-pi, pi] are wrapped into range
    """
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

    :raises InputError: for the first bad line met, naming it and what was expected
    """
    last_time = -np.inf
    previous: float | None = None  # the timestamp of the latest line that had one
    wrap = BearingWrapper(path, warn)
    for line, tokens in token_lines(path, progress):
        time: float | None = None
        if not tokens[0].isalpha():
            time = check_time(path, line, parse_number(path, line, tokens[0]))
            if time < last_time:
                raise InputError(
                    path,
                    line,
                    f"found time {time:g} after {last_time:g},"
                    " expected timestamps that never decrease",
                )
            last_time = time
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
            dt = None if time is None or previous is None else time - previous
            yield read_control(line, d, alpha, time, dt)
        elif keyword == "observe":
            yield _observation(path, line, values, time, wrap)
        elif keyword == "scan":
            yield _scan(path, line, values, time, wrap)
        else:
            shown = keyword if len(keyword) <= 20 else keyword[:20] + "..."
            raise InputError(
                path,
                line,
                f"found {shown!r}, expected a keyword: control, observe or scan"
                " (after an optional timestamp)",
            )
        if time is not None:
            previous = time


def _observation(
    path: Path, line: int, values: list[str], time: float | None, wrap: BearingWrapper
) -> Sighting:
    plain = _plain_observation(values)
    if plain is not None:
        ids_array, z = plain
        z[:, 0] = wrap(line, z[:, 0])
        return read_sighting(line, ids_array, z, time)
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
    with handle:
        for first, lines in line_blocks(path, handle):  # the readers' line ends and BOM
            for number, raw in enumerate(lines, start=first):
                text = raw.decode("utf-8", errors="replace").strip()
                if not text:
                    continue
                if not text.startswith("#"):
                    return {}  # the first event: no header after it counts
                if text.startswith(NOISE_HEADER):
                    return _parse_noise(path, number, text[len(NOISE_HEADER) :].split())
    return {}


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
