"""A new built-in model is the files docs/contribute.md lists, and nothing else (issue 50's done-means test).

The test copies the project (the package, the tools, the docs, the pages the generators write and the tests the zoo
runs on every model) into a temporary folder and plants a built-in model there by writing only the files that
docs/contribute.md's "A built-in model" section lists. It then runs the generators that page names, their ``--check``,
and the zoo's tests on the planted model, and checks that the model appears in every generated page and count.
"""

from __future__ import annotations

import os
import re
import shutil
import sys
from pathlib import Path

import pytest
from forked_bench import finish_python, package_from

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from tools.model_pages import BLOCKS, count_word, markers, zoo_models  # noqa: E402

NAME, DISPLAY = "planted_mlp", "Planted-MLP"
#: what the copy needs: the package, the tools, every page a generator writes, the tests run on the planted model
COPIED = ["tactile_zoo", "tools", "docs", "tests/conftest.py", "tests/models/test_zoo.py",
          "tests/models/test_recipe_files.py", "tests/models/fixtures", "tests/revisions", "CITATION.cff",
          "README.md", "CHANGELOG.md", "pyproject.toml", "mkdocs.yml"]

MODEL = f'''"""A planted model: every frame's taxels and globals through one layer, averaged over time.

Card: a test's planted model, no source to be faithful to; every size is ours.
"""

from __future__ import annotations

import torch
from torch import nn

from ..registry import recipe_file, register_model


@register_model(
    "{NAME}",
    paper="A Planted Model for the Zoo's Own Tests",
    citation="The tactile-zoo developers. A Planted Model for the Zoo's Own Tests, 2026",
    year=2026,
    url="https://example.org/planted",
    description="Per-frame linear layer on the taxels and the globals, tanh, mean over time, linear classifier.",
    tags=["example"],
    inputs=["globals"],
    display_name="{DISPLAY}",
    family="per-frame MLP, mean over time",
    reference={{"type": "article", "authors": ["Planter, Ada", "Grower, Ben"], "journal": "Journal of Tests"}},
    **recipe_file("tactile_zoo", "{NAME}"),
    causal=True,
    streaming=False,
    revision=1,
)
class PlantedMLP(nn.Module):
    """Planted MLP: fidelity and departures: none, it has no source (the card of a test's model).

    Args:
        spec: the dataset's :class:`DatasetSpec`.
        hidden: width of the per-frame layer.
    """

    def __init__(self, spec, hidden: int = 16) -> None:
        super().__init__()
        self.spec = spec
        self.body = nn.Linear(spec.num_nodes * spec.num_channels + spec.num_globals, hidden)
        self.head = nn.Linear(hidden, spec.num_classes)

    def forward(self, x: torch.Tensor, g: torch.Tensor | None = None) -> torch.Tensor:
        frames = x.flatten(2)
        if g is not None and g.shape[-1]:
            frames = torch.cat([frames, g], -1)
        elif self.spec.num_globals:
            frames = torch.cat([frames, frames.new_zeros(*frames.shape[:2], self.spec.num_globals)], -1)
        return self.head(torch.tanh(self.body(frames)).mean(1))
'''
RECIPE = """# the planted model's recipe (tests/test_new_model.py)
default: zoo
recipes:
  zoo:
    loss: ce
    optimizer: adam
    lr: 1e-3
    max_epochs: 5
    patience: null
    batch_size: 16
"""
TEST = f'''import tactile_zoo as tz
from tactile_zoo.testing import random_batch, tiny_spec


def test_{NAME}_scores_every_class() -> None:
    spec = tiny_spec("neutouch")
    x, g, _ = random_batch(spec, 3, seed=0)
    assert tz.create_model("{NAME}", spec)(x, g).shape == (3, spec.num_classes)
'''


def listed_files() -> list[str]:
    """The first path each numbered item of docs/contribute.md's "A built-in model" section names."""
    text = (REPO / "docs" / "contribute.md").read_text().split("## A built-in model\n", 1)[1].split("\n## ", 1)[0]
    items = re.findall(r"^\d+\. (.*?)(?=^\d+\. |^\S|\Z)", text, flags=re.S | re.M)
    return [re.search(r"`([^`]+\.[a-z]+)`", item).group(1) for item in items]


def test_contribute_lists_at_most_five_files() -> None:
    files = listed_files()
    assert len(files) <= 5 and "CHANGELOG.md" in files and "tactile_zoo/models/NAME.py" in files, files


def _copy(dest: Path) -> None:
    for rel in COPIED:
        src, out = REPO / rel, dest / rel
        out.parent.mkdir(parents=True, exist_ok=True)
        if src.is_dir():
            shutil.copytree(src, out, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
        else:
            shutil.copy2(src, out)
    (dest / "benchmarks").symlink_to(REPO / "benchmarks")  # the committed cells the ledger reads; read only


def _plant(dest: Path) -> list[str]:
    """Write the planted model's files: exactly the ones docs/contribute.md lists."""
    contents = {f"tactile_zoo/models/{NAME}.py": MODEL, f"tactile_zoo/recipes/{NAME}.yaml": RECIPE,
                f"tests/models/test_{NAME}.py": TEST}
    changelog = (dest / "CHANGELOG.md").read_text()
    contents["CHANGELOG.md"] = changelog.replace("### Added\n", f"### Added\n- `{NAME}`: a planted model.\n", 1)
    listed = {f.replace("NAME", NAME) for f in listed_files()}
    assert set(contents) <= listed, f"the test writes {sorted(set(contents) - listed)}, which contribute.md omits"
    for rel, text in contents.items():
        (dest / rel).write_text(text)
    return sorted(contents)


def _run(dest: Path, source: str, timeout: float = 240) -> None:
    """``python -c SOURCE`` in the copy, forked from the warm server of tests/forked_bench.py (torch and sklearn
    imported once per test process) and importing the copy's package and tools in place of the checkout's."""
    env = {**os.environ, "PYTHONPATH": str(dest), "OMP_NUM_THREADS": "1", "TACTILE_ZOO_NO_PLUGINS": "1"}
    code, out, err = finish_python(package_from(dest) + source, [], dest.parent / "child", timeout, **env)
    assert code == 0, f"{source}:\n{out[-4000:]}\n{err[-4000:]}"


#: the zoo's tests run on the planted model (``-k NAME``)
ZOO_TESTS = ["tests/models/test_zoo.py", "tests/models/test_recipe_files.py", "tests/revisions/test_revisions.py",
             f"tests/models/test_{NAME}.py"]
#: in one child (one import of the copy's package): the generators write, then their --check passes, then the zoo's
#: tests on the planted model, as the suite runs them
GENERATE_AND_TEST = f"""
import sys
from tools import fidelity, model_pages
sys.path.insert(0, "tests/revisions")
import regenerate
for check in (False, True):
    flag = ["--check"] if check else []
    assert model_pages.main(flag) == 0, "model_pages"
    assert fidelity.main(flag) == 0, "fidelity"
    assert regenerate.main([*flag, "--model", "{NAME}"]) == 0, "regenerate"
import pytest
sys.exit(pytest.main(["-q", "-p", "no:cacheprovider", "-k", "{NAME}", *{ZOO_TESTS!r}]))
"""


@pytest.mark.slow
def test_a_planted_model_needs_only_the_listed_files(tmp_path: Path) -> None:
    dest = tmp_path / "project"
    _copy(dest)
    _plant(dest)
    _run(dest, GENERATE_AND_TEST)
    count = count_word(len(zoo_models()) + 1)
    for rel, blocks in BLOCKS.items():
        text = (dest / rel).read_text()
        for what, comment, _ in blocks:
            begin, end = markers(what, comment)
            block = text.split(begin, 1)[1].split(end, 1)[0]
            assert DISPLAY in block or NAME in block or "Planter" in block, f"{rel}: block {what!r} lacks the model"
            if what == "model count":
                assert f"{count} models" in block, f"{rel}: the count is not {count}"
    assert f"| {DISPLAY} |" in (dest / "docs" / "fidelity.md").read_text()
    assert f"::: tactile_zoo.models.{NAME}" in (dest / "docs" / "api" / "registry.md").read_text()
    assert "title: \"A Planted Model for the Zoo's Own Tests\"" in (dest / "CITATION.cff").read_text()
    stored = (dest / "tests" / "revisions" / "expected_outputs.json").read_text()
    assert f'"{NAME}"' in stored and f'"{NAME}"' in (dest / "tests/models/fixtures/registered_recipes.json").read_text()
