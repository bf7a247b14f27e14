"""dlo_common.taichi_runtime: the process's one Taichi runtime (dlo_common README)."""
import json
import os
import subprocess
import sys

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
        "other": "Taichi is already running on cpu in this process"}


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
    result = subprocess.run([sys.executable, "-c", CAPITALS_PROBE], capture_output=True, text=True, timeout=300,
                            env=env)
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout.splitlines()[-1]) == {"before": "cpu", "after": "cpu"}
