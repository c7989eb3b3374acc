"""A classic log rewritten in the extended format, every number kept as written.

The log is read (and so checked) by the classic reader first; the extended text is then
made from the tokens of its lines, so that ``1.3180`` stays ``1.3180`` and a bearing the
reader would wrap stays as given (the extended reader wraps it the same way).
"""

from __future__ import annotations

from pathlib import Path

from ekfviz.core.errors import InputError
from ekfviz.io.classic import read_classic
from ekfviz.io.extended import is_extended
from ekfviz.io.text import token_lines

HEADER = "# ekfviz extended log: control d alpha | observe id bearing range ..."


def classic_to_extended(path: Path) -> tuple[str, int]:
    """The extended text of the classic log at ``path`` and its number of events.

    :raises InputError: a bad classic log (as :func:`~ekfviz.io.classic.read_classic`),
        or a log that is already in the extended format
    """
    if is_extended(path):
        first = next(token_lines(path))[0]
        raise InputError(
            path, first, "is already in the extended format (keyword lines): nothing to convert"
        )
    events = sum(1 for _ in read_classic(path))
    lines = [HEADER]
    for k, (_, tokens) in enumerate(token_lines(path)):
        if k > 0 and len(tokens) == 2:
            lines.append(f"control {tokens[0]} {tokens[1]}")
            continue
        cells = [f"{i + 1} {tokens[2 * i]} {tokens[2 * i + 1]}" for i in range(len(tokens) // 2)]
        lines.append(" ".join(["observe", *cells]))
    return "\n".join(lines) + "\n", events
