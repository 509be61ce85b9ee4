"""Issue 49, ``tactile-zoo train --save`` and the checkpoints it writes: the output-file ownership rule of
:mod:`tactile_zoo._owned` (a new file or a checkpoint it wrote; never a user's file, a link, a device, a FIFO or a
folder; an empty path refused; all before training), a full disk as one line with nothing left behind, ``evaluate``'s
one-line refusal of files that are not checkpoints, and the test figures of a ``--quick`` run named as a subset's."""

from __future__ import annotations

import json
import os
import resource
import stat
import textwrap
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import tiny_zoo
import torch
from forked_bench import run_python

from tactile_zoo.cli import main
from tactile_zoo.engine import load_checkpoint
from tactile_zoo.engine.checkpoint import is_checkpoint

TRAIN = ["train", "tiny_mlp", "tiny_blobs", "--plugin-module", "tiny_zoo", "--epochs", "1", "-q"]


@pytest.fixture(autouse=True)
def tiny() -> Iterator[None]:
    """The tiny zoo registered for each test: ``--plugin-module tiny_zoo`` is a no-op once another test module has
    imported it (and may have unregistered its models since)."""
    tiny_zoo.register()
    yield
    tiny_zoo.unregister()


@pytest.fixture()
def no_training(monkeypatch: pytest.MonkeyPatch) -> None:
    """Training fails the test: a refused path must be refused before any work."""
    from tactile_zoo.engine import cell

    def fail(*args: object, **kwargs: object) -> None:
        raise AssertionError("trained before the --save path was checked")

    monkeypatch.setattr(cell, "train_cell", fail)


def _refused(argv: list[str], capsys: pytest.CaptureFixture) -> str:
    assert main(argv) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1 and "Traceback" not in err
    return err


def test_save_refuses_what_it_does_not_own_before_training(tmp_path: Path, no_training: None,
                                                           capsys: pytest.CaptureFixture) -> None:
    mine = tmp_path / "notmine.txt"
    mine.write_text("a user's notes\n")
    assert "--save: an empty path names no file" in _refused([*TRAIN, "--save", ""], capsys)
    err = _refused([*TRAIN, "--save", str(mine)], capsys)
    assert f"--save {mine}: the file exists and is not a tactile-zoo checkpoint" in err
    assert mine.read_text() == "a user's notes\n"
    fifo = tmp_path / "pipe.pt"
    os.mkfifo(fifo)
    assert "it is a FIFO" in _refused([*TRAIN, "--save", str(fifo)], capsys)
    link = tmp_path / "link.pt"
    link.symlink_to(mine)
    assert "it is a symbolic link" in _refused([*TRAIN, "--save", str(link)], capsys)
    assert "it is a folder" in _refused([*TRAIN, "--save", str(tmp_path)], capsys)
    assert "cannot write there" in _refused([*TRAIN, "--save", str(mine / "x.pt")], capsys)
    if Path("/dev/null").exists():  # as root, replacing it with a regular file would break the machine
        assert "--save /dev/null: it is a character device" in _refused([*TRAIN, "--save", "/dev/null"], capsys)
        assert stat.S_ISCHR(os.stat("/dev/null").st_mode)
    assert mine.read_text() == "a user's notes\n" and stat.S_ISFIFO(os.lstat(fifo).st_mode) and link.is_symlink()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link.pt", "notmine.txt", "pipe.pt"]  # no temporaries


def test_save_writes_a_new_file_and_replaces_its_own_checkpoint(tmp_path: Path, capsys: pytest.CaptureFixture
                                                                ) -> None:
    path = tmp_path / "sub" / "model.pt"
    assert main([*TRAIN, "--save", str(path)]) == 0
    assert is_checkpoint(path) and f"saved {path}" in capsys.readouterr().out
    first = path.read_bytes()
    assert main([*TRAIN, "--save", str(path), "--seed", "1"]) == 0  # its own checkpoint: replaced
    assert path.read_bytes() != first and load_checkpoint(path)["config"]["seed"] == 1
    assert sorted(p.name for p in path.parent.iterdir()) == ["model.pt"]


_SPLIT = "--- next run ---"


def _limited(runs: list[tuple[list[str], int | None]], log: Path) -> tuple[list[int], list[str], list[list[Any]]]:
    """Each ``tactile-zoo ARGV`` of ``runs`` in turn, in one child process forked from the warm server of
    tests/forked_bench.py (the package imported: an interpreter's start-up is most of a run's cost), its files not
    allowed to grow beyond ``limit`` bytes (a full disk, as ``ulimit -f`` makes one; Python ignores SIGXFSZ, so a
    write past it fails with EFBIG), or without a limit where it is None. Each run's exit status, its stderr, and the
    names in the ``--save`` path's folder and that file's sha256 after it. The child's stdout and stderr are files
    (``log``, in another folder), under the limit too: what it prints stays far below 4 KiB."""
    code = textwrap.dedent(f"""
        import hashlib, json, os, resource, sys
        from tactile_zoo.cli import main
        for argv, limit in {runs!r}:
            soft = resource.RLIM_INFINITY if limit is None else limit
            resource.setrlimit(resource.RLIMIT_FSIZE, (soft, resource.RLIM_INFINITY))
            code = main(argv)
            save = argv[argv.index("--save") + 1]
            digest = hashlib.sha256(open(save, "rb").read()).hexdigest() if os.path.exists(save) else None
            print(json.dumps([code, sorted(os.listdir(os.path.dirname(save))), digest]), flush=True)
            print({_SPLIT!r}, file=sys.stderr, flush=True)
    """)
    out, err = run_python(code, [], log)
    results = [json.loads(line) for line in out.splitlines() if line.startswith("[")]
    errors = err.split(_SPLIT + "\n")
    assert len(results) == len(runs) and len(errors) == len(runs) + 1 and errors[-1] == "", (out, err)
    return [r[0] for r in results], errors[:-1], [r[1:] for r in results]


@pytest.mark.skipif(not hasattr(resource, "RLIMIT_FSIZE"), reason="no file size limit on this platform")
def test_a_full_disk_is_one_line_naming_the_path_and_leaves_nothing(tmp_path: Path,
                                                                   tmp_path_factory: pytest.TempPathFactory) -> None:
    path = tmp_path / "model.pt"
    codes, errors, listings = _limited([([*TRAIN, "--save", str(path)], 4096),
                                        ([*TRAIN, "--save", str(path)], None),
                                        ([*TRAIN, "--save", str(path), "--seed", "1"], 4096)],  # replacing its own
                                       tmp_path_factory.mktemp("full-disk-logs") / "child")
    assert codes[0] == 2, errors[0]
    assert errors[0].splitlines() == [f"tactile-zoo: error: --save {path}: cannot write the checkpoint (File too "
                                      f"large); nothing was written there"]
    assert listings[0] == [[], None]
    assert codes[1] == 0 and listings[1][0] == ["model.pt"] and is_checkpoint(path), errors[1]
    assert codes[2] == 2 and "cannot write the checkpoint" in errors[2]
    assert listings[2] == listings[1]  # the checkpoint as it was, byte for byte, and nothing beside it


def test_evaluate_names_a_file_that_is_not_a_checkpoint_in_one_line(tmp_path: Path,
                                                                    capsys: pytest.CaptureFixture) -> None:
    text = tmp_path / "notes.txt"
    text.write_text("hello\n")
    array = tmp_path / "grasp.npy"
    np.save(array, np.zeros((3, 4)))
    empty = tmp_path / "empty.pt"
    empty.touch()
    for path, what in ((text, "it is a text file"), (array, "it is a NumPy .npy array"), (empty, "it is empty")):
        err = _refused(["evaluate", str(path)], capsys)
        assert err.startswith(f"tactile-zoo: error: checkpoint {path} is not a tactile-zoo checkpoint: {what}")
    torch.save({"format": "tactile-zoo-checkpoint/1"}, tmp_path / "cut.pt")
    cut = tmp_path / "cut.pt"
    cut.write_bytes(cut.read_bytes()[:-40])  # a truncated zip
    err = _refused(["evaluate", str(cut)], capsys)
    assert f"checkpoint {cut} cannot be loaded safely: torch.load refused it" in err and len(err) < 300


def test_a_quick_run_says_its_test_figures_are_a_subsets(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    assert main([*TRAIN, "--quick"]) == 0
    out = capsys.readouterr().out
    assert ("note: a --quick run: test figures on 24 test samples (at most 64 per split, class-balanced), after "
            "training on at most 64; not comparable with the leaderboard's") in out
    assert main([*TRAIN, "--quick", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["subset"] == {"train": 64, "val": 32, "test": 64} and summary["test"]["n"] == 24
    assert main(TRAIN) == 0
    assert "subset" not in capsys.readouterr().out


def test_a_train_says_how_many_test_samples_were_ties(monkeypatch: pytest.MonkeyPatch,
                                                      capsys: pytest.CaptureFixture) -> None:
    """Issue 49 item 6: a model that names no class (all rates 0 after one quick epoch: p 1/K each) got "test
    accuracy 0.1094" without a word; the figure stays argmax's (as published cells), and the output says so."""
    from tactile_zoo.engine import cell

    real = cell.train_cell

    def silent(*args: object, **kwargs: object) -> object:
        outcome = real(*args, **kwargs)
        test = outcome.tests["test"]
        k = len(test.probabilities[0])
        test.probabilities = [[1.0 / k] * k for _ in test.probabilities[:5]] + test.probabilities[5:]
        return outcome

    monkeypatch.setattr(cell, "train_cell", silent)
    assert main(TRAIN) == 0
    assert ("note: 5 of 24 test samples are ties (several classes share the top score: the model named no class); "
            "the test figures count each as argmax's pick") in capsys.readouterr().out
    assert main([*TRAIN, "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["test_ties"] == 5
    monkeypatch.setattr(cell, "train_cell", real)
    assert main(TRAIN) == 0
    assert "ties" not in capsys.readouterr().out
