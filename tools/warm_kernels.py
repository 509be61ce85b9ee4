"""Fill the numba kernels' on-disk cache: one forward and backward pass of every built-in model on a tiny simulator
batch (ConvLSTM on its compiled path too), and the LIF kernel's parallel builds on two threads, so that each kernel the
models and tests call is compiled once and written beside its module (``tactile_zoo/nn/_kernels/__pycache__``).

    python -m tools.warm_kernels

A fresh checkout has no cache: every process that calls a kernel first compiles it (about 14 CPU seconds for the
LIF kernels, 25 for all of them), and the suite's two workers and its early child processes would each compile the
same kernels at once. ``make test`` runs this in the background while pytest collects, so the tests find the cache
written. Numba writes each cache file whole (a temporary file renamed), so a process that compiles a kernel at the
same time only repeats the work. Nothing else is written; it prints nothing unless a model fails.
"""

from __future__ import annotations

import sys

import torch


def _built_in(entry: object) -> bool:
    """A model of the package itself (not a plugin's, nor one a test registered)."""
    return getattr(entry, "dist", None) is None and getattr(entry.obj, "__module__", "").startswith(  # type: ignore
        "tactile_zoo.models.")


def warm() -> list[str]:
    """One forward and backward pass of each built-in model on 2 samples of ``sim_evtouch``; the failures."""
    import tactile_zoo as tz
    from tactile_zoo import registry

    ds = tz.load_dataset("sim_evtouch", split="test", n_train_per_class=2, n_test_per_class=1, seed=0,
                         num_steps=20)
    builds = [(name, {}) for name in tz.list_models() if _built_in(registry.get_model_entry(name))]
    builds.append(("convlstm", {"backend": "compiled"}))  # ConvLSTM's compiled path (not its default)
    torch.set_num_threads(1)  # as the suite runs: the kernels' serial builds
    failed = []
    for name, kwargs in builds:
        try:
            model = tz.create_model(name, ds.spec, **kwargs).train()
            model(ds.x[:2], None).float().sum().backward()
        except Exception as exc:  # a model this cannot warm is compiled by the tests that use it, as before
            failed.append(f"{name}{kwargs or ''}: {type(exc).__name__}: {exc}")
    return failed + warm_parallel_lif()


def warm_parallel_lif() -> list[str]:
    """One forward and backward pass of the fused LIF on two threads over more neurons than one chunk of the kernel
    (``CHUNK``) and more elements than ``SERIAL_BELOW``: the kernel's parallel builds, which the models' passes above
    (one thread) never reach and tests/nn/test_lif_kernel.py runs on two threads (each worker compiled them, about 6
    CPU seconds each, when the cache lacked them); the failure, if any."""
    from tactile_zoo.nn import backend
    from tactile_zoo.nn.lif import MultiStepLIF

    kernels = backend.lif_kernels()
    if kernels is None:  # no numba kernel on this machine: nothing to compile
        return []
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        steps = -(-kernels.SERIAL_BELOW // (kernels.CHUNK + 1))  # (steps, CHUNK + 1) holds at least SERIAL_BELOW
        x = torch.rand(steps, kernels.CHUNK + 1, requires_grad=True)
        MultiStepLIF(backend="fused")(x).sum().backward()
    except Exception as exc:
        return [f"parallel LIF: {type(exc).__name__}: {exc}"]
    finally:
        torch.set_num_threads(before)
    return []


if __name__ == "__main__":
    problems = warm()
    for line in problems:
        print(line, file=sys.stderr)
    sys.exit(int(bool(problems)))
