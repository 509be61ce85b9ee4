"""Whether calling a module would run hooks: a fused kernel that stands in for several modules runs only where none
of them is hooked, so that a hook (one recording spikes or activations, say) still sees every call."""

from __future__ import annotations

from torch import nn

__all__ = ["has_hooks"]


def has_hooks(*modules: nn.Module) -> bool:
    """True if a forward hook or pre-hook is registered on any of ``modules``, or globally."""
    glob = nn.modules.module
    return bool(glob._global_forward_hooks or glob._global_forward_pre_hooks) or any(
        m._forward_hooks or m._forward_pre_hooks for m in modules)
