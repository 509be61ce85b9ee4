"""The model zoo: one model family per module; importing a module registers its models."""

# importing a module registers its models
from . import cnn_lstm, convlstm, dcnn, deeptactile, multibarrel, sgnet, tacformer, x_tacformer  # noqa: F401
