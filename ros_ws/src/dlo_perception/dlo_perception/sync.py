"""Exact-stamp synchroniser: pairs messages of several inputs that carry the same stamp.

Step-locked control matches one control step exactly by stamp (DESIGN.md section 6), so an
approximate-time policy is not wanted: a set is emitted only when every input has a message with
the same stamp. Old unmatched stamps are dropped once ``depth`` newer ones are pending.
"""

from __future__ import annotations


class StampSync:
    """Collect ``(key, stamp_ns, value)`` items; ``add`` returns the full set once all keys have ``stamp_ns``."""

    def __init__(self, keys, depth: int = 32):
        self.keys = tuple(keys)
        self.depth = int(depth)
        self.pending = {}  # stamp_ns -> {key: value}
        self.dropped = 0  # stamps discarded incomplete

    def add(self, key, stamp_ns: int, value):
        if key not in self.keys:
            raise KeyError(f"unknown input {key!r}; inputs are {self.keys}")
        slot = self.pending.setdefault(int(stamp_ns), {})
        slot[key] = value
        if len(slot) == len(self.keys):
            del self.pending[int(stamp_ns)]
            for older in [s for s in self.pending if s < stamp_ns]:  # superseded, never complete now
                del self.pending[older]
                self.dropped += 1
            return tuple(slot[k] for k in self.keys)
        while len(self.pending) > self.depth:
            del self.pending[min(self.pending)]
            self.dropped += 1
        return None


def stamp_to_ns(stamp) -> int:
    """builtin_interfaces/Time (rclpy or rosbags message) -> integer nanoseconds."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
