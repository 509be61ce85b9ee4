"""Data: the sample/spec contract, sensors, splits, the dataset base class, and the built-in datasets."""

from .base import TactileDataset, TensorData, cache_home, data_home
from .sensors import Sensor
from .spec import DatasetSpec, TactileSample, collate

# importing these modules registers their datasets
# (each dataset module adds its import line here)

__all__ = ["TactileDataset", "TensorData", "cache_home", "data_home", "Sensor", "DatasetSpec", "TactileSample",
           "collate"]
