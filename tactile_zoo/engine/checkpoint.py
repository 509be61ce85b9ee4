"""Checkpoints: ``{"format", "state_dict", "config"}`` saved with ``torch.save`` and read back with
``torch.load(weights_only=True)``, so loading never runs code from the file.

``config`` holds plain JSON types only: the model's registry name and hyper-parameters (enough to rebuild it through
the registry), the dataset it was trained on and its spec, the resolved recipe, the seed and the metrics, and (from
``tactile-zoo train --save``) ``preprocessing``: what the dataset's loader did to a raw recording, as a weights
manifest entry records it (:func:`tactile_zoo.weights.checkpoint_preprocessing` applies it to a file).

Ownership (:mod:`tactile_zoo._owned`): the ``format`` key is the checkpoint's marker. :func:`save_checkpoint` writes
only to a free path or over a checkpoint (:func:`check_checkpoint_path`, which ``train --save`` calls before it
trains); never over another file, a link, a device or a folder. The file is serialised in memory and written
atomically, so a full disk is one error naming the path and leaves nothing behind.
"""

from __future__ import annotations

import io
import json
import os
import zipfile
from pathlib import Path
from typing import Any

import torch

from .._files import atomic_write_bytes
from .._owned import FileRule, check_file
from ..errors import ConfigError

__all__ = ["save_checkpoint", "load_checkpoint", "CHECKPOINT_FORMAT", "build_from_checkpoint", "is_checkpoint",
           "check_checkpoint_path"]

CHECKPOINT_FORMAT = "tactile-zoo-checkpoint/1"
#: the first bytes of a zip archive (what ``torch.save`` writes) and of a NumPy ``.npy`` file
_ZIP_MAGIC, _NPY_MAGIC = b"PK\x03\x04", b"\x93NUMPY"


def is_checkpoint(path: str | os.PathLike) -> bool:
    """Whether ``path`` is a regular file holding a tactile-zoo checkpoint (its ``format`` marker), read safely
    (``weights_only``, memory-mapped: the tensors are not read)."""
    path = Path(path)
    try:
        if not path.is_file() or not zipfile.is_zipfile(path):
            return False
        blob = torch.load(path, map_location="cpu", weights_only=True, mmap=True)
    except Exception:  # noqa: BLE001 - anything torch cannot read safely is not one of ours
        return False
    return isinstance(blob, dict) and blob.get("format") == CHECKPOINT_FORMAT


def check_checkpoint_path(path: str | os.PathLike, flag: str = "checkpoint path") -> Path:
    """The ownership rule (:func:`tactile_zoo._owned.check_file`) for a checkpoint file: a free path or an existing
    checkpoint, in a folder that can be written; ``flag`` names the argument in the error."""
    rule = FileRule(flag=flag, kind="tactile-zoo checkpoint", reuse="a checkpoint `tactile-zoo train --save` wrote",
                    example="MODEL.pt")
    return check_file(path, rule, is_checkpoint)


def _plain(value: Any, where: str) -> Any:
    """Check that ``value`` is JSON-able (what ``weights_only`` loading accepts besides tensors)."""
    try:
        return json.loads(json.dumps(value))
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"checkpoint {where} must hold plain JSON types: {exc}") from None


def save_checkpoint(path: str | os.PathLike, model: torch.nn.Module, config: dict[str, Any], *,
                    flag: str = "checkpoint path") -> Path:
    """Write ``model``'s weights and ``config`` to ``path`` atomically (temp file + rename), if the path is free or
    holds a checkpoint (:func:`check_checkpoint_path`; ``flag`` names the argument in errors).

    Raises:
        ConfigError: the path is not this tool's to write (see :func:`check_checkpoint_path`), or the file cannot be
            written (a full disk, a file size limit): one line naming the path; ``path`` is then left as it was and
            no temporary file remains.
    """
    path = check_checkpoint_path(path, flag)
    blob = {"format": CHECKPOINT_FORMAT, "state_dict": {k: v.detach().cpu() for k, v in model.state_dict().items()},
            "config": _plain(config, "config")}
    # serialised in memory first: torch's file writer turns a failed write (ENOSPC, EFBIG) into two chained
    # RuntimeErrors; Python's write raises one OSError, and the atomic writer removes its temporary file
    data = io.BytesIO()
    torch.save(blob, data)
    try:
        atomic_write_bytes(path, data.getbuffer())
    except OSError as exc:
        raise ConfigError(f"{flag} {path}: cannot write the checkpoint ({exc.strerror or exc}); nothing was written "
                          f"there") from None
    return path


def load_checkpoint(path: str | os.PathLike) -> dict[str, Any]:
    """Read a checkpoint with ``weights_only=True``; anything else (a pickle with code, a foreign file) is refused."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"checkpoint {path} does not exist or is not a file")
    _check_kind(path)
    try:
        blob = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # UnpicklingError for crafted pickles, RuntimeError/EOFError for truncated files
        raise ConfigError(f"checkpoint {path} cannot be loaded safely: {_why(exc)}") from None
    if not isinstance(blob, dict) or blob.get("format") != CHECKPOINT_FORMAT:
        raise ConfigError(f"checkpoint {path} is not a tactile-zoo checkpoint (expected format "
                          f"{CHECKPOINT_FORMAT!r})")
    if not isinstance(blob.get("state_dict"), dict) or not isinstance(blob.get("config"), dict):
        raise ConfigError(f"checkpoint {path} lacks its state_dict or config")
    if not isinstance(blob["config"].get("model"), str):
        raise ConfigError(f"checkpoint {path}: config has no model name")
    return blob


def _check_kind(path: Path) -> None:
    """Refuse, in one line, a file that is not a zip archive as ``torch.save`` writes (text, a NumPy array...)."""
    try:
        with path.open("rb") as f:
            head = f.read(512)
    except OSError as exc:
        raise ConfigError(f"checkpoint {path} cannot be read: {exc.strerror or exc}") from None
    if head.startswith(_ZIP_MAGIC):
        return
    expected = "a .pt file that `tactile-zoo train --save` writes"
    if not head:
        what = "it is empty"
    elif head.startswith(_NPY_MAGIC):
        what = "it is a NumPy .npy array (a recording? `tactile-zoo predict` and `stream --file` read those)"
    elif _is_text(head):
        what = "it is a text file"
    else:
        what = f"it is not a zip archive as torch.save writes (it starts with {head[:8]!r})"
    raise ConfigError(f"checkpoint {path} is not a tactile-zoo checkpoint: {what}; expected {expected}")


def _is_text(head: bytes) -> bool:
    try:
        text = head.decode("utf-8")
    except UnicodeDecodeError:  # possibly a multi-byte character cut at the end of the sample
        text = head[:-3].decode("utf-8", errors="replace")
    return "\x00" not in text and all(c.isprintable() or c.isspace() for c in text if c != "\ufffd")


def _why(exc: BaseException) -> str:
    """One line of what ``torch.load(weights_only=True)`` refused (its own message is several paragraphs)."""
    lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
    unpickler = next((line for line in lines if line.startswith("WeightsUnpickler error:")), None)
    if unpickler is not None:
        detail = unpickler.removeprefix("WeightsUnpickler error:").strip().split(". ")[0]
        return (f"it holds Python objects other than tensors and plain values, which would run code when loaded "
                f"({detail}); only files `tactile-zoo train --save` writes are read")
    first = lines[0].split(". ")[0] if lines else type(exc).__name__
    return f"torch.load refused it ({first}); the file is damaged or truncated"


def build_from_checkpoint(blob: dict[str, Any], spec: Any, where: str = "checkpoint") -> torch.nn.Module:
    """Rebuild the model of a loaded checkpoint for ``spec`` through the registry, at the model revision its
    ``config`` records (the path that trained it), and load its weights; the model keeps the checkpoint's ``config``
    as ``zoo_checkpoint`` (:func:`tactile_zoo.predict` applies its preprocessing).

    Raises:
        ConfigError: the checkpoint does not fit ``spec`` or the model, or its revision can no longer be built.
    """
    from ..registry import get_model_entry, instantiate_model, model_revisions

    config = blob["config"]
    trained = config.get("spec") or {}
    for key in ("num_classes", "num_nodes", "num_channels", "num_globals"):
        if key in trained and trained[key] != getattr(spec, key):
            raise ConfigError(f"{where} was trained on {trained.get('name')!r} with {key}={trained[key]}; dataset "
                              f"{spec.name!r} has {key}={getattr(spec, key)}")
    revision = config.get("model_revision")  # None: a checkpoint from before revisions, built at the default
    known = model_revisions(get_model_entry(config["model"]))
    if revision is not None and revision not in known:
        raise ConfigError(f"{where} was trained with revision {revision} of model {config['model']!r}, which the "
                          f"installed code no longer builds (its revisions: {', '.join(map(str, known))})")
    model = instantiate_model(config["model"], spec, revision=revision, **(config.get("hparams") or {}))
    try:
        model.load_state_dict(blob["state_dict"])
    except RuntimeError as exc:
        raise ConfigError(f"{where} does not fit model {config['model']!r}: {str(exc).splitlines()[0]}") from None
    model.zoo_loss = (config.get("recipe") or {}).get("loss", "ce")
    model.zoo_checkpoint = config  # what predict reads: the spec and the preprocessing the model was trained with
    return model
