"""Engine runtime: flushing subnormal floats to zero inside training, evaluation and bench cells."""

from __future__ import annotations

import pytest
import torch

import tactile_zoo as tz
from tactile_zoo.engine import fit
from tactile_zoo.engine.runtime import flush_denormals

SUBNORMAL = 1e-39  # below float32's smallest normal number (about 1.18e-38), above its smallest subnormal


def _survives() -> bool:
    """Whether a subnormal float32 survives arithmetic on this thread (it does not under flush-to-zero)."""
    return (torch.tensor([SUBNORMAL], dtype=torch.float32) * 1.0).item() != 0.0


@pytest.fixture
def supported() -> bool:
    with flush_denormals() as ok:
        pass
    if not ok:
        pytest.skip("this CPU has no flush-to-zero mode (torch.set_flush_denormal returns False)")
    return ok


def test_flushes_inside_and_restores_after_the_outermost_block(supported: bool) -> None:
    assert _survives()
    with flush_denormals():
        assert not _survives()
        with flush_denormals():  # re-entrant: leaving the inner block must not turn the mode off
            assert not _survives()
        assert not _survives()
    assert _survives()


def test_restores_after_an_exception(supported: bool) -> None:
    with pytest.raises(ValueError), flush_denormals():
        raise ValueError("boom")
    assert _survives()


def test_fit_and_evaluate_run_with_subnormals_flushed(supported: bool) -> None:
    splits = {s: tz.load_dataset("tiny_blobs", split=s) for s in ("train", "val")}
    seen: list[bool] = []
    result = fit("tiny_mlp", splits["train"], val_dataset=splits["val"], device="cpu", epochs=2,
                 callback=lambda row: seen.append(_survives()))
    assert seen == [False, False]  # every epoch ran under flush-to-zero
    assert _survives()  # and the caller's thread got its mode back
    model = result.model
    original = model.forward
    inside: list[bool] = []

    def spy(*args: object, **kwargs: object) -> torch.Tensor:
        inside.append(_survives())
        return original(*args, **kwargs)

    model.forward = spy  # type: ignore[method-assign]
    tz.evaluate(model, splits["val"])
    assert inside and not any(inside)
