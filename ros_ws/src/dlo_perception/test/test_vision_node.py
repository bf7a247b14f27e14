"""vision_node: its input queues (`queue_depth`) keep what a replay faster than the node sends."""
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
def test_queue_depth_is_the_depth_of_the_image_and_state_subscriptions(context, monkeypatch, depth):
    node = vision_node(context, monkeypatch, **({} if depth is None else {"queue_depth": depth}))
    try:
        depths = {s.topic_name: s.qos_profile.depth for s in node.subscriptions}
    finally:
        node.destroy_node()
    expected = 10 if depth is None else depth
    assert depths == {"/dlo/camera/image": expected, "/dlo/gripper/state": expected, "/dlo/camera/camera_info": 1}
