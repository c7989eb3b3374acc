"""The line of a submitted file that computes an operation, quoted in a cause's hint.

The file is read as text (never imported here), at most :data:`MAX_BYTES` of it: one pass
finds the functions (a ``def`` and the lines indented under it), another the lines of the
operation's function that assign one of the operation's names (``S = ...``, ``K[...] =``)
or hold the mutation's mark (``arctan2(``, ``deg2rad``); the first line with both wins,
else the first assignment, else the first mark. Linear in the file's size, and bounded.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from ekfviz.check.mutations import Mutation
from ekfviz.check.operations import OPERATION

MAX_BYTES = 1 << 20  # a course module is a few kB; a larger file is read this far
MAX_LINE = 300  # characters of a line looked at (a longer one is cut)

_DEF = re.compile(r"^(\s*)def\s+([A-Za-z_]\w*)\s*\(")
# the functions an operation may live in, beside its course module's own
_METHODS = {
    "predict": ("predict", "motion", "prediction", "predict_step"),
    "update": ("update", "observe", "correct", "correction", "update_step"),
    "init_landmarks": ("init_landmarks", "update", "add_landmark", "_add_landmark", "add",
                       "initialise", "initialize", "init_landmark", "new_landmark"),
}  # fmt: skip


@dataclass(frozen=True, slots=True)
class Quoted:
    """A line of the submitted file: its number (from 1), its function and its text."""

    line: int
    function: str
    text: str

    def to_json(self) -> dict[str, object]:
        return {"line": self.line, "function": self.function, "text": self.text}


class Source:
    """A submitted file's text, split into lines and functions once."""

    def __init__(self, text: str, name: str) -> None:
        self.name = name
        self.lines = [line[:MAX_LINE] for line in text.splitlines()]
        self.functions: dict[str, tuple[int, int]] = {}  # name -> [first, end) of its lines
        self._find_functions()

    @classmethod
    def read(cls, path: str | Path | None) -> Source | None:
        """The file at ``path`` (None where there is none, or it cannot be read)."""
        if path is None:
            return None
        try:
            with open(path, "rb") as handle:
                data = handle.read(MAX_BYTES)
        except OSError:
            return None
        return cls(data.decode("utf-8", errors="replace"), Path(path).name)

    def _find_functions(self) -> None:
        """Each ``def``'s lines: up to the next line indented no deeper than it, after its
        signature (which may run over several lines)."""
        open_defs: list[tuple[int, str, int]] = []  # (indent, name, first line)
        depth = 0  # of the brackets of a signature still open
        for number, line in enumerate(self.lines):
            code = line.split("#", 1)[0]
            if depth > 0:
                depth += _balance(code)
                continue
            stripped = code.strip()
            if not stripped:
                continue
            indent = len(line) - len(line.lstrip())
            while open_defs and indent <= open_defs[-1][0]:
                _, name, first = open_defs.pop()
                self.functions.setdefault(name, (first, number))
            match = _DEF.match(line)
            if match:
                open_defs.append((len(match.group(1)), match.group(2), number))
                depth = max(0, _balance(code))
        for _, name, first in open_defs:
            self.functions.setdefault(name, (first, len(self.lines)))

    def quote(self, mutation: Mutation) -> Quoted | None:
        """The line that computes ``mutation``'s operation, or None where none is found."""
        operation = OPERATION[mutation.operation]
        places = [f for f in _METHODS.get(operation.function, (operation.function,))
                  if f in self.functions]  # fmt: skip
        scopes = [(f, *self.functions[f]) for f in places] or [("", 0, len(self.lines))]
        names = "|".join(re.escape(n) for n in operation.names if n.isidentifier())
        if operation.id == "update_loop":
            assigns = re.compile(r"^\s*for\b|^\s*return\b")
        else:
            assigns = re.compile(
                rf"^\s*(?:self\.)?(?:{names})\s*(?:\[[^\]]*\])?\s*(?:,[^=]*)?[-+*/@]?=(?!=)"
                rf"|^\s*[\w\s,\[\]\.]*,\s*(?:{names})\s*=(?!=)"
            )
        for function, first, end in scopes:
            best: tuple[int, int] | None = None  # (score, line)
            for number in range(first, end):
                code = self.lines[number].split("#", 1)[0]
                if not code.strip() or _DEF.match(code):
                    continue
                score = 2 * bool(assigns.search(code)) + any(t in code for t in mutation.tokens)
                if score and (best is None or score > best[0]):
                    best = (score, number)
                    if score == 3:
                        break
            if best is not None:
                return Quoted(best[1] + 1, function, self.lines[best[1]].strip())
        return None


def _balance(code: str) -> int:
    """Brackets opened minus closed on a line of code (strings not told apart: a
    signature rarely holds a bracket in a string)."""
    return sum(code.count(c) for c in "([{") - sum(code.count(c) for c in ")]}")
