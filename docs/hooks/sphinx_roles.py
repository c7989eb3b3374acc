"""MkDocs hook: Sphinx roles in ekfviz's docstrings (``:class:`~a.b.C```) shown as code.

The docstrings name other objects the Sphinx way; mkdocstrings renders the role's name
beside the code (``:class:a.b.C``). This shows the code alone, and, for a name written
with ``~``, its last part, as Sphinx does.
"""

from __future__ import annotations

import re
from typing import Any

_ROLE = re.compile(r":(?:mod|class|func|meth|attr|data|exc|obj):<code>(~?)([^<]*)</code>")


def on_page_content(html: str, **_: Any) -> str:
    """Drop the roles' names from a page's HTML (MkDocs' page-content event)."""
    return _ROLE.sub(lambda m: f"<code>{m[2].rsplit('.', 1)[-1] if m[1] else m[2]}</code>", html)
