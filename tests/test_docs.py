"""The docs site builds with ``mkdocs build --strict``, and a broken link, anchor or image, or a page left out of the
nav, fails that build; the README stays short and its links into the site point at pages and headings that exist."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
DOCS = REPO / "docs"
CONFIG = REPO / "mkdocs.yml"
README = REPO / "README.md"

#: the most lines README.md may have (issue 31); everything else lives on the site
README_MAX_LINES = 250
#: a link to an excluded page (docs/pending/) is only an INFO line in mkdocs, so the tests look for it themselves
EXCLUDED_LINK = "which is excluded from the built site"

for _module in ("mkdocs", "material", "mkdocstrings_handlers.python"):
    pytest.importorskip(_module, reason='the docs site needs the docs extra: pip install -e ".[docs]"')

pytestmark = pytest.mark.xdist_group("docs")  # one worker builds the site once for the module


def _build(config: Path, site: Path) -> subprocess.CompletedProcess[str]:
    """``mkdocs build --strict``; its log and its last line ("Aborted with N warnings ...") both in ``.stdout``."""
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1", "PYTHONPATH": str(REPO)}
    return subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-f", str(config), "-d", str(site)],
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env, timeout=300)


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The real site, built once with the repository's configuration."""
    out = tmp_path_factory.mktemp("site")
    result = _build(CONFIG, out)
    assert result.returncode == 0, f"mkdocs build --strict failed:\n{result.stdout[-4000:]}"
    assert EXCLUDED_LINK not in result.stdout, result.stdout
    return out


def _nav_pages(nav: list) -> list[str]:
    pages = []
    for item in nav:
        value = next(iter(item.values())) if isinstance(item, dict) else item
        pages.extend(_nav_pages(value) if isinstance(value, list) else [value])
    return pages


def _page_html(site: Path, page: str) -> Path:
    stem = page.removesuffix(".md")
    return site / ("index.html" if stem == "index" else f"{stem.removesuffix('/index')}/index.html")


def _ids(html: Path) -> set[str]:
    return set(re.findall(r'\bid="([^"]+)"', html.read_text()))


def test_the_site_builds_strictly_with_every_nav_page_and_the_api_reference(site: Path) -> None:
    config = yaml.safe_load(CONFIG.read_text())
    pages = _nav_pages(config["nav"])
    assert {"quickstart.md", "datasets.md", "models.md", "harness.md", "pretrained.md", "plugins.md",
            "performance.md", "table1.md", "fidelity.md", "published-results.md", "cli.md",
            "changelog.md", "contribute.md"} <= set(pages)
    for page in pages:
        assert _page_html(site, page).is_file(), page
    # the API reference is generated from the docstrings, not left as ":::" lines
    api = {page: _ids(_page_html(site, page)) for page in pages if page.startswith("api/")}
    for page, qualified in [("api/registry.md", "tactile_zoo.registry.register_model"),
                            ("api/registry.md", "tactile_zoo.models.x_tacformer.XTacformer"),
                            ("api/data.md", "tactile_zoo.data.TactileDataset"),
                            ("api/engine.md", "tactile_zoo.engine.fit"),
                            ("api/bench.md", "tactile_zoo.bench.run_bench"),
                            ("api/weights.md", "tactile_zoo.create_model"),
                            ("api/nn.md", "tactile_zoo.nn.lif.MultiStepLIF"),
                            ("api/testing.md", "tactile_zoo.testing.check_model"),
                            ("api/testing.md", "tactile_zoo.testing.ContractError")]:
        assert qualified in api[page], (page, qualified)
    assert "<summary>Shapes</summary>" in _page_html(site, "api/nn.md").read_text()
    for page in pages:
        text = _page_html(site, page).read_text()
        assert ":::" not in text, f"an unrendered mkdocstrings block in {page}"
        # docs/hooks/sphinx_roles.py turns the docstrings' :class:`...` into code, or links
        assert not re.search(r":(class|func|meth|attr|data|mod|exc):<code>", text), f"a raw Sphinx role in {page}"
    # a role naming a documented object links to it: XTacformer's docstring names Tacformer
    xtacformer = _page_html(site, "api/registry.md").read_text().split('id="tactile_zoo.models.x_tacformer"')[1]
    assert 'href="#tactile_zoo.models.tacformer.Tacformer"' in xtacformer


def _copy_without_api_plugin(tmp_path: Path) -> Path:
    """The docs and configuration in ``tmp_path``, without mkdocstrings (the API pages become plain text): the same
    pages, nav and validation settings, built in about a second."""
    shutil.copytree(DOCS, tmp_path / "docs", ignore=shutil.ignore_patterns("pending"))
    shutil.copy(REPO / "CHANGELOG.md", tmp_path)  # docs/changelog.md includes it (docs/hooks/changelog.py)
    config = yaml.safe_load(CONFIG.read_text())
    config["plugins"] = [p for p in config["plugins"] if not (isinstance(p, dict) and "mkdocstrings" in p)]
    (tmp_path / "mkdocs.yml").write_text(yaml.safe_dump(config, sort_keys=False))
    return tmp_path / "mkdocs.yml"


@pytest.fixture(scope="module")
def planted(tmp_path_factory: pytest.TempPathFactory) -> tuple[str, Path]:
    """The log and the site of one build of the copy with what the three tests below plant (a build per test cost
    1.7 s of CPU each): in the pages a broken link, anchor, same-page anchor and image, an orphan page and a link
    into docs/pending/; in CHANGELOG.md a link outside the site and a missing heading; a note in docs/pending/ with a
    broken link. The build must fail (strict mode writes the whole site first)."""
    tmp_path = tmp_path_factory.mktemp("planted")
    config = _copy_without_api_plugin(tmp_path)
    docs = tmp_path / "docs"
    (docs / "pending").mkdir()
    (docs / "pending" / "note.md").write_text("# A note for the docs, not yet a page\n")
    (docs / "pending" / "harness-note.md").write_text("# Note\n\n[broken](../no-such-page.md#x)\n")
    (docs / "orphan.md").write_text("# A page nobody put in the nav\n")
    with (docs / "quickstart.md").open("a") as page:
        page.write("\n[a](no-such-page.md), [b](harness.md#no-such-section), [c](#nowhere), [d](pending/note.md)\n"
                   "\n![e](img/no-such-image.png)\n")
    with (tmp_path / "CHANGELOG.md").open("a") as changelog:
        changelog.write("\n- [the plan](benchmarks/results/PLAN.md), [a heading](docs/table1.md#no-such-heading)\n")
    result = _build(config, tmp_path / "site")
    assert result.returncode != 0
    # the five warnings planted in the pages, the two in the changelog, and nothing else (the link into pending/ is
    # the INFO line; the note's broken link is no warning)
    assert "Aborted with 7 warnings in strict mode!" in result.stdout, result.stdout
    return result.stdout, tmp_path / "site"


def test_a_broken_link_anchor_or_image_or_an_orphan_page_fails_the_strict_build(planted: tuple[str, Path]) -> None:
    for fault in ["'no-such-page.md', but the target is not found",
                  "'harness.md#no-such-section', but the doc 'harness.md' does not contain an anchor",
                  "'#nowhere', but there is no such anchor on this page",
                  "'img/no-such-image.png', but the target is not found",
                  "not included in the \"nav\" configuration:\n  - orphan.md",
                  f"'pending/note.md' {EXCLUDED_LINK}"]:
        assert fault in planted[0], (fault, planted[0])


def test_notes_in_docs_pending_never_break_the_build(planted: tuple[str, Path]) -> None:
    """The note's broken link adds no warning to the planted seven (the fixture counts them), and it is not built."""
    log, site = planted
    assert "no-such-page.md#x" not in log and "harness-note" not in log, log
    assert (site / "quickstart" / "index.html").is_file() and not (site / "pending").exists()


def test_the_changelog_is_on_the_site_with_its_links_into_the_docs(site: Path) -> None:
    """docs/changelog.md is CHANGELOG.md (docs/hooks/changelog.py): every version heading is on the page, and its
    links into docs/ resolve from the page (the strict build checked their anchors)."""
    page = _page_html(site, "changelog.md").read_text()
    changelog = (REPO / "CHANGELOG.md").read_text()
    versions = re.findall(r"^## \[([^\]]+)\]", changelog, re.M)
    assert versions[0] == "Unreleased" and len(versions) >= 2
    for version in versions:
        assert f">[{version}]" in page or f">{version}<" in page or f"[{version}]" in page, version
    targets = re.findall(r"\]\(docs/([\w/-]+)\.md", changelog)
    assert targets, "the changelog links to the pages that hold the details"
    for target in set(targets):
        assert f'href="../{target}/' in page, target


def test_a_changelog_link_outside_the_site_fails_the_strict_build(planted: tuple[str, Path]) -> None:
    log, _ = planted
    assert "'benchmarks/results/PLAN.md', but the target is not found" in log, log
    assert "'table1.md#no-such-heading', but the doc 'table1.md' does not contain an anchor" in log


def _readme_lines_outside_table1() -> list[str]:
    # Until the Table I branch is merged the README still holds "Reproducing the paper's Table I" (it moves to
    # docs/table1.md, leaving a generated headline block); that section is not counted. Once it is gone, every line is.
    lines = README.read_text().splitlines()
    heading = "## Reproducing the paper's Table I"
    if heading not in lines:
        return lines
    start = lines.index(heading)
    end = next((i for i in range(start + 1, len(lines)) if lines[i].startswith("## ")), len(lines))
    return lines[:start] + lines[end:]


def test_the_readme_fits_its_budget_and_holds_what_the_issue_asks() -> None:
    lines = _readme_lines_outside_table1()
    assert len(lines) <= README_MAX_LINES, f"README.md has {len(lines)} lines; move the rest to the docs site"
    text = "\n".join(lines)
    for needed in ["make bench", "make test", "```python", "## Citing", "CITATION.cff", "docs/index.md"]:
        assert needed in text, needed
    example = re.search(r"```python\n(.*?)```", text, re.S).group(1).strip().splitlines()
    assert len(example) <= 10, f"the README's Python example has {len(example)} lines"


def test_the_readme_links_point_at_files_pages_and_headings_that_exist(site: Path) -> None:
    links = re.findall(r"\]\(([^)\s]+)\)", README.read_text())
    local = [link for link in links if not re.match(r"[a-z]+://", link)]
    assert any(link.startswith("docs/") for link in local), "the README links into the site"
    for link in local:
        path, _, anchor = link.partition("#")
        assert (REPO / path).exists(), f"README.md links to {link}, which does not exist"
        if anchor and path.startswith("docs/") and path.endswith(".md"):
            html = _page_html(site, path.removeprefix("docs/"))
            assert anchor in _ids(html), f"README.md links to {link}, but the page has no heading #{anchor}"
