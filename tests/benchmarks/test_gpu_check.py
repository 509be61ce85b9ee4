"""benchmarks/gpu_check.py, the prepared command for a GPU machine: it skips cleanly without CUDA, runs the parity
tests (CPU against CPU with --allow-cpu) and the suite's benchmarks as child processes, and reports a failing or
overlong step. CPU only; the comparison itself is tested in tests/gpu/test_parity_helpers.py."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
import torch
from forked_bench import finish_python

REPO = Path(__file__).resolve().parents[2]
if str(REPO) not in sys.path:  # benchmarks/ is a top-level package of the checkout, not of the installed wheel
    sys.path.insert(0, str(REPO))

from benchmarks import BENCHMARKS, bench_wall, common, gpu_check, run  # noqa: E402


def _summary(out: Path) -> dict[str, Any]:
    return json.loads((out / "gpu_check.json").read_text())


# ``python -m pytest ARGV`` from the repository root, in a child forked from the warm server of tests/forked_bench.py
_PYTEST = "import os, sys, pytest; os.chdir(sys.argv[1]); sys.exit(pytest.main(sys.argv[2:]))"


def _forked_step(command: list[str], log: Path, timeout: float, env: dict[str, str] | None = None
                 ) -> dict[str, Any]:
    """:func:`gpu_check.run_step` for a ``python -m pytest`` step, the child forked from the warm server (torch and
    the package imported: an interpreter's start-up was 3 of the child's 8 CPU seconds) with the step's environment;
    ``run_step`` itself, a process group of its own, is tested below (and by the failing parity test's real child)."""
    assert command[:3] == [sys.executable, "-m", "pytest"], command
    start = time.perf_counter()
    code, out, err = finish_python(_PYTEST, [str(REPO), *command[3:]], log, timeout, **(env or {}))
    return {"status": "ok" if code == 0 else "FAIL", "exit_code": code,
            "seconds": round(time.perf_counter() - start, 1), "note": "" if code == 0 else (out + err)[-600:]}


# ------------------------------------------------------------------------------------------------ without CUDA
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
    assert len(err) == 1 and "missing package 'snntorch'" in err[0] and "pytest" in err[0]


# ------------------------------------------------------------------------------------------------ the parity step
def test_allow_cpu_runs_the_parity_tests_cpu_against_cpu(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The real test file in a child pytest (forked: :func:`_forked_step`), the device side on the CPU: the selected
    tests ran (not skipped: the step's environment says ``cpu``) and passed, and their measurements are in the JUnit
    XML."""
    monkeypatch.setattr(gpu_check, "run_step", _forked_step)
    assert gpu_check.main(["--allow-cpu", "--only", "parity", "--models", "dcnn,tacformer", "--datasets",
                           "sim_biotac_slip", "--out", str(tmp_path)]) == 0
    [row] = _summary(tmp_path)["steps"]
    # the two models' CUDA-graph tests skip: graphs are recorded on a GPU only
    assert (row["step"], row["status"], row["tests"], row["failed"], row["skipped"]) == ("parity", "ok", 4, 0, 2)
    xml = (tmp_path / "gpu_check_parity.xml").read_text()
    assert "test_cuda_matches_cpu[tacformer-sim_biotac_slip]" in xml and "x_tacformer" not in xml
    assert '<property name="stream"' in xml and "&quot;max_abs_diff&quot;: 0.0" in xml


def test_a_failing_parity_test_fails_the_command(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    tests = tmp_path / "test_planted.py"
    tests.write_text("def test_agrees():\n    pass\n\n\ndef test_differs():\n    assert 1 == 2\n")
    monkeypatch.setattr(gpu_check, "PARITY_TESTS", str(tests))
    graphs = tmp_path / "test_planted_graphs.py"
    graphs.write_text("def test_replays():\n    pass\n")
    monkeypatch.setattr(gpu_check, "GRAPH_TESTS", str(graphs))
    out = tmp_path / "out"
    assert gpu_check.main(["--allow-cpu", "--only", "parity", "--out", str(out)]) == 1
    summary = _summary(out)
    assert summary["passed"] is False and summary["failed"] == ["parity"]
    [row] = summary["steps"]
    assert (row["status"], row["exit_code"], row["tests"], row["failed_tests"]) == ("FAIL", 1, 3, ["test_differs"])


def test_parity_nodes_name_each_model_exactly() -> None:
    nodes = gpu_check.parity_nodes(["tacformer", "dcnn"], ["sim_evtouch", "sim_biotac_slip"])
    assert nodes[0] == "tests/gpu/test_cuda_parity.py::test_cuda_matches_cpu[tacformer-sim_evtouch]"
    assert [n.split("[")[1] for n in nodes] == ["tacformer-sim_evtouch]", "dcnn-sim_evtouch]",
                                                "tacformer-sim_biotac_slip]", "dcnn-sim_biotac_slip]",
                                                "tacformer]", "dcnn]"]
    assert nodes[-1] == "tests/gpu/test_cuda_graph_training.py::test_a_graph_replay_matches_the_eager_step[dcnn]"
    assert (REPO / gpu_check.PARITY_TESTS).exists() and (REPO / gpu_check.GRAPH_TESTS).exists()


# ------------------------------------------------------------------------------------------------ the suite steps
def test_the_suite_steps_are_benchmarks_run_on_the_device(tmp_path: Path) -> None:
    """Each suite step is a command line that the suite's own runner accepts, for a benchmark it has."""
    assert set(gpu_check.SUITE) <= set(BENCHMARKS)
    command = gpu_check.suite_command("bench_wall", "cuda", tmp_path, 4, quick=True)
    assert command[:3] == [sys.executable, "-m", "benchmarks.run"]
    args = run._parser().parse_args(command[3:])
    assert (args.only, args.device, args.threads, args.out, args.quick) == ("bench_wall", "cuda", 4, tmp_path, True)
    assert "--quick" not in gpu_check.suite_command("inference", "cuda", tmp_path, 4, quick=False)


def test_main_runs_every_step_in_order_and_a_failed_one_fails_it(tmp_path: Path,
                                                                monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[tuple[list[str], dict[str, str]]] = []

    def fake(command: list[str], log: Path, timeout: float, env: dict[str, str] | None = None) -> dict[str, Any]:
        calls.append((command, env or {}))
        for arg in command:  # the parity step's pytest writes its JUnit XML
            if arg.startswith("--junitxml="):
                Path(arg.split("=", 1)[1]).write_text('<testsuite><testcase name="test_cuda_matches_cpu[a-b]"/>'
                                                      '</testsuite>')
        failed = "epoch_all_models" in command
        return {"status": "FAIL" if failed else "ok", "exit_code": int(failed), "seconds": 0.0, "note": ""}

    monkeypatch.setattr(gpu_check, "run_step", fake)
    assert gpu_check.main(["--allow-cpu", "--out", str(tmp_path), "--threads", "2"]) == 1
    assert [c[c.index("--only") + 1] for c, _ in calls[1:]] == ["gpu_epoch", "inference", "epoch_all_models",
                                                                 "bench_wall"]
    assert calls[0][0][1:3] == ["-m", "pytest"]  # the whole files
    assert calls[0][0][-2:] == [gpu_check.PARITY_TESTS, gpu_check.GRAPH_TESTS]
    assert all(c[c.index("--device") + 1] == "cpu" and "--quick" not in c for c, _ in calls[1:])
    env = calls[0][1]
    assert env["TACTILE_ZOO_PARITY_DEVICE"] == "cpu" and env["BENCH_WALL_EPOCHS"] == "3"
    assert env["PYTHONPATH"].split(os.pathsep)[0] == str(REPO)
    summary = _summary(tmp_path)
    assert summary["failed"] == ["epoch_all_models"] and [r["status"] for r in summary["steps"]] == [
        "ok", "ok", "ok", "FAIL", "ok"]
    assert (summary["steps"][0]["tests"], summary["steps"][0]["failed"]) == (1, 0)
    assert (tmp_path / "gpu_check_parity.xml").exists()  # the later steps leave the parity results alone
    calls.clear()
    assert gpu_check.main(["--allow-cpu", "--quick", "--skip", "parity", "--out", str(tmp_path / "q")]) == 1
    assert len(calls) == 4 and all("--quick" in c for c, _ in calls) and "BENCH_WALL_EPOCHS" not in calls[0][1]


def test_a_spent_budget_skips_every_step_with_a_note(tmp_path: Path) -> None:
    stale = tmp_path / "gpu_check_parity.xml"  # an earlier run's results, which must not count for this one
    stale.write_text('<testsuite><testcase name="old"/></testsuite>')
    assert gpu_check.main(["--allow-cpu", "--timeout", "0", "--out", str(tmp_path)]) == 0
    assert not stale.exists() and "tests" not in _summary(tmp_path)["steps"][0]
    summary = _summary(tmp_path)
    assert [r["step"] for r in summary["steps"]] == list(gpu_check.STEPS)
    assert all(r["status"] == "skipped" and "budget" in r["note"] for r in summary["steps"])
    assert summary["passed"] is True and summary["skipped"] == list(gpu_check.STEPS)


def _alive(pid: int) -> bool:
    """Whether process ``pid`` still runs (a killed process not yet reaped by its new parent is a zombie)."""
    try:
        return Path(f"/proc/{pid}/status").read_text().split("State:")[1].split()[0] != "Z"
    except (OSError, IndexError):
        return False


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="reads process states from /proc (Linux)")
def test_a_step_over_its_time_is_stopped_with_its_children(tmp_path: Path) -> None:
    """The step starts a grandchild (as benchmarks.run starts bench children) and sleeps; when its time is up both
    are stopped, as the whole process group is."""
    pid_file = tmp_path / "grandchild.pid"
    # -S: no site packages, so both interpreters start in tens of milliseconds, well within the 2 s the step has
    script = ("import os, subprocess, sys, time; "
              "p = subprocess.Popen([sys.executable, '-S', '-c', 'import time; time.sleep(120)']); "
              f"open({str(pid_file)!r}, 'w').write(str(p.pid)); time.sleep(120)")
    row = gpu_check.run_step([sys.executable, "-S", "-c", script], tmp_path / "step.log", timeout=2)
    assert row["status"] == "timeout" and row["exit_code"] is None and "time budget" in row["note"]
    assert pid_file.exists(), "the step did not start its grandchild within its time; nothing was checked"
    grandchild = int(pid_file.read_text())
    for _ in range(100):  # SIGKILL is delivered asynchronously: give it a moment to land
        if not _alive(grandchild):
            break
        time.sleep(0.1)
    assert not _alive(grandchild)


def test_a_step_that_exits_nonzero_fails_with_its_output(tmp_path: Path) -> None:
    row = gpu_check.run_step([sys.executable, "-c", "print('broken here'); raise SystemExit(3)"], tmp_path / "s.log",
                             timeout=60)
    assert (row["status"], row["exit_code"]) == ("FAIL", 3) and "broken here" in row["note"]
    assert "broken here" in (tmp_path / "s.log").read_text()


def test_bench_wall_takes_its_epochs_from_the_environment(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    ctx = common.Context(device=torch.device("cpu"), threads=4, out=tmp_path, log=lambda _msg: None)
    monkeypatch.delenv("BENCH_WALL_EPOCHS", raising=False)
    assert "--epochs" not in bench_wall.bench_args(ctx, tmp_path)
    monkeypatch.setenv("BENCH_WALL_EPOCHS", "3")
    args = bench_wall.bench_args(ctx, tmp_path)
    assert args[args.index("--epochs") + 1] == "3" and args[args.index("--workers") + 1] == "4"
    assert args[:3] == ["bench", "--models", "all"] and args[args.index("--device") + 1] == "cpu"
