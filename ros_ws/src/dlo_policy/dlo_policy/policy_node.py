"""policy_node: K/T/V of one control step (matched by stamp) -> /dlo/gripper/cmd answering that step.

``policy``: ``sac`` (a checkpoint or shipped policy from dlo-train, deterministic actions),
``tactile_reactive`` (the classical baseline, observations only), ``oracle`` (ground truth from
``/dlo/rope/particles``: simulation only) or ``random``. With ``train:=true`` the node learns
online from the graph's steps (``dlo_policy.online``: same SAC and checkpoints as dlo-train), its
reward and episode ends taken from ``/dlo/task/state``. The observation is
assembled by ``dlo_policy.observation.build_observation``, exactly as in the gym environment: the node
subscribes to the topic of each observed modality and converts its message with the modality's record
(``dlo_policy.modalities``; topics and types from ``dlo_common.topics``).
Inputs that a step does not deliver within ``input_timeout`` s are reported as an error naming the
missing topic; the sim node then republishes the step, so nothing deadlocks.

``perturbations`` (off by default): the observation and action families of ``dlo_policy.perturbations``
(``observation_delay=1,vision_angle_noise=5,action_delay=1``), applied by the same ``Perturber`` as the gym env's
option ``perturbations``: over the observation before the policy acts, over its action before the command. Their noise
comes from the episode's seed, which the node then reads from ``/dlo/task/state``, so the graph's episodes equal the
env's. Physics and camera families belong to the simulator and are refused here.

A policy trained with the env option ``previous_action`` (its checkpoint's observation is 3 longer) gets its own
previous action appended to the observation, after the observation perturbations and before the action ones, zeros at
an episode's first step: ``dlo_policy.observation.PreviousAction``, as in the gym env.

At start it publishes what drives the graph once, latched, on ``/dlo/policy/info`` (std_msgs/String, JSON:
:func:`policy_record`): the policy, its checkpoint file and that file's sha256, the modalities observed and
ablated, and from the checkpoint's run config the task rules, grip and env_options it was trained under. The
recorder keeps it in the bag; ``dlo-analyze`` and its video titles read it.
"""

from __future__ import annotations

import hashlib
import json
import time
from pathlib import Path

import numpy as np
from dlo_common.node_util import ParameterError, declare_parameters
from dlo_common.params import Param
from dlo_common.topics import message_class, topic
from dlo_interface.cloud import unpack_particles
from dlo_interface.command import action_to_command
from dlo_interface.task import recorded_task_rules
from dlo_msgs.msg import GripperCommand
from dlo_perception.sync import IncompleteSteps, StampSync, stamp_to_ns
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile
from std_msgs.msg import String

from dlo_policy import perturbations
from dlo_policy.modalities import ALL, ALL_NAME, by_name, names
from dlo_policy.observation import (
    PreviousAction,
    build_observation,
    observation_size,
    parse_modalities,
    takes_previous_action,
)
from dlo_policy.rundir import (  # noqa: F401 (SHIPPED_POLICY, shipped_policy_path: re-exported)
    CONFIG_FILE,
    SHIPPED_POLICY,
    checkpoint_path,
    read_trained_config,
    shipped_name,
    shipped_policy_path,
)

POLICIES = ("sac", "tactile_reactive", "oracle", "random")


def node_perturbations(value) -> dict:
    """The ``perturbations`` parameter (text, dlo_policy.perturbations.parse): the observation and action families
    the node applies; ValueError in one line for anything else, physics and camera families included (the sim
    node's)."""
    return perturbations.owned(value, "policy node")


PARAMETERS = (
    Param("policy", "sac", f"controller, one of {POLICIES}", choices=POLICIES),
    Param(
        "checkpoint",
        "",
        "dlo-train policy.pt / checkpoint.pt, or shipped:NAME (a shipped policy; empty or shipped = the shipped All policy)",
    ),
    Param("modalities", "All", "observation modalities for policy=random (sac uses its training config)"),
    Param("without", "", "test-time ablation: zero these modalities, e.g. 'T' or 'V'"),
    Param("input_timeout", 1.0, "report an error when a step's inputs are incomplete after this long [s]", above=0.0),
    Param("seed", 0, "seed of the random policy and of online training", at_least=0),
    Param("train", False, "learn online from the graph (policy sac): SAC from scratch or from train_out"),
    Param("train_out", "runs/online", "run directory of online training (config, checkpoint.pt, policy.pt)"),
    Param("checkpoint_every", 1000, "online training: control steps between checkpoints", at_least=1),
    Param(
        "train_config",
        "",
        "online training: a dlo-train YAML config (SAC hyperparameters; env_options.previous_action adds the previous "
        "action to the observation); empty = defaults",
    ),
    Param(
        "perturbations",
        "",
        "observation and action perturbations (dlo_policy.perturbations), e.g. "
        "'observation_delay=1,action_delay=1'; empty = none",
        check=node_perturbations,
        types="string",
        accepts="name=value pairs of observation and action families joined by ','",
    ),
)


def modalities_parameter(name: str, value: str) -> tuple:
    """``parse_modalities(value)``, or a ParameterError naming the parameter and what it takes."""
    try:
        return parse_modalities(value)
    except ValueError:
        known = ", ".join(names())
        takes = (
            f"'' (none) or the modalities to zero: {known} or several joined by '+', e.g. T or T+V"
            if name == "without"
            else f"{ALL_NAME} or a '+'-joined subset of {known}, e.g. V+K"
        )
        raise ParameterError(f"parameter '{name}': expected {takes}, got {value!r}") from None


class GroundTruthView:
    """One step's particle cloud and gripper state, shaped like the env's simulator for OracleFollow."""

    def __init__(self):
        self.sim = self
        self.cloud = self.gripper = None

    def positions(self):
        return unpack_particles(self.cloud)[0][None]

    def held_mask(self):
        return unpack_particles(self.cloud)[1][None]

    @property
    def num_particles(self):
        return np.array([self.cloud.width])

    def gripper_state(self):
        g = self.gripper
        return np.array([[g.x, g.y, g.z, g.closure]], np.float32)


def load_policy(kind: str, checkpoint: str, modalities: str, seed: int):
    """-> (act(observation (1, D), new_episode, ground truth) -> action (1, 3), modalities actually used, whether the
    policy takes its previous action after them: env option ``previous_action``, D = their size + 3)."""
    if kind == "sac":
        from dlo_policy.evaluate import load_run_config
        from dlo_policy.sac import SAC, CheckpointError

        try:
            path = checkpoint_path(checkpoint)
        except ValueError as error:  # an unknown shipped name, with the shipped ones
            raise ParameterError(f"parameter 'checkpoint': {error}") from None
        if not path.exists():
            raise ParameterError(f"checkpoint {path} does not exist")
        try:
            agent = SAC.load(path)
        except CheckpointError as error:  # "not a dlo-vitac policy file: PATH (why)"
            raise ParameterError(f"parameter 'checkpoint': {error}") from None
        # the modalities the checkpoint stores; a checkpoint from before: its run's config.yaml ("All" = K+T+V)
        trained_on = agent.modalities or load_run_config(path).modalities
        try:
            previous_action = takes_previous_action(agent.obs_dim, trained_on)
        except ValueError as error:
            raise ParameterError(f"parameter 'checkpoint': {path} {error}") from None
        act = lambda obs, new_episode, truth: agent.predict(obs, deterministic=True).reshape(1, 3)  # noqa: E731
        return act, trained_on, previous_action
    if kind == "tactile_reactive":
        from dlo_policy.scripted import TactileReactive

        controller = TactileReactive()
        layout = type("ObservationLayout", (), {"modalities": ALL})()

        def act(obs, new_episode, truth):
            if new_episode:
                controller.reset()
            return controller(obs, layout)

        return act, ALL, False
    if kind == "oracle":
        from dlo_policy.scripted import OracleFollow

        oracle = OracleFollow()
        return (lambda obs, new_episode, truth: oracle(obs, truth)), modalities, False
    rng = np.random.default_rng(seed)
    return (lambda obs, new_episode, truth: rng.uniform(-1.0, 1.0, (1, 3)).astype(np.float32)), modalities, False


def file_sha256(path) -> str:
    """The sha256 of a file's bytes, hex."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def policy_record(
    kind: str,
    checkpoint: str,
    modalities,
    without=(),
    *,
    seed: int = 0,
    train: bool = False,
    train_out: str = "",
    train_config: str = "",
) -> dict:
    """What drives the graph, as ``/dlo/policy/info`` carries it (JSON): ``policy`` (its kind), ``checkpoint`` (the
    policy file's absolute path, None without one), ``sha256`` (of that file), ``shipped`` (whether the checkpoint
    spec names a shipped policy: empty, ``shipped`` or ``shipped:NAME``), ``modalities`` and ``without``
    ('+'-joined), and from the run config beside the file (or, learning online, the ``train_config``) ``task_rules``,
    ``single_particle_grip`` and every ``env_options`` entry it names (e.g. vision_source, carry_law, contact_radius),
    ``trained_label``; None where nothing says (a scripted policy: the sim's own task rules are in its TaskState). A
    config that cannot be read leaves them None and says why in ``config_error``."""
    record = {
        "policy": kind,
        "checkpoint": None,
        "sha256": None,
        "shipped": False,
        "modalities": "+".join(modalities),
        "without": "+".join(without),
        "task_rules": None,
        "single_particle_grip": None,
        "env_options": None,
        "trained_label": None,
    }
    config = None
    try:
        if train:
            from dlo_policy.config import load_config

            record["train_out"] = str(Path(train_out).resolve())
            config = load_config(train_config or None, values={"modalities": "+".join(modalities), "seed": seed})
        elif kind == "sac":
            path = checkpoint_path(checkpoint)
            record.update(checkpoint=str(path.resolve()), sha256=file_sha256(path), shipped=shipped_name(checkpoint) is not None)
            if (path.parent / CONFIG_FILE).exists():
                config = read_trained_config(path.parent)
    except (ValueError, OSError) as error:
        record["config_error"] = str(error)
    if kind == "random":
        record["seed"] = seed
    if config is not None:
        options = dict(config.env_options)
        record.update(
            task_rules=options.get("task_rules"),
            env_options=options,
            trained_label=config.name,
            single_particle_grip=bool(options.get("single_particle_grip", False)),
        )
    return record


class PolicyNode(Node):
    """Closes the loop: observations in, one gripper command per control step out."""

    def __init__(self, **options):
        super().__init__("policy_node", **options)
        p = declare_parameters(self, PARAMETERS)
        if p["train"] and p["policy"] != "sac":
            raise ParameterError("parameter 'train': online training needs policy:=sac")
        try:
            if p["train"]:
                self.act, modalities = None, p["modalities"]
                config = self.train_config(p)
                previous_action = config.env_options.get("previous_action", False)  # checked there
            else:
                self.act, modalities, previous_action = load_policy(p["policy"], p["checkpoint"], p["modalities"], p["seed"])
            # the policy's own previous action after the observation (env option previous_action; None: off)
            self.previous_action = PreviousAction(1) if previous_action else None
            self.modalities = modalities_parameter("modalities", modalities)
            self.without = modalities_parameter("without", p["without"]) if p["without"] else ()
            ablated_absent = [m for m in self.without if m not in self.modalities]
            if ablated_absent:
                raise ParameterError(
                    f"parameter 'without': cannot ablate {'+'.join(ablated_absent)}: the policy "
                    f"observes only {'+'.join(self.modalities)}"
                )
            self.observed = [by_name(m) for m in self.modalities if m not in self.without]
            self.observation({m.input_key: message_class(m.message_type)() for m in self.observed})  # it builds
            self.learner = self.make_learner(p, config) if p["train"] else None
        except (ValueError, OSError) as error:
            raise ParameterError(str(error)) from None
        self.input_timeout = p["input_timeout"]
        # the observation and action perturbations, as the gym env applies them (off: never called)
        self.perturber = perturbations.Perturber(p["perturbations"], self.modalities, self.without, 1)
        self.episode = None  # the episode of the last step answered: a step of another one starts a new episode
        # the gripper state (episode, step) always, then each observed modality's topic, the task state to learn
        # from, the particles for the oracle: input keys of dlo_common.topics
        inputs = list(dict.fromkeys(["gripper"] + [m.input_key for m in self.observed]))
        inputs += ["task"] if self.learner or self.perturber.active else []  # (the episode's seed: its noise)
        inputs += ["particles"] if p["policy"] == "oracle" else []
        self.truth = GroundTruthView()
        self.sync = StampSync(inputs)
        self.first_seen = {}  # stamp_ns -> wall time of its first input
        self.incomplete = IncompleteSteps(self.input_timeout, first_seen=self.first_seen)  # check_missing_inputs
        self.last = (None, None)  # (stamp_ns, GripperCommand): a republished step gets the same answer
        self.publisher = self.create_publisher(GripperCommand, topic("command").name, 10)
        # what drives the graph, once, latched: the recorder keeps it in the bag (dlo-analyze, video titles)
        self.record = policy_record(
            p["policy"],
            p["checkpoint"],
            self.modalities,
            self.without,
            seed=p["seed"],
            train=p["train"],
            train_out=p["train_out"],
            train_config=p["train_config"],
        )
        self.info_publisher = self.create_publisher(
            String, topic("policy_info").name, QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        )
        if self.perturber.active:
            self.record["perturbations"] = perturbations.text(self.perturber.setting)
        self.info_publisher.publish(String(data=json.dumps(self.record, sort_keys=True)))
        for key in inputs:
            t = topic(key)
            self.create_subscription(message_class(t.type), t.name, lambda m, key=key: self.on_input(key, m), 10)
        self.create_timer(0.25, self.check_missing_inputs)
        self.get_logger().info(
            f"policy {p['policy']} on {'+'.join(self.modalities)}"
            + (f" without {'+'.join(self.without)}" if self.without else "")
            + f"; inputs {inputs}"
            + (f"; perturbations {perturbations.text(self.perturber.setting)}" if self.perturber.active else "")
        )

    def on_input(self, key, msg):
        stamp = stamp_to_ns(msg.header.stamp)
        self.first_seen.setdefault(stamp, time.monotonic())
        matched = self.sync.add(key, stamp, msg)
        if matched is None:
            return
        self.first_seen.pop(stamp, None)
        if self.last[0] == stamp:  # the sim republished this step: answer it again, unchanged
            self.publisher.publish(self.last[1])
            return
        values = dict(zip(self.sync.keys, matched, strict=True))
        gripper = values["gripper"]
        new_episode = gripper.step == 0 or gripper.episode != self.episode  # (a missed step 0 too)
        self.episode = gripper.episode
        observation = self.observation(values)
        if self.perturber.active:
            if new_episode:  # its seed, its noise
                self.perturber.start([0], [values["task"].seed])
            observation = self.perturber.observe(observation)
        if self.previous_action is not None:
            if new_episode:
                self.previous_action.start()
            observation = self.previous_action.append(observation)
        if self.learner is not None:
            task = values["task"]
            terminated = task.done and bool(
                recorded_task_rules(task.task_rules).dropped(task.n_held, len(task.held_indices_authors))
            )
            action = self.learner.act(observation[0], task.reward, task.done, terminated, gripper.episode, gripper.step)
        else:
            self.truth.cloud, self.truth.gripper = values.get("particles"), gripper
            action = self.act(observation, new_episode, self.truth)[0]
        if self.previous_action is not None:
            self.previous_action.took(action)  # as the policy gave it (before the action perturbations)
        if self.perturber.active:
            action = self.perturber.act(np.asarray(action, np.float32)[None])[0]
        vx, vy, closure = action_to_command(action)
        command = GripperCommand(vx=vx, vy=vy, closure=closure, episode=gripper.episode, step=gripper.step)
        command.header = gripper.header
        self.last = (stamp, command)
        self.publisher.publish(command)

    def observation(self, messages: dict) -> np.ndarray:
        """(1, D) observation from one step's messages {input key: message}: each observed modality's
        ``from_message`` (dlo_policy.modalities), assembled by build_observation as in the gym env."""
        readings = {m.title: m.from_message(messages[m.input_key]) for m in self.observed}
        return build_observation(self.modalities, without=self.without, **readings)

    @staticmethod
    def train_config(p):
        """The online run's config (``train_config``, the node's modalities and seed), its env_options checked as
        dlo-train checks them (ConfigError, a ValueError: one line)."""
        from dlo_policy.config import check_env_options, load_config

        config = load_config(p["train_config"] or None, values={"modalities": p["modalities"], "seed": p["seed"]})
        check_env_options(config)
        return config

    @staticmethod
    def make_learner(p, config):
        """The online learner of ``config`` (:meth:`train_config`) in ``train_out``."""
        from dlo_policy.online import OnlineLearner

        previous_action = bool(config.env_options.get("previous_action", False))
        size = observation_size(p["modalities"], previous_action=previous_action)
        learner = OnlineLearner(config, size, p["train_out"], p["checkpoint_every"])
        if learner.agent.obs_dim != size:  # continuing a run of train_out made with other observations
            raise ParameterError(
                f"parameter 'train_out': {p['train_out']} holds a run with observations of {learner.agent.obs_dim} "
                f"entries, not {size} ({'+'.join(parse_modalities(p['modalities']))}"
                f"{' with the previous action' if previous_action else ''}): another train_out, or its settings"
            )
        return learner

    def finish(self):
        """Save the online run (run_node calls this once the node stops, before the middleware's teardown)."""
        if getattr(self, "learner", None) is not None:
            self.learner.save()
            self.get_logger().info(f"online training: {self.learner.agent.num_env_steps} steps, saved to {self.learner.run_dir}")

    def check_missing_inputs(self):
        """A step incomplete after ``input_timeout`` s: one error naming the missing input and the stamps
        the inputs did carry nearby, at most once a second (with the count of the other such steps)."""
        line = self.incomplete.check(self.sync, time.monotonic(), prefer="gripper")
        if line is not None:
            self.get_logger().error(line)


def main(args=None):
    from dlo_common.node_main import run_node

    return run_node(PolicyNode, args, parameters=PARAMETERS, summary=__doc__)


if __name__ == "__main__":
    raise SystemExit(main())
