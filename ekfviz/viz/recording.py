"""A recording stream sent to the sinks asked for, its file written whole or not at all.

:func:`open_recording` makes the stream (application id "ekfviz", a recording id fixed
by what made the run: see :mod:`ekfviz.viz.run_info`), attaches the sinks (a file, a
spawned viewer, a served web viewer, a viewer's URL), describes the run in the
recording's properties and documents, and on closing flushes it and commits its file
(:func:`ekfviz.io.files.commit_recording`). A served web viewer outlives the block
when the run ended well: the caller shows it until the user is done.
"""

from __future__ import annotations

import contextlib
import numbers
import threading
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import pyarrow as pa  # type: ignore[import-untyped]
import rerun as rr

from ekfviz.core.tables import utf8
from ekfviz.evaluation.errors import Evaluation
from ekfviz.filters.ekf import HAVE_KERNEL
from ekfviz.io.files import (
    OutputPathError,
    check_output_path,
    commit_recording,
    real_path,
    temporary_beside,
    unused_path,
)
from ekfviz.viz import style
from ekfviz.viz.flush import (
    DiskFull,
    disk_full,
    flush_interruptibly,
    note_writer,
    watch_file,
    written_file,
)
from ekfviz.viz.provenance import RunInfo, json_value
from ekfviz.viz.recorder import Recorder
from ekfviz.viz.viewer import (
    GRPC_PORT,
    LOOPBACK,
    ServedViewer,
    SinkError,
    check_bind,
    display_problem,
    no_viewer,
    rerun_executable,
    viewer_answers,
)

APPLICATION_ID = style.APPLICATION_ID
FLUSH_TIMEOUT_S = 60.0
ABANDON_WAIT_S = 1.0  # how long a stream whose file sink stopped is given to let go


@dataclass(frozen=True, slots=True)
class Sinks:
    """Where a recording goes: a file, a spawned viewer, a served web viewer, a viewer URL.

    :param bind: the address the served web viewer and its gRPC server listen on
        (loopback unless the user says otherwise)
    """

    save: Path | None = None
    spawn: bool = False
    serve: bool = False
    connect: str | None = None
    bind: str = LOOPBACK

    @property
    def any(self) -> bool:
        return self.save is not None or self.spawn or self.serve or self.connect is not None


def resolve_default_sinks(
    sinks: Sinks, input_path: Path, recordings_dir: Path, name: str | None = None
) -> tuple[Sinks, str | None]:
    """The sinks asked for or, when none: a viewer where a display exists, else a file.

    :return: the sinks to use and a note to print about the choice (None when asked for)
    """
    if sinks.any:
        return sinks, None
    problem = display_problem()
    if problem is None:
        return Sinks(spawn=True), "No Rerun output option given: sent the run to a Rerun viewer."
    try:
        if not recordings_dir.is_dir():
            try:  # the default folder, in the current one: made when missing (not its parents)
                recordings_dir.mkdir()
            except OSError as error:
                raise SinkError(
                    f"cannot make the folder {recordings_dir} ({error.strerror})"
                ) from None
        path = unused_path(recordings_dir / f"{name or input_path.stem}.rrd")
    except OSError as error:  # a folder that cannot be read, a name too long for it
        where = error.filename if isinstance(error.filename, str) else recordings_dir
        raise SinkError(
            f"cannot save the recording as {where} ({error.strerror or error});"
            " name the file with --save"
        ) from None
    no_display = "no display" if problem.endswith("not set") else f"no display ({problem})"
    return Sinks(save=path), f"No Rerun output option and {no_display}: the recording is saved"


class Recording:
    """An open recording stream with its sinks; built by :func:`open_recording`.

    :ivar rec: the stream to log to
    :ivar served: the web viewer when serving, else None (kept running after the block
        when the run ended well: the caller closes it)
    :ivar complete: set once everything is logged: only then is a ``--save`` file written
    :ivar partial: the run was cut short: its file goes to
        :func:`~ekfviz.io.files.partial_path` when one is already at the ``--save`` path
    :ivar saved_to: where the ``--save`` file was written, once it is
    """

    def __init__(
        self, rec: rr.RecordingStream, served: ServedViewer | None, unreachable: str | None = None
    ) -> None:
        self.rec = rec
        self.served = served
        self.complete = False
        self.save_failed: str | None = None  # why the --save file is not whole, if it is not
        self.save_path: Path | None = None  # the --save path, for messages
        self.partial = False  # a run cut short: never written over an existing file
        self.saved_to: Path | None = None  # where a --save file went, once written
        self.unreachable = unreachable  # a --connect URL without a viewer, when saving too

    @property
    def url(self) -> str | None:
        """The web viewer's address when serving, else None."""
        return None if self.served is None else self.served.url


def _save_failure(rec: rr.RecordingStream, error: RuntimeError) -> str | None:
    """Why the file a recording is saved to was not written whole, if the flush that
    raised ``error`` says so (Rerun's file writer stopped, or its disk is full); None
    for another sink's failure (a viewer that did not answer)."""
    path = written_file(rec)
    if path is None:
        return None
    if isinstance(error, DiskFull):
        return str(error)
    text = str(error).lower()
    if "file-writer" in text or "file writer" in text or disk_full(path):
        return "no space left on its disk" if disk_full(path) else str(error).splitlines()[0]
    return None


def finish_recorders(
    recording: Recording,
    recorders: Sequence[tuple[Recorder, Evaluation | None]],
    status: Mapping[str, str | int] | None = None,
) -> None:
    """Finish every recorder of a recording (series, evaluation), record how the run
    ended (the property ``status``: finished unless told otherwise) and mark it complete.
    """
    recording.rec.send_property("status", any_values(status or {"state": "finished"}))
    try:
        for recorder, evaluation in recorders:
            recorder.finish(evaluation)
    except RuntimeError as error:
        failed = _save_failure(recording.rec, error)
        if failed is not None:  # the file is not whole: it replaces nothing (not complete)
            recording.save_failed = failed
            raise SinkError(
                f"--save {recording.save_path}: the recording could not be written whole"
                f" ({failed}); nothing was replaced, no file left"
            ) from None
        # a viewer that never answered; a file is complete
        recording.complete = True
        reason = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise SinkError(f"the Rerun viewer did not take the recording: {reason}") from None
    recording.complete = True


@contextmanager
def open_recording(
    info: RunInfo, sinks: Sinks, *, recording_id: str | None = None, deferred: bool = False
) -> Iterator[Recording]:
    """A self-describing recording sent to ``sinks``, closed when the block ends.

    A ``--save`` file is written beside its path under a temporary name and moved over
    the path only once the recording is marked complete; otherwise the temporary file is
    removed and an existing file at the path is left untouched. The recording of a run
    cut short (marked ``partial``) never replaces a file: with one at the path it goes to
    :func:`~ekfviz.io.files.partial_path` instead (``saved_to`` says where). Temporary
    files that runs killed outright (``kill -9``) left beside the path are removed first.

    :param recording_id: the recording's id (default: ``info.recording_id``, fixed by
        what made the run; one of its own for each of several runs of the same input)
    :param deferred: hold what is logged in memory and send it to the sinks only once
        the block ends with the recording complete: a viewer then never shows, and no
        file holds, a recording that was given up half-way
    :raises SinkError: when a sink cannot be used (no display for ``spawn``, ...)
    """
    if not sinks.any:
        raise SinkError("no Rerun output: use --save PATH, --spawn, --serve or --connect URL")
    rec = rr.RecordingStream(
        APPLICATION_ID, recording_id=recording_id or info.recording_id, send_properties=False
    )
    rec.set_log_time_enabled(False)  # only step and event: the same run gives the same data
    unreachable: str | None = None
    if sinks.connect is not None and viewer_answers(sinks.connect) is False:
        if sinks.save is None and not sinks.spawn and not sinks.serve:
            raise SinkError(no_viewer(sinks.connect))
        unreachable = sinks.connect  # the other outputs go on; said at the end
        sinks = Sinks(save=sinks.save, spawn=sinks.spawn, serve=sinks.serve, bind=sinks.bind)
    attached = _Attached()
    recording: Recording | None = None
    ended = False  # the block ran to its end
    try:
        log_sinks = _attach(rec, sinks, attached)
        if not deferred:
            rec.set_sinks(*log_sinks)
        _describe(rec, info)
        if not deferred:
            note_writer(rec)  # (its thread is running by now: the description took a while)
        recording = Recording(rec, attached.served, unreachable)
        recording.save_path = sinks.save
        yield recording
        ended = True
    finally:
        if deferred and recording is not None and recording.complete:
            rec.set_sinks(*log_sinks)  # what was held goes to every sink now
            note_writer(rec)
        _close(rec, recording, attached, sinks.save, keep_serving=ended and unreachable is None)
    if unreachable is not None:
        kept = f"; the recording is saved in {sinks.save}" if sinks.save is not None else ""
        raise SinkError(f"no Rerun viewer at {unreachable}{kept}")


@dataclass(slots=True)
class _Attached:
    """What attaching the sinks started: a save's temporary file and the file it is to
    replace (a symbolic link's target, not the link), a served web viewer."""

    saving: tuple[Path, Path] | None = None
    served: ServedViewer | None = None


def _close(
    rec: rr.RecordingStream,
    recording: Recording | None,
    attached: _Attached,
    save: Path | None,
    *,
    keep_serving: bool,
) -> None:
    """Flush and disconnect the stream, stop a served viewer unless it is to be kept, and
    commit the ``--save`` file (or drop it)."""
    saving = attached.saving
    complete = recording is not None and recording.complete
    failed = recording is not None and recording.save_failed is not None
    try:
        if saving is not None and (failed or (not complete and disk_full(saving[0]))):
            _abandon(rec)  # its file sink has stopped: a flush or disconnect would wait
        else:
            with contextlib.suppress(Exception):
                flush_interruptibly(rec, FLUSH_TIMEOUT_S)
            rec.disconnect()  # finalises the file (footer) and stops a server
        if attached.served is not None and not (keep_serving and complete):
            attached.served.close()
            if recording is not None:
                recording.served = None
    except BaseException:  # a signal in the flush: the file is not known to be whole,
        if recording is not None:  # and is dropped (it left a hidden .part file)
            recording.complete = False
        if attached.served is not None:
            attached.served.close()
        raise
    finally:
        if saving is not None and save is not None:
            saved = commit_recording(
                *saving,
                save,
                complete=recording is not None and recording.complete,
                partial=recording is not None and recording.partial,
            )
            if recording is not None:
                recording.saved_to = saved


def _attach(rec: rr.RecordingStream, sinks: Sinks, attached: _Attached) -> list[rr.LogSinkLike]:
    """Make the sinks and return them; ``attached`` gets what they started (see
    :class:`_Attached`), to be stopped or committed once the recording is closed."""
    log_sinks: list[rr.LogSinkLike] = []
    if sinks.spawn:
        problem = display_problem()
        if problem is not None:
            raise SinkError(f"--spawn needs a display: {problem}; use --save or --serve")
        executable = rerun_executable()
        if executable is None:
            raise SinkError("--spawn needs the rerun viewer, which is not installed; use --save")
        rr.spawn(
            port=GRPC_PORT,
            connect=False,
            executable_path=executable,
            hide_welcome_screen=True,
            recording=rec,  # without it, spawn() asks the (absent) global recording and skips
        )
        log_sinks.append(rr.GrpcSink(f"rerun+http://127.0.0.1:{GRPC_PORT}/proxy"))
    if sinks.connect is not None:
        try:
            log_sinks.append(rr.GrpcSink(sinks.connect))
        except (ValueError, RuntimeError) as error:
            raise SinkError(f"--connect {sinks.connect}: {error}") from None
    if sinks.serve:
        attached.served = ServedViewer(check_bind(sinks.bind))
        try:
            log_sinks.append(rr.GrpcSink(attached.served.grpc_url))
        except (ValueError, RuntimeError) as error:
            raise SinkError(f"--serve: {error}") from None
    if sinks.save is not None:
        target = sinks.save
        try:  # no folder is made: a path that cannot be written is refused before any work
            check_output_path(target, "--save")
        except OutputPathError as error:
            raise SinkError(str(error)) from None
        # Beside the file it replaces (same file system, so os.replace is atomic), made
        # by the FileSink itself so that it gets the usual permissions
        real = real_path(target)
        temporary = temporary_beside(real)
        log_sinks.append(rr.FileSink(temporary))
        watch_file(rec, temporary)  # a full disk stops a flush at once (see viz.flush)
        attached.saving = temporary, real
    return log_sinks


def _abandon(rec: rr.RecordingStream) -> None:
    """Let go of a stream whose file sink stopped on a full disk: its disconnect (which
    flushes) is left to a helper thread, and Rerun's flush at exit is not waited for
    (both would wait for ever); its temporary file is then removed, replacing nothing."""
    helper = threading.Thread(target=rec.disconnect, name="ekfviz-abandon", daemon=True)
    helper.start()
    helper.join(ABANDON_WAIT_S)
    rr.unregister_shutdown()


def _describe(rec: rr.RecordingStream, info: RunInfo) -> None:
    """Recording name and properties, the run information and the input, all static."""
    rec.send_recording_name(utf8(info.name))
    values: dict[str, str | int | bool | None] = {
        "version": info.version,
        "kind": info.kind,
        "command": info.command,
        "parameters": json_value(info.parameters),
        "input_name": info.input_path.name,
        "input_size": info.input_size,
        "input_sha256": info.input_sha256,
        "input_embedded": info.input_text is not None,
        "truth_name": None if info.truth_path is None else info.truth_path.name,
        "truth_sha256": info.truth_sha256,
        "files_sha256": json_value(info.file_digests) if info.file_digests else None,
        "compiled_kernel": HAVE_KERNEL,  # numbers differ from numpy's by round-off only
    }
    values = {k: utf8(v) if isinstance(v, str) else v for k, v in values.items()}
    rec.send_property("ekfviz", any_values(values))
    if info.parameters:
        rec.send_property(
            # a parameter left unset (no --gate) is left out: its column's type is the
            # set value's, and a later recording in the process (a notebook's) would clash
            "parameters",
            any_values(
                {k: _property_value(v) for k, v in info.parameters.items() if v is not None}
            ),
        )
    rec.log(
        style.RUN_INFO,
        rr.TextDocument(utf8(info.markdown()), media_type=rr.MediaType.MARKDOWN),
        static=True,
    )
    if info.input_text is not None:
        rec.log(style.RUN_INPUT, rr.TextDocument(info.input_text), static=True)
    else:
        rec.log(
            style.RUN_INPUT,
            rr.TextDocument(
                f"The input {info.input_path.name} ({info.input_size} bytes, sha256"
                f" {info.input_sha256}) is {info.input_note}."
            ),
            static=True,
        )


def any_values(values: Mapping[str, object]) -> rr.AnyValues:
    """Properties as Rerun's ``AnyValues``, each value an Arrow array of its own type.

    Handed a plain Python value, Rerun asks pyarrow to infer its type, and pyarrow's
    inference first imports pandas, if installed, to know its types (0.3 s or more; see
    :mod:`ekfviz.startup`): the types are stated here instead, as inference gives them.
    A file name in a value may not be UTF-8 (Rerun's strings are).
    """
    bundle = rr.AnyValues()
    for name, value in values.items():
        bundle.with_component_from_data(name, _arrow(value))
    return bundle


def _arrow(value: object) -> pa.Array | None:
    """A property's value as the Arrow array Rerun would infer for it (None: no value)."""
    if value is None:
        return None
    if isinstance(value, bool):
        return pa.array([value], type=pa.bool_())
    if isinstance(value, numbers.Integral):
        return pa.array([int(value)], type=pa.int64())
    if isinstance(value, numbers.Real):
        return pa.array([float(value)], type=pa.float64())
    if isinstance(value, str):
        return pa.array([utf8(value)], type=pa.string())
    if isinstance(value, list | tuple) and all(isinstance(v, numbers.Real) for v in value):
        return pa.array([float(v) for v in value], type=pa.float64())
    raise TypeError(f"a property of type {type(value).__name__}: expected a number or text")


def _property_value(value: object) -> str | int | float | bool | list[float]:
    """A parameter as a value the viewer shows well: scalars as is, the rest as JSON."""
    if isinstance(value, str):
        return utf8(value)  # (a filter's file name may not be UTF-8)
    if isinstance(value, (int, float, bool)):
        return value
    if isinstance(value, (list, tuple)) and all(
        isinstance(v, (int, float)) and not isinstance(v, bool) for v in value
    ):
        return [float(v) for v in value]
    return json_value(value)
