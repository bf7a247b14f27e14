"""The Taichi kernel's own copies of the physics rules, checked against their definitions (issue 14):

- the grip law: the inverse mass and carried fraction the kernel gives the particles between the
  fingers equal ``dlo_interface.grip`` for closures across [0, 1]; every other particle keeps w_nom and is
  not carried; the pinned particle 0 is kinematic;
- the held rule (docs/ARCHITECTURE.md#constants) at its boundaries: the extent along the finger includes the
  capsule's rounded ends (|dy| <= half-length + radius), the distance to the lower finger's axis
  (inclusive, in float32), and "above the lower finger", measured from a gripper away from y = 0 too;
- finite grip: a firm grip on a taut cable stalls the gripper, a sliding grip slides along it, and
  a gripped cable is not stretched; the kernel's stall rule gives the displacement
  ``dlo_interface.grip.stall_firm_grip`` (its numpy statement, used by the driver template) gives, on
  taut, slack, curved and random cables under firm, sliding and no grips; motion ending exactly at the
  taut reach is not stalled, and the removed direction is a unit vector even for a 1.5e-9 m offset; the
  kernel's slip rule moves exactly the carried particles beyond their reach back onto it.

One simulator serves every test (each new one recompiles the kernels), so a kernel mutant costs one
compilation in tools/mutation_check.sh.
"""

import numpy as np
import pytest
import taichi as ti
from dlo_interface.grip import carried_fraction, inverse_mass, stall_firm_grip
from dlo_interface.world import (
    FINGER_AXIS_OFFSET,
    FINGER_HALF_LENGTH,
    FINGER_RADIUS,
    FIXED_END,
    NOMINAL_INVERSE_MASS,
    P_MAX,
    PARTICLE_RADIUS,
    REST_SPACING,
)
from dlo_sim import RopeSim

HELD_DISTANCE = PARTICLE_RADIUS + FINGER_RADIUS + REST_SPACING  # docs/ARCHITECTURE.md#constants
F32 = np.float32


@pytest.fixture(scope="module")
def sim():
    return RopeSim(1)


def closure_action(c, dx=0.0, dy=0.0):
    return np.array([[dx, dy, 2.0 * c - 1.0]], np.float32)


@pytest.mark.parametrize("seed", [0, 5])
def test_kernel_grip_fields_equal_the_grip_law(sim, seed):
    sim.reset(np.array([seed]))
    n = int(sim.num_particles[0])
    closures = [0.0, 0.2, 0.5, 0.55, 0.6, 0.7, 0.75, 0.8, 0.85, 0.89, 0.9, 0.95, 1.0, 0.3]
    held_seen = 0
    for c in closures:
        held = sim.held_mask()[0, :n]  # the held set at the start of the step: what update_grip uses
        sim.step_physics(closure_action(c), 1)
        c_kernel = float(sim.gripper_state()[0, 3])
        assert c_kernel == pytest.approx(c, abs=1e-6)
        w = sim._k.w.to_numpy()[0, :n]
        carry = sim._k.carry.to_numpy()[0, :n]
        expected_w = np.where(held, inverse_mass(c_kernel, NOMINAL_INVERSE_MASS), NOMINAL_INVERSE_MASS)
        expected_carry = np.where(held, carried_fraction(c_kernel), 0.0)
        expected_w[0] = expected_carry[0] = 0.0  # the fixed end is pinned
        np.testing.assert_allclose(w, expected_w, atol=2e-6, err_msg=f"inverse mass at c = {c}")
        np.testing.assert_allclose(carry, expected_carry, atol=2e-6, err_msg=f"carried fraction at c = {c}")
        held_seen += int(held[1:].sum())
    assert held_seen > 0  # the law was applied to particles between the fingers, not only to the pin


def place(sim, probes):
    """Particle i + 1 at gripper + probes[i] (dx, dy, dz with dz from the lower finger's axis), every other
    particle far from the gripper; returns the held mask of the probes (no physics step in between)."""
    g = sim.gripper_state()[0, :3].astype(np.float64)
    positions = np.zeros((1, P_MAX, 3), np.float32)
    positions[0, :, 0] = 0.25
    positions[0, :, 1] = 0.2 + 0.005 * np.arange(P_MAX)
    positions[0, :, 2] = 0.02
    axis_z = F32(F32(g[2]) - F32(FINGER_AXIS_OFFSET))  # as the kernel computes it, in float32
    for i, (dx, dy, dz) in enumerate(probes):
        positions[0, i + 1] = (F32(g[0]) + F32(dx), F32(g[1]) + F32(dy), axis_z + F32(dz) if dz else axis_z)
    sim.set_positions(positions)
    return sim.held_mask()[0, 1 : len(probes) + 1].tolist()


def test_held_rule_extent_along_the_finger_includes_the_rounded_ends(sim):
    sim.reset(np.array([1]))
    extent = FINGER_HALF_LENGTH + FINGER_RADIUS
    up = 0.002  # well above the lower finger's axis, well within the held distance
    probes = [
        (0.0, 0.0, up),
        (0.0, FINGER_HALF_LENGTH + 0.5 * FINGER_RADIUS, up),
        (0.0, -(FINGER_HALF_LENGTH + 0.5 * FINGER_RADIUS), up),
        (0.0, extent - 1e-4, up),
        (0.0, -(extent - 1e-4), up),
        (0.0, extent + 1e-4, up),
        (0.0, -(extent + 1e-4), up),
    ]
    assert place(sim, probes) == [True, True, True, True, True, False, False]


def test_held_rule_boundaries_are_inclusive_along_the_finger_and_strict_above_the_axis(sim):
    sim.reset(np.array([1]))
    assert float(sim.gripper_state()[0, 1]) == 0.0  # the gripper starts on y = 0: exact float32 boundaries
    extent = float(F32(FINGER_HALF_LENGTH + FINGER_RADIUS))
    # exactly at the end of the extent: held; exactly at the height of the lower finger's axis: not held
    assert place(
        sim,
        [(0.0, extent, 0.002), (0.0, -extent, 0.002), (0.0, 0.0, None), (0.001, 0.0, None), (0.0, 0.0, 1e-5), (0.0, 0.0, -1e-5)],
    ) == [True, True, False, False, True, False]


def test_held_rule_distance_from_the_lower_finger_axis(sim):
    sim.reset(np.array([1]))
    d = HELD_DISTANCE
    s = np.sqrt(0.5)
    probes = [
        (0.0, 0.0, d - 1e-4),
        (0.0, 0.0, d + 1e-4),
        (d - 1e-4, 0.0, 1e-3),
        (-(d - 1e-4), 0.0, 1e-3),
        ((d + 1e-4), 0.0, 1e-3),
        (-(d + 1e-4), 0.0, 1e-3),
        (s * (d - 1e-4), 0.0, s * (d - 1e-4)),
        (s * (d + 1e-4), 0.0, s * (d + 1e-4)),
    ]
    assert place(sim, probes) == [True, False, True, True, False, False, True, False]


def pull(sim, seed, closure, actions, command=(1.0, 0.0), lead_in=0):
    """As test_grip_stretch.pull, on the shared simulator: (held indices, positions, gripper x-y) per action."""
    sim.reset(np.array([seed]))
    n = int(sim.num_particles[0])
    for _ in range(lead_in):
        sim.step(closure_action(0.7, 1.0, 0.0))
    trace = []
    for _ in range(actions):
        sim.step(closure_action(closure, *command))
        trace.append((np.flatnonzero(sim.held_mask()[0]), sim.positions()[0][:n], sim.gripper_state()[0, :2].copy()))
    return trace


def test_a_firm_grip_on_a_taut_cable_stalls_the_gripper(sim):
    trace = pull(sim, 3, 1.0, actions=12, lead_in=4)
    (held0, _, g0), (held1, _, g1) = trace[0], trace[-1]
    assert len(held0) and len(held1)
    assert np.linalg.norm(g1 - g0) < 0.01  # 0.24 m commanded
    assert abs(held1.mean() - held0.mean()) <= 1.0


def test_a_sliding_grip_on_a_taut_cable_slides_and_nothing_stretches(sim):
    trace = pull(sim, 3, 0.85, actions=10)
    farthest = [held.max() for held, _, _ in trace if len(held)]
    assert farthest[-1] >= farthest[0] + 20
    for held, x, _ in trace:
        segments = np.linalg.norm(np.diff(x, axis=0), axis=1) / REST_SPACING
        assert segments.max() <= 1.5
        if len(held):
            far = held.max()
            assert np.linalg.norm(x[far] - x[0]) <= 1.05 * far * REST_SPACING


@ti.kernel
def _kernel_stall(k: ti.template(), dg: ti.types.ndarray(), out: ti.types.ndarray()):
    for _ in range(1):  # the rule's loop over particles runs serially, as inside step_env's loop over envs
        allowed = k.stall_firm_grip(0, ti.Vector([dg[0], dg[1], dg[2]]))
        for j in ti.static(range(3)):
            out[j] = allowed[j]


def load_particles(sim, positions, carried):
    """Env 0 of the kernels gets these particles (n = len(positions)) and carried fractions."""
    n = len(positions)
    x = np.zeros((1, P_MAX, 3), np.float32)
    x[0, :n] = positions
    carry = np.zeros((1, P_MAX), np.float32)
    carry[0, :n] = carried
    sim._k.x.from_numpy(x)
    sim._k.carry.from_numpy(carry)
    sim._k.n.from_numpy(np.array([n], np.int32))


def kernel_stall(sim, positions, carried, dg):
    """RopeKernels.stall_firm_grip of env 0 for these particles (n = len(positions)) and carried fractions."""
    load_particles(sim, positions, carried)
    out = np.zeros(3, np.float32)
    _kernel_stall(sim._k, np.asarray(dg, np.float32), out)
    return out


def stall_states():
    """(positions, carried, dg): taut, slack and curved cables under firm, sliding and no grips, and random ones."""
    anchor = np.array(FIXED_END)
    straight = anchor + np.arange(30)[:, None] * np.array([REST_SPACING, 0.0, 0.0])  # every particle at its reach
    slack = anchor + np.arange(30)[:, None] * np.array([0.8 * REST_SPACING, 0.0, 0.0])
    angle = np.linspace(0.0, 1.2, 30)  # each particle at its reach, in turning directions from the fixed end
    fan = anchor + REST_SPACING * np.arange(30)[:, None] * np.stack([np.cos(angle), np.sin(angle), 0 * angle], 1)
    firm = np.zeros(30)
    firm[20:23] = 1.0
    sliding = np.where(firm > 0, carried_fraction(0.8), 0.0)
    step = 0.0025 / 4  # m, the gripper's largest sub-step (full speed, 4 sub-steps)
    states = [
        (straight, firm, (step, 0.0, 0.0)),
        (straight, firm, (0.0, step, 0.0)),
        (straight, firm, (-step, 0.0, 0.0)),
        (straight, firm, (step, -step, 0.0)),
        (straight, sliding, (step, 0.0, 0.0)),
        (slack, firm, (step, 0.0, 0.0)),
        (fan, firm, (step, 0.0, 0.0)),
        (fan, firm, (step, step, 0.0)),
        (fan, firm, (0.0, -step, 0.0)),
    ]
    rng = np.random.default_rng(7)
    for _ in range(12):  # particle i at 0.97 .. 1.03 of its reach, in random directions (a little z)
        directions = rng.normal(size=(30, 3)) * [1.0, 1.0, 0.2] + [1.0, 0.0, 0.0]
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
        positions = anchor + directions * (np.arange(30) * REST_SPACING * rng.uniform(0.97, 1.03, 30))[:, None]
        held = rng.integers(1, 28)
        carried = np.zeros(30)
        carried[held : held + 3] = rng.choice([1.0, 1.0, 0.6])
        states.append((positions, carried, (*rng.uniform(-step, step, 2), 0.0)))
    return states


def test_the_numpy_stall_rule_equals_the_kernel_on_these_states(sim):
    stalled = free = 0
    for positions, carried, dg in stall_states():
        positions = positions.astype(np.float32)  # the kernel's precision
        expected = stall_firm_grip(positions, carried, dg)
        got = kernel_stall(sim, positions, carried, dg)
        np.testing.assert_allclose(got, expected, atol=1e-7, err_msg=f"dg {dg}, carried {np.flatnonzero(carried)}")
        changed = np.linalg.norm(expected - np.asarray(dg)) > 1e-6
        stalled, free = stalled + changed, free + (not changed)
    assert stalled >= 5 and free >= 5  # both outcomes were compared, not only one


def test_single_particle_grip_kernel_choice_equals_the_numpy_rule():
    """SimConfig.single_particle_grip (docs/FIDELITY.md row 5): at every 0.01 s step the kernel gives the
    grip law (inverse mass, carried fraction) to exactly the particle ``dlo_interface.grip.single_grip_particle``
    names from the held set at the step's start: the held particle nearest the finger axis in x, never
    particle 0; every other particle keeps w_nom and is not carried."""
    from dlo_interface.grip import single_grip_particle
    from dlo_interface.sim_config import SimConfig

    single = RopeSim(1, SimConfig(single_particle_grip=True))
    rng = np.random.default_rng(17)
    zero_nearest = several = not_lowest = 0
    for seed in (0, 5, 11):
        single.reset(np.array([seed]))
        n = int(single.num_particles[0])
        for _ in range(48):
            before = single.snapshot(render=False)
            held = before.held[0, :n]
            chosen = single_grip_particle(before.positions[0, :n], held, before.gripper[0, 0])
            c = float(rng.choice([0.6, 0.7, 0.8, 0.95, 1.0]))
            single.step_physics(closure_action(c, rng.uniform(0.2, 1.0), rng.uniform(-0.4, 0.4)), 1)
            c_kernel = float(single.gripper_state()[0, 3])
            expected_w = np.full(n, NOMINAL_INVERSE_MASS)
            expected_carry = np.zeros(n)
            if chosen >= 0:
                expected_w[chosen] = inverse_mass(c_kernel, NOMINAL_INVERSE_MASS)
                expected_carry[chosen] = carried_fraction(c_kernel)
            expected_w[0] = 0.0  # the fixed end is pinned
            np.testing.assert_allclose(single._k.w.to_numpy()[0, :n], expected_w, atol=2e-6)
            np.testing.assert_allclose(single._k.carry.to_numpy()[0, :n], expected_carry, atol=2e-6)
            assert chosen != 0 and (chosen == -1 or held[chosen])
            distance = np.abs(before.positions[0, :n, 0] - before.gripper[0, 0])
            others = np.flatnonzero(held[1:]) + 1
            zero_nearest += bool(held[0] and len(others) and distance[0] < distance[others].min())
            several += len(others) >= 2
            not_lowest += bool(len(others) and chosen != others[0])
    # the cases that tell the rule apart: particle 0 nearest but skipped, a choice among several held
    # particles, and one that is not simply the lowest held index
    assert zero_nearest >= 3 and several >= 50 and not_lowest >= 20, (zero_nearest, several, not_lowest)


@ti.kernel
def _kernel_slip(k: ti.template()):
    for _ in range(1):  # serially, as inside step_env's loop over envs
        k.slip_taut_grip(0)


def kernel_slip(sim, positions, carried):
    """RopeKernels.slip_taut_grip of env 0 for these particles and carried fractions: the positions after it."""
    load_particles(sim, positions, carried)
    _kernel_slip(sim._k)
    return sim._k.x.to_numpy()[0, : len(positions)]


def test_finite_grip_pulls_only_carried_particles_beyond_their_reach_back_onto_it(sim):
    """slip_taut_grip: every carried particle (carried fraction > 0, firm or sliding) further than its rest
    length along the cable (i * REST_SPACING, GRIP_SLIP_STRAIN = 0) from the fixed end is moved back onto that
    distance along the line from the fixed end; carried particles within reach and particles not carried stay."""
    anchor = np.array(FIXED_END)
    rng = np.random.default_rng(3)
    direction = rng.normal(size=(10, 3)) * [1.0, 1.0, 0.3] + [1.0, 0.0, 0.0]
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    stretch = np.array([0.0, 1.5, 1.6, 1.2, 0.7, 1.04, 1.3, 0.95, 1.01, 2.0])  # distance / rest length along the cable
    carried = np.array([0.0, 1.0, 0.0, 0.6, 1.0, 0.3, 1e-3, 0.8, 0.0, 1.0])
    positions = (anchor + direction * (np.arange(10) * REST_SPACING * stretch)[:, None]).astype(np.float32)
    got = kernel_slip(sim, positions, carried)
    x = positions.astype(np.float64)
    d = x - x[0]
    length = np.linalg.norm(d, axis=1)
    reach = np.arange(10) * REST_SPACING
    pulled = (carried > 0) & (length > reach)
    assert pulled.tolist() == [False, True, False, True, False, True, True, False, False, True]
    expected = np.where(pulled[:, None], x[0] + d * (reach / np.maximum(length, 1e-12))[:, None], x)
    np.testing.assert_allclose(got, expected, atol=2e-7)
    np.testing.assert_allclose(np.linalg.norm(got[pulled] - x[0], axis=1), reach[pulled], atol=2e-7)


def test_a_firm_grip_is_not_stalled_by_motion_that_ends_exactly_at_the_taut_reach(sim):
    """The stall removes the motion that would take a firmly held particle *beyond* its rest length from the
    fixed end: in the kernel's float32, motion ending exactly at it is allowed, one float32 step further is not."""
    reach = F32(REST_SPACING)  # particle 1: taut_reach(1) = 1 * REST_SPACING, in float32
    dg = F32(2.0**-12)  # m, outward along x (a sub-step is at most 0.000625 m); reach - dg is exact
    at_reach = F32(reach - dg)
    beyond = np.nextafter(at_reach, F32(1.0))
    for x1, allowed in ((at_reach, dg), (beyond, 0.0)):
        got = kernel_stall(sim, np.array([[0.0, 0.0, 0.0], [x1, 0.0, 0.0]], np.float32), [0.0, 1.0], (dg, 0.0, 0.0))
        np.testing.assert_array_equal(got, np.array([allowed, 0.0, 0.0], np.float32), err_msg=f"x1 = {x1!r}")


def test_a_firm_grip_stall_removes_all_outward_motion_even_for_a_tiny_horizontal_offset(sim):
    """The direction of the removed motion is the unit horizontal vector from the fixed end to the particle for
    any offset longer than the rule's 1e-9 m guard: a particle 1.5e-9 m beside the vertical through the fixed end
    (and beyond its reach above it) stops all motion away from it, as in dlo_interface.grip.stall_firm_grip."""
    positions = np.array([[0.0, 0.0, 0.0], [1.5e-9, 0.0, 2.0 * REST_SPACING]], np.float32)
    dg = (2.0**-12, 2.0**-13, 0.0)
    got = kernel_stall(sim, positions, [0.0, 1.0], dg)
    expected = stall_firm_grip(positions, [0.0, 1.0], dg)
    np.testing.assert_allclose(expected, [0.0, 2.0**-13, 0.0], atol=1e-12)  # sideways motion stays
    np.testing.assert_allclose(got, expected, atol=1e-9)


def test_held_rule_is_relative_to_the_gripper_and_its_distance_bound_is_inclusive(sim):
    """The held rule measured from a gripper away from y = 0 (a reachable pose: x = 0, y = 0.05 m in the
    workspace): the extent along the finger is |y - y_G|, not |y|; and "within HELD_DISTANCE of the lower
    finger's axis" includes the distance itself, in the kernel's float32 (a particle exactly HELD_DISTANCE beside
    the axis, a hair above it, is held; one float32 step further is not)."""
    sim.reset(np.array([1]))
    g = sim._k.gripper.to_numpy()
    g[0] = (0.0, 0.05, g[0, 2])  # x = 0 exactly: dx = x of the particle, no rounding
    sim._k.gripper.from_numpy(g)
    d = F32(HELD_DISTANCE)  # float32(d) ** 2 rounds to float32(d ** 2), the kernel's bound
    assert F32(d * d) == F32(HELD_DISTANCE * HELD_DISTANCE) and F32(np.nextafter(d, F32(1)) ** 2) > F32(d * d)
    hair = float(np.spacing(F32(F32(g[0, 2]) - F32(FINGER_AXIS_OFFSET))))  # the next float32 above the axis
    extent = FINGER_HALF_LENGTH + FINGER_RADIUS
    probes = [
        (d, 0.0, hair),
        (-d, 0.0, hair),
        (np.nextafter(d, F32(1)), 0.0, hair),
        (0.0, extent - 1e-4, 0.002),
        (0.0, -(extent - 1e-4), 0.002),
        (0.0, extent + 1e-4, 0.002),
        (0.0, -(extent + 1e-4), 0.002),
    ]
    assert place(sim, probes) == [True, True, False, True, True, False, False]


@pytest.fixture(scope="module")
def authors_sim():
    from dlo_interface.sim_config import SimConfig

    return RopeSim(1, SimConfig(carry_law="authors"))


def test_authors_carry_law_kernel_choice_equals_the_numpy_rule(authors_sim):
    """SimConfig.carry_law = "authors" (docs/FIDELITY.md rows 5-6): at every 0.01 s step the kernel carries
    exactly the particle ``dlo_interface.grip.authors_grip_particle`` names (their narrow held set, nearest the
    finger axis in x, never particle 0; none at c <= 0.5), moved by the WHOLE displacement (carry 1) with
    the grip law's inverse mass; every other particle keeps w_nom and is not carried."""
    from dlo_interface.grip import authors_grip_particle

    rng = np.random.default_rng(23)
    carried = none = 0
    for seed in (0, 5, 11):
        authors_sim.reset(np.array([seed]))
        n = int(authors_sim.num_particles[0])
        for _ in range(48):
            before = authors_sim.snapshot(render=False)
            c = float(rng.choice([0.3, 0.5, 0.6, 0.7, 0.8, 0.95, 1.0]))
            action = closure_action(c, rng.uniform(0.2, 1.0), rng.uniform(-0.4, 0.4))
            c_kernel = float(0.5 * (action[0, 2] + 1.0))
            chosen = authors_grip_particle(before.positions[0, :n], n, before.gripper[0, :3], c_kernel)
            authors_sim.step_physics(action, 1)
            expected_w = np.full(n, NOMINAL_INVERSE_MASS)
            expected_carry = np.zeros(n)
            if chosen >= 0:
                expected_w[chosen] = inverse_mass(c_kernel, NOMINAL_INVERSE_MASS)
                expected_carry[chosen] = 1.0
            expected_w[0] = 0.0
            np.testing.assert_allclose(authors_sim._k.w.to_numpy()[0, :n], expected_w, atol=2e-6)
            np.testing.assert_allclose(authors_sim._k.carry.to_numpy()[0, :n], expected_carry, atol=0)
            carried += chosen >= 1
            none += chosen == -1
    assert carried >= 50 and none >= 10, (carried, none)  # both branches compared


@ti.kernel
def _kernel_cancel(k: ti.template(), dg: ti.types.vector(3, ti.f32)) -> ti.types.vector(3, ti.f32):
    result = ti.Vector([0.0, 0.0, 0.0])
    for _ in range(1):
        result = k.authors_cancel(0, dg)
    return result


def test_authors_cancel_equals_the_numpy_rule_and_cuts_at_ten_millimetres(authors_sim):
    """The authors' stretch limit: the sub-step motion is cancelled (0) when it would take the carried particle
    more than 10 mm from particle i - 1 or i + 1, kept otherwise; the kernel equals ``grip.authors_cancel``."""
    from dlo_interface.grip import AUTHORS_MAX_NEIGHBOUR_DISTANCE, authors_cancel

    assert AUTHORS_MAX_NEIGHBOUR_DISTANCE == pytest.approx(0.01)
    n = 20
    positions = np.stack([FIXED_END[0] + REST_SPACING * np.arange(n), np.zeros(n), np.full(n, FIXED_END[2])], 1)
    rng = np.random.default_rng(3)
    kept = cancelled = 0
    for _ in range(200):
        index = int(rng.integers(1, n))
        carried = np.zeros(n)
        carried[index] = 1.0
        dg = rng.uniform(-0.008, 0.008, 3) * np.array([1.0, 1.0, 0.0])
        load_particles(authors_sim, positions.astype(np.float32), carried)
        kernel = np.array(_kernel_cancel(authors_sim._k, ti.Vector(dg.astype(np.float32))))
        numpy = authors_cancel(positions.astype(np.float32), n, index, dg.astype(np.float32))
        np.testing.assert_allclose(kernel, numpy, atol=1e-7)
        kept += bool(np.any(numpy))
        cancelled += not np.any(numpy)
    assert kept >= 20 and cancelled >= 20, (kept, cancelled)
    # the bound itself: 10 mm - 0.1 mm from the neighbour kept, 10 mm + 0.1 mm cancelled (last particle: one neighbour)
    for extra, moves in ((-0.0001, True), (0.0001, False)):
        dg = np.array([0.01 + extra - REST_SPACING, 0.0, 0.0])
        assert bool(np.any(authors_cancel(positions, n, n - 1, dg))) is moves
    assert not np.any(authors_cancel(positions, n, -1, np.zeros(3)))  # nothing carried: nothing to cancel
    assert np.all(authors_cancel(positions, n, -1, np.ones(3)) == 1.0)
