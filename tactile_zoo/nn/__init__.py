"""Building blocks shared by the models: LIF neurons, graph convolution over frames, tdBN, attention, T-GCN."""
from .attention import SpikingSelfAttention  # noqa: F401,E402
from .convlstm import ConvLSTM, ConvLSTMCell, ConvLSTMConfig  # noqa: F401,E402
from .graph import FrameGraphConv, dense_propagator  # noqa: F401,E402
from .lif import LIFConfig, MultiStepLIF  # noqa: F401,E402
from .sensor_grid import SensorGrid, grid_weights  # noqa: F401,E402
from .surrogate import Surrogate, make_surrogate, open_interval_mask  # noqa: F401,E402
from .tdbn import TdBatchNorm  # noqa: F401,E402
from .tgcn import TemporalAttention, TemporalGraphAttention, TGCN2Cell, TGCNCell  # noqa: F401,E402
