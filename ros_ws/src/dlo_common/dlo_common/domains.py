"""The DDS domains of this machine: which are busy, and the directory of their locks (no rclpy here).

A domain is busy when a participant on this machine has bound one of its UDP ports (RTPS: 7400 + 250 * domain
+ 0..249). Whoever uses a domain locks it in :data:`DOMAIN_LOCK_DIR` (flock on ``N.lock``) while it does: the
launcher (``dlo_bringup.domain``, domains 10..99) and the tests (``tests/support/harness.py``, 100..232), so
that two graphs or tests started at the same moment never share one.
"""

from __future__ import annotations

import os
from pathlib import Path

DOMAIN_LOCK_DIR = Path(os.environ.get("XDG_RUNTIME_DIR") or "/tmp") / f"dlo-vitac-domains-{os.getuid()}"


def domain_busy(domain: int) -> bool:
    """Whether a DDS participant on this machine bound a UDP port of ``domain`` (RTPS: 7400 + 250 d + 0..249)."""
    lo, hi = 7400 + 250 * domain, 7400 + 250 * domain + 249
    for table in ("/proc/net/udp", "/proc/net/udp6"):
        try:
            with open(table) as f:
                next(f, None)
                for line in f:
                    port = int(line.split()[1].rsplit(":", 1)[1], 16)
                    if lo <= port <= hi:
                        return True
        except OSError:
            continue
    return False
