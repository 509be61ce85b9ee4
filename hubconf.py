"""torch.hub entry points: one per built-in model of tactile-zoo, named as in the registry.

From a checkout (or an unpacked sdist), without installing anything but the dependencies below::

    import torch

    model = torch.hub.load("path/to/tactile-zoo", "x_tacformer", source="local", pretrained="ev_objects")
    fresh = torch.hub.load("path/to/tactile-zoo", "sgnet", source="local", spec=my_dataset.spec)

Each entry point is :func:`tactile_zoo.create_model` for its model, with the same arguments: ``pretrained=`` a
dataset the weights were trained on (``"ev_objects"``), a weights tag (``"x_tacformer.full_ev_objects"``), ``True``
(the installed weights that match), a local ``.safetensors``/``.json`` file, or ``False`` (the default: fresh weights
for ``spec=``); ``spec=``, ``new_head=``, ``num_classes=``, ``dataset=`` and the model's constructor keywords pass
through. The zoo's weights come in the weight pack (``pip install ./plugins/tactile-zoo-weights``); asking for
weights that no installed pack provides is one :class:`~tactile_zoo.errors.UnknownNameError` naming the pack, the
datasets it provides for the model, and the weights installed.

The entry points are made from the registry when this file is imported, so a model added to the zoo gets one with no
change here. torch.hub imports this file with the checkout first on ``sys.path``, so the checkout's own package is
used, unless another copy of ``tactile_zoo`` was imported in the process before. Docs: docs/pretrained.md, section
"torch.hub".
"""

from __future__ import annotations

import json as _json
from collections.abc import Callable as _Callable
from pathlib import Path as _Path
from typing import Any as _Any

#: the modules torch.hub checks before loading an entry point: the runtime dependencies in pyproject.toml, by import
#: name (tests/test_hubconf.py keeps the two lists in step)
dependencies = ["torch", "torch_geometric", "snntorch", "numpy", "scipy", "sklearn", "pandas", "tqdm", "matplotlib",
                "yaml", "safetensors", "numba", "pydantic"]

_CHECKOUT = _Path(__file__).resolve().parent
#: the weight pack of this checkout (absent from an sdist): what ``pip install`` of it would provide
_PACK = _CHECKOUT / "plugins" / "tactile-zoo-weights"
_PACK_MANIFEST = _PACK / "tactile_zoo_weights" / "manifest.json"


def _pack_datasets(model: str) -> list[str]:
    """The datasets the checkout's weight pack has weights of ``model`` for (empty without the pack's manifest)."""
    try:
        entries = _json.loads(_PACK_MANIFEST.read_text())["weights"]
    except (OSError, ValueError, KeyError, TypeError):
        return []
    return sorted({e["dataset"] for e in entries if isinstance(e, dict) and e.get("model") == model})


def _no_weights(model: str, pretrained: _Any, error: Exception) -> str:
    """The message for ``pretrained=`` weights of ``model`` that no installed pack provides."""
    import tactile_zoo

    installed = sorted(e.tag for e in tactile_zoo.list_weights() if e.model == model)
    shipped = _pack_datasets(model)
    if shipped:
        pack = (f"the weight pack (pip install {_PACK}) has weights of {model!r} for "
                f"{', '.join(map(repr, shipped))}")
    elif _PACK_MANIFEST.is_file():
        pack = (f"the weight pack ({_PACK}) has no weights of {model!r}: train your own "
                "(tactile-zoo bench --save-weights)")
    else:
        pack = "the zoo's weights come in the weight pack, plugins/tactile-zoo-weights of a checkout (pip install it)"
    return (f"torch.hub entry {model!r}: pretrained={pretrained!r}: {error}. Installed weights of {model!r}: "
            f"{', '.join(installed) or 'none'}; {pack}")


def _entry(model: str, summary: str) -> _Callable[..., _Any]:
    """The entry point of registered model ``model``."""

    def entry(pretrained: _Any = False, **kwargs: _Any) -> _Any:
        import tactile_zoo
        from tactile_zoo.errors import UnknownNameError

        try:
            return tactile_zoo.create_model(model, pretrained=pretrained, **kwargs)
        except UnknownNameError as exc:
            if pretrained is None or pretrained is False:
                raise
            raise UnknownNameError(_no_weights(model, pretrained, exc)) from None

    entry.__name__ = entry.__qualname__ = model
    entry.__doc__ = (f"{summary}\n\n``torch.hub.load(CHECKOUT, {model!r}, source='local', pretrained=..., **kwargs)``"
                     f" is ``tactile_zoo.create_model({model!r}, pretrained=..., **kwargs)``: see the module "
                     "docstring.")
    return entry


def _builtin_entries() -> dict[str, _Callable[..., _Any]]:
    """One entry point per built-in model (plugins' models are not the zoo's: they keep their own hub files)."""
    from tactile_zoo import registry

    found = {}
    for name in registry.model_names():
        registered = registry.get_model_entry(name)
        # the zoo's own: defined in tactile_zoo.models (a plugin has a dist; a model a script registered has neither)
        if registered.dist is None and getattr(registered.obj, "__module__", "").startswith("tactile_zoo.models."):
            found[name] = _entry(name, str(registered.meta.get("description") or name))
    return found


globals().update(_builtin_entries())
