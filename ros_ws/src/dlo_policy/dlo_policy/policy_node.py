"""policy_node: K/T/V of one control step (matched by stamp) -> /dlo/gripper/cmd answering that step.

``policy``: ``sac`` (a checkpoint or shipped policy from dlo-train, deterministic actions),
``tactile_reactive`` (the classical baseline, observations only), ``oracle`` (ground truth from
``/dlo/rope/particles``: simulation only) or ``random``. With ``train:=true`` the node learns
online from the graph's steps (``dlo_policy.online``: same SAC and checkpoints as dlo-train), its
reward and episode ends taken from ``/dlo/task/state``. The observation is
assembled by ``dlo_policy.observation.build_observation``, exactly as in the gym environment.
Inputs that a step does not deliver within ``input_timeout`` s are reported as an error naming the
missing topic; the sim node then republishes the step, so nothing deadlocks.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from rclpy.node import Node

from sensor_msgs.msg import PointCloud2

from dlo_common.node_util import ParameterError, declare_parameters
from dlo_common.params import Param
from dlo_msgs.msg import GripperCommand, GripperState, TactilePose, TaskState, VisualPose
from dlo_perception.cloud import unpack_particles
from dlo_perception.sync import IncompleteSteps, StampSync, stamp_to_ns
from dlo_perception.tactile import TactilePose as Tactile
from dlo_perception.vision import VisualPose as Visual
from dlo_policy.observation import build_observation, parse_modalities
from dlo_sim.command import action_to_command
from dlo_sim.task import LEGACY_TASK_RULES, dropped

POLICIES = ("sac", "tactile_reactive", "oracle", "random")
PARAMETERS = (
    Param("policy", "sac", f"controller, one of {POLICIES}", choices=POLICIES),
    Param("checkpoint", "", "dlo-train policy.pt / checkpoint.pt (empty = the shipped All policy)"),
    Param("modalities", "All", "observation modalities for policy=random (sac uses its training config)"),
    Param("without", "", "test-time ablation: zero these modalities, e.g. 'T' or 'V'"),
    Param("input_timeout", 1.0, "report an error when a step's inputs are incomplete after this long [s]",
          above=0.0),
    Param("seed", 0, "seed of the random policy and of online training", at_least=0),
    Param("train", False, "learn online from the graph (policy sac): SAC from scratch or from train_out"),
    Param("train_out", "runs/online", "run directory of online training (config, checkpoint.pt, policy.pt)"),
    Param("checkpoint_every", 1000, "online training: control steps between checkpoints", at_least=1),
    Param("train_config", "", "online training: a dlo-train YAML config (SAC hyperparameters); empty = defaults"),
)
SHIPPED_POLICY = "policies/all/policy.pt"


def shipped_policy_path() -> Path:
    """The bundled All-modalities policy: installed share dir first, then the source tree."""
    try:
        from ament_index_python.packages import get_package_share_directory

        installed = Path(get_package_share_directory("dlo_policy")) / SHIPPED_POLICY
        if installed.exists():
            return installed
    except (ImportError, LookupError):
        pass
    return Path(__file__).resolve().parents[1] / SHIPPED_POLICY


def modalities_parameter(name: str, value: str) -> tuple:
    """``parse_modalities(value)``, or a ParameterError naming the parameter and what it takes."""
    try:
        return parse_modalities(value)
    except ValueError:
        takes = ("'' (none) or the modalities to zero: K, T, V or several joined by '+', e.g. T or T+V"
                 if name == "without" else "All or a '+'-joined subset of K, T, V, e.g. V+K")
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
    """-> (act(observation (1, D), new_episode, ground truth) -> action (1, 3), modalities actually used)."""
    if kind == "sac":
        from dlo_policy.evaluate import load_run_config
        from dlo_policy.sac import SAC, CheckpointError

        path = Path(checkpoint) if checkpoint else shipped_policy_path()
        if not path.exists():
            raise ParameterError(f"checkpoint {path} does not exist")
        try:
            agent = SAC.load(path)
        except CheckpointError as error:  # "not a dlo-vitac policy file: PATH (why)"
            raise ParameterError(f"parameter 'checkpoint': {error}") from None
        trained_on = load_run_config(path).modalities
        return (lambda obs, new_episode, truth: agent.predict(obs, deterministic=True).reshape(1, 3)), trained_on
    if kind == "tactile_reactive":
        from dlo_policy.scripted import TactileReactive

        controller = TactileReactive()
        layout = type("ObservationLayout", (), {"modalities": parse_modalities("All")})()

        def act(obs, new_episode, truth):
            if new_episode:
                controller.reset()
            return controller(obs, layout)
        return act, "All"
    if kind == "oracle":
        from dlo_policy.scripted import OracleFollow

        oracle = OracleFollow()
        return (lambda obs, new_episode, truth: oracle(obs, truth)), modalities
    rng = np.random.default_rng(seed)
    return (lambda obs, new_episode, truth: rng.uniform(-1.0, 1.0, (1, 3)).astype(np.float32)), modalities


class PolicyNode(Node):
    """Closes the loop: observations in, one gripper command per control step out."""

    def __init__(self):
        super().__init__("policy_node")
        p = declare_parameters(self, PARAMETERS)
        if p["train"] and p["policy"] != "sac":
            raise ParameterError("parameter 'train': online training needs policy:=sac")
        try:
            if p["train"]:
                self.act, modalities = None, p["modalities"]
            else:
                self.act, modalities = load_policy(p["policy"], p["checkpoint"], p["modalities"], p["seed"])
            self.modalities = modalities_parameter("modalities", modalities)
            self.without = modalities_parameter("without", p["without"]) if p["without"] else ()
            ablated_absent = [m for m in self.without if m not in self.modalities]
            if ablated_absent:
                raise ParameterError(f"parameter 'without': cannot ablate {'+'.join(ablated_absent)}: the policy "
                                     f"observes only {'+'.join(self.modalities)}")
            build_observation(self.modalities, np.zeros((1, 3)), Tactile(*np.zeros((4, 1))),
                              Visual(*np.zeros((4, 1))), without=self.without)
            self.learner = self.make_learner(p) if p["train"] else None
        except (ValueError, OSError) as error:
            raise ParameterError(str(error)) from None
        self.input_timeout = p["input_timeout"]
        inputs = ["gripper"] + [key for key, m in (("tactile", "T"), ("vision", "V"))
                                if m in self.modalities and m not in self.without]
        inputs += ["task"] if self.learner else []
        inputs += ["particles"] if p["policy"] == "oracle" else []
        self.truth = GroundTruthView()
        self.sync = StampSync(inputs)
        self.first_seen = {}  # stamp_ns -> wall time of its first input
        self.incomplete = IncompleteSteps(self.input_timeout, first_seen=self.first_seen)  # check_missing_inputs
        self.last = (None, None)  # (stamp_ns, GripperCommand): a republished step gets the same answer
        self.publisher = self.create_publisher(GripperCommand, "/dlo/gripper/cmd", 10)
        self.create_subscription(GripperState, "/dlo/gripper/state", lambda m: self.on_input("gripper", m), 10)
        if "tactile" in inputs:
            self.create_subscription(TactilePose, "/dlo/tactile/pose", lambda m: self.on_input("tactile", m), 10)
        if "vision" in inputs:
            self.create_subscription(VisualPose, "/dlo/vision/pose", lambda m: self.on_input("vision", m), 10)
        if "task" in inputs:
            self.create_subscription(TaskState, "/dlo/task/state", lambda m: self.on_input("task", m), 10)
        if "particles" in inputs:
            self.create_subscription(PointCloud2, "/dlo/rope/particles", lambda m: self.on_input("particles", m), 10)
        self.create_timer(0.25, self.check_missing_inputs)
        self.get_logger().info(f"policy {p['policy']} on {'+'.join(self.modalities)}"
                               + (f" without {'+'.join(self.without)}" if self.without else "")
                               + f"; inputs {inputs}")

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
        values = dict(zip(self.sync.keys, matched))
        gripper = values["gripper"]
        tactile = values.get("tactile")
        vision = values.get("vision")
        observation = build_observation(
            self.modalities, np.array([[gripper.x, gripper.y, gripper.closure]]),
            Tactile(np.array([tactile.angle]), np.array([tactile.y]), np.array([tactile.contact]),
                    np.array([tactile.contact_count])) if tactile else None,
            Visual(np.array([vision.visible]), np.array([vision.confidence]), np.array([vision.angle]),
                   np.array([vision.y])) if vision else None,
            without=self.without)
        if self.learner is not None:
            task = values["task"]
            terminated = task.done and bool(dropped(task.task_rules or LEGACY_TASK_RULES, task.n_held,
                                                    len(task.held_indices_authors)))
            action = self.learner.act(observation[0], task.reward, task.done, terminated,
                                      gripper.episode, gripper.step)
        else:
            self.truth.cloud, self.truth.gripper = values.get("particles"), gripper
            action = self.act(observation, gripper.step == 0, self.truth)[0]
        vx, vy, closure = action_to_command(action)
        command = GripperCommand(vx=vx, vy=vy, closure=closure, episode=gripper.episode, step=gripper.step)
        command.header = gripper.header
        self.last = (stamp, command)
        self.publisher.publish(command)

    @staticmethod
    def make_learner(p):
        from dlo_policy.config import load_config
        from dlo_policy.observation import MODALITY_SIZES
        from dlo_policy.online import OnlineLearner

        config = load_config(p["train_config"] or None, values={"modalities": p["modalities"], "seed": p["seed"]})
        obs_dim = sum(MODALITY_SIZES[m] for m in parse_modalities(p["modalities"]))
        return OnlineLearner(config, obs_dim, p["train_out"], p["checkpoint_every"])

    def destroy_node(self):
        if getattr(self, "learner", None) is not None:
            self.learner.save()
            self.get_logger().info(f"online training: {self.learner.agent.num_env_steps} steps, saved to "
                                   f"{self.learner.run_dir}")
        super().destroy_node()

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
