"""Remaking saved weights from cell records (``tactile_zoo.bench.rebuild``, ``tactile-zoo rebuild-weights``): the
same bytes as the run that computed the cell, never a test split read, and nothing kept that is not the recorded
file."""

from __future__ import annotations

import gzip
import json
import shutil
from pathlib import Path

import pytest
import tiny_zoo
import torch

from tactile_zoo import registry
from tactile_zoo.bench.config import BenchConfig
from tactile_zoo.bench.rebuild import rebuild_weights, weight_cells
from tactile_zoo.bench.runner import run_bench
from tactile_zoo.cli import main
from tactile_zoo.data.base import file_sha256
from tactile_zoo.engine.cell import train_cell
from tactile_zoo.engine.config import CellConfig
from tactile_zoo.errors import ConfigError

GRID = {"models": ["tiny_mlp"], "datasets": ["tiny_kfold"], "folds": 1, "threads": 1, "evaluation": "final",
        "recipe": {"max_epochs": 2}, "plugin_modules": ["tiny_zoo"]}


@pytest.fixture(scope="module")
def saved(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("rebuild") / "run"
    tiny_zoo.register()
    # run in this process: the rebuilds, each in a spawned worker, must still come out byte for byte
    outcome = run_bench(BenchConfig(**GRID, seeds=[0, 1], save_weights=True, out=str(out)), quiet=True, plots=False)
    assert outcome.exit_code == 0 and len(outcome.ran) == 2
    return out


def _copy(saved: Path, tmp_path: Path) -> Path:
    folder = tmp_path / "run"
    shutil.copytree(saved, folder)
    return folder


def _weights(folder: Path) -> dict[str, Path]:
    return {p.name.split("__")[3]: p for p in (folder / "weights").glob("*.safetensors")}


def test_train_cell_without_the_test_split_trains_the_same_model_and_never_loads_it(monkeypatch) -> None:
    tiny_zoo.register()
    config = CellConfig.from_dict({"model": "tiny_mlp", "dataset": "tiny_kfold", "evaluation": "final",
                                   "recipe": {"max_epochs": 2}})
    full = train_cell(config, seed=3, measure=False)
    loaded: list[str] = []
    real = registry.load_dataset

    def spy(name, *args, split="train", **kwargs):
        loaded.append(split)
        if split == "test":
            raise AssertionError("the test split was loaded")
        return real(name, *args, split=split, **kwargs)

    monkeypatch.setattr(registry, "load_dataset", spy)
    from tactile_zoo.engine import build

    build._SPLIT_CACHE.clear()  # the first call cached the splits; the second must ask for its own
    blind = train_cell(config, seed=3, measure=False, read_test=False)
    assert "test" not in loaded and {"train", "val"} <= set(loaded)
    assert blind.tests == {} and blind.test_reads == 0 and blind.n_test == 0 and full.test_reads == 1
    a, b = full.fit.model.state_dict(), blind.fit.model.state_dict()
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


def test_a_reference_cell_cannot_be_trained_blind() -> None:
    tiny_zoo.register()
    config = CellConfig.from_dict({"model": "tiny_mlp", "dataset": "tiny_kfold", "evaluation": "reference",
                                   "recipe": {"max_epochs": 1}})
    with pytest.raises(ConfigError, match="reference cell reads the test split after every epoch"):
        train_cell(config, read_test=False)


def test_missing_weights_are_remade_byte_for_byte(saved: Path, tmp_path: Path) -> None:
    folder = _copy(saved, tmp_path)
    before = {seed: file_sha256(p) for seed, p in _weights(folder).items()}
    _weights(folder)["s0"].unlink()
    outcomes = rebuild_weights(folder, root=None, workers=2, plugin_modules=["tiny_zoo"])
    assert [(o.cell_id.split("__")[3], o.status) for o in outcomes] == [("s0", "rebuilt"), ("s1", "present")]
    assert {seed: file_sha256(p) for seed, p in _weights(folder).items()} == before
    assert not list((folder / "weights").glob(".*"))  # no temporary left


def test_weights_that_come_out_different_are_not_kept(saved: Path, tmp_path: Path) -> None:
    folder = _copy(saved, tmp_path)
    (path,) = (folder / "cells").glob("*__s1__*")
    record = json.loads(gzip.decompress(path.read_bytes()) if path.suffix == ".gz" else path.read_bytes())
    record["weights"]["sha256"] = "0" * 64  # as if another CPU type had trained the recorded file
    path.unlink()
    (folder / "cells" / f"{record['cell_id']}.json").write_text(json.dumps(record))
    _weights(folder)["s1"].unlink()
    (outcome,) = rebuild_weights(folder, ["*__s1__*"], plugin_modules=["tiny_zoo"])
    assert outcome.status == "differs" and outcome.sha256 != "0" * 64
    assert "s1" not in _weights(folder) and not list((folder / "weights").glob(".*"))


def test_an_altered_file_is_replaced_by_the_recorded_one(saved: Path, tmp_path: Path) -> None:
    folder = _copy(saved, tmp_path)
    path = _weights(folder)["s1"]
    recorded = file_sha256(path)
    data = bytearray(path.read_bytes())
    data[-1] ^= 1
    path.write_bytes(bytes(data))
    (outcome,) = rebuild_weights(folder, ["*__s1__*"], plugin_modules=["tiny_zoo"])
    assert outcome.status == "rebuilt" and file_sha256(path) == recorded


def test_bad_selections_are_refused_before_any_work(saved: Path, tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"--cell 'nothing\*': no cell of .* matches it"):
        weight_cells(saved, ["nothing*"])
    with pytest.raises(ConfigError, match="no finished cell records"):
        weight_cells(tmp_path)
    with pytest.raises(ConfigError, match="workers: 0"):
        rebuild_weights(saved, workers=0)


def test_the_command_lists_rebuilds_and_fails_on_a_difference(saved: Path, tmp_path: Path, capsys) -> None:
    folder = _copy(saved, tmp_path)
    assert main(["rebuild-weights", str(folder), "--dry-run"]) == 0
    assert capsys.readouterr().out.count(".safetensors") == 2
    _weights(folder)["s0"].unlink()
    assert main(["rebuild-weights", str(folder), "--cell", "*__s0__*", "--plugin-module", "tiny_zoo"]) == 0
    out = capsys.readouterr().out
    assert "rebuilt tiny_mlp__tiny_kfold__f0__s0__" in out and "1 cell(s): 0 already there, 1 rebuilt, 0 differ" in out


def test_the_command_warns_before_work_when_the_cells_ran_on_another_cpu(saved: Path, tmp_path: Path,
                                                                         capsys) -> None:
    folder = _copy(saved, tmp_path)
    (path,) = (folder / "cells").glob("*__s1__*")
    record = json.loads(gzip.decompress(path.read_bytes()) if path.suffix == ".gz" else path.read_bytes())
    record["cpu"] = "Imaginary CPU 9000"
    path.unlink()
    (folder / "cells" / f"{record['cell_id']}.json").write_text(json.dumps(record))
    assert main(["rebuild-weights", str(folder), "--dry-run"]) == 0
    err = capsys.readouterr().err
    assert err.count("will probably not reproduce") == 1 and "__s1__" in err and "Imaginary CPU 9000" in err
