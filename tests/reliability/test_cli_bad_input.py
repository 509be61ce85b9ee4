"""Bad command lines and config files: exit code 2, one line on stderr naming the argument, no traceback (and the
traceback with ``--debug``). Everything is refused before any cell runs."""

from __future__ import annotations

from pathlib import Path

import pytest

from tactile_zoo.cli import main
from tactile_zoo.errors import TactileZooError

BENCH = ["bench", "--plugin-module", "tiny_zoo", "--dry-run"]
GRID = ["--models", "tiny_mlp", "--datasets", "tiny_blobs"]
TRAIN = ["train", "tiny_mlp", "tiny_blobs", "--plugin-module", "tiny_zoo", "-q"]

CASES = {  # id -> (argv with {tmp} for the test's folder, what the one line must say)
    "unknown model": ([*BENCH, "--models", "tiny_mpl", "--datasets", "tiny_blobs"],
                      "unknown model 'tiny_mpl'. Did you mean 'tiny_mlp'"),
    "unknown dataset": ([*BENCH, "--models", "tiny_mlp", "--datasets", "tiny_blbos"],
                        "unknown dataset 'tiny_blbos'. Did you mean 'tiny_blobs'"),
    "pattern matches nothing": ([*BENCH, "--models", "tiny_zz*", "--datasets", "tiny_blobs"],
                                "--models: pattern 'tiny_zz*' matches no registered model; known: "),
    "train unknown model": (["train", "tiny_mpl", "tiny_blobs", "--plugin-module", "tiny_zoo"],
                            "Did you mean 'tiny_mlp'"),
    "seeds not numbers": ([*BENCH, *GRID, "--seeds", "a,b"], "--seeds: 'a' is not a non-negative integer"),
    "negative seed": ([*BENCH, *GRID, "--seeds", "-1"], "--seeds: '-1' is not a non-negative integer"),
    "reversed range": ([*BENCH, *GRID, "--seeds", "3-1"], "--seeds: '3-1' is not"),
    "fractional seed": ([*BENCH, *GRID, "--seeds", "0,1.5"], "--seeds: '1.5' is not"),
    "empty seeds": ([*BENCH, *GRID, "--seeds", ""], "--seeds"),
    "huge seed": ([*BENCH, *GRID, "--seeds", str(2**64)], "--seeds: a seed must be below 2**63"),
    "train bad seed": ([*TRAIN, "--seed", "x"], "--seed: 'x' is not a non-negative integer"),
    "train two seeds": ([*TRAIN, "--seed", "0,1"], "--seed takes one seed"),
    "zero folds": ([*BENCH, *GRID, "--folds", "0"], "--folds must be a positive integer"),
    "negative folds": ([*BENCH, *GRID, "--folds", "-2"], "--folds must be a positive integer"),
    "folds not a number": ([*BENCH, *GRID, "--folds", "two"], "got 'two'"),
    "train negative fold": ([*TRAIN, "--fold", "-1"], "--fold must be a non-negative integer, got '-1'"),
    "train fold out of range": (["train", "tiny_mlp", "tiny_kfold", "--plugin-module", "tiny_zoo", "--fold", "3"],
                                "fold=3 is out of range; this protocol has 3 fold(s) (0..2)"),
    "zero epochs": ([*BENCH, *GRID, "--epochs", "0"], "--epochs must be an integer >= 1"),
    "unknown recipe key": ([*BENCH, *GRID, "--set", "lrr=0.1"], "unknown recipe key(s) ['lrr']"),
    "negative lr": ([*BENCH, *GRID, "--set", "tiny_mlp:lr=-1"], "lr must be a positive number"),
    "zero workers": ([*BENCH, *GRID, "--workers", "0"], "--workers must be an integer >= 1"),
    "out under a file": (["bench", "--plugin-module", "tiny_zoo", *GRID, "--out", "{tmp}/file/run"],
                         "--out {tmp}/file/run: cannot write there (Not a directory)"),
    "out is a file": (["bench", "--plugin-module", "tiny_zoo", *GRID, "--out", "{tmp}/file"],
                      "--out {tmp}/file: cannot write there"),
    "missing plugin module": ([*BENCH, *GRID, "--plugin-module", "zt_no_such_module"],
                              "--plugin-module 'zt_no_such_module' cannot be imported: ModuleNotFoundError"),
    "missing config": ([*BENCH, "--config", "{tmp}/nothing.yaml"], "--config {tmp}/nothing.yaml: cannot read it"),
    "config unknown key": ([*BENCH, "--config", "{tmp}/typo.yaml"],
                           "--config {tmp}/typo.yaml: unknown key(s) epoch, model_override; known keys: "),
    "config nested unknown key": ([*BENCH, "--config", "{tmp}/nested.yaml"],
                                  "model_overrides.tiny_mlp: unknown key(s) ['hparam']"),
    "config recipe typo": ([*BENCH, "--config", "{tmp}/recipe.yaml"], "unknown recipe key(s) ['learning_rate']"),
    "config not a mapping": ([*BENCH, "--config", "{tmp}/list.yaml"], "the top level must be a mapping"),
    "config not yaml": ([*BENCH, "--config", "{tmp}/broken.yaml"], "--config {tmp}/broken.yaml: not valid YAML"),
    "missing checkpoint": (["evaluate", "{tmp}/none.pt"], "checkpoint {tmp}/none.pt does not exist"),
}

CONFIGS = {
    "typo.yaml": "models: tiny_mlp\ndatasets: tiny_blobs\nepoch: 3\nmodel_override: {}\n",
    "nested.yaml": "models: tiny_mlp\ndatasets: tiny_blobs\nmodel_overrides:\n  tiny_mlp: {hparam: {hidden: 4}}\n",
    "recipe.yaml": "models: tiny_mlp\ndatasets: tiny_blobs\nrecipe: {learning_rate: 0.1}\n",
    "list.yaml": "- tiny_mlp\n- tiny_blobs\n",
    "broken.yaml": "models: [tiny_mlp\ndatasets: tiny_blobs\n",
}


@pytest.fixture
def folder(tmp_path: Path) -> Path:
    (tmp_path / "file").write_text("a file, not a folder\n")
    for name, text in CONFIGS.items():
        (tmp_path / name).write_text(text)
    return tmp_path


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_input_is_one_line_exit_2_and_a_traceback_only_with_debug(case: str, folder: Path,
                                                                        capsys: pytest.CaptureFixture) -> None:
    argv, message = ([a.replace("{tmp}", str(folder)) for a in CASES[case][0]],
                     CASES[case][1].replace("{tmp}", str(folder)))
    assert main(argv) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1 and err.startswith("tactile-zoo: error: ")
    assert message in err and "Traceback" not in err
    assert not (folder / "file" / "run").exists() and not list(folder.glob("**/cells"))  # nothing ran
    with pytest.raises(TactileZooError) as raised:
        main(["--debug", *argv])
    assert message in str(raised.value)
