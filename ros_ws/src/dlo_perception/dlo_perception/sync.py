"""Exact-stamp synchroniser: pairs messages of several inputs that carry the same stamp.

Step-locked control matches one control step exactly by stamp (docs/ARCHITECTURE.md#topics), so an
approximate-time policy is not wanted: a set is emitted only when every input has a message with
the same stamp. Old unmatched stamps are dropped once ``depth`` newer ones are pending.

A step that stays incomplete is reported by the node that waits for it (``IncompleteSteps``): which
input is missing and which stamps that input did carry nearby (a driver stamping its state with a
clock reading a few microseconds off the image's shows up as "image has stamps 1.28 ... nearby;
gripper state at 1.2800004"), at most one line per ``interval`` with the count of the others.
"""

from __future__ import annotations

from collections import deque

NAMES = {"gripper": "gripper state", "particles": "particle cloud"}  # how a report names an input (default: its key)
PUBLISHERS = {"tactile": ("tactile_node", "particles"), "vision": ("vision_node", "image")}  # node, its other input
PENDING_DEPTH = 32  # incomplete steps a synchroniser keeps by default (older ones: superseded)
NEAR_MISS_NS = 20_000_000  # stamps < 20 ms apart (a quarter control period): one step, stamped by two clock readings


class StampSync:
    """Collect ``(key, stamp_ns, value)`` items; ``add`` returns the full set once all keys have ``stamp_ns``."""

    def __init__(self, keys, depth: int = PENDING_DEPTH, history: int = 64):
        self.keys = tuple(keys)
        self.depth = int(depth)
        self.pending = {}  # stamp_ns -> {key: value}
        self.recent = {key: deque(maxlen=history) for key in self.keys}  # latest stamps of each input, for reports

    def add(self, key, stamp_ns: int, value):
        if key not in self.keys:
            raise KeyError(f"unknown input {key!r}; inputs are {self.keys}")
        self.recent[key].append(int(stamp_ns))
        slot = self.pending.setdefault(int(stamp_ns), {})
        slot[key] = value
        if len(slot) == len(self.keys):
            del self.pending[int(stamp_ns)]
            for older in [s for s in self.pending if s < stamp_ns]:  # superseded, never complete now
                del self.pending[older]
            return tuple(slot[k] for k in self.keys)
        while len(self.pending) > self.depth:
            del self.pending[min(self.pending)]
        return None

    def missing(self, stamp_ns: int) -> list:
        """The inputs that have not delivered ``stamp_ns`` among their latest ``history`` stamps."""
        return [key for key in self.keys if int(stamp_ns) not in self.recent[key]]

    def nearby(self, key, stamp_ns: int, count: int = 2) -> list:
        """Up to ``count`` of ``key``'s latest stamps closest to ``stamp_ns`` [ns], in time order."""
        closest = sorted(set(self.recent[key]), key=lambda s: (abs(s - stamp_ns), s))[:count]
        return sorted(closest)

    def stamps_seen(self, stamp_ns: int) -> str:
        """What the inputs carried around an incomplete step, e.g. ``tactile has stamps 1.2800004, 1.36
        nearby; gripper state at 1.28`` (each missing input with its nearest stamps, each present one)."""
        parts, near_miss = [], None
        missing = self.missing(stamp_ns)
        for key in self.keys:
            name = NAMES.get(key, key)
            if key not in missing:
                parts.append(f"{name} at {format_stamp(stamp_ns)}")
                continue
            near = self.nearby(key, stamp_ns)
            if not near:
                node, other = PUBLISHERS.get(key, (None, None))
                parts.append(
                    f"{name}: nothing received yet "
                    + (
                        f"(is {node} running? it publishes only steps whose {other} and gripper state share one stamp: "
                        "see its log)"
                        if node
                        else "(is its publisher running?)"
                    )
                )
                continue
            parts.append(f"{name} has stamps {', '.join(format_stamp(s) for s in near)} nearby")
            off = min(near, key=lambda s: abs(s - stamp_ns)) - stamp_ns
            if 0 < abs(off) < NEAR_MISS_NS and (near_miss is None or abs(off) < abs(near_miss[1])):
                near_miss = (name, off)
        text = "; ".join(parts)
        if near_miss is not None:
            name, off = near_miss
            text += (
                f" (the {name}'s nearest stamp is {abs(off) / 1000:g} us {'later' if off > 0 else 'earlier'}: "
                "every input of a step must carry the state's exact stamp)"
            )
        return text


class IncompleteSteps:
    """Reports steps whose inputs stay incomplete for ``timeout`` s: one line at most every ``interval``
    s (the latest such step, with the count of the others since the last line), never one per step.

    ``seen(stamp_ns, now)`` when an input of a step arrives, ``matched(stamp_ns)`` when the step is
    complete; ``check(sync, now)`` returns the line to log now, or None. ``first_seen``: a node's own
    {stamp_ns: wall time of its first input} to share (default: a new one).
    """

    def __init__(self, timeout: float = 1.0, interval: float = 1.0, first_seen: dict | None = None):
        self.timeout, self.interval = float(timeout), float(interval)
        self.first_seen = {} if first_seen is None else first_seen  # stamp_ns -> wall time of its first input
        self.last_line = None  # wall time of the last line
        self.held = []  # (stamp_ns, preferred, line) of incomplete steps not yet reported

    def seen(self, stamp_ns: int, now: float) -> None:
        self.first_seen.setdefault(int(stamp_ns), now)

    def matched(self, stamp_ns: int) -> None:
        self.first_seen.pop(int(stamp_ns), None)

    def expire(self, sync: StampSync, now: float, prefer=None) -> None:
        """Move the steps waiting longer than ``timeout`` to the report (``prefer``: the key whose
        stamps define a step, e.g. 'gripper': a stamp without it is reported only if no other is)."""
        for stamp, seen in sorted(self.first_seen.items()):
            if now - seen <= self.timeout:
                continue
            del self.first_seen[stamp]
            missing = sync.missing(stamp)
            if missing and len(missing) < len(sync.keys):
                self.held.append(
                    (stamp, prefer is None or prefer not in missing, incomplete_line(sync, stamp, missing, self.timeout))
                )

    def report(self, now: float) -> str | None:
        """The line for the latest incomplete step (a preferred one if any), once per ``interval``."""
        if not self.held or (self.last_line is not None and now - self.last_line < self.interval):
            return None
        preferred = [item for item in self.held if item[1]] or self.held
        line = preferred[-1][2]
        others = len(preferred) - 1
        if others:
            line += f" ({others} other incomplete step{'s' if others > 1 else ''} since the last report)"
        self.held, self.last_line = [], now
        return line

    def check(self, sync: StampSync, now: float, prefer=None) -> str | None:
        self.expire(sync, now, prefer)
        return self.report(now)

    def note(self, sync: StampSync, stamp_ns: int, matched: bool, now: float, prefer=None) -> str | None:
        """For a node without a timer: after each ``sync.add``, whether it completed ``stamp_ns``."""
        if matched:
            self.matched(stamp_ns)
        else:
            self.seen(stamp_ns, now)
        return self.check(sync, now, prefer)


def incomplete_line(sync: StampSync, stamp_ns: int, missing, timeout: float) -> str:
    """``step at t=1.28 s: no tactile input after 1.0 s; tactile has stamps ... nearby; gripper state at 1.28``."""
    return f"step at t={stamp_ns / 1e9:.2f} s: no {', '.join(missing)} input after {timeout} s; " + sync.stamps_seen(stamp_ns)


def format_stamp(stamp_ns: int) -> str:
    """Integer nanoseconds -> seconds with as many digits as needed, exactly (1280000400 -> '1.2800004')."""
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    return f"{sec}.{nanosec:09d}".rstrip("0").rstrip(".")


def stamp_to_ns(stamp) -> int:
    """builtin_interfaces/Time (rclpy or rosbags message) -> integer nanoseconds."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
