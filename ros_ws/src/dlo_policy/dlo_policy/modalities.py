"""The observation modalities: one record each, in one registry (docs/ARCHITECTURE.md#observations).

Everything the code knows about a modality sits in its :class:`Modality` record in ``MODALITIES``,
and the observation vector (``dlo_policy.observation``), the gym environment (``dlo_policy.env``)
and the policy node (``dlo_policy.policy_node``) loop over the registry: adding a modality is
adding a record here (docs/ARCHITECTURE.md#adding-an-observation-modality). A record:

    name          "K": how subsets are written ("T+K") and the order of the vector (registry order)
    title         "kinematic": its reading's keyword in ``build_observation`` (and its name in words)
    labels        the names of its observation entries, in order (their number is its size)
    bounds        (low, high) of each entry: the observation space
    observe       env -> the reading of the env's current state (``dlo_policy.env``: its TaskSim
                  ``task``, ``sim``, ``tactile_sigma``, ``noise_rng``); batched over the env's N
    columns       reading -> (N, size) array: its block of the observation vector
    topic         the topic the graph delivers the reading on (``dlo_common.topics``; its record
                  gives the message type, ``message_type``)
    from_message  a message of that topic -> the reading (a batch of 1); reads fields by name, so
                  rclpy messages and bag messages alike
    renders       the reading needs the top-camera image (the env renders only then)

``ALL`` is what "All" means: the paper's K+T+V, a named constant, not "every modality known", so a
new modality does not change what a trained "All" policy (the shipped one) observes. Checkpoints
store their expanded list (``SAC.modalities``). No rclpy here.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np
from dlo_common.topics import topic as topic_record
from dlo_interface.world import GRIPPER_HEIGHT, WORKSPACE_HALF_WIDTH
from dlo_perception.tactile import Y_LIMIT, TactilePose, tactile_pose
from dlo_perception.vision import SEARCH_HALF_WIDTH, VisualPose, visual_pose, visual_pose_particles

# The gripper's height as the simulator stores (float32) and publishes it: the vision node computes
# O_V at the published gripper z, so the same value here keeps graph and env bit-identical.
VISION_PLANE_Z = float(np.float32(GRIPPER_HEIGHT))
HALF_PI = np.pi / 2


@dataclass(frozen=True)
class Modality:
    """One observation modality (module docstring)."""

    name: str
    title: str
    labels: tuple
    bounds: tuple  # ((low, high), ...) per label
    observe: Callable[[Any], Any]
    columns: Callable[[Any], np.ndarray]
    topic: str
    from_message: Callable[[Any], Any]
    renders: bool = False

    def __post_init__(self):
        if len(self.bounds) != len(self.labels):
            raise ValueError(f"modality {self.name}: one (low, high) per label")
        topic_record(self.topic)  # a topic of the registry

    @property
    def size(self) -> int:
        return len(self.labels)

    @property
    def message_type(self) -> str:
        """The type of the message the graph delivers it in ("dlo_msgs/msg/TactilePose")."""
        return topic_record(self.topic).type

    @property
    def input_key(self) -> str:
        """The input name of its topic in a node's stamp matching ("tactile")."""
        return topic_record(self.topic).key


def _symmetric(limit: float) -> tuple:
    return (-limit, limit)


def _observe_visual(env):
    """O_V from the env's vision source (``vision_source``, dlo_perception.vision): the rendered top view
    ("image") or the authors' index walk on the task rules' held set ("particles")."""
    state = env.task.state
    if env.vision_source == "particles":
        return visual_pose_particles(state.positions, env.task.held_task, env.sim.num_particles, state.gripper[:, :2])
    plane_z = float(np.float32(env.sim.config.gripper_height))  # VISION_PLANE_Z at the default start pose
    # the camera the vision assumes: the one that rendered, unless a camera perturbation moved that one
    camera = getattr(env, "vision_camera", None) or env.sim.camera
    return visual_pose(state.image, camera, state.gripper[:, :2], plane_z)


MODALITIES = (
    Modality(
        "K",
        "kinematic",
        ("x_G", "y_G", "c_G"),
        (_symmetric(WORKSPACE_HALF_WIDTH), _symmetric(WORKSPACE_HALF_WIDTH), (0.0, 1.0)),
        observe=lambda env: env.task.state.gripper[:, [0, 1, 3]],
        columns=lambda kinematic: np.asarray(kinematic, dtype=np.float32).reshape(-1, 3),
        topic="/dlo/gripper/state",
        from_message=lambda msg: np.array([[msg.x, msg.y, msg.closure]]),
    ),
    Modality(
        "T",
        "tactile",
        ("theta_T", "y_T"),
        (_symmetric(HALF_PI), _symmetric(Y_LIMIT)),
        observe=lambda env: tactile_pose(
            env.task.state.positions,
            env.task.held_task,
            env.task.state.gripper[:, :2],
            env.task.state.gripper[:, 3],
            sigma=env.tactile_sigma,
            rng=env.noise_rng,
        ),
        columns=lambda tactile: np.stack([np.asarray(tactile.angle), np.asarray(tactile.y)], axis=-1).reshape(-1, 2),
        topic="/dlo/tactile/pose",
        from_message=lambda msg: TactilePose(
            np.array([msg.angle]), np.array([msg.y]), np.array([msg.contact]), np.array([msg.contact_count])
        ),
    ),
    Modality(
        "V",
        "visual",
        ("v_V", "q_V", "theta_V", "y_V"),
        ((0.0, 1.0), (0.0, 1.0), _symmetric(HALF_PI), _symmetric(SEARCH_HALF_WIDTH)),
        observe=_observe_visual,
        columns=lambda visual: np.stack(
            [
                np.asarray(visual.visible, dtype=np.float32),
                np.asarray(visual.confidence),
                np.asarray(visual.angle),
                np.asarray(visual.y),
            ],
            axis=-1,
        ).reshape(-1, 4),
        topic="/dlo/vision/pose",
        from_message=lambda msg: VisualPose(
            np.array([msg.visible]), np.array([msg.confidence]), np.array([msg.angle]), np.array([msg.y])
        ),
        renders=True,
    ),
)
ALL = ("K", "T", "V")  # "All": the paper's K+T+V (module docstring); never "every modality known"
ALL_NAME = "All"


def names() -> tuple:
    """Every modality known, in the order of the observation vector (registry order)."""
    return tuple(m.name for m in MODALITIES)


def by_name(name: str) -> Modality:
    """The record of modality ``name`` ("K"); KeyError for an unknown one."""
    for m in MODALITIES:
        if m.name == name:
            return m
    raise KeyError(f"no modality {name!r}; known: {', '.join(names())}")


assert len(set(names())) == len(MODALITIES) and set(ALL) <= set(names())


def parse_modalities(modalities) -> tuple:
    """ "T+K", "All", ("V", "K"), ... -> the present modalities in the fixed order, e.g. ("K", "T")."""
    if isinstance(modalities, str):
        given = ALL if modalities.strip().lower() == ALL_NAME.lower() else modalities.split("+")
    else:
        given = tuple(modalities)
    wanted = {name.strip().upper() for name in given}
    known = names()
    unknown = wanted - set(known)
    if unknown or not wanted:
        raise ValueError(f"modalities must be a '+'-joined subset of {', '.join(known)} or '{ALL_NAME}', got {modalities!r}")
    return tuple(m for m in known if m in wanted)


def without_problem(text: str) -> str | None:
    """``launch_graph.sh --without`` checked as the launcher always did (empty, or registry names joined
    by '+', exactly): None if fine, else the one-line reason."""
    if not text or all(part in names() for part in text.split("+")):
        return None
    return f"--without must be empty or modalities joined by '+' ({', '.join(names())}), e.g. T or T+V, got '{text}'"
