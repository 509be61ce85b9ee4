"""``python -m tactile_zoo.cli``."""

from . import entry

entry()
