"""The benchmarks/ suite keeps working: tiny runs write CSVs with the declared columns (no timings are asserted)."""

from __future__ import annotations

import csv
import sys
from pathlib import Path

import pytest
import torch

REPO = Path(__file__).resolve().parents[2]
if str(REPO) not in sys.path:  # benchmarks/ is a top-level package of the checkout, not of the installed wheel
    sys.path.insert(0, str(REPO))

from benchmarks import BENCHMARKS, common, graph_conv, grid_size, lif, run, scaling, sgnet_epoch  # noqa: E402


def _ctx(tmp_path: Path) -> common.Context:
    return common.Context(threads=1, quick=True, repeats=1, out=tmp_path, log=lambda _msg: None)


def _read(path: Path) -> list[dict[str, str]]:
    with path.open() as fh:
        return list(csv.DictReader(fh))


def test_lif_writes_csv_with_columns_and_environment(tmp_path: Path) -> None:
    path = lif.run(_ctx(tmp_path), batch=2, steps=8, nodes=3, features=4)
    assert path == tmp_path / "lif.csv"
    rows = _read(path)
    assert list(rows[0]) == ["benchmark", "case", *lif.COLUMNS, "note", *common.ENV_COLUMNS]
    assert [r["case"] for r in rows] == [f"{case}{kind}" for case in ("sgnet", "snntorch_default")
                                         for kind in ("", "_fused", "_compiled_vs_fused")]
    for row in rows:
        assert float(row["ratio"]) > 0 and row["repeats"] == "1" and row["threads"] == "1"
        assert float(row["max_spike_diff"]) == 0.0  # the compiled, fused and snnTorch paths agree on every spike
        assert row["equal_to_fused"] == "True" and row["load_avg"]
        assert row["torch"] == torch.__version__ and row["device"] == "cpu" and row["quick"] == "True"
        assert row["cpu_model"] and row["snntorch"] and row["tactile_zoo"]


def test_graph_conv_compares_all_paths_on_the_same_outputs(tmp_path: Path) -> None:
    rows = _read(graph_conv.run(_ctx(tmp_path), batch=2, steps=3, out_channels=4))
    assert {r["case"] for r in rows} == {"dense_vs_per_frame", "pyg_vs_per_frame", "dense_vs_per_step",
                                         "pyg_vs_per_step"}
    assert all(float(r["max_abs_diff"]) < 1e-5 for r in rows)


def test_stepwise_sgnet_is_the_zoo_model() -> None:
    """The naive side of sgnet_epoch computes the same rates and gradients as the zoo's SGnet with its weights."""
    from tactile_zoo.engine import resolve_recipe
    from tactile_zoo.registry import instantiate_model

    spec = common.ev_spec(num_steps=12)
    split = common.synthetic_events(spec, 3, seed=0, density=0.5)
    torch.manual_seed(0)
    model = instantiate_model("sgnet", spec)
    with torch.no_grad():  # a larger first layer so that spikes reach the output within 12 steps
        model.gc.conv.lins[0].weight.mul_(8.0)
    net = sgnet_epoch.StepwiseSGNet.like(model)
    rate_diff, grad_diff = sgnet_epoch._same_model(model, net, split, 3, resolve_recipe({"loss": "mse_rate"}))
    assert rate_diff == 0.0 and grad_diff < 1e-4
    with torch.no_grad():
        assert float(model.eval()(split.x).sum()) > 0  # the comparison saw output spikes, not two silent nets


def test_scaling_batch_and_breakdown_parts_keep_the_other_rows(tmp_path: Path) -> None:
    """The batch curve and the attention breakdown run small; rows of parts not measured stay as committed."""
    old = {"case": "sgnet_T50", "model": "sgnet", "axis": "T", "T": 50, "N": 39, "epoch_median_s": 2.25,
           "date": "2026-01-01T00:00:00+00:00", "git_commit": "abc"}
    common.write_csv(_ctx(tmp_path), "scaling", ("model", "axis", "T", "N", "epoch_median_s"), [old])
    path = scaling.run(_ctx(tmp_path), parts=("batch", "breakdown"), batch_models=("sgnet",), batch_sizes=(1, 2),
                       batch_samples=2, breakdown_copies=(1, 2), num_steps=10)
    rows = _read(path)
    assert list(rows[0]) == ["benchmark", "case", *scaling.COLUMNS, "note", *common.ENV_COLUMNS]
    kept = [r for r in rows if r["axis"] == "T"]
    assert len(kept) == 1 and kept[0]["git_commit"] == "abc" and kept[0]["epoch_median_s"] == "2.25"
    batch = {int(r["batch_size"]): r for r in rows if r["axis"] == "batch"}
    assert sorted(batch) == [1, 2, 8]  # the recipe's batch 8 is always measured
    assert float(batch[8]["ratio_to_recipe"]) == 1.0 and float(batch[1]["per_sample_s"]) > 0
    parts = {(r["part"], int(r["N"])) for r in rows if r["axis"] == "breakdown"}
    assert parts == {(p, n) for p in ("total", "attention", "rest", "graph_conv") for n in (39, 78)}
    assert all(r["crossover_N"] and r["quick"] == "True" for r in rows if r["axis"] == "breakdown")
    assert all(0 < float(r["profiled_share"]) < 1 for r in rows if r["part"] == "attention")


def test_scaling_fits_recover_known_curves() -> None:
    ns = [39, 78, 156, 312]
    att = scaling._fit(ns, [2e-4 * n * n + 0.1 for n in ns], 2)
    rest = scaling._fit(ns, [0.05 * n + 1.0 for n in ns], 1)
    assert att == pytest.approx((2e-4, 0.1)) and rest == pytest.approx((0.05, 1.0))
    cross = scaling._crossover(att, rest)
    assert 2e-4 * cross ** 2 + 0.1 == pytest.approx(0.05 * cross + 1.0)
    c, p = scaling._power_law(ns, [3.0 * n ** 1.5 for n in ns])
    assert (c, p) == pytest.approx((3.0, 1.5))
    assert scaling._power_crossover((1.0, 2.0), (4.0, 1.0)) == pytest.approx(4.0)


def test_runner_rejects_unknown_names_and_lists(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        run.main(["--only", "nope"])
    assert exc.value.code == 2 and "unknown benchmark" in capsys.readouterr().err
    assert run.main(["--list"]) == 0
    listed = capsys.readouterr().out.splitlines()
    assert [line.split()[0] for line in listed] == list(BENCHMARKS)


def test_grid_size_measures_the_refused_huge_seed_range(tmp_path: Path) -> None:
    rows = _read(grid_size.run(_ctx(tmp_path), cases=("huge_seed_range",)))
    assert list(rows[0]) == ["benchmark", "case", *grid_size.COLUMNS, "note", *common.ENV_COLUMNS]
    (row,) = rows
    assert row["case"] == "huge_seed_range" and row["exit_code"] == "2" and row["output_lines"] == "1"
    assert "100,000,001 seeds" in row["answer"] and float(row["peak_rss_mb"]) > 0  # no time is asserted


def test_write_csv_refuses_undeclared_columns(tmp_path: Path) -> None:
    with pytest.raises(KeyError, match="bogus"):
        common.write_csv(_ctx(tmp_path), "x", ("a",), [{"case": "c", "a": 1, "bogus": 2}])


def test_sgnet_event_times_both_computations_on_the_same_network(tmp_path: Path) -> None:
    """The opt-in event-driven SGnet against the dense default: same spikes, gradients to rounding, every row."""
    from benchmarks import sgnet_event

    rows = _read(sgnet_event.run(_ctx(tmp_path), variant="event", batches=1))
    assert [r["case"] for r in rows] == ["train_step", "graph_conv", "first_linear", "event_scan"]
    step = rows[0]
    assert step["same_spikes"] == "True" and float(step["grad_rel_diff"]) < 1e-4
    assert 0 < float(step["lif_rate"]) < 0.5 and step["variant"] == "event"
    assert all(float(r["fast_median_s"]) > 0 for r in rows) and all(float(r["ratio"]) > 0 for r in rows[:3])
    with pytest.raises(ValueError, match="variant"):
        sgnet_event.run(_ctx(tmp_path), variant="sparse")


def test_gpu_epoch_times_the_cpu_and_says_the_gpu_cases_are_unmeasured_without_one(tmp_path: Path) -> None:
    from benchmarks import gpu_epoch

    assert BENCHMARKS["gpu_epoch"] == "gpu_epoch" and gpu_epoch.MODELS == ("sgnet", "convlstm")
    ctx = _ctx(tmp_path)
    ctx.root = tmp_path  # no Ev-Objects there: synthetic events of its shape, as in CI
    rows = _read(gpu_epoch.run(ctx, models=("sgnet",)))
    assert [r["case"] for r in rows] == ["sgnet/cpu", "sgnet/eager", "sgnet/graphed"]
    cpu, *gpu = rows
    assert float(cpu["epoch_median_s"]) > 0 and float(cpu["speedup_vs_cpu"]) == 1.0 and cpu["repeats"] == "1"
    assert cpu["samples_timed"] == "64" and "2 CPU threads" in cpu["note"] and "scaled to 576" in cpu["note"]
    assert all(r["epoch_median_s"] == "" and r["note"].startswith("unmeasured: no CUDA device") for r in gpu)
    assert torch.get_num_threads() == 1  # the 2-thread case gave the process its count back
