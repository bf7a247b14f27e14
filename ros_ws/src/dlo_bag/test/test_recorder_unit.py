"""recorder_node in-process with a publisher node in the same process (no child processes; issue 14).

What the recorder's other unit tests (test_bag.py, on the library) cannot see and its process tests
see only slowly:
- the bag timestamp of a message is its RECEIVE time (wall clock), not its header stamp;
- a transient-local topic published before the recorder started (camera_info) is recorded, and
  so is a best-effort topic (the subscription matches every publisher's QoS, as rosbag2 does);
- topic selection: /dlo and below, /clock only when asked, nothing else; a topic without a
  publisher is not subscribed.
"""

import os
import random
import time

import pytest

rclpy = pytest.importorskip("rclpy")
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from rosbags.interfaces import QosDurability, QosReliability  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from sensor_msgs.msg import CameraInfo  # noqa: E402

from dlo_msgs.msg import GripperState  # noqa: E402
from dlo_bag import recorder_node as recorder_module  # noqa: E402
from dlo_bag.bag import bag_info, read_messages  # noqa: E402

N = 5


@pytest.fixture(scope="module")
def context():
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=random.Random(os.getpid() + 3).randint(201, 230))
    yield context
    rclpy.shutdown(context=context)


def spin_until(executor, condition, timeout=20.0):
    deadline = time.monotonic() + timeout
    while not condition() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)
    return condition()


def old_state(i):
    msg = GripperState(x=0.001 * i, step=i)
    msg.header.stamp.sec, msg.header.stamp.nanosec = 1, i  # a header stamp far in the past
    msg.header.frame_id = str(i)
    return msg


def test_receive_timestamps_latched_and_best_effort_topics_and_selection(context, tmp_path, monkeypatch):
    pub_node = rclpy.create_node("recorder_unit_publisher", context=context)
    latched = pub_node.create_publisher(CameraInfo, "/dlo/camera/camera_info",
                                        QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL))
    info = CameraInfo(width=32, height=32)
    info.header.frame_id = "top_camera_optical"
    latched.publish(info)  # before the recorder exists
    states = pub_node.create_publisher(GripperState, "/dlo/gripper/state", 10)
    best_effort = pub_node.create_publisher(GripperState, "/dlo/best_effort",
                                            QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT))
    clock = pub_node.create_publisher(Clock, "/clock", 10)
    outside = pub_node.create_publisher(GripperState, "/dlox/state", 10)
    pub_node.create_subscription(GripperState, "/dlo/nobody_publishes", lambda m: None, 10)

    bag = tmp_path / "bag"
    declare = recorder_module.declare_parameters
    monkeypatch.setattr(recorder_module, "declare_parameters", lambda n, specs: {
        **declare(n, specs), "output": str(bag), "discovery_period": 0.05, "flush_period": 0.1, "fsync": False})
    init = rclpy.node.Node.__init__
    monkeypatch.setattr(rclpy.node.Node, "__init__", lambda self, *a, **k: init(self, *a, **{"context": context, **k}))
    recorder = recorder_module.RecorderNode(None)
    monkeypatch.setattr(rclpy.node.Node, "__init__", init)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(pub_node)
    executor.add_node(recorder)
    try:
        wanted = {"/dlo/camera/camera_info", "/dlo/gripper/state", "/dlo/best_effort"}
        assert spin_until(executor, lambda: wanted <= set(recorder._recorded)), recorder._recorded
        assert spin_until(executor, lambda: recorder.recorder.received["/dlo/camera/camera_info"] == 1)
        matched = lambda: states.get_subscription_count() >= 1 and best_effort.get_subscription_count() >= 1  # noqa: E731
        assert spin_until(executor, matched)
        before = time.time_ns()
        for i in range(N):
            states.publish(old_state(i))
            best_effort.publish(old_state(100 + i))
            clock.publish(Clock())
            outside.publish(old_state(i))
        received = recorder.recorder.received
        assert spin_until(executor, lambda: received["/dlo/gripper/state"] == N and received["/dlo/best_effort"] == N)
        after = time.time_ns()
        for _ in range(5):
            executor.spin_once(timeout_sec=0.05)
    finally:
        summary = recorder.finish()
        executor.shutdown()
        recorder.destroy_node()
        pub_node.destroy_node()
    assert summary.dropped == 0
    assert set(recorder._recorded) == wanted  # not /clock, not /dlox/..., not a topic without a publisher
    info = bag_info(bag)
    assert set(info.topics) == wanted
    assert [q.durability for q in info.topics["/dlo/camera/camera_info"].qos] == [QosDurability.TRANSIENT_LOCAL]
    assert [q.reliability for q in info.topics["/dlo/best_effort"].qos] == [QosReliability.BEST_EFFORT]
    assert [q.reliability for q in info.topics["/dlo/gripper/state"].qos] == [QosReliability.RELIABLE]
    messages = list(read_messages(bag))
    by_topic = {t: [m for m in messages if m.topic == t] for t in wanted}
    assert len(by_topic["/dlo/camera/camera_info"]) == 1
    assert by_topic["/dlo/camera/camera_info"][0].msg.header.frame_id == "top_camera_optical"
    assert [m.msg.step for m in by_topic["/dlo/gripper/state"]] == list(range(N))
    assert [m.msg.step for m in by_topic["/dlo/best_effort"]] == [100 + i for i in range(N)]
    for m in by_topic["/dlo/gripper/state"] + by_topic["/dlo/best_effort"]:
        assert before <= m.timestamp <= after, (m.topic, m.timestamp, before, after)  # received now, not stamped 1 s
    latched_at = by_topic["/dlo/camera/camera_info"][0].timestamp
    assert latched_at <= before and latched_at > before - 600 * 10**9  # when the recorder got it


def test_clock_is_recorded_when_asked(context, tmp_path, monkeypatch):
    pub_node = rclpy.create_node("recorder_unit_clock", context=context)
    clock = pub_node.create_publisher(Clock, "/clock", 10)
    bag = tmp_path / "bag"
    declare = recorder_module.declare_parameters
    monkeypatch.setattr(recorder_module, "declare_parameters", lambda n, specs: {
        **declare(n, specs), "output": str(bag), "discovery_period": 0.05, "record_clock": True,
        "extra_topics": ["/extra/topic"], "fsync": False})
    extra = pub_node.create_publisher(GripperState, "/extra/topic", 10)
    init = rclpy.node.Node.__init__
    monkeypatch.setattr(rclpy.node.Node, "__init__", lambda self, *a, **k: init(self, *a, **{"context": context, **k}))
    recorder = recorder_module.RecorderNode(None)
    monkeypatch.setattr(rclpy.node.Node, "__init__", init)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(pub_node)
    executor.add_node(recorder)
    try:
        assert spin_until(executor, lambda: {"/clock", "/extra/topic"} <= set(recorder._recorded)), recorder._recorded
        assert spin_until(executor, lambda: clock.get_subscription_count() >= 1 and extra.get_subscription_count() >= 1)
        clock.publish(Clock())
        extra.publish(old_state(1))
        assert spin_until(executor, lambda: recorder.recorder.received["/clock"] == 1
                          and recorder.recorder.received["/extra/topic"] == 1)
    finally:
        recorder.finish()
        executor.shutdown()
        recorder.destroy_node()
        pub_node.destroy_node()
    assert set(bag_info(bag).topics) == {"/clock", "/extra/topic"}
