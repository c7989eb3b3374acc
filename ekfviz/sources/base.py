"""What a source gives a run, and the registry that picks the source of a path.

A :class:`Source` is one input format seen whole: its events (through a reader of
:mod:`ekfviz.io`), the truth it comes with, the models and default noise it implies, its
reference and the words that describe it in a recording. The runner and the commands
only ask a source; none of them tests which format it is.

Numpy only: the command line turns each format's :class:`SourceOption` into an option
of every command that opens a log.
"""

from __future__ import annotations

import abc
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar, Protocol, TypeVar

from ekfviz.core.batch import EventBatch
from ekfviz.core.errors import InputError
from ekfviz.core.params import FilterParams, MotionNoise
from ekfviz.core.records import AnyEvent
from ekfviz.core.truth import GroundTruth
from ekfviz.core.types import FloatArray
from ekfviz.evaluation.reference import ReferenceFit
from ekfviz.filters.ekf import EkfSlam
from ekfviz.io.extended import LogNoise
from ekfviz.io.text import ProgressCallback, WarningCallback
from ekfviz.models.range_bearing import RangeBearing

OptionValue = int | float | str


@dataclass(frozen=True, slots=True)
class SourceOption:
    """A command-line option of one format (MRCLAM's ``--robot``, a bag's topics).

    :param name: the Python name; the flag is ``--name-with-dashes``
    :param kind: the value's type
    :param default: None: not given unless given (the source chooses)
    :param show_default: as Typer's (False, True or the text to show)
    :param panel: the help panel, None for the commands' main one
    """

    name: str
    kind: type[int] | type[float] | type[str]
    help: str
    default: OptionValue | None = None
    show_default: bool | str = False
    panel: str | None = None
    metavar: str | None = None
    min: float | None = None

    @property
    def flag(self) -> str:
        return "--" + self.name.replace("_", "-")


@dataclass(frozen=True, slots=True)
class SourceArgs:
    """The source options of one command line: every value, and the names given."""

    values: Mapping[str, OptionValue | None] = field(default_factory=dict)
    given: frozenset[str] = frozenset()

    def value(self, option: SourceOption) -> OptionValue | None:
        """The option's value: the one given, else its default."""
        found = self.values.get(option.name)
        return option.default if found is None else found


@dataclass(frozen=True, slots=True)
class OwnTruth:
    """The truth a source comes with and the files it was read from."""

    truth: GroundTruth
    files: list[Path]


@dataclass(frozen=True, slots=True)
class Models:
    """The built-in filter a source implies, with its models and what to record of them.

    :param params: the filter's parameters with the source's defaults applied
    :param slam: the built-in filter, its vehicle and sensor models inside
    :param sensor: the filter's sensor (the associator's: mounted where the source says)
    :param recorded_sensor: the sensor as seen from the records' pose
    :param parameters: what the recording says of the models (name -> value)
    :param builtin_only: why only the built-in filter can replay the source, if so
    """

    params: FilterParams
    slam: EkfSlam
    sensor: RangeBearing
    recorded_sensor: RangeBearing
    parameters: dict[str, object] = field(default_factory=dict)
    builtin_only: str | None = None


class Reference(Protocol):
    """An independent reference of the path (Victoria Park's GPS): it watches every
    batch of a run's events and is fitted to the estimated path at the end.

    ``key`` names its results in the report (``gps``)."""

    key: str

    def add(self, events: EventBatch) -> None: ...

    def fit(self, warn: WarningCallback) -> FittedReference | None: ...


@dataclass(frozen=True, slots=True)
class FittedReference:
    """A reference fitted to the path: the fit, the step of each of its points (for the
    recording's timeline), the figures of the report and the summary line."""

    fit: ReferenceFit
    steps: FloatArray  # (K,) the step of each point, for the recording's timeline
    results: dict[str, object]
    summary: str


Given = Callable[[str], bool]  # whether an option was given on the command line


class Source(abc.ABC):
    """One input to replay (see the module). Subclasses are frozen dataclasses with a
    ``path`` field, registered with :func:`register`."""

    kind: ClassVar[str]  # a short name: "classic", "mrclam", "rosbag"
    description: ClassVar[str]  # what it is, for messages: "an MRCLAM dataset directory"
    # for directory formats: the files that mark one (said when a directory is none)
    marker: ClassVar[str | None] = None
    options: ClassVar[tuple[SourceOption, ...]] = ()
    # the motion noise its controls imply: time-scaled for velocity odometry
    motion_noise: ClassVar[MotionNoise] = MotionNoise.PER_STEP
    # its first line names every landmark (classic): a --truth file must know them all
    names_every_landmark: ClassVar[bool] = False
    # every observation names its landmark: the association applies to no scan, and its
    # settings are recorded only when asked for
    ids_only: ClassVar[bool] = False
    # why it cannot be one of a study's runs (sweep, compare), if it cannot
    study_refusal: ClassVar[str | None] = None

    path: Path

    @classmethod
    @abc.abstractmethod
    def detect(cls, path: Path) -> bool:
        """Whether ``path`` is of this format (asked in registration order)."""

    @classmethod
    def open(cls: type[S], path: Path, args: SourceArgs) -> S:
        """The source of ``path`` with the options given.

        :raises InputError: what is missing or wrong, in one line
        """
        return cls(path)  # type: ignore[call-arg]  # the dataclass's one field

    @property
    def name(self) -> str:
        """A short name for recordings (the file's stem)."""
        return self.path.stem

    @property
    def files(self) -> list[Path]:
        """The files the events are read from."""
        return [self.path]

    @property
    def progress_paths(self) -> list[Path]:
        """The files whose bytes read, summed, measure the progress."""
        return [self.path]

    @abc.abstractmethod
    def events(
        self, progress: ProgressCallback | None = None, warn: WarningCallback | None = None
    ) -> Iterator[AnyEvent]:
        """Stream the events in time order.

        :param progress: called now and then with the bytes of ``progress_paths`` read
        :param warn: told what the reader let pass (wrapped bearings, skipped lines)
        :raises InputError: at the first bad input, naming its file and line
        """

    def own_truth(self, warn: WarningCallback) -> OwnTruth | None:
        """The truth the source comes with, if any (``warn``: why it has none, if it
        should have)."""
        return None

    def file_of(self, motion: bool) -> Path | None:
        """The file an event's line number is in, where the source is more than one: of a
        motion (a predict) or not (an update); None: the input as given (one file)."""
        return None

    def stated_noise(self) -> LogNoise:
        """The noise the input states of itself (an extended log's ``# noise:`` header),
        the filter's defaults where no option is given; empty when it states none.

        :raises InputError: a statement that does not read
        """
        return {}

    def models(self, params: FilterParams, given: Given) -> Models:
        """The built-in filter for this source (classic models unless it says otherwise).

        :param given: whether an option was given on the command line (the source's
            defaults replace only the others)
        :raises InputError: options or files the source refuses
        """
        sensor = RangeBearing()
        return Models(params, EkfSlam(params), sensor, sensor)

    def reference(self) -> Reference | None:
        """A fresh reference of the path, if the source has one."""
        return None

    def command_options(self, args: SourceArgs) -> list[str]:
        """The options that open this source again (for a printed replay line)."""
        return [
            token
            for option in self.options
            if option.name in args.given
            for token in (option.flag, str(args.values[option.name]))
        ]


S = TypeVar("S", bound=Source)
_FORMATS: list[type[Source]] = []


def register(cls: type[S]) -> type[S]:
    """Add a format to the registry (detection asks formats in the order registered)."""
    _FORMATS.append(cls)
    return cls


def formats() -> list[type[Source]]:
    """The registered formats, in detection order."""
    return list(_FORMATS)


def source_options() -> list[SourceOption]:
    """Every format's options, each name once."""
    seen: dict[str, SourceOption] = {}
    for fmt in _FORMATS:
        for option in fmt.options:
            seen.setdefault(option.name, option)
    return list(seen.values())


def open_source(path: Path | str, args: SourceArgs | None = None) -> Source:
    """The source of ``path``: the first registered format that claims it.

    :raises InputError: a directory of no known format, an option given for another
        format, what the format itself refuses
    """
    path = Path(path)  # (a str from a notebook)
    args = SourceArgs() if args is None else args
    for fmt in _FORMATS:
        if fmt.detect(path):
            _refuse_others(fmt, path, args)
            return fmt.open(path, args)
    directories = [f for f in _FORMATS if f.marker is not None]
    markers = _listed([str(f.marker) for f in directories], "or")
    expected = _listed(["a log file", *(f.description for f in directories)], "or")
    raise InputError(path, 0, f"is a directory without {markers}, expected {expected}")


def _listed(items: list[str], last: str) -> str:
    """``a, b or c``."""
    return items[0] if len(items) == 1 else f"{', '.join(items[:-1])} {last} {items[-1]}"


def _refuse_others(fmt: type[Source], path: Path, args: SourceArgs) -> None:
    """One line for an option of another format."""
    own = {option.name for option in fmt.options}
    for name in sorted(args.given - own):
        owners = [f for f in _FORMATS if any(o.name == name for o in f.options)]
        flag = "--" + name.replace("_", "-")
        whose = " or ".join(f.description for f in owners) or "no format"
        raise InputError(path, 0, f"{flag} is for {whose}, not {fmt.description}")


def read_log(
    path: Path | str,
    progress: ProgressCallback | None = None,
    warn: WarningCallback | None = None,
) -> Iterator[AnyEvent]:
    """Stream the events of a log of any format, its options at their defaults."""
    return open_source(path).events(progress, warn)
