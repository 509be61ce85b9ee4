"""tactile_zoo.engine.malloc: the start-up malloc settings are applied by training processes, not by an import, are
skipped with TACTILE_ZOO_DEFAULT_MALLOC=1 and off glibc, and make a rewritten large buffer cost no page faults."""

from __future__ import annotations

import json
import sys
import textwrap
from pathlib import Path

import pytest
from forked_bench import run_python

from tactile_zoo.engine import malloc

GLIBC = sys.platform.startswith("linux") and malloc._mallopt() is not None

# Hold as many large blocks as the settings let glibc map (M_MMAP_MAX), then allocate, write and free a 40 MB block
# (above glibc's largest mmap threshold, 32 MiB: by default a fresh mmap each time) and count the page faults of
# writing a second one of the same size: none where it came back from the heap already faulted in. One child runs
# its modes in order and prints one line per mode; each mode frees what it held, so the next starts from the
# allocator as that mode left it. The children are forked from the warm server of tests/forked_bench.py, which
# imported torch and the package (an interpreter's start-up is most of a child's cost) and never tunes malloc: a
# child starts with glibc's defaults, as a new process does.
_CHILD = textwrap.dedent("""
    import ctypes, json, os, resource, sys
    os.environ.pop("TACTILE_ZOO_DEFAULT_MALLOC", None)
    for mode in sys.argv[1:]:
        result = None
        if mode in ("opt_out", "allow"):  # the opt-out variable set, or gone (as in a process started without it)
            if mode == "opt_out":
                os.environ["TACTILE_ZOO_DEFAULT_MALLOC"] = "1"
            else:
                os.environ.pop("TACTILE_ZOO_DEFAULT_MALLOC", None)
            continue
        if mode == "tune":
            from tactile_zoo.engine.malloc import tune_malloc
            result = tune_malloc()
        elif mode == "worker":
            from tactile_zoo.bench.worker import setup_worker
            setup_worker()
        else:  # importing the package and its training layers changes nothing
            import tactile_zoo, tactile_zoo.bench, tactile_zoo.cli, tactile_zoo.engine  # noqa: F401
        from tactile_zoo.engine.malloc import SETTINGS
        libc = ctypes.CDLL(None)
        libc.malloc.restype, libc.malloc.argtypes = ctypes.c_void_p, [ctypes.c_size_t]
        libc.free.argtypes = [ctypes.c_void_p]
        size = 40 << 20
        # never written: no memory used; at most 64, so that a cap too high to matter leaves the block mapped
        held = [libc.malloc(size) for _ in range(min(SETTINGS.get("M_MMAP_MAX", 0), 64))]
        first = libc.malloc(size)
        ctypes.memset(first, 1, size)
        libc.free(first)
        before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
        second = libc.malloc(size)
        ctypes.memset(second, 2, size)
        faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before
        byte = ctypes.string_at(second + size - 1, 1)[0]
        for block in [*held, second]:
            libc.free(block)
        print(json.dumps({"mode": mode, "result": result, "faults": faults, "byte": byte}), flush=True)
""")


def _child(log: Path, *modes: str) -> dict[str, dict]:
    """Each mode's measurement, in one forked child that runs them in order (its output in ``log``.out/.err)."""
    out, err = run_python(_CHILD, list(modes), log)
    rows = [json.loads(line) for line in out.splitlines() if line.startswith('{"mode"')]
    assert [row["mode"] for row in rows] == [m for m in modes if m not in ("opt_out", "allow")], (out, err)
    return {row["mode"]: row for row in rows}


FRESH_FAULTS = (40 << 20) // 4096 // 2  # at least half the buffer's 4 KiB pages faulted in


@pytest.fixture(scope="module")
def measured(tmp_path_factory: pytest.TempPathFactory) -> dict[str, dict]:
    """Two children: one imports the package (and measures), then tunes; the other sets the opt-out variable and
    tunes (which must do nothing), then drops it and sets up a bench worker."""
    logs = tmp_path_factory.mktemp("malloc")
    return {**_child(logs / "a", "import", "tune"), **{f"opt_out_{k}": v for k, v in _child(
        logs / "b", "opt_out", "tune", "allow", "worker").items()}}


@pytest.mark.skipif(not GLIBC, reason="mallopt exists on glibc Linux only")
def test_tuned_process_rewrites_a_freed_buffer_without_faults(measured: dict[str, dict]) -> None:
    tuned = measured["tune"]
    assert tuned["result"] == {name: 1 for name in malloc.SETTINGS}  # glibc accepted every setting
    assert tuned["faults"] < 500, tuned
    worker = measured["opt_out_worker"]  # every bench worker (and the serial executor's process) applies it
    assert worker["faults"] < 500, worker
    imported = measured["import"]  # an import leaves the library user's allocator alone
    assert imported["result"] is None and imported["faults"] > FRESH_FAULTS, imported
    assert tuned["byte"] == imported["byte"] == worker["byte"] == 2


@pytest.mark.skipif(not GLIBC, reason="mallopt exists on glibc Linux only")
def test_opt_out_keeps_the_defaults(measured: dict[str, dict]) -> None:
    out = measured["opt_out_tune"]
    assert out["result"] is None
    assert out["faults"] > FRESH_FAULTS, out


def test_settings_go_to_mallopt_once(monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[tuple[int, int]] = []
    monkeypatch.setattr(malloc, "_mallopt", lambda: lambda param, value: calls.append((param, value)) or 1)
    monkeypatch.setattr(malloc, "_APPLIED", {})
    monkeypatch.delenv("TACTILE_ZOO_DEFAULT_MALLOC", raising=False)
    assert malloc.tune_malloc() == {name: 1 for name in malloc.SETTINGS}
    assert malloc.tune_malloc() == {name: 1 for name in malloc.SETTINGS}  # a second call does nothing
    assert calls == [(malloc.PARAMETERS[name], value) for name, value in malloc.SETTINGS.items()]
    # glibc's <malloc.h> numbers: a wrong one would set another parameter
    assert malloc.PARAMETERS == {"M_TRIM_THRESHOLD": -1, "M_TOP_PAD": -2, "M_MMAP_THRESHOLD": -3, "M_MMAP_MAX": -4,
                                 "M_ARENA_MAX": -8}


@pytest.mark.parametrize(("platform_name", "libc"), [("darwin", ("", "")), ("win32", ("", "")),
                                                     ("linux", ("", ""))])  # the last: musl, no glibc
def test_no_op_off_glibc(monkeypatch: pytest.MonkeyPatch, platform_name: str, libc: tuple[str, str]) -> None:
    monkeypatch.setattr(malloc.sys, "platform", platform_name)
    monkeypatch.setattr(malloc.platform, "libc_ver", lambda: libc)
    monkeypatch.setattr(malloc, "_APPLIED", {})
    monkeypatch.delenv("TACTILE_ZOO_DEFAULT_MALLOC", raising=False)
    assert malloc.apply_mallopt({"M_MMAP_MAX": 0}) is None
    assert malloc.tune_malloc() is None
    assert malloc._APPLIED == {}


def test_opt_out_variable_is_parsed(monkeypatch: pytest.MonkeyPatch) -> None:
    from tactile_zoo.errors import ConfigError

    monkeypatch.setenv("TACTILE_ZOO_DEFAULT_MALLOC", "banana")
    with pytest.raises(ConfigError, match="TACTILE_ZOO_DEFAULT_MALLOC"):
        malloc.tune_malloc()
