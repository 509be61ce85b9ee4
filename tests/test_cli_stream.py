"""``tactile-zoo stream``: a checkpoint saved by ``tactile-zoo train --save`` replayed frame by frame."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

import tactile_zoo as tz
from tactile_zoo.cli import main
from tactile_zoo.engine import build_from_checkpoint, load_checkpoint, save_checkpoint
from tactile_zoo.engine.metrics import tied_top
from tactile_zoo.engine.stream import settled_step

EV_ARGS = {"n_train_per_class": 3, "n_test_per_class": 1, "num_steps": 20}  # 10 test samples of 20 steps
SLIP_ARGS = {"n_train_per_class": 2, "n_test_per_class": 1, "num_steps": 8}


@pytest.fixture(scope="module")
def sgnet_ckpt(tmp_path_factory: pytest.TempPathFactory) -> str:
    """A small SGNet trained for one epoch by the real ``train --save`` path."""
    path = str(tmp_path_factory.mktemp("stream") / "sgnet.pt")
    argv = ["train", "sgnet", "sim_evtouch", "--epochs", "1", "--save", path, "-q", "--device", "cpu",
            "--hparam", "graph_channels=8", "--hparam", "hidden=[16, 16]"]
    for key, value in EV_ARGS.items():
        argv += ["--dataset-arg", f"{key}={value}"]
    assert main(argv) == 0
    return path


def _untrained(tmp_path: Path, name: str, dataset: str, kwargs: dict, **hparams: object) -> str:
    """An untrained model in the exact checkpoint format ``train --save`` writes (the keys ``stream`` reads)."""
    spec = tz.load_dataset(dataset, split="test", **kwargs).spec
    torch.manual_seed(0)
    model = tz.create_model(name, spec, **hparams)
    loss = tz.registry.get_model_entry(name).meta["recipe"]["loss"]
    config = {"model": name, "hparams": hparams, "dataset": dataset, "dataset_kwargs": kwargs, "fold": 0, "seed": 0,
              "recipe": {"loss": loss}, "spec": spec.to_dict()}
    return str(save_checkpoint(tmp_path / f"{name}.pt", model, config))


def _step_lines(out: str) -> list[list[str]]:
    lines = out.splitlines()
    header = next(i for i, line in enumerate(lines) if line.split()[:2] == ["step", "time"])
    end = next(i for i, line in enumerate(lines) if line.startswith("true class:"))
    return [line.split() for line in lines[header + 1:end]]


def test_stream_prints_every_step_and_matches_the_full_forward(sgnet_ckpt: str, capsys: pytest.CaptureFixture
                                                                ) -> None:
    ds = tz.load_dataset("sim_evtouch", split="test", **EV_ARGS)
    names = ds.spec.class_names
    capsys.readouterr()
    assert main(["stream", sgnet_ckpt, "--dataset", "sim_evtouch", "--index", "0", "--threads", "1"]) == 0
    out = capsys.readouterr().out
    rows = _step_lines(out)
    assert [int(r[0]) for r in rows] == list(range(1, 21))
    true = names[ds[0].y]
    for step, row in enumerate(rows, start=1):
        # step, "<pct> % of T" (no frame period for sim_evtouch), class (or "(tie of K)"), p, yes/no/undecided
        assert row[1:4] == [f"{100 * step / 20:.1f}", "%", "of"] and row[4] == "T"
        if row[5] == "(tie":  # one epoch on 30 samples: the SNN's outputs are often still silent, all classes tied
            assert row[6] == "of" and row[7].endswith(")") and row[-1] == "undecided"
            continue
        assert row[5] in names and 0.0 <= float(row[6]) <= 1.0
        assert row[7] == ("yes" if row[5] == true else "no")
    assert f"true class: {true};" in out and "per-step latency: median" in out and "1 thread(s)" in out

    assert main(["stream", sgnet_ckpt, "--dataset", "sim_evtouch", "--index", "0", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    model = build_from_checkpoint(load_checkpoint(sgnet_ckpt), ds.spec).eval()
    x = ds[0].x[None]  # (1, T, N, C)
    with torch.no_grad():
        full = model(x)[0]
        prefix_scores = torch.cat([model(x[:, :t]) for t in range(1, 21)])
    prefix_preds = [None if tie else p for p, tie in zip(prefix_scores.argmax(-1).tolist(),
                                                         tied_top(prefix_scores, "mse_rate").tolist())]
    torch.testing.assert_close(torch.tensor(report["final_scores"]), full, atol=1e-5, rtol=1e-4)
    assert [s["top_class"] for s in report["steps"]] == [None if p is None else names[p] for p in prefix_preds]
    assert report["settled_step"] == settled_step(prefix_preds, ds[0].y)
    assert report["loss"] == "mse_rate" and report["true_class"] == true and report["frame_period_s"] is None
    probs = [s["probability"] for s in report["steps"]]
    assert all(0.0 <= p <= 1.0 for p in probs)


def test_every_k_and_frame_period_in_seconds(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    ckpt = _untrained(tmp_path, "convlstm", "sim_biotac_slip", SLIP_ARGS, hidden_channels=4, fc_units=8)
    assert main(["stream", ckpt, "--index", "2", "--every", "3"]) == 0  # the checkpoint's dataset by default
    rows = _step_lines(capsys.readouterr().out)
    assert [(r[0], r[1], r[2]) for r in rows] == [("3", "0.030", "s"), ("6", "0.060", "s"), ("8", "0.080", "s")]
    assert main(["stream", ckpt, "--index", "2", "--every", "3", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["frame_period_s"] == 0.01 and report["loss"] == "ce" and report["num_steps"] == 8
    assert [s["step"] for s in report["steps"]] == [3, 6, 8]
    assert [s["time_s"] for s in report["steps"]] == pytest.approx([0.03, 0.06, 0.08])
    settled = report["settled_step"]
    assert settled is None or report["settled_time_s"] == pytest.approx(0.01 * settled)


def test_a_non_streaming_model_is_exit_2_naming_it(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    ckpt = _untrained(tmp_path, "dcnn", "sim_evtouch", EV_ARGS)
    assert main(["stream", ckpt, "--index", "0"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert "'dcnn' does not stream" in err and "streaming=False" in err and "prefix" in err


@pytest.mark.parametrize(("argv", "message"), [
    (["--index", "10"], "--index 10 is out of range: split 'test' of sim_evtouch (fold 0) has 10 samples (0..9)"),
    (["--index", "-1"], "--index -1 is out of range"),
    (["--index", "x"], "argument --index: invalid int value"),
    (["--index", "0", "--every", "0"], "--every must be a positive integer"),
])
def test_bad_arguments_are_exit_2(sgnet_ckpt: str, capsys: pytest.CaptureFixture, argv: list[str], message: str
                                  ) -> None:
    capsys.readouterr()
    assert main(["stream", sgnet_ckpt, *argv]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1


def test_a_tie_is_reported_undecided_never_correct(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """Issue 49 item 6: a DeepTactile whose output neurons never fire (as after one quick epoch: every rate 0, p 0.100
    for each of 10 classes) was "correct and stayed correct from step 1" on a class-0 sample, argmax's pick."""
    spec = tz.load_dataset("sim_evtouch", split="test", **EV_ARGS).spec
    model = tz.create_model("deeptactile", spec)
    with torch.no_grad():
        for p in model.parameters():
            p.zero_()  # silent: no spike reaches the output layer
    config = {"model": "deeptactile", "hparams": {}, "dataset": "sim_evtouch", "dataset_kwargs": EV_ARGS, "fold": 0,
              "seed": 0, "recipe": {"loss": "mse_rate"}, "spec": spec.to_dict()}
    ckpt = str(save_checkpoint(tmp_path / "dt.pt", model, config))
    ds = tz.load_dataset("sim_evtouch", split="test", **EV_ARGS)
    index = next(i for i in range(len(ds)) if int(ds[i].y) == 0)  # argmax of a tie is class 0
    assert main(["stream", ckpt, "--index", str(index), "-q"]) == 0
    out = capsys.readouterr().out
    rows = _step_lines(out)
    assert rows and all(r[5:8] == ["(tie", "of", "10)"] and r[8] == "0.100" and r[9] == "undecided" for r in rows)
    assert "final prediction: undecided: a tie of 10 classes at p 0.100 each" in out
    assert "correct and stayed correct: never (the last prediction is undecided (a tie))" in out
    assert f"undecided steps: {len(rows)} of {len(rows)}" in out
    assert main(["stream", ckpt, "--index", str(index), "--json", "-q"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["settled_step"] is None
    assert all(s["top_class"] is None and s["correct"] is False and len(s["tied_classes"]) == 10
               for s in report["steps"])


def test_a_dataset_arg_keeps_the_checkpoints_own_dataset_options(sgnet_ckpt: str, capsys: pytest.CaptureFixture
                                                                  ) -> None:
    """Issue 49 item 7: the data a checkpoint is evaluated or streamed on are loaded with the options (the
    preprocessing) it was trained with; one ``--dataset-arg`` overrides one key instead of dropping them all (it used
    to load 100-step default recordings into a model trained on 20 steps)."""
    capsys.readouterr()
    assert main(["evaluate", sgnet_ckpt, "--dataset-arg", "seed=1", "--json", "-q"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["n"] == 10  # n_test_per_class=1 of the checkpoint, 10 classes
    assert main(["stream", sgnet_ckpt, "--index", "0", "--dataset-arg", "seed=1", "--json", "-q"]) == 0
    assert json.loads(capsys.readouterr().out)["num_steps"] == 20
