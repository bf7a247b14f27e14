"""Workspace-level fixtures: an isolated ROS 2 domain per test session."""

import os
import random

import pytest


@pytest.fixture(scope="session", autouse=True)
def isolated_ros_domain():
    """Give this test session its own DDS domain so parallel runs do not cross-talk."""
    os.environ.setdefault("ROS_DOMAIN_ID", str(random.Random(os.getpid()).randint(100, 200)))
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    yield os.environ["ROS_DOMAIN_ID"]
