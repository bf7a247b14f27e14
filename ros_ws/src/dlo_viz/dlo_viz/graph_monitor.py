"""What a running graph does, for scripts/launch_graph.sh: one line per finished episode as the sim
appends it to the outcomes file, and every ``--status-period`` seconds one status line on the graph's
health (control steps per second counted on ``/clock``, episodes done, node processes alive, missing
inputs and warnings from the nodes' logs) until all ``--episodes`` are done. Formatting:
dlo_bag.outcome_table. Stops on SIGINT/SIGTERM after printing the episodes that finished meanwhile.

Warnings and missing inputs are events: a status line counts those logged since the previous one. What a
node waits for (its last "waiting for ..." line, e.g. the sim's "waiting for the recorder ...") is a state:
it is shown while it holds and dropped once it no longer does, i.e. once that node has logged anything
after it (it started, finished an episode, ...) or a control step was counted on ``/clock`` after it was
logged (the graph runs).

    python -m dlo_viz.graph_monitor OUTCOMES.jsonl --logs DIR --node sim=PID --node policy=PID ...

Without rclpy (or with ``--no-ros``) the step rate is shown as unknown.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import sys
import time

from dlo_bag.outcome_table import _WAITING, episode_line, health_notes, status_line

PREFIX = "[launch] "
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
        self.node.create_subscription(Clock, topic, self.on_clock,
                                      QoSProfile(depth=50, reliability=ReliabilityPolicy.BEST_EFFORT))
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


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m dlo_viz.graph_monitor", description=__doc__.splitlines()[0])
    parser.add_argument("outcomes", help="JSON-lines file the sim appends finished episodes to (summary_file)")
    parser.add_argument("--logs", default="", help="directory of the nodes' logs (<name>.log)")
    parser.add_argument("--node", action="append", default=[], metavar="NAME=PID",
                        help="a node process of the graph to watch (repeatable)")
    parser.add_argument("--episodes", type=int, default=0, help="episodes of the run (0 = unlimited)")
    parser.add_argument("--status-period", type=float, default=10.0,
                        help="seconds between status lines (default 10; 0 = no status lines)")
    parser.add_argument("--clock-topic", default="/clock", help="the sim's clock topic (steps are counted on it)")
    parser.add_argument("--no-ros", action="store_true", help="do not join the ROS graph (no step rate)")
    args = parser.parse_args(argv)
    nodes = {}
    for spec in args.node:
        name, _, pid = spec.partition("=")
        if not pid.isdigit():
            parser.error(f"--node expects NAME=PID, got {spec!r}")
        nodes[name] = int(pid)

    stop = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.append(True))
    counter = None
    if args.status_period > 0 and not args.no_ros:
        try:
            counter = ClockCounter(args.clock_topic)
        except Exception as error:  # noqa: BLE001 (no rclpy here: status lines without the step rate)
            print(f"{PREFIX}status: no step rate ({type(error).__name__}: {error})", flush=True)
    outcomes = LogTail(args.outcomes)
    logs = {name: LogTail(os.path.join(args.logs, f"{name}.log")) for name in nodes} if args.logs else {}
    health = [NodeHealth(name, tail) for name, tail in logs.items()]
    for node in health:  # warnings count from the monitor's start on; a wait logged before it holds
        node.catch_up()
    done = 0
    last_status, last_steps = time.monotonic(), 0
    last_sim_ns = None

    def report_episodes():
        nonlocal done
        for line in outcomes.new_lines():
            if line.strip():
                done += 1
                try:
                    print(PREFIX + episode_line(json.loads(line), done, args.episodes), flush=True)
                except (ValueError, KeyError) as error:
                    print(f"{PREFIX}unreadable outcome line ({error}): {line[:80]}", flush=True)

    try:
        while not stop:
            if counter is not None:
                counter.spin(0.2)
            else:
                time.sleep(0.2)
            report_episodes()
            now = time.monotonic()
            finished = args.episodes and done >= args.episodes  # the sim exits: nothing more to report
            if args.status_period > 0 and now - last_status >= args.status_period and not finished:
                rate = factor = None
                if counter is not None:
                    rate = (counter.steps - last_steps) / (now - last_status)
                    if last_sim_ns is not None and counter.last_ns is not None:
                        factor = (counter.last_ns - last_sim_ns) / 1e9 / (now - last_status)
                    last_steps, last_sim_ns = counter.steps, counter.last_ns
                alive = {}
                for name, pid in nodes.items():
                    try:
                        os.kill(pid, 0)
                        alive[name] = True
                    except ProcessLookupError:
                        alive[name] = False
                    except PermissionError:
                        alive[name] = True
                stepped = counter.last_step_wall if counter is not None else None
                notes = [note for node in health for note in node.notes(stepped)]
                print(PREFIX + "status: " + status_line(rate, factor, done, args.episodes, alive, notes), flush=True)
                last_status = now
        report_episodes()  # those that finished while the graph stopped
    finally:
        if counter is not None:
            try:
                counter.close()
            except Exception:  # noqa: BLE001 (shutting down anyway)
                pass
    return 0


if __name__ == "__main__":
    sys.exit(main())
