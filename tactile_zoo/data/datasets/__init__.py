"""The built-in datasets: importing this package registers them, real datasets first, then the simulators.

Real: ``ev_objects`` / ``ev_containers`` (:mod:`.ev`), ``biotac_dos`` (:mod:`.biotac_dos`), ``augment8000``
(:mod:`.augment8000`), and ``alu_textures`` plus the bring-your-own-recordings loader (:mod:`.recordings`).
Simulated (the embedded default without real data; shared base in :mod:`._simulator`): ``sim_evtouch``
(:mod:`.sim_evtouch`), ``sim_biotac_slip`` (:mod:`.sim_biotac_slip`), ``sim_uskin_textures``
(:mod:`.sim_uskin_textures`).
"""

from .augment8000 import Augment8000
from .biotac_dos import BioTacDoS
from .ev import EvContainers, EvObjects, EvTouchDataset
from .recordings import AluTextures, RecordingsDataset, define_recordings

# the simulators register after the real datasets and in this order (registration order is the registry's
# contract, so the imports are not sorted)
# isort: off
from .sim_evtouch import SimEvTouch
from .sim_biotac_slip import SimBiotacSlip
from .sim_uskin_textures import SimUskinTextures
# isort: on

__all__ = ["EvTouchDataset", "EvObjects", "EvContainers", "BioTacDoS", "Augment8000", "AluTextures",
           "RecordingsDataset", "define_recordings", "SimEvTouch", "SimBiotacSlip", "SimUskinTextures"]
