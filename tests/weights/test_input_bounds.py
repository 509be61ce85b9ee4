"""Issue 28, bounded input: ``predict`` and ``stream`` read a recording in bounded memory, refuse a file above the size
limit, and refuse anything that is not a regular file (a device behind a symlink, a FIFO) without opening it.

The memory and non-regular-file checks run the real command in a subprocess: one child runs every command of this module
in turn (forked from the warm server of tests/forked_bench.py, torch and the package imported: not six interpreters, nor
one), each with its own stdout and stderr (the file descriptors themselves, so that what C code writes is seen too), its
exit code, and the process's peak resident memory (``ru_maxrss``) after it. Peak memory on a 1 GiB file is compared with
the peak after the same command on a small file, run first. A command that would hang on a FIFO is stopped by an alarm
in the child (and the child by the subprocess timeout) instead of hanging the suite.
"""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from forked_bench import finish_python
from weights_helpers import MODEL, Trained, sample_table

import tactile_zoo as tz
from tactile_zoo.errors import ConfigError, DatasetError

#: The documented setting of the input size limit, in MiB (default 2048).
MAX_INPUT_ENV = "TACTILE_ZOO_MAX_INPUT_MB"
#: seconds a refusal may take in the child before it counts as hung (imports are done by then: the first command,
#: on the small file, paid for them)
HANG_S = 120

#: Runs the CLI commands of the JSON list argv[2] (``[argv, alarm seconds or 0]``) in turn, each with file descriptors
#: 1 and 2 on files of its own; appends one JSON line per command to argv[1]: its exit code ("hung" when the alarm
#: stopped it; 1 and the traceback
#: on stderr for an exception main() let through, as a process of its own), its stdout and stderr, and the
#: process's peak resident memory after it (KiB on Linux).
_RUNNER = """
import json, os, resource, signal, sys, traceback
from tactile_zoo.cli import main

os.environ.pop("TACTILE_ZOO_MAX_INPUT_MB", None)  # the default limit
# a reader that loops on /dev/zero would eat the machine's memory before the timeout; with this ceiling it fails
# fast with MemoryError instead (the fixed reader never gets near it: its baseline is a few hundred MiB)
resource.setrlimit(resource.RLIMIT_DATA, (6 * 2**30, 6 * 2**30))

class Hung(BaseException):
    pass

def _alarm(signum, frame):
    raise Hung

signal.signal(signal.SIGALRM, _alarm)
results = sys.argv[1]
for i, (argv, alarm) in enumerate(json.loads(sys.argv[2])):
    out, err = f"{results}.{i}.out", f"{results}.{i}.err"
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    with open(out, "w") as o, open(err, "w") as e:
        os.dup2(o.fileno(), 1)
        os.dup2(e.fileno(), 2)
        signal.alarm(alarm)
        try:
            rc = main(argv)
        except Hung:
            rc = "hung"
        except SystemExit as exc:
            rc = exc.code
        except BaseException:  # what a process of its own would do: the traceback, exit 1
            traceback.print_exc()
            rc = 1
        finally:
            signal.alarm(0)
            sys.stdout.flush()
            sys.stderr.flush()
            for fd, copy in enumerate(saved, start=1):
                os.dup2(copy, fd)
                os.close(copy)
    with open(out) as o, open(err) as e:
        row = {"rc": rc, "stdout": o.read(), "stderr": e.read(),
               "peak_kib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss}
    with open(results, "a") as fh:
        fh.write(json.dumps(row) + "\\n")
"""

#: the non-regular files: a device behind a symlink, a FIFO
KINDS = ("a character device", "a FIFO (named pipe)")
COMMANDS = ("predict", "stream")


def _local(trained: Trained) -> list[str]:
    return ["--weights", str(trained.file), "--manifest", str(trained.manifest)]


def _run_cli(commands: dict[Any, tuple[list[str], int]], folder: Path, timeout: float = 900
             ) -> dict[Any, dict[str, Any]]:
    """Each command's result (:data:`_RUNNER`), by its key (the values: argv and the alarm's seconds, 0 for none); a
    command the child did not finish gets exit code ``None`` and the child's failure."""
    results = folder / "results.jsonl"
    try:
        status, _, err = finish_python(_RUNNER, [str(results), json.dumps(list(commands.values()))],
                                       folder / "child", timeout)
        failure = f"the child exited {status}: {err[-2000:]}" if status else ""
    except subprocess.TimeoutExpired:
        failure = f"the child ran past {timeout} s"
    rows = [json.loads(line) for line in results.read_text().splitlines()] if results.exists() else []
    done = dict(zip(commands, rows))
    return {key: done.get(key) or {"rc": None, "failure": failure} for key in commands}


@pytest.fixture(scope="module")
def cli(trained: Trained, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """The files, and every command of this module run once in one child: ``predict`` on a 12-row file, then on a
    1 GiB file; ``predict`` and ``stream`` on a device behind a symlink and on a FIFO."""
    folder = tmp_path_factory.mktemp("input_bounds")
    table = sample_table(trained.test, 0)  # (12, 188)
    small = folder / "small.npy"
    np.save(small, table)
    big = folder / "big.npy"
    rows = 2**30 // (table.shape[1] * 4)
    mapped = np.lib.format.open_memmap(big, mode="w+", dtype=np.float32, shape=(rows, table.shape[1]))  # sparse
    mapped[: len(table)] = table
    mapped.flush()
    del mapped
    device = folder / "grasp.npy"
    device.symlink_to("/dev/zero")  # endless zeros: a reader that reads to the end never ends
    fifo = folder / "grasp.csv"
    os.mkfifo(fifo)  # no writer ever comes: open() for reading blocks forever
    paths = {KINDS[0]: device, KINDS[1]: fifo}
    commands: dict[Any, tuple[list[str], int]] = {
        name: (["predict", MODEL, *_local(trained), str(path), "--top-k", "1"], 0)
        for name, path in (("small", small), ("big", big))}
    for kind, path in paths.items():
        commands[("predict", kind)] = (["predict", MODEL, *_local(trained), str(path)], HANG_S)
        commands[("stream", kind)] = (["stream", MODEL, *_local(trained), "--file", str(path)], HANG_S)
    return {"results": _run_cli(commands, folder), "rows": rows, "big": big, "paths": paths}


@pytest.mark.xdist_group("input_bounds")  # one worker runs the module's one child
def test_a_1_gib_npy_is_predicted_in_bounded_memory(cli: dict[str, Any]) -> None:
    """1 GiB of valid float32 rows of which predict uses the first 12: the peak stays within 300 MiB of the same
    command on a 12-row file (the old reader held the whole file, then a float64 copy: gigabytes)."""
    assert 2**30 <= cli["big"].stat().st_size < 2048 * 2**20  # within the default limit
    base, big = cli["results"]["small"], cli["results"]["big"]
    for run in (base, big):
        assert run["rc"] == 0, run
    assert f"({cli['rows']} steps, cropped to 12)" in big["stdout"]  # every row counted, the first 12 used
    assert big["stdout"].splitlines()[4].split()[1] == base["stdout"].splitlines()[4].split()[1]  # the same answer
    growth_mib = (big["peak_kib"] - base["peak_kib"]) / 1024
    print(f"peak RSS: {base['peak_kib'] / 1024:.0f} MiB after 12 rows, {big['peak_kib'] / 1024:.0f} MiB after 1 GiB "
          f"(+{growth_mib:.0f} MiB)")
    assert growth_mib < 300, f"peak {big['peak_kib'] / 1024:.0f} MiB after the 1 GiB file vs " \
                             f"{base['peak_kib'] / 1024:.0f} MiB after 12 rows"


@pytest.mark.xdist_group("input_bounds")
@pytest.mark.parametrize("command", COMMANDS)
@pytest.mark.parametrize("kind", KINDS)
def test_a_device_behind_a_symlink_and_a_fifo_are_refused_without_reading(cli: dict[str, Any], command: str,
                                                                          kind: str) -> None:
    path, run = cli["paths"][kind], cli["results"][(command, kind)]
    if run["rc"] == "hung":
        pytest.fail(f"{command} {path.name} ({kind}) hung")
    err = run["stderr"].strip()
    assert run["rc"] == 2, run.get("failure") or err[-2000:]
    assert err == f"tactile-zoo: error: {path}: {kind}, not a regular file; only regular files are read"
    assert run["stdout"] == ""


def test_a_file_above_the_size_limit_is_refused_naming_the_limit(trained: Trained, tmp_path: Path,
                                                                monkeypatch: pytest.MonkeyPatch) -> None:
    table = sample_table(trained.test, 0)
    npy, csv = tmp_path / "r.npy", tmp_path / "r.csv"
    np.save(npy, table)
    csv.write_text("\n".join(",".join(f"{v:.9g}" for v in row) for row in table) + "\n")
    assert len(tz.predict(trained.model, [npy, csv])) == 2  # within the default limit
    monkeypatch.setenv(MAX_INPUT_ENV, "0.004")  # 4194 bytes: both files are larger
    for path in (npy, csv):
        with pytest.raises(DatasetError, match=rf"^{path}: [0-9]+ bytes, above the input size limit of 4194 bytes "
                                               rf"\(set {MAX_INPUT_ENV} to raise the limit\)$"):
            tz.predict(trained.model, [path])
    for bad in ("0", "-1", "lots", "1_0", "inf"):
        monkeypatch.setenv(MAX_INPUT_ENV, bad)
        with pytest.raises(ConfigError, match=rf"\${MAX_INPUT_ENV}=.*expected a positive number of MiB"):
            tz.predict(trained.model, [npy])
