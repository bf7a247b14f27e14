"""The paper's grip law: closure c in [0, 1] -> inverse mass of the particles between the fingers.

``w = max(2.25 w_nom - 2.5 w_nom max(c, 0.5), 0)``: c <= 0.5 leaves the particles free (w = w_nom),
c >= 0.9 makes them kinematic (w = 0, held firmly), in between they slide with growing drag.
Held particles are carried with the gripper in proportion ``1 - w / w_nom``. This module states the rules in
numpy, the contract a simulator implements and a driver reproduces; the reference simulator's Taichi kernel
(``dlo_sim.kernels``) mirrors it.

The finite grip's stall (the dlo_sim README, "finite grip"): a firm grip (c >= 0.9, the held particles fully
carried) may not pull a held particle further from the fixed end than its rest length along the
cable (``taut_reach``); the part of the gripper's motion that would is removed
(``stall_firm_grip``): the robot's force limit. The kernel (``RopeKernels.stall_firm_grip``) runs
the same rule every sub-step; ``dlo_sim/test/test_kernel_rules.py`` checks that the two agree. The driver
template (``dlo_driver_kit.mock_driver_node``) uses this function for its kinematic gripper.

The authors' single-particle grip (``SimConfig.single_particle_grip``, off by default;
docs/FIDELITY.md row 5): instead of every held particle, the grip law acts on ONE, the held particle
nearest the finger axis measured along x (the direction of travel, |x_i - x_G|, as their
``action_space_sliding.py`` measures it), never the fixed end (particle 0), ties to the lower index,
re-chosen every 0.01 s step from the held set at its start (``single_grip_particle``; the kernel's
``RopeKernels.single_grip_particle`` runs the same rule, ``dlo_sim/test/test_kernel_rules.py`` checks they agree).

The authors' carry law (``SimConfig.carry_law = "authors"``, off by default; SoftSlidingGym
``action_space_sliding.py`` Picker.step; docs/FIDELITY.md rows 5 and 6): above c = 0.5 ONE particle is
carried, picked every 0.01 s step from the authors' narrow held set (``dlo_interface.task.held_mask_authors``:
under the ``authors_code`` task rules, the task's held set) nearest the finger axis in x, never particle 0
(``authors_grip_particle``). It is moved by the WHOLE gripper displacement (the paper's law moves it by the
fraction ``carried_fraction(c)``), then left to the constraints with inverse mass ``inverse_mass(c)``
(their 4.5 - 5c at w_nom = 2): at c < 0.9 the cable pulls it back, at c >= 0.9 it is kinematic. Instead of
the finite grip's stall and slip, a sub-step's motion is cancelled (gripper and particle stay) when it
would take the particle more than AUTHORS_MAX_NEIGHBOUR_DISTANCE (10 mm) from a neighbour
(``authors_cancel``). c <= 0.5 carries nothing.
"""

from __future__ import annotations

import numpy as np

from dlo_interface.world import REST_SPACING

# a grip slips (c < 0.9) or stalls (c >= 0.9) once the straight line fixed end -> held particle exceeds
# its rest length along the cable by this
GRIP_SLIP_STRAIN = 0.0
CARRY_LAWS = ("paper", "authors")  # SimConfig.carry_law (module docstring)
AUTHORS_MAX_NEIGHBOUR_DISTANCE = 2.5 * 0.5 * 0.008  # m, the authors' cap: 2.5 x half their particle radius


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


def authors_grip_particle(positions, num_particles, gripper, c) -> int:
    """The one particle the authors' carry law moves (module docstring), -1 if none: c > 0.5 and, in
    their narrow held set (``dlo_interface.task.held_mask_authors``), the one nearest the finger axis in x, never
    particle 0, ties to the lower index. positions (P, 3), gripper (3,) [m]; float32 as the kernel."""
    from dlo_interface.task import held_mask_authors

    if not c > 0.5:
        return -1
    positions = np.asarray(positions, dtype=np.float32)
    held = held_mask_authors(positions[None], [num_particles], np.asarray(gripper, dtype=np.float32)[None])[0]
    candidates = np.flatnonzero(held)
    candidates = candidates[candidates >= 1]
    if candidates.size == 0:
        return -1
    distance = np.abs(positions[candidates, 0] - np.float32(gripper[0]))
    return int(candidates[np.argmin(distance)])


def authors_cancel(positions, num_particles, carried_index, dg) -> np.ndarray:
    """The authors' stretch limit (module docstring): ``dg`` (3,), or zeros when moving particle
    ``carried_index`` (-1: none) by it would take it further than AUTHORS_MAX_NEIGHBOUR_DISTANCE from
    particle i - 1 or i + 1."""
    dg = np.asarray(dg, dtype=np.float64).reshape(3)
    if carried_index < 1:
        return dg
    positions = np.asarray(positions, dtype=np.float64)
    q = positions[carried_index] + dg
    neighbours = [carried_index - 1] + ([carried_index + 1] if carried_index + 1 < num_particles else [])
    if any(np.linalg.norm(q - positions[j]) > AUTHORS_MAX_NEIGHBOUR_DISTANCE for j in neighbours):
        return np.zeros(3)
    return dg


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
