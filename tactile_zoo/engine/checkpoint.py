"""Checkpoints: ``{"format", "state_dict", "config"}`` saved with ``torch.save`` and read back with
``torch.load(weights_only=True)``, so loading never runs code from the file.

``config`` holds plain JSON types only: the model's registry name and hyper-parameters (enough to rebuild it through
the registry), the dataset it was trained on and its spec, the resolved recipe, the seed and the metrics.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import torch

from .._files import atomic_path
from ..errors import ConfigError

__all__ = ["save_checkpoint", "load_checkpoint", "CHECKPOINT_FORMAT", "build_from_checkpoint"]

CHECKPOINT_FORMAT = "tactile-zoo-checkpoint/1"


def _plain(value: Any, where: str) -> Any:
    """Check that ``value`` is JSON-able (what ``weights_only`` loading accepts besides tensors)."""
    try:
        return json.loads(json.dumps(value))
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"checkpoint {where} must hold plain JSON types: {exc}") from None


def save_checkpoint(path: str | os.PathLike, model: torch.nn.Module, config: dict[str, Any]) -> Path:
    """Write ``model``'s weights and ``config`` to ``path`` atomically (temp file + rename)."""
    path = Path(path)
    blob = {"format": CHECKPOINT_FORMAT, "state_dict": {k: v.detach().cpu() for k, v in model.state_dict().items()},
            "config": _plain(config, "config")}
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(path) as tmp:
            torch.save(blob, tmp)
    except OSError as exc:  # the folder is not writable, or the disk is full: path is left as it was
        raise ConfigError(f"cannot write checkpoint {path}: {exc.strerror or exc}") from None
    return path


def load_checkpoint(path: str | os.PathLike) -> dict[str, Any]:
    """Read a checkpoint with ``weights_only=True``; anything else (a pickle with code, a foreign file) is refused."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"checkpoint {path} does not exist or is not a file")
    try:
        blob = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # UnpicklingError for crafted pickles, RuntimeError/EOFError for truncated files
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ConfigError(f"checkpoint {path} cannot be loaded safely (weights_only=True refused it): {first}") \
            from None
    if not isinstance(blob, dict) or blob.get("format") != CHECKPOINT_FORMAT:
        raise ConfigError(f"checkpoint {path} is not a tactile-zoo checkpoint (expected format "
                          f"{CHECKPOINT_FORMAT!r})")
    if not isinstance(blob.get("state_dict"), dict) or not isinstance(blob.get("config"), dict):
        raise ConfigError(f"checkpoint {path} lacks its state_dict or config")
    if not isinstance(blob["config"].get("model"), str):
        raise ConfigError(f"checkpoint {path}: config has no model name")
    return blob


def build_from_checkpoint(blob: dict[str, Any], spec: Any, where: str = "checkpoint") -> torch.nn.Module:
    """Rebuild the model of a loaded checkpoint for ``spec`` through the registry and load its weights."""
    from ..registry import instantiate_model

    config = blob["config"]
    trained = config.get("spec") or {}
    for key in ("num_classes", "num_nodes", "num_channels", "num_globals"):
        if key in trained and trained[key] != getattr(spec, key):
            raise ConfigError(f"{where} was trained on {trained.get('name')!r} with {key}={trained[key]}; dataset "
                              f"{spec.name!r} has {key}={getattr(spec, key)}")
    model = instantiate_model(config["model"], spec, **(config.get("hparams") or {}))
    try:
        model.load_state_dict(blob["state_dict"])
    except RuntimeError as exc:
        raise ConfigError(f"{where} does not fit model {config['model']!r}: {str(exc).splitlines()[0]}") from None
    model.zoo_loss = (config.get("recipe") or {}).get("loss", "ce")
    return model
