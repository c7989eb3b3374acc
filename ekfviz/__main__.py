"""``ekfviz`` and ``python -m ekfviz``: the command line."""

import contextlib
import errno
import os
import sys

from ekfviz import signals, startup


def main() -> None:
    """Defer SIGINT and SIGTERM before the slow imports (see ``ekfviz.signals``), keep
    pyarrow from importing pandas and numpy to one BLAS thread, Rerun's own log lines
    off, collect garbage less often (see ``ekfviz.startup``), then run."""
    signals.defer()
    startup.standard_streams()
    startup.one_blas_thread()
    startup.quiet_rerun_logs(sys.argv[1:])
    startup.pyarrow_without_pandas()

    import typer

    from ekfviz.cli import COMMANDS, command_of, load
    from ekfviz.cli.program import prepare_argv

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
        except OSError as error:  # written past ekfviz's own output (typer's help)
            _say_os_error(error)
    except SystemExit as leaving:
        if signals.fired():
            # Stopped by a signal, with its line said and its clean-up done: leave now.
            # Python's own exit would join a stopped process pool's threads, which can
            # wait for ever on a queue whose workers were killed.
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(leaving.code if isinstance(leaving.code, int) else 1)
        if leaving.code is None or isinstance(leaving.code, int):
            _leave(leaving.code or 0)
        raise


def _say_os_error(error: OSError) -> None:
    """One line for a system error no command's own checks named; exit 2."""
    import typer

    from ekfviz.cli.console import DEBUG, fail

    if DEBUG["traceback"]:
        raise error
    if _stdout_refused(sys.stdout, error):
        sys.stderr.write(_said(error))
        raise SystemExit(2) from None
    if not isinstance(error.filename, str | bytes) or error.errno not in _PATH_ERRNOS:
        raise error
    # a path of the user's that the command's own checks did not name (a name too long
    # for its file system, a folder that cannot be searched)
    try:
        fail(f"{os.fsdecode(error.filename)}: {error.strerror}")
    except typer.Exit as stop:  # outside the app: exit with the code it carries
        raise SystemExit(stop.exit_code) from None


# what the system says of a path itself, not of the command's work on it
_PATH_ERRNOS = frozenset((errno.ENAMETOOLONG, errno.EACCES, errno.EPERM, errno.ELOOP))


def _leave(code: int) -> None:
    """Exit with ``code`` once the command is done: what it printed flushed first, so that
    a standard output that took nothing more is said (a full disk: exit 2) and a reader
    that went away (``| head``) is not; Python's exit then flushes nothing more. The
    objects made so far are set apart from the garbage collector first (see
    :func:`ekfviz.startup.collect_no_more`).
    """
    try:
        sys.stdout.flush()
    except BrokenPipeError:  # its reader went away: nothing to say
        _stdout_to_null()
    except (OSError, ValueError) as error:  # a full disk: what was printed is not whole
        if code == 0:
            with contextlib.suppress(OSError, ValueError):
                sys.stderr.write(_said(error))
            code = 2
        _stdout_to_null()
    startup.collect_no_more()
    raise SystemExit(code)


def _stdout_to_null() -> None:
    """Point standard output at the null device, so that Python's flush of it at exit
    (of what it could not write) does not fail again (as Python's documentation advises
    for a closed pipe)."""
    with contextlib.suppress(OSError, ValueError, AttributeError):
        null = os.open(os.devnull, os.O_WRONLY)
        os.dup2(null, sys.stdout.fileno())
        os.close(null)


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
    says it (see ``ekfviz.cli.console``, imported by then)."""
    from ekfviz.cli.console import refused

    return f"error: {refused('standard output', error)}\n"


if __name__ == "__main__":
    main()
