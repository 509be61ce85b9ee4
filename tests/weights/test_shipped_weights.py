"""The weights shipped in ``plugins/tactile-zoo-weights`` are exactly their committed cells' trained models.

Without data (CI): ``python -m tools.weights_pack --check`` passes (manifest, files, sha256, accuracy, config hash,
expected logits and the README table are what the committed cell records give), and every shipped model reproduces
the logits committed in ``expected_logits.json`` on the seeded probe inputs. Tolerance: ``rtol = atol = 1e-6``
(``|got - expected| <= 1e-6 + 1e-6 |expected|``), not bit equality: the builder and this test run the same code with
one thread, and on the machine that built the pack the difference is exactly 0, but another CPU or torch build may
pick other float32 kernels (oneDNN, vectorised reductions) that sum in another order; 1e-6 relative is a few float32
rounding steps at these magnitudes, while a change of a weight moves the logits by far more (a test below shows that
a shift of 1e-4 in the classifier's bias fails it). SGnet's scores are spike rates (multiples of 1/T): they are
compared the same way, but only a change that moves a spike shows in them.

With the real data under ``../shared/data`` (skipped, with the reason, otherwise): each shipped checkpoint, loaded
through ``create_model(..., pretrained=...)`` and evaluated on its real test split by :func:`tactile_zoo.evaluate`
(what the cell ran), gives exactly its entry's accuracy and the cell's predictions, sample for sample; and ``.npy``
files of real test samples (X-Tacformer on Ev-Objects and on BioTac-DoS), classified by ``tactile-zoo predict MODEL
--pretrained DATASET`` with the pack installed by pip, get exactly ``evaluate``'s prediction for each.

Cost, measured in CPU seconds on one thread: the BioTac-DoS test split is read once per loading configuration
(window 10: 5290 windows; window 5 for SGnet and, in raw units, for ConvLSTM: 10,705), about 1 s each, and each model
evaluates it once: 1-4 s each, ConvLSTM about 12 s (in batches of 32, :data:`EVAL_BATCH`). The Ev entries are marked
``slow``.
"""

from __future__ import annotations

import json
import os
import shutil
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from weights_helpers import installed_weight_pack, sample_table

import tactile_zoo as tz
from tactile_zoo import create_model, registry
from tactile_zoo.bench.records import CELLS_DIR, cell_file, read_cell_bytes
from tactile_zoo.cli import main
from tactile_zoo.engine.evaluate import EvalResult, predict_scores
from tactile_zoo.engine.runtime import flush_denormals
from tactile_zoo.weights import WeightEntry, head_name, read_manifest

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

from tools import weights_pack  # noqa: E402

SHARED_DATA = Path(os.environ.get("TACTILE_ZOO_SHARED_DATA", REPO.parent / "shared" / "data"))  # as tests/conftest.py
ENTRIES = read_manifest(weights_pack.PACK / weights_pack.MANIFEST)
LOGITS = json.loads((weights_pack.PACK / weights_pack.LOGITS).read_text()) if ENTRIES else {"entries": {}}
# float32 logits recomputed on another x86 CPU (an AVX-512 Xeon against the AMD EPYC that wrote them) differ by up
# to 9e-6: other vector widths sum in another order. A changed weight moves them by far more (the test below: 1e-3)
TOLERANCE = {"rtol": 1e-4, "atol": 5e-5}


def _params(entries: list[WeightEntry], *, real_data: bool = False) -> list[Any]:
    """One case per entry. On real data, an entry whose test split is not BioTac-DoS's is marked ``slow``: the Ev
    splits are small, but SGnet and D-CNN read 250-325 event frames per sample."""
    return [pytest.param(e, id=e.tag, marks=pytest.mark.slow if real_data and e.dataset != "biotac_dos" else ())
            for e in entries]


def _logits(entry: WeightEntry, model: torch.nn.Module | None = None) -> tuple[torch.Tensor, dict[str, Any]]:
    stored = LOGITS["entries"][entry.tag]
    x, g = weights_pack.probe_inputs(entry.spec, entry.dataset, LOGITS["samples"], LOGITS["seed"])
    assert weights_pack.inputs_sha256(x, g) == stored["inputs"]["sha256"], \
        "the probe inputs changed (tools.weights_pack.probe_inputs), not the weights: rebuild the pack"
    model = model if model is not None else create_model(entry.model, pretrained=entry)
    with flush_denormals():  # as the builder (and evaluate) computed them
        return predict_scores(model, x, g), stored


# ----------------------------------------------------------------------------------------------- without data
def test_the_pack_ships_weights_and_the_check_passes() -> None:
    assert {e.dataset for e in ENTRIES} >= {"biotac_dos"}, "the pack lost its BioTac-DoS weights"
    problems = weights_pack.check(weights_pack.rerun_folders())
    assert problems == [], "\n".join(problems)


def test_the_check_names_each_mismatch(tmp_path: Path) -> None:
    plugin = tmp_path / "plugin"
    shutil.copytree(weights_pack.PLUGIN, plugin, ignore=shutil.ignore_patterns("build", "*.egg-info", "__pycache__"))
    pack = plugin / weights_pack.PACK.name
    first, second = ENTRIES[0], ENTRIES[-1]
    document = json.loads((pack / weights_pack.MANIFEST).read_text())
    document["weights"][0]["accuracy"] += 0.01
    document["weights"][0]["config_hash"] = "0" * 16
    (pack / weights_pack.MANIFEST).write_text(json.dumps(document))
    damaged = bytearray((pack / second.file).read_bytes())
    damaged[-1] ^= 1  # one bit of the last tensor
    (pack / second.file).write_bytes(bytes(damaged))
    (pack / "stray.safetensors").write_bytes(b"x")
    problems = "\n".join(weights_pack.check(weights_pack.rerun_folders(), pack, plugin / "README.md"))
    assert f"{first.tag}: accuracy is {first.accuracy + 0.01!r} in the pack, {first.accuracy!r} from cell" in problems
    assert f"{first.tag}: config_hash is '{'0' * 16}' in the pack, '{first.config_hash}' from cell" in problems
    assert f"{first.tag}: accuracy {first.accuracy + 0.01!r}, the cell's leaderboard row says" in problems
    assert f"{second.tag}: " in problems and f"the cell record {second.cell_id} says {second.sha256}" in problems
    assert "stray.safetensors: in the pack, but no manifest entry lists it" in problems
    assert "the table of shipped weights is out of date" in problems


def test_rebuilding_the_pack_changes_nothing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # as on a checkout without the runs' own files (they are not committed): the builder takes the pack's copies,
    # whose sha256 are the records'
    monkeypatch.setattr(weights_pack.Source, "file", property(lambda self: tmp_path / "not-here.safetensors"))
    plugin = tmp_path / "plugin"
    shutil.copytree(weights_pack.PLUGIN, plugin, ignore=shutil.ignore_patterns("build", "*.egg-info", "__pycache__"))
    pack = plugin / weights_pack.PACK.name
    assert weights_pack.build(weights_pack.rerun_folders(), pack, plugin / "README.md") == 0
    for name in [weights_pack.MANIFEST, *(e.file for e in ENTRIES)]:
        assert (pack / name).read_bytes() == (weights_pack.PACK / name).read_bytes(), name
    assert (plugin / "README.md").read_text() == weights_pack.README.read_text()
    rebuilt = json.loads((pack / weights_pack.LOGITS).read_text())["entries"]
    assert set(rebuilt) == set(LOGITS["entries"])
    # recomputed here: equal within the tolerance above (exactly, on the machine that wrote them)
    for tag, item in rebuilt.items():
        torch.testing.assert_close(torch.tensor(item["logits"]), torch.tensor(LOGITS["entries"][tag]["logits"]),
                                   **TOLERANCE)
    (pack / ENTRIES[0].file).unlink()  # neither the run's file nor the pack's copy: the build stops, naming it
    with pytest.raises(SystemExit, match=rf"neither here nor in the pack .*\n  {ENTRIES[0].tag}: "):
        weights_pack.build(weights_pack.rerun_folders(), pack, plugin / "README.md")


def test_probe_inputs_are_seeded_and_shaped_like_the_dataset() -> None:
    spec = {"num_steps": 7, "num_nodes": 39, "num_channels": 2, "num_globals": 0}
    x, g = weights_pack.probe_inputs(spec, "ev_objects", samples=3)
    assert x.shape == (3, 7, 39, 2) and g.shape == (3, 7, 0) and x.dtype == torch.float32
    assert set(x.unique().tolist()) == {0.0, 1.0}  # event data: 0/1
    again, _ = weights_pack.probe_inputs(spec, "ev_objects", samples=3)
    assert torch.equal(x, again) and not torch.equal(x, weights_pack.probe_inputs(spec, "ev_objects", 3, seed=1)[0])
    analog, _ = weights_pack.probe_inputs({**spec, "num_nodes": 24, "num_channels": 1}, "biotac_dos", samples=3)
    assert analog.min() >= -1 and analog.max() < 1 and len(analog.unique()) > 100


@pytest.mark.parametrize("entry", _params(ENTRIES))
def test_a_shipped_model_reproduces_its_committed_logits(entry: WeightEntry) -> None:
    got, stored = _logits(entry)
    expected = torch.tensor(stored["logits"], dtype=torch.float32)
    assert got.shape == expected.shape == (LOGITS["samples"], entry.num_classes)
    torch.testing.assert_close(got, expected, **TOLERANCE)
    assert got.argmax(1).tolist() == expected.argmax(1).tolist()


@pytest.mark.parametrize("entry", _params([e for e in ENTRIES if e.loss == "ce"]))
def test_the_logits_check_sees_a_change_of_the_classifiers_bias(entry: WeightEntry) -> None:
    # models trained with "ce" output real-valued logits, which move with every weight; SGnet ("mse_rate") outputs
    # spike rates, multiples of 1/T, which a change this small may leave as they are (its real-data test covers it)
    model = create_model(entry.model, pretrained=entry)
    with torch.no_grad():
        model.get_submodule(head_name(model, entry.num_classes)).bias.add_(1e-3)
    got, stored = _logits(entry, model)
    with pytest.raises(AssertionError):
        torch.testing.assert_close(got, torch.tensor(stored["logits"], dtype=torch.float32), **TOLERANCE)


# ----------------------------------------------------------------------------------------------- with the real data
_SPLITS: dict[str, Any] = {}
_EVALS: dict[str, EvalResult] = {}
#: The eval batch of an entry whose cell's batch is slow here. Each sample's scores do not depend on the batch it sits
#: in (eval mode: no batch statistics), and the test compares every prediction with the cell's, so another split of
#: the test set proves as much. ConvLSTM at the cells' 256: a step's im2col matrix (144 x 256 x 132 floats, 19 MB)
#: and gates leave the cache, 20 CPU-s; at 32, 12 CPU-s, and its scores are bit-equal to batch 256's (measured: AMD
#: EPYC, one thread; batches of 16 or 48 differ in the last bit of some scores, not in a prediction).
EVAL_BATCH = {"convlstm.full_biotac_dos": 32}


def _record(entry: WeightEntry) -> dict[str, Any]:
    return json.loads(read_cell_bytes(cell_file(weights_pack.TABLES[entry.recipe] / CELLS_DIR, entry.cell_id)))


def _test_split(entry: WeightEntry) -> Any:
    """The entry's real test split, read once per loading configuration (skips when the data are absent)."""
    present, why = registry.get_dataset_entry(entry.dataset).obj.availability(SHARED_DATA)
    if not present:
        pytest.skip(f"real {entry.dataset} data not found ({why}); set TACTILE_ZOO_SHARED_DATA to run this test")
    key = json.dumps([entry.dataset, entry.fold, entry.dataset_kwargs], sort_keys=True)
    if key not in _SPLITS:
        _SPLITS[key] = tz.load_dataset(entry.dataset, root=SHARED_DATA, split="test", fold=entry.fold,
                                       **entry.dataset_kwargs)
    return _SPLITS[key]


def _evaluate(entry: WeightEntry) -> tuple[Any, EvalResult]:
    """The shipped checkpoint evaluated on its test split as the cell evaluated it (its eval batch size, or the
    entry's :data:`EVAL_BATCH`)."""
    test = _test_split(entry)
    if entry.tag not in _EVALS:
        model = create_model(entry.model, pretrained=entry)
        batch = EVAL_BATCH.get(entry.tag) or _record(entry)["config"]["recipe"]["eval_batch_size"]
        _EVALS[entry.tag] = tz.evaluate(model, test, batch_size=batch)
    return test, _EVALS[entry.tag]


@pytest.mark.real_data
@pytest.mark.parametrize("entry", _params(ENTRIES, real_data=True))
def test_a_shipped_checkpoint_evaluates_to_its_entrys_accuracy_exactly(entry: WeightEntry) -> None:
    test, result = _evaluate(entry)
    record = _record(entry)
    assert len(test) == record["n_test"]
    assert result.accuracy == entry.accuracy == record["metrics"]["test"]["accuracy"]
    assert result.targets == record["predictions"]["test"]["targets"]
    assert result.predictions == record["predictions"]["test"]["predictions"]


@pytest.fixture(scope="module")
def installed(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """The pack installed by pip (offline) and on ``sys.path``, found through its entry point."""
    with installed_weight_pack(weights_pack.PLUGIN, tmp_path_factory) as target:
        yield target


def _predict_cases() -> list[Any]:
    """The issue's example, X-Tacformer's Ev-Objects weights (``slow``: 250 event frames per file), and X-Tacformer's
    BioTac-DoS weights (else the first shipped BioTac-DoS entry)."""
    cases = [pytest.param(e, id=e.tag, marks=pytest.mark.slow) for e in ENTRIES
             if (e.model, e.dataset) == ("x_tacformer", "ev_objects")]
    biotac = sorted((e for e in ENTRIES if e.dataset == "biotac_dos"), key=lambda e: e.model != "x_tacformer")
    return cases + [pytest.param(e, id=e.tag) for e in biotac[:1]]


@pytest.mark.real_data
@pytest.mark.xdist_group("plugin_weights")
@pytest.mark.parametrize("entry", _predict_cases())
def test_npy_files_of_real_test_samples_get_evaluates_prediction(entry: WeightEntry, tmp_path: Path,
                                                                 capsys: pytest.CaptureFixture,
                                                                 request: pytest.FixtureRequest) -> None:
    test, result = _evaluate(entry)  # skips without the data, before installing anything
    request.getfixturevalue("installed")
    targets = np.asarray(result.targets)
    chosen = [int(i) for c in range(entry.num_classes) for i in np.flatnonzero(targets == c)[[0, -1]]]
    files = []
    for i in chosen:  # one sample of the documented recordings format per file: (T, N * C + G)
        files.append(tmp_path / f"sample{i}.npy")
        np.save(files[-1], sample_table(test, i))
    # the samples are the loader's output, already preprocessed: --raw, or BioTac-DoS's normalisation would run twice
    assert main(["predict", entry.model, "--pretrained", entry.dataset, *map(str, files), "--json", "--raw"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["weights"] == f"tactile-zoo-weights:{entry.tag}" and out["test_accuracy"] == entry.accuracy
    expected = [result.predictions[i] for i in chosen]
    assert [p["index"] for p in out["predictions"]] == expected
    assert [p["file"] for p in out["predictions"]] == [str(f) for f in files]
    assert expected == [_record(entry)["predictions"]["test"]["predictions"][i] for i in chosen]
    assert len(set(expected)) > 1  # the samples are not all read as one class
    api = tz.predict(entry.model, files, pretrained=entry.dataset, raw=True)  # the Python equivalent
    assert [p.index for p in api] == expected
    assert np.allclose([p.probabilities for p in api], [result.probabilities[i] for i in chosen], atol=1e-6)


@pytest.mark.real_data
@pytest.mark.xdist_group("plugin_weights")
@pytest.mark.parametrize(("file", "label"), [("n/bottle12.csv", "n"), ("s/bottle16.csv", "s")])
def test_a_raw_biotac_dos_file_is_answered_after_the_weights_own_preprocessing(file: str, label: str,
                                                                               request: pytest.FixtureRequest,
                                                                               capsys: pytest.CaptureFixture) -> None:
    """Issue 38, item 16: a release file of BioTac-DoS, as recorded, used to be read as class 'e' with p = 0.926;
    X-Tacformer's weights were trained on min-max scaled readings, which their manifest records and predict now
    applies by default (and names); ``--raw`` feeds the raw values and gets the old answer."""
    path = SHARED_DATA / "biotac_dos" / "raw" / "csvs" / file
    if not path.is_file():
        pytest.skip(f"real BioTac-DoS file {path} not found; set TACTILE_ZOO_SHARED_DATA to run this test")
    request.getfixturevalue("installed")
    capsys.readouterr()
    assert main(["predict", "x_tacformer", "--pretrained", "biotac_dos", str(path), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    answer = out["predictions"][0]
    assert out["preprocessing"] == answer["preprocessing"] == "biotac_dos normalize='minmax'"
    assert answer["class"] == label and answer["probability"] > 0.99
    assert main(["predict", "x_tacformer", "--pretrained", "biotac_dos", str(path), "--raw", "--json"]) == 0
    raw = json.loads(capsys.readouterr().out)["predictions"][0]
    assert raw["class"] == "e" and raw["preprocessing"] is None  # the wrong answer the issue reported
    assert main(["predict", "x_tacformer", "--pretrained", "biotac_dos", str(path)]) == 0
    assert "preprocessing: biotac_dos normalize='minmax': each reading scaled by its own range" in \
        capsys.readouterr().out
