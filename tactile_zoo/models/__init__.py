"""The model zoo: one model family per module; importing a module registers its models."""

from . import cnn_lstm, convlstm, dcnn, deeptactile, sgnet, tacformer, x_tacformer  # noqa: F401  (import registers the models)
