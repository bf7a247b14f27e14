"""The bag library (dlo_bag.typestore, qos, writer, reader, info) and recording: types, hashes, QoS, writing, rolling and
reading."""

from __future__ import annotations

import json
import os

import pytest
from dlo_bag.errors import BagError
from dlo_bag.info import bag_info, format_info
from dlo_bag.qos import qos_from_profile, subscription_qos
from dlo_bag.reader import bag_parts, read_messages
from dlo_bag.recording import Recorder, topic_selected
from dlo_bag.typestore import ament_prefixes, make_typestore
from dlo_bag.writer import BagWriter
from dlo_msgs.msg import GripperState, TaskState
from mcap.reader import make_reader
from rclpy.duration import Infinite
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from rosbags.interfaces import QosDurability, QosReliability


def installed_msgs(package):
    for prefix in ament_prefixes():
        msgdir = prefix / "share" / package / "msg"
        if msgdir.is_dir():
            return sorted(msgdir.glob("*.msg"))
    return []


def test_dlo_msgs_hashes_match_rosidl():
    """The typestore's RIHS01 of every dlo_msgs type equals rosidl's (share/.../X.json)."""
    typestore = make_typestore()
    msgs = installed_msgs("dlo_msgs")
    assert len(msgs) >= 5
    for path in msgs:
        name = f"dlo_msgs/msg/{path.stem}"
        hashes = json.loads(path.with_suffix(".json").read_text())["type_hashes"]
        want = next(h["hash_string"] for h in hashes if h["type_name"] == name)
        assert typestore.hash_rihs01(name) == want, name


def test_qos_from_rclpy_profile():
    profile = QoSProfile(depth=7, reliability=ReliabilityPolicy.BEST_EFFORT, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    qos = qos_from_profile(profile)
    assert qos.depth == 7
    assert qos.reliability == QosReliability.BEST_EFFORT
    assert qos.durability == QosDurability.TRANSIENT_LOCAL
    inf = qos_from_profile(QoSProfile(depth=1, deadline=Infinite))
    assert (inf.deadline.sec, inf.deadline.nsec) == (9223372036, 854775807)


def test_subscription_qos_matches_every_publisher():
    rel = qos_from_profile(
        QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    )
    be = qos_from_profile(QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT))
    assert subscription_qos([rel]) == (QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL)
    assert subscription_qos([rel, be]) == (QosReliability.BEST_EFFORT, QosDurability.VOLATILE)


def test_topic_selection():
    assert topic_selected("/dlo/gripper/state")
    assert topic_selected("/dlo")
    assert not topic_selected("/dlox/a")
    assert not topic_selected("/clock")
    assert topic_selected("/clock", clock=True)
    assert topic_selected("/tf", extra=["/tf"])
    assert topic_selected("/anything", namespace="/")


def state(i):
    msg = GripperState()
    msg.x, msg.step = 0.01 * i, i
    msg.header.frame_id = str(i)
    return serialize_message(msg)


def test_writer_roundtrip_and_info(tmp_path):
    bag = tmp_path / "bag"
    with BagWriter(bag) as writer:
        writer.add_topic("/dlo/gripper/state", "dlo_msgs/msg/GripperState")
        writer.add_topic("/dlo/rope/particles", "sensor_msgs/msg/PointCloud2")
        for i in range(5):
            writer.write("/dlo/gripper/state", state(i), 1_000 + i)
    assert (bag / "metadata.yaml").is_file()
    msgs = list(read_messages(bag))
    assert [m.msg.step for m in msgs] == list(range(5))
    assert [m.timestamp for m in msgs] == [1_000 + i for i in range(5)]
    info = bag_info(bag)
    assert info.message_count == 5 and info.duration_ns == 4
    assert info.topics["/dlo/rope/particles"].count == 0
    text = format_info(info, verbose=True)
    assert "dlo_msgs/msg/GripperState | Count: 5" in text and "RIHS01_" in text
    with pytest.raises(BagError, match="exists already"):
        BagWriter(bag)


def synced_files(monkeypatch) -> list[str]:
    """The paths os.fsync is called on from now on (the call still happens)."""
    synced, real = [], os.fsync

    def spy(fd):
        synced.append(os.readlink(f"/proc/self/fd/{fd}"))
        return real(fd)

    monkeypatch.setattr(os, "fsync", spy)
    return synced


def test_a_flush_syncs_the_mcap_file_unless_fsync_is_off(tmp_path, monkeypatch):
    """BagWriter.flush: 'put every message written so far on disk (a complete chunk; fsync if enabled)'."""
    synced = synced_files(monkeypatch)
    for fsync in (True, False):
        bag = tmp_path / f"run_{fsync}"
        with BagWriter(bag, fsync=fsync) as writer:
            writer.add_topic("/dlo/gripper/state", "dlo_msgs/msg/GripperState")
            writer.write("/dlo/gripper/state", state(1), 1)
            synced.clear()
            writer.flush()
            mcaps = [path for path in synced if path.endswith(".mcap")]
            assert mcaps == ([os.path.realpath(bag / f"{bag.name}.mcap")] if fsync else []), synced


def test_a_bag_of_many_chunks_starts_at_its_first_message(tmp_path):
    """metadata.yaml, dlo-bag-info and the MCAP statistics: the time range of all chunks, not of the last."""
    bag = tmp_path / "run"
    with BagWriter(bag, chunk_size=2000) as writer:
        writer.add_topic("/dlo/gripper/state", "dlo_msgs/msg/GripperState")
        for i in range(1, 51):
            writer.write("/dlo/gripper/state", state(i), i)
    info = bag_info(bag)
    assert (info.start_ns, info.end_ns, info.message_count) == (1, 50, 50)
    with (bag / "run.mcap").open("rb") as f:
        summary = make_reader(f).get_summary()
    assert len(summary.chunk_indexes) > 2  # the case: several chunks
    assert (summary.statistics.message_start_time, summary.statistics.message_end_time) == (1, 50)


def test_writer_errors(tmp_path):
    writer = BagWriter(tmp_path / "bag")
    with pytest.raises(BagError, match="unknown message type"):
        writer.add_topic("/dlo/x", "nopkg/msg/Nothing")
    with pytest.raises(BagError, match="add_topic first"):
        writer.write("/dlo/y", b"", 0)
    writer.close()
    writer.close()  # idempotent
    assert bag_info(tmp_path / "bag").message_count == 0


def test_recorder_rolls_every_n_episodes(tmp_path):
    rec = Recorder(tmp_path / "run", split_episodes=2)
    rec.add_topic("/dlo/task/state", "dlo_msgs/msg/TaskState")
    rec.add_topic("/dlo/gripper/state", "dlo_msgs/msg/GripperState")
    t = 0
    for episode in range(5):
        for step in range(3):
            task = TaskState()
            task.episode, task.step = episode, step
            assert rec.on_message("/dlo/task/state", serialize_message(task), t) is None
            assert rec.on_message("/dlo/gripper/state", state(t), t + 1) is None
            t += 2
    summary = rec.close()
    assert summary.dropped == 0 and summary.total_written == 30
    parts = bag_parts(tmp_path / "run")
    assert [p.name for p in parts] == ["run_0000", "run_0001", "run_0002"]
    eps = [sorted({m.msg.episode for m in read_messages(p, ["/dlo/task/state"])}) for p in parts]
    assert eps == [[0, 1], [2, 3], [4]]
    assert [m.msg.step for m in read_messages(tmp_path / "run", ["/dlo/gripper/state"])] == list(range(0, 30, 2))
    assert rec.close() is summary


def test_recorder_counts_write_errors(tmp_path):
    rec = Recorder(tmp_path / "run")
    err = rec.on_message("/dlo/never/added", b"\x00", 1)
    assert err and "add_topic first" in err
    summary = rec.close()
    assert summary.dropped == 1 and summary.errors == 1


def test_incomplete_bag_is_reported(tmp_path):
    (tmp_path / "killed").mkdir()
    (tmp_path / "killed" / "killed.mcap").write_bytes(b"\x89MCAP0\r\n")
    with pytest.raises(BagError, match="needs recovering.*run: dlo-bag-recover .*killed$"):
        bag_parts(tmp_path / "killed")
    with pytest.raises(BagError, match="does not exist"):
        bag_parts(tmp_path / "nothing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(BagError, match="not a rosbag2 bag"):
        bag_parts(tmp_path / "empty")
