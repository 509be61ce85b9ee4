"""The pages that list the zoo's models, generated from the registry: the one source of a model's facts.

    python -m tools.model_pages            # rewrite every generated block
    python -m tools.model_pages --check    # exit 1, naming each stale file, if a block is not what the registry gives

Each built-in model's ``@register_model(...)`` metadata (``display_name``, ``family``, ``paper``, ``year``, ``url``,
``reference``, ``tags``: ``table1`` marks the X-Tacformer paper's Table I models) writes, between generated markers:

- ``docs/models.md``: the models table and the parameters per dataset;
- ``docs/citing.md``: the models' papers, and their BibTeX;
- ``CITATION.cff``: the models' ``references`` (the datasets' and methods' entries after them are hand-written);
- ``docs/api/registry.md``: one ``:::`` section per model module;
- ``README.md``, ``docs/index.md``, ``docs/pypi.md``: the sentence that counts and names the models.

Parameter counts are computed, not typed: each model is built on each built-in dataset's spec as its registry
metadata gives it (``tactile_zoo.export.spec_for_dataset``: the dataset's default keywords, no data read), with the
constructor keywords its default recipe sets for that dataset. A model that does not take a dataset's input
(``ConfigError``) shows ``-`` there.
"""

from __future__ import annotations

import argparse
import functools
import json
import sys
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import tactile_zoo
from tactile_zoo import registry
from tactile_zoo._files import replace_block, stale_files, update_pages
from tactile_zoo.engine.config import resolve_model_recipe
from tactile_zoo.errors import ConfigError
from tactile_zoo.export import spec_for_dataset

REPO = Path(__file__).resolve().parents[1]
COMMAND = "python -m tools.model_pages"
NUMBER_WORDS = ("no", "one", "two", "three", "four", "five", "six", "seven", "eight", "nine", "ten", "eleven",
                "twelve", "thirteen", "fourteen", "fifteen", "sixteen", "seventeen", "eighteen", "nineteen", "twenty")


def markers(what: str, comment: str = "html") -> tuple[str, str]:
    """The begin and end lines of the generated block ``what`` (``comment="yaml"``: YAML comments)."""
    if comment == "yaml":
        return f"# {what}: begin ({COMMAND})", f"# {what}: end"
    return f"<!-- {what}: begin ({COMMAND}) -->", f"<!-- {what}: end -->"


# ----------------------------------------------------------------------------------------------- the models
def zoo_models() -> list[str]:
    """The built-in models (defined in ``tactile_zoo.models``): Table I's first, then the others, each by name."""
    names = [n for n in tactile_zoo.list_models()
             if str(getattr(registry.get_model_entry(n).obj, "__module__", "")).startswith("tactile_zoo.models.")]
    return sorted(names, key=lambda n: ("table1" not in meta(n).get("tags", ()), n))


def meta(name: str) -> Mapping[str, Any]:
    return registry.get_model_entry(name).meta


def display(name: str) -> str:
    """A model's display name (its registry name where the metadata gives none)."""
    return str(meta(name).get("display_name") or name)


def count_word(n: int) -> str:
    return NUMBER_WORDS[n] if n < len(NUMBER_WORDS) else str(n)


def join(items: list[str]) -> str:
    """``a``, ``a and b``, ``a, b and c``."""
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " and " + items[-1] if items else ""


def _family_names(ref: Mapping[str, Any]) -> list[str]:
    names = []
    for author in ref.get("authors", ()):
        if isinstance(author, Mapping):
            names.append(str(author.get("family-names") or author.get("name")))
        else:
            names.append(str(author).split(",")[0].strip())
    return names


def short_authors(ref: Mapping[str, Any]) -> str:
    """``Gu, Sng, Taunyazov and Soh``; five authors or more: ``Zhu et al.``."""
    names = _family_names(ref)
    return f"{names[0]} et al." if len(names) > 4 else join(names)


def venue(ref: Mapping[str, Any]) -> str:
    conference = ref.get("conference")
    return str(ref.get("journal") or ref.get("collection-title") or
               (conference.get("name") if isinstance(conference, Mapping) else conference) or "")


def papers() -> list[tuple[dict[str, Any], list[str]]]:
    """(reference, its models) per cited paper, in model order: a model's ``reference`` metadata with its ``paper``
    as title (unless the reference names one), its ``year`` and ``url``; models citing one title share an entry."""
    out: dict[str, tuple[dict[str, Any], list[str]]] = {}
    for name in zoo_models():
        m = meta(name)
        if "reference" not in m:
            continue
        ref = {"title": m.get("paper", name), **({"year": m["year"]} if "year" in m else {}),
               **({"url": m["url"]} if "url" in m else {}), **dict(m["reference"])}
        ref_, models = out.setdefault(ref["title"], (ref, []))
        models.append(name)
        notes = [n for n in (ref_.get("notes"), ref.get("notes")) if n]
        if notes:
            ref_["notes"] = "; ".join(dict.fromkeys(notes))
    return list(out.values())


def models_phrase(models: list[str]) -> str:
    return f"the {join([display(m) for m in models])} model{'s' if len(models) > 1 else ''}"


# ----------------------------------------------------------------------------------------------- parameters
def _format_count(n: int) -> str:
    """3 significant figures: ``362 k``, ``1.95 M``, ``39.5 k``."""
    for scale, unit in ((1e6, "M"), (1e3, "k")):
        if n >= scale:
            return f"{n / scale:.3g} {unit}"
    return str(n)


@functools.cache  # a --check after writing, in one process, builds each model once
def parameter_count(model: str, dataset: str) -> int | None:
    """Parameters of ``model`` built on ``dataset``'s registered spec with its default recipe's keywords for it;
    ``None`` when the model does not take that input."""
    spec = spec_for_dataset(dataset)
    hparams = resolve_model_recipe(meta(model), None, dataset, owner=model).hparams
    try:
        built = registry.instantiate_model(model, spec, **hparams)
    except ConfigError:
        return None
    return sum(p.numel() for p in built.parameters())


#: what a dataset's metadata must give for its spec to be built without data
SPEC_KEYS = ("sensor", "num_classes", "class_names", "num_steps", "num_nodes", "num_channels", "num_globals")


def datasets() -> list[str]:
    """The built-in datasets whose registry metadata gives the whole spec (no data is read), real ones first (the
    papers'), then the simulators. A dataset whose metadata leaves its spec to the data (ALU-Textures: its class
    names are the recordings' folders) has no column."""
    names = [n for n in tactile_zoo.list_datasets() if registry.get_dataset_entry(n).dist is None
             and str(getattr(registry.get_dataset_entry(n).obj, "__module__", "")).startswith("tactile_zoo.")
             and all(registry.get_dataset_entry(n).meta.get(k) is not None for k in SPEC_KEYS)]
    return sorted(names, key=lambda n: (bool(registry.get_dataset_entry(n).meta.get("simulated")), n))


# ----------------------------------------------------------------------------------------------- the blocks
def _anchor(heading: str) -> str:
    """The id Python-Markdown's ``toc`` gives a heading (lower case, punctuation dropped, spaces to hyphens)."""
    text = "".join(c for c in heading.lower().replace("`", "") if c.isalnum() or c in " -_")
    return "-".join(text.split())


def card_link(name: str, models_page: str) -> str:
    """The model card: a ``## `name` ...`` section of docs/models.md, else the model's docstring in the API page."""
    for line in models_page.splitlines():
        if line.startswith(f"## `{name}`"):
            return f"[card](#{_anchor(line[3:])})"
    module = registry.get_model_entry(name).obj.__module__
    return f"[docstring](api/registry.md#{module})"


def models_table(models_page: str) -> str:
    rows = ["| model | name | family | causal / streaming | source | card |", "| --- | --- | --- | --- | --- | --- |"]
    for name in zoo_models():
        m = meta(name)
        ref = m.get("reference")
        source = f"{short_authors(ref)} {m.get('year', '')}".strip() if ref else str(m.get("paper", "-"))
        yes = {True: "yes", False: "no"}
        rows.append(f"| `{name}` | {display(name)} | {m.get('family', '-')} | {yes[bool(m.get('causal'))]} / "
                    f"{yes[bool(m.get('streaming'))]} | {source} | {card_link(name, models_page)} |")
    sets = datasets()
    rows += ["", _wrap("Parameters per dataset, computed by `python -m tools.model_pages`: each model built on the "
                       "dataset's registered spec (its registry metadata with the default dataset keywords; no data "
                       "is read; a dataset whose metadata leaves the spec to its data has no column) with the "
                       "constructor keywords its default recipe sets for that dataset; `-`: the model does not "
                       "take that input.", "", ""),
             "", "| model | " + " | ".join(f"`{d}`" for d in sets) + " |", "| --- |" + " ---: |" * len(sets)]
    for name in zoo_models():
        counts = [parameter_count(name, d) for d in sets]
        rows.append(f"| `{name}` | " + " | ".join("-" if c is None else _format_count(c) for c in counts) + " |")
    return "\n".join(rows + ["", *revisions_table()])


def revisions_table() -> list[str]:
    """Each model's revisions (registry metadata ``revision`` and ``revisions``): the default, and what every revision
    it still builds sets its compute keywords to (see docs/revisions.md)."""
    rows = [_wrap("Revisions, from the registry: a cell records the revision that trained it, and "
                  "`create_model(name, spec, revision=N)` or `--model-revision NAME=N` builds any revision listed "
                  "([Revisions](revisions.md)); the default is in bold, and each revision's compute keywords are "
                  "what its constructor defaults to.", "", ""),
            "", "| model | revisions | compute keywords of each |", "| --- | --- | --- |"]
    for name in zoo_models():
        entry = registry.get_model_entry(name)
        known, default = registry.model_revisions(entry), registry.revision_of(entry)
        numbers = ", ".join(f"**{n}**" if n == default else str(n) for n in known)
        paths = "; ".join(f"{n}: " + (", ".join(f"`{k}={v}`" for k, v in path.items()) or "-")
                          for n, path in known.items())
        rows.append(f"| `{name}` | {numbers} | {paths if any(known.values()) else '-'} |")
    return rows


def citing_list() -> str:
    lines = []
    for ref, models in papers():
        where = ", ".join(str(x) for x in (venue(ref), ref.get("year")) if x)
        notes = f"; {ref['notes']}" if ref.get("notes") else ""
        lines.append(_wrap(f"{short_authors(ref)}, *{ref['title']}*{f' ({where})' if where else ''}: "
                           f"{models_phrase(models)}{notes}.", "- ", "  "))
    cited = {m for _, models in papers() for m in models}
    for name in (n for n in zoo_models() if n not in cited):
        cite = str(meta(name).get("citation") or meta(name).get("paper", "-")).rstrip(".")
        lines.append(_wrap(f"{display(name)} (`{name}`), no paper of its own: {cite}.", "- ", "  "))
    return "\n".join(lines) + "\n\n```bibtex\n" + "\n\n".join(bibtex(ref) for ref, _ in papers()) + "\n```"


def bibtex(ref: Mapping[str, Any]) -> str:
    kind = "inproceedings" if ref.get("type") == "conference-paper" else "article"
    names = []
    for author in ref.get("authors", ()):
        names.append("{" + str(author["name"]) + "}" if isinstance(author, Mapping) and "name" in author
                     else str(author))
    first = "".join(c for c in _family_names(ref)[0].lower() if c.isalpha()) if names else "anon"
    word = "".join(c for c in ref["title"].split()[0].lower() if c.isalnum())
    fields = {"title": "{" + ref["title"] + "}", "author": " and ".join(names),
              ("booktitle" if kind == "inproceedings" else "journal"): venue(ref), "year": ref.get("year"),
              "volume": ref.get("volume"), "number": ref.get("issue"), "doi": ref.get("doi"), "url": ref.get("url")}
    body = ",\n".join(f"  {k:<9} = {{{v}}}" for k, v in fields.items() if v not in (None, ""))
    return f"@{kind}{{{first}{ref.get('year', '')}{word},\n{body}\n}}"


def _yaml(value: Any) -> str:
    return str(value) if isinstance(value, int) else json.dumps(str(value), ensure_ascii=False)


def cff_references() -> str:
    """The models' papers as CITATION.cff ``references`` entries (two-space list items under ``references:``)."""
    out = []
    for ref, models in papers():
        lines = [f"  - type: {ref.get('type', 'article')}", f"    title: {_yaml(ref['title'])}", "    authors:"]
        for author in ref.get("authors", ()):
            if isinstance(author, Mapping):
                keys = list(author.items())
            else:
                family, _, given = str(author).partition(",")
                keys = [("family-names", family.strip())] + ([("given-names", given.strip())] if given else [])
            lines += [f"      {'-' if i == 0 else ' '} {k}: {_yaml(v)}" for i, (k, v) in enumerate(keys)]
        for key, value in ref.items():
            if key in ("type", "title", "authors", "notes", "url"):
                continue
            if isinstance(value, Mapping):
                lines += [f"    {key}:"] + [f"      {k}: {_yaml(v)}" for k, v in value.items()]
            else:
                lines.append(f"    {key}: {_yaml(value)}")
        if ref.get("url"):
            lines.append(f"    url: {_yaml(ref['url'])}")
        notes = models_phrase(models) + (f"; {ref['notes']}" if ref.get("notes") else "")
        lines.append(f"    notes: {_yaml(notes[0].upper() + notes[1:] + '.')}")
        out.append("\n".join(lines))
    return "\n".join(out)


def api_sections() -> str:
    modules = dict.fromkeys(registry.get_model_entry(n).obj.__module__ for n in zoo_models())
    return "\n\n".join(f"::: {m}" for m in modules)


def _wrap(text: str, first: str, rest: str, width: int = 118) -> str:
    lines, line = [], first
    for word in text.split():
        if len(line) + 1 + len(word) > width and line.strip() not in ("", first.strip()):
            lines.append(line)
            line = rest + word
        else:
            line = f"{line}{'' if line in (first, rest) else ' '}{word}"
    return "\n".join(lines + [line])


def model_names_phrase() -> str:
    """``SGnet, ... and X-Tacformer (the paper's Table I), DeepTactile and multi-barrel SNN``."""
    models = zoo_models()
    table1 = [display(m) for m in models if "table1" in meta(m).get("tags", ())]
    others = [display(m) for m in models if "table1" not in meta(m).get("tags", ())]
    return join(([f"{join(table1)} (the paper's Table I)"] if table1 else []) + others)


def models_sentence() -> str:
    """``eight models: SGnet, ... and X-Tacformer (the paper's Table I), DeepTactile and multi-barrel SNN``."""
    return f"{count_word(len(zoo_models()))} models: {model_names_phrase()}"


def readme_item() -> str:
    return _wrap(f"**{models_sentence().replace(' models:', ' models**:', 1)}, built from PyTorch Geometric graph "
                 f"layers and snnTorch LIF neurons, each with a model card and an entry in the fidelity ledger;",
                 "- ", "  ")


def index_item() -> str:
    return _wrap(f"{models_sentence()}, built from PyTorch Geometric graph layers and snnTorch LIF neurons "
                 f"([Models](models.md));", "- ", "  ")


def pypi_paragraph() -> str:
    return _wrap(f"A model zoo and benchmark harness for tactile object recognition from sensor arrays, in PyTorch: "
                 f"{count_word(len(zoo_models()))} models ({model_names_phrase()}) built from PyTorch Geometric graph "
                 f"layers and snnTorch LIF neurons; loaders "
                 f"for the public datasets (Ev-Objects, Ev-Containers, BioTac-DoS, Augment8000) and your own "
                 f"recordings, simulated datasets for working offline, and `tactile-zoo bench`, which crosses every "
                 f"model with every dataset into a resumable leaderboard.", "", "")


def readme_citing() -> str:
    by_paper = [f"{short_authors(ref)} ({join([display(m) for m in models])})" for ref, models in papers()]
    return _wrap(f"`CITATION.cff` says how to cite tactile-zoo. Please also cite the papers whose models and datasets "
                 f"you use: the models' ({'; '.join(by_paper)}), and the datasets' and methods' (the NeuTouch "
                 f"recordings, Um et al.'s augmentations); [Citing](docs/citing.md) lists them.", "", "")


#: file -> [(block name, comment style, body)]; a body is computed from the page's current text. Blank lines around
#: a table or a ``:::`` section: Markdown starts them only at the top of a block
BLOCKS: dict[str, list[tuple[str, str, Callable[[str], str]]]] = {
    "docs/models.md": [("models table", "html", lambda text: f"\n{models_table(text)}\n")],
    "docs/citing.md": [("model papers", "html", lambda _: f"\n{citing_list()}\n")],
    "CITATION.cff": [("model references", "yaml", lambda _: cff_references())],
    "docs/api/registry.md": [("model modules", "html", lambda _: f"\n{api_sections()}\n")],
    "README.md": [("model count", "html", lambda _: readme_item()),
                  ("model citing", "html", lambda _: readme_citing())],
    "docs/index.md": [("model count", "html", lambda _: index_item())],
    "docs/pypi.md": [("model count", "html", lambda _: pypi_paragraph())],
}


def render(path: str, text: str, root: Path = REPO) -> str:
    for what, comment, body in BLOCKS[path]:
        begin, end = markers(what, comment)
        text = replace_block(text, begin, end, body(text), root / path, error=SystemExit)
    return text


def run(root: Path | None = None, check: bool = False) -> list[Path]:
    """Write every generated block under ``root`` (default: this checkout; ``check``: write nothing); the files that
    were (or are) stale."""
    root = REPO if root is None else root
    return stale_files(pages(root), write=not check)


def pages(root: Path | None = None) -> dict[Path, str]:
    """Every page with a generated block under ``root`` (default: this checkout), as the registry gives it."""
    root = REPO if root is None else root
    return {root / rel: render(rel, (root / rel).read_text(encoding="utf-8"), root) for rel in BLOCKS}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog=COMMAND, description=__doc__.split("\n")[0])
    parser.add_argument("--check", action="store_true", help="exit 1, naming each stale file, if a page is out of date")
    args = parser.parse_args(argv)
    return update_pages(pages(REPO), args.check, COMMAND, root=REPO)


if __name__ == "__main__":
    sys.exit(main())
