"""``ekfviz`` and ``python -m ekfviz``: the command line."""

from ekfviz import signals, startup


def main() -> None:
    """Defer SIGINT and SIGTERM before the slow imports (see ``ekfviz.signals``), keep
    pyarrow from importing pandas and numpy to one BLAS thread, Rerun's own log lines
    off, collect garbage less often (see ``ekfviz.startup``), then run."""
    import sys

    signals.defer()
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
            from ekfviz.cli.common import interrupted

            interrupted(stop, "nothing was written; existing files are left as they were")
    except SystemExit as leaving:
        if signals.fired():
            # Stopped by a signal, with its line said and its clean-up done: leave now.
            # Python's own exit would join a stopped process pool's threads, which can
            # wait for ever on a queue whose workers were killed.
            import os

            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(leaving.code if isinstance(leaving.code, int) else 1)
        if leaving.code is None or isinstance(leaving.code, int):
            _leave_now(leaving.code or 0)
        raise


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
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError):  # a closed pipe: nothing to say
            stream.flush()
    os._exit(code)


if __name__ == "__main__":
    main()
