"""Pretrained weights: what they are, where they come from, loading them into a model, and predicting with them.

The layer sits between the harness and the engine (``cli -> bench -> weights -> engine -> models -> data``): it
builds models through the registry (never importing a model module), reads specs and files with the data layer, and
runs inference with the engine's :func:`~tactile_zoo.engine.evaluate.predict_scores`, so a prediction here is the
prediction :func:`tactile_zoo.evaluate` makes. The harness and the command line use it; the engine never does.

Parts (one concept per module):

- :mod:`.entry`: :class:`WeightEntry`, the manifest keys, the tag scheme ``<model>.<recipe>_<dataset>``;
- :mod:`.manifest`: manifest files, and :func:`entry_from_record` (a ``bench --save-weights`` cell to an entry);
- :mod:`.discovery`: installed weights, through the entry-point group ``tactile_zoo.weights``;
- :mod:`.files`: locating a file (installed, local, or a URL downloaded into the cache), sha256-checked;
- :mod:`.heads`: the classifier-head convention (``zoo_head``) that ``new_head=True`` relies on;
- :mod:`.load`: loading weights into a model, and the public :func:`tactile_zoo.create_model` and
  :func:`tactile_zoo.list_models` (their one home is the top-level package);
- :mod:`.predict`: reading recordings in the bring-your-own format, and :func:`predict` (:func:`iter_predict`:
  the same, streamed in bounded batches).

Sources of weights: (a) a distribution that declares a ``tactile_zoo.weights`` entry point (``pip install
./plugins/tactile-zoo-weights``); (b) a local ``.safetensors`` file with a manifest (``<stem>.json`` or
``manifest.json`` next to it); (c) a manifest entry with a ``url`` and ``sha256``, downloaded into
``<cache home>/weights`` and verified.
"""

from __future__ import annotations

from .discovery import WEIGHTS_GROUP, WeightSource, find_weights, list_weights, reset_weights, weight_sources
from .entry import ENTRY_KEYS, MANIFEST_FORMAT, WeightEntry, make_tag, tag_key
from .files import locate, weights_cache
from .heads import head_keys, head_name
from .load import check_fit, load_pretrained, local_weights, resolve_weights
from .manifest import (
    DEFAULT_LICENCE,
    checkpoint_preprocessing,
    dataset_options,
    entry_from_record,
    entry_preprocessing,
    parse_manifest,
    preprocessing_of,
    read_manifest,
    write_manifest,
)
from .predict import (
    DEFAULT_BATCH,
    LENGTHS,
    ON_ERROR,
    Prediction,
    Recording,
    Refused,
    iter_predict,
    predict,
    read_recording,
)

__all__ = [
    "WeightEntry", "MANIFEST_FORMAT", "ENTRY_KEYS", "make_tag", "tag_key", "read_manifest", "parse_manifest",
    "write_manifest", "entry_from_record", "preprocessing_of", "DEFAULT_LICENCE", "WEIGHTS_GROUP", "WeightSource",
    "weight_sources", "list_weights", "find_weights", "reset_weights", "locate", "weights_cache", "head_name",
    "head_keys", "load_pretrained", "resolve_weights", "local_weights", "check_fit",
    "predict", "iter_predict", "read_recording", "Prediction", "Recording", "Refused", "LENGTHS", "ON_ERROR",
    "DEFAULT_BATCH", "dataset_options", "entry_preprocessing", "checkpoint_preprocessing",
]
