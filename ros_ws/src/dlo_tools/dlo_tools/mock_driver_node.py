"""mock_driver_node: a kinematic stand-in for a real robot driver (not the simulator).

It shows what a driver must do for the rest of the graph to run unchanged (README, "Swap for a
real robot"): publish ``/dlo/gripper/state`` and the top camera's ``/dlo/camera/image`` +
``camera_info``, a tactile source (here ``/dlo/rope/particles`` with the contact points between
the fingers flagged, which the tactile node turns into ``/dlo/tactile/pose``; a real sensor driver
may publish ``/dlo/tactile/pose`` itself), and obey ``/dlo/gripper/cmd``.

The "cable" is a fixed curve on the gripper's plane, the gripper integrates the commanded
velocity and takes the commanded closure at once, and the image is drawn with plain numpy. It
is step-locked like the sim: one command per published state.
"""

from __future__ import annotations

import numpy as np
from builtin_interfaces.msg import Time
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile
from sensor_msgs.msg import CameraInfo, Image, PointCloud2

from dlo_msgs.msg import GripperCommand, GripperState
from dlo_perception.camera import TopCamera
from dlo_perception.cloud import particle_cloud
from dlo_common.node_util import ParameterError, declare_parameters

CONTROL_PERIOD_NS = 80_000_000  # one command per 0.08 s of driver time
FINGER_REACH = 0.0125 + 0.0043  # m, a point this close to the gripper centre (in x-y) is in contact
CABLE_RADIUS = 0.008  # m, drawn width


def mock_cable(length: float, amplitude: float, spacing: float = 0.0043, height: float = 0.1) -> np.ndarray:
    """(P, 3) points of a gentle S-curve starting at the fixed end (-0.25, 0, height) along +x [m]."""
    x = -0.25 + np.arange(0.0, length, spacing)
    y = amplitude * np.sin(2 * np.pi * (x + 0.25) / max(length, 1e-6))
    return np.stack([x, y, np.full_like(x, height)], axis=1)


def draw_cable(points: np.ndarray, camera: TopCamera, gripper_xy) -> np.ndarray:
    """Top-view segmentation image (255 cable, 128 gripper) of the points, like a segmented camera frame."""
    v, u = np.mgrid[0:camera.height, 0:camera.width]
    centres = np.stack([u + 0.5, v + 0.5], axis=-1)
    world = camera.pixel_to_world(centres, points[0, 2])
    image = np.zeros((camera.height, camera.width), np.uint8)
    near = np.min(np.linalg.norm(world[:, :, None, :] - points[None, None, :, :2], axis=-1), axis=2)
    image[near <= CABLE_RADIUS] = 255
    image[np.linalg.norm(world - np.asarray(gripper_xy), axis=-1) <= 0.0125] = 128
    return image


class MockDriver(Node):
    """Kinematic gripper over a fixed cable; obeys commands one step at a time."""

    def __init__(self):
        super().__init__("mock_driver")
        p = declare_parameters(self, [
            ("cable_length", 0.2, "length of the mock cable [m]"),
            ("amplitude", 0.02, "lateral amplitude of its S-curve [m]"),
            ("steps", 100, "control steps before the driver exits"),
        ])
        if not 0.05 <= p["cable_length"] <= 0.5 or p["steps"] < 1:
            raise ParameterError(f"cable_length must be in [0.05, 0.5] m and steps >= 1, got {p}")
        self.cable = mock_cable(p["cable_length"], p["amplitude"])
        self.camera = TopCamera.covering_workspace(128)
        self.gripper = np.array([self.cable[0, 0] + 0.005, self.cable[0, 1]])
        self.closure, self.step, self.max_steps, self.stamp_ns = 0.7, 0, p["steps"], CONTROL_PERIOD_NS
        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.pub_state = self.create_publisher(GripperState, "/dlo/gripper/state", 10)
        self.pub_image = self.create_publisher(Image, "/dlo/camera/image", 10)
        self.pub_cloud = self.create_publisher(PointCloud2, "/dlo/rope/particles", 10)
        info_pub = self.create_publisher(CameraInfo, "/dlo/camera/camera_info", latched)
        info = CameraInfo(width=self.camera.width, height=self.camera.height)
        info.header.frame_id = "top_camera_optical"
        info.k = self.camera.k_matrix.reshape(-1).tolist()
        info_pub.publish(info)
        self.create_subscription(GripperCommand, "/dlo/gripper/cmd", self.on_command, 10)
        self.create_timer(0.25, self.publish_state)  # (re)publish until the step is answered

    def on_command(self, msg):
        if msg.step != self.step or not np.isfinite([msg.vx, msg.vy, msg.closure]).all():
            return
        self.gripper += 0.08 * np.clip([msg.vx, msg.vy], -0.25, 0.25)
        self.closure = float(np.clip(msg.closure, 0.0, 1.0))
        self.step += 1
        self.stamp_ns += CONTROL_PERIOD_NS
        if self.step >= self.max_steps:
            self.get_logger().info(f"mock driver done at x = {self.gripper[0]:.3f} m, y = {self.gripper[1]:.4f} m")
            raise SystemExit(0)
        self.publish_state()

    def publish_state(self):
        stamp = Time(sec=self.stamp_ns // 1_000_000_000, nanosec=self.stamp_ns % 1_000_000_000)
        contact = np.linalg.norm(self.cable[:, :2] - self.gripper, axis=1) <= FINGER_REACH
        cloud = particle_cloud(self.cable, contact)
        pixels = draw_cable(self.cable, self.camera, self.gripper)
        image = Image(height=pixels.shape[0], width=pixels.shape[1], encoding="mono8", step=pixels.shape[1],
                      data=pixels.tobytes())
        state = GripperState(x=float(self.gripper[0]), y=float(self.gripper[1]), z=float(self.cable[0, 2]),
                             closure=self.closure, episode=0, step=self.step)
        for msg in (cloud, image, state):
            msg.header.stamp, msg.header.frame_id = stamp, "world"
        image.header.frame_id = "top_camera_optical"  # shared with camera_info
        self.pub_cloud.publish(cloud)
        self.pub_image.publish(image)
        self.pub_state.publish(state)


def main(args=None):
    from dlo_common.node_main import run_node

    return run_node(MockDriver, args)


if __name__ == "__main__":
    raise SystemExit(main())
