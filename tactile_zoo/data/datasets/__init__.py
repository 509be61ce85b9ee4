"""The real datasets: importing this package registers them.

``ev_objects`` / ``ev_containers`` (:mod:`.ev`), ``biotac_dos`` (:mod:`.biotac_dos`), ``augment8000``
(:mod:`.augment8000`), and ``alu_textures`` plus the bring-your-own-recordings loader (:mod:`.recordings`).
"""

from .augment8000 import Augment8000
from .biotac_dos import BioTacDoS
from .ev import EvContainers, EvObjects, EvTouchDataset
from .recordings import AluTextures, RecordingsDataset, define_recordings

__all__ = ["EvTouchDataset", "EvObjects", "EvContainers", "BioTacDoS", "Augment8000", "AluTextures",
           "RecordingsDataset", "define_recordings"]
