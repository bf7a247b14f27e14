"""Commands for the dlo_bag tests (processes, ros2run, the environment: tests/support/harness.py)."""

from __future__ import annotations

import sys
from pathlib import Path

from harness import ROS2RUN

HERE = Path(__file__).resolve().parent
HELPER = HERE / "dlo_bag_graph_helper.py"


def recorder_cmd(output: Path, *params: str) -> list[str]:
    cmd = [str(ROS2RUN), "dlo_bag", "recorder_node", "--ros-args", "-p", f"output:={output}", "-p", "discovery_period:=0.1"]
    for p in params:
        cmd += ["-p", p]
    return cmd


def helper_cmd(*args: str) -> list[str]:
    return [sys.executable, str(HELPER), *args]
