"""The multi-barrel SNN's fidelity fixture: the released code's outputs at reduced sizes, for
``tests/models/test_multibarrel_fidelity.py``.

``python -m tools.multibarrel_fixture CHECKOUT`` imports ``SharedMultiBarrelModel`` from ``CHECKOUT`` (a checkout of
github.com/fun0515/MultiBarrelModel; nothing of it is copied into this repository), runs it on the CPU and writes
``tests/models/fixtures/multibarrel_reference.json``. ``--compare`` also loads the same weights into our
:class:`~tactile_zoo.models.multibarrel.MultiBarrel` and prints the largest differences (what the test asserts).

What is changed around the released code, and why:

* CPU instead of CUDA: ``Tensor.cuda()`` and ``Tensor.to("cuda")`` return the tensor itself;
* noise off: the membrane noise (``torch.normal`` inside ``utils.mem_update_adp``) is zeros; the random start
  (``torch.rand`` in ``forward``) is drawn as released and recorded, so that ours can start from the same values;
* the random start: ``torch.rand`` floored to multiples of 1/256 (stored as bytes);
* reduced sizes, the same code paths: 7 taxels (a subset of NeuTouch's, whose 4 nearest neighbours are set on
  ``neighbor_agg.neighbor_indices``), and a read-out of 8 channels with a 3-step kernel and an MLP of 12 (modules
  replaced after construction; ``Readout.forward`` unchanged); the populations, the compressor and the gate keep the
  released sizes (their widths are written into the released code);
* weights: drawn as released (seed 0), then rounded to 8-bit multiples of a power of two per tensor (exact in
  float32; the JSON stays small), BatchNorm and LayerNorm affine parameters drawn away from 1 and 0 so that their
  mapping matters.

Recorded: the weights before (released names), the input, the two random starts, the training-mode output (batch
statistics; it also updates the running ones, recorded after), the gradients of the released loss
(``CrossEntropyLoss`` on the softmax) for the time constants and the per-tensor gradient sums, then the eval-mode
output (running statistics), all spikes of the training-mode run, and the released 39-taxel neighbour table.
"""

from __future__ import annotations

import argparse
import base64
import contextlib
import json
import subprocess
import sys
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

OUT = Path(__file__).resolve().parents[1] / "tests" / "models" / "fixtures" / "multibarrel_reference.json"
TAXELS = (14, 15, 16, 20, 22, 23, 26)  # NeuTouch's centre: every taxel has 4 neighbours in the subset
BATCH, STEPS, CLASSES = 2, 250, 3
READOUT_CHANNELS, READOUT_KERNEL, HIDDEN = 8, 3, 12
LEVELS = 7  # weights are multiples of a power of two, at most 7 of them in size: 4 bits, so the JSON stays small
INIT = {"init_b": 0.46028508, "init_tau_a": 9.90546331, "init_tau_m": 4.34378016}  # the released train() call


def pack(array: np.ndarray) -> dict[str, Any]:
    """An array as JSON: dtype, shape and the zlib-compressed bytes in base64."""
    shape = list(np.shape(array))  # before ascontiguousarray, which makes a 0-d array 1-d
    array = np.ascontiguousarray(array)
    return {"dtype": str(array.dtype), "shape": shape,
            "data": base64.b64encode(zlib.compress(array.tobytes(), 9)).decode()}


def unpack(entry: dict[str, Any]) -> np.ndarray:
    raw = zlib.decompress(base64.b64decode(entry["data"]))
    return np.frombuffer(raw, dtype=entry["dtype"]).reshape(entry["shape"]).copy()


def pack_weight(t: torch.Tensor) -> dict[str, Any]:
    """A float32 tensor whose values are ``q * 2**-exp`` with integers ``|q| <= 7`` (see :func:`quantise`), stored as
    the int8 array ``q``."""
    exp = _exponent(t)
    q = torch.round(t.double() * 2.0 ** exp)
    assert q.abs().max() <= LEVELS and torch.equal((q * 2.0 ** -exp).float(), t.float()), "not a quantised tensor"
    return {"exp": exp, **pack(q.numpy().astype(np.int8))}


def unpack_weight(entry: dict[str, Any]) -> torch.Tensor:
    if "exp" not in entry:
        return torch.from_numpy(unpack(entry))
    return (torch.from_numpy(unpack(entry)).double() * 2.0 ** -entry["exp"]).float()


def _exponent(t: torch.Tensor) -> int:
    top = float(t.abs().max()) if t.numel() else 0.0
    return 0 if top == 0 else int(np.floor(np.log2(LEVELS / top)))


def quantise(t: torch.Tensor) -> torch.Tensor:
    """``t`` rounded to the nearest multiple of ``2**-exp``, ``exp`` the largest keeping every multiple within 7."""
    exp = _exponent(t)
    return (torch.round(t.double() * 2.0 ** exp) * 2.0 ** -exp).float()


@contextlib.contextmanager
def released_on_cpu(checkout: Path, starts: list[torch.Tensor]) -> Iterator[Any]:
    """The released module, importable from ``checkout``, running on the CPU with the noise off; every
    ``torch.rand`` draw is appended to ``starts``."""
    saved = torch.Tensor.cuda, torch.Tensor.to, torch.normal, torch.rand
    to = torch.Tensor.to

    def rand(*args: Any, **kwargs: Any) -> torch.Tensor:
        out = torch.floor(saved[3](*args, **kwargs) * 256) / 256  # U(0, 1) on a grid of 1/256, stored as bytes
        starts.append(out.clone())
        return out

    torch.Tensor.cuda = lambda self, *a, **k: self  # type: ignore[method-assign]
    torch.Tensor.to = lambda self, *a, **k: self if a[:1] == ("cuda",) else to(self, *a, **k)  # type: ignore
    torch.normal = lambda *a, **k: torch.zeros(k["size"])  # type: ignore[assignment]  # the membrane noise only
    torch.rand = rand  # type: ignore[assignment]
    sys.path.insert(0, str(checkout))
    try:
        import SharedMultiBarrel4EvTask as released  # noqa: N813 (the released module's own name)

        yield released
    finally:
        torch.Tensor.cuda, torch.Tensor.to, torch.normal, torch.rand = saved  # type: ignore[method-assign]
        sys.path.remove(str(checkout))


def build(released: Any) -> nn.Module:
    """The released model at the reduced sizes (module docstring), weights drawn from seed 0 and quantised."""
    torch.manual_seed(0)
    model = released.SharedMultiBarrelModel(num_barrels=len(TAXELS), output_size=CLASSES, **INIT)
    model.readout.conv = nn.Sequential(nn.Conv2d(128, READOUT_CHANNELS, (READOUT_KERNEL, len(TAXELS))),
                                       nn.BatchNorm2d(READOUT_CHANNELS), nn.GELU())
    model.readout.classifier = nn.Sequential(nn.Linear(READOUT_CHANNELS, HIDDEN), nn.LayerNorm(HIDDEN), nn.GELU(),
                                             nn.Linear(HIDDEN, CLASSES))
    pos = torch.tensor([_neutouch()[i] for i in TAXELS], dtype=torch.float32)
    model.neighbor_agg.neighbor_indices = torch.topk(torch.cdist(pos, pos), 5, largest=False)[1][:, 1:5]
    gen = torch.Generator().manual_seed(1)
    with torch.no_grad():
        for module in model.modules():
            if isinstance(module, (nn.BatchNorm1d, nn.BatchNorm2d, nn.LayerNorm)):
                module.weight.copy_(torch.rand(module.weight.shape, generator=gen) + 0.5)
                module.bias.copy_(torch.randn(module.bias.shape, generator=gen) * 0.2)
        for p in model.parameters():
            p.copy_(quantise(p))
    return model


def _neutouch() -> tuple[tuple[float, float], ...]:
    import tactile_zoo as tz

    return tz.get_sensor("neutouch").positions


def make(checkout: Path, commit: str | None = None) -> dict[str, Any]:
    starts: list[torch.Tensor] = []
    with released_on_cpu(checkout, starts) as released:
        model = build(released)
        neutouch = released.NeighborAggregator(k=4).neighbor_indices
        before = {k: v.clone() for k, v in model.state_dict().items()}
        gen = torch.Generator().manual_seed(2)
        x = (torch.rand(BATCH, len(TAXELS), 2, STEPS, generator=gen) < 0.15).float()  # (B, N, C, T), as released
        y = torch.arange(BATCH) % CLASSES
        starts.clear()  # from here on, only the model's own draws
        model.train()
        probs, spikes, _ = model(x)
        nn.CrossEntropyLoss()(probs, y).backward()  # the released loss: cross-entropy on the softmax
        assert len(starts) == 2 * 8, f"{len(starts)} draws of torch.rand; the released forward makes 16"
        train_starts = [s.numpy() for s in starts[:2 * 8]]
        grads = {k: p.grad.double() for k, p in model.named_parameters() if p.grad is not None}
        model.eval()
        with torch.no_grad():
            probs_eval, _, _ = model(x)
        eval_starts = [s.numpy() for s in starts[2 * 8:]]
    return {
        "_about": "made by tools/multibarrel_fixture.py from the released SharedMultiBarrelModel "
                  "(github.com/fun0515/MultiBarrelModel); released parameter names; see the tool's docstring",
        "commit": commit or _commit(checkout), "torch": torch.__version__,
        "sizes": {"taxels": list(TAXELS), "batch": BATCH, "steps": STEPS, "classes": CLASSES,
                  "readout_channels": READOUT_CHANNELS, "readout_kernel": READOUT_KERNEL, "hidden": HIDDEN, **INIT},
        "neighbours_neutouch": neutouch.tolist(),
        "neighbours": model.neighbor_agg.neighbor_indices.tolist(),
        "weights": {k: pack_weight(v) if v.is_floating_point() and k in dict(model.named_parameters())
                    else pack(v.numpy()) for k, v in before.items()},
        "buffers_after_train": {k: pack(v.numpy()) for k, v in model.state_dict().items()
                                if k not in dict(model.named_parameters())},
        "input": pack(np.packbits(x.numpy().astype(bool))), "input_shape": list(x.shape), "labels": y.tolist(),
        "start_train": pack((np.stack(train_starts) * 256).astype(np.uint8)),  # (2 * 8, B, N, 32), /256
        "start_eval": pack((np.stack(eval_starts) * 256).astype(np.uint8)),
        "probs_train": pack(probs.detach().numpy()), "probs_eval": pack(probs_eval.numpy()),
        "spikes_train": pack(np.packbits(spikes.detach().numpy().astype(bool))),
        "spikes_shape": list(spikes.shape),
        "grads_tau": {k: pack(v.float().numpy()) for k, v in grads.items() if k.startswith("tau_")},
        "grad_abs_sums": {k: float(v.abs().sum()) for k, v in grads.items()},
    }


def _commit(checkout: Path) -> str | None:
    done = subprocess.run(["git", "-C", str(checkout), "rev-parse", "HEAD"], capture_output=True, text=True)
    return done.stdout.strip() if done.returncode == 0 else None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkout", type=Path, help="a checkout of github.com/fun0515/MultiBarrelModel")
    parser.add_argument("--out", type=Path, default=OUT)
    parser.add_argument("--commit", help="the checkout's commit, when it is no git work tree (an exported archive)")
    args = parser.parse_args(argv)
    if not (args.checkout / "SharedMultiBarrel4EvTask.py").is_file():
        print(f"multibarrel_fixture: {args.checkout} has no SharedMultiBarrel4EvTask.py; pass a checkout of "
              f"github.com/fun0515/MultiBarrelModel", file=sys.stderr)
        return 2
    torch.set_num_threads(1)
    record = make(args.checkout, args.commit)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(record, indent=0) + "\n")
    print(f"wrote {args.out} ({args.out.stat().st_size / 1024:.0f} kB)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
