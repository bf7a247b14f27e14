"""vision_node: its queues (`queue_depth`) keep what a replay faster than the node or its subscribers sends."""
import pytest

rclpy = pytest.importorskip("rclpy")


def vision_node(context, monkeypatch, **parameters):
    from rclpy.parameter import Parameter

    from dlo_perception import vision_node as module

    init = rclpy.node.Node.__init__
    overrides = [Parameter(name, value=value) for name, value in parameters.items()]
    monkeypatch.setattr(rclpy.node.Node, "__init__", lambda self, *a, **k: init(
        self, *a, **{"context": context, "parameter_overrides": overrides, **k}))
    try:
        return module.VisionNode()
    finally:
        monkeypatch.setattr(rclpy.node.Node, "__init__", init)


@pytest.mark.parametrize("depth", [None, 1000])
def test_queue_depth_is_the_depth_of_the_image_and_state_subscriptions_and_the_pose_publisher(context, monkeypatch,
                                                                                               depth):
    node = vision_node(context, monkeypatch, **({} if depth is None else {"queue_depth": depth}))
    try:
        depths = {s.topic_name: s.qos_profile.depth for s in node.subscriptions}
        published = {p.topic_name: p.qos_profile.depth for p in node.publishers if p.topic_name.startswith("/dlo/")}
    finally:
        node.destroy_node()
    expected = 10 if depth is None else depth
    assert depths == {"/dlo/camera/image": expected, "/dlo/gripper/state": expected, "/dlo/camera/camera_info": 1}
    assert published == {"/dlo/vision/pose": expected}  # a busy subscriber of a fast replay gets every pose


@pytest.mark.parametrize("depth, processed", [(None, 32), (1000, 160)])
def test_a_replay_whose_images_come_before_their_states_is_processed_whole(context, monkeypatch, depth, processed):
    """Two inputs of a replay reach a node out of step when one of them is resent (a node starved of CPU acknowledges
    late; each topic is resent on its own): here every image comes before the first gripper state. With a deep queue
    (replaying) every frame is still matched and processed; at the live depth the newest 32 are (the older stamps
    are dropped as superseded)."""
    from dlo_msgs.msg import GripperState
    from sensor_msgs.msg import Image

    from dlo_perception.camera import camera_info
    from dlo_perception.vision_node import DEFAULT_CAMERA

    node = vision_node(context, monkeypatch, **({} if depth is None else {"queue_depth": depth}))
    try:
        sent = []
        monkeypatch.setattr(node.publisher, "publish", sent.append)
        node.on_camera_info(camera_info(DEFAULT_CAMERA))
        stamps = [(1 + k // 12, (k % 12) * 80_000_000) for k in range(160)]  # 160 steps of 0.08 s from 1 s
        for sec, nanosec in stamps:
            image = Image(height=DEFAULT_CAMERA.height, width=DEFAULT_CAMERA.width, encoding="mono8",
                          step=DEFAULT_CAMERA.width, data=bytes(DEFAULT_CAMERA.height * DEFAULT_CAMERA.width))
            image.header.stamp.sec, image.header.stamp.nanosec = sec, nanosec
            node.on_input("image", image)
        for sec, nanosec in stamps:
            state = GripperState(x=0.1, y=0.0, z=0.05)
            state.header.stamp.sec, state.header.stamp.nanosec = sec, nanosec
            node.on_input("gripper", state)
    finally:
        node.destroy_node()
    assert [(p.header.stamp.sec, p.header.stamp.nanosec) for p in sent] == stamps[-processed:]
