"""tactile-zoo-tcn: a temporal convolutional network baseline, added to tactile-zoo as an out-of-tree plugin.

tactile-zoo finds the model through the entry point declared in this distribution's ``pyproject.toml``::

    [project.entry-points."tactile_zoo.models"]
    tcn = "tactile_zoo_tcn:TCN"

The target is a class called as ``TCN(spec, **hparams)``; its ``zoo_meta`` attribute carries the metadata (paper,
tags, inputs, training recipe) that tactile-zoo's ``register_model(**meta)`` would take. Nothing here registers at
import time, so importing this package has no side effects, and tactile-zoo imports it only when a model is
listed or created.
"""

from .model import TCN, receptive_field

__version__ = "0.2.0"

__all__ = ["TCN", "receptive_field", "__version__"]
