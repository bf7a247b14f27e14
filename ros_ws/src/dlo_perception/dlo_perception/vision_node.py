"""vision_node: top-view image + gripper state of one step -> /dlo/vision/pose with the image's stamp.

The intrinsics come from ``/dlo/camera/camera_info`` (K); the camera's mounting position, which
CameraInfo does not carry, from parameters (defaults: the simulator's camera).

``vision_source:=particles`` (simulation only): O_V from ``/dlo/rope/particles`` and the gripper state
instead, as the authors' environment computes it (``dlo_perception.vision.visual_pose_particles``: the
index walk on the particles' held flags, the task rules' held set), stamped with the cloud's stamp.
"""

from __future__ import annotations

import time

import numpy as np
from dlo_common.node_util import declare_parameters
from dlo_common.params import Param
from dlo_common.topics import topic
from dlo_interface.camera import TopCamera
from dlo_interface.cloud import unpack_particles
from dlo_msgs.msg import GripperState, VisualPose
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile
from sensor_msgs.msg import CameraInfo, Image, PointCloud2

from dlo_perception.sync import PENDING_DEPTH, IncompleteSteps, StampSync, stamp_to_ns
from dlo_perception.vision import DEFAULT_VISION_SOURCE, VISION_SOURCES, visual_pose, visual_pose_particles

DEFAULT_CAMERA = TopCamera.covering_workspace()
INPUT_TIMEOUT = 1.0  # s, a step's image and state not matched by stamp after this long are reported
PARAMETERS = (
    Param(
        "vision_source",
        DEFAULT_VISION_SOURCE,
        "where O_V comes from: image (the top-view camera, what a robot "
        "has) or particles (simulation: the paper's scalars by the authors' index walk on /dlo/rope/particles)",
        choices=VISION_SOURCES,
    ),
    Param(
        "camera_position",
        tuple(float(c) for c in DEFAULT_CAMERA.position),
        "camera centre in the world frame [m], [x, y, z] (looks down -z)",
        length=3,
    ),
    Param(
        "queue_depth",
        10,
        "images and gripper states kept while the node is busy or waits for a step's other "
        "input, and poses kept while a subscriber is busy (keep last): raise it when replaying a bag faster than "
        "the node or its subscribers keep up, so that every frame is processed and every pose received (later)",
        at_least=1,
    ),
)


class VisionNode(Node):
    """Distils O_V = [v_V, q_V, theta_V, y_V] from the camera image (dlo_perception.vision)."""

    def __init__(self, **options):
        super().__init__("vision_node", **options)
        p = declare_parameters(self, PARAMETERS)
        self.camera_position = tuple(p["camera_position"])  # three numbers (declare_parameters checks)
        self.camera = None
        self.source = p["vision_source"]
        primary = "image" if self.source == "image" else "particles"
        # Compile the vision kernel now, not on the first frame (a replayed or live stream would
        # queue up behind the compilation and drop frames).
        visual_pose(np.zeros((1, DEFAULT_CAMERA.height, DEFAULT_CAMERA.width), np.uint8), DEFAULT_CAMERA, np.zeros((1, 2)), 0.1)
        depth = p["queue_depth"]
        # a replay's inputs can reach the node out of step (each topic is resent on its own to a node that
        # acknowledged late): as many incomplete steps are kept as queued inputs
        self.sync = StampSync((primary, "gripper"), depth=max(PENDING_DEPTH, depth))
        self.incomplete = IncompleteSteps(INPUT_TIMEOUT)  # a step whose inputs never share one stamp: reported
        self.publisher = self.create_publisher(VisualPose, topic("vision").name, depth)
        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.create_subscription(CameraInfo, topic("camera_info").name, self.on_camera_info, latched)
        if self.source == "image":
            self.create_subscription(Image, topic("image").name, lambda m: self.on_input("image", m), depth)
        else:
            self.create_subscription(PointCloud2, topic("particles").name, lambda m: self.on_input("particles", m), depth)
        self.create_subscription(GripperState, topic("gripper").name, lambda m: self.on_input("gripper", m), depth)

    def on_camera_info(self, info):
        self.camera = TopCamera.from_camera_info(info.width, info.height, info.k, self.camera_position)

    def on_input(self, key, msg):
        stamp = stamp_to_ns(msg.header.stamp)
        matched = self.sync.add(key, stamp, msg)
        self.report_incomplete(stamp, matched is not None)
        if matched is None:
            return
        if self.source == "particles":
            cloud, gripper = matched
            positions, held = unpack_particles(cloud)
            pose = visual_pose_particles(positions[None], held[None], [len(positions)], np.array([[gripper.x, gripper.y]]))
            self.publish(pose, cloud.header.stamp)
            return
        image, gripper = matched
        if self.camera is None:
            self.get_logger().warning("no camera_info yet: skipping an image", throttle_duration_sec=2.0)
            return
        if image.encoding != "mono8":
            self.get_logger().error(f"expected a mono8 segmentation image, got {image.encoding}", throttle_duration_sec=2.0)
            return
        pixels = np.frombuffer(bytes(image.data), np.uint8).reshape(image.height, image.step)[:, : image.width]
        pose = visual_pose(pixels[None], self.camera, np.array([[gripper.x, gripper.y]]), gripper.z)
        self.publish(pose, image.header.stamp)

    def publish(self, pose, stamp):
        """One reading (a batch of 1) as /dlo/vision/pose with the stamp of the input it was computed from."""
        out = VisualPose(
            visible=bool(pose.visible[0]), confidence=float(pose.confidence[0]), angle=float(pose.angle[0]), y=float(pose.y[0])
        )
        out.header.stamp = stamp
        out.header.frame_id = "gripper"  # angle and offset relative to the gripper, in its frame
        self.publisher.publish(out)

    def report_incomplete(self, stamp, matched):
        """Steps whose image and state do not meet within INPUT_TIMEOUT s: one error a second at most,
        naming the missing input and the stamps seen nearby (dlo_perception.sync.IncompleteSteps)."""
        line = self.incomplete.note(self.sync, stamp, matched, time.monotonic(), prefer="gripper")
        if line is not None:
            self.get_logger().error(line)


def main(args=None):
    from dlo_common.node_main import run_node

    return run_node(VisionNode, args, parameters=PARAMETERS, summary=__doc__)


if __name__ == "__main__":
    raise SystemExit(main())
