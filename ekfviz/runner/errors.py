"""How the runner names the line where a filter could not go on."""

from __future__ import annotations

from ekfviz.core.errors import FilterError
from ekfviz.core.records import AnyEvent, Control, Drive
from ekfviz.filters.plugged import PluginError


class FilterLineError(FilterError):
    """The filter could not go on at a line of the log.

    :param line: the log line whose event failed
    :param motion: whether that event was a motion (a predict); None: not known
    """

    def __init__(self, line: int, message: str, motion: bool | None = None) -> None:
        self.line = line
        self.motion = motion
        super().__init__(message)

    def __reduce__(self) -> tuple[type[FilterLineError], tuple[int, str, bool | None]]:
        # rebuilt from its arguments where a study's worker process hands it back
        return type(self), (self.line, str(self), self.motion)


def line_error(error: FilterError, log_event: AnyEvent, event: int) -> FilterLineError:
    """``error``, raised at ``log_event`` (the run's ``event``-th), as the error of its
    line: a protocol filter's own failure says which event and kind it was; a
    :class:`FilterLineError` raised at the line already is that error, told whether the
    event was a motion."""
    motion = isinstance(log_event, Control | Drive)
    if isinstance(error, FilterLineError):
        if error.motion is None and error.line == log_event.line:
            error.motion = motion
        return error
    if isinstance(error, PluginError):
        kind = "predict" if isinstance(log_event, Control) else "update"
        return FilterLineError(log_event.line, f"event {event} ({kind}): {error}", motion)
    return FilterLineError(log_event.line, str(error), motion)


def initial_error(error: FilterError, line: int) -> FilterLineError:
    """``error``, raised where the filter is set up from the log's first line (an
    observation: ``line``; 0 where the prior alone)."""
    if isinstance(error, FilterLineError):
        return error
    if isinstance(error, PluginError):
        return FilterLineError(line, f"event 0 (init): {error}", False if line else None)
    return FilterLineError(line, str(error), False if line else None)
