"""playback_node republishes a bag into a live graph; Pacer keeps relative timing."""

from __future__ import annotations

import json
import signal
import sys
from pathlib import Path

import pytest
from rclpy.serialization import serialize_message

sys.path.insert(0, str(Path(__file__).resolve().parent))  # --import-mode=importlib

from dlo_bag.playback import Pacer, import_message_class  # noqa: E402
from dlo_bag.reader import read_messages  # noqa: E402
from dlo_bag.writer import BagWriter  # noqa: E402
from dlo_bag_graph_helper import TOPICS, TYPE_NAMES, make_message  # noqa: E402
from dlo_bag_testutil import helper_cmd  # noqa: E402
from harness import ROS2RUN  # noqa: E402

N = 8
PLAYED = ["/dlo/gripper/state", "/dlo/task/state", "/dlo/rope/particles", "/dlo/camera/image"]


def write_bag(path: Path) -> dict[str, list[bytes]]:
    """A bag of N messages per topic, 5 ms apart; returns the raw CDR of each per topic."""
    sent: dict[str, list[bytes]] = {t: [] for t in TOPICS}
    with BagWriter(path) as writer:
        for topic in TOPICS:
            writer.add_topic(topic, TYPE_NAMES[topic])
        stamp = 1_000_000_000
        for i in range(N):
            for topic in TOPICS:
                data = serialize_message(make_message(topic, i))
                writer.write(topic, data, stamp)
                sent[topic].append(bytes(data))
                stamp += 5_000_000
    return sent


def test_playback_republishes_the_same_messages(procs, tmp_path):
    bag = tmp_path / "run.bag"  # a '.bag' directory name is a rosbag2 bag too (not ROS 1)
    sent = write_bag(bag)
    assert [m.topic for m in read_messages(bag)][: len(TOPICS)] == list(TOPICS)
    sub = procs("sub", helper_cmd("sub", "--topics", *PLAYED, "--expect", str(N), "--timeout", "60"))
    sub.wait_line("SUBSCRIBED")
    play = procs(
        "playback",
        [
            str(ROS2RUN),
            "dlo_bag",
            "playback_node",
            "--ros-args",
            "-p",
            f"bag:={bag}",
            "-p",
            "rate:=4.0",
            "-p",
            f"topics:={json.dumps(PLAYED)}",
            "-p",
            "wait_for_subscribers:=1",
            "-p",
            "wait_timeout:=60.0",
        ],
    )
    received = json.loads(sub.wait_line("RECEIVED ", timeout=90).split(" ", 1)[1])
    assert play.wait(timeout=60) == 0, play.output()
    assert f"published {N * len(PLAYED)} messages" in play.output()
    for topic in PLAYED:  # same messages, same order
        got = [bytes.fromhex(h) for h in received[topic]]
        assert len(got) == N, topic
        for want, have in zip(sent[topic], got):
            assert same_cdr(want, have), topic


def test_it_plays_at_once_without_wait_for_subscribers_else_once_every_topic_has_them_or_after_wait_timeout(procs, tmp_path):
    bag = tmp_path / "bag"
    write_bag(bag)
    play = procs(
        "playback",
        [str(ROS2RUN), "dlo_bag", "playback_node", "--ros-args", "-p", f"bag:={bag}", "-p", "rate:=0.0", "-p", "linger:=60.0"],
    )
    assert play.wait(timeout=60) == 0, play.output()
    assert f"published {N * len(TOPICS)} messages" in play.output()  # with nobody to acknowledge, no waiting
    assert "subscriber(s)" not in play.output() and "waiting up to" not in play.output(), play.output()
    sub = procs("sub", helper_cmd("sub", "--topics", PLAYED[0], "--expect", str(N), "--timeout", "60"))
    sub.wait_line("SUBSCRIBED")  # a subscriber of one topic of the four
    play = procs(
        "playback",
        [
            str(ROS2RUN),
            "dlo_bag",
            "playback_node",
            "--ros-args",
            "-p",
            f"bag:={bag}",
            "-p",
            "rate:=0.0",
            "-p",
            f"topics:={json.dumps(PLAYED)}",
            "-p",
            "linger:=60.0",
            "-p",
            "wait_for_subscribers:=1",
            "-p",
            "wait_timeout:=3.0",
        ],
    )
    assert play.wait(timeout=60) == 0, play.output()
    assert "not every topic has 1 subscriber(s) after 3 s; playing anyway" in play.output()
    assert f"published {N * len(PLAYED)} messages" in play.output()
    assert len(json.loads(sub.wait_line("RECEIVED ", timeout=60).split(" ", 1)[1])[PLAYED[0]]) == N


def test_a_paused_subscriber_gets_every_message_within_linger(procs, tmp_path):
    """A subscriber starved of CPU (here stopped with SIGSTOP from the start of the playing to its end): the
    playback waits up to `linger` s for it to acknowledge every message; one that resumes within it receives them
    all, and no warning is given."""
    bag = tmp_path / "bag"
    sent = write_bag(bag)
    sub = procs("sub", helper_cmd("sub", "--topics", *PLAYED, "--expect", str(N), "--timeout", "60"))
    sub.wait_line("SUBSCRIBED")
    play = start_slow_playback(procs, bag, PLAYED, linger=30.0)
    try:
        play.wait_line("subscriber(s): playing", timeout=90)  # matched: the subscriber has its publishers
        sub.signal(signal.SIGSTOP)
        play.wait_line("played; waiting up to", timeout=60)  # every message sent, not all acknowledged
    finally:
        sub.signal(signal.SIGCONT)
    received = json.loads(sub.wait_line("RECEIVED ", timeout=90).split(" ", 1)[1])
    assert play.wait(timeout=60) == 0, play.output()
    assert f"published {N * len(PLAYED)} messages" in play.output()
    assert "acknowledged the last messages" not in play.output()
    for topic in PLAYED:  # every message, in order
        got = [bytes.fromhex(h) for h in received[topic]]
        assert len(got) == N and all(same_cdr(want, have) for want, have in zip(sent[topic], got)), topic


def test_the_warning_names_the_topics_whose_subscriber_did_not_acknowledge_within_linger(procs, tmp_path):
    """Two subscribers stopped while the bag plays: the playback waits for the subscribers of all four topics;
    the one resumed within `linger` receives everything and its topics are not named; the other one's topics
    are, in a warning (what it has not received is lost once the playback exits)."""
    bag = tmp_path / "bag"
    write_bag(bag)
    late, resumed = PLAYED[:2], PLAYED[2:]
    stuck = procs("stuck", helper_cmd("sub", "--topics", *late, "--expect", str(N), "--timeout", "120"))
    back = procs("back", helper_cmd("sub", "--topics", *resumed, "--expect", str(N), "--timeout", "120"))
    stuck.wait_line("SUBSCRIBED")
    back.wait_line("SUBSCRIBED")
    # linger 6 s: the stuck subscriber stays stopped for ~12 s, less than the 20 s after which Fast DDS drops a
    # participant it has not heard from (then nothing is left to acknowledge and nothing to warn about)
    play = start_slow_playback(procs, bag, PLAYED, linger=6.0)
    try:
        play.wait_line("subscriber(s): playing", timeout=90)
        stuck.signal(signal.SIGSTOP)
        back.signal(signal.SIGSTOP)
        waiting = play.wait_line("played; waiting up to", timeout=60)
        assert all(topic in waiting for topic in PLAYED), waiting
        back.signal(signal.SIGCONT)
        assert len(json.loads(back.wait_line("RECEIVED ", timeout=60).split(" ", 1)[1])[resumed[0]]) == N
        warning = play.wait_line("acknowledged the last messages", timeout=60)
        assert play.wait(timeout=60) == 0, play.output()
    finally:
        stuck.signal(signal.SIGCONT)
        back.signal(signal.SIGCONT)
    named = warning.split("not every subscriber of ", 1)[1].split(" acknowledged", 1)[0]
    assert named == ", ".join(late), warning
    assert "raise -p linger" in warning


def start_slow_playback(procs, bag: Path, topics: list[str], linger: float):
    """The playback of ``bag`` once every topic has a subscriber, at rate 0.05: the playing takes 5.6 s, so most
    messages are sent after a test stops its subscribers even on a loaded machine."""
    return procs(
        "playback",
        [
            str(ROS2RUN),
            "dlo_bag",
            "playback_node",
            "--ros-args",
            "-p",
            f"bag:={bag}",
            "-p",
            "rate:=0.05",
            "-p",
            f"topics:={json.dumps(topics)}",
            "-p",
            f"linger:={linger}",
            "-p",
            "wait_for_subscribers:=1",
            "-p",
            "wait_timeout:=60.0",
        ],
    )


def same_cdr(sent: bytes, received: bytes) -> bool:
    """Equal CDR payloads; DDS may pad the end to 4 bytes (noted in the header's options)."""
    return received[:2] == sent[:2] and received[4 : len(sent)] == sent[4:] and 0 <= len(received) - len(sent) < 4


def test_playback_bad_parameters(procs, tmp_path):
    play = procs("playback", [str(ROS2RUN), "dlo_bag", "playback_node", "--ros-args", "-p", f"bag:={tmp_path / 'missing'}"])
    assert play.wait(timeout=60) == 2
    assert "does not exist" in play.output() and "Traceback" not in play.output()
    bag = tmp_path / "bag"
    write_bag(bag)
    killed = tmp_path / "killed"  # a recorder killed before closing: .mcap, no metadata.yaml
    killed.mkdir()
    (killed / "killed.mcap").write_bytes((bag / "bag.mcap").read_bytes()[:-200])
    play = procs("playback", [str(ROS2RUN), "dlo_bag", "playback_node", "--ros-args", "-p", f"bag:={killed}"])
    assert play.wait(timeout=60) == 2
    lines = [line for line in play.output().splitlines() if line.strip()]
    assert len(lines) == 1 and f"dlo-bag-recover {killed}" in lines[0], play.output()
    for param, text in [
        ("rate:=-1.0", "parameter 'rate'"),
        ("rate:=fast", "parameter 'rate': expected a number"),
        ("topics:=['/dlo/nope']", "parameter 'topics'"),
        ("linger:=-1.0", "parameter 'linger': must be >= 0, got -1.0"),
    ]:
        play = procs("playback", [str(ROS2RUN), "dlo_bag", "playback_node", "--ros-args", "-p", f"bag:={bag}", "-p", param])
        assert play.wait(timeout=60) == 2, play.output()
        assert text in play.output() and "Traceback" not in play.output()


def test_pacer_keeps_relative_timing():
    pacer = Pacer(2.0)
    pacer.start(10_000_000_000, 100.0)
    assert pacer.deadline(10_000_000_000) == pytest.approx(100.0)
    assert pacer.deadline(11_000_000_000) == pytest.approx(100.5)
    assert pacer.deadline(14_000_000_000) == pytest.approx(102.0)
    one = Pacer(1.0)
    one.start(0, 5.0)
    assert one.deadline(250_000_000) == pytest.approx(5.25)
    fast = Pacer(0.0)
    fast.start(0, 5.0)
    assert fast.deadline(10**12) == 5.0
    with pytest.raises(ValueError):
        Pacer(-1.0)


def test_import_message_class():
    from dlo_msgs.msg import TaskState
    from sensor_msgs.msg import Image

    assert import_message_class("sensor_msgs/msg/Image") is Image
    assert import_message_class("dlo_msgs/msg/TaskState") is TaskState
    with pytest.raises(ValueError):
        import_message_class("no_such_pkg/msg/X")
    with pytest.raises(ValueError):
        import_message_class("sensor_msgs/msg/NoSuch")
