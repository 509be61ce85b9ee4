"""The ``tactile-zoo`` command line, called in-process through ``main(argv) -> int``.

Models and datasets the tests need are registered here under ``zt_`` names and removed afterwards, so nothing depends
on which built-ins exist (only on the four built-in sensors).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from fake_plugins import GOOD_MODULE, FakeSite, forget_test_registrations, snapshot, unique

import tactile_zoo
from tactile_zoo import registry
from tactile_zoo.cli import main
from tactile_zoo.data import DatasetSpec
from tactile_zoo.errors import UnknownNameError
from tactile_zoo.registry import get_sensor, register_dataset, register_model


@pytest.fixture(autouse=True)
def _clean_registry():
    before = snapshot()
    yield
    forget_test_registrations(before)
    registry.reset_plugins()


@pytest.fixture
def zoo():
    """One local model and one local dataset (sizes 6/2/4 per split) under fresh names."""
    model, dataset = unique("cli_model"), unique("cli_set")

    class Net(torch.nn.Module):
        def __init__(self, spec: DatasetSpec, hidden: int = 5) -> None:
            super().__init__()
            self.body = torch.nn.Linear(spec.num_nodes * spec.num_channels, hidden)
            self.head = torch.nn.Linear(hidden, spec.num_classes)

        def forward(self, x: torch.Tensor, g: torch.Tensor | None = None) -> torch.Tensor:
            return self.head(self.body(x.mean(1).flatten(1)))

    register_model(model, paper="A CLI paper", year=2022, tags=["graph", "spiking"], inputs=["graph"],
                   recipe={"loss": "ce", "optimizer": "adam", "lr": 0.01})(Net)

    class Set(torch.utils.data.Dataset):
        num_folds = 1
        sizes = {"train": 6, "val": 2, "test": 4, None: 12}

        def __init__(self, root=None, split=None, fold=0, download=False):
            self.spec = DatasetSpec(dataset, 2, ("left", "right"), 7, 39, 2, 0, get_sensor("neutouch"))
            self.n = self.sizes[split]

        def __len__(self) -> int:
            return self.n

    register_dataset(dataset, sensor="neutouch", num_classes=2, description="A CLI test set")(Set)
    return model, dataset


def _lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.strip()]


def test_list_models_with_pattern_and_tags(zoo, capsys):
    model, _ = zoo
    assert main(["list", "models"]) == 0
    out = capsys.readouterr().out
    [line] = [line for line in _lines(out) if line.split()[0] == model]
    assert "graph, spiking" in line and "A CLI paper" in line
    assert main(["list", "models", "zt_cli_model*", "--tags", "graph,spiking"]) == 0
    assert [line.split()[0] for line in _lines(capsys.readouterr().out)] == [model]
    assert main(["list", "models", "zt_cli_model*", "--tags", "attention"]) == 0
    out, err = capsys.readouterr()
    assert out == "" and "no models match" in err


def test_list_datasets_and_sensors(zoo, capsys):
    _, dataset = zoo
    assert main(["list", "datasets", "ZT-CLI-SET*"]) == 0
    [line] = _lines(capsys.readouterr().out)
    assert line.split()[:3] == [dataset, "neutouch", "2"] and "A CLI test set" in line
    assert main(["list", "sensors"]) == 0
    rows = {line.split()[0]: line for line in _lines(capsys.readouterr().out)}
    assert {"neutouch", "biotac_sp", "optoforce3", "uskin_allegro"} <= set(rows)
    assert " 39 taxels" in rows["neutouch"] and " 24 taxels" in rows["biotac_sp"] and "grid 12x11" in rows["biotac_sp"]
    assert " 60 taxels" in rows["uskin_allegro"] and "grid 6x12" in rows["uskin_allegro"]


def test_info_sensor(capsys):
    assert main(["info", "NeuTouch", "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["kind"] == "sensor" and info["name"] == "neutouch" and info["taxels"] == 39
    assert info["default_graph"] == "edges" and info["edges"] == 38 and info["channels"] == ["on", "off"]
    assert main(["info", "biotac_sp"]) == 0
    rows = {line.split()[0]: line.split(None, 1)[1] for line in _lines(capsys.readouterr().out)}
    assert rows["kind"] == "sensor" and rows["taxels"] == "24" and rows["grid_shape"] == "[12, 11]"


def test_info_model_reports_metadata_and_parameter_count(zoo, capsys):
    model, dataset = zoo
    assert main(["info", model, "--dataset", dataset, "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["kind"] == "model" and info["name"] == model and info["paper"] == "A CLI paper"
    assert info["tags"] == ["graph", "spiking"] and info["recipe"]["lr"] == 0.01
    assert info["built_for"] == dataset
    assert info["parameters"] == (78 * 5 + 5) + (5 * 2 + 2)  # Linear(39*2 -> 5) + Linear(5 -> 2)


def test_info_dataset_reports_spec_and_split_sizes(zoo, capsys):
    _, dataset = zoo
    assert main(["info", dataset, "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["kind"] == "dataset" and info["sensor"] == "neutouch" and info["num_folds"] == 1
    assert info["spec"]["class_names"] == ["left", "right"] and info["spec"]["num_steps"] == 7
    assert info["samples"] == 12 and info["split_sizes_fold0"] == {"train": 6, "val": 2, "test": 4}


def test_plugins_lists_each_entry_with_status(tmp_path: Path, monkeypatch, capsys):
    site = FakeSite(tmp_path, monkeypatch)
    try:
        good, broken = unique("cli_plug"), unique("cli_broken")
        module = site.add("zt-cli-good", GOOD_MODULE, models={good: "Net"}, version="2.5")
        site.add("zt-cli-broken", "import zt_cli_missing_dependency\n", models={broken: "Net"})
        assert main(["plugins"]) == 0
        out, err = capsys.readouterr()
        rows = {line.split()[0]: line for line in _lines(out)}
        assert rows["zt-cli-good"].split()[:3] == ["zt-cli-good", "2.5", "tactile_zoo.models"]
        assert f"{good} = {module}:Net" in rows["zt-cli-good"] and rows["zt-cli-good"].endswith("[ok]")
        assert "[failed]" in rows["zt-cli-broken"] and "zt_cli_missing_dependency" in rows["zt-cli-broken"]
        assert "warning" in err and "zt-cli-broken" in err
        assert main(["--no-plugins", "plugins"]) == 0
        assert capsys.readouterr().out.strip() == "no tactile-zoo plugins installed (discovery disabled)"
    finally:
        site.close()


@pytest.mark.parametrize("argv, suggestion", [
    (["info", "neutuch"], "'neutouch'"),
    (["info", "zt_cli_modle"], "'zt_cli_model"),
    (["list", "modles"], "invalid choice"),
    (["info", "neutouch", "--bogus"], "unrecognized arguments"),
])
def test_bad_input_is_one_line_and_exit_2(zoo, capsys, argv, suggestion):
    if argv[1] == "zt_cli_modle":  # a typo of the fixture's model name
        argv = ["info", zoo[0].replace("model", "modle")]
    assert main(argv) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1 and err.startswith("tactile-zoo: error:")
    assert suggestion in err


def test_unknown_name_error_lists_every_kind(capsys):
    assert main(["info", "zt_nothing_like_it"]) == 2
    err = capsys.readouterr().err
    assert "not a model, dataset or sensor" in err and "sensors: biotac_sp, neutouch, optoforce3, uskin_allegro" in err


def test_debug_shows_the_traceback():
    with pytest.raises(UnknownNameError, match="neutouch"):
        main(["--debug", "info", "neutuch"])


def test_version(capsys):
    assert main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"tactile-zoo {tactile_zoo.__version__}"


def test_console_script_is_installed():
    script = Path(sys.executable).with_name("tactile-zoo")
    if not script.exists():
        pytest.skip(f"no console script next to {sys.executable} (package not pip-installed)")
    proc = subprocess.run([str(script), "--version"], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0 and proc.stdout.strip() == f"tactile-zoo {tactile_zoo.__version__}"


@pytest.mark.parametrize("argv", [["list", "models"], ["info", "dcnn"]])
def test_a_reader_that_closes_the_pipe_ends_the_command_quietly(argv: list[str]) -> None:
    """Issue 28: ``tactile-zoo weights | head -1`` printed a BrokenPipeError traceback. The pipe's read end is closed
    before the command starts, so its first line already meets a closed pipe (as ``head -1`` leaves it, without the
    race of waiting for head): no output on stderr, status 141 as for a command killed by SIGPIPE. A new interpreter
    each (its exit flushes stdout: where the traceback was printed); ``info`` of D-CNN, which builds without PyG
    (``info sgnet`` imported it: 6.4 CPU-s against 3.0)."""
    import os

    read_end, write_end = os.pipe()
    os.close(read_end)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(Path(tactile_zoo.__file__).resolve().parents[1]),
                                                        os.environ.get("PYTHONPATH", "")])}
    try:
        proc = subprocess.run([sys.executable, "-m", "tactile_zoo.cli", *argv], stdout=write_end,
                              stderr=subprocess.PIPE, text=True, timeout=300, env=env)
    finally:
        os.close(write_end)
    assert proc.stderr == "" and proc.returncode == 141
