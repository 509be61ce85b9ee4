"""benchmarks/gpu_check.py: skips cleanly without CUDA, runs its comparison for real with --allow-cpu, and reports a
perturbed comparison (logits, spikes, gradients, a bench cell) as a failure. CPU only, small shapes."""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
import types
from pathlib import Path

import pytest
import torch

REPO = Path(__file__).resolve().parents[2]
if str(REPO) not in sys.path:  # benchmarks/ is a top-level package of the checkout, not of the installed wheel
    sys.path.insert(0, str(REPO))

from benchmarks import gpu_check  # noqa: E402
from benchmarks.gpu_check import Run, compare_runs  # noqa: E402

#: a tiny configuration: short sequences of one simulator, batch 2, 8 training samples, 1 thread, no bench
TINY = ["--allow-cpu", "--quick", "--datasets", "sim_biotac_slip", "--steps", "10", "--batch", "2", "--samples", "8",
        "--threads", "1", "--skip", "bench"]


def _read(path: Path) -> list[dict[str, str]]:
    with path.open() as fh:
        return list(csv.DictReader(fh))


# ------------------------------------------------------------------------------------------------ the command
def test_without_cuda_it_skips_writes_nothing_and_exits_0(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    out = tmp_path / "out"
    assert gpu_check.main(["--quick", "--out", str(out)]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 1 and "CUDA is not available" in lines[0] and "skipped" in lines[0]
    assert not out.exists()


def test_the_command_line_skips_where_cuda_is_hidden(tmp_path: Path) -> None:
    """``python -m benchmarks.gpu_check`` from the repository root, as the GPU machine runs it, with no GPU visible."""
    env = {**os.environ, "CUDA_VISIBLE_DEVICES": ""}
    proc = subprocess.run([sys.executable, "-m", "benchmarks.gpu_check", "--out", str(tmp_path / "out")], cwd=REPO,
                          env=env, capture_output=True, text=True, timeout=300, check=False)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.strip().splitlines() == ["gpu_check: CUDA is not available here; skipped (nothing written)"]
    assert not (tmp_path / "out").exists()


def test_a_missing_package_is_named_and_exits_2(monkeypatch: pytest.MonkeyPatch,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setitem(sys.modules, "snntorch", None)  # import snntorch now raises ModuleNotFoundError
    assert gpu_check.main(["--allow-cpu"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "missing package 'snntorch'" in err[0]


def test_allow_cpu_quick_runs_the_comparison_and_timings_and_passes(tmp_path: Path) -> None:
    threads = torch.get_num_threads()
    assert gpu_check.main([*TINY, "--models", "sgnet,tacformer,dcnn", "--out", str(tmp_path)]) == 0
    assert torch.get_num_threads() == threads  # the process's thread count is restored
    rows = {r["case"]: r for r in _read(tmp_path / "gpu_check_compare.csv")}
    expected = {f"{m}/sim_biotac_slip/{c}" for m in ("sgnet", "tacformer") for c in ("forward", "backward", "stream")}
    assert set(rows) == expected | {"dcnn/sim_biotac_slip/forward", "dcnn/sim_biotac_slip/backward"}
    for row in rows.values():
        assert row["status"] == "pass" and float(row["max_abs_diff"]) == 0.0 and row["device"] == "cpu"
        assert row["torch"] == torch.__version__ and row["quick"] == "True"
    for check in ("forward", "backward", "stream"):
        sg = rows[f"sgnet/sim_biotac_slip/{check}"]  # a spiking model: spikes counted, and there were some
        assert float(sg["spike_total"]) > 0 and sg["spikes_equal"] == "True"
        assert float(sg["spike_rate_diff"]) == 0.0 and float(sg["spike_rate_limit"]) == pytest.approx(1 / 10)
    assert float(rows["tacformer/sim_biotac_slip/forward"]["spike_rate_limit"]) == pytest.approx(1 / 2)  # 2 bins
    assert rows["dcnn/sim_biotac_slip/forward"]["spike_total"] == ""  # not spiking
    assert float(rows["dcnn/sim_biotac_slip/backward"]["grad_rel_diff"]) == 0.0
    assert float(rows["sgnet/sim_biotac_slip/stream"]["stream_vs_forward_diff"]) == 0.0
    timing = _read(tmp_path / "gpu_check_timing.csv")
    assert [r["model"] for r in timing] == ["sgnet", "tacformer", "dcnn"]
    assert all(r["status"] == "ok" and float(r["epoch_s"]) > 0 and float(r["latency_ms"]) > 0 for r in timing)
    assert {r["samples"] for r in timing} == {"8"}
    summary = json.loads((tmp_path / "gpu_check.json").read_text())
    assert summary["passed"] is True and summary["failed"] == [] and len(summary["sections"]["compare"]) == 8
    assert not (tmp_path / "gpu_check_bench.csv").exists()


def test_a_perturbed_device_copy_fails_the_command(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The 'device' copy of the model gets one weight moved by 1e-2: its logits and gradients no longer match."""
    import copy

    def perturbed(model: torch.nn.Module) -> torch.nn.Module:
        twin = copy.deepcopy(model)
        with torch.no_grad():
            next(twin.parameters()).add_(1e-2)
        return twin

    monkeypatch.setattr(gpu_check, "copy", types.SimpleNamespace(deepcopy=perturbed))
    assert gpu_check.main([*TINY, "--models", "dcnn", "--only", "compare", "--out", str(tmp_path)]) == 1
    rows = _read(tmp_path / "gpu_check_compare.csv")
    assert [r["status"] for r in rows] == ["FAIL", "FAIL"]
    assert all("scores differ" in r["note"] and float(r["max_abs_diff"]) > 1e-4 for r in rows)
    assert "gradients differ" in rows[1]["note"]
    assert json.loads((tmp_path / "gpu_check.json").read_text())["failed"] == ["dcnn/sim_biotac_slip/forward",
                                                                             "dcnn/sim_biotac_slip/backward"]


def test_a_spent_budget_skips_the_remaining_work_with_a_note(tmp_path: Path) -> None:
    assert gpu_check.main([*TINY[:-2], "--models", "dcnn", "--timeout", "0", "--out", str(tmp_path)]) == 0
    for section in ("compare", "timing", "bench"):
        rows = _read(tmp_path / f"gpu_check_{section}.csv")
        assert rows and all(r["status"] == "skipped" and "budget" in r["note"] for r in rows), section
    assert json.loads((tmp_path / "gpu_check.json").read_text())["passed"] is True


# ------------------------------------------------------------------------------------------------ the judgement
def _run(scores: torch.Tensor, counts: torch.Tensor | None = None, steps: int = 10, horizon: int | None = None,
         grads: dict | None = None) -> Run:
    """A run whose one LIF layer ``lif`` fired ``counts`` over ``steps`` steps of sequences of ``horizon`` steps."""
    if counts is None:
        return Run(scores, grads=grads)
    return Run(scores, {"lif": counts}, {"lif": steps}, {"lif": horizon or steps}, grads)


def test_logits_beyond_the_tolerance_fail() -> None:
    scores = torch.randn(2, 5, generator=torch.Generator().manual_seed(0))
    assert compare_runs(_run(scores), _run(scores + 5e-5))["passed"]
    bad = scores.clone()
    bad[1, 3] += 3e-4
    verdict = compare_runs(_run(scores), _run(bad))
    assert not verdict["passed"] and "scores differ" in verdict["why"]
    assert verdict["max_abs_diff"] == pytest.approx(3e-4, rel=1e-3)
    nan = scores.clone()
    nan[0, 0] = float("nan")
    assert not compare_runs(_run(scores), _run(nan))["passed"]
    assert not compare_runs(_run(scores), _run(scores[:1]))["passed"]  # shapes differ


def test_spikes_differing_by_more_than_one_over_t_fail() -> None:
    """T = 10 steps: one spike more on one neuron (rate 1/10) is allowed, and then the logits are not judged; two
    spikes more (rate 2/10) fail."""
    counts = torch.tensor([[3.0, 0.0, 7.0], [1.0, 1.0, 0.0]], dtype=torch.float64)
    scores = torch.zeros(2, 3)
    same = compare_runs(_run(scores, counts), _run(scores, counts.clone()))
    assert same["passed"] and same["spikes_equal"] and same["spike_rate_diff"] == 0.0
    one = counts.clone()
    one[0, 1] += 1
    verdict = compare_runs(_run(scores, counts), _run(scores + 0.5, one))
    assert verdict["passed"] and verdict["spikes_equal"] is False and "not judged" in verdict["why"]
    assert verdict["spike_rate_diff"] == pytest.approx(0.1) and verdict["spike_rate_limit"] == pytest.approx(0.1)
    two = counts.clone()
    two[1, 2] += 2
    verdict = compare_runs(_run(scores, counts), _run(scores, two))
    assert not verdict["passed"] and "spike-rate mismatch" in verdict["why"]
    assert verdict["spike_rate_diff"] == pytest.approx(0.2)
    # a stream of 20 calls over a 10-step sequence (re-reading an open bin): 2 spikes in 20 calls is the limit
    assert compare_runs(_run(scores, counts, 20, 10), _run(scores, two, 20, 10))["passed"]
    three = two.clone()
    three[1, 2] += 1
    assert not compare_runs(_run(scores, counts, 20, 10), _run(scores, three, 20, 10))["passed"]
    assert not compare_runs(_run(scores, counts), _run(scores))["passed"]  # spiking layers missing on one side


def test_gradients_beyond_the_tolerance_fail() -> None:
    gen = torch.Generator().manual_seed(1)
    grads = {"w": torch.randn(4, 3, generator=gen), "b": torch.randn(3, generator=gen)}
    scores = torch.zeros(1, 3)
    close = {k: v + 1e-5 for k, v in grads.items()}
    assert compare_runs(_run(scores, grads=grads), _run(scores, grads=close))["passed"]
    far = {"w": grads["w"].clone(), "b": grads["b"] * 1.01}
    verdict = compare_runs(_run(scores, grads=grads), _run(scores, grads=far))
    assert not verdict["passed"] and "gradients differ" in verdict["why"] and verdict["grad_rel_diff"] > 1e-3
    assert not compare_runs(_run(scores, grads=grads), _run(scores, grads={"w": grads["w"], "b": None}))["passed"]


# ------------------------------------------------------------------------------------------------ the bench child
def test_bench_cells_that_failed_fail_the_section(tmp_path: Path) -> None:
    out = tmp_path / "out"
    script = ("import json, pathlib, sys; cells = pathlib.Path(sys.argv[1]) / 'cells'; cells.mkdir(parents=True); "
              "[(cells / f'{i}.json').write_text(json.dumps({'status': s})) "
              "for i, s in enumerate(['ok', 'ok', 'skipped', 'failed'])]")
    row = gpu_check.run_bench_command([sys.executable, "-c", script, str(out)], out, timeout=60)
    assert row["status"] == "FAIL" and row["exit_code"] == 0
    assert (row["cells_ok"], row["cells_skipped"], row["cells_failed"]) == (2, 1, 1)


def test_a_bench_over_the_budget_is_stopped(tmp_path: Path) -> None:
    out = tmp_path / "out"
    row = gpu_check.run_bench_command([sys.executable, "-c", "import time; time.sleep(60)"], out, timeout=1)
    assert row["status"] == "timeout" and row["exit_code"] is None and row["wall_s"] < 30
    assert row["cells_ok"] == 0 and "time budget" in row["note"]


def test_bench_command_is_bench_walls_on_the_device() -> None:
    args = gpu_check.bench_command("cuda", Path("/tmp/x"), 4, quick=False, epochs=3)
    assert args[:3] == ["bench", "--models", "all"] and args[args.index("--device") + 1] == "cuda"
    assert args[args.index("--executor") + 1] == "process" and args[args.index("--epochs") + 1] == "3"
    assert "--quick" in gpu_check.bench_command("cuda", Path("/tmp/x"), 4, quick=True, epochs=None)
