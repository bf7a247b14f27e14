"""Fixtures of the perception tests that run a node in-process."""
import os
import random

import pytest


@pytest.fixture(scope="module")
def context(request):
    """An rclpy context of the module's own, on a DDS domain of its own (201-230, from the pid and the
    module: two test modules or two test processes do not share one)."""
    rclpy = pytest.importorskip("rclpy")
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    context = rclpy.Context()
    seed = f"{os.getpid()}:{request.module.__name__}"
    rclpy.init(context=context, domain_id=random.Random(seed).randint(201, 230))
    yield context
    rclpy.shutdown(context=context)
