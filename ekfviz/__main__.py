"""``ekfviz`` and ``python -m ekfviz``: the command line."""

import errno
import os

from ekfviz import signals, startup


def main() -> None:
    """Defer SIGINT and SIGTERM before the slow imports (see ``ekfviz.signals``), keep
    pyarrow from importing pandas and numpy to one BLAS thread, Rerun's own log lines
    off, collect garbage less often (see ``ekfviz.startup``), then run."""
    import sys

    signals.defer()
    startup.standard_streams()
    startup.one_blas_thread()
    startup.quiet_rerun_logs(sys.argv[1:])
    startup.pyarrow_without_pandas()

    import typer

    from ekfviz.cli import COMMANDS, command_of, load
    from ekfviz.cli.common import prepare_argv

    try:
        argv = prepare_argv(sys.argv[1:])
    except typer.Exit as stop:  # outside the app: exit with the code it carries
        raise SystemExit(stop.exit_code) from None
    name = command_of(argv)  # only that command's module: the others cost start-up
    app = load(COMMANDS if name is None else (name,))
    startup.collect_less()  # after the command's imports: see ekfviz.startup
    try:
        try:
            app(args=argv, prog_name="ekfviz")
        except signals.Interrupted as stop:  # a command that did not say more itself
            from ekfviz.cli.common import interrupted, written_before

            written = getattr(stop, "written", ())  # (files written whole just before it)
            interrupted(
                stop,
                written_before(written, [])
                if written
                else "nothing was written; existing files are left as they were",
            )
        except OSError as error:  # written past ekfviz's own output (typer's help)
            from ekfviz.cli.common import DEBUG, fail

            if DEBUG["traceback"]:
                raise
            if _stdout_refused(sys.stdout, error):
                sys.stderr.write(_said(error))
                raise SystemExit(2) from None
            if not isinstance(error.filename, str | bytes) or error.errno not in _PATH_ERRNOS:
                raise
            # a path of the user's that the command's own checks did not name (a name
            # too long for its file system, a folder that cannot be searched)
            try:
                fail(f"{os.fsdecode(error.filename)}: {error.strerror}")
            except typer.Exit as stop:
                raise SystemExit(stop.exit_code) from None
    except SystemExit as leaving:
        if signals.fired():
            # Stopped by a signal, with its line said and its clean-up done: leave now.
            # Python's own exit would join a stopped process pool's threads, which can
            # wait for ever on a queue whose workers were killed.
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(leaving.code if isinstance(leaving.code, int) else 1)
        if leaving.code is None or isinstance(leaving.code, int):
            _leave_now(leaving.code or 0)
        raise


# what the system says of a path itself, not of the command's work on it
_PATH_ERRNOS = frozenset((errno.ENAMETOOLONG, errno.EACCES, errno.EPERM, errno.ELOOP))


def _leave_now(code: int) -> None:
    """Exit with ``code`` once the command is done, without the interpreter's teardown.

    The command has written, committed and flushed all it writes. Tearing down the
    interpreter (clearing a few thousand modules, freeing their objects) would only add
    0.1-0.3 s to every command. The exit handlers still run (Rerun's flush of its
    sinks, a worker's end, a process pool's), then stdout and stderr are flushed. While
    a thread other than the main one is still running, Python's exit waits for it: so
    does this, by leaving it to Python; so it does under a profiler or a tracer.
    """
    import atexit
    import contextlib
    import os
    import sys
    import threading

    if any(not t.daemon and t is not threading.main_thread() for t in threading.enumerate()):
        return
    if sys.getprofile() is not None or sys.gettrace() is not None:
        return  # a profiler or a coverage tool writes its results at the normal exit
    atexit._run_exitfuncs()
    try:
        sys.stdout.flush()
    except BrokenPipeError:  # its reader went away (``| head``): nothing to say
        pass
    except (OSError, ValueError) as error:  # a full disk: what was printed is not whole
        if code == 0:
            with contextlib.suppress(OSError, ValueError):
                sys.stderr.write(_said(error))
            code = 2
    with contextlib.suppress(OSError, ValueError):
        sys.stderr.flush()
    os._exit(code)


def _stdout_refused(stream: object, error: OSError) -> bool:
    """Whether ``error`` is a standard stream's that takes nothing more (a full disk,
    ``> /dev/full``), not a file's of the command (those name their file) nor a reader's
    that went away (``| head``)."""
    if isinstance(error, BrokenPipeError) or error.filename is not None:
        return False
    if error.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EIO, errno.EBADF):
        return True
    try:
        stream.flush()  # type: ignore[attr-defined]
    except BrokenPipeError:
        return False
    except (OSError, ValueError):
        return True
    return False


def _said(error: BaseException) -> str:
    """The error line for standard output that took nothing more, as ekfviz's own output
    says it (see ``ekfviz.cli.common``, imported by then)."""
    from ekfviz.cli.common import refused

    return f"error: {refused('standard output', error)}\n"


if __name__ == "__main__":
    main()
