"""Data: the sample/spec contract, sensors, splits, the dataset base class, and the built-in datasets."""

# importing the datasets package registers every built-in dataset, real and simulated (see its docstring)
from . import datasets  # noqa: F401
from .base import TactileDataset, TensorData, cache_home, data_home
from .pyg import to_pyg
from .sensors import Sensor
from .spec import DatasetSpec, TactileBatch, TactileSample, collate

__all__ = ["TactileDataset", "TensorData", "cache_home", "data_home", "Sensor", "DatasetSpec", "TactileSample",
           "TactileBatch", "collate", "to_pyg"]
