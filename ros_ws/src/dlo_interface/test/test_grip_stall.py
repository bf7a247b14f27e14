"""dlo_interface.grip.stall_firm_grip, the finite grip's stall in numpy (no Taichi; the kernel's agreement with
it is test_kernel_rules.py::test_the_numpy_stall_rule_equals_the_kernel_on_these_states):

- a firm grip (fully carried particles) on a taut cable: the motion away from the fixed end is removed,
  sideways and back the gripper still moves, z is never added;
- a sliding grip, a slack cable, particles not carried and the fixed end itself never stall it;
- several firm particles: each removes its own outward part, in index order.
"""

import numpy as np
import pytest
from dlo_interface.grip import GRIP_SLIP_STRAIN, carried_fraction, stall_firm_grip, taut_reach
from dlo_interface.world import FIXED_END, REST_SPACING

STEP = 0.0025 / 4  # m, the gripper's largest sub-step


def straight(n=30, stretch=1.0, direction=(1.0, 0.0, 0.0)):
    """n particles from the fixed end along ``direction``, ``stretch`` times their rest spacing apart."""
    return np.asarray(FIXED_END) + np.arange(n)[:, None] * stretch * REST_SPACING * np.asarray(direction)


def held(indices, closure=1.0, n=30):
    carried = np.zeros(n)
    carried[list(indices)] = carried_fraction(closure)
    return carried


def test_taut_reach_is_the_rest_length_along_the_cable():
    assert GRIP_SLIP_STRAIN == 0.0
    assert taut_reach(0) == 0.0 and taut_reach(20) == pytest.approx(20 * REST_SPACING)
    np.testing.assert_allclose(taut_reach([1, 2]), [REST_SPACING, 2 * REST_SPACING])


def test_a_firm_grip_on_a_taut_cable_stops_going_further_but_moves_sideways_and_back():
    cable, firm = straight(), held([20, 21, 22])
    np.testing.assert_allclose(stall_firm_grip(cable, firm, (STEP, 0.0, 0.0)), 0.0, atol=1e-15)
    np.testing.assert_allclose(stall_firm_grip(cable, firm, (STEP, STEP, 0.0)), (0.0, STEP, 0.0), atol=1e-15)
    np.testing.assert_allclose(stall_firm_grip(cable, firm, (0.0, -STEP, 0.0)), (0.0, -STEP, 0.0))
    np.testing.assert_allclose(stall_firm_grip(cable, firm, (-STEP, 0.0, 0.0)), (-STEP, 0.0, 0.0))


def test_the_stall_is_horizontal_only():
    raised = straight()
    raised[1:, 2] += 0.01  # the held part higher than the fixed end: the outward direction has a z part
    allowed = stall_firm_grip(raised, held([20]), (STEP, 0.0, 0.0))
    assert allowed[2] == 0.0 and abs(allowed[0]) < 1e-15


@pytest.mark.parametrize(
    "cable, carried",
    [
        (straight(), held([20, 21], closure=0.85)),  # sliding grip: slides through the fingers instead
        (straight(), held([20, 21], closure=0.5)),
        (straight(stretch=0.8), held([20, 21])),  # slack cable: the firm grip carries it
        (straight(), np.zeros(30)),  # nothing between the fingers
        (straight(), held([0])),  # the fixed end is not a held particle
    ],
)
def test_no_stall_without_a_firm_grip_on_a_taut_cable(cable, carried):
    np.testing.assert_allclose(stall_firm_grip(cable, carried, (STEP, 0.0, 0.0)), (STEP, 0.0, 0.0))


def test_a_firm_grip_near_its_reach_may_move_until_taut():
    cable = straight(stretch=0.999)  # particle 20 about 0.09 mm short of its reach
    firm = held([20])
    np.testing.assert_allclose(stall_firm_grip(cable, firm, (0.00005, 0.0, 0.0)), (0.00005, 0.0, 0.0))
    np.testing.assert_allclose(stall_firm_grip(cable, firm, (STEP, 0.0, 0.0)), 0.0, atol=1e-15)


def test_each_firm_particle_removes_its_own_outward_part_in_index_order():
    cable = straight()
    diagonal = np.array([np.cos(0.5), np.sin(0.5), 0.0])
    cable[21] = cable[0] + 21 * REST_SPACING * diagonal  # taut towards +x+y
    allowed = stall_firm_grip(cable, held([20, 21]), (STEP, STEP, 0.0))
    after_20 = np.array([0.0, STEP, 0.0])  # particle 20 (along +x) removes the x part first
    expected = after_20 - (after_20 @ diagonal) * diagonal  # then particle 21 its outward part of the rest
    np.testing.assert_allclose(allowed, expected, atol=1e-15)
    assert allowed @ diagonal == pytest.approx(0.0, abs=1e-15) and allowed[0] <= 0.0


def test_inputs_are_not_modified():
    cable, dg = straight(), np.array([STEP, 0.0, 0.0])
    stall_firm_grip(cable, held([20]), dg)
    assert dg[0] == STEP and cable[20, 0] == pytest.approx(FIXED_END[0] + 20 * REST_SPACING)


def test_the_single_particle_grip_picks_the_held_particle_nearest_the_finger_never_the_fixed_end():
    """dlo_interface.grip.single_grip_particle (docs/FIDELITY.md row 5): the held particle nearest the gripper in x,
    the lower index on a tie, never particle 0; -1 when nothing but particle 0 (or nothing) is held."""
    from dlo_interface.grip import single_grip_particle

    x = np.array([[0.0, 0, 0], [0.25, 0, 0], [0.5, 0, 0], [0.75, 0, 0], [1.0, 0, 0]], np.float32)  # exact in binary
    held = np.array([True, True, True, True, False])
    assert single_grip_particle(x, held, 0.7) == 3
    assert single_grip_particle(x, held, 0.95) == 3  # particle 4 is nearer, but not held
    assert single_grip_particle(x, held, 0.0) == 1  # particle 0 is nearer, but never carried
    assert single_grip_particle(x, held, 0.375) == 1  # an exact tie: the lower index
    assert single_grip_particle(x, [True, False, False, False, False], 0.0) == -1
    assert single_grip_particle(x, np.zeros(5, bool), 0.02) == -1


def test_a_firm_grip_on_the_first_free_particle_stalls_too():
    """stall_firm_grip: particle 1 (the first after the fixed end) held firmly on a taut cable stops the
    gripper's outward motion like any other; particle 0 (the fixed end) never stalls anything."""
    x = np.array([FIXED_END, np.add(FIXED_END, [REST_SPACING, 0.0, 0.0]), np.add(FIXED_END, [2 * REST_SPACING, 0.0, 0.0])])
    assert np.allclose(stall_firm_grip(x, [0.0, 1.0, 0.0], [0.001, 0.0005, 0.0]), [0.0, 0.0005, 0.0])
    assert np.allclose(stall_firm_grip(x, [1.0, 0.0, 0.0], [0.001, 0.0005, 0.0]), [0.001, 0.0005, 0.0])
