from __future__ import annotations

import json
from pathlib import Path

import pytest
from conftest import SMALL, run_cli

from tactile_zoo.cli import build_parser, main


def _err(capsys: pytest.CaptureFixture) -> str:
    return capsys.readouterr().err


def test_bench_flags_parse() -> None:
    args = build_parser().parse_args(["bench", "--models", "a,b", "--models", "c*", "--seeds", "0-2", "--folds", "3",
                                      "--epochs", "5", "--refit", "--quick", "--device", "cpu", "--out", "x",
                                      "--force", "--executor", "dask", "--scheduler", "tcp://h:8786", "--workers",
                                      "4", "--plugin-module", "m1", "--plugin-module", "m2", "--dry-run", "-q",
                                      "--set", "lr=0.1", "--hparam", "m:hidden=3", "--dataset-arg", "seed=2"])
    assert args.models == ["a,b", "c*"] and args.seeds == "0-2" and args.force is True and args.refit
    assert args.plugin_modules == ["m1", "m2"] and args.sets == ["lr=0.1"] and args.hparams == ["m:hidden=3"]
    assert build_parser().parse_args(["bench", "--resume"]).force is False
    assert build_parser().parse_args(["bench"]).force is None


@pytest.mark.parametrize(("argv", "message"), [
    (["--seeds", "1,x"], "--seeds"), (["--seeds", "-3"], "--seeds"), (["--folds", "0"], "--folds"),
    (["--folds", "two"], "--folds"), (["--epochs", "0"], "--epochs"), (["--workers", "-1"], "--workers"),
    (["--models", "tiny_mpl"], "Did you mean 'tiny_mlp'"), (["--datasets", "nope_*"], "matches no registered"),
    (["--set", "tiny_mlp:lrr=1"], "lrr"), (["--set", "lr"], "KEY=VALUE"), (["--prefixes", "0"], "--prefixes"),
    (["--resume", "--force"], "not allowed with"), (["--scheduler", "tcp://x:1"], "--scheduler only applies"),
    (["--plugin-module", "no_such_module_xyz"], "no_such_module_xyz"),
])
def test_bad_input_is_one_line_and_exit_2(argv: list[str], message: str, capsys: pytest.CaptureFixture,
                                          tmp_path: Path) -> None:
    assert run_cli([*SMALL, *argv, "--out", str(tmp_path / "o")]) == 2
    err = _err(capsys)
    assert message in err and err.startswith("tactile-zoo: error:") and "Traceback" not in err
    assert not (tmp_path / "o").exists()


def test_unwritable_out_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    (tmp_path / "file").write_text("")
    assert run_cli([*SMALL, "--out", str(tmp_path / "file" / "run")]) == 2
    assert "cannot write there" in _err(capsys)


def test_yaml_config_and_unknown_keys(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    cfg = tmp_path / "bench.yaml"
    cfg.write_text("models: [tiny_mlp]\ndatasets: tiny_kfold\nfolds: 1\nseeds: 0,3\nthreads: 1\n")
    assert run_cli(["--config", str(cfg), "--dry-run", "--seeds", "5"]) == 0  # the flag wins over the file
    out = capsys.readouterr().out
    assert "1 cells" in out and "__s5__" in out and "__s3__" not in out
    cfg.write_text("models: [tiny_mlp]\nlearning_rate: 0.1\n")
    assert run_cli(["--config", str(cfg)]) == 2
    assert "unknown key(s) learning_rate" in _err(capsys)


def test_dry_run_prints_the_grid_and_writes_nothing(tmp_path: Path, capsys: pytest.CaptureFixture,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    assert run_cli(["--models", "tiny_mlp,tiny_rate", "--datasets", "tiny_*", "--seeds", "0,1", "--root",
                    str(tmp_path / "data"), "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "16 cells: 2 model(s) x 2 dataset(s)" in out
    assert "skipped dataset tiny_absent" in out and "copy the tiny files" in out
    assert out.count("  cell ") == 16 and "tactile-zoo-results" in out
    assert not (tmp_path / "tactile-zoo-results").exists()


def test_default_out_dir_reruns_resume(tmp_path: Path, capsys: pytest.CaptureFixture,
                                       monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    args = ["--models", "tiny_mlp", "--datasets", "tiny_blobs", "--epochs", "2", "--no-plots"]
    assert run_cli(args) == 0
    (out,) = (tmp_path / "tactile-zoo-results").iterdir()
    assert run_cli(args) == 0
    assert "1 already finished, 0 to run" in capsys.readouterr().out
    assert [p.name for p in (tmp_path / "tactile-zoo-results").iterdir()] == [out.name]


def test_train_save_and_evaluate(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    ckpt = tmp_path / "m.pt"
    assert main(["train", "tiny_mlp", "tiny_blobs", "--seed", "1", "--epochs", "3", "--hparam", "hidden=8",
                 "--save", str(ckpt), "--json", "-q"]) == 0
    trained = json.loads(capsys.readouterr().out)
    assert trained["epochs_run"] == 3 and trained["seed"] == 1 and Path(trained["saved"]) == ckpt
    import torch

    blob = torch.load(ckpt, weights_only=True)
    assert blob["config"]["model"] == "tiny_mlp" and blob["config"]["hparams"] == {"hidden": 8}
    assert blob["config"]["recipe"]["max_epochs"] == 3
    assert main(["evaluate", str(ckpt), "--json"]) == 0  # dataset and fold default to the checkpoint's
    evaluated = json.loads(capsys.readouterr().out)
    assert evaluated["accuracy"] == trained["test"]["accuracy"] and evaluated["split"] == "test"
    assert main(["evaluate", str(ckpt), "tiny_blobs", "--split", "test_shifted"]) == 0
    assert "test_shifted" in capsys.readouterr().out
    assert main(["evaluate", str(ckpt), "tiny_kfold"]) == 2  # no globals there: a different spec
    assert "num_globals=3" in _err(capsys)
    (tmp_path / "bad.pt").write_bytes(b"not a checkpoint")
    assert main(["evaluate", str(tmp_path / "bad.pt")]) == 2
    assert f"checkpoint {tmp_path / 'bad.pt'} is not a tactile-zoo checkpoint: it is a text file" in _err(capsys)


def test_train_bad_seed_and_fold(capsys: pytest.CaptureFixture) -> None:
    assert main(["train", "tiny_mlp", "tiny_blobs", "--seed", "x"]) == 2
    assert "--seed: 'x'" in _err(capsys)  # the flag train has, not bench's --seeds
    assert main(["train", "tiny_mlp", "tiny_kfold", "--fold", "7"]) == 2
    assert "out of range" in _err(capsys)


def test_report_of_a_folder_that_is_not_a_run(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    assert main(["report", str(tmp_path)]) == 2
    assert "no cells/ folder" in _err(capsys)


def test_train_resolves_its_cell_with_the_harness_function(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``train`` builds its cell configuration through bench's one function (``bench.config.plan_cells``): a plugin
    model's override scoped by its qualified name (``dist:name``) reaches ``train`` as it reaches ``bench``, and the
    saved configuration hashes as the harness's cell does. The copy ``train`` once kept knew only the bare name."""
    import torch
    from fake_plugins import GOOD_MODULE, FakeSite, unique

    from tactile_zoo.bench.config import merge_config
    from tactile_zoo.bench.grid import build_grid
    from tactile_zoo.engine.config import CellConfig, config_hash

    site = FakeSite(tmp_path, monkeypatch)
    try:
        name = unique("bench_scoped")
        site.add("zt-bench-scoped", GOOD_MODULE, models={name: "Net"})
        qualified, scoped = f"zt-bench-scoped:{name}", [f"zt-bench-scoped:{name}:width=7"]
        saved = tmp_path / "scoped.pt"
        assert main(["train", qualified, "tiny_blobs", "--hparam", scoped[0], "--epochs", "1", "-q",
                     "--save", str(saved)]) == 0
        trained = CellConfig.from_dict(torch.load(saved, weights_only=True)["config"])
        assert trained.hparams == {"width": 7}
        flags = {"models": [qualified], "datasets": ["tiny_blobs"], "epochs": 1}
        assert config_hash(trained) == build_grid(merge_config(None, flags, (), scoped)).cells[0].config_hash
    finally:
        site.close()
