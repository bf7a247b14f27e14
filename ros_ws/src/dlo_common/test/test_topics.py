"""dlo_common.topics: the one registry of the graph's topics and services (names, types, publishers, roles),
its lookups and subsets, and the name list the launcher remaps under --namespace."""

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
    assert {t.key for t in select(publisher="sim_node")} == {
        "clock",
        "particles",
        "gripper",
        "image",
        "camera_info",
        "task",
        "markers",
        "instance",
    }
    assert [t.name for t in select(exclude=("internal",))] == [t.name for t in TOPICS if t.key != "instance"]
    assert select() == TOPICS
    with pytest.raises(ValueError, match="unknown role"):
        select("nosuch")
    # the driver's part: what a robot driver in sim_node's place publishes or obeys
    assert {t.key for t in TOPICS if t.driver} == {"particles", "gripper", "image", "camera_info", "tactile", "command"}


def test_names_are_every_topic_and_service():
    """(What the launcher's --namespace remaps: dlo_bringup test_graph_description.py.)"""
    assert names() == tuple(t.name for t in TOPICS) + tuple(s.name for s in SERVICES)
    assert names()[-1] == "/dlo/sim/reset"


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
