"""Units a reader can hold: list ekfviz's functions over 100 lines and modules over 800.

    python tools/sizes.py            every offender in ekfviz/, longest first
    python tools/sizes.py cli app    those in the named packages or modules only

Exit status 1 when there is any. A function is counted from its first decorator to its
last line (a nested function is counted in its own right, and in the one holding it);
a module by its lines.
"""

from __future__ import annotations

import ast
import sys
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "ekfviz"
MAX_FUNCTION_LINES = 100
MAX_MODULE_LINES = 800


@dataclass(frozen=True, slots=True)
class Oversized:
    """A unit over its bound: ``where`` is ``path`` or ``path:line function``."""

    where: str
    lines: int
    bound: int

    def __str__(self) -> str:
        return f"{self.where}: {self.lines} lines (at most {self.bound})"


def modules(areas: Iterable[str] = ()) -> list[Path]:
    """The modules of ekfviz, or of the named areas (``cli``, ``viz/run``, ``startup``:
    a package, or the modules whose path starts so)."""
    found = sorted(PACKAGE.rglob("*.py"))
    wanted = [area.strip("/") for area in areas]
    if not wanted:
        return found
    return [
        path
        for path in found
        if any(str(path.relative_to(PACKAGE).with_suffix("")).startswith(w) for w in wanted)
    ]


def oversized(paths: Iterable[Path], root: Path = PACKAGE.parent) -> list[Oversized]:
    """Every module over :data:`MAX_MODULE_LINES` and function over
    :data:`MAX_FUNCTION_LINES` in ``paths`` (named from ``root``), longest first."""
    found: list[Oversized] = []
    for path in paths:
        text = path.read_text(encoding="utf-8")
        name = str(path.relative_to(root))
        length = len(text.splitlines())
        if length > MAX_MODULE_LINES:
            found.append(Oversized(name, length, MAX_MODULE_LINES))
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                start = min([node.lineno, *(d.lineno for d in node.decorator_list)])
                lines = (node.end_lineno or node.lineno) - start + 1
                if lines > MAX_FUNCTION_LINES:
                    found.append(
                        Oversized(f"{name}:{node.lineno} {node.name}", lines, MAX_FUNCTION_LINES)
                    )
    return sorted(found, key=lambda unit: -unit.lines)


def main(argv: list[str]) -> int:
    found = oversized(modules(argv))
    for unit in found:
        print(unit)
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
