"""The agent's observation vector: the one place that assembles it (gym env and ROS policy node).

Modalities in the registry's fixed order (``dlo_policy.modalities``), each present or not (paper:
Observations):
    K (3) [x_G [m], y_G [m], c_G [0..1]]
    T (2) [theta_T [rad], y_T [m]]
    V (4) [v_V (0/1), q_V [0..1], theta_V [rad], y_V [m]]
Subsets are named "K", "T", "V", "T+K", "V+K", "T+V", "All" (any "+"-joined set, any order; "All" is
the paper's K+T+V, ``dlo_policy.modalities.ALL``). Values are SI, unscaled, as in the paper.
``without`` zeroes a modality that is present: the test-time ablation "tested without X" (the
vector keeps its size so a trained network still fits).

The previous action (option ``previous_action``, off by default): the action the policy gave at the step before,
appended after the modalities as PREVIOUS_ACTION_LABELS [a_x, a_y, a_c] in the env's action box [-1, 1]^3, zeros at
an episode's first step (:func:`with_previous_action`). It is the policy's own memory, not a sensor: the observation
perturbations (delay, noise) do not act on it, and it is the action as the policy gave it, before any action
perturbation (delay, gain, lag) that stands for the robot. With it a policy can know the commands still in flight
under a delay (the gym env and the policy node append it alike).
"""

from __future__ import annotations

import numpy as np

from dlo_policy import modalities as registry
from dlo_policy.modalities import ALL, parse_modalities

__all__ = [
    "ALL",
    "MODALITY_LABELS",
    "PREVIOUS_ACTION_LABELS",
    "MODALITY_ORDER",
    "MODALITY_SIZES",
    "build_observation",
    "observation_bounds",
    "observation_labels",
    "observation_size",
    "parse_modalities",
    "PreviousAction",
    "takes_previous_action",
    "with_previous_action",
]

# Views of the registry (dlo_policy.modalities) as of import, for the callers that index by name; the functions
# below read the registry itself.
MODALITY_ORDER = registry.names()
MODALITY_SIZES = {m.name: m.size for m in registry.MODALITIES}
MODALITY_LABELS = {m.name: m.labels for m in registry.MODALITIES}


PREVIOUS_ACTION_LABELS = ("a_x", "a_y", "a_c")  # the previous action's entries (module docstring)
ACTION_SIZE = len(PREVIOUS_ACTION_LABELS)


def observation_labels(modalities, previous_action: bool = False) -> tuple:
    """Names of the observation entries in order, e.g. ("x_G", "y_G", "c_G", "theta_T", "y_T")."""
    labels = tuple(label for m in parse_modalities(modalities) for label in registry.by_name(m).labels)
    return labels + (PREVIOUS_ACTION_LABELS if previous_action else ())


def observation_size(modalities, previous_action: bool = False) -> int:
    """Length D of the observation of ``modalities`` (with the previous action: D + 3)."""
    return sum(registry.by_name(m).size for m in parse_modalities(modalities)) + (ACTION_SIZE if previous_action else 0)


def observation_bounds(modalities, previous_action: bool = False) -> tuple:
    """(low, high) float32 arrays of the observation: the workspace, closure and flags in [0, 1],
    angles in [-pi/2, pi/2], y_T and y_V within the sensors' ranges; the previous action in [-1, 1]."""
    pairs = [pair for m in parse_modalities(modalities) for pair in registry.by_name(m).bounds]
    pairs += [(-1.0, 1.0)] * (ACTION_SIZE if previous_action else 0)
    low, high = zip(*pairs, strict=True)
    return np.array(low, np.float32), np.array(high, np.float32)


def build_observation(modalities, *readings, without=(), **named) -> np.ndarray:
    """(N, D) float32 observation.

    The readings of the modalities, by position in registry order (``kinematic, tactile, visual``)
    or by keyword (the record's ``title``): kinematic (N, 3) [x_G, y_G, c_G]; tactile a
    ``TactilePose`` (angle, y), visual a ``VisualPose`` (visible, confidence, angle, y), batched
    (N,). Only the readings of present, not ablated modalities are read (each record's ``columns``).
    without: modalities to zero (test-time ablation), e.g. ("T",). With every modality ablated the
    batch size is 1.
    """
    records = registry.MODALITIES
    if len(readings) > len(records):
        raise TypeError(f"build_observation takes at most {len(records)} readings, got {len(readings)}")
    given = {m.title: reading for m, reading in zip(records, readings, strict=False)}  # readings may be fewer
    unknown = set(named) - {m.title for m in records}
    if unknown or set(named) & set(given):
        raise TypeError(f"build_observation: unknown or repeated reading(s) {sorted(unknown or set(named) & set(given))}")
    given.update(named)
    present = parse_modalities(modalities)
    ablated = parse_modalities(without) if without else ()
    if set(ablated) - set(present):
        raise ValueError(f"cannot ablate {ablated}: the observation has only {present}")
    present = [registry.by_name(m) for m in present]
    parts = [None if m.name in ablated else m.columns(given.get(m.title)) for m in present]
    num_envs = next((len(part) for part in parts if part is not None), 1)
    return np.concatenate(
        [
            np.zeros((num_envs, m.size), np.float32) if part is None else part.astype(np.float32)
            for m, part in zip(present, parts, strict=True)
        ],
        axis=1,
    )


def takes_previous_action(obs_dim: int, modalities) -> bool:
    """Whether a policy of input size ``obs_dim`` over ``modalities`` takes the previous action after them (its size +
    3); ValueError when the size is neither."""
    if obs_dim == observation_size(modalities, previous_action=True):
        return True
    if obs_dim != observation_size(modalities):
        raise ValueError(
            f"takes observations of {obs_dim} entries, not those of {'+'.join(parse_modalities(modalities))} "
            f"({observation_size(modalities)}, with the previous action {observation_size(modalities, previous_action=True)})"
        )
    return False


def with_previous_action(observation, previous_action) -> np.ndarray:
    """(N, D) observation and (N, 3) previous actions (the env's action box; zeros at an episode's first step)
    -> the (N, D + 3) float32 observation the policy takes with option ``previous_action`` (module docstring)."""
    observation = np.asarray(observation, dtype=np.float32)
    previous = np.asarray(previous_action, dtype=np.float32).reshape(len(observation), ACTION_SIZE)
    return np.concatenate([observation, previous], axis=1)


class PreviousAction:
    """The previous action of ``num_envs`` streams of control steps, appended to their observations: the gym env
    (batched) and the policy node (one stream) keep it alike. ``start(ids)``: new episodes (zeros); ``took(actions)``:
    the actions (N, 3) the policy gave this step; ``append(observation, ids)``: the observations of these envs
    (all by default) with their previous action (:func:`with_previous_action`)."""

    def __init__(self, num_envs: int = 1):
        self.actions = np.zeros((int(num_envs), ACTION_SIZE), np.float32)

    def start(self, env_ids=None) -> None:
        self.actions[slice(None) if env_ids is None else env_ids] = 0.0

    def took(self, actions) -> None:
        self.actions[:] = np.asarray(actions, dtype=np.float32).reshape(self.actions.shape)

    def append(self, observation, env_ids=None) -> np.ndarray:
        return with_previous_action(observation, self.actions if env_ids is None else self.actions[env_ids])
