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
import time

import pytest

rclpy = pytest.importorskip("rclpy")
from dlo_bag import recorder_node as recorder_module  # noqa: E402
from dlo_bag.info import bag_info  # noqa: E402
from dlo_bag.reader import read_messages  # noqa: E402
from dlo_msgs.msg import GripperState  # noqa: E402
from harness import LogLines, reserved_domain  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from rosbags.interfaces import QosDurability, QosReliability  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from sensor_msgs.msg import CameraInfo  # noqa: E402

N = 5


@pytest.fixture(scope="module")
def context():
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    context = rclpy.Context()
    with reserved_domain() as domain:  # harness: no other test or graph on this machine uses it meanwhile
        rclpy.init(context=context, domain_id=domain)
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
    latched = pub_node.create_publisher(
        CameraInfo, "/dlo/camera/camera_info", QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    )
    info = CameraInfo(width=32, height=32)
    info.header.frame_id = "top_camera_optical"
    latched.publish(info)  # before the recorder exists
    states = pub_node.create_publisher(GripperState, "/dlo/gripper/state", 10)
    best_effort = pub_node.create_publisher(
        GripperState, "/dlo/best_effort", QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)
    )
    clock = pub_node.create_publisher(Clock, "/clock", 10)
    outside = pub_node.create_publisher(GripperState, "/dlox/state", 10)
    pub_node.create_subscription(GripperState, "/dlo/nobody_publishes", lambda m: None, 10)

    bag = tmp_path / "bag"
    declare = recorder_module.declare_parameters
    monkeypatch.setattr(
        recorder_module,
        "declare_parameters",
        lambda n, specs: {**declare(n, specs), "output": str(bag), "discovery_period": 0.05, "flush_period": 0.1, "fsync": False},
    )
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
    monkeypatch.setattr(
        recorder_module,
        "declare_parameters",
        lambda n, specs: {
            **declare(n, specs),
            "output": str(bag),
            "discovery_period": 0.05,
            "record_clock": True,
            "extra_topics": ["/extra/topic"],
            "fsync": False,
        },
    )
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
        assert spin_until(
            executor, lambda: recorder.recorder.received["/clock"] == 1 and recorder.recorder.received["/extra/topic"] == 1
        )
    finally:
        recorder.finish()
        executor.shutdown()
        recorder.destroy_node()
        pub_node.destroy_node()
    assert set(bag_info(bag).topics) == {"/clock", "/extra/topic"}


# ------------------------------------------------------------------ discovery and errors, one pass at a time
# (the graph the node sees is given: its get_topic_names_and_types / get_publishers_info_by_topic replaced)


class PublisherInfo:
    """What get_publishers_info_by_topic tells about one publisher (the fields discover() reads)."""

    def __init__(self, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE, type_hash=""):
        self.qos_profile = QoSProfile(depth=10, reliability=reliability, durability=durability)
        self.topic_type_hash = type_hash


class FakeStop:
    def __init__(self):
        self.requests = 0

    def request(self):
        self.requests += 1


@pytest.fixture
def offline_recorder(context, tmp_path, monkeypatch):
    """A RecorderNode (no timers firing: nothing spins it) whose graph, subscriptions and log are the test's."""
    declare = recorder_module.declare_parameters
    monkeypatch.setattr(
        recorder_module,
        "declare_parameters",
        lambda n, specs: {**declare(n, specs), "output": str(tmp_path / "bag"), "fsync": False},
    )
    init = rclpy.node.Node.__init__
    monkeypatch.setattr(rclpy.node.Node, "__init__", lambda self, *a, **k: init(self, *a, **{"context": context, **k}))
    stop = FakeStop()
    node = recorder_module.RecorderNode(stop)
    monkeypatch.setattr(rclpy.node.Node, "__init__", init)
    node.graph, node.publishers_of, node.subscribed = [], {}, []
    node.get_topic_names_and_types = lambda: node.graph
    node.get_publishers_info_by_topic = lambda topic: node.publishers_of.get(topic, [])
    real_subscribe = node.create_subscription

    def create_subscription(msg_class, topic, callback, qos, **kwargs):
        node.subscribed.append((topic, qos, kwargs))
        return real_subscribe(msg_class, topic, callback, qos, **kwargs)

    node.create_subscription = create_subscription
    log = LogLines()
    node.get_logger = lambda: log
    node.log, node.stop_request = log, stop
    yield node
    node.finish()
    node.destroy_node()


def test_discovery_warns_about_several_types_a_new_best_effort_publisher_and_a_foreign_type_hash(offline_recorder):
    node, log = offline_recorder, offline_recorder.log
    node.graph = [
        ("/dlo/gripper/state", ["dlo_msgs/msg/GripperState"]),
        ("/dlo/two_types", ["dlo_msgs/msg/GripperState", "sensor_msgs/msg/CameraInfo"]),
    ]
    node.publishers_of = {
        "/dlo/gripper/state": [PublisherInfo(type_hash="not a RIHS01 hash")],
        "/dlo/two_types": [PublisherInfo()],
    }
    node.discover()
    assert [t for t, _, _ in node.subscribed] == ["/dlo/gripper/state", "/dlo/two_types"]
    assert node.recorder.topics["/dlo/two_types"].msgtype == "dlo_msgs/msg/GripperState"  # the first type
    assert log.of("warning") == [
        "/dlo/two_types: several types ['dlo_msgs/msg/GripperState', "
        "'sensor_msgs/msg/CameraInfo']; recording dlo_msgs/msg/GripperState only"
    ]
    _, qos, kwargs = node.subscribed[0]
    assert (qos.depth, qos.reliability, qos.durability) == (1000, ReliabilityPolicy.RELIABLE, DurabilityPolicy.VOLATILE)
    events = kwargs["event_callbacks"]  # a message lost or an incompatible publisher is reported, per topic
    assert events.message_lost is not None and events.incompatible_qos is not None

    class Incompatible:
        last_policy_kind = "RELIABILITY"

    events.incompatible_qos(Incompatible())
    assert log.of("warning")[-1] == (
        "/dlo/gripper/state: a publisher's QoS is incompatible with the recorder's "
        "subscription (policy RELIABILITY); not recorded"
    )

    # a best-effort publisher joins a topic subscribed reliably: warned once, not subscribed again
    del log.lines[:]
    node.publishers_of["/dlo/gripper/state"].append(PublisherInfo(reliability=ReliabilityPolicy.BEST_EFFORT))
    node.discover()
    node.discover()
    assert len(node.subscribed) == 2
    assert log.of("warning") == [
        "/dlo/gripper/state: a publisher now offers best-effort QoS; the reliable subscription cannot receive from it"
    ]

    # a publisher whose RIHS01 type hash differs from the installed definition's; the same hash says nothing
    rihs01 = node.recorder.topics["/dlo/gripper/state"].rihs01
    assert rihs01.startswith("RIHS01_")
    del log.lines[:]
    node.graph = [("/dlo/same_hash", ["dlo_msgs/msg/GripperState"]), ("/dlo/other_hash", ["dlo_msgs/msg/GripperState"])]
    node.publishers_of = {
        "/dlo/same_hash": [PublisherInfo(type_hash=rihs01)],
        "/dlo/other_hash": [PublisherInfo(type_hash="RIHS01_" + "0" * 64)],
    }
    node.discover()
    assert log.of("warning") == [
        f"/dlo/other_hash: publisher type hash RIHS01_{'0' * 64} differs from the installed definition's {rihs01}"
    ]
    assert [t for t, _, _ in node.subscribed][2:] == ["/dlo/same_hash", "/dlo/other_hash"]


def test_a_topic_that_cannot_be_recorded_is_reported_once_and_left_alone(offline_recorder):
    node, log = offline_recorder, offline_recorder.log
    node.graph = [("/dlo/unknown", ["no_such_pkg/msg/Nothing"]), ("/dlo/gripper/state", ["dlo_msgs/msg/GripperState"])]
    node.publishers_of = {"/dlo/unknown": [PublisherInfo()], "/dlo/gripper/state": [PublisherInfo()]}
    for _ in range(3):
        node.discover()
    errors = log.of("error")
    assert len(errors) == 1 and errors[0].startswith("/dlo/unknown: not recorded: "), log.lines
    assert [t for t, _, _ in node.subscribed] == ["/dlo/gripper/state"]  # the other topic is recorded
    assert "/dlo/unknown" not in node.recorder.topics


def test_write_errors_are_logged_once_a_second_and_a_failed_recording_stops_the_node(offline_recorder, monkeypatch):
    from dlo_bag.writer import BagWriteError
    from rclpy.serialization import serialize_message

    node, log = offline_recorder, offline_recorder.log
    node.graph = [("/dlo/gripper/state", ["dlo_msgs/msg/GripperState"])]
    node.publishers_of = {"/dlo/gripper/state": [PublisherInfo()]}
    node.discover()
    data = serialize_message(old_state(1))
    now = [100.0]

    class Clock:
        @staticmethod
        def monotonic():
            return now[0]

    monkeypatch.setattr(recorder_module, "time", Clock)
    node._on_message("/dlo/gripper/state", data)  # written: nothing logged
    assert log.of("error") == [] and node.recorder.received["/dlo/gripper/state"] == 1

    def bad_write(topic, data, timestamp):
        raise ValueError("bad message")

    monkeypatch.setattr(node.recorder.writer, "write", bad_write)
    logged = []
    for t in (100.0, 100.5, 101.0, 101.01, 101.5, 102.02):
        now[0] = t
        before = len(log.of("error"))
        node._on_message("/dlo/gripper/state", data)
        if len(log.of("error")) > before:
            logged.append(t)
    assert logged == [100.0, 101.01, 102.02]  # at most one line a second (more than 1 s apart)
    assert log.of("error")[0] == "write failed (1 so far): /dlo/gripper/state: ValueError: bad message"
    assert node.stop_request.requests == 0 and not node.recorder.failure

    def full_disk(topic, data, timestamp):
        raise BagWriteError("cannot write", cause="no space left on device")

    monkeypatch.setattr(node.recorder.writer, "write", full_disk)
    now[0] = 200.0
    del log.lines[:]
    node._on_message("/dlo/gripper/state", data)
    node._on_message("/dlo/gripper/state", data)
    assert node.stop_request.requests == 1  # the failure stops the node (once)
    assert len(log.of("error")) == 1 and log.of("error")[0].startswith(
        "recording failed: no space left on device (cannot write); stopping"
    ), log.lines
