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


# The paper's graph (docs/ARCHITECTURE.md#topics), in registry order: key, role, publisher, whether a robot driver
# has a part in it, the plot series. A topic added to the registry (a new modality) leaves this pin as it is; one
# lost, reordered or changed fails it.
PAPER_GRAPH = (
    ("clock", "clock", "sim_node", False, ()),
    ("particles", "sensor", "sim_node", True, ()),
    ("gripper", "state", "sim_node", True, ()),
    ("image", "sensor", "sim_node", True, ()),
    ("camera_info", "sensor", "sim_node", True, ()),
    ("tactile", "observation", "tactile_node", True, ("theta_T", "y_T")),
    ("vision", "observation", "vision_node", False, ("q_V", "theta_V", "y_V")),
    ("command", "command", "policy_node", True, ()),
    ("task", "task", "sim_node", False, ()),
    ("markers", "visualisation", "sim_node", False, ()),
    ("instance", "internal", "sim_node", False, ()),
    ("policy_info", "provenance", "policy_node", False, ()),
)


def test_the_papers_graph_is_in_the_registry_in_order():
    keys = {row[0] for row in PAPER_GRAPH}
    found = [(t.key, t.role, t.publisher, bool(t.driver), tuple(s.name for s in t.plot)) for t in TOPICS if t.key in keys]
    assert found == list(PAPER_GRAPH)


def test_subsets_are_filters_of_the_registry():
    for role in ROLES:
        assert select(role) == tuple(t for t in TOPICS if t.role == role)
    for publisher in {t.publisher for t in TOPICS}:
        assert select(publisher=publisher) == tuple(t for t in TOPICS if t.publisher == publisher)
    assert select("observation", "state") == tuple(t for t in TOPICS if t.role in ("observation", "state"))
    assert select(exclude=("internal",)) == tuple(t for t in TOPICS if t.role != "internal")
    assert select() == TOPICS
    with pytest.raises(ValueError, match="unknown role"):
        select("nosuch")


@pytest.mark.parametrize("record", [t for t in TOPICS if t.plot], ids=lambda t: t.key)
def test_every_plot_series_is_a_number_of_its_message(record):
    """Bag analysis reads each plot series' field from the topic's message (a dotted field: a nested one)."""
    from operator import attrgetter

    message = topics.message_class(record.type)()
    for series in record.plot:
        assert isinstance(attrgetter(series.field)(message), (int, float)), series
        assert series.name and series.unit
    assert len({s.name for t in TOPICS for s in t.plot}) == sum(len(t.plot) for t in TOPICS)  # names are unique
    with pytest.raises(ValueError, match="plot must be Series"):
        Topic("/dlo/x", "pkg/msg/X", "x_node", "observation", "x", key="x", plot=(("angle", "theta", "rad"),))


def test_plot_series_by_unit_groups_every_series_of_the_roles_in_registry_order():
    """The paper's observations: q_V unitless, the angles in rad, the offsets in m (the plots', video's and layout's
    rows); every series of the role once, a topic of another role not at all."""
    units = topics.plot_series_by_unit("observation")
    named = {unit: [(t.key, s.name) for t, s in pairs] for unit, pairs in units.items()}
    assert named["rad"] == [("tactile", "theta_T"), ("vision", "theta_V")]
    assert named["m"] == [("tactile", "y_T"), ("vision", "y_V")]
    assert ("vision", "q_V") in named["-"]
    flat = [(t.key, s.name) for pairs in units.values() for t, s in pairs]
    assert sorted(flat) == sorted((t.key, s.name) for t in select("observation") for s in t.plot)
    assert topics.plot_series_by_unit("clock") == {}


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
