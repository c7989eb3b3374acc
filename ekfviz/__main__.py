"""``ekfviz`` and ``python -m ekfviz``: the command line."""

from ekfviz import signals


def main() -> None:
    """Defer SIGINT and SIGTERM before the slow imports (see ``ekfviz.signals``), then run."""
    signals.defer()
    from ekfviz.cli import app

    app(prog_name="ekfviz")


if __name__ == "__main__":
    main()
