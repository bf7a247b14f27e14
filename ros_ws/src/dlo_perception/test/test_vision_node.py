"""vision_node in-process (no graph): what it publishes for a step's image and gripper state, what it says when it
cannot (no camera_info yet, not mono8, a state stamped apart from its image), and its queues (`queue_depth`), which
keep what a replay faster than the node or its subscribers sends."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))  # --import-mode=importlib

from harness import LogLines  # noqa: E402
from test_vision import GRIPPER, PLANE_Z, draw, held_then_bent  # noqa: E402

rclpy = pytest.importorskip("rclpy")
STEP_NS = 80_000_000


def vision_node(context, monkeypatch, **parameters):
    from dlo_perception import vision_node as module
    from rclpy.parameter import Parameter

    init = rclpy.node.Node.__init__
    overrides = [Parameter(name, value=value) for name, value in parameters.items()]
    monkeypatch.setattr(
        rclpy.node.Node,
        "__init__",
        lambda self, *a, **k: init(self, *a, **{"context": context, "parameter_overrides": overrides, **k}),
    )
    try:
        return module.VisionNode()
    finally:
        monkeypatch.setattr(rclpy.node.Node, "__init__", init)


@pytest.mark.parametrize("depth", [None, 1000])
def test_queue_depth_is_the_depth_of_the_image_and_state_subscriptions_and_the_pose_publisher(context, monkeypatch, depth):
    node = vision_node(context, monkeypatch, **({} if depth is None else {"queue_depth": depth}))
    try:
        depths = {s.topic_name: s.qos_profile.depth for s in node.subscriptions}
        published = {p.topic_name: p.qos_profile.depth for p in node.publishers if p.topic_name.startswith("/dlo/")}
        latched = [s.qos_profile.durability for s in node.subscriptions if s.topic_name == "/dlo/camera/camera_info"]
    finally:
        node.destroy_node()
    expected = 10 if depth is None else depth
    assert depths == {"/dlo/camera/image": expected, "/dlo/gripper/state": expected, "/dlo/camera/camera_info": 1}
    assert published == {"/dlo/vision/pose": expected}  # a busy subscriber of a fast replay gets every pose
    assert latched == [rclpy.qos.DurabilityPolicy.TRANSIENT_LOCAL]  # a node started late still gets the intrinsics


@pytest.mark.parametrize("depth, processed", [(None, 32), (1000, 160)])
def test_a_replay_whose_images_come_before_their_states_is_processed_whole(context, monkeypatch, depth, processed):
    """Two inputs of a replay reach a node out of step when one of them is resent (a node starved of CPU acknowledges
    late; each topic is resent on its own): here every image comes before the first gripper state. With a deep queue
    (replaying) every frame is still matched and processed; at the live depth the newest 32 are (the older stamps
    are dropped as superseded)."""
    from dlo_interface.camera import camera_info
    from dlo_perception.vision_node import DEFAULT_CAMERA

    node = vision_node(context, monkeypatch, **({} if depth is None else {"queue_depth": depth}))
    try:
        sent = []
        monkeypatch.setattr(node.publisher, "publish", sent.append)
        node.on_camera_info(camera_info(DEFAULT_CAMERA))
        stamps = [(1 + k // 12, (k % 12) * 80_000_000) for k in range(160)]  # 160 steps of 0.08 s from 1 s
        blank = np.zeros((DEFAULT_CAMERA.height, DEFAULT_CAMERA.width), np.uint8)
        steps = [step_messages(blank, sec, nanosec) for sec, nanosec in stamps]
        for image, _ in steps:
            node.on_input("image", image)
        for _, state in steps:
            node.on_input("gripper", state)
    finally:
        node.destroy_node()
    assert [(p.header.stamp.sec, p.header.stamp.nanosec) for p in sent] == stamps[-processed:]


def step_messages(pixels, sec, nanosec, *, encoding="mono8", padding=0, stamp_offset_ns=0):
    """The image (rows padded by ``padding`` bytes, as ``step`` allows) and gripper state of one step."""
    from dlo_msgs.msg import GripperState
    from sensor_msgs.msg import Image

    height, width = pixels.shape
    rows = np.hstack([pixels, np.full((height, padding), 7, np.uint8)])
    image = Image(height=height, width=width, encoding=encoding, step=width + padding, data=rows.tobytes())
    image.header.stamp.sec, image.header.stamp.nanosec = sec, nanosec
    state = GripperState(x=float(GRIPPER[0]), y=float(GRIPPER[1]), z=PLANE_Z, closure=0.7)
    state.header.stamp.sec, state.header.stamp.nanosec = divmod(sec * 1_000_000_000 + nanosec + stamp_offset_ns, 1_000_000_000)
    return image, state


@pytest.mark.parametrize("padding", [0, 3])
def test_the_pose_is_the_image_s_reading_with_its_stamp_in_the_gripper_frame(context, monkeypatch, padding):
    from dlo_interface.camera import camera_info
    from dlo_perception.vision import visual_pose
    from dlo_perception.vision_node import DEFAULT_CAMERA

    pixels = draw([held_then_bent(-0.6, 0.004)], GRIPPER)  # cable bent down right of the gripper, held 4 mm off
    node = vision_node(context, monkeypatch)
    try:
        sent = []
        monkeypatch.setattr(node.publisher, "publish", sent.append)
        node.on_camera_info(camera_info(DEFAULT_CAMERA))
        image, state = step_messages(pixels, 3, 240_000_000, padding=padding)
        node.on_input("gripper", state)
        assert sent == []  # the step's image has not come yet
        node.on_input("image", image)
    finally:
        node.destroy_node()
    want = visual_pose(pixels[None], DEFAULT_CAMERA, GRIPPER[None], PLANE_Z)
    assert want.visible[0] and want.confidence[0] > 0.5 and want.angle[0] < -0.3 and want.y[0] != 0.0  # a real reading
    [pose] = sent
    assert (pose.header.stamp.sec, pose.header.stamp.nanosec, pose.header.frame_id) == (3, 240_000_000, "gripper")
    assert (pose.visible, pose.confidence, pose.angle, pose.y) == (
        bool(want.visible[0]),
        float(want.confidence[0]),
        float(want.angle[0]),
        float(want.y[0]),
    )


def test_without_camera_info_or_with_a_colour_image_no_pose_and_a_line_says_why(context, monkeypatch):
    from dlo_interface.camera import camera_info
    from dlo_perception.vision_node import DEFAULT_CAMERA

    pixels = draw([held_then_bent(0.0)], GRIPPER)
    node = vision_node(context, monkeypatch)
    log = LogLines()
    monkeypatch.setattr(node, "get_logger", lambda: log)
    try:
        sent = []
        monkeypatch.setattr(node.publisher, "publish", sent.append)
        image, state = step_messages(pixels, 1, 0)
        node.on_input("image", image)
        node.on_input("gripper", state)
        assert sent == [] and log.lines == [("warning", "no camera_info yet: skipping an image")]
        node.on_camera_info(camera_info(DEFAULT_CAMERA))
        image, state = step_messages(np.repeat(pixels, 3, axis=1), 1, STEP_NS, encoding="rgb8")
        image.width //= 3
        node.on_input("image", image)
        node.on_input("gripper", state)
        assert sent == [] and log.lines[1:] == [("error", "expected a mono8 segmentation image, got rgb8")]
        image, state = step_messages(pixels, 1, 2 * STEP_NS)
        node.on_input("image", image)
        node.on_input("gripper", state)
        assert len(sent) == 1 and len(log.lines) == 2  # the next mono8 step after camera_info: a pose
    finally:
        node.destroy_node()


def test_a_state_stamped_apart_from_its_image_is_reported_once_a_second(context, monkeypatch):
    """A driver whose image is stamped 0.4 us after its state: no step matches; about one error a second naming
    the state's step (not the image's, which comes later), the image's stamps nearby and the state's stamp
    (dlo_perception.sync.IncompleteSteps)."""
    from dlo_interface.camera import camera_info
    from dlo_perception import vision_node as module

    pixels = draw([held_then_bent(0.0)], GRIPPER)
    node = vision_node(context, monkeypatch)
    log, clock = LogLines(), [50.0]
    monkeypatch.setattr(node, "get_logger", lambda: log)
    monkeypatch.setattr(module, "time", type("Clock", (), {"monotonic": staticmethod(lambda: clock[0])}))
    try:
        sent = []
        monkeypatch.setattr(node.publisher, "publish", sent.append)
        node.on_camera_info(camera_info(module.DEFAULT_CAMERA))
        for k in range(50):  # 4 s of steps
            image, state = step_messages(pixels, *divmod(1_000_000_400 + k * STEP_NS, 1_000_000_000), stamp_offset_ns=-400)
            node.on_input("image", image)
            node.on_input("gripper", state)
            clock[0] += 0.08
    finally:
        node.destroy_node()
    assert sent == []
    errors = log.of("error")
    assert len(errors) == len(log.lines) and 3 <= len(errors) <= 4, log.lines  # once a second, not 50 times
    assert errors[0].startswith(
        "step at t=1.00 s: no image input after 1.0 s; image has stamps 1.0000004, 1.0800004 "
        "nearby; gripper state at 1 (the image's nearest stamp is 0.4 us later"
    ), errors[0]
