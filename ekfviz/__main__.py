"""``ekfviz`` and ``python -m ekfviz``: the command line."""

from ekfviz import signals


def main() -> None:
    """Defer SIGINT and SIGTERM before the slow imports (see ``ekfviz.signals``), then run."""
    signals.defer()
    import sys

    import typer

    from ekfviz.cli import app
    from ekfviz.cli.common import prepare_argv

    try:
        argv = prepare_argv(sys.argv[1:])
    except typer.Exit as stop:  # outside the app: exit with the code it carries
        raise SystemExit(stop.exit_code) from None
    try:
        app(args=argv, prog_name="ekfviz")
    except signals.Interrupted as stop:  # a command that did not say more itself
        from ekfviz.cli.common import interrupted

        interrupted(stop, "nothing was written; existing files are left as they were")


if __name__ == "__main__":
    main()
