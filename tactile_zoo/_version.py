"""The package version, in a module of its own: reading it must not import the package root, which registers (and so
imports) every built-in model and dataset."""

__version__ = "0.2.0"
