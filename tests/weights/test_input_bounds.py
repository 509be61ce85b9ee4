"""Issue 28, bounded input: ``predict`` and ``stream`` read a recording in bounded memory, refuse a file above the size
limit, and refuse anything that is not a regular file (a device behind a symlink, a FIFO) without opening it.

The memory and non-regular-file checks run the real command in a subprocess: peak memory is the process's own
``ru_maxrss``, compared with the same command on a small file, and a command that would hang on a FIFO is stopped by
the subprocess timeout instead of hanging the suite.
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from weights_helpers import MODEL, Trained, sample_table

import tactile_zoo as tz
from tactile_zoo.errors import ConfigError, DatasetError

#: The documented setting of the input size limit, in MiB (default 2048).
MAX_INPUT_ENV = "TACTILE_ZOO_MAX_INPUT_MB"
PACKAGE_ROOT = Path(tz.__file__).resolve().parent.parent

#: Runs the CLI and writes the process's peak resident memory (KiB on Linux) to argv[1].
_PEAK = ("import resource, sys\n"
         "from tactile_zoo.cli import main\n"
         "rc = main(sys.argv[2:])\n"
         "open(sys.argv[1], 'w').write(str(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss))\n"
         "sys.exit(rc)\n")


def _env() -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != MAX_INPUT_ENV}  # the default limit
    env.update(PYTHONPATH=os.pathsep.join([str(PACKAGE_ROOT), env.get("PYTHONPATH", "")]), OMP_NUM_THREADS="1")
    return env


def _limit_heap() -> None:
    # a reader that loops on /dev/zero would eat the machine's memory before the timeout; with this ceiling it fails
    # fast with MemoryError instead (the fixed reader never gets near it: its baseline is a few hundred MiB)
    resource.setrlimit(resource.RLIMIT_DATA, (6 * 2**30, 6 * 2**30))


def _run(args: list[str], timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "tactile_zoo.cli", *args], capture_output=True, text=True,
                          timeout=timeout, env=_env(), preexec_fn=_limit_heap)


def _local(trained: Trained) -> list[str]:
    return ["--weights", str(trained.file), "--manifest", str(trained.manifest)]


def _peak_kib(trained: Trained, file: Path, tmp_path: Path) -> tuple[int, str]:
    out = tmp_path / f"peak-{file.stem}.txt"
    proc = subprocess.run([sys.executable, "-c", _PEAK, str(out), "predict", MODEL, *_local(trained), str(file),
                           "--top-k", "1"], capture_output=True, text=True, timeout=600, env=_env(),
                          preexec_fn=_limit_heap)
    assert proc.returncode == 0, proc.stderr
    return int(out.read_text()), proc.stdout


def test_a_1_gib_npy_is_predicted_in_bounded_memory(trained: Trained, tmp_path: Path) -> None:
    """1 GiB of valid float32 rows of which predict uses the first 12: the peak stays within 300 MiB of the same
    command on a 12-row file (the old reader held the whole file, then a float64 copy: gigabytes)."""
    table = sample_table(trained.test, 0)  # (12, 188)
    small = tmp_path / "small.npy"
    np.save(small, table)
    big = tmp_path / "big.npy"
    rows = 2**30 // (table.shape[1] * 4)
    mapped = np.lib.format.open_memmap(big, mode="w+", dtype=np.float32, shape=(rows, table.shape[1]))  # sparse
    mapped[: len(table)] = table
    mapped.flush()
    del mapped
    assert 2**30 <= big.stat().st_size < 2048 * 2**20  # within the default limit
    base, base_out = _peak_kib(trained, small, tmp_path)
    peak, out = _peak_kib(trained, big, tmp_path)
    assert f"({rows} steps, cropped to 12)" in out  # every row counted, the first 12 used
    assert out.splitlines()[4].split()[1] == base_out.splitlines()[4].split()[1]  # the small file's answer
    growth_mib = (peak - base) / 1024
    print(f"peak RSS: {base / 1024:.0f} MiB on 12 rows, {peak / 1024:.0f} MiB on 1 GiB (+{growth_mib:.0f} MiB)")
    assert growth_mib < 300, f"peak {peak / 1024:.0f} MiB on the 1 GiB file vs {base / 1024:.0f} MiB on 12 rows"


@pytest.mark.parametrize("command", ["predict", "stream"])
@pytest.mark.parametrize("kind", ["a character device", "a FIFO (named pipe)"])
def test_a_device_behind_a_symlink_and_a_fifo_are_refused_without_reading(trained: Trained, tmp_path: Path,
                                                                          command: str, kind: str) -> None:
    if kind == "a character device":
        path = tmp_path / "grasp.npy"
        path.symlink_to("/dev/zero")  # endless zeros: a reader that reads to the end never ends
    else:
        path = tmp_path / "grasp.csv"
        os.mkfifo(path)  # no writer ever comes: open() for reading blocks forever
    args = [MODEL, *_local(trained), str(path)] if command == "predict" else \
        [MODEL, *_local(trained), "--file", str(path)]
    try:
        proc = _run([command, *args], timeout=240)
    except subprocess.TimeoutExpired:
        pytest.fail(f"{command} {path.name} ({kind}) hung")
    err = proc.stderr.strip()
    assert proc.returncode == 2, err[-2000:]
    assert err == f"tactile-zoo: error: {path}: {kind}, not a regular file; only regular files are read"
    assert proc.stdout == ""


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
