"""The driver template's force limit (no ROS graph): mock_driver_node moves its kinematic gripper with
``kinematic_move``, which stalls a firm grip on the taut mock cable as the sim does
(``dlo_interface.grip.stall_firm_grip``, the sim's rule, not a copy of it):

- driven along the cable to its end with a sliding grip, then closed firmly (closure >= 0.9) and
  commanded on at full speed, the gripper stays at the end of the cable (before: it drove on to
  the workspace edge); with the sliding grip it does drive on;
- closed firmly it still moves back, sideways only about the fixed end (never away from it, and it
  comes to rest), carrying the points between its fingers; away from the cable nothing stalls it;
- a sliding grip leaves the cable where it is; the workspace limit still holds.
"""

from __future__ import annotations

import numpy as np
import pytest
from dlo_driver_kit.mock_driver_node import CONTROL_RATE, kinematic_move, mock_cable, touching
from dlo_interface.command import MAX_SPEED
from dlo_interface.world import WORKSPACE_HALF_WIDTH

PERIOD = 1.0 / CONTROL_RATE
CABLE = mock_cable(0.2, 0.02)


def drive(gripper, closure, vx, vy=0.0, steps=1, cable=CABLE, with_cable=False):
    """The gripper after ``steps`` control periods of this command (and the cable, as the grip carried it)."""
    gripper = np.asarray(gripper, dtype=np.float64)
    for _ in range(steps):
        gripper, cable = kinematic_move(gripper, cable, vx, vy, closure, PERIOD)
    return (gripper, cable) if with_cable else gripper


def outward(before, after, gripper):
    """The largest motion [m] away from the fixed end along the directions to the touched points."""
    anchor, touched = CABLE[0, :2], CABLE[touching(CABLE, gripper), :2]
    r = (touched - anchor) / np.linalg.norm(touched - anchor, axis=1, keepdims=True)
    return float(np.max(r @ (np.asarray(after) - before)))


def test_closed_firmly_at_the_end_of_the_cable_the_gripper_stalls():
    at_end = CABLE[0, :2] - [0.005, 0.0]
    while at_end[0] < CABLE[-1, 0]:  # slide along the cable to its end (the sim's sliding grip), on the cable
        at_end = drive(at_end, 0.7, min(MAX_SPEED, (CABLE[-1, 0] - at_end[0]) / PERIOD + 1e-6))
        at_end[1] = np.interp(at_end[0], CABLE[:, 0], CABLE[:, 1])
    assert touching(CABLE, at_end)[-1]
    held, cable = drive(at_end, 1.0, MAX_SPEED, steps=40, with_cable=True)  # closes firmly, drives on for 3.2 s
    assert abs(held[0] - at_end[0]) < 0.001  # stalled at the end of the cable (0.8 m commanded) ...
    assert np.linalg.norm(held - at_end) < 0.015  # ... having swung the end of the S-curve straight
    assert np.linalg.norm(drive(held, 1.0, MAX_SPEED, steps=5, cable=cable) - held) < 1e-4  # at rest
    sliding = drive(at_end, 0.85, MAX_SPEED, steps=40)  # a sliding grip slides off the end and drives on
    assert sliding[0] == pytest.approx(WORKSPACE_HALF_WIDTH)


@pytest.mark.parametrize("index", [5, 20, 40])
def test_a_firm_grip_on_the_taut_mock_cable_moves_back_and_sideways_but_not_away(index):
    on_cable = CABLE[index, :2]
    for command in [(MAX_SPEED, 0.0), (MAX_SPEED, MAX_SPEED), (MAX_SPEED, -MAX_SPEED)]:  # all away from the fixed end
        moved = drive(on_cable, 1.0, *command)
        assert outward(on_cable, moved, on_cable) <= 1e-6  # what is left of it is sideways (1 um per sub-step)
    if index > 10:  # (closer to the fixed end, 0.02 m back takes the held points past it: outward again)
        back = drive(on_cable, 1.0, -MAX_SPEED)
        assert back[0] == pytest.approx(on_cable[0] - MAX_SPEED * PERIOD)
    assert drive(on_cable, 0.89, MAX_SPEED)[0] == pytest.approx(on_cable[0] + MAX_SPEED * PERIOD)  # sliding
    swung, cable = drive(on_cable, 1.0, MAX_SPEED, steps=60, with_cable=True)  # pulled on: it swings about the
    assert np.linalg.norm(drive(swung, 1.0, MAX_SPEED, steps=5, cable=cable) - swung) < 1e-4  # fixed end, stops
    assert np.linalg.norm(swung - CABLE[0, :2]) <= np.linalg.norm(on_cable - CABLE[0, :2]) + 0.001


def test_a_firm_grip_carries_the_points_between_the_fingers_a_sliding_one_leaves_the_cable():
    on_cable = CABLE[20, :2]
    gripper, carried = kinematic_move(on_cable, CABLE, 0.0, MAX_SPEED, 1.0, PERIOD)
    moved = np.flatnonzero(np.any(carried != CABLE, axis=1))
    np.testing.assert_array_equal(moved, np.flatnonzero(touching(CABLE, on_cable)))
    np.testing.assert_allclose(carried[moved, :2] - CABLE[moved, :2], np.broadcast_to(gripper - on_cable, (len(moved), 2)))
    assert carried[moved, 2] == pytest.approx(CABLE[moved, 2])  # in the horizontal plane
    gripper, same = kinematic_move(on_cable, CABLE, 0.0, MAX_SPEED, 0.85, PERIOD)
    assert same is CABLE and gripper[1] == pytest.approx(on_cable[1] + MAX_SPEED * PERIOD)


def test_away_from_the_cable_nothing_stalls_and_the_workspace_still_holds():
    free = np.array([0.0, 0.2])
    assert not touching(CABLE, free).any()
    assert drive(free, 1.0, MAX_SPEED)[0] == pytest.approx(MAX_SPEED * PERIOD)
    corner = drive(free, 1.0, MAX_SPEED, MAX_SPEED, steps=30)
    np.testing.assert_allclose(corner, [WORKSPACE_HALF_WIDTH, WORKSPACE_HALF_WIDTH])
