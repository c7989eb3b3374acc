"""``ekfviz ARGS`` run in the test's own process, answered as ``subprocess.run`` answers.

A command costs its imports once per test process instead of once per call. Tests about
the process itself (signals, a closed or full standard stream, start-up imports, the exit
of a process killed part-way) start ``python -m ekfviz`` instead.
"""

from __future__ import annotations

import io
import os
import subprocess
import sys
import traceback
from collections.abc import Iterator, Mapping
from contextlib import contextmanager, redirect_stderr
from pathlib import Path

import typer
from typer.testing import CliRunner


def run_ekfviz(
    *args: object,
    cwd: Path | str | None = None,
    input: str | None = None,
    env: Mapping[str, str | None] | None = None,
) -> subprocess.CompletedProcess[str]:
    """Run ``ekfviz *args`` as ``main()`` does (``--debug`` hoisted, the numbers of
    multi-value options checked) and return its exit code, standard output and standard
    error; an exception the command let out is written to standard error as a traceback,
    as Python would, with exit code 1. ``env`` sets variables for the run (None: unset)."""
    from ekfviz.cli import app
    from ekfviz.cli.program import prepare_argv

    argv = [os.fspath(a) if isinstance(a, os.PathLike) else str(a) for a in args]
    with _working_directory(cwd):
        said = io.StringIO()
        try:
            with redirect_stderr(said):
                argv = prepare_argv(argv)
        except typer.Exit as stop:
            return subprocess.CompletedProcess(argv, stop.exit_code, "", said.getvalue())
        result = CliRunner().invoke(app, argv, input=input, env=env, prog_name="ekfviz")
    stderr = result.stderr
    code = result.exit_code
    error = result.exception
    if error is not None and not isinstance(error, SystemExit):
        stderr += "Traceback (most recent call last):\n" + "".join(
            traceback.format_exception(type(error), error, error.__traceback__)
        )
        code = 1
    return subprocess.CompletedProcess(argv, code, result.stdout, stderr)


def run_ekfviz_process(
    *args: object, cwd: Path | str | None = None, timeout: float = 300, **options: object
) -> subprocess.CompletedProcess[str]:
    """Run ``python -m ekfviz *args`` in a process of its own (for what is about the process:
    its exit, its streams, its start-up)."""
    return subprocess.run(
        [sys.executable, "-m", "ekfviz", *map(str, args)],
        capture_output=True,
        text=True,
        cwd=cwd,
        timeout=timeout,
        **options,  # type: ignore[call-overload]
    )


def one_error_line(output: str, expected: str) -> str:
    """The only line of ``output``, an error holding ``expected``."""
    lines = [line for line in output.splitlines() if line.strip()]
    assert len(lines) == 1, output
    assert lines[0].startswith("error: ") and expected in lines[0], lines[0]
    assert "Traceback" not in output
    return lines[0]


@contextmanager
def _working_directory(path: Path | str | None) -> Iterator[None]:
    """Run in ``path`` (as a process started there would), then go back."""
    if path is None:
        yield
        return
    before = os.getcwd()
    os.chdir(path)
    try:
        yield
    finally:
        os.chdir(before)
