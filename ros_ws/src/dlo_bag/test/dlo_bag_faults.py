"""Fault injection for the dlo_bag tests: a small full disk, a per-file size limit."""

from __future__ import annotations

import contextlib
import os
import resource
import shutil
import signal
import subprocess
from collections.abc import Iterator
from pathlib import Path

TMPFS_SIZE = "2m"


@contextlib.contextmanager
def small_disk(base: Path) -> Iterator[Path | None]:
    """A real 2 MiB tmpfs mounted at ``base/disk`` (root only); None where it cannot be mounted."""
    mount = base / "disk"
    mount.mkdir(parents=True, exist_ok=True)
    if shutil.which("mount") is None or os.geteuid() != 0:
        yield None
        return
    done = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={TMPFS_SIZE}", "tmpfs", str(mount)], capture_output=True, text=True
    )
    if done.returncode != 0:
        yield None
        return
    try:
        yield mount
    finally:
        subprocess.run(["umount", "-l", str(mount)], capture_output=True)


def file_size_limit(limit: int):
    """preexec_fn: writes past ``limit`` bytes of any one file fail with EFBIG (no root needed)."""

    def apply() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # EFBIG instead of being killed
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    return apply
