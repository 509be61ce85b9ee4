"""matplotlib's ``MPLBACKEND``: a name matplotlib does not know is refused before any work, with one line naming the
variable and the value and exit 2, instead of a traceback from the plots after every cell has run (issue 49,
item 11). Any name matplotlib takes is accepted: the bench draws with Agg whatever it names."""

from __future__ import annotations

from pathlib import Path

import pytest
from forked_bench import run_python

from tactile_zoo._env import check_environment, check_matplotlib_backend
from tactile_zoo.cli import main
from tactile_zoo.errors import ConfigError

BAD = "nonexistent"


def test_the_bench_refuses_an_unknown_backend_before_any_work(monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
                                                            capsys: pytest.CaptureFixture) -> None:
    monkeypatch.setenv("MPLBACKEND", BAD)
    out = tmp_path / "run"
    assert main(["bench", "--models", "sgnet", "--datasets", "sim_evtouch", "--quick", "--out", str(out)]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err.count("\n") == 1
    assert captured.err.startswith("tactile-zoo: error:") and f"MPLBACKEND={BAD!r}" in captured.err
    assert "not a matplotlib backend" in captured.err
    assert not out.exists()  # nothing was done


@pytest.mark.parametrize("value", ["agg", "Agg", "svg", "module://some_package.backend", ""])
def test_names_matplotlib_takes_are_accepted(monkeypatch: pytest.MonkeyPatch, value: str) -> None:
    monkeypatch.setenv("MPLBACKEND", value)
    check_environment()


def test_the_check_runs_where_matplotlib_was_imported_before(monkeypatch: pytest.MonkeyPatch) -> None:
    """In a process that imported matplotlib already (a notebook), matplotlib's own validator is asked."""
    import matplotlib  # noqa: F401

    monkeypatch.setenv("MPLBACKEND", BAD)
    with pytest.raises(ConfigError, match=f"MPLBACKEND={BAD!r}"):
        check_matplotlib_backend()


def test_a_fresh_process_is_refused_and_keeps_no_half_imported_matplotlib(tmp_path: Path) -> None:
    """The first import of matplotlib is where it reads the variable: the refusal leaves no partial modules, so that
    the same process imports matplotlib cleanly once the variable is fixed. The process is forked from the warm
    server of tests/forked_bench.py, which has imported the package but never matplotlib (the child asserts it), not
    started as a new interpreter that imports torch first."""
    code = ("import os, sys\n"
            "from tactile_zoo._env import check_environment\n"
            "from tactile_zoo.errors import ConfigError\n"
            "assert 'matplotlib' not in sys.modules\n"
            "try:\n"
            "    check_environment()\n"
            "except ConfigError as exc:\n"
            "    print('refused:', exc)\n"
            "assert not [m for m in sys.modules if m.startswith('matplotlib')]\n"
            "os.environ['MPLBACKEND'] = 'agg'\n"
            "import matplotlib.pyplot as plt\n"
            "print('backend:', plt.get_backend())\n")
    out, _ = run_python(code, [], tmp_path / "child", MPLBACKEND=BAD)
    assert f"refused: environment variable MPLBACKEND={BAD!r}" in out
    assert "backend: agg" in out
