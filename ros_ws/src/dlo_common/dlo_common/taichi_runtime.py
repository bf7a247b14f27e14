"""The process's one Taichi runtime, shared by the vision kernel (``dlo_perception.vision``) and the
simulator (``dlo_sim.kernels``), so every process (env, sim node, vision node) compiles its kernels
with the same options.

- ``select(name)``: ask for a backend before the first kernel runs (``dlo-train``'s
  ``train.sim_arch``); ValueError for an unknown name or when Taichi already runs on another one.
- ``init(arch=None)``: ``ti.init`` once per process (later calls return at once) on ``arch``, else
  the selected backend, else the one named by the environment variable ``DLO_TI_ARCH``
  (cpu/cuda/gpu/vulkan; the user's switch, read here only), else the CPU. Fast math: results are
  bit-reproducible for a given build, and the simulator's NaN checks test exponent bits.
- ``arch()``: the backend Taichi runs on, or the one ``init()`` would start.

``init`` also removes a leftover lock of Taichi's kernel cache (``ticache.lock`` older than
``STALE_LOCK_AGE``): Taichi holds it while it writes the cache at exit, well under a second; a process
killed meanwhile (SIGKILL, out of memory) leaves it, and every later process then failed to save its
kernels ("Lock .../ticache.lock failed") and compiled them again at each start.

Taichi is imported inside ``init`` only, so importing ``dlo_common`` stays light. Taichi's own lines
stay off stdout, which carries what each command promises (dlo-train's JSON summary, dlo-evaluate's
table): importing this module keeps its "[Taichi] version ..." banner away, and ``init`` keeps the
"[Taichi] Starting on arch=..." line that ``ti.init`` prints (with ``print``, whatever the log level);
``ENABLE_TAICHI_HEADER_PRINT=1`` brings both back, on stderr for the second.
"""

from __future__ import annotations

import contextlib
import io
import os
import sys
import time
from pathlib import Path
from typing import Optional

os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "0")

ENV_VAR = "DLO_TI_ARCH"  # the user's backend choice, read by init() (docs: dlo_sim/README.md)
ARCHS = ("cpu", "cuda", "gpu", "vulkan")  # backend names, as Taichi calls them (ti.cpu, ...)
DEFAULT_ARCH = "cpu"
STALE_LOCK_AGE = 60.0  # s: a kernel-cache lock this old is a killed process's leftover

_selected: Optional[str] = None  # select(name)
_running: Optional[str] = None  # the backend init() started


def select(name: str) -> None:
    """Ask for backend ``name`` before the first kernel runs (it overrides ``DLO_TI_ARCH``)."""
    global _selected
    if name not in ARCHS:
        raise ValueError(f"Taichi arch: expected one of {', '.join(ARCHS)}, got {name!r}")
    if _running is not None and _running != name:
        raise ValueError(f"Taichi is already running on {_running} in this process")
    _selected = name


def arch() -> str:
    """The backend Taichi runs on, or, before ``init``, the one it would start (not checked yet)."""
    return _running if _running is not None else _wanted()


def _wanted() -> str:
    """The selected backend, else DLO_TI_ARCH's, else the CPU."""
    if _selected is not None:
        return _selected
    return os.environ.get(ENV_VAR, DEFAULT_ARCH).lower()


def init(arch: Optional[str] = None) -> None:
    """``ti.init`` once per process on ``arch`` (``select(arch)`` first), else the selected backend, else
    ``DLO_TI_ARCH``, else the CPU. ValueError for an unknown name, and when cuda was asked for but
    Taichi found no CUDA device (it falls back to the CPU silently otherwise)."""
    global _running
    if arch is not None:
        select(arch)
    if _running is not None:
        return
    name = _wanted()
    if name not in ARCHS:
        raise ValueError(f"{ENV_VAR}={name!r}: expected one of {', '.join(ARCHS)}")
    import taichi as ti  # noqa: PLC0415 (light dlo_common: Taichi only when a kernel is about to run)

    printed = io.StringIO()  # ti.init's "[Taichi] Starting on arch=x64": never on stdout (module docstring)
    with contextlib.redirect_stdout(printed):
        ti.init(
            arch=getattr(ti, name),
            fast_math=True,
            default_fp=ti.f32,
            offline_cache=True,
            log_level=ti.WARN if name == "cpu" else ti.ERROR,
        )  # a missing GPU: our one line, not Taichi's three
    if printed.getvalue() and _header_wanted():
        sys.stderr.write(printed.getvalue())
    _running = name
    clear_stale_cache_lock(ti.lang.impl.current_cfg().offline_cache_file_path)
    if name == "cuda" and ti.lang.impl.current_cfg().arch != ti.cuda:  # Taichi falls back to the CPU silently
        raise ValueError(
            f"Taichi arch cuda asked for ({ENV_VAR} / train.sim_arch), but Taichi found no "
            "CUDA device and fell back to the CPU (use cpu)"
        )


def _header_wanted() -> bool:
    """Whether the user asked for Taichi's own lines (ENABLE_TAICHI_HEADER_PRINT, read as Taichi reads it)."""
    return os.environ.get("ENABLE_TAICHI_HEADER_PRINT", "0").lower() not in ("false", "0", "f")


def clear_stale_cache_lock(cache_dir: str | os.PathLike, now: Optional[float] = None) -> bool:
    """Remove ``cache_dir``/ticache.lock when it was last written more than STALE_LOCK_AGE s before ``now``
    (default: the clock); True when one was removed. A younger one is left: another process may be writing."""
    lock = Path(cache_dir) / "ticache.lock"
    try:
        if (time.time() if now is None else now) - lock.stat().st_mtime <= STALE_LOCK_AGE:
            return False
        lock.unlink()
    except OSError:  # none, or gone meanwhile
        return False
    return True
