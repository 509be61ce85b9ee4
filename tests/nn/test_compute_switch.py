"""One switch for compute paths (tactile_zoo.nn.backend): read from the package's syntax trees.

- No module of ``nn/`` or ``models/`` other than the switch compares a compute-path keyword (``backend``, ``compute``,
  ``attention``, ``weight_grad``, ``stats`` and their model forms such as ``lif_backend``, ``bn_stats``) with a string
  literal, a literal tuple/list/set of strings, or a module constant holding one, nor looks one up in a string-keyed
  dict literal.
- No module of the package other than the switch (and ``_env.py``'s table of variables) names the LIF's environment
  variable.
- No module of ``nn/`` or ``models/`` imports an underscore name from another module of the package.

Each rule is shown to catch a planted offender, so none can pass by finding nothing.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import tactile_zoo
from tactile_zoo.errors import ConfigError
from tactile_zoo.nn import backend

PACKAGE = Path(tactile_zoo.__file__).parent
SWITCH = PACKAGE / "nn" / "backend.py"
ENV = PACKAGE / "_env.py"
LIF_ENV = "TACTILE_ZOO_LIF_BACKEND"
#: the packages whose modules choose compute paths
LAYERS = ("nn", "models")


def _keyword(node: ast.AST) -> str | None:
    """The name of a compute-path keyword read by ``node`` (a name or an attribute), else None."""
    name = node.id if isinstance(node, ast.Name) else node.attr if isinstance(node, ast.Attribute) else None
    if name is None:
        return None
    base = name.lstrip("_")
    if base in ("backend", "compute", "attention", "weight_grad", "stats") or base.endswith(
            ("_backend", "_weight_grad", "bn_stats")):
        return name
    return None


def _strings(node: ast.AST) -> bool:
    """A string literal, or a literal tuple/list/set holding one."""
    if isinstance(node, ast.Constant):
        return isinstance(node.value, str)
    if isinstance(node, (ast.Tuple, ast.List, ast.Set)):
        return any(_strings(e) for e in node.elts)
    return False


def _string_tables(tree: ast.Module) -> tuple[set[str], set[str]]:
    """Names bound anywhere in ``tree`` to a literal collection of strings, and to a dict literal with string keys."""
    collections, dicts = set(), set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Assign, ast.AnnAssign)) and node.value is not None:
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            names = {t.id for t in targets if isinstance(t, ast.Name)}
            if isinstance(node.value, (ast.Tuple, ast.List, ast.Set)) and _strings(node.value):
                collections |= names
            if isinstance(node.value, ast.Dict) and any(_strings(k) for k in node.value.keys if k is not None):
                dicts |= names
    return collections, dicts


def second_resolvers(source: str, where: str) -> list[str]:
    """Every place in ``source`` that resolves a compute-path keyword on its own."""
    tree = ast.parse(source)
    collections, dicts = _string_tables(tree)

    def literal(node: ast.AST) -> bool:
        return _strings(node) or isinstance(node, ast.Dict) or isinstance(node, ast.Name) and node.id in (
            collections | dicts)

    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Compare):
            operands = [node.left, *node.comparators]
            keys = [k for k in map(_keyword, operands) if k]
            if keys and any(literal(o) for o in operands if not _keyword(o)):
                found.append(f"{where}:{node.lineno}: {keys[0]} compared with a string of its own")
        elif isinstance(node, ast.Subscript) and _keyword(node.slice) and (
                isinstance(node.value, ast.Dict) or isinstance(node.value, ast.Name) and node.value.id in dicts):
            found.append(f"{where}:{node.lineno}: {_keyword(node.slice)} looked up in a table of its own")
        elif isinstance(node, ast.Match) and _keyword(node.subject):
            found.append(f"{where}:{node.lineno}: match on {_keyword(node.subject)}")
    return found


def env_reads(source: str, where: str, declaration: bool = False) -> list[str]:
    """Every string constant naming the LIF's environment variable; with ``declaration`` the keys of the
    ``CHOICE_VARIABLES`` dict literal (the table the command line checks) are allowed."""
    tree = ast.parse(source)
    allowed: set[int] = set()
    if declaration:
        for node in ast.walk(tree):
            if isinstance(node, ast.Assign) and isinstance(node.value, ast.Dict) and any(
                    isinstance(t, ast.Name) and t.id == "CHOICE_VARIABLES" for t in node.targets):
                allowed |= {id(k) for k in node.value.keys}
    return [f"{where}:{node.lineno}: names {LIF_ENV}" for node in ast.walk(tree)
            if isinstance(node, ast.Constant) and node.value == LIF_ENV and id(node) not in allowed]


def private_imports(source: str, module: str) -> list[str]:
    """Underscore names imported by ``module`` (dotted) from another module of the package. Importing a module
    (``from . import _kernels``) is allowed: a private module is private to its package, not to a file."""
    tree = ast.parse(source)
    package = module.rsplit(".", 1)[0]  # a module's package; nn/__init__.py is "tactile_zoo.nn.__init__"
    found = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.ImportFrom):
            continue
        if node.level:
            base = package.split(".")
            base = base[:len(base) - node.level + 1]
            origin = ".".join([*base, *([node.module] if node.module else [])])
        else:
            origin = node.module or ""
        if not origin.startswith("tactile_zoo"):
            continue
        for alias in node.names:
            dunder = alias.name.startswith("__")
            if alias.name.startswith("_") and not dunder and not _is_module(f"{origin}.{alias.name}"):
                found.append(f"{module}:{node.lineno}: imports {alias.name} from {origin}")
    return found


def _is_module(dotted: str) -> bool:
    path = PACKAGE.parent.joinpath(*dotted.split("."))
    return path.with_suffix(".py").is_file() or (path / "__init__.py").is_file()


def _modules(*packages: str) -> list[Path]:
    roots = [PACKAGE / p for p in packages] if packages else [PACKAGE]
    return sorted(p for root in roots for p in root.rglob("*.py"))


def _dotted(path: Path) -> str:
    return ".".join(path.relative_to(PACKAGE.parent).with_suffix("").parts)


# ------------------------------------------------------------------------------------------------ the package
def test_no_module_but_the_switch_resolves_a_compute_path() -> None:
    found = [hit for path in _modules(*LAYERS) if path != SWITCH
             for hit in second_resolvers(path.read_text(), str(path.relative_to(PACKAGE)))]
    assert not found, "\n".join(found)


def test_only_the_switch_reads_the_lif_environment_variable() -> None:
    found = [hit for path in _modules() if path != SWITCH
             for hit in env_reads(path.read_text(), str(path.relative_to(PACKAGE)), declaration=path == ENV)]
    assert not found, "\n".join(found)
    assert env_reads(SWITCH.read_text(), "nn/backend.py"), "the switch no longer names the variable: update this test"


def test_no_private_name_crosses_a_module_boundary() -> None:
    found = [hit for path in _modules(*LAYERS) for hit in private_imports(path.read_text(), _dotted(path))]
    assert not found, "\n".join(found)


# -------------------------------------------------------------------------------------- the rules can fail
@pytest.mark.parametrize("planted", [
    'def f(backend):\n    return backend == "fused"\n',
    'class L:\n    def forward(self):\n        return 1 if self.attention != "explicit" else 2\n',
    'def f(compute):\n    if compute not in ("dense", "event"):\n        raise ValueError(compute)\n',
    '_KINDS = ("dense", "pyg")\n\ndef f(graph_backend):\n    return graph_backend in _KINDS\n',
    'def f(temporal_backend):\n    cells = {"native": 1, "tgt": 2}\n    return cells[temporal_backend]\n',
    'def f(lif_backend):\n    match lif_backend:\n        case "fused":\n            return 1\n',
    'def f(weight_grad):\n    return "fast" == weight_grad\n',
    'def f(bn_stats):\n    return bn_stats == "float64"\n',
    'class B:\n    def forward(self):\n        return self.stats in ("two_pass", "float64")\n',
])
def test_a_planted_second_resolver_is_caught(planted: str) -> None:
    assert second_resolvers(planted, "planted.py")


def test_the_resolved_forms_are_not_flagged() -> None:
    ok = ("from tactile_zoo.nn.backend import LIFBackend\n"
          "def f(self, backend, kind):\n"
          "    backend = resolve(LIFBackend, backend, 'backend', 'X')\n"
          "    return self.backend is LIFBackend.FUSED or kind == 'tag'\n")
    assert not second_resolvers(ok, "ok.py")


def test_a_planted_environment_read_is_caught() -> None:
    planted = f"import os\nchoice = os.environ.get({LIF_ENV!r}, 'auto')\n"
    assert env_reads(planted, "planted.py")
    table = f"CHOICE_VARIABLES = {{{LIF_ENV!r}: ('auto', 'numba', 'torch')}}\n"
    assert not env_reads(table, "_env.py", declaration=True) and env_reads(table, "other.py")


def test_a_planted_private_import_is_caught() -> None:
    assert private_imports("from .lif_fused import _advance\n", "tactile_zoo.nn.lif")
    assert private_imports("from ..nn.graph import _tall_linear\n", "tactile_zoo.models.sgnet")
    assert not private_imports("from . import _kernels\nfrom .lif_fused import FusedLIF\n", "tactile_zoo.nn.lif")
    assert not private_imports("from ._binned import BinnedStreamer\n", "tactile_zoo.models.cnn_lstm")


# ---------------------------------------------------------------------------------------------- the switch
def test_an_unknown_value_names_the_owner_the_keyword_and_the_choices() -> None:
    with pytest.raises(ConfigError, match=r"sgnet: lif_backend must be one of 'fused', 'snntorch', got 'fast'"):
        backend.resolve(backend.LIFBackend, "fast", "lif_backend", "sgnet")
    with pytest.raises(ConfigError, match=r"compute must be one of 'dense', 'event', got None"):
        backend.resolve_compute(None, "dense", "sgnet")
    with pytest.raises(ConfigError, match="compute='event' needs graph_backend='dense'"):
        backend.resolve_compute("event", "pyg", "sgnet")
    chosen = backend.resolve(backend.Attention, "explicit", "attention", "X")
    assert chosen is backend.Attention.EXPLICIT and chosen == "explicit" and str(chosen) == "explicit"


def test_the_environment_choices_are_the_switch_choices() -> None:
    from tactile_zoo._env import CHOICE_VARIABLES

    assert CHOICE_VARIABLES[backend.LIF_KERNEL_ENV] == tuple(backend.LIFKernel)
    assert backend.LIF_KERNEL_ENV == LIF_ENV


def test_layers_refuse_an_unknown_path_through_the_switch() -> None:
    from tactile_zoo.nn import ConvLSTMCell, MultiStepLIF, SpikingSelfAttention

    for owner, make in (("MultiStepLIF: backend", lambda: MultiStepLIF(backend="nope")),
                        ("ConvLSTM: backend", lambda: ConvLSTMCell(2, 2, backend="nope")),
                        ("SpikingSelfAttention: attention", lambda: SpikingSelfAttention(8, attention="nope"))):
        with pytest.raises(ConfigError, match=rf"{owner} must be one of '.*', got 'nope'"):
            make()
    assert MultiStepLIF(backend="snntorch").backend is backend.LIFBackend.SNNTORCH
