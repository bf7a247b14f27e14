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
from dlo_msgs.msg import GripperState, TaskState
from mcap.records import Message
from rclpy.serialization import serialize_message
from sensor_msgs.msg import Image

sys.path.insert(0, str(Path(__file__).resolve().parent))  # --import-mode=importlib

from dlo_bag import bag_info as bag_info_cli  # noqa: E402
from dlo_bag.errors import EXIT_OK, EXIT_USAGE, BagError  # noqa: E402
from dlo_bag.info import bag_info  # noqa: E402
from dlo_bag.mcap_file import _record_bytes  # noqa: E402
from dlo_bag.metadata import METADATA  # noqa: E402
from dlo_bag.reader import bag_parts, read_messages  # noqa: E402
from dlo_bag.recover import main as recover_cli  # noqa: E402
from dlo_bag.recover import recover_bag  # noqa: E402
from dlo_bag.writer import BagWriter  # noqa: E402
from dlo_bag_faults import file_size_limit, small_disk  # noqa: E402

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
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True, timeout=120, **kwargs)


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
        from dlo_bag.writer import BagWriter
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
        record = _record_bytes(
            Message(
                channel_id=1 if m.topic == STATE else 2,
                log_time=m.timestamp,
                data=bytes(m.msg),
                publish_time=m.timestamp,
                sequence=0,
            )
        )
        pos = data.find(record)
        assert pos > 0
        ends.append(pos + len(record))
    assert ends == sorted(ends)
    cuts = sorted(
        {len(data) - 1, len(data) - 30, ends[-1], ends[-1] - 1, 200, 9}
        | {e for e in ends[::17]}
        | {e - 5 for e in ends[5::23]}
        | {e + 40 for e in ends[7::31]}
    )
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
    raw[middle : middle + 60] = os.urandom(60)  # bytes flipped inside a chunk in the middle
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
            child = subprocess.run(
                [sys.executable, "-c", textwrap.dedent(WRITER_UNTIL_FULL), str(bag)], capture_output=True, text=True, timeout=300
            )
        else:  # not root: a per-file size limit fails the writes the same way (EFBIG)
            bag = tmp_path / "run"
            child = subprocess.run(
                [sys.executable, "-c", textwrap.dedent(WRITER_UNTIL_FULL), str(bag)],
                capture_output=True,
                text=True,
                timeout=300,
                preexec_fn=file_size_limit(1_500_000),
            )
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


# ---- dlo-bag-recover, case by case ---------------------------------------------------------


def killed_bag(path, messages: int = 60):
    """A bag whose writer was "killed" after flushing `messages` gripper states: no metadata.yaml."""
    writer = BagWriter(path, chunk_size=2000)
    writer.add_topic(STATE, "dlo_msgs/msg/GripperState")
    for i in range(messages):
        writer.write(STATE, state(i), 1 + i)
    writer.flush()
    return path


def listing(path) -> list[str]:
    return sorted(str(p.relative_to(path)) for p in Path(path).rglob("*"))


def test_the_report_line_of_each_outcome():
    from dlo_bag.recover import RecoverReport

    part = Path("bags/run")
    assert RecoverReport(part, "intact", messages=7).line() == "bags/run: complete and readable (7 messages); nothing to recover"
    assert RecoverReport(part, "failed", error="why").line() == "bags/run: cannot be recovered: why"
    full = RecoverReport(
        part,
        "recovered",
        messages=5,
        topics={"/a": 3, "/b": 2},
        discarded_bytes=17,
        original=part / "run.mcap.damaged",
        output=Path("bags/fixed"),
    )
    assert full.line() == (
        "bags/run: recovered 5 messages on 2 topics into bags/fixed (metadata.yaml rebuilt; "
        "the last 17 byte(s), an incomplete record, discarded; original kept as run.mcap.damaged)"
    )
    in_place = RecoverReport(part, "recovered", messages=5, topics={"/a": 5}, output=part)
    assert in_place.line() == "bags/run: recovered 5 messages on 1 topics (metadata.yaml rebuilt)"
    assert RecoverReport(part, "recovered", messages=5, topics={"/a": 5}).line() == in_place.line()


def test_a_channel_without_a_recorded_hash_gets_it_from_its_definition_in_either_encoding():
    from dlo_bag.recover import _hash_from_definition

    idl = "module test_msgs {\n  module msg {\n    struct Simple {\n      int32 a;\n    };\n  };\n};\n"
    from_msg = _hash_from_definition("test_msgs/msg/Simple", "ros2msg", "int32 a\n")
    assert from_msg.startswith("RIHS01_") and _hash_from_definition("test_msgs/msg/Simple", "ros2idl", idl) == from_msg
    assert _hash_from_definition("test_msgs/msg/Simple", "ros2msg", idl) == ""  # unparsable: no hash
    assert _hash_from_definition("test_msgs/msg/Simple", "ros2idl", "int32 a\n") == ""


def test_topic_specs_of_scanned_channels(tmp_path):
    """A channel's spec keeps its recorded QoS and hash (or computes the hash from the definition), decodes a
    definition with bad bytes leniently; a channel without a schema is skipped with a problem, an unknown one
    quietly."""
    from types import SimpleNamespace

    from dlo_bag.qos import qos_from_profile, qos_yaml
    from dlo_bag.recover import _topic_spec
    from mcap.records import Channel, Schema
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    with BagWriter(tmp_path / "reference") as writer:
        reference = writer.add_topic(STATE, "dlo_msgs/msg/GripperState")
    qos = qos_from_profile(
        QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    )
    scan = SimpleNamespace(
        problems=[],
        schemas={
            1: Schema(id=1, name="dlo_msgs/msg/GripperState", encoding="ros2msg", data=reference.msgdef.encode()),
            2: Schema(id=2, name="dlo_msgs/msg/GripperState", encoding="ros2msg", data=b"int32 a\n# \xff\n"),
        },
        channels={
            1: Channel(
                id=1,
                topic=STATE,
                schema_id=1,
                message_encoding="cdr",
                metadata={"offered_qos_profiles": qos_yaml([qos]), "topic_type_hash": "RIHS01_recorded"},
            ),
            2: Channel(id=2, topic="/no/hash", schema_id=1, message_encoding="cdr", metadata={}),
            3: Channel(id=3, topic="/bad/bytes", schema_id=2, message_encoding="cdr", metadata={"topic_type_hash": "RIHS01_x"}),
            4: Channel(id=4, topic="/lost", schema_id=9, message_encoding="cdr", metadata={}),
        },
    )
    recorded = _topic_spec(scan, 1)
    assert (recorded.topic, recorded.msgtype, recorded.rihs01) == (STATE, "dlo_msgs/msg/GripperState", "RIHS01_recorded")
    assert recorded.qos == [qos] and recorded.msgdef == reference.msgdef
    computed = _topic_spec(scan, 2)
    assert computed.rihs01 == reference.rihs01 and computed.qos == []
    assert _topic_spec(scan, 3).msgdef == "int32 a\n# \ufffd\n"
    assert scan.problems == []
    assert _topic_spec(scan, 99) is None and scan.problems == []
    assert _topic_spec(scan, 4) is None
    assert scan.problems == ["channel /lost has no schema: its messages are skipped"]


def test_only_sub_directories_with_an_mcap_are_parts_and_output_keeps_the_layout(tmp_path, capsys):
    from dlo_bag.recover import bag_dirs

    out = tmp_path / "run"
    writer = BagWriter(out, split=True, chunk_size=1000)
    writer.add_topic(STATE, "dlo_msgs/msg/GripperState")
    for i in range(20):
        writer.write(STATE, state(i), 1 + i)
        if i == 9:
            writer.roll()
    writer.close()
    (out / "notes").mkdir()
    (out / "notes" / "todo.txt").write_text("x\n")
    (out / "README.txt").write_text("x\n")
    assert bag_dirs(out) == [out / "run_0000", out / "run_0001"]
    assert [r.action for r in recover_bag(out)] == ["intact", "intact"]
    reports = recover_bag(out, output=tmp_path / "copy")  # parts: one directory each under DIR
    assert [(r.action, r.output) for r in reports] == [
        ("recovered", tmp_path / "copy" / "run_0000"),
        ("recovered", tmp_path / "copy" / "run_0001"),
    ]
    assert sorted(p.name for p in (tmp_path / "copy").iterdir()) == ["run_0000", "run_0001"]
    assert seqs(tmp_path / "copy") == list(range(20))
    single = write_bag(tmp_path / "single")  # one bag: DIR is the bag
    assert recover_cli([str(single), "--output", str(tmp_path / "one")]) == EXIT_OK
    assert capsys.readouterr().out == (
        f"{single}: recovered 50 messages on 1 topics into {tmp_path / 'one'} ({METADATA} rebuilt)\n"
    )
    assert sorted(p.name for p in (tmp_path / "one").iterdir()) == [METADATA, "one.mcap"]


def test_an_intact_bag_is_checked_without_decoding_its_messages(tmp_path, capsys):
    """'A bag that reads completely is left alone': the check reads the container (every record), not the
    payloads, and names how many messages it holds."""
    bag = write_bag(tmp_path / "run")
    assert recover_cli([str(bag)]) == EXIT_OK
    assert capsys.readouterr().out == f"{bag}: complete and readable (50 messages); nothing to recover\n"
    odd = tmp_path / "odd"
    with BagWriter(odd) as writer:
        writer.add_topic(STATE, "dlo_msgs/msg/GripperState")
        writer.write(STATE, b"\x00\x01", 5)  # not a CDR GripperState: the bag itself is complete
    before = listing(odd)
    assert recover_cli([str(odd)]) == EXIT_OK
    assert capsys.readouterr().out == f"{odd}: complete and readable (1 messages); nothing to recover\n"
    assert listing(odd) == before


def test_a_part_without_one_mcap_cannot_be_recovered(tmp_path, capsys):
    source = write_bag(tmp_path / "source")
    none = tmp_path / "none"
    none.mkdir()
    shutil.copy(source / METADATA, none / METADATA)  # the data file is gone
    assert recover_cli([str(none)]) == 1
    assert capsys.readouterr().out == f"{none}: cannot be recovered: no .mcap file in it\n"
    two = tmp_path / "two"
    two.mkdir()
    shutil.copy(source / "source.mcap", two / "a.mcap")
    shutil.copy(source / "source.mcap", two / "b.mcap")
    assert recover_cli([str(two)]) == 1
    assert capsys.readouterr().out == (
        f"{two}: cannot be recovered: 2 .mcap files; recover a bag of one file (copy each into its own directory)\n"
    )
    assert listing(two) == ["a.mcap", "b.mcap"]


def test_a_work_directory_left_by_an_interrupted_recovery_is_replaced(tmp_path):
    bag = killed_bag(tmp_path / "run")
    stale = bag / ".dlo_recovering" / "run"
    stale.mkdir(parents=True)
    (stale / "run.mcap").write_bytes(b"half")
    (stale / METADATA).write_text("half\n")
    report = recover_bag(bag)[0]
    assert report.action == "recovered", report.line()
    assert seqs(bag) == list(range(60))
    assert listing(bag) == [METADATA, "run.mcap", "run.mcap.damaged"]


def test_recovery_holds_no_disk_space_in_reserve(tmp_path):
    """The recovered bag is written without the recorder's reserve (at least 256 KiB): a small bag recovers
    where a file may grow to 200 kB only (a per-file size limit stands in for a nearly full disk)."""
    bag = killed_bag(tmp_path / "run")
    result = subprocess.run(
        [sys.executable, "-m", "dlo_bag.recover", str(bag)],
        capture_output=True,
        text=True,
        timeout=120,
        preexec_fn=file_size_limit(200_000),
    )
    assert result.returncode == 0 and "recovered 60 messages" in one_line(result)
    assert seqs(bag) == list(range(60))


def test_custom_data_is_kept_and_the_recovery_is_noted(tmp_path):
    import re

    from dlo_bag.mcap_file import WRITER_NAME

    bag = tmp_path / "run"
    with BagWriter(bag, chunk_size=2000) as writer:
        writer.custom_data["dlo.episode"] = "3"
        writer.add_topic(STATE, "dlo_msgs/msg/GripperState")
        for i in range(50):
            writer.write(STATE, state(i), 1 + i)
    assert recover_bag(bag, output=tmp_path / "copy")[0].action == "recovered"
    custom = bag_info(tmp_path / "copy").custom_data[0]
    assert sorted(custom) == ["dlo.episode", f"{WRITER_NAME}.recovered"] and custom["dlo.episode"] == "3"
    assert re.fullmatch(
        r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d by dlo-bag-recover from run\.mcap: 50 messages, "
        r"0 bytes discarded",
        custom[f"{WRITER_NAME}.recovered"],
    )


def test_a_recovered_bag_that_cannot_be_written_is_one_line_and_leaves_the_bag_as_it_was(tmp_path, monkeypatch):
    """A write failure (the writer's short cause, or the OSError) is the failed report's one line; in place
    the work directory is removed, whether the writer had made it or not; the damaged bag is untouched."""
    from dlo_bag import recover
    from dlo_bag.writer import BagWriteError

    bag = killed_bag(tmp_path / "run")
    before = {name: (bag / name).read_bytes() for name in listing(bag) if name != ".dlo_reserve"}  # the killed
    # writer's reserve is freed first, whatever follows

    def full_disk(path, *args, **kwargs):
        Path(path).mkdir(parents=True)
        raise BagWriteError(f"cannot create the bag '{path}': no space left on device", "no space left on device")

    def denied(path, *args, **kwargs):
        raise PermissionError(13, "Permission denied", str(path))

    for writer, cause in (
        (full_disk, "no space left on device"),
        (denied, f"[Errno 13] Permission denied: '{bag / '.dlo_recovering' / 'run'}'"),
    ):
        monkeypatch.setattr(recover, "BagWriter", writer)
        report = recover.recover_bag(bag)[0]
        assert (report.action, report.error) == (
            "failed",
            f"cannot write the recovered bag: {cause} (free some space, or use --output DIR elsewhere)",
        )
        assert {name: (bag / name).read_bytes() for name in listing(bag)} == before


def test_nothing_to_salvage_fails_and_leaves_nothing_behind(tmp_path, capsys):
    bag = killed_bag(tmp_path / "run")
    os.truncate(bag / "run.mcap", 60)  # the first chunk's header is cut: not one record
    before = ["run.mcap"]  # (the killed writer's .dlo_reserve is freed first)
    assert recover_cli([str(bag), "-v"]) == 1
    assert capsys.readouterr().out == (
        f"{bag}: cannot be recovered: run.mcap holds no complete record to salvage\n"
        "  chunk cut at byte 51 (its header is incomplete)\n"
    )
    assert listing(bag) == before
    assert recover_cli([str(bag), "--output", str(tmp_path / "copy")]) == 1
    assert "holds no complete record" in capsys.readouterr().out
    assert not (tmp_path / "copy").exists() and listing(bag) == before


def test_a_bag_of_topics_without_messages_is_recovered_with_its_topics(tmp_path, capsys):
    bag = tmp_path / "run"
    with BagWriter(bag) as writer:
        writer.add_topic(STATE, "dlo_msgs/msg/GripperState")
        writer.add_topic(IMAGE, "sensor_msgs/msg/Image")
    assert recover_cli([str(bag), "--output", str(tmp_path / "copy")]) == EXIT_OK
    assert "recovered 0 messages on 0 topics" in capsys.readouterr().out
    info = bag_info(tmp_path / "copy")
    assert {t: i.count for t, i in info.topics.items()} == {STATE: 0, IMAGE: 0}


def test_a_cut_bag_reports_its_topics_and_the_bytes_discarded(tmp_path, capsys):
    bag = write_bag(tmp_path / "run", messages=200)
    size = (bag / "run.mcap").stat().st_size
    os.truncate(bag / "run.mcap", size * 2 // 3)
    report = recover_bag(bag)[0]
    kept = len(seqs(bag))
    assert report.action == "recovered" and 0 < kept < 200
    assert report.messages == kept and report.topics == {STATE: kept}
    assert 0 < report.discarded_bytes < size * 2 // 3
    assert (
        f"on 1 topics ({METADATA} rebuilt; the last {report.discarded_bytes} byte(s), an incomplete record, "
        f"discarded; original kept as run.mcap.damaged)" in report.line()
    )


def test_a_data_file_named_otherwise_keeps_its_name(tmp_path):
    """ros2 bag record names the file run_0.mcap in the directory run: metadata.yaml names that file."""
    bag = killed_bag(tmp_path / "run")
    (bag / "run.mcap").rename(bag / "run_0.mcap")
    assert recover_bag(bag)[0].action == "recovered"
    info = bag_info(bag)
    assert info.files == [bag / "run_0.mcap"] and info.message_count == 60
    import yaml

    meta = yaml.safe_load((bag / METADATA).read_text())["rosbag2_bagfile_information"]
    assert meta["relative_file_paths"] == ["run_0.mcap"] and [f["path"] for f in meta["files"]] == ["run_0.mcap"]


def test_the_command_line_errors_help_and_exit_status(tmp_path, capsys, monkeypatch):
    from dlo_bag import recover

    bag = write_bag(tmp_path / "run")
    assert recover_cli([str(bag / "run.mcap")]) == EXIT_USAGE
    assert capsys.readouterr().err == (
        f"dlo-bag-recover: error: '{bag / 'run.mcap'}' is not a directory (give the bag directory, not a file)\n"
    )
    # a split bag with one part beyond recovery: exit 1, the good part still reported
    out = tmp_path / "split"
    writer = BagWriter(out, split=True, chunk_size=1000)
    writer.add_topic(STATE, "dlo_msgs/msg/GripperState")
    writer.write(STATE, state(0), 1)
    writer.close()
    (out / "split_0001").mkdir()
    (out / "split_0001" / "split_0001.mcap").write_bytes(b"not an mcap" * 50)
    assert recover_cli([str(out)]) == 1
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == f"{out / 'split_0000'}: complete and readable (1 messages); nothing to recover"
    assert lines[1].startswith(f"{out / 'split_0001'}: cannot be recovered:") and len(lines) == 2

    def io_error(*args, **kwargs):
        raise OSError(5, "Input/output error")

    monkeypatch.setattr(recover, "recover_bag", io_error)
    assert recover_cli([str(bag)]) == 1  # a read error is a bad bag, not a usage error
    assert capsys.readouterr().err == "dlo-bag-recover: error: [Errno 5] Input/output error\n"
    monkeypatch.undo()
    with pytest.raises(SystemExit) as exit_info:
        recover_cli(["--help"])
    assert exit_info.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    assert text.startswith("usage: dlo-bag-recover [-h] [--output OUTPUT] [--delete-original] [-v] bag")
    for words in (
        "Recover a rosbag2 MCAP bag whose recorder was killed (no metadata.yaml) or whose .mcap was cut "
        "short: salvage every complete message into a valid, indexed bag and rebuild metadata.yaml "
        "(like 'ros2 bag reindex' + 'mcap recover').",
        "bag bag directory (or a directory of rolled parts)",
        "--output OUTPUT, -o OUTPUT write the recovered bag here and leave BAG untouched",
        "--delete-original in place: delete the damaged .mcap instead of keeping it as *.mcap.damaged",
        "-v, --verbose also list what was damaged",
    ):
        assert words in text, words
