"""dlo-bag-info BAG (dlo_bag.bag_info): like `ros2 bag info`; -v adds type hashes and QoS, --json one
object. Exit statuses: test_bag_exit_codes.py."""

import json
import os
import subprocess
import sys

from dlo_bag import bag_info as bag_info_cli
from dlo_bag.writer import BagWriter
from dlo_msgs.msg import GripperState
from rclpy.serialization import serialize_message


def write_bag(path):
    with BagWriter(path) as writer:
        writer.add_topic("/dlo/gripper/state", "dlo_msgs/msg/GripperState")
        writer.add_topic("/dlo/rope/particles", "sensor_msgs/msg/PointCloud2")
        for i in range(4):
            writer.write("/dlo/gripper/state", serialize_message(GripperState(step=i)), 1_000_000_000 + 250_000_000 * i)
        return writer.topics["/dlo/gripper/state"].rihs01


def test_topics_types_counts_and_duration_plain_verbose_and_as_json(tmp_path, capsys):
    """dlo_bag README: dlo-bag-info BAG prints topics, types, counts, duration; -v hashes/QoS; --json."""
    bag = tmp_path / "run"
    rihs01 = write_bag(bag)
    assert bag_info_cli.main([str(bag)]) == 0
    plain = capsys.readouterr().out
    assert "Messages:          4" in plain and "dlo_msgs/msg/GripperState | Count: 4 |" in plain
    assert "sensor_msgs/msg/PointCloud2 | Count: 0 |" in plain and "RIHS01_" not in plain
    assert bag_info_cli.main([str(bag), "-v"]) == 0
    assert rihs01 in capsys.readouterr().out
    assert bag_info_cli.main([str(bag), "--json"]) == 0
    out = capsys.readouterr().out
    assert out.count("\n") == 1  # one JSON object
    info = json.loads(out)
    assert info["message_count"] == 4 and info["duration_s"] == 0.75 and info["path"] == str(bag)
    assert info["topics"] == {
        "/dlo/gripper/state": {"type": "dlo_msgs/msg/GripperState", "count": 4, "type_hash": rihs01},
        "/dlo/rope/particles": {
            "type": "sensor_msgs/msg/PointCloud2",
            "count": 0,
            "type_hash": info["topics"]["/dlo/rope/particles"]["type_hash"],
        },
    }


def test_a_reader_that_stops_early_ends_it_quietly(tmp_path):
    """`dlo-bag-info BAG | head -12`: when the reader goes away the command ends quietly (exit 141, as coreutils'
    commands do), not with a BrokenPipeError traceback."""
    bag = tmp_path / "run"
    write_bag(bag)
    read, write = os.pipe()
    os.close(read)  # the reader has gone (head read its lines)
    try:
        result = subprocess.run(
            [sys.executable, "-c", "import sys\nfrom dlo_bag.bag_info import main\nsys.exit(main())", str(bag), "-v"],
            stdout=write,
            stderr=subprocess.PIPE,
            text=True,
            timeout=120,
        )
    finally:
        os.close(write)
    assert (result.returncode, result.stderr) == (141, "")


def test_a_folder_with_only_a_junk_metadata_file_is_not_a_bag_and_not_sent_to_recovery(tmp_path, capsys):
    """A folder holding a metadata.yaml but no .mcap data is not a bag (exit 2, one line); the tools do not tell the
    user to run dlo-bag-recover, which would only answer that there is nothing to recover."""
    from dlo_bag import recover

    junk = tmp_path / "junk"
    junk.mkdir()
    (junk / "metadata.yaml").write_text("not: a bag\n")
    assert bag_info_cli.main([str(junk)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no .mcap data" in err[0] and "dlo-bag-recover" not in err[0], err
    assert recover.main([str(junk)]) == 1  # and the recovery tool agrees: nothing it could salvage
    assert "no .mcap file in it" in capsys.readouterr().out
