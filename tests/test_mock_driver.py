"""A driver that is not the simulator (dlo_driver_kit mock_driver_node) runs the rest of the graph unchanged."""

import pathlib
import re
import subprocess

import numpy as np
from dlo_driver_kit.mock_driver_node import FINGER_REACH, mock_cable

ROOT = pathlib.Path(__file__).resolve().parents[1]
ROS2RUN = str(ROOT / "scripts" / "ros2run")


def test_perception_and_policy_follow_a_mock_robot_cable(own_groups):
    quiet = dict(stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT, start_new_session=True)
    nodes = [
        subprocess.Popen([ROS2RUN, "dlo_perception", "tactile_node"], **quiet),
        subprocess.Popen([ROS2RUN, "dlo_perception", "vision_node"], **quiet),
        subprocess.Popen([ROS2RUN, "dlo_policy", "policy_node", "--ros-args", "-p", "policy:=tactile_reactive"], **quiet),
    ]
    for node in nodes:
        own_groups(node.pid)  # stopped at teardown (SIGINT, then SIGKILL), even if this test fails
    driver = subprocess.run(
        [
            ROS2RUN,
            "dlo_driver_kit",
            "mock_driver_node",
            "--ros-args",
            "-p",
            "steps:=40",
            "-p",
            "mode:=step_locked",
        ],  # one answered state = one step: 40 steps of the policy
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert driver.returncode == 0, driver.stdout + driver.stderr
    x, y = map(float, re.search(r"done at x = (\S+) m, y = (\S+) m", driver.stdout + driver.stderr).groups())
    cable = mock_cable(0.2, 0.02)
    assert x > cable[0, 0] + 0.1  # it travelled along the cable ...
    assert np.min(np.linalg.norm(cable[:, :2] - [x, y], axis=1)) <= FINGER_REACH  # ... and still touches it
