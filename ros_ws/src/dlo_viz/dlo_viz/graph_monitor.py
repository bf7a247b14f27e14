"""What a running graph does, read for the launcher's episode and status lines (dlo_bringup.graph_monitor
prints them): new lines of a growing file (:class:`LogTail`: the outcomes file, the nodes' logs), a node's
health from its log (:class:`NodeHealth`), and the control steps counted on ``/clock``
(:class:`ClockCounter`, the only part that needs rclpy, imported when it is built). The notes' texts:
dlo_bag.outcome_table.

Warnings and missing inputs are events: a status line counts those logged since the previous one. What a
node waits for (its last "waiting for ..." line, e.g. the sim's "waiting for the recorder ...") is a state:
it is shown while it holds and dropped once it no longer does, i.e. once that node has logged anything
after it (it started, finished an episode, ...) or a control step was counted on ``/clock`` after it was
logged (the graph runs).
"""

from __future__ import annotations

import re
import time

from dlo_bag.outcome_table import _WAITING, health_notes

# a line a node logged (rclpy's console format: [SEVERITY] [time] [name]: text; the time may be left out)
_LOG_LINE = re.compile(r"^\[(?:DEBUG|INFO|WARN|WARNING|ERROR|FATAL)\](?: \[(\d+(?:\.\d+)?)\])?")


class LogTail:
    """New complete lines of a growing text file."""

    def __init__(self, path: str):
        self.path, self.offset, self.partial = path, 0, ""

    def new_lines(self) -> list:
        try:
            with open(self.path, errors="replace") as f:
                f.seek(self.offset)
                text = f.read()
                self.offset = f.tell()
        except OSError:
            return []
        text, self.partial = self.partial + text, ""
        lines = text.split("\n")
        self.partial = lines.pop()  # "" after a final newline, else an incomplete line kept for later
        return lines


class NodeHealth:
    """The notes on one node for the status line, from its log (see the module docstring): the lines logged
    since the previous status line, and the "waiting for ..." line that still holds, if any."""

    def __init__(self, name: str, tail: LogTail):
        self.name, self.tail = name, tail
        self.waiting, self.waiting_since = None, None  # the last "waiting for" line, its wall time [s]

    def catch_up(self) -> None:
        """Read what the node logged before the monitor started: what it waits for holds, the rest is past."""
        self._read()

    def notes(self, last_step_wall: float | None = None) -> list:
        """Notes for a status line now; ``last_step_wall``: wall time (time.time()) of the last control step
        counted, None if unknown."""
        lines = self._read()
        if self.waiting is not None and last_step_wall is not None and last_step_wall > self.waiting_since:
            self.waiting = None  # the graph stepped after the line was logged
        events = [line for line in lines if not _WAITING.search(line)]
        return health_notes(self.name, ([self.waiting] if self.waiting else []) + events)

    def _read(self) -> list:
        lines = self.tail.new_lines()
        for line in lines:
            logged = _LOG_LINE.match(line)
            if _WAITING.search(line):
                self.waiting = line
                self.waiting_since = float(logged.group(1)) if logged and logged.group(1) else time.time()
            elif logged:  # the node did something after waiting: it no longer waits
                self.waiting = None
        return lines


class ClockCounter:
    """Counts distinct /clock stamps (one per control step of the sim) on the graph's domain."""

    def __init__(self, topic: str):
        import rclpy
        import rclpy.executors
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from rclpy.signals import SignalHandlerOptions
        from rosgraph_msgs.msg import Clock

        self.rclpy = rclpy
        self.context = rclpy.Context()
        rclpy.init(context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node("launch_monitor", context=self.context)
        self.last_ns, self.steps, self.first_ns = None, 0, None
        self.last_step_wall = None  # time.time() when the last new step was counted
        self.node.create_subscription(
            Clock, topic, self.on_clock, QoSProfile(depth=50, reliability=ReliabilityPolicy.BEST_EFFORT)
        )
        self.executor = rclpy.executors.SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def on_clock(self, msg):
        ns = msg.clock.sec * 1_000_000_000 + msg.clock.nanosec
        if ns != self.last_ns:  # a republished step repeats its stamp
            self.steps += 1
            self.last_ns = ns
            self.last_step_wall = time.time()
            if self.first_ns is None:
                self.first_ns = ns

    def spin(self, seconds: float):
        self.executor.spin_once(timeout_sec=seconds)

    def close(self):
        self.executor.shutdown()
        self.node.destroy_node()
        self.rclpy.shutdown(context=self.context)
