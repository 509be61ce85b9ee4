"""The plugin module of ``my_recordings.yaml``: registers your recordings as the dataset ``my_grasps``.

Put one file per trial at ``<data home>/my_grasps/raw/<class name>/<trial>.csv`` (or ``.npy``): one row per time
step, the taxel readings in row-major taxel order, then the global features (docs/datasets.md, "Bring your own
recordings"). Change the sensor and the channel counts to yours; a study finds this module beside its file.
"""

from tactile_zoo.data.datasets import define_recordings

define_recordings("my_grasps", sensor="biotac_sp", num_channels=1, num_globals=0,
                  description="my own grasps, recorded with a BioTac SP")
