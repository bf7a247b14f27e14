"""tactile_node: particles + gripper state of one step -> /dlo/tactile/pose with the same stamp.

Its noise is ``tactile_noise``, read as the gym env and ``launch_graph.sh --tactile-noise`` read it
(``dlo_perception.tactile.noise_setting``): ``none``, ``partial``, ``full`` or a pair
``[sigma_theta,sigma_y]`` [rad, m].
"""

from __future__ import annotations

import time

import numpy as np
from dlo_common.node_util import declare_parameters
from dlo_common.params import Param
from dlo_common.topics import topic
from dlo_interface.cloud import unpack_particles
from dlo_msgs.msg import GripperState, TactilePose
from rclpy.node import Node
from sensor_msgs.msg import PointCloud2

from dlo_perception.sync import IncompleteSteps, StampSync, stamp_to_ns
from dlo_perception.tactile import TACTILE_NOISE, noise_label, noise_setting, noise_sigma, tactile_pose

INPUT_TIMEOUT = 1.0  # s, a step's particles and state not matched by stamp after this long are reported
PARAMETERS = (
    Param(
        "tactile_noise",
        "none",
        "noise std of theta_T and y_T at an open gripper (scaled by 1 - closure): none, "
        f"partial ({list(TACTILE_NOISE['partial'])}), full ({list(TACTILE_NOISE['full'])}) or a pair "
        "[sigma_theta [rad], sigma_y [m]] such as [0.1,0.001]",
        check=noise_setting,
        types="string or double_array",
        accepts="none | partial | full | [sigma_theta,sigma_y]",
    ),
    Param("seed", 0, "seed of the noise generator", at_least=0),
)


class TactileNode(Node):
    """Fits the held cable line in the gripper frame (dlo_perception.tactile) for every step."""

    def __init__(self, **options):
        super().__init__("tactile_node", **options)
        p = declare_parameters(self, PARAMETERS)
        self.tactile_noise = noise_setting(p["tactile_noise"])
        self.sigma = noise_sigma(self.tactile_noise)
        self.get_logger().info(f"tactile noise: {noise_label(self.tactile_noise)}; seed {p['seed']}")
        self.rng = np.random.default_rng(p["seed"])
        self.sync = StampSync(("particles", "gripper"))
        self.incomplete = IncompleteSteps(INPUT_TIMEOUT)  # a step whose inputs never share one stamp: reported
        self.last = (None, None)  # (stamp_ns, TactilePose): a republished step gets the same reading
        self.publisher = self.create_publisher(TactilePose, topic("tactile").name, 10)
        self.create_subscription(PointCloud2, topic("particles").name, lambda m: self.on_input("particles", m), 10)
        self.create_subscription(GripperState, topic("gripper").name, lambda m: self.on_input("gripper", m), 10)

    def on_input(self, key, msg):
        stamp = stamp_to_ns(msg.header.stamp)
        matched = self.sync.add(key, stamp, msg)
        self.report_incomplete(stamp, matched is not None)
        if matched is None:
            return
        if self.last[0] == stamp:  # the sim republished this step: same noise draw, not a new one
            self.publisher.publish(self.last[1])
            return
        cloud, gripper = matched
        positions, held = unpack_particles(cloud)
        pose = tactile_pose(
            positions[None], held[None], np.array([[gripper.x, gripper.y]]), np.array([gripper.closure]), self.sigma, self.rng
        )
        out = TactilePose(
            angle=float(pose.angle[0]), y=float(pose.y[0]), contact=bool(pose.contact[0]), contact_count=int(pose.count[0])
        )
        out.header.stamp = cloud.header.stamp
        out.header.frame_id = "gripper"  # angle and offset are in the gripper frame (docs/ARCHITECTURE.md#world)
        self.last = (stamp, out)
        self.publisher.publish(out)

    def report_incomplete(self, stamp, matched):
        """Steps whose particles and state do not meet within INPUT_TIMEOUT s: one error a second at most,
        naming the missing input and the stamps seen nearby (dlo_perception.sync.IncompleteSteps)."""
        line = self.incomplete.note(self.sync, stamp, matched, time.monotonic(), prefer="gripper")
        if line is not None:
            self.get_logger().error(line)


def main(args=None):
    from dlo_common.node_main import run_node

    return run_node(TactileNode, args, parameters=PARAMETERS, summary=__doc__)


if __name__ == "__main__":
    raise SystemExit(main())
