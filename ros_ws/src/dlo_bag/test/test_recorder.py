"""recorder_node as a separate process against publisher processes (isolated ROS domain)."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from collections import Counter
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))  # --import-mode=importlib

from dlo_bag.info import bag_info  # noqa: E402
from dlo_bag.reader import bag_parts, read_messages  # noqa: E402
from dlo_bag_graph_helper import TOPICS, TYPE_NAMES  # noqa: E402
from dlo_bag_testutil import helper_cmd, recorder_cmd  # noqa: E402
from harness import ROS2RUN  # noqa: E402

N = 12


def seqs(bag, topic):
    """Sequence numbers (header.frame_id) of ``topic`` in bag order."""
    return [int(m.msg.header.frame_id) for m in read_messages(bag, [topic])]


def stop_recorder(rec, sig=signal.SIGINT):
    rec.signal(sig)
    rc = rec.wait(timeout=30)
    out = rec.output()
    assert rc == 0, out
    assert "dropped 0" in out, out
    assert "Traceback" not in out, out
    return out


def test_records_every_topic_exact_counts_and_hashes(procs, tmp_bags, ros_env):
    bag = tmp_bags / "run"
    summary_file = tmp_bags / "summary.json"
    rec = procs("recorder", recorder_cmd(bag, f"summary_file:={summary_file}"))
    pub = procs("pub", helper_cmd("pub", "--count", str(N), "--then", "hold"))
    hashes = json.loads(pub.wait_line("HASHES ").split(" ", 1)[1])
    published = json.loads(pub.wait_line("PUBLISHED ").split(" ", 1)[1])
    out = stop_recorder(rec, signal.SIGINT)  # publisher still alive: SIGINT mid-run
    assert f"received {N * len(TOPICS)}, written {N * len(TOPICS)}, dropped 0" in out
    summary = json.loads(summary_file.read_text())
    assert summary["dropped"] == 0 and summary["written"] == N * len(TOPICS)
    assert summary["topics"]["/dlo/camera/image"] == {"received": N, "written": N, "lost": 0}

    # metadata.yaml written, every topic with its type, exact count and rclpy's type hash
    assert (bag / "metadata.yaml").is_file()
    info = bag_info(bag)
    assert set(info.topics) == set(TOPICS)
    for topic, t in info.topics.items():
        assert t.msgtype == TYPE_NAMES[topic]
        assert t.count == published[topic] == N
        assert t.rihs01 == hashes[topic], topic
        assert t.qos and t.qos[0].reliability.name == "RELIABLE"

    # rosbags: every message deserialises; order and content as published
    for topic in TOPICS:
        assert seqs(bag, topic) == list(range(N)), topic
    states = [m.msg for m in read_messages(bag, ["/dlo/gripper/state"])]
    assert states[5].x == pytest.approx(0.005) and states[5].step == 5
    images = [m.msg for m in read_messages(bag, ["/dlo/camera/image"])]
    assert images[3].encoding == "rgb8" and len(images[3].data) == 24 * 96

    # the mcap reader (with the ROS 2 decoder): same counts, schemas are ros2msg, decodes
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    mcaps = list(bag.glob("*.mcap"))
    assert len(mcaps) == 1
    with open(mcaps[0], "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        assert {s.encoding for s in summary.schemas.values()} == {"ros2msg"}
        counts = Counter()
        for _schema, channel, _message, decoded in reader.iter_decoded_messages():
            assert channel.message_encoding == "cdr"
            counts[channel.topic] += 1
            assert int(decoded.header.frame_id) < N
    assert counts == {t: N for t in TOPICS}

    # dlo-bag-info
    res = subprocess.run(
        [str(ROS2RUN), "dlo_bag", "dlo-bag-info", str(bag)], env=ros_env, capture_output=True, text=True, timeout=60
    )
    assert res.returncode == 0, res.stderr
    assert f"Messages:          {N * len(TOPICS)}" in res.stdout
    for topic, typ in TYPE_NAMES.items():
        assert topic in res.stdout and typ in res.stdout
    assert f"Count: {N} |" in res.stdout


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP], ids=["SIGINT", "SIGTERM", "SIGHUP"])
def test_signal_mid_stream_leaves_complete_bag(procs, tmp_bags, sig):
    bag = tmp_bags / "run"
    rec = procs("recorder", recorder_cmd(bag))
    pub = procs("pub", helper_cmd("pub", "--count", str(N), "--then", "stream"))
    pub.wait_line("PUBLISHED ")
    stop_recorder(rec, sig)  # while the publisher keeps streaming gripper states
    assert (bag / "metadata.yaml").is_file()
    info = bag_info(bag)
    for topic in TOPICS:
        got = seqs(bag, topic)
        if topic == "/dlo/gripper/state":
            # everything published before the signal, without gaps, then possibly more
            assert len(got) >= N and got == list(range(len(got)))
            assert info.topics[topic].count == len(got)
        else:
            assert got == list(range(N)), topic


def test_survives_publisher_dying_and_restarting(procs, tmp_bags):
    bag = tmp_bags / "run"
    rec = procs("recorder", recorder_cmd(bag))
    first = procs("pub1", helper_cmd("pub", "--count", str(N), "--then", "exit"))
    first.wait_line("PUBLISHED ")
    assert first.wait(timeout=30) == 0
    second = procs("pub2", helper_cmd("pub", "--count", str(N), "--start", str(N), "--then", "exit"))
    second.wait_line("PUBLISHED ")
    assert second.wait(timeout=30) == 0
    stop_recorder(rec)
    for topic in TOPICS:
        assert seqs(bag, topic) == list(range(2 * N)), topic


def test_split_every_n_episodes(procs, tmp_bags):
    out = tmp_bags / "run"
    rec = procs("recorder", recorder_cmd(out, "split_episodes:=2"))
    pub = procs(
        "pub", helper_cmd("pub", "--count", "16", "--episode-every", "4", "--topics", "/dlo/task/state", "/dlo/gripper/state")
    )
    pub.wait_line("PUBLISHED ")
    pub.wait(timeout=30)
    stop_recorder(rec)
    parts = bag_parts(out)  # episodes 0-3, two per bag
    assert [p.name for p in parts] == ["run_0000", "run_0001"]
    episodes = [[m.msg.episode for m in read_messages(p, ["/dlo/task/state"])] for p in parts]
    assert episodes == [[0] * 4 + [1] * 4, [2] * 4 + [3] * 4]
    # the key every bag has had (dlo_bag.mcap_file.WRITER_NAME: the package's name before the split)
    assert [bag_info(p).custom_data[0]["dlo_tools.episodes"] for p in parts] == ["0-1", "2-3"]
    # reading the directory reads every part, in order
    assert seqs(out, "/dlo/task/state") == list(range(16))
    assert seqs(out, "/dlo/gripper/state") == list(range(16))


@pytest.mark.parametrize(
    "param, expected",
    [
        ("queue_depth:=abc", "parameter 'queue_depth': expected an integer"),
        ("split_episodes:=-1", "parameter 'split_episodes': must be >= 0"),
        ("record_clock:=3", "parameter 'record_clock': expected a bool"),
    ],
)
def test_malformed_parameter_is_a_clear_error(procs, tmp_bags, param, expected):
    bag = tmp_bags / "never"
    rec = procs("recorder", recorder_cmd(bag, param))
    rc = rec.wait(timeout=60)
    assert rc == 2
    assert expected in rec.output()
    assert "Traceback" not in rec.output()
    assert not bag.exists()


def test_existing_output_is_refused(procs, tmp_bags):
    bag = tmp_bags / "exists"
    bag.mkdir()
    rec = procs("recorder", recorder_cmd(bag))
    assert rec.wait(timeout=60) == 2
    assert "exists already" in rec.output()


LOSES_MESSAGES = """
import sys
from types import SimpleNamespace
from dlo_bag import recorder_node

discover = recorder_node.RecorderNode.discover

def discover_then_lose(self):  # the middleware reports 2 messages of a topic lost before delivery
    discover(self)
    if not self.stop.is_set():
        self._on_lost("/dlo/gripper/state", SimpleNamespace(total_count_change=2, total_count=2))
        self.stop.request()

recorder_node.RecorderNode.discover = discover_then_lose
sys.exit(recorder_node.main(sys.argv[1:]))
"""


def run_patched_recorder(procs, tmp_bags, script):
    """recorder_node run by ``script`` (``python -c``: it patches the node, then calls main) into tmp_bags/run,
    with a summary_file: -> (exit status, output, bag, summary or None when it wrote none)."""
    bag, summary_file = tmp_bags / "run", tmp_bags / "summary.json"
    rec = procs(
        "recorder", [sys.executable, "-c", script, "--ros-args", "-p", f"output:={bag}", "-p", f"summary_file:={summary_file}"]
    )
    rc = rec.wait(timeout=60)
    return rc, rec.output(), bag, json.loads(summary_file.read_text()) if summary_file.exists() else None


def test_messages_lost_before_delivery_make_exit_status_1_with_a_closed_bag(procs, tmp_bags):
    """dlo_bag README (recorder_node): dropped also counts messages the middleware reports lost; exit 1
    when messages were dropped (the bag is still closed); the launcher then exits 4."""
    rc, out, bag, summary = run_patched_recorder(procs, tmp_bags, LOSES_MESSAGES)
    assert rc == 1, out
    assert "the middleware lost 2 message(s) before delivery" in out, out
    assert "received 0, written 0, dropped 2" in out and "2 messages were not written" in out, out
    assert summary["dropped"] == 2
    assert (bag / "metadata.yaml").is_file() and "Traceback" not in out


HANGS_IN_TEARDOWN = """
import ctypes, sys
from dlo_bag import recorder_node
from dlo_common import node_main

node_main.TEARDOWN_LIMIT = 1.0
discover = recorder_node.RecorderNode.discover

def discover_then_stop(self):
    discover(self)
    self.stop.request()

recorder_node.RecorderNode.discover = discover_then_stop
recorder_node.RecorderNode.destroy_node = lambda self: ctypes.PyDLL(None).sleep(120)  # Fast DDS's deadlock: C, GIL held
sys.exit(recorder_node.main(sys.argv[1:]))
"""


def test_a_middleware_teardown_that_hangs_is_cut_after_the_bag_is_closed(procs, tmp_bags):
    """dlo_bag README (recorder_node): the bag is closed and the summary written before the middleware's teardown;
    a teardown that hangs (Fast DDS can deadlock there) ends the recorder after TEARDOWN_LIMIT s with exit 1."""
    rc, out, bag, summary = run_patched_recorder(procs, tmp_bags, HANGS_IN_TEARDOWN)
    assert rc == 1, out
    assert "Timeout (0:00:01)!" in out and "in shut_down" in out, out
    assert summary["dropped"] == 0
    assert (bag / "metadata.yaml").is_file()
    assert bag_info(bag).topics == {}  # a complete bag, readable, that recorded nothing
