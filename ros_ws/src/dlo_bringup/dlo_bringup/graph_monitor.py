"""What a running graph does, for the launcher: one line per finished episode as the sim appends it to the
outcomes file, and every ``status_period`` seconds one status line on the graph's health (control steps per
second counted on ``/clock``, episodes done, node processes alive, missing inputs and warnings from the nodes'
logs) until every episode is done. Texts: dlo_bag.outcome_table; log reading: dlo_viz.graph_monitor.

- :class:`Monitor` runs inside the launcher (its loop calls :meth:`Monitor.tick`); which nodes are alive it asks
  the launcher, which knows its children.
- The step rate comes from a child process, ``python -m dlo_bringup.graph_monitor --clock-topic /clock``
  (:func:`main`, node ``launch_monitor``): it counts the steps on ``/clock`` and prints ``STEPS LAST_NS
  LAST_STEP_WALL`` whenever they change; :class:`ClockReader` reads them. A process of its own, so that the
  launcher never joins DDS: a participant's teardown can deadlock in Fast DDS 2.14 (dlo_common.node_main), and
  the launcher must always end.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
import time
from pathlib import Path
from typing import Callable

PREFIX = "[launch] "


class ClockReader:
    """The step counts the clock child prints, read in a thread: ``steps``, ``last_ns`` (the last step's sim
    time), ``last_step_wall`` (time.time() when it was counted), ``error`` (why there is no step rate)."""

    def __init__(self, stream):
        self.steps, self.last_ns, self.last_step_wall, self.error = 0, None, None, None
        self._thread = threading.Thread(target=self._read, args=(stream,), daemon=True)
        self._thread.start()

    def _read(self, stream) -> None:
        for line in stream:
            parts = line.split()
            if parts[:1] == ["error"]:
                self.error = line.strip()[len("error ") :]
            elif len(parts) == 3:
                try:
                    steps, last_ns, wall = int(parts[0]), int(parts[1]), float(parts[2])
                except ValueError:
                    continue
                self.last_ns = last_ns if last_ns >= 0 else None
                self.last_step_wall = wall if wall >= 0 else None
                self.steps = steps


class Monitor:
    """The episode and status lines of one run. ``alive()``: {node name: running}, in start order (their logs are
    ``logs/<name>.log``); ``clock``: a :class:`ClockReader` or None (no step rate); ``say``: prints one line."""

    def __init__(
        self,
        outcomes: Path,
        logs: Path,
        episodes: int,
        status_period: float,
        alive: Callable[[], dict],
        clock: ClockReader | None = None,
        say: Callable[[str], None] = print,
        now: Callable[[], float] = time.monotonic,
    ):
        from dlo_viz.graph_monitor import LogTail, NodeHealth

        self.outcomes = LogTail(str(outcomes))
        self.episodes, self.status_period, self.alive, self.clock = episodes, status_period, alive, clock
        self.say, self.now = say, now
        self.health = [NodeHealth(name, LogTail(str(Path(logs) / f"{name}.log"))) for name in alive()]
        for node in self.health:  # warnings count from the monitor's start on; a wait logged before it holds
            node.catch_up()
        self.done = 0
        self.last_status, self.last_steps, self.last_sim_ns = now(), 0, None
        self.clock_error_said = False

    def report_episodes(self) -> None:
        """A line per episode appended to the outcomes file since the last call."""
        from dlo_bag.outcome_table import episode_line

        for line in self.outcomes.new_lines():
            if line.strip():
                self.done += 1
                try:
                    self.say(PREFIX + episode_line(json.loads(line), self.done, self.episodes))
                except (ValueError, KeyError) as error:
                    self.say(f"{PREFIX}unreadable outcome line ({error}): {line[:80]}")

    def tick(self) -> None:
        """The new episodes, and a status line when one is due (none once every episode is done: the sim ends)."""
        if self.clock is not None and self.clock.error and not self.clock_error_said:
            self.say(f"{PREFIX}status: no step rate ({self.clock.error})")
            self.clock_error_said = True
        self.report_episodes()
        now = self.now()
        finished = self.episodes and self.done >= self.episodes
        if self.status_period > 0 and now - self.last_status >= self.status_period and not finished:
            self.say(PREFIX + "status: " + self.status(now))
            self.last_status = now

    def status(self, now: float) -> str:
        from dlo_bag.outcome_table import status_line

        rate = factor = None
        counting = self.clock is not None and not self.clock.error
        if counting:
            steps, last_ns = self.clock.steps, self.clock.last_ns
            rate = (steps - self.last_steps) / (now - self.last_status)
            if self.last_sim_ns is not None and last_ns is not None:
                factor = (last_ns - self.last_sim_ns) / 1e9 / (now - self.last_status)
            self.last_steps, self.last_sim_ns = steps, last_ns
        stepped = self.clock.last_step_wall if counting else None
        notes = [note for node in self.health for note in node.notes(stepped)]
        return status_line(rate, factor, self.done, self.episodes, self.alive(), notes)


def main(argv=None) -> int:
    """The launcher's /clock step counter (see the module docstring); ends on SIGINT/SIGTERM."""
    parser = argparse.ArgumentParser(
        prog="python -m dlo_bringup.graph_monitor",
        description="Count the control steps on /clock for the launcher's status line.",
    )
    parser.add_argument("--clock-topic", default="/clock", help="the sim's clock topic")
    args = parser.parse_args(argv)
    stop = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.append(True))
    try:
        from dlo_viz.graph_monitor import ClockCounter

        counter = ClockCounter(args.clock_topic)
    except Exception as error:  # noqa: BLE001 (no rclpy here: the status lines go on without the step rate)
        print(f"error {type(error).__name__}: {error}", flush=True)
        return 1
    said = None
    try:
        while not stop:
            counter.spin(0.2)
            state = (counter.steps, counter.last_ns, counter.last_step_wall)
            if state != said:
                print(f"{state[0]} {-1 if state[1] is None else state[1]} {-1 if state[2] is None else state[2]}", flush=True)
                said = state
    finally:
        counter.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
