"""The one description of the dlo-vitac graph: which nodes run, with which parameters and remappings, in which
order, for given options. The launcher (:mod:`dlo_bringup.launcher`, ``scripts/launch_graph.sh``) starts these
processes; the launch file (``launch/graph.launch.py``, ``ros2 launch dlo_bringup graph.launch.py``) turns the
same records into ``launch_ros.actions.Node`` entries. Change the graph here, and both follow.

Standard library and pure-Python dlo packages only (the launch file imports it on a real ROS 2 install, the launcher
before anything runs).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from decimal import Decimal
from pathlib import Path

from dlo_bringup.options import GraphOptions

SIM_READY = "alone on ROS_DOMAIN_ID"  # the sim's line once it has looked for another simulator on its domain
FOXGLOVE_READY = "Foxglove bridge on ws://"  # the bridge's line once it listens
OUTCOMES_FILE = "outcomes.jsonl"  # in the logs directory: the sim's per-episode lines (its summary_file)
RECORDER_SUMMARY_FILE = "recorder_summary.json"  # in the logs directory: the recorder's counts (its summary_file)
# s a node may take to stop after SIGINT before it is killed: its own closing work (the recorder drains and closes
# its bag, an online policy saves its run), then its middleware teardown, which dlo_common.node_main cuts after
# TEARDOWN_LIMIT (10 s: the node then exits 1 on its own, its work done). Longer than both.
STOP_LIMIT = 30.0


@dataclass(frozen=True)
class NodeSpec:
    """One node process of the graph.

    ``name``: the launcher's name for it (its log is ``<name>.log``); ``parameters``: ``(name, value)`` in order,
    values typed as the node reads them (bool, int, float, str, list of float); ``remappings``: ``(from, to)``;
    ``ready_line``: the line it prints once it is ready; the launcher waits for it before it starts the nodes after
    it (the sim: once it found itself alone on the domain; the Foxglove bridge: its URL, printed first), the launch
    file for the sim's. ``plugin``: ``module:Class``, the class the executable runs, which builds the node in a process
    of its own or, given ``cli_args`` (these ``ros_args()``), next to the others in one (``--composed``,
    :mod:`dlo_bringup.composed`)."""

    name: str
    package: str
    executable: str
    parameters: tuple = ()
    remappings: tuple = ()
    ready_line: str = ""
    plugin: str = ""

    def to_dict(self) -> dict:
        """The record as JSON values (``--composed`` hands the graph to its process so)."""
        return {field.name: getattr(self, field.name) for field in fields(self)}

    @classmethod
    def from_dict(cls, values: dict) -> NodeSpec:
        """The record :meth:`to_dict` gave, read back from JSON (lists become tuples, list values stay lists)."""
        values = dict(values)
        values["parameters"] = tuple((name, value) for name, value in values.get("parameters", ()))
        values["remappings"] = tuple((source, target) for source, target in values.get("remappings", ()))
        return cls(**values)

    def ros_args(self) -> list[str]:
        """Its command-line arguments: ``--ros-args -p name:=value ... -r from:=to ...``."""
        args = ["--ros-args"]
        for name, value in self.parameters:
            args += ["-p", f"{name}:={ros_value(value)}"]
        for source, target in self.remappings:
            args += ["-r", f"{source}:={target}"]
        return args


def ros_value(value) -> str:
    """A parameter value as ``-p name:=<this>`` writes it (YAML): true/false, 3, 0.004 (a float always with a
    decimal point, never an exponent, which YAML would read as a string), [0.1,0.001], text as it is."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        text = format(Decimal(repr(value)), "f")
        return text if "." in text else text + ".0"
    if isinstance(value, (list, tuple)):
        return "[" + ",".join(ros_value(v) for v in value) + "]"
    return str(value)


def _number(text: str):
    """A number given as text (``--rate-factor 2``) as a float; text that is none as itself (the node refuses it
    in its own words)."""
    try:
        value = float(text)
    except ValueError:
        return text
    return value if math.isfinite(value) else text


def _tactile_noise(text: str):
    """The tactile node's ``tactile_noise``: a preset name, or the pair [sigma_theta, sigma_y] as floats."""
    if text.startswith("["):
        return [float(v) for v in text.strip("[]").split(",")]
    return text


def _perturbations(o: GraphOptions, owner: str) -> list:
    """The ``perturbations`` parameter of the node ``owner`` (a key of dlo_interface.perturbations.OWNERS): the
    families of --perturbations it applies, as text; none when it owns none of them."""
    if not o.perturbations:
        return []
    from dlo_interface import perturbations

    mine = perturbations.of_side(perturbations.parse(o.perturbations), *perturbations.OWNERS[owner])
    return [("perturbations", perturbations.text(mine))] if mine else []


def graph_nodes(o: GraphOptions, logs: Path | None = None) -> list[NodeSpec]:
    """The graph's nodes for the resolved options ``o`` (:func:`dlo_bringup.options.resolve`), in the order they
    start: the sim first (nothing else starts before it has found itself alone on the domain), then the recorder
    (``--record``), the Foxglove bridge (``--foxglove``), tactile, vision and policy. ``logs``: where the sim and
    the recorder write their summaries (None: nowhere)."""
    prefix = o.prefix
    remap = ()
    if prefix:
        from dlo_common.topics import names  # every topic and service of the graph

        remap = tuple((name, prefix + name) for name in names())
    seed = int(o.seed)
    sim = [
        ("mode", o.mode),
        ("seed", seed),
        ("episodes", int(o.episodes)),
        ("rate_factor", _number(o.rate_factor)),
        ("min_subscribers", 4 if o.record else 3),
    ]
    if logs is not None:
        sim.append(("summary_file", str(logs / OUTCOMES_FILE)))
    sim += [
        ("task_rules", o.task_rules),
        ("single_particle_grip", o.single_particle_grip == "true"),
        ("carry_law", o.carry_law),
        ("contact_radius", float(o.contact_radius)),
        ("start_pose", o.start_pose),
        ("move_spacing", float(o.move_spacing)),
    ]
    sim += _perturbations(o, "simulator")
    if o.record:
        sim.append(("wait_for_recorder", "recorder"))  # the first episode is recorded whole
    nodes = [NodeSpec("sim", "dlo_sim", "sim_node", tuple(sim), remap, SIM_READY, "dlo_sim.sim_node:SimNode")]
    if o.record:
        recorder = [("output", o.record)]
        recorder.append(("namespace", prefix) if prefix else ("record_clock", True))
        if logs is not None:
            recorder.append(("summary_file", str(logs / RECORDER_SUMMARY_FILE)))
        nodes.append(
            NodeSpec("recorder", "dlo_bag", "recorder_node", tuple(recorder), remap, plugin="dlo_bag.recorder_node:RecorderNode")
        )
    if o.foxglove:
        nodes.append(
            NodeSpec(
                "foxglove",
                "dlo_viz",
                "foxglove_bridge",
                (("port", int(o.foxglove)), ("address", "127.0.0.1"), ("topics", f"{prefix}/dlo,{prefix}/clock")),
                ready_line=FOXGLOVE_READY,
                plugin="dlo_viz.foxglove_bridge_node:FoxgloveBridgeNode",
            )
        )
    nodes.append(
        NodeSpec(
            "tactile",
            "dlo_perception",
            "tactile_node",
            (("tactile_noise", _tactile_noise(o.tactile_noise)), ("seed", seed)),
            remap,
            plugin="dlo_perception.tactile_node:TactileNode",
        )
    )
    nodes.append(
        NodeSpec(
            "vision",
            "dlo_perception",
            "vision_node",
            (("vision_source", o.vision_source),),
            remap,
            plugin="dlo_perception.vision_node:VisionNode",
        )
    )
    policy = [("policy", o.policy)]
    if o.checkpoint:
        policy.append(("checkpoint", o.checkpoint))
    if o.without:
        policy.append(("without", o.without))
    if o.train_out:
        policy += [("train", True), ("train_out", o.train_out), ("seed", seed)]
    if o.train_config:
        policy.append(("train_config", o.train_config))
    policy += _perturbations(o, "policy node")
    nodes.append(
        NodeSpec("policy", "dlo_policy", "policy_node", tuple(policy), remap, plugin="dlo_policy.policy_node:PolicyNode")
    )
    return nodes
