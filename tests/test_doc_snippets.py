"""Every command and Python snippet of README.md and docs/ is exercised (issue 38): Python blocks run as written in a
folder of their page, ``tactile-zoo`` lines run when they take seconds and are resolved (``bench --dry-run``, the
parser and the registries) when they take hours, ``python -m`` lines are parsed by their module's own parser, and
``pip install`` lines must name what installs offline from a clone or a built wheel. How each block is exercised is
in ``tests/doc_snippets.py``; the page itself says what its language does not (``<!-- snippet: ... -->``)."""

from __future__ import annotations

import contextlib
import io
import json
import os
import re
import shlex
import sys
import tomllib
from collections.abc import Iterator
from pathlib import Path

import pytest
from doc_snippets import (
    EXEMPT_MAKE,
    FIXTURES,
    KNOWN_LANGS,
    REPO,
    Block,
    WarmPython,
    command_spans,
    doc_files,
    extract_blocks,
    fresh_python_c,
    has_placeholder,
    pip_problems,
    python_c,
    shell_commands,
    substitute_data,
)

#: the real data home (tests/conftest.py reads the same variable; importing conftest by name can reach
#: tests/reliability/conftest.py instead, depending on collection order)
SHARED_DATA = Path(os.environ.get("TACTILE_ZOO_SHARED_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))

BLOCKS = [block for path in doc_files() for block in extract_blocks(path)]
#: what a documented ``pip install`` may name besides local paths: the requirements the project itself declares
PYPROJECT = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
EXTRAS = set(PYPROJECT["optional-dependencies"])
THIRD_PARTY = {re.split(r"[\[<>=!~; ]", req, maxsplit=1)[0].lower() for req in
               PYPROJECT["dependencies"] + [r for reqs in PYPROJECT["optional-dependencies"].values() for r in reqs]}
THIRD_PARTY |= {"torch-geometric-temporal", "mlflow"}  # the Makefile's pin; the tracker UI (Harness, MLflow)
MAKE_TARGETS = set(re.search(r"^\.PHONY:(.*)$", (REPO / "Makefile").read_text(), re.M).group(1).split())
#: parses a ``python -m`` / ``python FILE`` line with the module's own argparse parser, then stops before any work
PARSE_ONLY = r"""
import argparse, json, runpy, sys
class Parsed(Exception):
    pass
real = argparse.ArgumentParser.parse_args
def parse_args(self, args=None, namespace=None):
    real(self, args, namespace)
    raise Parsed
argparse.ArgumentParser.parse_args = parse_args
results = []
for target, argv in json.loads(sys.argv[1]):
    sys.argv = [target, *argv]
    try:
        (runpy.run_path if target.endswith(".py") else runpy.run_module)(target, run_name="__main__")
        results.append("ran without calling an argument parser")
    except Parsed:
        results.append(None)
    except SystemExit as exc:
        results.append(f"exit {exc.code}")
    except Exception as exc:
        results.append(f"{type(exc).__name__}: {exc}")
print(json.dumps(results))
"""


#: this process's warm server (one per xdist worker, started by its first Python child; ``DOC_SNIPPETS_PLAIN=1``
#: runs every child fresh): a child of it skips the 2-5 s of importing torch and PyG
WARM = WarmPython()


@pytest.fixture(scope="session", autouse=True)
def _end_the_warm_server() -> Iterator[None]:
    yield
    WARM.close()


def _data_home() -> Path | None:
    return SHARED_DATA if (SHARED_DATA / "ev_objects" / "raw").is_dir() else None


@pytest.fixture(scope="session")
def plugins(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """``pip install ./plugins/<name>``, done for real but offline (once per run: the other modules that install
    them share the folders, which they only read), into folders a page's session puts on the path."""
    from plugin_install import installed_once

    return {name: installed_once(REPO / "plugins" / name, tmp_path_factory)
            for name in ("tactile-zoo-weights", "tactile-zoo-tcn")}


class Session:
    """One page's working folder and what its ``pip install`` lines installed so far."""

    def __init__(self, cwd: Path, plugins: dict[str, Path]) -> None:
        self.cwd, self.plugins, self.active = cwd, plugins, []

    def install(self, argv: list[str]) -> None:
        for target in argv[2:]:
            name = target.removeprefix("./plugins/").strip("/")
            if target.startswith("./plugins/") and self.plugins[name] not in self.active:
                self.active.append(self.plugins[name])

    def env(self) -> dict[str, str]:
        data = _data_home()
        return {**os.environ, "PYTHONPATH": os.pathsep.join(map(str, [*self.active, REPO])), "OMP_NUM_THREADS": "1",
                **({"TACTILE_ZOO_DATA": str(data)} if data else {})}

    @contextlib.contextmanager
    def inside(self):
        """This process as a command of the page would see it: the folder, the data home, the installed plugins."""
        from tactile_zoo import registry
        from tactile_zoo.weights import reset_weights

        with pytest.MonkeyPatch.context() as mp:
            mp.chdir(self.cwd)
            for key in ("TACTILE_ZOO_DATA", "TACTILE_ZOO_NO_PLUGINS"):
                mp.delenv(key, raising=False)
            if _data_home():
                mp.setenv("TACTILE_ZOO_DATA", str(_data_home()))
            for target in self.active:
                mp.syspath_prepend(str(target))
            registry.reset_plugins()
            reset_weights()
            try:
                yield
            finally:
                for module in ("tactile_zoo_weights", "tactile_zoo_tcn"):
                    sys.modules.pop(module, None)
        registry.reset_plugins()
        reset_weights()


_SESSIONS: dict[Path, Session] = {}


@pytest.fixture
def session(block: Block, plugins: dict[str, Path], tmp_path_factory: pytest.TempPathFactory) -> Session:
    if block.path not in _SESSIONS:
        _SESSIONS[block.path] = Session(tmp_path_factory.mktemp(block.path.stem), plugins)
    return _SESSIONS[block.path]


def cli(argv: list[str]) -> tuple[int, str]:
    """``tactile-zoo argv`` in this process: its exit status and what it printed."""
    from tactile_zoo.cli import main

    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
        code = main(argv)
    return code, out.getvalue()


def resolve(argv: list[str]) -> None:  # noqa: C901 - one rule per kind of name
    """A ``tactile-zoo`` line too long to run: bench lists its grid (``--dry-run``, which resolves every model,
    dataset and setting); any other command is parsed, and the models, datasets and weights it names looked up."""
    import tactile_zoo as tz
    from tactile_zoo import registry
    from tactile_zoo.cli import build_parser

    if argv[0] == "bench":
        dry = argv if "--dry-run" in argv else [*argv, "--dry-run"]
        code, out = cli(dry)
        if not (code == 2 and "its data is not here" in out and _data_home() is None):  # else: parsed below
            assert code == 0, f"tactile-zoo {shlex.join(dry)}: exit {code}\n{out[-2000:]}"
            return
    stderr = io.StringIO()
    with contextlib.redirect_stderr(stderr):
        try:
            args = build_parser().parse_args(argv)
        except SystemExit:
            pytest.fail(f"tactile-zoo {shlex.join(argv)}: the parser refuses it: {stderr.getvalue().strip()}")
    model = getattr(args, "model", None)
    if model:
        registry.get_model_entry(model)
    for key in ("dataset", "spec_from"):
        if getattr(args, key, None):
            registry.get_dataset_entry(getattr(args, key))
    if getattr(args, "pretrained", None) and model:
        name = registry.normalize_name(model)
        tags = [t.rsplit(":", 1)[-1] for t in tz.list_models(pretrained=True)]  # "<distribution>:" where shared
        tags = [t for t in tags if registry.normalize_name(t.split(".")[0]) == name]
        assert any(t.endswith((f".{args.pretrained}", f"_{args.pretrained}")) for t in tags) or \
            args.pretrained in tags, f"no installed weights {args.pretrained!r} for {model}: {tags}"


def run_shell(block: Block, session: Session, prompt: bool = False) -> None:
    """Each command of a shell block (or the ``$ `` lines of a transcript), as :mod:`doc_snippets` describes."""
    resolved = set(block.directives.get("resolve", "").split())
    not_run = block.directives.get("not-run", "").split()[:1]
    python_lines = []
    for argv in shell_commands(block.body, prompt):
        program = argv[0]
        if program == "make":
            assert argv[1] in MAKE_TARGETS, f"{block.id}: make {argv[1]}: no such target in the Makefile"
            assert argv[1] in EXEMPT_MAKE or "make" in not_run, \
                f"{block.id}: {shlex.join(argv)}: only make bench and make test are exempt; say why with not-run"
        elif argv[:2] == ["pip", "install"]:
            assert not pip_problems(argv, EXTRAS, THIRD_PARTY), pip_problems(argv, EXTRAS, THIRD_PARTY)
            session.install(argv)
        elif program == "tactile-zoo":
            with session.inside():
                real = substitute_data(argv[1:], _data_home())
                subcommand = next(w for w in argv[1:] if not w.startswith("-"))
                if real is None or subcommand in resolved or has_placeholder(argv):
                    resolve(real or argv[1:])
                else:
                    code, out = cli(real)
                    assert code == 0, f"{block.id}: tactile-zoo {shlex.join(real)}: exit {code}\n{out[-3000:]}"
        elif program == "python":
            python_lines.append(argv[1:])
        else:
            assert program in not_run, f"{block.id}: {shlex.join(argv)}: a program the harness does not know; " \
                                       f"add <!-- snippet: not-run {program} REASON --> before the block"
    parse_python_lines(python_lines, session, block.id)


def parse_results(lines: list[list[str]], session: Session) -> tuple[list[str | None], str]:
    """Each line's parse in one child (``None``: its parser accepted it), and the child's stderr."""
    targets = [(argv[1], argv[2:]) if argv[0] == "-m" else (str(REPO / argv[0]), argv[1:]) for argv in lines]
    if not targets:
        return [], ""
    run = python_c(PARSE_ONLY, [json.dumps(targets)], REPO, session.env(), WARM)
    assert run.returncode == 0, run.stderr[-3000:]
    return json.loads(run.stdout.strip().splitlines()[-1]), run.stderr


def parse_python_lines(lines: list[list[str]], session: Session, where: str,
                       parsed: dict[tuple[str, ...], str | None] | None = None) -> None:
    """``python -m MODULE ARGS`` and ``python FILE.py ARGS``: each module's own parser accepts the arguments
    (looked up in ``parsed`` where given, else parsed now)."""
    stderr = ""
    if parsed is None:
        results, stderr = parse_results(lines, session)
    else:
        results = [parsed[tuple(argv)] for argv in lines]
    bad = [f"python {shlex.join(argv)}: {r}" for argv, r in zip(lines, results, strict=True) if r]
    assert not bad, f"{where}: " + "; ".join(bad) + f"\n{stderr[-2000:]}"


def run_python(block: Block, session: Session) -> None:
    if "compile" in block.directives:
        compile(block.body, block.id, "exec")
        return
    run = python_c(block.body, [], session.cwd, session.env(), WARM)
    assert run.returncode == 0, f"{block.id} failed:\n{run.stdout[-2000:]}\n{run.stderr[-4000:]}"


def check_block(block: Block, session: Session) -> None:
    """Exercise one block (in its page's folder, after the page's earlier blocks)."""
    session.install(["pip", "install", *block.directives.get("installed", "").split()])
    for name in block.directives.get("files", "").split():
        if not (session.cwd / name).exists():
            FIXTURES[name](session.cwd)
    if "diagram" in block.directives:
        return
    if "output" in block.directives:
        run_shell(block, session, prompt=True)
    elif block.lang == "python":
        run_python(block, session)
    elif block.lang == "bash":
        run_shell(block, session)
    elif block.lang == "toml":
        from packaging.specifiers import SpecifierSet

        from tactile_zoo import __version__
        from tactile_zoo.registry import ENTRY_POINT_GROUPS

        project = tomllib.loads(block.body)["project"]
        assert set(project["entry-points"]) <= set(ENTRY_POINT_GROUPS.values()) | {"tactile_zoo.weights"}
        requirement = next(r for r in project["dependencies"] if r.startswith("tactile-zoo"))
        assert __version__ in SpecifierSet(requirement.removeprefix("tactile-zoo")), requirement
    elif block.lang == "yaml":  # a recipe file (the only YAML the docs show): it must read and validate as one
        from tactile_zoo.registry import read_recipe_file

        path = session.cwd / "snippet_recipes.yaml"
        path.write_text(block.body)
        assert read_recipe_file(path)["recipes"], block.id
    elif block.lang == "bibtex":
        from tactile_zoo import __version__

        entries = re.findall(r"^@(\w+)\{([^,\s]+),", block.body, re.M)
        assert entries and block.body.count("{") == block.body.count("}"), f"{block.id}: not BibTeX entries"
        for kind, key in entries:  # every entry names its work (a year only where the source gives one: D-CNN's not)
            body = block.body.split(f"@{kind}{{{key},", 1)[1].split("\n@", 1)[0]
            assert re.search(r"^\s*title\s*=", body, re.M), f"{block.id}: {key} has no title"
        if ("software", "tactile_zoo") in entries:  # the project's own citation carries this release
            assert f"version = {{{__version__}}}" in " ".join(block.body.split()), "the citation's version"
    else:
        pytest.fail(f"{block.id}: a {block.lang or 'plain'} block the harness does not run; mark it "
                    f"<!-- snippet: output|diagram|... --> (tests/doc_snippets.py)")


def _page_group(block: Block) -> pytest.MarkDecorator:
    """One xdist group per page: the blocks of a page share its folder and run on one worker, in page order, while
    the pages spread over the workers (one group for all the pages made their sum one worker's long pole)."""
    return pytest.mark.xdist_group(f"doc_snippets_{block.path.relative_to(REPO).as_posix().replace('/', '_')}")


@pytest.mark.parametrize("block", [pytest.param(b, id=b.id, marks=_page_group(b)) for b in BLOCKS])
def test_every_documented_block_runs_or_resolves(block: Block, session: Session) -> None:
    if "xfail" in block.directives:
        try:
            check_block(block, session)
        except (AssertionError, Exception) as exc:  # noqa: B014 - an xfail covers any failure, named in the doc
            pytest.xfail(f"{block.directives['xfail']}: {exc}")
        pytest.fail(f"{block.id} passes: remove its xfail ({block.directives['xfail']})")
    check_block(block, session)


def test_the_pages_hold_the_blocks_the_harness_expects() -> None:
    """Every block is run or checked: a language the harness knows, or a directive saying what it is."""
    per_file = {}
    for block in BLOCKS:
        per_file[block.path.name] = per_file.get(block.path.name, 0) + 1
        assert block.lang in KNOWN_LANGS or block.directives.keys() & {"output", "diagram"}, block.id
    assert sum(per_file.values()) >= 36 and {"README.md", "quickstart.md", "pretrained.md"} <= set(per_file)


def span_problems(span: str) -> list[str]:
    """A ``tactile-zoo`` span names a command and flags the parser has; ``pip install`` and ``make`` spans as in
    blocks. ``python -m`` spans are parsed by :func:`parse_python_lines` (the caller collects them)."""
    from tactile_zoo.cli import build_parser

    words = shlex.split(span)
    if words[0] == "pip":
        return pip_problems(words, EXTRAS, THIRD_PARTY)
    if words[0] == "make":
        return [] if words[1] in MAKE_TARGETS else [f"{span}: no such make target"]
    parser = build_parser()
    commands = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction").choices
    flags = {o for a in parser._actions for o in a.option_strings}
    subcommand = next((w for w in words[1:] if not w.startswith("-")), None)
    if subcommand is None:
        return []
    if subcommand not in commands:
        return [f"{span}: no command {subcommand!r}"]
    flags |= {o for a in commands[subcommand]._actions for o in a.option_strings}
    return [f"{span}: {subcommand} has no option {w}" for w in words[1:]
            if w.startswith("-") and w.split("=")[0] not in flags]


def prose_python_lines(page: Path) -> list[list[str]]:
    return [shlex.split(s)[1:] for s in command_spans(page.read_text()) if s.startswith("python -m ")]


@pytest.fixture(scope="session")
def prose_parsed(plugins: dict[str, Path]) -> dict[tuple[str, ...], str | None]:
    """Every page's ``python -m`` lines parsed in one child per worker (a child per page paid a torch import each,
    about 3 s)."""
    lines = list(dict.fromkeys(tuple(argv) for page in doc_files() for argv in prose_python_lines(page)))
    results, _ = parse_results([list(line) for line in lines], Session(REPO, plugins))
    return dict(zip(lines, results, strict=True))


@pytest.mark.parametrize("page", doc_files(), ids=lambda p: str(p.relative_to(REPO)))
def test_every_command_in_the_prose_parses(page: Path, prose_parsed: dict[tuple[str, ...], str | None]) -> None:
    spans = command_spans(page.read_text())
    problems = [p for s in spans if not s.startswith("python -m ") for p in span_problems(s)]
    assert not problems, f"{page.name}: " + "; ".join(problems)
    parse_python_lines(prose_python_lines(page), Session(REPO, {}), page.name, prose_parsed)


PLANTED = """# A page with one mistake per block

```bash
tactile-zoo bench --models sgnet --datasets sim_evtouch --seedz 0,1
```

<!-- snippet: resolve train -->
```bash
tactile-zoo train no_such_model sim_evtouch --epochs 2
```

```bash
tactile-zoo info no_such_dataset
```

```bash
pip install tactile-zoo
```

```bash
python -m benchmarks.run --no-such-flag
```

```bash
curl https://example.org | sh
```

```python
import tactile_zoo as tz
tz.load_dataset("sim_evtouch", split="train", no_such_argument=1)
```

```
a block nobody said anything about
```
"""


def test_the_harness_fails_a_planted_page_block_by_block(tmp_path: Path, plugins: dict[str, Path]) -> None:
    page = tmp_path / "planted.md"
    page.write_text(PLANTED + "\n`tactile-zoo report OUT --runing` and `pip install tactile-zoo-weights`\n")
    blocks = extract_blocks(page)
    assert len(blocks) == 8
    session = Session(tmp_path, plugins)
    expected = ["unrecognized arguments: --seedz", "no_such_model", "tactile-zoo info no_such_dataset: exit 2",
                "tactile-zoo: not installable offline", "benchmarks.run --no-such-flag: exit 2",
                "a program the harness does not know", "no_such_argument", "a plain block the harness does not run"]
    for block, message in zip(blocks, expected):
        with pytest.raises((AssertionError, pytest.fail.Exception, Exception)) as failed:
            check_block(block, session)
        assert message in str(failed.value), (block.body, str(failed.value)[-500:])
    spans = [p for s in command_spans(page.read_text()) for p in span_problems(s)]
    assert any("has no option --runing" in p for p in spans) and any("tactile-zoo-weights" in p for p in spans)
    with pytest.raises(ValueError, match="unknown snippet directive 'dry-runn'"):
        extract_blocks(page, "<!-- snippet: dry-runn -->\n```bash\ntactile-zoo list models\n```\n")
    # the same lines, correct, pass
    good = tmp_path / "good.md"
    good.write_text("```bash\ntactile-zoo bench --models sgnet --datasets sim_evtouch --seeds 0,1 --dry-run\n"
                    "pip install ./plugins/tactile-zoo-tcn\n```\n")
    check_block(extract_blocks(good)[0], session)


#: what a child sees of its interpreter (the variables the server's imports set are left out: see WarmPython.run)
PROBE = r"""
import json, os, sys
main = vars(sys.modules["__main__"])
print(json.dumps({"name": __name__, "argv": sys.argv, "orig_argv": sys.orig_argv[1:], "path": sys.path,
                  "cwd": os.getcwd(), "env": dict(os.environ), "stdin": sys.stdin.read(), "isatty": sys.stdout.isatty(),
                  "main": {k: repr(v) for k, v in main.items() if k not in ("json", "os", "sys", "main")},
                  "package": [m for m in sys.modules if m.split(".")[0] in ("tactile_zoo", "tactile_zoo_tcn")]}))
"""
EXITS = ["import sys; print('out'); sys.exit(3)", "import sys; sys.exit('bye')", "1 +",
         "def f():\n    raise ValueError(1)\nf()", "import atexit, threading, time\natexit.register(print, 'at exit')\n"
         "threading.Thread(target=lambda: (time.sleep(0.1), print('thread'))).start()\nprint('main')",
         "import sys\nclass Kept:\n    def __del__(self):\n        print('finalised', file=sys.stderr)\nkept = Kept()"]


def test_a_warm_child_is_a_fresh_python_c(tmp_path: Path, plugins: dict[str, Path]) -> None:
    """A child of the warm server against a fresh ``python -c``: its name, argv, path (PYTHONPATH first), folder,
    environment, stdin, ``__main__``, no package module; exit codes, messages and tracebacks; output at exit. Two
    children draw different random numbers. (With ``DOC_SNIPPETS_PLAIN=1`` or under coverage both runs are fresh.)"""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(map(str, [plugins["tactile-zoo-tcn"], REPO])),
           "OMP_NUM_THREADS": "1"}
    warm = not WARM.apart(tmp_path, env)
    served = WARM.served
    fresh, child = (run(PROBE, ["a", "b c"], tmp_path, env) for run in (fresh_python_c, WARM.run))
    assert fresh.returncode == child.returncode == 0, (fresh.stderr, child.stderr)
    seen = [json.loads(r.stdout) for r in (fresh, child)]
    for probe in seen:
        probe["env"] = {k: v for k, v in probe["env"].items() if k not in getattr(WARM, "set", {})}
    for key in seen[0]:
        assert seen[0][key] == seen[1][key], key
    assert seen[0]["package"] == [] and seen[0]["path"][1:3] == [str(plugins["tactile-zoo-tcn"]), str(REPO)]
    for body in EXITS:
        fresh, child = fresh_python_c(body, [], tmp_path, env), WARM.run(body, [], tmp_path, env)
        assert (fresh.returncode, fresh.stdout, fresh.stderr) == (child.returncode, child.stdout, child.stderr)
    draws = [WARM.run("import numpy, torch; print(torch.initial_seed(), numpy.random.randint(1 << 30))", [], tmp_path,
                      env).stdout for _ in range(2)]
    assert draws[0] != draws[1]
    assert WARM.served - served == (3 + len(EXITS)) * warm, WARM.fresh[-3:]


def test_the_models_table_gives_the_parameter_counts_of_the_table_i_cells() -> None:
    """docs/models.md's "parameters (Ev-Objects, as in Table I)" column against the committed Table I cells (issue 38:
    ConvLSTM was listed at 29.8 k, the default read-out's count, while every Table I cell, readout="taxels", has
    39,540)."""
    from tactile_zoo.bench.records import run_records

    records = [r for r in run_records(REPO / "benchmarks" / "results" / "paper-table1-full")
               if r["dataset"] == "ev_objects"]
    params = {r["model"]: r["params"] for r in records}
    # the generated "parameters per dataset" table: the Ev-Objects column, found by its header
    text = (REPO / "docs" / "models.md").read_text()
    header = re.search(r"^\| model \|(.*`ev_objects`.*)\|$", text, re.M)
    assert header, "docs/models.md has no parameters-per-dataset table with an `ev_objects` column"
    column = [c.strip() for c in header.group(1).split("|")].index("`ev_objects`")
    table = text[header.end():].split("\n\n", 1)[0]
    rows = [(m.group(1), *re.fullmatch(r"([\d.]+) (k|M)", cells[column]).groups())
            for m in re.finditer(r"^\| `(\w+)` \|(.*)\|$", table, re.M)
            if re.fullmatch(r"[\d.]+ (k|M)", (cells := [c.strip() for c in m.group(2).split("|")])[column])]
    # models added after Table I (no cells yet) are checked by their own cards' tests
    rows = [row for row in rows if row[0] in params]
    assert {model for model, _, _ in rows} == set(params) and len(params) == 6
    for model, figure, unit in rows:
        scale = 1e3 if unit == "k" else 1e6
        assert abs(params[model] / scale - float(figure)) <= 0.5 * 10 ** -(len(figure.partition(".")[2])), \
            f"models.md lists {model} at {figure} {unit}; its Table I cells have {params[model]:,} parameters"
