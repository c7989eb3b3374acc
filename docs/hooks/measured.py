"""MkDocs hook: ``benchmarks/RESULTS.md``, which ``make bench`` writes, as the site's
page of measured figures (``results.md``), with the pictures it shows.

The file stays where ``make bench`` writes it; the site reads it at every build, so the
page always holds the figures of the last ``make bench``.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from mkdocs.structure.files import File, Files

RESULTS = Path(__file__).resolve().parents[2] / "benchmarks" / "RESULTS.md"
PAGE = "results.md"


def on_files(files: Files, config: Any, **_: Any) -> Files:
    """Add the page and every picture it links beside it (MkDocs' files event)."""
    text = RESULTS.read_text(encoding="utf-8")
    files.append(File.generated(config, PAGE, content=text))
    for name in sorted(set(re.findall(r"!\[[^\]]*\]\(([\w.-]+\.png)\)", text))):
        files.append(File.generated(config, name, abs_src_path=str(RESULTS.parent / name)))
    return files
