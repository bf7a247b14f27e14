"""Fixtures for the dlo_driver_kit tests: processes on an isolated ROS domain (dlo_common.testing)."""

from __future__ import annotations

import pytest

from dlo_common.testing import Procs, package_test_env

DRIVER_CHECK_DOMAINS = 20  # the session's domain and one per broken driver (16, test_driver_check.py), with room


@pytest.fixture(scope="session")
def ros_env() -> dict[str, str]:
    """Environment of env.sh on reserved ROS domains (ROS_DOMAIN_ID the first; the broken-driver checks use
    the next DRIVER_CHECK_DOMAINS - 1) and localhost discovery."""
    return package_test_env("dlo_driver_kit", "mock_driver_node", domains=DRIVER_CHECK_DOMAINS)


@pytest.fixture
def procs(ros_env):
    """Start processes with ``procs(name, cmd)``; every one still running is stopped afterwards."""
    with Procs(ros_env) as start:
        yield start
