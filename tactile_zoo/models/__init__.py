"""The model zoo: one model family per module; importing a module registers its models.

Every public module of this package (a name without a leading underscore) is imported here, so a new built-in model
is its own file and nothing else: no list of modules to extend.
"""

import importlib
import pkgutil

for _module in sorted(m.name for m in pkgutil.iter_modules(__path__) if not m.name.startswith("_")):
    importlib.import_module(f"{__name__}.{_module}")
del _module
