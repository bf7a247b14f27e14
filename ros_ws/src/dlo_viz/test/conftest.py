"""Fixtures for the dlo_viz tests: processes on an isolated ROS domain."""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))  # --import-mode=importlib

from dlo_viz_testutil import ROS2RUN, Proc  # noqa: E402


@pytest.fixture(scope="session")
def ros_env() -> dict[str, str]:
    """Environment of env.sh with a random ROS_DOMAIN_ID (100..200) and localhost discovery."""
    if not ROS2RUN.exists():
        pytest.skip("scripts/ros2run missing")
    env = dict(os.environ)
    if "DLO_ROOT" not in env:
        pytest.skip("source scripts/env.sh first")
    env["ROS_DOMAIN_ID"] = str(random.randint(100, 200))
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env["PYTHONUNBUFFERED"] = "1"
    env.pop("ROS_LOCALHOST_ONLY", None)
    check = subprocess.run([str(ROS2RUN), "dlo_viz"], env=env, capture_output=True, text=True)
    if "foxglove_bridge" not in check.stdout:
        pytest.skip("dlo_viz is not built (run scripts/setup.sh): " + check.stderr)
    return env


@pytest.fixture
def procs(ros_env):
    """Start processes with ``start(name, cmd)``; every one still running is killed afterwards."""
    started: list[Proc] = []

    def start(name: str, cmd: list[str], **popen) -> Proc:
        proc = Proc(cmd, ros_env, name, **popen)
        started.append(proc)
        return proc

    yield start
    for proc in started:
        if proc.p.poll() is None:
            proc.signal(signal.SIGINT)
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
