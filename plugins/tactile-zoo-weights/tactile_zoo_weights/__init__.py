"""tactile-zoo-weights: pretrained weights for tactile-zoo's models, found through an entry point.

tactile-zoo finds the weights through the entry point declared in this distribution's ``pyproject.toml``::

    [project.entry-points."tactile_zoo.weights"]
    manifest = "tactile_zoo_weights:manifest"

:func:`manifest` returns the path of ``manifest.json`` (format ``tactile-zoo-weights/1``, see
``tactile_zoo.weights.entry``), which lists every ``.safetensors`` file of this folder with its sha256, the model and
dataset, the spec the weights expect, the recipe, the cell's config hash, the test accuracy, the commit and the
licences. ``expected_logits.json`` holds each model's logits on seeded probe inputs (tactile-zoo's test suite
reproduces them). Everything here is built from committed benchmark cells by ``python -m tools.weights_pack`` in a
tactile-zoo checkout. Importing this package has no side effects; tactile-zoo imports it on the first ``tactile-zoo
weights``, ``create_model(..., pretrained=...)`` or ``predict`` call.
"""

from __future__ import annotations

from pathlib import Path

__version__ = "0.3.0"

__all__ = ["manifest", "MANIFEST", "__version__"]

#: the manifest listing the weights shipped in this folder
MANIFEST = Path(__file__).resolve().parent / "manifest.json"


def manifest() -> Path:
    """The path of this distribution's manifest (the target of its ``tactile_zoo.weights`` entry point)."""
    return MANIFEST
