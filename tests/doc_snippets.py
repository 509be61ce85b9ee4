"""What tests/test_doc_snippets.py runs: every fenced block and command code span of README.md and docs/ (not
docs/pending/), split into what each line asks for.

A block says how it is exercised by its language and, where that is not enough, by an HTML comment on the line
before its fence, ``<!-- snippet: DIRECTIVE; DIRECTIVE ... -->`` (invisible on the site and on the index page):

- ``python`` blocks run as written, ``bash`` blocks line by line (see :func:`shell_commands`); ``toml`` and
  ``bibtex`` blocks are checked against the package (entry-point groups, version), ``yaml`` blocks are recipe files
  (read with ``tactile_zoo.registry.read_recipe_file``, which validates them);
- ``output``: a transcript: its ``$ `` lines are commands, run like a bash block's; the rest is not checked;
- ``diagram``: an architecture sketch, nothing to run;
- ``installed ./plugins/NAME``: the block needs that distribution installed, as the page says in prose;
- ``files NAME ...``: fixture files (:data:`FIXTURES`) written into the working folder before the block runs, for
  the placeholders a snippet reads (``grasp.csv``); the snippet itself is never rewritten;
- ``resolve SUBCOMMAND ...``: those ``tactile-zoo`` commands take minutes to hours: ``bench`` runs with ``--dry-run``,
  the others are parsed by the CLI's parser and their model, dataset and weights names looked up;
- ``not-run PROGRAM REASON``: lines of that program (a server, another tool) are not run;
- ``compile REASON``: a Python block that needs what CI has not (a cluster) is compiled, not run;
- ``xfail REASON``: the block fails until the named issue item is fixed.

A block without a directive in a language the harness does not run fails the suite, so a new block is covered or
says why not. A command line holding a placeholder (an upper-case word such as ``OUT``, ``CELL``, ``MODEL``) is
resolved, not run; ``DATA``, ``DIR`` and ``../shared/data`` stand for the real data home, which is substituted where
it is present.

A Python block (and the parse of a page's ``python -m`` lines) runs as ``python -c BODY``; to spare each the 2-5 s
of importing torch and PyG, :class:`WarmPython` runs it in a child forked from a server that imported them once per
test process, set up as the fresh interpreter would be (folder, environment, ``sys.path``, ``__main__``, exit
status and traceback); where it cannot stand in, and with ``DOC_SNIPPETS_PLAIN=1``, the child is a fresh one.
"""

from __future__ import annotations

import inspect
import json
import os
import re
import select
import shlex
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
DIRECTIVES = {"output", "diagram", "files", "installed", "resolve", "not-run", "compile", "xfail"}
#: languages run or checked without a directive
KNOWN_LANGS = {"python", "bash", "toml", "bibtex", "yaml"}
#: placeholders for the data home (quick start: ``--root DATA``; Datasets: ``DIR``; Table I: ``../shared/data``)
DATA_PLACEHOLDERS = ("DATA", "DIR", "../shared/data")
#: the two ``make`` commands CI's fresh clone runs (issue 38: exempt)
EXEMPT_MAKE = {"bench", "test"}
_PLACEHOLDER = re.compile(r"(?<![A-Za-z_])(?!DATA\b|DIR\b)[A-Z]{2,}(?![a-z_])")


@dataclass
class Block:
    """One fenced block: where it is, its language, its text and its directives."""

    path: Path
    line: int
    lang: str
    body: str
    directives: dict[str, str] = field(default_factory=dict)

    @property
    def id(self) -> str:
        where = self.path.relative_to(REPO) if self.path.is_relative_to(REPO) else self.path
        return f"{where}:{self.line}"


def doc_files(root: Path = REPO) -> list[Path]:
    """README.md and every page under docs/ except the notes in docs/pending/."""
    return [root / "README.md"] + sorted(p for p in (root / "docs").rglob("*.md") if "pending" not in p.parts)


def parse_directives(comment: str, where: str) -> dict[str, str]:
    """``output; files grasp.csv`` -> ``{"output": "", "files": "grasp.csv"}``; an unknown directive is an error."""
    found = {}
    for item in filter(None, (part.strip() for part in comment.split(";"))):
        key, _, value = item.partition(" ")
        if key not in DIRECTIVES:
            raise ValueError(f"{where}: unknown snippet directive {key!r} (known: {', '.join(sorted(DIRECTIVES))})")
        found[key] = value.strip()
    return found


def extract_blocks(path: Path, text: str | None = None) -> list[Block]:
    """Every fenced block of ``path`` with the directives of the comment just before it (blank lines between
    allowed)."""
    lines = (path.read_text() if text is None else text).splitlines()
    blocks, i = [], 0
    while i < len(lines):
        match = re.match(r"^\s*(`{3,}|~{3,})\s*([\w+-]*)", lines[i])
        if not match:
            i += 1
            continue
        fence, start = match.group(1), i
        j = i - 1
        while j >= 0 and not lines[j].strip():
            j -= 1
        comment = re.match(r"^\s*<!--\s*snippet:(.*?)-->\s*$", lines[j]) if j >= 0 else None
        i += 1
        while i < len(lines) and not lines[i].strip().startswith(fence):
            i += 1
        if i == len(lines):
            raise ValueError(f"{path}:{start + 1}: the fence is never closed")
        where = f"{path}:{start + 1}"
        blocks.append(Block(path, start + 1, match.group(2).lower(), "\n".join(lines[start + 1:i]),
                            parse_directives(comment.group(1), where) if comment else {}))
        i += 1
    return blocks


def code_spans(text: str) -> list[str]:
    """The inline code spans outside fenced blocks, whitespace (line breaks) collapsed."""
    prose = re.sub(r"^\s*(`{3,}|~{3,}).*?^\s*\1\s*$", "", text, flags=re.S | re.M)
    return [" ".join(span.split()) for span in re.findall(r"(?<!`)`([^`]+)`(?!`)", prose)]


def command_spans(text: str) -> list[str]:
    """The spans that are commands: ``tactile-zoo ...``, ``python -m ...``, ``pip install ...``, ``make ...`` (a
    leading ``VAR=value`` and anything after a pipe dropped)."""
    out = []
    for span in code_spans(text):
        span = re.sub(r"^(\w+=\S+\s+)+", "", span).split("|")[0].strip()
        if re.match(r"(tactile-zoo(\s|$)|python -m |pip install |make )", span):
            out.append(span)
    return out


def shell_commands(body: str, prompt: bool = False) -> list[list[str]]:
    """The commands of a shell block as argument lists: continuation lines joined, comments dropped, ``a && b`` as
    two commands; with ``prompt``, only the ``$ `` lines of a transcript."""
    joined, current = [], ""
    for line in body.splitlines():
        if prompt:
            if not line.startswith("$ "):
                continue
            line = line[2:]
        current += line.rstrip()
        if current.endswith("\\"):
            current = current[:-1] + " "
            continue
        joined.append(current)
        current = ""
    commands = []
    for line in joined:
        words = shlex.split(line, comments=True)
        while words:
            cut = words.index("&&") if "&&" in words else len(words)
            commands.append(words[:cut])
            words = words[cut + 1:]
    return [c for c in commands if c]


def has_placeholder(argv: list[str]) -> bool:
    """A word such as ``OUT``, ``CELL`` or ``MODEL`` in the command: it cannot run as written."""
    return any(_PLACEHOLDER.search(word) for word in argv[1:])


def substitute_data(argv: list[str], data: Path | None) -> list[str] | None:
    """``argv`` with the data-home placeholders replaced by ``data``; None when it needs data and there is none."""
    if not any(w in DATA_PLACEHOLDERS for w in argv):
        return argv
    if data is None:
        return None
    return [str(data) if w in DATA_PLACEHOLDERS else w for w in argv]


def pip_problems(argv: list[str], extras: set[str], third_party: set[str]) -> list[str]:
    """What is wrong with a documented ``pip install`` line: each target must install offline from a clone or a
    built wheel (``.``, ``.[extra]``, ``./plugins/<folder>``, a ``.whl`` path), or be a third-party requirement the
    project itself names (``third_party``: pyproject's dependencies and extras, the Makefile's pins)."""
    problems = []
    targets = [w for w in argv[2:] if not w.startswith("-")]
    if not targets:
        problems.append(f"{shlex.join(argv)}: names nothing to install")
    for target in targets:
        local = re.fullmatch(r"(\.|\./plugins/[\w.-]+)(\[([\w,-]+)\])?", target)
        if local:
            if local.group(1) != "." and not (REPO / local.group(1)).is_dir():
                problems.append(f"{target}: no such folder in the clone")
            unknown = set((local.group(3) or "").split(",")) - extras - {""}
            if unknown and local.group(1) == ".":
                problems.append(f"{target}: no extra {sorted(unknown)} in pyproject.toml")
        elif target.endswith(".whl"):
            continue
        else:
            name = re.split(r"[\[<>=!~; ]", target, maxsplit=1)[0].lower().replace("_", "-")
            if name.startswith("tactile-zoo") or name not in third_party:
                problems.append(f"{target}: not installable offline from a clone or a built wheel (tactile-zoo is "
                                f"not on the index: use ., .[extra], ./plugins/<folder> or a wheel path)")
    return problems


# ----------------------------------------------------------------------------------------------- fixture files
def _recording(steps: int = 250, columns: int = 78, seed: int = 0) -> np.ndarray:
    """One Ev-Objects grasp in the recordings format: 250 steps x (39 taxels x 2 polarities) event counts."""
    return np.random.default_rng(seed).poisson(0.05, size=(steps, columns)).astype(np.float32)


def _write_csv(path: Path, table: np.ndarray) -> None:
    path.write_text("\n".join(",".join(f"{v:g}" for v in row) for row in table) + "\n")


def _my_grasps(cwd: Path) -> None:
    """``DIR/my_grasps/raw/<class>/<trial>.csv``: 3 classes x 5 trials of 20 BioTac SP readings (24 columns)."""
    for c in range(3):
        folder = cwd / "DIR" / "my_grasps" / "raw" / f"class_{c}"
        folder.mkdir(parents=True)
        for t in range(5):
            _write_csv(folder / f"trial_{t}.csv", _recording(20, 24, seed=10 * c + t) + c)


def _biotac_recording(cwd: Path) -> None:
    """``bottle12.csv`` in BioTac-DoS's release format: a header ``ff_e1..ff_e24``, then 275 rows of 24 integer
    electrode readings."""
    rows = np.random.default_rng(4).integers(2200, 3400, size=(275, 24))
    header = ",".join(f"ff_e{i}" for i in range(1, 25))
    (cwd / "bottle12.csv").write_text(header + "\n" + "\n".join(",".join(map(str, r)) for r in rows) + "\n")


FIXTURES = {
    "grasp.csv": lambda cwd: _write_csv(cwd / "grasp.csv", _recording()),
    "grasp1.csv": lambda cwd: _write_csv(cwd / "grasp1.csv", _recording(seed=1)),
    "grasp.npy": lambda cwd: np.save(cwd / "grasp.npy", _recording(seed=2)),
    "grasp2.npy": lambda cwd: np.save(cwd / "grasp2.npy", _recording(seed=3)),
    "DIR/my_grasps": _my_grasps,
    "bottle12.csv": _biotac_recording,
}


# ------------------------------------------------------------------------------------------------ the warm server
#: set to 1 to run every Python child in a fresh ``python -c`` (the plain path), never in the warm server
PLAIN_SWITCH = "DOC_SNIPPETS_PLAIN"
#: what the warm server imports once: torch (about 2 s of CPU a child), PyG (3 s more), and what the package imports on
#: its first fit or evaluate: numba (its kernels, 0.4 s) and sklearn.metrics (0.8 s); never the package itself
WARM_PRELOAD = ("torch", "torch_geometric", "numba", "sklearn.metrics")
#: variables a child's environment may hold apart from the server's (the server checks that its imports read none):
#: the path (rebuilt per child), pytest's current test, the package's own, MLflow's (``bench --tracker mlflow`` sets
#: one in the tests' process)
WARM_FREE = ("PYTHONPATH", "PYTEST_CURRENT_TEST", "TACTILE_ZOO_", "MLFLOW_")


def _warm_server() -> None:  # noqa: C901 - one program, sent whole as `python -c` source
    """The warm server's program (``python -c SOURCE PRELOAD``: it shares nothing with the tests). It imports
    ``PRELOAD``, noting which variables the imports read and set, answers what it holds, then for each request (a
    JSON line) forks a child that runs the body as ``python -c BODY ARGS`` would, in the request's folder,
    environment (with what the imports set, as they would have set it) and ``sys.path``, stdin /dev/null and
    stdout/stderr in the request's files; it answers the child's pid, then its exit status and CPU seconds. The
    server runs no torch op, so no thread pool exists when it forks; it checks that it is alone before each fork.
    What the imports made is frozen (:func:`gc.freeze`): a child's collections skip it (they would copy its pages,
    about 1 s of CPU a child), as they skip nothing the child makes."""
    import atexit
    import builtins
    import gc
    import importlib
    import json
    import os
    import sys
    import threading
    import types

    requests, replies = os.fdopen(os.dup(0), "r"), os.fdopen(os.dup(1), "w")  # non-inheritable copies
    null = os.open(os.devnull, os.O_RDWR)
    os.dup2(null, 0)
    os.dup2(null, 1)

    def reply(**message: object) -> None:
        replies.write(json.dumps(message) + "\n")
        replies.flush()

    read, environ, start = set(), type(os.environ), dict(os.environ)

    class Reading(environ):  # os.environ itself, for the imports: every name they look up is noted
        def __getitem__(self, key: str) -> str:
            read.add(key)
            return super().__getitem__(key)

        def __contains__(self, key: object) -> bool:
            read.add(key)
            return super().__contains__(key)

    os.environ.__class__ = Reading
    for name in json.loads(sys.argv[1]):
        importlib.import_module(name)
    os.environ.__class__ = environ
    gc.freeze()  # what the imports made, out of the collector's sight: a child's collections do not copy its pages
    files = {name: getattr(module, "__file__", None) for name, module in list(sys.modules.items())}
    home = (sys.prefix, sys.base_prefix)
    maps = {line.split()[-1] for line in open("/proc/self/maps").read().splitlines() if ".so" in line}
    reply(read=sorted(read), set={k: v for k, v in os.environ.items() if start.get(k) != v},
          kmp=sorted(p for p in maps if os.path.basename(p).startswith(("libiomp", "libomp"))),
          unset=sorted(start.keys() - os.environ.keys()), modules=sorted({name.split(".")[0] for name in files}),
          foreign=sorted(name for name, file in files.items()  # torch.ops' "_ops.py" is no file
                         if isinstance(file, str) and os.path.isabs(file) and not file.startswith(home)))
    for line in requests:
        job = json.loads(line)
        tasks = len(os.listdir("/proc/self/task"))
        if tasks != 1 or threading.active_count() != 1:
            reply(refused=f"{tasks} threads in the server")
            continue
        sys.stdout.flush()
        sys.stderr.flush()
        pid = os.fork()
        if pid == 0:
            break
        reply(pid=pid)
        _, status, usage = os.wait4(pid, 0)
        reply(rc=os.waitstatus_to_exitcode(status), cpu=usage.ru_utime + usage.ru_stime)
    else:
        return
    # the child: what `python -c BODY ARGS` would be, started in the request's folder and environment
    requests.close()
    replies.close()
    for fd, path in ((1, job["stdout"]), (2, job["stderr"])):
        out = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        os.dup2(out, fd)
        os.close(out)
    os.close(null)
    os.chdir(job["cwd"])
    os.environ.clear()
    os.environ.update(job["env"])
    sys.path[:] = job["path"]
    sys.path_importer_cache.clear()
    importlib.invalidate_caches()
    sys.argv = ["-c", *job["args"]]
    sys.orig_argv = [sys.orig_argv[0], "-c", job["body"], *job["args"]]
    if "numpy" in sys.modules:  # random's own state is reseeded at fork; these would repeat the server's
        sys.modules["numpy"].random.seed()
    if "torch" in sys.modules:
        sys.modules["torch"].seed()
    main = types.ModuleType("__main__")
    vars(main).update(__loader__=sys.modules["__main__"].__loader__, __annotations__={}, __builtins__=builtins)
    sys.modules["__main__"] = main
    code = 0
    try:
        exec(compile(job["body"], "<string>", "exec"), vars(main))
    except SystemExit as exc:  # as the interpreter handles it: None is 0, an int itself, else its text and 1
        if exc.code is None or isinstance(exc.code, int):
            code = exc.code or 0
        else:
            print(exc.code, file=sys.stderr)
            code = 1
    except BaseException as exc:  # noqa: BLE001 - as `python -c`: the traceback (from the body down), exit 1
        exc.__traceback__ = exc.__traceback__.tb_next  # this frame is not the body's
        sys.excepthook(type(exc), exc, exc.__traceback__)
        code = 1
    # the interpreter's exit, in its order: non-daemon threads joined, atexit handlers, the body's own objects
    # finalised (a file it left open is flushed) and the streams flushed; not the teardown of every module, whose
    # reference counts would copy the server's pages (0.3-0.5 s of CPU a child, a fresh interpreter's is 0.02 s)
    threading._shutdown()
    atexit._run_exitfuncs()
    sys.modules.pop("__main__", None)  # the body's namespace freed, or collected with its cycles, globals intact
    del main
    gc.collect()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except Exception:  # noqa: BLE001 - as the interpreter: a stream it cannot flush makes the exit status 120
            code = 120
    os._exit(code & 0xFF)


#: the server's program as sent (read when this module is imported, not when a server starts from an edited file)
WARM_SERVER = inspect.getsource(_warm_server) + f"\n{_warm_server.__name__}()\n"


class WarmPython:
    """One warm server per process (an xdist worker), started on first use: :meth:`run` is ``python -c BODY ARGS``
    as :func:`subprocess.run` gives it (exit status, stdout, stderr; :class:`subprocess.TimeoutExpired` past the
    timeout), where the server can stand in for a fresh interpreter (:meth:`apart`); 2-5 s of CPU less a child."""

    def __init__(self) -> None:
        self.proc: subprocess.Popen | None = None
        self.broken = ""  # why the server cannot serve (then every child runs fresh)
        self.paths: dict[str | None, list[str]] = {}
        self.base: dict[str, str] = {}  # the server's environment when it started
        self.served, self.cpu, self.fresh = 0, 0.0, []  # children served, their CPU seconds; (why fresh) per other

    def apart(self, cwd: Path, env: dict[str, str]) -> str:
        """Why a child in ``cwd`` under ``env`` must start fresh ("" if the server can stand in): switched off, a
        coverage measurement (each child measures from its own start), more than one OpenMP thread (read when torch
        loads), a variable set apart from the server's (besides :data:`WARM_FREE`, the ones its imports set as the
        child's would, and Intel OpenMP's ``KMP_*`` (scikit-learn sets two) where the server loaded none and read
        none), or a module the server holds that the child's folder or path would shadow."""
        if self.broken:
            return self.broken
        if env.get(PLAIN_SWITCH, os.environ.get(PLAIN_SWITCH)) == "1":
            return PLAIN_SWITCH
        if not hasattr(os, "fork") or not Path("/proc/self/task").is_dir():
            return "no fork or /proc"
        coverage = sorted(k for k in env if k.startswith(("COVERAGE_", "COV_CORE_")))  # coverage.py, pytest-cov < 7
        if coverage:
            return f"coverage measured ({', '.join(coverage)})"
        if env.get("OMP_NUM_THREADS") != "1":
            return "OMP_NUM_THREADS is not 1"
        if self.proc is None:
            return ""  # the server starts in this environment
        mine = _server_env(env)
        apart = sorted(k for k in self.base.keys() | mine.keys() if mine.get(k) != self.base.get(k)
                       and not (k in self.set and mine.get(k) == self.set[k] or k in self.unset and k not in mine)
                       and not (k.startswith("KMP_") and k not in self.read and not self.kmp))
        if apart:
            return f"variables {apart} apart from the server's"
        folders = [cwd, *filter(None, env.get("PYTHONPATH", "").split(os.pathsep))]
        shadow = {p.name.split(".")[0] for d in folders if Path(d).is_dir() for p in Path(d).iterdir()} & self.modules
        return f"{sorted(shadow)} in the child's folder or path" if shadow else ""

    def start(self, env: dict[str, str]) -> None:
        self.base = _server_env(env)
        self.home = Path(tempfile.mkdtemp(prefix="doc_snippets_warm_"))
        self.log = (self.home / "server.log").open("w")
        self.proc = subprocess.Popen([sys.executable, "-c", WARM_SERVER, json.dumps(WARM_PRELOAD)], cwd=self.home,
                                     env=self.base, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self.log)
        self._buffer = b""
        ready = self._message(300)
        self.set, self.unset, self.modules = ready["set"], set(ready["unset"]), set(ready["modules"])
        self.read, self.kmp = set(ready["read"]), ready["kmp"]
        free = [k for k in ready["read"] if k.startswith(WARM_FREE)]
        if ready["foreign"] or free:
            self.close(f"preloaded modules from outside the interpreter's prefixes {ready['foreign'][:5]}"
                       if ready["foreign"] else f"the imports read {free}")

    def run(self, body: str, args: list[str], cwd: Path, env: dict[str, str],
            timeout: float = 300) -> subprocess.CompletedProcess:
        """``python -c BODY ARGS`` in ``cwd`` under ``env``: a child of the server where it can stand in (started
        now if it is not yet), else a fresh interpreter."""
        if self.proc is None and not self.apart(cwd, env):
            self.start(env)
        why = self.apart(cwd, env)
        if why:
            self.fresh.append(why)
            return fresh_python_c(body, args, cwd, env, timeout)
        key = env.get("PYTHONPATH")
        if key not in self.paths:  # sys.path as a fresh interpreter builds it from this PYTHONPATH
            probe = fresh_python_c("import json, sys; print(json.dumps(sys.path))", [], self.home, env, 60)
            self.paths[key] = json.loads(probe.stdout)
        # what the server's imports set in its environment, they would have set in the child's
        child = {**env, **{k: v for k, v in self.set.items() if env.get(k) == self.base.get(k)}}
        child = {k: v for k, v in child.items() if k not in self.unset or env.get(k) != self.base.get(k)}
        out, err = self.home / "stdout", self.home / "stderr"
        job = {"body": body, "args": args, "cwd": str(cwd), "env": child, "path": self.paths[key],
               "stdout": str(out), "stderr": str(err)}
        self.proc.stdin.write((json.dumps(job) + "\n").encode())
        self.proc.stdin.flush()
        started = self._message(60)
        if "refused" in started:
            self.close(started["refused"])
            self.fresh.append(self.broken)
            return fresh_python_c(body, args, cwd, env, timeout)
        try:
            done = self._message(timeout)
        except TimeoutError:
            os.kill(started["pid"], signal.SIGKILL)
            self._message(60)
            raise subprocess.TimeoutExpired([sys.executable, "-c", body, *args], timeout, out.read_text(),
                                            err.read_text()) from None
        self.served, self.cpu = self.served + 1, self.cpu + done["cpu"]
        return subprocess.CompletedProcess([sys.executable, "-c", body, *args], done["rc"], out.read_text(),
                                           err.read_text())

    def _message(self, timeout: float) -> dict:
        deadline = time.monotonic() + timeout
        while b"\n" not in self._buffer:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([self.proc.stdout], [], [], left)[0]:
                raise TimeoutError(f"the warm server did not answer in {timeout} s")
            chunk = os.read(self.proc.stdout.fileno(), 1 << 16)
            if not chunk:
                self.log.flush()
                raise RuntimeError("the warm server died:\n" + (self.home / "server.log").read_text()[-3000:])
            self._buffer += chunk
        line, _, self._buffer = self._buffer.partition(b"\n")
        return json.loads(line)

    def close(self, why: str = "") -> None:
        """End the server (it leaves its loop at the end of its input) and remove its folder; with ``why``, for
        good: every later child starts fresh."""
        self.broken = why
        if self.proc is not None:
            self.proc.stdin.close()
            try:
                self.proc.wait(30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
            self.proc.stdout.close()
            self.log.close()
            shutil.rmtree(self.home, ignore_errors=True)
            self.proc = None


def _server_env(env: dict[str, str]) -> dict[str, str]:
    return {k: v for k, v in env.items() if not k.startswith(WARM_FREE)}


def fresh_python_c(body: str, args: list[str], cwd: Path, env: dict[str, str],
                   timeout: float = 300) -> subprocess.CompletedProcess:
    """``python -c BODY ARGS`` in a fresh interpreter (the plain path)."""
    return subprocess.run([sys.executable, "-c", body, *args], cwd=cwd, env=env, stdin=subprocess.DEVNULL,
                          capture_output=True, text=True, timeout=timeout)


def python_c(body: str, args: list[str], cwd: Path, env: dict[str, str], warm: WarmPython | None,
             timeout: float = 300) -> subprocess.CompletedProcess:
    """``python -c BODY ARGS`` in ``cwd`` under ``env`` (stdin /dev/null, stdout and stderr captured as text): a
    child of the warm server where it can stand in for a fresh interpreter, else a fresh one."""
    return (warm.run if warm is not None else fresh_python_c)(body, args, cwd, env, timeout)
