"""The graph's options: read from the launcher's command line (``scripts/launch_graph.sh --episodes 3 ...``) or
from a launch file's arguments (``ros2 launch dlo_bringup graph.launch.py episodes:=3``), checked, and resolved
into :class:`GraphOptions` (the settings of the sim the ``--policy sac`` checkpoint was trained under filled in).

Both ways in go through :func:`parse_args` and :func:`resolve`: a launch argument ``name:=value`` is the option
``--name value`` (:func:`argv_from_launch_arguments`). A bad option is a :class:`UsageError`, one line.

No message package at import (``--help`` and a bad option work before the workspace is built): the option values
come from their homes (the simulator's, the task's, the vision sources, the modality registry); the library
checks (tactile noise, modalities, the checkpoint's run) are imported by :func:`resolve`.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field, replace

from dlo_interface import perturbations
from dlo_interface.grip import CARRY_LAWS
from dlo_interface.sim_config import MAX_CONTACT_RADIUS, SimConfig
from dlo_interface.task import AUTHORS_MOVE_SPACING, DEFAULT_MOVE_SPACING, DEFAULT_TASK_RULES, MAX_MOVE_SPACING, TASK_RULES
from dlo_interface.world import START_POSES
from dlo_perception.vision_source import DEFAULT_VISION_SOURCE, VISION_SOURCES
from dlo_policy.modalities import names as modality_names  # the registry: --without's help

HELP_HINT = "(options: scripts/launch_graph.sh --help)"
FOXGLOVE_PORT = 8765  # --foxglove without a port
# (name, metavar, default, help); default None: not a plain value (see parse_args). LAUNCH: a launch argument too.
OPTIONS = (
    ("episodes", "N", "5", "episodes to run (default 5; 0 = until Ctrl-C)"),
    ("seed", "S", "0", "episode k uses seed S + k (default 0)"),
    ("mode", "MODE", "step_locked", "step_locked (default, deterministic) or real_time"),
    ("rate-factor", "F", "1.0", "real_time: simulation speed relative to wall time (default 1.0)"),
    ("policy", "P", "sac", "sac (default: the shipped All policy), tactile_reactive, oracle or random"),
    (
        "checkpoint",
        "PATH",
        "",
        "policy file for --policy sac, or shipped:NAME, a shipped policy (default: shipped, the shipped All policy)",
    ),
    (
        "without",
        "M",
        "",
        f"test-time ablation: zero modality M for the policy ({', '.join(modality_names()[:-1])} or {modality_names()[-1]}; "
        "several joined by '+', e.g. T+V)",
    ),
    ("train-out", "DIR", "", "learn online (SAC) while running; checkpoints and policy.pt go to DIR"),
    ("train-config", "YAML", "", "online training: dlo-train config file (SAC hyperparameters)"),
    (
        "tactile-noise",
        "N",
        "none",
        "tactile noise (the tactile node's tactile_noise parameter): none (default), "
        "partial, full, or sigma_theta,sigma_y [rad, m] such as 0.1,0.001 (or [0.1,0.001])",
    ),
    (
        "perturbations",
        "P",
        "",
        "robustness perturbations, each off by default (python -m dlo_policy.perturbations lists them): name=value "
        "pairs joined by ',', e.g. friction=0.6,observation_delay=1 (as the gym env's option); the sim node applies "
        "the physics and camera families, the policy node the observation and action families (each its "
        "perturbations parameter)",
    ),
    (
        "task-rules",
        "R",
        "",
        "authors_code or paper_text: the held set the reward, the episode's end and the tactile "
        "input use (the sim's task_rules parameter). Default: what the --policy sac checkpoint "
        "was trained on (its run's config.yaml), else authors_code",
    ),
    (
        "single-particle-grip",
        "[true|false]",
        "",
        "the grip carries one particle, as the authors' code did (the sim's "
        "single_particle_grip parameter; alone = true). Default: what the "
        "--policy sac checkpoint was trained on "
        "(env_options.single_particle_grip), else false.",
    ),
    ("carry-law", "L", "", "paper or authors: how the grip carries the cable (the sim's carry_law parameter)"),
    ("contact-radius", "R", "", "the cable's contact half-thickness [m], up to 0.006 (the sim's contact_radius)"),
    ("vision-source", "S", "", "image or particles: where the vision node's O_V comes from (its vision_source)"),
    (
        "start-pose",
        "P",
        "",
        "ours or authors: where the gripper starts (the sim's start_pose)",
    ),
    (
        "move-spacing",
        "M",
        "",
        f"the move reward's particle spacing [m], up to {MAX_MOVE_SPACING}: 0 = the cable's own, "
        f"{AUTHORS_MOVE_SPACING} = the authors' (the sim's move_spacing). These five default to what the --policy sac "
        "checkpoint was trained on (its env_options), else paper, 0.004, image, ours and 0. Settings that differ "
        "from the checkpoint's training are run as asked, with a note",
    ),
    ("record", "DIR", "", "record every /dlo topic to the rosbag2 (MCAP) directory DIR"),
    (
        "foxglove",
        "[PORT]",
        "",
        f"live view: also start the Foxglove bridge (dlo_viz foxglove_bridge) on "
        f"127.0.0.1:PORT (default {FOXGLOVE_PORT}; 0 = any free port) and print the URL to "
        "open; layout to import: docs/foxglove/dlo_vitac.json",
    ),
    (
        "logs",
        "DIR",
        "",
        "node logs and the outcome file go here, and stay (default: a new temp dir, removed at the end unless the run failed)",
    ),
    (
        "composed",
        "[true|false]",
        "",
        "every node in one process on one executor (ROS 2 composition, dlo_bringup.composed; alone = true): the "
        "same nodes, parameters, lines, exit codes and bag, the same episodes step for step, without a process "
        "and a DDS hop per node (faster: python benchmarks/run.py composed)",
    ),
    ("status-period", "S", "10", "seconds between status lines while the graph runs (default 10; 0 = none)"),
    (
        "domain-id",
        "N",
        "",
        "run on ROS_DOMAIN_ID N (default: a free domain of its own, so that two graphs on one "
        "machine never see each other; the chosen id is printed)",
    ),
    (
        "namespace",
        "NS",
        "",
        "put every topic of the graph under /NS (/NS/dlo/..., /NS/clock): several graphs can "
        "then share a domain deliberately (with --domain-id)",
    ),
)
# ros2 launch: ROS_DOMAIN_ID from the environment, its own output, a process per node
LAUNCHER_ONLY = ("composed", "status-period", "domain-id")
OPTIONAL_VALUE = {
    "single-particle-grip": (re.compile(r"(true|false)"), "true"),  # alone: this value
    "foxglove": (re.compile(r"[0-9]+"), str(FOXGLOVE_PORT)),
    "composed": (re.compile(r"(true|false)"), "true"),
}
POLICIES = ("sac", "tactile_reactive", "oracle", "random")


class UsageError(Exception):
    """A bad option: its one-line reason (the launcher prints ``launch_graph: <reason>``, exit 2)."""


@dataclass
class GraphOptions:
    """The options of one graph, as given (strings, "" = not given) until :func:`resolve` fills in the rest."""

    episodes: str = "5"
    seed: str = "0"
    mode: str = "step_locked"
    rate_factor: str = "1.0"
    policy: str = "sac"
    checkpoint: str = ""
    without: str = ""
    train_out: str = ""
    train_config: str = ""
    tactile_noise: str = "none"  # resolved: the node's -p form (dlo_perception.tactile.noise_parameter_value)
    perturbations: str = ""  # checked: dlo_interface.perturbations.parse; split between the nodes by graph.py
    task_rules: str = ""
    single_particle_grip: str = ""  # "true" / "false"
    carry_law: str = ""
    contact_radius: str = ""
    vision_source: str = ""
    start_pose: str = ""
    move_spacing: str = ""
    record: str = ""
    foxglove: str = ""  # "" = no bridge, else its port
    logs: str = ""
    composed: str = ""  # "true": every node in one process
    status_period: str = "10"
    domain_id: str = ""
    namespace: str = ""  # without slashes at either end
    help: bool = False
    notes: list = field(default_factory=list)  # resolve: settings that differ from the checkpoint's training

    @property
    def prefix(self) -> str:
        """What every topic name of the graph is put under: "" or "/NS"."""
        return f"/{self.namespace}" if self.namespace else ""


def parse_args(argv) -> GraphOptions:
    """The command line as given, each option checked on its own (in the order and words of the launcher's
    --help); UsageError for the first bad one. ``-h``/``--help`` sets ``help`` and ends the parse."""
    given = {}
    args = list(argv)
    i = 0
    names = {name for name, *_ in OPTIONS}
    while i < len(args):
        arg = args[i]
        if arg in ("-h", "--help"):
            return GraphOptions(help=True)
        name = arg[2:] if arg.startswith("--") else None
        if name not in names:
            raise UsageError(f"unknown option '{arg}' {HELP_HINT}")
        if name in OPTIONAL_VALUE:
            pattern, alone = OPTIONAL_VALUE[name]
            if i + 1 < len(args) and pattern.fullmatch(args[i + 1]):
                given[name], i = args[i + 1], i + 2
            else:
                given[name], i = alone, i + 1
            continue
        if i + 1 >= len(args):
            raise UsageError(f"{arg} needs a value {HELP_HINT}")
        given[name], i = args[i + 1], i + 2
    options = GraphOptions(**{name.replace("-", "_"): value for name, value in given.items()})
    check(options)
    return options


def _one_of(option: str, value: str, allowed) -> None:
    if value and value not in allowed:
        raise UsageError(f"--{option} must be {' or '.join(allowed)}, got '{value}'")


def check(o: GraphOptions) -> None:
    """Each option on its own: UsageError for the first bad one (nothing read from disk but whether a
    --checkpoint file and a --record directory exist)."""
    if not re.fullmatch(r"[0-9]+", o.episodes):
        raise UsageError(f"--episodes must be a number >= 0, got '{o.episodes}'")
    if not re.fullmatch(r"[0-9]+", o.seed):
        raise UsageError(f"--seed must be a number >= 0, got '{o.seed}'")
    if o.mode not in ("step_locked", "real_time"):
        raise UsageError("--mode must be step_locked or real_time")
    _one_of("task-rules", o.task_rules, TASK_RULES)
    _one_of("carry-law", o.carry_law, CARRY_LAWS)
    _one_of("start-pose", o.start_pose, tuple(START_POSES))
    _one_of("vision-source", o.vision_source, VISION_SOURCES)
    if o.contact_radius and not (
        re.fullmatch(r"[0-9]*[.]?[0-9]+", o.contact_radius) and 0 < float(o.contact_radius) <= MAX_CONTACT_RADIUS
    ):
        raise UsageError(f"--contact-radius must be a number in (0, {MAX_CONTACT_RADIUS}] m, got '{o.contact_radius}'")
    if o.move_spacing and not (re.fullmatch(r"[0-9]*[.]?[0-9]+", o.move_spacing) and float(o.move_spacing) <= MAX_MOVE_SPACING):
        raise UsageError(
            f"--move-spacing must be a number in [0, {MAX_MOVE_SPACING}] m (0: the cable's own spacing), got '{o.move_spacing}'"
        )
    if o.perturbations:
        try:
            perturbations.parse(o.perturbations)
        except ValueError as error:
            raise UsageError(f"--perturbations: {error}") from None
    if o.policy not in POLICIES:
        raise UsageError(f"--policy must be one of {', '.join(POLICIES)}, got '{o.policy}'")
    if o.checkpoint and not checkpoint_file(o.checkpoint).is_file():
        raise UsageError(f"--checkpoint {o.checkpoint}: no such file")
    if not re.fullmatch(r"[0-9]+([.][0-9]+)?", o.status_period):
        raise UsageError(f"--status-period must be a number of seconds >= 0, got '{o.status_period}'")
    if o.domain_id and not (re.fullmatch(r"[0-9]+", o.domain_id) and int(o.domain_id) <= 232):
        raise UsageError(f"--domain-id must be a number in 0..232, got '{o.domain_id}'")
    o.namespace = o.namespace[1:] if o.namespace.startswith("/") else o.namespace  # one slash at either end
    o.namespace = o.namespace[:-1] if o.namespace.endswith("/") else o.namespace
    if o.namespace and not re.fullmatch(r"[A-Za-z][A-Za-z0-9_]*(/[A-Za-z][A-Za-z0-9_]*)*", o.namespace):
        raise UsageError(f"--namespace must be a ROS name like 'robot1' or 'lab/robot1', got '{o.namespace}'")
    if o.foxglove and int(o.foxglove) > 65535:
        raise UsageError(f"--foxglove PORT must be in 0..65535, got '{o.foxglove}'")
    if o.record and os.path.exists(o.record):
        raise UsageError(f"--record {o.record} already exists; choose a new directory")


def resolve(o: GraphOptions) -> GraphOptions:
    """The options with what they leave open filled in: the tactile noise in its ``-p`` form, --without checked,
    and with --policy sac (not learning online) the sim settings the checkpoint was trained under, where not
    given (a given one that differs from its training is kept, with a line in ``notes``); then the defaults
    (authors_code, finite grip, paper, 0.004, image, ours, 0). UsageError when one is bad or the checkpoint's run
    cannot be read."""
    from dlo_perception.tactile import noise_parameter_value

    o = replace(o, notes=[])
    try:
        o.tactile_noise = noise_parameter_value(o.tactile_noise)
    except ValueError as error:
        raise UsageError(f"--tactile-noise: {error}") from None
    if o.without:
        from dlo_policy.modalities import without_problem

        problem = without_problem(o.without)
        if problem:
            raise UsageError(problem)
    if o.policy == "sac" and not o.train_out:
        trained = trained_settings(o.checkpoint)
        if trained is not None:
            _fill_in_from_training(o, trained)
    # the defaults are the simulator's and the vision node's own (one home each)
    o.task_rules = o.task_rules or DEFAULT_TASK_RULES
    o.single_particle_grip = o.single_particle_grip or str(SimConfig.single_particle_grip).lower()
    o.carry_law = o.carry_law or SimConfig.carry_law
    o.contact_radius = o.contact_radius or str(SimConfig.contact_radius)
    o.vision_source = o.vision_source or DEFAULT_VISION_SOURCE
    o.start_pose = o.start_pose or SimConfig.start_pose
    o.move_spacing = o.move_spacing or str(DEFAULT_MOVE_SPACING)
    return o


def checkpoint_file(checkpoint: str):
    """The policy file ``--checkpoint`` names (a path; ``shipped``, ``shipped:NAME`` or ``""``: a shipped policy,
    dlo_policy.rundir.checkpoint_path); UsageError naming the shipped policies for an unknown shipped name."""
    from dlo_policy.rundir import checkpoint_path

    try:
        return checkpoint_path(checkpoint)
    except ValueError as error:
        raise UsageError(f"--checkpoint: {error}") from None


def trained_settings(checkpoint: str) -> dict | None:
    """The sim settings the policy file (a path, or ``shipped:NAME``; ``""``: the shipped policy) was trained under,
    as option text (``{"task_rules": "authors_code", "single_particle_grip": "true", "contact_radius": "0.004", ...}``); None when
    no config.yaml is beside it. UsageError when the file or its run's config.yaml cannot be read."""
    from dlo_policy.config import ConfigError
    from dlo_policy.rundir import CONFIG_FILE, trained_sim_settings

    path = checkpoint_file(checkpoint)
    if not path.is_file():
        raise UsageError(f"--checkpoint: checkpoint {path}: no such file")
    try:
        settings = trained_sim_settings(path)
    except (ConfigError, OSError) as error:
        raise UsageError(f"--checkpoint: checkpoint {path}: its run's {CONFIG_FILE} cannot be read: {error}") from None
    if settings is None:
        return None
    return {key: ("true" if value else "false") if isinstance(value, bool) else str(value) for key, value in settings.items()}


def _fill_in_from_training(o: GraphOptions, trained: dict) -> None:
    asked = {key: getattr(o, key) for key in trained}
    for key, value in trained.items():
        setattr(o, key, asked[key] or value)

    def differs(key):
        if key in ("contact_radius", "move_spacing"):  # numbers: 0.0040 is 0.004
            return float(getattr(o, key)) != float(trained[key])
        return getattr(o, key) != trained[key]

    levers = ("carry_law", "contact_radius", "vision_source", "start_pose", "move_spacing")
    if any(differs(key) for key in levers):
        o.notes.append(
            "the policy was trained with "
            + ", ".join(f"{k}={trained[k]}" for k in levers)
            + "; this graph runs "
            + ", ".join(f"{k}={getattr(o, k)}" for k in levers)
            + " (as asked)"
        )
    task = ("task_rules", "single_particle_grip")
    if any(differs(key) for key in task):
        o.notes.append(
            "the policy was trained with "
            + ", ".join(f"{k}={trained[k]}" for k in task)
            + "; this graph runs "
            + ", ".join(f"{k}={getattr(o, k)}" for k in task)
            + " (as asked)"
        )


def launch_arguments() -> list[tuple[str, str, str]]:
    """(name, default, description) of every launch argument of graph.launch.py: the options but the
    launcher's own (--status-period, --domain-id), with underscores (``task_rules:=paper_text``)."""
    return [
        (name.replace("-", "_"), "" if name in OPTIONAL_VALUE else default, text)
        for name, _, default, text in OPTIONS
        if name not in LAUNCHER_ONLY
    ]


def argv_from_launch_arguments(values: dict) -> list[str]:
    """The launcher's command line that asks for what the launch arguments ``values`` ask for (an empty value:
    the option not given)."""
    argv = []
    for name, default, _ in launch_arguments():
        value = str(values.get(name, default))
        if value != "":
            argv += [f"--{name.replace('_', '-')}", value]
    return argv
