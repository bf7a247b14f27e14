"""dlo_msgs: the interfaces build, round-trip through CDR and travel between processes."""

import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
from dlo_common.topics import TOPICS  # noqa: E402
from dlo_msgs.msg import GripperCommand, GripperState, TactilePose, TaskState, VisualPose  # noqa: E402
from dlo_msgs.srv import ResetEpisode  # noqa: E402
from rclpy.serialization import deserialize_message, serialize_message  # noqa: E402


def sample_messages():
    """One message of every dlo_msgs type with distinctive, non-default field values."""
    state = GripperState(x=-0.25, y=0.01, z=0.1, closure=0.7, episode=3, step=42)
    state.header.frame_id = "world"
    state.header.stamp.sec, state.header.stamp.nanosec = 12, 340_000_000
    command = GripperCommand(vx=0.25, vy=-0.1, closure=0.95, episode=3, step=42)
    tactile = TactilePose(angle=0.3, y=-0.004, contact=True, contact_count=5)
    visual = VisualPose(visible=True, confidence=0.75, angle=-0.2, y=0.006)
    task = TaskState(
        episode=3,
        seed=2**40 + 7,
        step=42,
        held_indices=[10, 11, 12],
        n_held=3,
        mean_held_index=11.0,
        num_particles=47,
        cable_length=0.1978,
        reward=0.0431,
        episode_return=1.5,
        done=True,
        outcome=TaskState.OUTCOME_HOLD_THE_END,
        held_indices_authors=[11],
        mean_held_index_authors=11.0,
        outcome_authors=TaskState.OUTCOME_STOP_BEFORE,
    )
    return [state, command, tactile, visual, task]


def registry_message_names():
    """The dlo_msgs messages the graph's topics carry (the registry, dlo_common.topics), e.g. "GripperState"."""
    return {t.type.rsplit("/", 1)[-1] for t in TOPICS if t.type.startswith("dlo_msgs/msg/")}


def test_every_message_of_the_graph_has_a_sample_here():
    """sample_messages covers every dlo_msgs type a topic of the registry carries (and only those), so the
    round-trip and cross-process tests below see each one."""
    assert {type(m).__name__ for m in sample_messages()} == registry_message_names()


def test_every_topic_and_service_type_of_the_registry_is_built():
    """Each type dlo_common.topics names resolves to its generated class (the nodes create their publishers
    and subscriptions from it)."""
    from dlo_common.topics import SERVICES, message_class

    for name, msgtype in [(t.name, t.type) for t in TOPICS] + [(s.name, s.type) for s in SERVICES]:
        assert message_class(msgtype).__name__ == msgtype.rsplit("/", 1)[-1], name


def fields_equal(a, b):
    return (
        all(
            np.all(np.asarray(getattr(a, f)) == np.asarray(getattr(b, f)))
            for f in a.get_fields_and_field_types()
            if f != "header"
        )
        and a.header == b.header
    )


@pytest.mark.parametrize("msg", sample_messages(), ids=lambda m: type(m).__name__)
def test_message_round_trips_through_cdr(msg):
    data = serialize_message(msg)
    back = deserialize_message(data, type(msg))
    assert fields_equal(msg, back)
    # Serialising again gives the same message; bytes are not compared because CDR alignment
    # padding is uninitialised memory in rmw's serializer (it differs between calls).
    again = deserialize_message(serialize_message(back), type(msg))
    assert fields_equal(msg, again)
    assert len(serialize_message(back)) == len(data)


def test_outcome_constants_match_the_task_contract():
    assert [
        TaskState.OUTCOME_NONE,
        TaskState.OUTCOME_HOLD_THE_END,
        TaskState.OUTCOME_STOP_BEFORE,
        TaskState.OUTCOME_REACH_END_BUT_DROP,
        TaskState.OUTCOME_DROP_BEFORE,
    ] == [0, 1, 2, 3, 4]


def test_every_message_has_a_header_and_documented_fields():
    import pathlib

    from ament_index_python.packages import get_package_share_directory

    share = pathlib.Path(get_package_share_directory("dlo_msgs"))
    msg_files = sorted((share / "msg").glob("*.msg"))
    assert {p.stem for p in msg_files} == registry_message_names()  # every message is a topic's (dlo_common.topics)
    for path in msg_files:
        lines = [ln.strip() for ln in path.read_text().splitlines()]
        assert "std_msgs/Header header" in lines, path.name
        fields = [ln for ln in lines if ln and not ln.startswith("#") and "=" not in ln]
        for field in fields:  # each field sits in a block of fields led by a comment
            i = lines.index(field)
            while i > 0 and lines[i - 1] in fields:
                i -= 1
            assert lines[i - 1].startswith("#"), f"{path.name}: '{field}' has no comment"


def test_reset_service_contract():
    """/dlo/sim/reset (dlo_msgs/srv/ResetEpisode): a signed seed (< 0 = the node's own sequence), and
    the new episode's counter and seed in the answer; documented, and both halves survive CDR. (The
    sim node's answers: ros_ws/src/dlo_sim/test/test_sim_node_commands.py.)"""
    import pathlib

    from ament_index_python.packages import get_package_share_directory

    assert ResetEpisode.Request.get_fields_and_field_types() == {"seed": "int64"}
    assert ResetEpisode.Response.get_fields_and_field_types() == {
        "success": "boolean",
        "message": "string",
        "episode": "uint32",
        "seed": "uint64",
    }
    assert ResetEpisode.Request().seed == 0
    for value in (-1, 2**40 + 7):  # "use your own sequence" and a seed beyond 32 bits both fit
        request = deserialize_message(serialize_message(ResetEpisode.Request(seed=value)), ResetEpisode.Request)
        assert request.seed == value
    response = ResetEpisode.Response(success=True, message="episode 4 started with seed 12", episode=4, seed=2**40 + 7)
    back = deserialize_message(serialize_message(response), ResetEpisode.Response)
    assert (back.success, back.message, back.episode, back.seed) == (True, "episode 4 started with seed 12", 4, 2**40 + 7)
    text = (pathlib.Path(get_package_share_directory("dlo_msgs")) / "srv" / "ResetEpisode.srv").read_text()
    request_text, response_text = text.split("---")
    assert "seed < 0" in request_text and "int64 seed" in request_text
    assert "uint32 episode" in response_text and "uint64 seed" in response_text


PUBLISHER = textwrap.dedent("""
    import sys, time, rclpy
    sys.path.insert(0, {test_dir!r})
    from test_msgs import sample_messages
    rclpy.init()
    node = rclpy.create_node("dlo_msgs_test_publisher")
    msgs = sample_messages()
    pubs = [node.create_publisher(type(m), "/dlo/test/" + type(m).__name__, 10) for m in msgs]
    deadline = time.time() + 60
    while time.time() < deadline:
        for pub, msg in zip(pubs, msgs):
            pub.publish(msg)
        rclpy.spin_once(node, timeout_sec=0.05)
""")


def test_every_message_type_crosses_processes(tmp_path):
    import pathlib

    test_dir = str(pathlib.Path(__file__).parent)
    publisher = subprocess.Popen([sys.executable, "-c", PUBLISHER.format(test_dir=test_dir)])
    rclpy.init()
    try:
        node = rclpy.create_node("dlo_msgs_test_subscriber")
        expected = {type(m).__name__: m for m in sample_messages()}
        received = {}
        for name, msg in expected.items():
            node.create_subscription(type(msg), "/dlo/test/" + name, lambda m, name=name: received.setdefault(name, m), 10)
        deadline = time.time() + 45
        while len(received) < len(expected) and time.time() < deadline and publisher.poll() is None:
            rclpy.spin_once(node, timeout_sec=0.1)
        assert set(received) == set(expected), f"missing: {set(expected) - set(received)}"
        for name, msg in expected.items():
            assert fields_equal(msg, received[name]), name
    finally:
        rclpy.shutdown()
        publisher.kill()
        publisher.wait()
