"""Data: the sample/spec contract, sensors, splits, the dataset base class, and the built-in datasets."""

# importing these modules registers their datasets
# (each dataset module adds its import line here)
from . import datasets, simulated  # noqa: F401
from .base import TactileDataset, TensorData, cache_home, data_home
from .sensors import Sensor
from .spec import DatasetSpec, TactileSample, collate

__all__ = ["TactileDataset", "TensorData", "cache_home", "data_home", "Sensor", "DatasetSpec", "TactileSample",
           "collate"]
