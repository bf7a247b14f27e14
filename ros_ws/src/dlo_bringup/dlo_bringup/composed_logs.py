"""The nodes' own logs from the output of the one ``--composed`` process (:mod:`dlo_bringup.composed`), so that the
launcher reads ``<name>.log`` of each node as it does when every node has a process of its own: its ready line,
its warnings for the status line, the end of its log when it fails, the recorder's failure, the policy's line.

The lines go to the log of the node they name: an rclpy log line by its logger (``[INFO] [time] [sim_node]: ...``),
a line of the runner by the node name it starts with (``[sim_node] bad parameter: ...``); the runner's
``[composed] building NAME`` / ``[composed] built NAME as NODE_NAME`` lines frame each node's building and say the
node names. A line that names no node (a traceback's, the Taichi banner) goes with the node being built, else with
the node of the line before. Everything stays in the process's own log as well.

Standard library only (the launcher's).
"""

from __future__ import annotations

import re
import threading
from pathlib import Path

RUNNER = "[composed] "  # the runner's own lines start so
BUILDING, BUILT = RUNNER + "building ", RUNNER + "built "  # the lines that frame a node's building
_ROS_LINE = re.compile(r"\[[A-Z]+\] \[[0-9.]+\] \[([^\]]+)\]")  # rclpy: [SEVERITY] [time] [logger]: text
_OWN_LINE = re.compile(r"\[([^\]\s]+)\] ")  # the runner's line about a node: [node name] text


class LogSplitter:
    """Copies the lines appended to ``source`` into ``logs`` ({spec name: its log}), each to its node's log
    (the module docstring); :meth:`pump` copies what is new, :meth:`start` does so in a thread until :meth:`stop`."""

    def __init__(self, source: Path, logs: dict, period: float = 0.05):
        self.source, self.period = Path(source), period
        self.files = {name: open(path, "a") for name, path in logs.items()}
        self.names: dict = {}  # node name -> spec name
        self.building = None  # the spec name being built
        self.last = None  # the spec name of the line before
        self.offset, self.rest = 0, b""
        self._stop = threading.Event()
        self._thread = None
        self._lock = threading.Lock()

    def route(self, line: str) -> str | None:
        """The spec name whose log gets ``line``, or None (only the process's own log keeps it)."""
        if line.startswith(BUILDING):
            self.building = self.last = line[len(BUILDING) :].strip()
            return None
        if line.startswith(BUILT):
            name, _, node = line[len(BUILT) :].strip().partition(" as ")
            if node:
                self.names[node] = name
            self.building = None
            return None
        if line.startswith(RUNNER):  # the runner's own (its end)
            return None
        found = _ROS_LINE.match(line) or _OWN_LINE.match(line)
        named = self.names.get(found.group(1).split(".")[0]) if found else None
        owner = named or self.building or self.last
        self.last = owner
        return owner

    def pump(self) -> None:
        """Copy the complete lines appended to the source since the last call."""
        with self._lock:
            try:
                with open(self.source, "rb") as f:
                    f.seek(self.offset)
                    data = f.read()
            except FileNotFoundError:
                return
            self.offset += len(data)
            *lines, self.rest = (self.rest + data).split(b"\n")
            touched = set()
            for raw in lines:
                line = raw.decode(errors="replace")
                owner = self.route(line)
                if owner in self.files:
                    self.files[owner].write(line + "\n")
                    touched.add(owner)
            for owner in touched:
                self.files[owner].flush()

    def _run(self) -> None:
        while not self._stop.wait(self.period):
            self.pump()

    def start(self) -> LogSplitter:
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """The last lines copied (a line the process left unfinished too), the logs closed."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        self.pump()
        with self._lock:
            if self.rest:
                owner = self.route(self.rest.decode(errors="replace"))
                if owner in self.files:
                    self.files[owner].write(self.rest.decode(errors="replace") + "\n")
                self.rest = b""
            for f in self.files.values():
                f.close()
            self.files = {}
