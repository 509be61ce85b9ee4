"""One public home per name: ``tactile_zoo.create_model`` and ``tactile_zoo.list_models`` are the weights-aware
calls, the registry's lower-level ones are named for what they do (``instantiate_model``, ``model_names``), and no two
public functions of the same name with different signatures live anywhere in the package."""

from __future__ import annotations

import importlib
import inspect
import pkgutil
from collections import defaultdict

import tactile_zoo
from tactile_zoo import registry


def _modules() -> list[object]:
    out = [tactile_zoo]
    for info in pkgutil.walk_packages(tactile_zoo.__path__, "tactile_zoo."):
        if info.name.rpartition(".")[2].startswith("_") and not info.ispkg:
            continue  # private modules (kernels, the version file) hold no public names
        try:
            out.append(importlib.import_module(info.name))
        except ImportError:  # an optional dependency (dask, onnx) that is not installed
            continue
    return out


def test_no_two_public_functions_share_a_name_with_different_signatures() -> None:
    found: dict[str, dict[str, str]] = defaultdict(dict)
    for module in _modules():
        for name, obj in vars(module).items():
            if name.startswith("_") or not inspect.isfunction(obj) or not obj.__module__.startswith("tactile_zoo"):
                continue
            found[name][f"{obj.__module__}.{obj.__qualname__}"] = str(inspect.signature(obj))
    clashes = {name: defs for name, defs in found.items() if len(set(defs.values())) > 1}
    assert not clashes, clashes


def test_no_module_lists_another_modules_function_or_class_in_its_all() -> None:
    """A module's ``__all__`` holds what it defines; only a package's ``__init__`` gathers names from its modules."""
    reexported = []
    for module in _modules():
        if hasattr(module, "__path__"):  # a package: its __init__ is its public surface
            continue
        for name in getattr(module, "__all__", ()):
            obj = getattr(module, name, None)
            home = getattr(obj, "__module__", "") or ""
            if (inspect.isfunction(obj) or inspect.isclass(obj)) and home.startswith("tactile_zoo") \
                    and home != module.__name__:
                reexported.append(f"{module.__name__}.{name} (defined in {home})")
    assert not reexported, reexported


def test_create_model_and_list_models_have_one_home() -> None:
    assert "create_model" not in vars(registry) and "list_models" not in vars(registry)
    assert "create_model" not in tactile_zoo.weights.__all__ and "list_models" not in tactile_zoo.weights.__all__
    assert set(inspect.signature(tactile_zoo.create_model).parameters) >= {"name", "spec", "pretrained", "hparams"}
    assert set(inspect.signature(tactile_zoo.list_models).parameters) == {"pattern", "tags", "pretrained"}
    assert tactile_zoo.list_models() == registry.model_names()  # without pretrained= the same names
