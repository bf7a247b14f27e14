"""Crash-safe bags, for real: a writer killed with SIGKILL, a .mcap cut at every kind of place,
a full disk (a real 2 MiB tmpfs; a per-file size limit where mounting is not allowed), and the
recovery tool (dlo-bag-recover) that makes such bags complete again."""

from __future__ import annotations

import contextlib
import io
import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from mcap.records import Message
from rclpy.serialization import serialize_message

from dlo_msgs.msg import GripperState, TaskState
from sensor_msgs.msg import Image

sys.path.insert(0, str(Path(__file__).resolve().parent))  # --import-mode=importlib

from dlo_bag_faults import file_size_limit, small_disk  # noqa: E402

from dlo_bag.bag import (  # noqa: E402
    EXIT_OK,
    EXIT_USAGE,
    METADATA,
    BagError,
    BagWriter,
    bag_info,
    bag_parts,
    read_messages,
)
from dlo_bag.mcap_file import _record_bytes  # noqa: E402
from dlo_bag import bag_info as bag_info_cli  # noqa: E402
from dlo_bag.recover import main as recover_cli  # noqa: E402
from dlo_bag.recover import recover_bag  # noqa: E402

STATE = "/dlo/gripper/state"
IMAGE = "/dlo/camera/image"


def state(i: int) -> bytes:
    msg = GripperState()
    msg.x, msg.step = 0.001 * i, i
    msg.header.frame_id = str(i)
    return serialize_message(msg)


def image(i: int, size: int = 128) -> bytes:
    msg = Image(height=size, width=size, step=size, encoding="mono8", data=bytes([i % 251]) * size * size)
    msg.header.frame_id = str(i)
    return serialize_message(msg)


def seqs(bag, topic=None) -> list[int]:
    return [int(m.msg.header.frame_id) for m in read_messages(bag, None if topic is None else [topic])]


def run_py(code: str, **kwargs) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True,
                          timeout=120, **kwargs)


def cli(module: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", module, *args], capture_output=True, text=True, timeout=120)


def in_process(main, *args: str) -> subprocess.CompletedProcess:
    """A command's main() run here (no interpreter start-up), as a CompletedProcess."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            rc = main(list(args))
        except SystemExit as exit_:
            rc = exit_.code
    return subprocess.CompletedProcess(args, rc, out.getvalue(), err.getvalue())


def one_line(result: subprocess.CompletedProcess) -> str:
    text = (result.stdout + result.stderr).strip()
    assert "Traceback" not in text and len(text.splitlines()) == 1, text
    return text


# ---- SIGKILL -------------------------------------------------------------------------------

def test_sigkilled_writer_loses_only_what_was_not_flushed(tmp_path):
    bag = tmp_path / "run"
    child = run_py(f"""
        import os, signal
        from rclpy.serialization import serialize_message
        from dlo_msgs.msg import GripperState
        from dlo_bag.bag import BagWriter
        def state(i):
            m = GripperState(); m.step = i; m.header.frame_id = str(i); return serialize_message(m)
        w = BagWriter({str(bag)!r}, chunk_size=4096)
        w.add_topic({STATE!r}, "dlo_msgs/msg/GripperState")
        w.add_topic("/dlo/rope/particles", "sensor_msgs/msg/PointCloud2")
        for i in range(300):
            w.write({STATE!r}, state(i), 1_000 + i)
        w.flush()                      # what a recorder does every flush_period
        for i in range(300, 305):      # received after the last flush: in memory only
            w.write({STATE!r}, state(i), 1_000 + i)
        os.kill(os.getpid(), signal.SIGKILL)
        """)
    assert child.returncode == -signal.SIGKILL, child.stderr
    assert not (bag / METADATA).exists()
    with pytest.raises(BagError, match=f"needs recovering.*dlo-bag-recover {bag}$"):
        bag_parts(bag)
    for module in ("dlo_bag.bag_info", "dlo_bag.analysis"):  # one line naming the command
        result = cli(module, str(bag))
        assert result.returncode != 0 and f"dlo-bag-recover {bag}" in one_line(result)

    result = cli("dlo_bag.recover", str(bag))
    assert result.returncode == 0, result.stdout + result.stderr
    assert "recovered 300 messages" in one_line(result)
    assert seqs(bag) == list(range(300))  # everything flushed survives, nothing else
    info = bag_info(bag)
    assert info.topics[STATE].count == 300 and info.topics["/dlo/rope/particles"].count == 0
    want = BagWriter(tmp_path / "reference", chunk_size=4096)  # same hash/QoS as a live writer
    want.add_topic(STATE, "dlo_msgs/msg/GripperState")
    assert info.topics[STATE].rihs01 == want.topics[STATE].rihs01 and info.topics[STATE].rihs01
    want.close()
    assert (bag / "run.mcap.damaged").is_file() and not (bag / ".dlo_reserve").exists()
    again = in_process(recover_cli, str(bag))  # a complete bag is left alone
    assert again.returncode == 0 and "nothing to recover" in one_line(again)


# ---- truncation ----------------------------------------------------------------------------

def test_cut_mcap_keeps_every_complete_message(tmp_path):
    """Cut a closed bag's .mcap everywhere that matters (a copy interrupted); recovery keeps
    exactly the messages whose record lies wholly before the cut."""
    source = tmp_path / "source"
    with BagWriter(source, chunk_size=3000) as writer:
        writer.add_topic(STATE, "dlo_msgs/msg/GripperState")
        writer.add_topic(IMAGE, "sensor_msgs/msg/Image")
        for i in range(120):
            writer.write(STATE, state(i), 10_000 + 2 * i)
            if i % 10 == 0:
                writer.write(IMAGE, image(i, 24), 10_000 + 2 * i + 1)
    data = (source / "source.mcap").read_bytes()
    # where each message record ends in the file (independent of the scanner: a byte search)
    ends = []
    for m in read_messages(source, raw=True):
        record = _record_bytes(Message(channel_id=1 if m.topic == STATE else 2, log_time=m.timestamp,
                                       data=bytes(m.msg), publish_time=m.timestamp, sequence=0))
        pos = data.find(record)
        assert pos > 0
        ends.append(pos + len(record))
    assert ends == sorted(ends)
    cuts = sorted({len(data) - 1, len(data) - 30, ends[-1], ends[-1] - 1, 200, 9}
                  | {e for e in ends[::17]} | {e - 5 for e in ends[5::23]} | {e + 40 for e in ends[7::31]})
    everything = seqs(source)
    for cut in cuts:
        bag = tmp_path / f"cut_{cut}"
        shutil.copytree(source, bag)
        with open(bag / "source.mcap", "r+b") as f:
            f.truncate(cut)
        result = in_process(bag_info_cli.main, str(bag))  # metadata.yaml is there, the data is not
        assert result.returncode == 1 and f"dlo-bag-recover {bag}" in one_line(result), cut
        expected = sum(1 for e in ends if e <= cut)
        reports = recover_bag(bag)
        if expected == 0:  # not even one message: nothing (or only definitions) to keep
            assert reports[0].action in ("failed", "recovered")
            continue
        assert reports[0].action == "recovered", (cut, reports[0].line())
        assert seqs(bag) == everything[:expected], cut


def test_recover_leaves_the_original_untouched_with_output(tmp_path):
    bag = tmp_path / "run"
    with BagWriter(bag, chunk_size=2000) as writer:
        writer.add_topic(STATE, "dlo_msgs/msg/GripperState")
        for i in range(50):
            writer.write(STATE, state(i), 1 + i)
    mcap = bag / "run.mcap"
    os.truncate(mcap, mcap.stat().st_size // 2)
    (bag / METADATA).unlink()
    before = mcap.read_bytes()
    result = in_process(recover_cli, str(bag), "--output", str(tmp_path / "fixed"))
    assert result.returncode == 0, result.stdout + result.stderr
    assert mcap.read_bytes() == before and not (bag / METADATA).exists()
    assert seqs(tmp_path / "fixed") == list(range(len(seqs(tmp_path / "fixed"))))
    assert 0 < len(seqs(tmp_path / "fixed")) < 50


def write_bag(path, messages: int = 50, chunk_size: int = 2000):
    """A complete bag of `messages` gripper states, log times 1..messages ns, in chunks of `chunk_size` bytes."""
    with BagWriter(path, chunk_size=chunk_size) as writer:
        writer.add_topic(STATE, "dlo_msgs/msg/GripperState")
        for i in range(1, messages + 1):
            writer.write(STATE, state(i), i)
    return path


def test_recover_with_output_copies_an_intact_bag(tmp_path, capsys):
    """dlo-bag-recover BAG --output DIR: 'write the recovered bag here and leave BAG untouched', also for a bag
    that reads completely (in place such a bag is left alone)."""
    bag = write_bag(tmp_path / "run")
    before = {p.name: p.read_bytes() for p in bag.iterdir()}
    assert recover_cli([str(bag), "--output", str(tmp_path / "copy")]) == EXIT_OK
    assert "recovered 50 messages" in capsys.readouterr().out
    assert [m.timestamp for m in read_messages(tmp_path / "copy", raw=True)] == list(range(1, 51))
    assert {p.name: p.read_bytes() for p in bag.iterdir()} == before
    assert recover_cli([str(bag)]) == EXIT_OK
    assert "nothing to recover" in capsys.readouterr().out


def test_recover_refuses_an_output_directory_that_exists(tmp_path, capsys):
    """dlo-bag-recover BAG --output DIR refuses a DIR that exists (one line, exit 2) and leaves it as it was."""
    bag = write_bag(tmp_path / "run")
    os.truncate(bag / "run.mcap", (bag / "run.mcap").stat().st_size // 2)
    (bag / METADATA).unlink()
    existing = tmp_path / "existing"
    existing.mkdir()
    (existing / "keep.txt").write_text("mine\n")
    assert recover_cli([str(bag), "--output", str(existing)]) == EXIT_USAGE
    err = capsys.readouterr().err
    assert "exists already" in err and len(err.strip().splitlines()) == 1
    assert sorted(p.name for p in existing.iterdir()) == ["keep.txt"]


def test_split_bag_with_a_killed_last_part(tmp_path):
    out = tmp_path / "run"
    writer = BagWriter(out, split=True, chunk_size=1000)
    writer.add_topic(STATE, "dlo_msgs/msg/GripperState")
    for i in range(20):
        writer.write(STATE, state(i), 1 + i)
    writer.roll()
    for i in range(20, 40):
        writer.write(STATE, state(i), 1 + i)
    writer.flush()  # then "killed": the second part is never closed
    with pytest.raises(BagError, match="part run_0001 has no metadata.yaml.*dlo-bag-recover"):
        bag_parts(out)
    reports = recover_bag(out)
    assert [r.action for r in reports] == ["intact", "recovered"]
    assert seqs(out) == list(range(40))


def test_not_an_mcap_and_garbage_are_one_line_errors(tmp_path):
    bag = tmp_path / "junk"
    bag.mkdir()
    (bag / "junk.mcap").write_bytes(os.urandom(3000))
    result = in_process(recover_cli, str(bag))
    assert result.returncode == 1 and "not an MCAP file" in one_line(result)
    result = in_process(recover_cli, str(tmp_path / "missing"))
    assert result.returncode == 2 and "does not exist" in one_line(result)
    good = tmp_path / "good"
    with BagWriter(good, chunk_size=500) as writer:
        writer.add_topic(STATE, "dlo_msgs/msg/GripperState")
        for i in range(30):
            writer.write(STATE, state(i), 1 + i)
    raw = bytearray((good / "good.mcap").read_bytes())
    middle = len(raw) // 2
    raw[middle:middle + 60] = os.urandom(60)  # bytes flipped inside a chunk in the middle
    (good / "good.mcap").write_bytes(bytes(raw))
    from dlo_bag import analysis

    info = in_process(bag_info_cli.main, str(good))  # reads metadata.yaml only, like ros2 bag info
    assert info.returncode == 0, info.stderr
    result = in_process(analysis.main, str(good))  # reads the data: the damaged chunk is one line
    assert result.returncode != 0 and "dlo-bag-recover" in one_line(result)
    report = recover_bag(good)[0]
    assert report.action == "recovered" and any("CRC" in p or "opcode" in p for p in report.problems)
    assert set(seqs(good)) < set(range(30))  # the damaged chunk is left out, the rest kept


# ---- disk full -----------------------------------------------------------------------------

WRITER_UNTIL_FULL = """
    import json, sys
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import Image
    from dlo_bag.recording import Recorder
    def image(i):
        m = Image(height=128, width=128, step=128, encoding="mono8", data=bytes([i % 251]) * 16384)
        m.header.frame_id = str(i)
        return serialize_message(m)
    rec = Recorder(sys.argv[1])
    rec.add_topic("/dlo/camera/image", "sensor_msgs/msg/Image")
    i = 0
    while not rec.failure and i < 100000:
        rec.on_message("/dlo/camera/image", image(i), 1_000 + i)
        i += 1
        if i % 7 == 0:
            rec.flush()
    for _ in range(3):  # received after the failure: counted, not written
        rec.on_message("/dlo/camera/image", image(i), 1_000 + i)
        i += 1
    print(json.dumps(rec.close().to_dict()))
"""


def test_disk_full_is_final_and_the_bag_stays_readable(tmp_path):
    with small_disk(tmp_path) as disk:
        if disk is not None:
            bag = disk / "run"
            child = subprocess.run([sys.executable, "-c", textwrap.dedent(WRITER_UNTIL_FULL), str(bag)],
                                   capture_output=True, text=True, timeout=300)
        else:  # not root: a per-file size limit fails the writes the same way (EFBIG)
            bag = tmp_path / "run"
            child = subprocess.run([sys.executable, "-c", textwrap.dedent(WRITER_UNTIL_FULL), str(bag)],
                                   capture_output=True, text=True, timeout=300,
                                   preexec_fn=file_size_limit(1_500_000))
        assert child.returncode == 0 and "Traceback" not in child.stderr, child.stderr
        summary = json.loads(child.stdout.splitlines()[-1])
        assert summary["failure"] == ("no space left on device" if disk is not None else "file too large")
        assert summary["complete"] and summary["written"] > 20
        assert summary["received"] == summary["received_at_failure"] + 3
        got = seqs(bag)
        assert got == list(range(len(got))) and len(got) == summary["written"]
        assert bag_info(bag).message_count == summary["written"]
        if disk is not None:  # the space held in reserve closed the bag with every message received
            assert summary["written"] == summary["received_at_failure"]
        assert not (bag / ".dlo_reserve").exists()


# ---- names and reading ---------------------------------------------------------------------

def test_bag_directory_named_dot_bag(tmp_path):
    """rosbags takes '*.bag' for ROS 1 files; a rosbag2 directory of that name must still read."""
    bag = tmp_path / "run.bag"
    with BagWriter(bag) as writer:
        writer.add_topic("/dlo/task/state", "dlo_msgs/msg/TaskState")
        for step in range(3):
            task = TaskState(episode=0, step=step, num_particles=40, cable_length=0.4)
            task.header.stamp.nanosec = step + 1
            writer.write("/dlo/task/state", serialize_message(task), 100 + step)
    assert [m.msg.step for m in read_messages(bag)] == [0, 1, 2]
    assert bag_info(bag).message_count == 3
    from dlo_bag.analysis import read_run

    assert sorted(read_run(bag)[0]["task"]) == [0, 1, 2]


def test_delete_original_recovers_in_place_and_keeps_no_damaged_copy(tmp_path):
    """dlo_bag README (Crash safety) / dlo-bag-recover --help: --delete-original deletes the damaged
    .mcap instead of keeping it as *.mcap.damaged; the recovered bag holds every flushed message."""
    bag = tmp_path / "run"
    writer = BagWriter(bag, chunk_size=2000)
    writer.add_topic(STATE, "dlo_msgs/msg/GripperState")
    for i in range(60):
        writer.write(STATE, state(i), 1 + i)
    writer.flush()  # then "killed": no metadata.yaml
    result = in_process(recover_cli, str(bag), "--delete-original")
    assert result.returncode == 0 and "recovered 60 messages" in one_line(result)
    assert sorted(p.name for p in bag.iterdir()) == [METADATA, "run.mcap"]
    assert seqs(bag) == list(range(60))
