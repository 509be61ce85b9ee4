"""Where a cell's configuration goes, from the command line to the training loop: through few files, once each.

One real cell (SGnet on the simulated Ev-Touch, ``--quick``, one epoch) runs in this process through
``tactile-zoo bench``. Every construction of a configuration object (:class:`BenchConfig`, :class:`CellConfig`,
:class:`Recipe`) and every read of one of its fields is attributed to the package file whose code did it; the
objects' own methods (``validate``, ``to_dict``, ``hashed``...) count for the code that called them. Of a
``BenchConfig`` only the settings that make up a cell's configuration are followed (:data:`CELL_SETTINGS`); the
others say where and how cells run (executor, threads, output folder, which models and seeds) and no cell hash
covers them. The trace stops when the training loop starts its first epoch.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Iterator
from pathlib import Path
from types import FrameType
from typing import Any

import pytest

from tactile_zoo.bench.config import BenchConfig
from tactile_zoo.cli import main
from tactile_zoo.engine import train
from tactile_zoo.engine.config import CellConfig, config_hash
from tactile_zoo.recipe import Recipe

PACKAGE = Path(__file__).resolve().parents[2] / "tactile_zoo"
TRACKED = (BenchConfig, CellConfig, Recipe)
#: the BenchConfig settings that become a cell's configuration (every other setting says where and how cells run)
CELL_SETTINGS = frozenset({"recipe", "recipe_name", "hparams", "model_overrides", "dataset_kwargs", "epochs",
                           "quick", "refit", "prefixes", "evaluation", "model_revisions"})
MAX_FILES = 5


def _own(frame: FrameType) -> bool:
    """Whether ``frame`` runs a method of a configuration class (its reads are its caller's)."""
    local = frame.f_locals
    me = local.get("self", local.get("cls"))
    return isinstance(me, TRACKED) or (isinstance(me, type) and issubclass(me, TRACKED))


def _where(frame: FrameType | None) -> str | None:
    """The package file of the nearest frame that is not a configuration class's own method (nor library code)."""
    while frame is not None:
        path = Path(frame.f_code.co_filename)
        if path.is_relative_to(PACKAGE) and not _own(frame):
            return path.relative_to(PACKAGE.parent).as_posix()
        frame = frame.f_back
    return None


class Tracer:
    def __init__(self) -> None:
        self.on = False
        self.events: list[tuple[str, str, str]] = []  # (file, class, field or "built")

    def note(self, obj: Any, what: str) -> None:
        if self.on:
            where = _where(sys._getframe(2))
            if where is not None:
                self.events.append((where, type(obj).__name__, what))

    def path(self) -> list[str]:
        """The files in the order the configuration reached them, consecutive events in one file merged."""
        out: list[str] = []
        for where, _, _ in self.events:
            if not out or out[-1] != where:
                out.append(where)
        return out


@pytest.fixture
def tracer(monkeypatch: pytest.MonkeyPatch) -> Iterator[Tracer]:
    traced = Tracer()
    for cls in TRACKED:
        followed = CELL_SETTINGS if cls is BenchConfig else frozenset(f for f in cls.__dataclass_fields__)
        init, getattribute = cls.__init__, cls.__getattribute__

        def built(self: Any, *args: Any, _init: Any = init, **kwargs: Any) -> None:
            traced.note(self, "built")
            _init(self, *args, **kwargs)

        def read(self: Any, name: str, _get: Any = getattribute, _followed: frozenset = followed) -> Any:
            if name in _followed:
                traced.note(self, name)
            return _get(self, name)

        monkeypatch.setattr(cls, "__init__", built)
        monkeypatch.setattr(cls, "__getattribute__", read)
    epoch = train._Trainer.epoch

    def first_epoch(self: Any, index: int) -> float:
        traced.on = False  # the training loop has the configuration: the trace ends here
        return epoch(self, index)

    monkeypatch.setattr(train._Trainer, "epoch", first_epoch)
    yield traced


def test_the_configuration_reaches_the_training_loop_through_five_files_once_each(tracer: Tracer,
                                                                                  tmp_path: Path) -> None:
    tracer.on = True
    code = main(["bench", "--models", "sgnet", "--datasets", "sim_evtouch", "--quick", "--epochs", "1",
                 "--seeds", "0", "--threads", "1", "--no-plots", "-q", "--set", "lr=0.002", "--out",
                 str(tmp_path / "run")])
    assert code == 0
    path = tracer.path()
    assert path[0] == "tactile_zoo/bench/config.py" and path[-1] == "tactile_zoo/engine/train.py", path
    assert len(path) == len(set(path)), f"the configuration went back to a file it had left: {path}"
    assert len(path) <= MAX_FILES, path
    built = [(where, cls) for where, cls, what in tracer.events if what == "built"]
    # resolved once: one BenchConfig, one CellConfig and one Recipe, all before the worker runs the cell
    assert sorted(cls for _, cls in built) == ["BenchConfig", "CellConfig", "Recipe"], built
    assert {where for where, cls in built if cls != "BenchConfig"} == {"tactile_zoo/engine/config.py"}
    (record,) = [json.loads(p.read_text()) for p in (tmp_path / "run" / "cells").glob("*.json")]
    assert record["config"]["recipe"]["lr"] == 0.002 and record["config"]["recipe"]["max_epochs"] == 1
    assert record["config_hash"] == config_hash(record["config"])


def test_the_trace_sees_a_second_resolution(tracer: Tracer) -> None:
    """The trace can fail: a worker that reads the configuration and resolves it again (what workers once did,
    rebuilding it from a dict) sends it back to a file it had left."""
    from tactile_zoo.engine.config import resolve_cell

    tracer.on = True
    config = resolve_cell("sgnet", "sim_evtouch", quick=True)
    assert tracer.path() == ["tactile_zoo/engine/config.py"]
    # these lines run as if written in bench/worker.py (its file name is what the trace attributes them to)
    code = compile("again = resolve_cell(config.model, config.dataset, quick=config.subset is not None)",
                   str(PACKAGE / "bench" / "worker.py"), "exec")
    scope = {"config": config, "resolve_cell": resolve_cell}
    exec(code, scope)  # noqa: S102
    assert scope["again"] == config
    assert tracer.path() == ["tactile_zoo/engine/config.py", "tactile_zoo/bench/worker.py",
                             "tactile_zoo/engine/config.py"]
