"""recorder_node under real faults (separate processes, isolated ROS domain): SIGKILL mid-stream,
a full disk, plus what its unit tests used to miss: receive timestamps and transient-local topics."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))  # --import-mode=importlib

from dlo_bag.info import bag_info  # noqa: E402
from dlo_bag.mcap_file import scan_mcap  # noqa: E402
from dlo_bag.reader import read_messages  # noqa: E402
from dlo_bag_faults import file_size_limit, small_disk  # noqa: E402
from dlo_bag_graph_helper import LATCHED_TOPIC, TOPICS, latched_message  # noqa: E402
from dlo_bag_testutil import helper_cmd, recorder_cmd  # noqa: E402
from harness import ROS2RUN  # noqa: E402

N = 12


def seqs(bag, topic):
    return [int(m.msg.header.frame_id) for m in read_messages(bag, [topic])]


def on_disk(mcap: Path) -> Counter:
    """Messages per topic in the (growing, unfinished) .mcap as another process sees it now."""
    if not mcap.exists():
        return Counter()
    scan, messages = scan_mcap(mcap)
    counts: Counter = Counter()
    for m in messages:
        counts[scan.channels[m.channel_id].topic] += 1
    return counts


def tool(ros_env, exe, *args) -> subprocess.CompletedProcess:
    return subprocess.run(
        [str(ROS2RUN), "dlo_bag", exe, *map(str, args)], env=ros_env, capture_output=True, text=True, timeout=120
    )


def test_sigkill_loses_nothing_that_reached_the_recorder_before_the_last_flush(procs, tmp_bags, ros_env):
    bag = tmp_bags / "run"
    rec = procs("recorder", recorder_cmd(bag, "flush_period:=0.2"))
    pub = procs("pub", helper_cmd("pub", "--count", str(N), "--then", "stream"))
    pub.wait_line("PUBLISHED ")  # N of each topic acknowledged by the recorder; states keep coming
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:  # the recorder puts them on disk while it runs
        counts = on_disk(bag / "run.mcap")
        if all(counts[t] >= N for t in TOPICS):
            break
        time.sleep(0.1)
    assert all(counts[t] >= N for t in TOPICS), counts
    rec.p.kill()  # SIGKILL: no signal handler, no close, no metadata.yaml
    assert rec.wait(timeout=30) == -signal.SIGKILL
    pub.signal(signal.SIGINT)
    streamed = int(pub.wait_line("STREAMED ").split()[1])

    info = tool(ros_env, "dlo-bag-info", bag)
    text = (info.stdout + info.stderr).strip()
    assert info.returncode == 1 and "Traceback" not in text and len(text.splitlines()) == 1, text
    assert f"dlo-bag-recover {bag}" in text
    fixed = tool(ros_env, "dlo-bag-recover", bag)
    assert fixed.returncode == 0 and "recovered" in fixed.stdout, fixed.stdout + fixed.stderr
    for topic in TOPICS:
        got = seqs(bag, topic)
        if topic == "/dlo/gripper/state":  # everything on disk at the kill, without gaps
            assert len(got) >= N and got == list(range(len(got))) and len(got) <= streamed
        else:
            assert got == list(range(N)), topic
    assert bag_info(bag).topics["/dlo/camera/image"].count == N


def test_disk_full_stops_the_recorder_loudly_with_a_readable_bag(procs, tmp_bags, ros_env):
    summary_file = tmp_bags / "summary.json"  # on another disk than the bag
    with small_disk(tmp_bags) as disk:
        if disk is not None:
            bag = disk / "run"
            rec = procs("recorder", recorder_cmd(bag, f"summary_file:={summary_file}"))
        else:  # not root: the same write failures from a per-file size limit (EFBIG)
            bag = tmp_bags / "run"
            rec = procs("recorder", recorder_cmd(bag, f"summary_file:={summary_file}"), preexec_fn=file_size_limit(1_500_000))
        pub = procs("pub", helper_cmd("pub", "--count", "1", "--then", "stream", "--stream-topic", "/dlo/camera/image"))
        rc = rec.wait(timeout=120)  # it stops by itself once the disk is full
        pub.signal(signal.SIGINT)
        pub.wait(timeout=30)
        out = rec.output()
        cause = "no space left on device" if disk is not None else "file too large"
        assert rc == 3, out
        assert out.count("recording failed") == 1 and f"recording failed: {cause}" in out, out
        assert "Traceback" not in out
        summary = json.loads(summary_file.read_text())
        assert summary["failure"] == cause and summary["complete"]
        images = seqs(bag, "/dlo/camera/image")  # readable as is, no recovery needed
        assert images == list(range(len(images))) and len(images) > 20
        assert summary["written"] == bag_info(bag).message_count
        if disk is not None:  # every message received before the failure is in the bag
            assert summary["written"] == summary["received_at_failure"]
        info = tool(ros_env, "dlo-bag-info", bag)
        assert info.returncode == 0, info.stderr


def test_receive_timestamps_and_a_transient_local_topic(procs, tmp_bags):
    """Bag timestamps are the recorder's receive times (not the header stamps); a latched topic
    published before the recorder started is recorded, with its transient-local QoS."""
    bag = tmp_bags / "run"
    pub = procs("pub", helper_cmd("pub", "--count", str(N), "--latched", "--then", "hold", "--timeout", "90"))
    pub.wait_line("LATCHED")
    t0 = time.time_ns()
    rec = procs("recorder", recorder_cmd(bag))
    pub.wait_line("PUBLISHED ", timeout=90)
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline and on_disk(bag / "run.mcap")[LATCHED_TOPIC] < 1:
        time.sleep(0.1)
    rec.signal(signal.SIGINT)
    assert rec.wait(timeout=30) == 0, rec.output()
    t1 = time.time_ns()
    stamps: dict[str, list[int]] = {}
    for m in read_messages(bag, raw=True):
        stamps.setdefault(m.topic, []).append(m.timestamp)
    for topic, times in stamps.items():
        assert all(t0 <= t <= t1 for t in times), topic
        assert times == sorted(times), topic
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import CameraInfo

    latched = [m for m in read_messages(bag, [LATCHED_TOPIC], raw=True)]
    assert len(latched) == 1
    assert deserialize_message(bytes(latched[0].msg), CameraInfo) == latched_message()
    qos = bag_info(bag).topics[LATCHED_TOPIC].qos
    assert qos and qos[0].durability.name == "TRANSIENT_LOCAL"  # (DDS does not tell the depth)
