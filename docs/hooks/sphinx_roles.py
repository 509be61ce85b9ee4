"""A mkdocs hook for the API reference: the docstrings cross-reference with Sphinx roles (:class:`~pkg.mod.Name`),
which mkdocstrings leaves as text. A role becomes the code it names, shortened as Sphinx would for ``~``, and a link
where the name is fully qualified and documented on the site (an optional autorefs reference: no warning when not)."""

from __future__ import annotations

import html
import re
from typing import Any

# after Markdown: the role's text, then its target in <code>
ROLE = re.compile(r":(?:py:)?(?:class|func|meth|attr|data|mod|exc|obj|const):<code>(~?)([^<]+)</code>")


def _replace(match: re.Match[str]) -> str:
    short, target = match[1], html.unescape(match[2]).strip()
    shown = target.rsplit(".", 1)[-1] if short else target.lstrip(".")
    code = f"<code>{html.escape(shown)}</code>"
    if target.startswith("tactile_zoo."):
        return f'<autoref identifier="{html.escape(target)}" optional>{code}</autoref>'
    return code


def on_page_content(content: str, **kwargs: Any) -> str:
    return ROLE.sub(_replace, content)
