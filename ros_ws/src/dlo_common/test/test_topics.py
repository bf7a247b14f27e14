"""dlo_common.topics: the one registry of the graph's topics and services (names, types, publishers, roles),
its lookups and subsets, and the name list the launcher remaps under --namespace."""

import subprocess
import sys

import pytest

from dlo_common import topics
from dlo_common.topics import ROLES, SERVICES, TOPICS, Topic, names, select, topic


def test_every_record_is_complete_and_unique():
    assert len({t.name for t in TOPICS}) == len({t.key for t in TOPICS}) == len(TOPICS)
    for t in TOPICS:
        assert t.name == "/clock" or t.name.startswith("/dlo/"), t.name
        assert t.type.count("/") == 2 and "/msg/" in t.type, t.type
        assert t.role in ROLES and t.rate in ("step", "latched") and t.description and t.publisher.endswith("_node")
    for s in SERVICES:
        assert s.name.startswith("/dlo/") and "/srv/" in s.type and s.server.endswith("_node")


def test_lookup_by_key_or_name_and_a_clear_error():
    assert topic("gripper") is topic("/dlo/gripper/state")
    assert topic("gripper").type == "dlo_msgs/msg/GripperState" and topic("gripper").publisher == "sim_node"
    with pytest.raises(KeyError, match="no topic 'nosuch'"):
        topic("nosuch")
    with pytest.raises(ValueError, match="role"):
        Topic("/dlo/x", "pkg/msg/X", "x_node", "nosuch", "x", key="x")


def test_subsets_are_filters_of_the_registry():
    assert [t.key for t in select("observation")] == ["tactile", "vision"]
    assert {t.key for t in select(publisher="sim_node")} == {"clock", "particles", "gripper", "image", "camera_info",
                                                             "task", "markers", "instance"}
    assert [t.name for t in select(exclude=("internal",))] == [t.name for t in TOPICS if t.key != "instance"]
    assert select() == TOPICS
    with pytest.raises(ValueError, match="unknown role"):
        select("nosuch")
    # the driver's part: what a robot driver in sim_node's place publishes or obeys
    assert {t.key for t in TOPICS if t.driver} == {"particles", "gripper", "image", "camera_info", "tactile", "command"}


def test_names_are_every_topic_and_service_and_the_launcher_reads_them():
    assert names() == tuple(t.name for t in TOPICS) + ("/dlo/sim/reset",)
    result = subprocess.run([sys.executable, "-m", "dlo_common.topics", "--names"], capture_output=True, text=True,
                            timeout=60)
    assert result.returncode == 0 and result.stdout.split() == list(names())
    table = subprocess.run([sys.executable, "-m", "dlo_common.topics"], capture_output=True, text=True, timeout=60)
    assert table.returncode == 0 and len(table.stdout.splitlines()) == len(TOPICS) + len(SERVICES)


def test_message_class_names_a_bad_type_in_one_line():
    with pytest.raises(ValueError, match="not a ROS 2 type name"):
        topics.message_class("nonsense")
    with pytest.raises(ValueError, match="cannot import message package 'no_such_pkg.msg'"):
        topics.message_class("no_such_pkg/msg/X")


def test_message_class_takes_the_short_form_and_refuses_an_empty_part():
    """message_class: "pkg/Name" is read as "pkg/msg/Name"; a type with an empty part is not a type name."""
    from std_msgs.msg import String

    assert topics.message_class("std_msgs/String") is String
    assert topics.message_class("std_msgs/msg/String") is String
    for bad in ("std_msgs/msg/", "/msg/String", "std_msgs//String", "std_msgs/"):
        with pytest.raises(ValueError, match="not a ROS 2 type name"):
            topics.message_class(bad)


def test_help_names_the_module_its_summary_and_the_names_option(capsys):
    """python -m dlo_common.topics --help: the usage names how it is run, the description is the module doc's
    first paragraph (and no more), --names is explained."""
    with pytest.raises(SystemExit) as exit_info:
        topics.main(["--help"])
    assert exit_info.value.code == 0
    out = " ".join(capsys.readouterr().out.split())
    assert out.startswith("usage: python -m dlo_common.topics [-h] [--names]")
    summary = " ".join(topics.__doc__.split("\n\n")[0].split())
    assert summary.startswith("The graph's topics and services") and summary in out
    assert "Every tool that needs" not in out
    assert "--names print every topic and service name, one a line" in out
