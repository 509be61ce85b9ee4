"""Environment variables: one boolean parser (1/0, true/false, yes/no, on/off, any case), a refused value stops the
command with one line and exit 2, and every boolean the package reads goes through that parser (issue 38, item 2)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

import tactile_zoo
from tactile_zoo import registry
from tactile_zoo._env import BOOLEAN_VARIABLES, CHOICE_VARIABLES, check_environment, env_choice, env_flag
from tactile_zoo.cli import main
from tactile_zoo.data.guard import TUNING_ENV, in_tuning_mode
from tactile_zoo.errors import ConfigError, TestSplitForbidden

PACKAGE = Path(tactile_zoo.__file__).parent
VAR = "TACTILE_ZOO_TUNING"


@pytest.mark.parametrize("text", ["1", "true", "TRUE", "True", " yes ", "Yes", "on", "ON\n"])
def test_true_words(monkeypatch: pytest.MonkeyPatch, text: str) -> None:
    monkeypatch.setenv(VAR, text)
    assert env_flag(VAR) is True


@pytest.mark.parametrize("text", ["0", "false", "False", " no", "NO", "off"])
def test_false_words(monkeypatch: pytest.MonkeyPatch, text: str) -> None:
    monkeypatch.setenv(VAR, text)
    assert env_flag(VAR, default=True) is False


@pytest.mark.parametrize("text", ["", "   "])
def test_empty_means_unset(monkeypatch: pytest.MonkeyPatch, text: str) -> None:
    monkeypatch.setenv(VAR, text)
    assert env_flag(VAR) is False and env_flag(VAR, default=True) is True
    monkeypatch.delenv(VAR)
    assert env_flag(VAR) is False


@pytest.mark.parametrize("text", ["banana", "maybe", "2", "y", "-1", "truee"])
def test_anything_else_is_refused_naming_the_variable_and_value(monkeypatch: pytest.MonkeyPatch, text: str) -> None:
    monkeypatch.setenv(VAR, text)
    with pytest.raises(ConfigError, match=f"{VAR}={text!r}.*1/0, true/false, yes/no"):
        env_flag(VAR)
    with pytest.raises(ConfigError, match=VAR):
        check_environment()


@pytest.mark.parametrize("text", ["true", "yes", "On"])
def test_tuning_true_turns_tuning_mode_on(monkeypatch: pytest.MonkeyPatch, text: str) -> None:
    monkeypatch.setenv(TUNING_ENV, text)
    assert in_tuning_mode()
    with pytest.raises(TestSplitForbidden):
        tactile_zoo.load_dataset("sim_evtouch", split="test", n_train_per_class=2, n_test_per_class=1)


def test_tuning_false_words_leave_it_off(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(TUNING_ENV, "false")
    assert not in_tuning_mode()


@pytest.mark.parametrize(("name", "value"), [("TACTILE_ZOO_TUNING", "banana"), ("TACTILE_ZOO_NO_PLUGINS", "maybe"),
                                             ("TACTILE_ZOO_STRICT_PLUGINS", "sure"),
                                             ("TACTILE_ZOO_NO_HUGEPAGES", "2"),
                                             ("TACTILE_ZOO_KEEP_DENORMALS", "keep"),
                                             ("TACTILE_ZOO_LIF_BACKEND", "bogus")])
def test_the_cli_refuses_a_bad_value_before_any_work(monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
                                                     capsys: pytest.CaptureFixture, name: str, value: str) -> None:
    monkeypatch.setenv(name, value)
    out = tmp_path / "run"
    assert main(["bench", "--models", "sgnet", "--datasets", "sim_evtouch", "--quick", "--out", str(out)]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err.count("\n") == 1
    assert captured.err.startswith("tactile-zoo: error:") and f"{name}={value!r}" in captured.err
    assert not out.exists()  # nothing was done
    assert main(["list", "models"]) == 2  # every command, not only bench
    capsys.readouterr()


def test_no_plugins_accepts_the_boolean_words(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("TACTILE_ZOO_NO_PLUGINS", "Yes")
    registry.set_plugin_policy()
    assert not registry._enabled()
    monkeypatch.setenv("TACTILE_ZOO_NO_PLUGINS", "off")
    assert registry._enabled()


def test_choice_variables(monkeypatch: pytest.MonkeyPatch) -> None:
    name = "TACTILE_ZOO_LIF_BACKEND"
    monkeypatch.setenv(name, " Torch ")
    assert env_choice(name, CHOICE_VARIABLES[name]) == "torch"
    monkeypatch.setenv(name, "")
    assert env_choice(name, CHOICE_VARIABLES[name]) == "auto"
    monkeypatch.setenv(name, "bogus")
    with pytest.raises(ConfigError, match=r"TACTILE_ZOO_LIF_BACKEND='bogus' must be one of auto, numba, torch"):
        env_choice(name, CHOICE_VARIABLES[name])


#: environment reads that are not booleans or choices, each parsed (and checked) where it is used
OTHER_READS = ("TACTILE_ZOO_DATA", "TACTILE_ZOO_CACHE", "MAX_INPUT_ENV", "url_env", "OMP_NUM_THREADS",
               "MLFLOW_ALLOW_FILE_STORE")


def test_every_environment_read_goes_through_the_one_parser() -> None:
    """The class, not the reproduction: a new ``os.environ.get("TACTILE_ZOO_X") == "1"`` fails here."""
    stray = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if path.name == "_env.py":
            continue
        for number, line in enumerate(path.read_text().splitlines(), 1):
            if re.search(r"os\.environ|os\.getenv", line) and not any(name in line for name in OTHER_READS):
                stray.append(f"{path.relative_to(PACKAGE)}:{number}: {line.strip()}")
    assert stray == [], "read boolean and choice variables with tactile_zoo._env.env_flag / env_choice"
    named = set()
    for path in sorted(PACKAGE.rglob("*.py")):
        named |= set(re.findall(r"env_flag\(\s*[\"'](\w+)[\"']", path.read_text()))
    assert named <= set(BOOLEAN_VARIABLES), "list every boolean variable in BOOLEAN_VARIABLES (checked up front)"
