"""Weights the tests make themselves: a small CNN-LSTM trained for two epochs on a small ``sim_uskin_textures`` (60
taxels x 3 channels + 8 globals, so the column order of a recording file matters) through the harness's own cell
(:func:`tactile_zoo.bench.worker.run_cell` with a weights folder, which calls ``save_weights``), then described by a
manifest built from the cell record."""

from __future__ import annotations

import copy
import dataclasses
import json
from pathlib import Path
from typing import Any

import pytest
import torch
from weights_helpers import CELL_ID, CONFIG_HASH, DATA_ARGS, DATASET, HPARAMS, MODEL, Trained

import tactile_zoo as tz
from tactile_zoo.bench import worker as bench_cell
from tactile_zoo.engine.config import resolve_cell
from tactile_zoo.engine.evaluate import predict_scores
from tactile_zoo.weights import entry_from_record, make_tag, write_manifest


@pytest.fixture(scope="session")
def trained(tmp_path_factory: pytest.TempPathFactory) -> Trained:
    run = tmp_path_factory.mktemp("run")
    captured: dict[str, torch.nn.Module] = {}
    real = bench_cell.save_weights

    def keep(model: torch.nn.Module, path: Path, metadata: dict[str, str]) -> dict[str, Any]:
        captured["model"] = copy.deepcopy(model)  # the very model the cell saves
        return real(model, path, metadata)

    cell = resolve_cell(MODEL, DATASET, hparams=HPARAMS, epochs=2, dataset_kwargs=DATA_ARGS, prefixes=(1.0,))
    task = bench_cell.CellTask(MODEL, DATASET, 0, 0, CONFIG_HASH, CELL_ID, cell, device="cpu", threads=1,
                               weights_dir=str(run / "weights"), commit="0123abc")
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(bench_cell, "save_weights", keep)
        record = json.loads(json.dumps(bench_cell.run_cell(task)))  # as read back from cells/<id>.json
    assert record["status"] == "ok", record.get("error")
    honest = entry_from_record(record, run, note="trained by the test suite")  # a 2-epoch run: recipe "custom"
    # labelled as the model's default recipe, as shipped weights are, so that the default-recipe preference of
    # discovery can be tested; test_manifest checks the honest label of these 2 epochs
    entry = dataclasses.replace(honest, tag=make_tag(MODEL, DATASET, "full"), recipe="full",
                                note="trained by the test suite")
    manifest = write_manifest([entry], run / "manifest.json")
    test = tz.load_dataset(DATASET, split="test", **DATA_ARGS)
    model = captured["model"].eval()
    logits = predict_scores(model, test.x, test.g)
    return Trained(run, record, model, run / record["weights"]["file"], manifest, entry, test, logits)
