"""The graph's topics and services: one record each, in one registry (docs/ARCHITECTURE.md#topics).

Every tool that needs the graph's topic names, types or publishers reads them here instead of keeping
a list of its own: the nodes (the simulator's publishers, the policy node's inputs), the launcher's
``--namespace`` remapping (:func:`names`), the interface doc generator
(tools/gen_interfaces.py: the contract, rates, the driver's part), bag analysis (``dlo_bag.analysis``),
the driver checker, the Foxglove layout and the message tests. A consumer that needs a subset takes it
with :func:`select` (by role or publisher) rather than listing names.

A :class:`Topic` record:
    name        the topic, e.g. "/dlo/gripper/state" (``launch_graph.sh --namespace NS`` puts it under /NS)
    type        its message type, "pkg/msg/Name" (:func:`message_class` imports it)
    publisher   the node of the graph that publishes it (a robot driver takes sim_node's place)
    role        what it is to the graph, one of ``ROLES``
    description one line: what it carries
    key         a short name: the stream of bag analysis, the input of a node's stamp matching
    rate        "step" (one message per control step) or "latched" (once, transient-local)
    driver      what a robot driver that replaces sim_node does with it ("" = nothing; INTERFACES.md's
                driver table)
    sim_only    the simulator publishes it and a robot cannot (ground truth, simulator internals)
    plot        the values of its message that bag analysis plots over an episode (dlo_bag.analysis: one axis per
                unit) and the interface doc lists when it has no hand-written line: one :class:`Series` each

Plain data and the standard library only (no rclpy, no message imports until :func:`message_class`).
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass

ROLES = {
    "clock": "simulation time",
    "state": "the gripper's state of a control step: every node reacts to it",
    "sensor": "raw sensor data that a perception node distils (a robot driver publishes it)",
    "observation": "a distilled modality reading the policy observes (dlo_policy.modalities)",
    "command": "the policy's answer to a control step",
    "task": "the task's ground truth: held particles, reward, outcome",
    "visualisation": "for viewers only",
    "internal": "the simulator's own bookkeeping",
    "provenance": "what drives the run (the policy and what it was trained under): recorded in bags, for their readers",
}
RATES = ("step", "latched")


@dataclass(frozen=True)
class Series:
    """One value of a topic's message, plotted over an episode by bag analysis (``dlo_bag.episode_series``)."""

    field: str  # the message's field, dotted for a nested one ("wrench.force.x")
    name: str  # the series' name: the symbol of the paper or of the observation entry it becomes ("theta_T")
    unit: str  # its SI unit ("rad", "m", "N"; "-" for none): the plots put the series of one unit on one axis


@dataclass(frozen=True)
class Topic:
    """One topic of the graph (module docstring)."""

    name: str
    type: str
    publisher: str
    role: str
    description: str
    key: str
    rate: str = "step"
    driver: str = ""
    sim_only: bool = False
    plot: tuple = ()  # (Series, ...)

    def __post_init__(self):
        if self.role not in ROLES or self.rate not in RATES:
            raise ValueError(f"{self.name}: role must be one of {sorted(ROLES)} and rate one of {RATES}")
        if not all(isinstance(series, Series) for series in self.plot):
            raise ValueError(f"{self.name}: plot must be Series records")


@dataclass(frozen=True)
class Service:
    """One service of the graph."""

    name: str
    type: str
    server: str
    description: str


TOPICS = (
    Topic(
        "/clock",
        "rosgraph_msgs/msg/Clock",
        "sim_node",
        "clock",
        "simulation time of the state just published",
        key="clock",
        sim_only=True,
    ),
    Topic(
        "/dlo/rope/particles",
        "sensor_msgs/msg/PointCloud2",
        "sim_node",
        "sensor",
        "the cable's particles (x, y, z, held): tactile_node's input; a driver's tactile contact points",
        key="particles",
        driver="publishes contact points, **or** `/dlo/tactile/pose`",
        sim_only=True,
    ),
    Topic(
        "/dlo/gripper/state",
        "dlo_msgs/msg/GripperState",
        "sim_node",
        "state",
        "gripper position and closure, episode and step",
        key="gripper",
        driver="publishes",
    ),
    Topic(
        "/dlo/camera/image",
        "sensor_msgs/msg/Image",
        "sim_node",
        "sensor",
        "the top camera's segmented image: vision_node's input",
        key="image",
        driver="publishes (or publishes `/dlo/vision/pose`)",
    ),
    Topic(
        "/dlo/camera/camera_info",
        "sensor_msgs/msg/CameraInfo",
        "sim_node",
        "sensor",
        "the top camera's intrinsics",
        key="camera_info",
        rate="latched",
        driver="publishes",
    ),
    Topic(
        "/dlo/tactile/pose",
        "dlo_msgs/msg/TactilePose",
        "tactile_node",
        "observation",
        "O_T: the held cable's angle and offset in the gripper frame",
        key="tactile",
        driver="publishes, **or** `/dlo/rope/particles` contact points",
        plot=(Series("angle", "theta_T", "rad"), Series("y", "y_T", "m")),
    ),
    Topic(
        "/dlo/vision/pose",
        "dlo_msgs/msg/VisualPose",
        "vision_node",
        "observation",
        "O_V: the cable just right of the gripper, seen by the top camera",
        key="vision",
        plot=(Series("confidence", "q_V", "-"), Series("angle", "theta_V", "rad"), Series("y", "y_V", "m")),
    ),
    Topic(
        "/dlo/gripper/cmd",
        "dlo_msgs/msg/GripperCommand",
        "policy_node",
        "command",
        "velocity and closure answering one state",
        key="command",
        driver="subscribes (as `sim_node` does)",
    ),
    Topic(
        "/dlo/task/state",
        "dlo_msgs/msg/TaskState",
        "sim_node",
        "task",
        "held particles, reward, episode end and outcome under both rules",
        key="task",
        sim_only=True,
    ),
    Topic(
        "/dlo/markers",
        "visualization_msgs/msg/MarkerArray",
        "sim_node",
        "visualisation",
        "the cable line and the two fingers",
        key="markers",
        sim_only=True,
    ),
    Topic(
        "/dlo/sim/instance",
        "std_msgs/msg/String",
        "sim_node",
        "internal",
        "which simulator runs on this domain (two simulators: the later one leaves)",
        key="instance",
        rate="latched",
        sim_only=True,
    ),
    Topic(
        "/dlo/policy/info",
        "std_msgs/msg/String",
        "policy_node",
        "provenance",
        "which policy drives the graph (JSON: policy, checkpoint and its sha256, modalities, the task rules, grip "
        "and env_options it was trained under): dlo-analyze and its video titles read it from the bag",
        key="policy_info",
        rate="latched",
    ),
)
SERVICES = (Service("/dlo/sim/reset", "dlo_msgs/srv/ResetEpisode", "sim_node", "start a new episode (with a seed)"),)

_BY_KEY = {t.key: t for t in TOPICS}
_BY_NAME = {t.name: t for t in TOPICS}
assert len(_BY_KEY) == len(_BY_NAME) == len(TOPICS), "topic keys and names must be unique"


def topic(key_or_name: str) -> Topic:
    """The record of a topic by its key ("gripper") or name ("/dlo/gripper/state"); KeyError otherwise."""
    found = _BY_KEY.get(key_or_name) or _BY_NAME.get(key_or_name)
    if found is None:
        raise KeyError(f"no topic {key_or_name!r} in dlo_common.topics (keys: {', '.join(_BY_KEY)})")
    return found


def select(*roles: str, publisher: str | None = None, exclude: tuple = ()) -> tuple:
    """The topics with one of ``roles`` (all when none is given), of ``publisher`` if given, without the
    roles in ``exclude``, in registry order."""
    for role in roles + tuple(exclude):
        if role not in ROLES:
            raise ValueError(f"unknown role {role!r}; roles: {', '.join(ROLES)}")
    return tuple(
        t
        for t in TOPICS
        if (not roles or t.role in roles) and t.role not in exclude and (publisher is None or t.publisher == publisher)
    )


def plot_series_by_unit(*roles: str) -> dict:
    """{unit: [(topic, series)]} of the ``plot`` series of the topics with one of ``roles`` (:func:`select`), units
    and series in registry order: what the episode plots, the video strip and the Foxglove layout draw, one axis,
    row or panel per unit."""
    units: dict = {}
    for t in select(*roles):
        for series in t.plot:
            units.setdefault(series.unit, []).append((t, series))
    return units


def names() -> tuple:
    """Every topic and service name of the graph (what ``launch_graph.sh --namespace`` remaps)."""
    return tuple(t.name for t in TOPICS) + tuple(s.name for s in SERVICES)


def message_class(msgtype: str) -> type:
    """The generated Python class of ``pkg/msg/Name`` (e.g. ``sensor_msgs/msg/Image``; ``pkg/srv/Name`` too).

    (rosidl_runtime_py.utilities.get_message is not in the Jazzy wheels; this is what it does.)
    """
    parts = msgtype.split("/")
    if len(parts) == 2:
        parts = [parts[0], "msg", parts[1]]
    if len(parts) != 3 or not all(parts):
        raise ValueError(f"'{msgtype}' is not a ROS 2 type name like 'pkg/msg/Name'")
    pkg, kind, name = parts
    try:
        module = importlib.import_module(f"{pkg}.{kind}")
    except ImportError as err:
        raise ValueError(
            f"cannot import message package '{pkg}.{kind}' for '{msgtype}': "
            f"{err} (is it built and on PYTHONPATH? 'source scripts/env.sh')"
        ) from err
    try:
        return getattr(module, name)
    except AttributeError:
        raise ValueError(f"'{pkg}.{kind}' has no type '{name}'") from None
