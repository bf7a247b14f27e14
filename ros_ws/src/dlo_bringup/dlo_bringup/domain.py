"""A DDS domain of the graph's own.

A domain is busy when a participant on this machine has bound one of its UDP ports (RTPS: 7400 + 250 * domain
+ 0..249); a lock per domain (flock on ``<DOMAIN_LOCK_DIR>/N.lock``) keeps two launchers starting at the same
moment apart. Tests lock theirs in the same directory (tests/support/harness.py, domains 100..232; dlo_common.domains);
launchers pick from 10..99 (not 0, the default; below the ephemeral ports). The lock is held while the graph runs,
by the launcher and its nodes (they inherit the descriptor: a killed launcher's nodes still stopping keep it).
"""

from __future__ import annotations

import fcntl
import os
import random

from dlo_common.domains import DOMAIN_LOCK_DIR, domain_busy

LAUNCH_DOMAINS = (10, 99)


def lock_domain(domain: int) -> int | None:
    """Hold the lock of ``domain``: its file descriptor, or None when another process holds it. Without a lock
    directory (not writable) there is nothing to hold: -1."""
    try:
        DOMAIN_LOCK_DIR.mkdir(parents=True, exist_ok=True)
        fd = os.open(DOMAIN_LOCK_DIR / f"{domain}.lock", os.O_RDWR | os.O_CREAT, 0o644)
    except OSError:
        return -1
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        return None
    return fd


def free_domain() -> tuple[int, int] | None:
    """A domain in LAUNCH_DOMAINS that no participant on this machine uses, locked: (domain, lock fd); None when
    every one is taken. The search starts at a random place, so that launchers started together rarely race."""
    first, last = LAUNCH_DOMAINS
    count = last - first + 1
    start = random.randrange(count)
    for i in range(count):
        domain = first + (start + i) % count
        if domain_busy(domain):
            continue
        fd = lock_domain(domain)
        if fd is not None:
            return domain, fd
    return None


__all__ = ["LAUNCH_DOMAINS", "domain_busy", "free_domain", "lock_domain"]
