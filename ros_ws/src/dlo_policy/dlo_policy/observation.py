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
"""

from __future__ import annotations

import numpy as np

from dlo_policy import modalities as registry
from dlo_policy.modalities import ALL, parse_modalities

__all__ = [
    "ALL",
    "MODALITY_LABELS",
    "MODALITY_ORDER",
    "MODALITY_SIZES",
    "build_observation",
    "observation_bounds",
    "observation_labels",
    "observation_size",
    "parse_modalities",
]

# Views of the registry (dlo_policy.modalities) as of import, for the callers that index by name; the functions
# below read the registry itself.
MODALITY_ORDER = registry.names()
MODALITY_SIZES = {m.name: m.size for m in registry.MODALITIES}
MODALITY_LABELS = {m.name: m.labels for m in registry.MODALITIES}


def observation_labels(modalities) -> tuple:
    """Names of the observation entries in order, e.g. ("x_G", "y_G", "c_G", "theta_T", "y_T")."""
    return tuple(label for m in parse_modalities(modalities) for label in registry.by_name(m).labels)


def observation_size(modalities) -> int:
    """Length D of the observation of ``modalities``."""
    return sum(registry.by_name(m).size for m in parse_modalities(modalities))


def observation_bounds(modalities) -> tuple:
    """(low, high) float32 arrays of the observation: the workspace, closure and flags in [0, 1],
    angles in [-pi/2, pi/2], y_T and y_V within the sensors' ranges."""
    pairs = [pair for m in parse_modalities(modalities) for pair in registry.by_name(m).bounds]
    low, high = zip(*pairs)
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
    given = {m.title: reading for m, reading in zip(records, readings)}
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
            for m, part in zip(present, parts)
        ],
        axis=1,
    )
