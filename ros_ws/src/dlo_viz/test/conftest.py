"""Fixtures for the dlo_viz tests: processes on an isolated ROS domain (tests/support/harness.py)."""

from __future__ import annotations

import pytest
from harness import Procs, package_test_env


@pytest.fixture(scope="session")
def ros_env() -> dict[str, str]:
    """Environment of env.sh on a reserved ROS_DOMAIN_ID (tests/support/harness.py) and localhost discovery."""
    return package_test_env("dlo_viz", "foxglove_bridge")


@pytest.fixture
def procs(ros_env):
    """Start processes with ``procs(name, cmd)``; every one still running is stopped afterwards."""
    with Procs(ros_env) as start:
        yield start
