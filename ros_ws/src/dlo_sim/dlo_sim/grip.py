"""The paper's grip law: closure c in [0, 1] -> inverse mass of the particles between the fingers.

``w = max(2.25 w_nom - 2.5 w_nom max(c, 0.5), 0)``: c <= 0.5 leaves the particles free (w = w_nom),
c >= 0.9 makes them kinematic (w = 0, held firmly), in between they slide with growing drag.
Held particles are carried with the gripper in proportion ``1 - w / w_nom``. The Taichi kernel
(``kernels.py``) mirrors this function.

The finite grip's stall (README "finite grip"): a firm grip (c >= 0.9, the held particles fully
carried) may not pull a held particle further from the fixed end than its rest length along the
cable (``taut_reach``); the part of the gripper's motion that would is removed
(``stall_firm_grip``): the robot's force limit. The kernel (``RopeKernels.stall_firm_grip``) runs
the same rule every sub-step; ``test/test_kernel_rules.py`` checks that the two agree. The driver
template (``dlo_driver_kit.mock_driver_node``) uses this function for its kinematic gripper.

The authors' single-particle grip (``SimConfig.single_particle_grip``, off by default;
docs/FIDELITY.md row 5): instead of every held particle, the grip law acts on ONE, the held particle
nearest the finger axis measured along x (the direction of travel, |x_i - x_G|, as their
``action_space_sliding.py`` measures it), never the fixed end (particle 0), ties to the lower index,
re-chosen every 0.01 s step from the held set at its start (``single_grip_particle``; the kernel's
``RopeKernels.single_grip_particle`` runs the same rule, ``test/test_kernel_rules.py`` checks they agree).
"""

from __future__ import annotations

import numpy as np

from .config import REST_SPACING

# a grip slips (c < 0.9) or stalls (c >= 0.9) once the straight line fixed end -> held particle exceeds
# its rest length along the cable by this
GRIP_SLIP_STRAIN = 0.0


def inverse_mass(c, w_nom):
    """Inverse mass [1/kg] of a held particle at closure ``c`` (scalar or array)."""
    c = np.asarray(c, dtype=np.float64)
    return np.maximum(2.25 * w_nom - 2.5 * w_nom * np.maximum(c, 0.5), 0.0)


def carried_fraction(c):
    """Fraction of the gripper's displacement a held particle follows at closure ``c``."""
    return 1.0 - inverse_mass(c, 1.0)


def single_grip_particle(positions, held, gripper_x) -> int:
    """The one particle the single-particle grip carries (module docstring), -1 if none.

    positions: (P, 3) float32 cable particles [m]; held: (P,) bool, the physics' held set; gripper_x:
    the gripper's x [m]. Computed in float32, as the kernel does, so that near-ties agree."""
    x = np.asarray(positions, dtype=np.float32)[:, 0]
    candidates = np.flatnonzero(np.asarray(held, dtype=bool))
    candidates = candidates[candidates >= 1]
    if candidates.size == 0:
        return -1
    distance = np.abs(x[candidates] - np.float32(gripper_x))
    return int(candidates[np.argmin(distance)])  # argmin: the first (lowest index) of equal distances


def taut_reach(index):
    """Straight-line distance [m] from the fixed end at which particle ``index``'s cable is pulled taut:
    its rest length along the cable, ``index * REST_SPACING`` (times 1 + GRIP_SLIP_STRAIN)."""
    return (1.0 + GRIP_SLIP_STRAIN) * np.asarray(index, dtype=np.float64) * REST_SPACING


def stall_firm_grip(positions, carried, dg) -> np.ndarray:
    """The gripper displacement ``dg`` (3,) [m] that a firm grip allows (the kernel's rule, in numpy).

    positions: (P, 3) cable particles [m], index 0 = the fixed end; carried: (P,) fraction of the
    gripper motion each particle follows (``carried_fraction(c)`` for the particles between the
    fingers, 0 for the others). For each fully carried particle i (carried >= 1: c >= 0.9), in index
    order: if ``positions[i] + dg`` lies further than ``taut_reach(i)`` from the fixed end, the part of
    ``dg`` along the horizontal direction from the fixed end to the particle, if positive (away from
    it), is removed. Sideways and back the gripper still moves; a sliding grip (c < 0.9) is never
    stalled (it slides through the fingers instead).
    """
    positions = np.asarray(positions, dtype=np.float64)
    dg = np.array(dg, dtype=np.float64).reshape(3)
    anchor = positions[0]
    firm = np.flatnonzero(np.asarray(carried, dtype=np.float64) >= 1.0)
    for i in firm[firm >= 1]:
        d = positions[i] - anchor
        if np.linalg.norm(d + dg) > taut_reach(i):
            r = np.array([d[0], d[1], 0.0])  # the gripper moves in the horizontal plane only: never add z
            r /= max(float(np.linalg.norm(r)), 1e-9)
            outward = float(dg @ r)
            if outward > 0.0:
                dg -= outward * r
    return dg
