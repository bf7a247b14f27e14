"""Helpers for the dlo_bag tests: child processes with collected output, commands."""

from __future__ import annotations

import queue
import subprocess
import sys
import threading
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[3]
ROS2RUN = REPO / "scripts" / "ros2run"
HELPER = HERE / "dlo_bag_graph_helper.py"


class Proc:
    """A child process whose merged stdout/stderr is collected line by line."""

    def __init__(self, cmd: list[str], env: dict[str, str], name: str, **popen) -> None:
        self.name = name
        self.cmd = cmd
        self.p = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                  text=True, bufsize=1, start_new_session=True, **popen)
        self.lines: list[str] = []
        self._q: queue.Queue[str | None] = queue.Queue()
        self._t = threading.Thread(target=self._pump, daemon=True)
        self._t.start()

    def _pump(self) -> None:
        assert self.p.stdout is not None
        for line in self.p.stdout:
            self.lines.append(line.rstrip("\n"))
            self._q.put(line.rstrip("\n"))
        self._q.put(None)

    def output(self) -> str:
        return "\n".join(self.lines)

    def wait_line(self, prefix: str, timeout: float = 60.0) -> str:
        """The first new line containing ``prefix``; fails if the process ends first."""
        end = time.monotonic() + timeout
        while True:
            left = end - time.monotonic()
            if left <= 0:
                raise AssertionError(f"{self.name}: no '{prefix}' within {timeout} s:\n"
                                     + self.output())
            try:
                line = self._q.get(timeout=left)
            except queue.Empty:
                continue
            if line is None:
                raise AssertionError(f"{self.name} exited ({self.p.wait()}) before '{prefix}':\n"
                                     + self.output())
            if prefix in line:
                return line

    def signal(self, sig: int) -> None:
        self.p.send_signal(sig)

    def wait(self, timeout: float = 30.0) -> int:
        rc = self.p.wait(timeout=timeout)
        self._t.join(timeout=5)
        return rc

    def kill(self) -> None:
        if self.p.poll() is None:
            self.p.kill()
            self.p.wait(timeout=10)


def recorder_cmd(output: Path, *params: str) -> list[str]:
    cmd = [str(ROS2RUN), "dlo_bag", "recorder_node", "--ros-args",
           "-p", f"output:={output}", "-p", "discovery_period:=0.1"]
    for p in params:
        cmd += ["-p", p]
    return cmd


def helper_cmd(*args: str) -> list[str]:
    return [sys.executable, str(HELPER), *args]
