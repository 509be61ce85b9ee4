"""The model pages are what the registry gives (``python -m tools.model_pages`` rewrites them), and the metadata
they read is checked when a model registers."""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from tactile_zoo import registry  # noqa: E402
from tactile_zoo.errors import ConfigError  # noqa: E402
from tools import model_pages  # noqa: E402


def test_the_model_pages_are_regenerated_from_the_registry(capsys: pytest.CaptureFixture[str]) -> None:
    assert model_pages.main(["--check"]) == 0, capsys.readouterr().err


def test_a_stale_page_fails_the_check_naming_the_file(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    for rel in model_pages.BLOCKS:
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(REPO / rel, tmp_path / rel)
    pypi = tmp_path / "docs" / "pypi.md"
    pypi.write_text(pypi.read_text().replace(f"{model_pages.count_word(len(model_pages.zoo_models()))} models",
                                             "seven models", 1))
    monkeypatch.setattr(model_pages, "REPO", tmp_path)
    assert model_pages.run(tmp_path, check=True) == [pypi]
    assert model_pages.main(["--check"]) == 1
    assert "docs/pypi.md is out of date: run python -m tools.model_pages" in capsys.readouterr().err
    assert model_pages.run(tmp_path) == [pypi] and model_pages.run(tmp_path, check=True) == []


def test_every_count_names_every_model() -> None:
    count = f"{model_pages.count_word(len(model_pages.zoo_models()))} models"
    for rel in ("README.md", "docs/index.md", "docs/pypi.md"):
        block = (REPO / rel).read_text().split(model_pages.markers("model count")[0], 1)[1]
        block = block.split(model_pages.markers("model count")[1], 1)[0]
        assert count in " ".join(block.split()), rel
        for name in model_pages.zoo_models():
            assert model_pages.display(name) in " ".join(block.split()), (rel, name)


def test_parameter_counts_are_computed_per_dataset() -> None:
    """Ev-Objects with the default recipe: the figures the model cards quote (ConvLSTM with the taxel read-out)."""
    assert model_pages._format_count(model_pages.parameter_count("sgnet", "ev_objects")) == "362 k"
    assert model_pages._format_count(model_pages.parameter_count("convlstm", "ev_objects")) == "39.5 k"
    assert model_pages._format_count(1_950_000) == "1.95 M" and model_pages._format_count(999) == "999"


@pytest.mark.parametrize(("meta", "key"), [({"display_name": ""}, "display_name"), ({"family": 3}, "family"),
                                           ({"reference": ["a"]}, "reference"),
                                           ({"test_hparams": {1: 2}}, "test_hparams")])
def test_bad_page_metadata_is_refused_at_registration(meta: dict[str, object], key: str) -> None:
    class Model:
        pass

    with pytest.raises(ConfigError, match=f"metadata '{key}'"):
        registry.register_model("zt_pages_bad", **meta)(Model)
    assert registry._unregister("model", "zt_pages_bad") is None


def test_page_metadata_is_optional_for_a_plugin() -> None:
    class Model:
        pass

    try:
        registry.register_model("zt_pages_plain", paper="-")(Model)
        assert "display_name" not in registry.get_model_entry("zt_pages_plain").meta
    finally:
        registry._unregister("model", "zt_pages_plain")
