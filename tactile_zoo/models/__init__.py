"""The model zoo: one model family per module; importing a module registers its models."""

# importing these modules registers their models
from . import cnn_lstm, convlstm, dcnn  # noqa: F401,E402
from . import tacformer, x_tacformer  # noqa: F401,E402
from . import sgnet  # noqa: F401,E402
