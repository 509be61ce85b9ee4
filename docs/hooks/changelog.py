"""A mkdocs hook that puts the repository's CHANGELOG.md on the site as it is, one source for both.

``docs/changelog.md`` holds only the marker line below; this hook replaces the page's Markdown with CHANGELOG.md (next
to mkdocs.yml) before it is rendered. CHANGELOG.md links into the site as GitHub reads it from the repository root
(``docs/table1.md#...``); on the site the page lives in ``docs/``, so those links lose their ``docs/`` prefix here. Any
other relative link stays as written, and the strict build fails on it: the changelog may link only to site pages.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

#: the whole content of docs/changelog.md
MARKER = "<!-- CHANGELOG.md is included here by docs/hooks/changelog.py -->"
# a Markdown link or link definition whose target starts with docs/: `](docs/x.md)` and `[x]: docs/x.md`
DOCS_LINK = re.compile(r"(\]\(|^\[[^\]]+\]:\s*)docs/", re.M)


def site_markdown(changelog: str) -> str:
    """CHANGELOG.md's text with its links into docs/ made relative to docs/changelog.md."""
    return DOCS_LINK.sub(r"\1", changelog)


def on_page_markdown(markdown: str, page: Any, config: Any, **kwargs: Any) -> str:
    if MARKER not in markdown:
        return markdown
    source = Path(config["config_file_path"]).parent / "CHANGELOG.md"
    return markdown.replace(MARKER, site_markdown(source.read_text()))
