"""Readers of ground-truth files.

Plain text: one ``x y`` pair per line in landmark order (ids 1, 2, ...), ``#`` comments
and blank lines allowed. JSON: ``{"landmarks": {"<id>": [x, y], ...}, "poses": [[x, y,
theta], ...]}`` with one pose per step (step 0 = the start; optional), or landmarks as a
list ``[[x, y], ...]`` in landmark order (ids 1, 2, ...).
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np

from ekfviz.core.errors import InputError
from ekfviz.core.records import AnyEvent, Control, Scan, Sighting
from ekfviz.core.steps import StepCounter
from ekfviz.core.truth import GroundTruth
from ekfviz.core.types import FloatArray
from ekfviz.io.jsontext import load_json
from ekfviz.io.text import MAX_MAGNITUDE, RANGE_TEXT, numeric_lines, open_input

_ID = re.compile(r"\d+", re.ASCII)
MAX_ID = 2**63 - 1  # ids are int64


def read_truth(path: Path | str) -> GroundTruth:
    """Read a truth file, JSON when it ends in ``.json`` or starts with ``{``.

    :raises InputError: naming the line and what was expected
    """
    path = Path(path)  # (a str from a notebook)
    if path.suffix.lower() == ".json" or _starts_with_brace(path):
        return _read_json(path)
    return _read_text(path)


def _starts_with_brace(path: Path) -> bool:
    try:  # opened as the readers open it: a FIFO is refused, not waited on
        with open_input(path) as handle:
            return handle.read(64).removeprefix(b"\xef\xbb\xbf").lstrip().startswith(b"{")
    except (InputError, OSError):
        return False  # the text reader reports it


def _read_text(path: Path) -> GroundTruth:
    rows: list[list[float]] = []
    for line, values in numeric_lines(path):
        if len(values) != 2:
            raise InputError(
                path, line, f"found {len(values)} numbers, expected 2 (a landmark's x y)"
            )
        rows.append(values)
    if not rows:
        raise InputError(path, 1, "found no data, expected one 'x y' line per landmark")
    return _truth(rows)


def _read_json(path: Path) -> GroundTruth:
    document = load_json(path, "a JSON truth file")
    if not isinstance(document, dict):
        document = {}  # refused below, as an object without landmarks
    where = _KeyLines(path)
    landmarks = document.get("landmarks")
    if isinstance(landmarks, list) and landmarks:
        ids = list(range(1, len(landmarks) + 1))
        pairs = landmarks
        names: list[str] = []  # ids by position: their lines are the list's
    elif isinstance(landmarks, dict) and landmarks:
        if not all(_ID.fullmatch(key) for key in landmarks):
            bad = next(key for key in landmarks if not _ID.fullmatch(key))
            raise InputError(
                path, where.line(bad), f"found landmark id {bad!r}, expected an integer >= 0"
            )
        long = next((key for key in landmarks if len(key) > len(str(MAX_ID))), None)
        if long is not None:  # before int(): Python refuses over 4,300 digits
            raise InputError(
                path, where.line(long),
                f"found landmark id {long[:20]}..., expected an integer up to {MAX_ID}",
            )  # fmt: skip
        names = list(landmarks)
        ids = [int(key) for key in names]
        if max(ids, default=0) > MAX_ID:
            key = names[ids.index(max(ids))]
            raise InputError(
                path, where.line(key), f"found landmark id {max(ids)}, expected up to {MAX_ID}"
            )
        if len(set(ids)) != len(ids):  # "1" and "01": JSON's keys differ, the ids do not
            seen: dict[int, str] = {}
            for key, landmark_id in zip(names, ids, strict=True):
                if landmark_id in seen:
                    raise InputError(
                        path, where.line(key), f"found landmark id {key!r} after"
                        f" {seen[landmark_id]!r}, the same landmark twice; expected each once",
                    )  # fmt: skip
                seen[landmark_id] = key
        pairs = list(landmarks.values())
    else:
        raise InputError(
            path, where.line("landmarks"),
            'expected an object {"landmarks": {"<id>": [x, y], ...}} or [[x, y], ...]',
        )  # fmt: skip
    for k, (landmark_id, pair) in enumerate(zip(ids, pairs, strict=True)):
        if not _finite_numbers(pair, 2):
            line = where.line(names[k]) if names else where.line("landmarks")
            numbers = isinstance(pair, list) and len(pair) == 2 and all(map(_json_number, pair))
            expected = f"[x, y] within {RANGE_TEXT}" if numbers else "[x, y]"
            raise InputError(
                path,
                line,
                f"landmark {landmark_id} is {json.dumps(pair)[:40]}, expected {expected}",
            )
    poses = document.get("poses")
    poses_xytheta = None
    if poses is not None:
        if not (isinstance(poses, list) and poses and all(_finite_numbers(p, 3) for p in poses)):
            raise InputError(
                path, where.line("poses"), '"poses" must be a list of [x, y, theta], one per step'
            )
        poses_xytheta = np.array(poses, dtype=np.float64)
    scan_ids = _scan_ids(path, document.get("scan_ids"), where.line("scan_ids"))
    settings: dict[str, float | list[float]] = {}
    noise = document.get("noise")
    if noise is not None:
        if not isinstance(noise, dict) or not all(_sigma(v) for v in noise.values()):
            bad = next((k for k, v in noise.items() if not _sigma(v)), None) if isinstance(
                noise, dict
            ) else None  # fmt: skip
            raise InputError(
                path, where.line("noise") if bad is None else where.line(bad, after="noise"),
                f'"noise" is {json.dumps(noise)[:60]}, expected {{"sigma_x": 0.1, ...}}'
                " with sigmas >= 0",
            )  # fmt: skip
        settings.update({k: float(v) for k, v in noise.items()})
    prior = document.get("init_pose_sigma")
    if prior is not None:
        if not (_finite_numbers(prior, 3) and all(map(_sigma, prior))):
            raise InputError(
                path, where.line("init_pose_sigma"),
                f'"init_pose_sigma" is {json.dumps(prior)[:60]}, expected [sx, sy,'
                " stheta] with sigmas >= 0",
            )  # fmt: skip
        settings["init_pose_sigma"] = [float(v) for v in prior]
    return GroundTruth(
        ids=np.array(ids, dtype=np.int64),
        landmarks_xy=np.array(pairs, dtype=np.float64).reshape(-1, 2),
        poses_xytheta=poses_xytheta,
        simulated_with=settings or None,
        scan_ids=scan_ids,
    )


class _KeyLines:
    """The line of a JSON truth file where a key is first written (``"key":``), read
    once asked: the line an error names (1 where the key is not found)."""

    def __init__(self, path: Path) -> None:
        self._path = path
        self._text: str | None = None

    def line(self, key: str, after: str | None = None) -> int:
        """The line of ``key`` (the first one after the key ``after``, where given)."""
        if self._text is None:
            with open_input(self._path) as handle:
                raw = handle.read().replace(b"\r\n", b"\n").replace(b"\r", b"\n")
                self._text = raw.decode("utf-8", errors="replace")
        start = 0
        if after is not None:
            outer = re.search(rf'"{re.escape(after)}"\s*:', self._text)
            start = 0 if outer is None else outer.end()
        found = re.compile(rf'"{re.escape(key)}"\s*:').search(self._text, start)
        return 1 if found is None else self._text.count("\n", 0, found.start()) + 1


def _scan_ids(
    path: Path, value: object, line: int = 1
) -> tuple[tuple[int | None, ...], ...] | None:
    """The truth's ``scan_ids``: per scan line, each measurement's landmark id or null
    (``line``: where the key is written, for the message)."""
    if value is None:
        return None
    expected = '"scan_ids" must be a list with one list per scan line of landmark ids or null'
    if not isinstance(value, list):
        raise InputError(path, line, expected)
    scans: list[tuple[int | None, ...]] = []
    for k, ids in enumerate(value):
        if not isinstance(ids, list) or not all(
            i is None or (isinstance(i, int) and not isinstance(i, bool) and 0 <= i <= MAX_ID)
            for i in ids
        ):
            raise InputError(path, line, f"{expected}; scan {k + 1} is {json.dumps(ids)[:40]}")
        scans.append(tuple(ids))
    return tuple(scans)


def _finite_numbers(value: object, count: int) -> bool:
    return isinstance(value, list) and len(value) == count and all(map(_number, value))


def _number(value: object) -> bool:
    """A JSON number within +-MAX_MAGNITUDE (load_json holds no other, a caller might)."""
    return (
        isinstance(value, int | float)
        and not isinstance(value, bool)
        and -MAX_MAGNITUDE <= value <= MAX_MAGNITUDE
    )


def _json_number(value: object) -> bool:
    """A JSON number, of any size (out of range: another message)."""
    return isinstance(value, int | float) and not isinstance(value, bool)


def _sigma(value: object) -> bool:
    return _number(value) and value >= 0  # type: ignore[operator]


def truth_json(truth: GroundTruth, **extra: object) -> str:
    """A truth file's JSON text, one landmark and one pose a line, ``extra`` keys first."""
    lines = [
        f"  {json.dumps(key)}: {json.dumps(value)},"
        for key, value in extra.items()
        if key != "scan_ids"
    ]
    if "scan_ids" in extra:  # one scan a line
        scans = ",\n".join(f"    {json.dumps(ids)}" for ids in extra["scan_ids"])  # type: ignore[attr-defined]
        lines.append('  "scan_ids": [\n' + scans + "\n  ],")
    order = np.argsort(truth.ids, kind="stable")
    landmarks = [
        f'    "{int(truth.ids[i])}": {json.dumps(truth.landmarks_xy[i].tolist())}' for i in order
    ]
    lines.append('  "landmarks": {\n' + ",\n".join(landmarks) + "\n  }")
    if truth.poses_xytheta is not None:
        poses = [
            f"    {json.dumps([round(v, 9) for v in p])}" for p in truth.poses_xytheta.tolist()
        ]
        lines[-1] += ","
        lines.append('  "poses": [\n' + ",\n".join(poses) + "\n  ]")
    return "{\n" + "\n".join(lines) + "\n}\n"


def _truth(rows: list[list[float]]) -> GroundTruth:
    xy = np.array(rows, dtype=np.float64).reshape(-1, 2)
    return GroundTruth(ids=np.arange(1, len(xy) + 1, dtype=np.int64), landmarks_xy=xy)


def checked_against(
    events: Iterable[AnyEvent], truth: GroundTruth, truth_path: Path, *, every_id: bool
) -> Iterator[AnyEvent]:
    """Pass events through, stopping at the first landmark the truth does not know, and,
    when the truth has ``scan_ids``, at the first scan line they do not fit.

    :param every_id: the log names all its landmarks on its first line (the classic
        format): then the truth must hold exactly those
    :raises InputError: naming the truth file and the log line that does not fit it
    """
    known = set(truth.ids.tolist())
    first = True
    scans = 0
    scan_ids = truth.scan_ids
    steps = StepCounter()
    driven = 0.0  # the log's path length: the sum of |d| of its controls
    for index, event in enumerate(events):
        if isinstance(event, Control):
            steps.predict()
            driven += abs(event.d)
        elif index == 0:  # an observation first (a sighting or a scan): the initialisation
            steps.initialise()
        else:
            steps.update()
        if isinstance(event, Sighting):
            ids = set(event.ids.tolist())
            if first and every_id and ids != known:
                raise InputError(
                    truth_path,
                    0,
                    f"found {len(known)} landmarks, expected the {len(ids)} of the log's"
                    f" first line (ids 1 to {len(ids)})",
                )
            unknown = ids - known
            if unknown:
                raise InputError(
                    truth_path,
                    0,
                    f"has no landmark {min(unknown)}, which line {event.line} of the log"
                    " observes: expected a true position for every landmark",
                )
            first = False
        elif isinstance(event, Scan) and scan_ids is not None:
            scans += 1
            _check_scan(truth_path, scan_ids, scans, event, known)
        yield event
    if scan_ids is not None and scans != len(scan_ids):
        raise InputError(
            truth_path,
            0,
            f'has {len(scan_ids)} lists in "scan_ids", expected one per scan line of the log'
            f" ({scans})",
        )
    if truth.poses_xytheta is not None:
        _check_poses(truth_path, truth.poses_xytheta, steps.step, driven)


# a truth's path this many times longer or shorter than the log's controls drive is of
# another run (odometry errs by percents, not by factors)
PATH_RATIO_LIMIT = 3.0


def _check_poses(truth_path: Path, poses: FloatArray, steps: int, driven: float) -> None:
    """Refuse true poses that do not fit the log: one for the start and each step of the
    log (``steps``; more are a longer run's, of which the log is the beginning), along a
    path about as long as the controls drive (``driven`` metres).

    :raises InputError: naming the truth file and both numbers
    """
    if len(poses) < steps + 1:
        expected = steps + 1
        raise InputError(truth_path, 0, f'has {len(poses)} "poses", expected one per step of the'
                         f" log and the start ({expected}): another run's")  # fmt: skip
    walked = float(np.sum(np.hypot(*np.diff(poses[: steps + 1, :2], axis=0).T)))
    longest, shortest = max(walked, driven), min(walked, driven)
    if longest > 1.0 and longest > PATH_RATIO_LIMIT * shortest:
        raise InputError(truth_path, 0, f"its poses walk {walked:.3g} m where the log's controls"
                         f" drive {driven:.3g} m: its poses belong to another run")  # fmt: skip


def _check_scan(
    truth_path: Path,
    scan_ids: tuple[tuple[int | None, ...], ...],
    k: int,
    scan: Scan,
    known: set[int],
) -> None:
    """Refuse a scan line (the k-th, 1-based) that its ``scan_ids`` entry does not fit."""
    where = f"the log's scan line {scan.line} (scan {k})"
    if k > len(scan_ids):
        raise InputError(
            truth_path,
            0,
            f'has {len(scan_ids)} lists in "scan_ids", expected one for {where} and every'
            " other scan line",
        )
    ids = scan_ids[k - 1]
    if len(ids) != len(scan.z):
        raise InputError(
            truth_path,
            0,
            f'has {len(ids)} ids in "scan_ids" for {where}, expected one per measurement'
            f" ({len(scan.z)})",
        )
    unknown = {i for i in ids if i is not None} - known
    if unknown:
        raise InputError(
            truth_path,
            0,
            f'has landmark {min(unknown)} in "scan_ids" for {where}, which is not among its'
            " landmarks: expected their ids or null (clutter)",
        )
