"""Simulated tactile datasets (compatibility module): the simulators live in :mod:`tactile_zoo.data.datasets`.

``sim_evtouch`` (:mod:`~tactile_zoo.data.datasets.sim_evtouch`), ``sim_biotac_slip``
(:mod:`~tactile_zoo.data.datasets.sim_biotac_slip`) and ``sim_uskin_textures``
(:mod:`~tactile_zoo.data.datasets.sim_uskin_textures`), with their shared base, ``SIM_EPOCH_BUDGET`` and helpers in
:mod:`~tactile_zoo.data.datasets._simulator`. This module re-exports the names importable from it before the split.
"""

from .datasets._simulator import _MEMO, _MEMO_SIZE, SIM_EPOCH_BUDGET, _min_jerk, _Simulator, _smoothstep  # noqa: F401
from .datasets.sim_biotac_slip import SimBiotacSlip, _biotac_chart, _biotac_raw  # noqa: F401
from .datasets.sim_evtouch import SimEvTouch, _evtouch_pressure, _log_events  # noqa: F401
from .datasets.sim_uskin_textures import SimUskinTextures, _relief, _uskin_local, _uskin_rub  # noqa: F401

__all__ = ["SimEvTouch", "SimBiotacSlip", "SimUskinTextures", "SIM_EPOCH_BUDGET"]
