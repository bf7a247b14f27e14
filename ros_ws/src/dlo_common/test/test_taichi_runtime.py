"""dlo_common.taichi_runtime: the process's one Taichi runtime (dlo_common README)."""

import json
import os
import subprocess
import sys

import pytest

PROBE = """
import json, os, sys
import dlo_common, dlo_common.taichi_runtime as runtime
imported_with_the_module = 'taichi' in sys.modules
errors = {}
for name, call in (("unknown", lambda: runtime.select("tpu")), ("env", runtime.init)):
    try:
        call()
    except ValueError as error:
        errors[name] = str(error)
os.environ.pop("DLO_TI_ARCH")
runtime.init()  # the CPU: nothing asked for
import taichi as ti
field = ti.field(ti.i32, shape=2)
field[0] = 7
runtime.init()  # once per process: a second call returns at once (a second ti.init would drop the field)
kept = int(field[0])
try:
    runtime.select("vulkan")
except ValueError as error:
    errors["other"] = str(error)
runtime.select("cpu")  # the one it runs on: fine
print(json.dumps({"imported": imported_with_the_module, "arch": runtime.arch(), "errors": errors, "kept": kept}))
"""


def test_taichi_starts_once_on_the_cpu_only_when_asked_and_refuses_a_second_backend():
    """dlo_common README: Taichi is imported inside init only (importing the module keeps Taichi's
    banner off stdout); init runs ti.init once per process, on the CPU unless asked; select(name) is a
    ValueError for an unknown name and when Taichi already runs on another backend; so is a bad
    DLO_TI_ARCH."""
    env = {**os.environ, "DLO_TI_ARCH": "warp"}
    env.pop("ENABLE_TAICHI_HEADER_PRINT", None)
    result = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, timeout=300, env=env)
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert not any("[Taichi] version" in line for line in lines), result.stdout  # (ti.init's own start line may be)
    probe = json.loads(lines[-1])
    assert probe["imported"] is False and probe["arch"] == "cpu" and probe["kept"] == 7
    assert probe["errors"] == {
        "unknown": "Taichi arch: expected one of cpu, cuda, gpu, vulkan, got 'tpu'",
        "env": "DLO_TI_ARCH='warp': expected one of cpu, cuda, gpu, vulkan",
        "other": "Taichi is already running on cpu in this process",
    }


CAPITALS_PROBE = """
import json
import dlo_common.taichi_runtime as runtime
before = runtime.arch()
runtime.init()
print(json.dumps({"before": before, "after": runtime.arch()}))
"""


def test_the_backend_named_in_capitals_is_the_same_backend():
    """DLO_TI_ARCH, the user's switch (dlo_sim/README.md), is read case-insensitively: DLO_TI_ARCH=CPU is
    the CPU backend, not a one-line error."""
    env = {**os.environ, "DLO_TI_ARCH": "CPU"}
    result = subprocess.run([sys.executable, "-c", CAPITALS_PROBE], capture_output=True, text=True, timeout=300, env=env)
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout.splitlines()[-1]) == {"before": "cpu", "after": "cpu"}


KERNEL_PROBE = """
import dlo_common.taichi_runtime as runtime
runtime.init()
import taichi as ti


@ti.kernel
def twice(x: ti.i32) -> ti.i32:
    return 2 * x


print(twice(21))
"""


def test_a_lock_left_by_a_killed_process_no_longer_keeps_kernels_out_of_the_cache(tmp_path):
    """Taichi holds ticache.lock while it writes its kernel cache at exit; a process killed meanwhile leaves
    it, and every later process failed to save its kernels ("Lock .../ticache.lock failed") and compiled
    them again at each start. init removes a lock older than STALE_LOCK_AGE: the kernel is saved, no warning."""
    from dlo_common.taichi_runtime import STALE_LOCK_AGE

    cache = tmp_path / "ticache"
    cache.mkdir()
    lock = cache / "ticache.lock"
    lock.touch()
    old = lock.stat().st_mtime - STALE_LOCK_AGE - 5
    os.utime(lock, (old, old))
    env = {**os.environ, "TI_OFFLINE_CACHE_FILE_PATH": str(cache)}
    env.pop("DLO_TI_ARCH", None)
    probe = tmp_path / "probe.py"  # (Taichi reads a kernel's source from its file)
    probe.write_text(KERNEL_PROBE)
    result = subprocess.run([sys.executable, str(probe)], capture_output=True, text=True, timeout=300, env=env)
    assert result.returncode == 0, result.stderr
    assert result.stdout.splitlines()[-1] == "42"
    assert "ticache.lock failed" not in result.stderr, result.stderr
    assert not lock.exists()
    assert any(p.suffix == ".tic" for p in cache.iterdir()), sorted(p.name for p in cache.iterdir())  # saved


def test_a_recent_lock_is_left_to_the_process_writing_the_cache(tmp_path):
    from dlo_common.taichi_runtime import STALE_LOCK_AGE, clear_stale_cache_lock

    lock = tmp_path / "ticache.lock"
    assert clear_stale_cache_lock(tmp_path) is False  # none
    lock.touch()
    written = lock.stat().st_mtime
    assert clear_stale_cache_lock(tmp_path) is False and lock.exists()  # just written
    assert clear_stale_cache_lock(tmp_path, now=written + STALE_LOCK_AGE) is False and lock.exists()
    assert clear_stale_cache_lock(tmp_path, now=written + STALE_LOCK_AGE + 0.01) is True and not lock.exists()


QUIET_PROBE = """
import dlo_common.taichi_runtime as runtime
runtime.init()
"""


def test_starting_taichi_prints_nothing_on_stdout():
    """dlo_common README: stdout carries what a command promises (dlo-train's JSON summary, dlo-evaluate's
    table): ti.init's own "[Taichi] Starting on arch=x64" line (a print, whatever the log level) stays off it;
    ENABLE_TAICHI_HEADER_PRINT=1, the user's switch for Taichi's lines, shows it on stderr."""
    env = {k: v for k, v in os.environ.items() if k not in ("DLO_TI_ARCH", "ENABLE_TAICHI_HEADER_PRINT")}
    result = subprocess.run([sys.executable, "-c", QUIET_PROBE], capture_output=True, text=True, timeout=300, env=env)
    assert result.returncode == 0, result.stderr
    assert result.stdout == "" and "[Taichi]" not in result.stderr, result.stdout + result.stderr
    env["ENABLE_TAICHI_HEADER_PRINT"] = "1"
    result = subprocess.run([sys.executable, "-c", QUIET_PROBE], capture_output=True, text=True, timeout=300, env=env)
    assert result.returncode == 0, result.stderr
    assert "[Taichi] Starting on arch=x64" in result.stderr and "Starting on arch" not in result.stdout


@pytest.mark.parametrize("module", ["dlo_perception.vision", "dlo_sim.kernels"])
def test_the_modules_that_import_taichi_import_the_runtime_first(module):
    """Importing taichi prints "[Taichi] version ..." on stdout unless dlo_common.taichi_runtime came first: the
    two library modules that import taichi themselves keep that order (an import sort once put taichi first)."""
    env = {k: v for k, v in os.environ.items() if k != "ENABLE_TAICHI_HEADER_PRINT"}
    result = subprocess.run([sys.executable, "-c", f"import {module}"], capture_output=True, text=True, timeout=300, env=env)
    assert result.returncode == 0, result.stderr
    assert result.stdout == "", result.stdout
