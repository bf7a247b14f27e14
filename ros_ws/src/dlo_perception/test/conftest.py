"""Fixtures of the perception tests that run a node in-process."""

import os

import pytest
from harness import reserved_domain


@pytest.fixture(scope="module")
def context():
    """An rclpy context of the module's own, on a DDS domain reserved for it (harness: no other
    test module, test process or graph on this machine uses it meanwhile)."""
    rclpy = pytest.importorskip("rclpy")
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    context = rclpy.Context()
    with reserved_domain() as domain:
        rclpy.init(context=context, domain_id=domain)
        yield context
        rclpy.shutdown(context=context)
