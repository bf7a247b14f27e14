"""The agent's observation vector: the one place that assembles it (gym env and ROS policy node).

Modalities in this fixed order, each present or not (paper: Observations):
    K (3) [x_G [m], y_G [m], c_G [0..1]]
    T (2) [theta_T [rad], y_T [m]]
    V (4) [v_V (0/1), q_V [0..1], theta_V [rad], y_V [m]]
Subsets are named "K", "T", "V", "T+K", "V+K", "T+V", "All" (any "+"-joined set, any order).
Values are SI, unscaled, as in the paper. ``without`` zeroes a modality that is present: the
test-time ablation "tested without X" (the vector keeps its size so a trained network still fits).
"""

from __future__ import annotations

import numpy as np

from dlo_perception.camera import WORKSPACE_HALF_WIDTH
from dlo_perception.tactile import Y_LIMIT
from dlo_perception.vision import SEARCH_HALF_WIDTH

MODALITY_ORDER = ("K", "T", "V")
MODALITY_SIZES = {"K": 3, "T": 2, "V": 4}
MODALITY_LABELS = {
    "K": ("x_G", "y_G", "c_G"),
    "T": ("theta_T", "y_T"),
    "V": ("v_V", "q_V", "theta_V", "y_V"),
}


def parse_modalities(modalities) -> tuple:
    """"T+K", "All", ("V", "K"), ... -> the present modalities in the fixed order, e.g. ("K", "T")."""
    if isinstance(modalities, str):
        names = MODALITY_ORDER if modalities.strip().lower() == "all" else modalities.split("+")
    else:
        names = tuple(modalities)
    names = {name.strip().upper() for name in names}
    unknown = names - set(MODALITY_ORDER)
    if unknown or not names:
        raise ValueError(f"modalities must be a '+'-joined subset of K, T, V or 'All', got {modalities!r}")
    return tuple(m for m in MODALITY_ORDER if m in names)


def observation_labels(modalities) -> tuple:
    """Names of the observation entries in order, e.g. ("x_G", "y_G", "c_G", "theta_T", "y_T")."""
    return tuple(label for m in parse_modalities(modalities) for label in MODALITY_LABELS[m])


def observation_bounds(modalities) -> tuple:
    """(low, high) float32 arrays of the observation: the workspace, closure and flags in [0, 1],
    angles in [-pi/2, pi/2], y_T and y_V within the sensors' ranges."""
    bounds = {"x_G": WORKSPACE_HALF_WIDTH, "y_G": WORKSPACE_HALF_WIDTH, "c_G": (0.0, 1.0),
              "theta_T": np.pi / 2, "y_T": Y_LIMIT,
              "v_V": (0.0, 1.0), "q_V": (0.0, 1.0), "theta_V": np.pi / 2, "y_V": SEARCH_HALF_WIDTH}
    pairs = [bounds[label] if isinstance(bounds[label], tuple) else (-bounds[label], bounds[label])
             for label in observation_labels(modalities)]
    low, high = zip(*pairs)
    return np.array(low, np.float32), np.array(high, np.float32)


def build_observation(modalities, kinematic=None, tactile=None, visual=None, without=()) -> np.ndarray:
    """(N, D) float32 observation.

    kinematic: (N, 3) [x_G, y_G, c_G]; tactile: a ``TactilePose`` (angle, y), visual: a
    ``VisualPose`` (visible, confidence, angle, y), batched (N,). Only the inputs of present,
    not ablated modalities are read. without: modalities to zero (test-time ablation), e.g. ("T",).
    With every modality ablated the batch size is 1.
    """
    present = parse_modalities(modalities)
    ablated = parse_modalities(without) if without else ()
    if set(ablated) - set(present):
        raise ValueError(f"cannot ablate {ablated}: the observation has only {present}")
    parts = []
    for m in present:
        if m in ablated:
            parts.append(None)
        elif m == "K":
            parts.append(np.asarray(kinematic, dtype=np.float32).reshape(-1, 3))
        elif m == "T":
            parts.append(np.stack([np.asarray(tactile.angle), np.asarray(tactile.y)], axis=-1).reshape(-1, 2))
        else:
            parts.append(np.stack([np.asarray(visual.visible, dtype=np.float32), np.asarray(visual.confidence),
                                   np.asarray(visual.angle), np.asarray(visual.y)], axis=-1).reshape(-1, 4))
    num_envs = next((len(part) for part in parts if part is not None), 1)
    return np.concatenate([np.zeros((num_envs, MODALITY_SIZES[m]), np.float32) if part is None
                           else part.astype(np.float32) for m, part in zip(present, parts)], axis=1)
