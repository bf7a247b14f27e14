"""The vision ground truth (visual_pose_ground_truth, line_slope) on hand-placed particles, rule by
rule and at the rules' edges (issue 14, found by tools/mutation_check.sh): which particle is the
entry, which way the cable is walked, where following stops, what is padding, and the line fit."""

import numpy as np
import pytest

from dlo_perception.vision import (CONFIDENCE_LENGTH, ENTRY_BAND, OCCLUSION_RADIUS, SEARCH_HALF_WIDTH,
                                   TRACK_LENGTH, line_slope, visual_pose_ground_truth)

X_O = OCCLUSION_RADIUS  # occlusion edge for a gripper at the origin


def truth(*cables, pad=0, gripper=(0.0, 0.0)):
    """Ground truth of one env per cable ((K, 2) [m] points in index order), padded to a common size."""
    size = max(len(c) for c in cables) + pad
    positions = np.full((len(cables), size, 3), 0.0)
    for e, cable in enumerate(cables):
        positions[e, :len(cable), :2] = cable
    return visual_pose_ground_truth(positions, [len(c) for c in cables], np.tile(gripper, (len(cables), 1)))


def run(start, step, count):
    return np.asarray(start, float) + np.arange(count)[:, None] * np.asarray(step, float)


def test_the_entry_is_the_candidate_nearest_the_gripper_in_y():
    upper = run((X_O + 0.002, 0.004), (0.004, 0.0), 4)   # |dy| = 0.004
    lower = run((X_O + 0.001, -0.010), (0.004, 0.0), 4)  # dy = -0.010: smaller signed, farther
    pose = truth(np.vstack([lower, upper]))
    assert pose.visible[0] and pose.y[0] == pytest.approx(0.004)
    pose = truth(np.vstack([upper, lower]) * [1, -1])  # mirrored: the nearer one is below now
    assert pose.y[0] == pytest.approx(-0.004)


def test_entry_band_and_search_width_edges_are_inclusive():
    assert truth(np.array([[X_O, 0.0]])).confidence[0] == 0.0  # exactly at the occlusion edge: visible
    assert truth(np.array([[X_O, 0.0]])).visible[0]
    assert truth(np.array([[0.05, SEARCH_HALF_WIDTH]]), gripper=(0.05 - X_O, 0.0)).visible[0]
    assert truth(np.array([[0.05, -SEARCH_HALF_WIDTH]]), gripper=(0.05 - X_O, 0.0)).y[0] == -SEARCH_HALF_WIDTH
    gx = next(g for g in np.arange(0.0, 0.01, 0.0001) if (g + X_O + ENTRY_BAND) - (g + X_O) == ENTRY_BAND)
    far_edge = truth(np.array([[gx + X_O + ENTRY_BAND, 0.0]]), gripper=(gx, 0.0))
    assert far_edge.visible[0] and far_edge.confidence[0] == pytest.approx(ENTRY_BAND / CONFIDENCE_LENGTH)
    for outside in ([X_O - 1e-6, 0.0], [X_O + ENTRY_BAND + 1e-6, 0.0], [X_O + 0.001, SEARCH_HALF_WIDTH + 1e-6],
                    [X_O + 0.001, -0.05]):
        pose = truth(np.array([outside]))
        assert not pose.visible[0] and (pose.confidence[0], pose.angle[0], pose.y[0]) == (0.0, 0.0, 0.0), outside


def test_padding_is_never_a_candidate_nor_followed():
    cable = run((-0.1, 0.0), (0.0043, 0.0), 3)  # far left of the gripper
    positions = np.zeros((1, 6, 3))
    positions[0, :3, :2] = cable
    positions[0, 3:, :2] = run((X_O + 0.001, 0.0), (0.004, 0.0), 3)  # leftovers of a longer cable
    assert not visual_pose_ground_truth(positions, [3], [(0.0, 0.0)]).visible[0]
    # a cable that ends 2 particles right of its entry: the padding after it is not followed
    positions[0, :3, :2] = run((X_O + 0.001, 0.0), (0.004, 0.001), 3)
    positions[0, 3:, :2] = run((X_O + 0.013, 0.002), (0.004, 0.0), 3)
    pose = visual_pose_ground_truth(positions, [3], [(0.0, 0.0)])
    assert pose.confidence[0] == pytest.approx(0.009 / CONFIDENCE_LENGTH)
    assert pose.angle[0] == pytest.approx(np.arctan(0.25))


def test_an_entry_at_the_free_end_looks_back_not_into_the_padding():
    # indices run rightwards and the free end is the entry: walking on would leave the cable
    cable = run((X_O - 0.02, 0.0), (0.0043, 0.0), 6)
    cable[-1, 0] = X_O + 0.003
    positions = np.zeros((1, 8, 3))
    positions[0, :6, :2] = cable
    positions[0, 6:, :2] = [[X_O + 0.007, 0.0], [X_O + 0.011, 0.0]]  # stale rows to the right
    pose = visual_pose_ground_truth(positions, [6], [(0.0, 0.0)])
    assert pose.visible[0] and pose.confidence[0] == pytest.approx(0.003 / CONFIDENCE_LENGTH) and pose.angle[0] == 0.0
    # indices run leftwards (fixed end on the right) and the entry is the last index: walk to lower indices
    back = run((X_O + 0.001, 0.0), (0.004, 0.002), 4)[::-1]  # index 3 = entry, index 0 rightmost
    positions = np.zeros((1, 6, 3))
    positions[0, :4, :2] = back
    positions[0, 4:, :2] = [[X_O + 0.030, 0.0], [X_O + 0.034, 0.0]]
    pose = visual_pose_ground_truth(positions, [4], [(0.0, 0.0)])
    assert pose.confidence[0] == pytest.approx(0.013 / CONFIDENCE_LENGTH)  # followed down to index 0
    assert pose.angle[0] == pytest.approx(np.arctan(0.5))


def test_a_cable_that_fills_the_whole_array():
    forward = run((X_O + 0.001, 0.0), (0.002, 0.0), 8)  # 8 of 8 rows, walked forwards past the last row
    assert truth(forward).confidence[0] == pytest.approx(0.015 / CONFIDENCE_LENGTH)
    backward = forward[::-1]  # entry in the last row
    assert truth(backward).confidence[0] == pytest.approx(0.015 / CONFIDENCE_LENGTH)


def test_at_most_eleven_particles_are_followed():
    pose = truth(run((X_O + 0.001, 0.001), (0.002, 0.0), 20))
    assert pose.confidence[0] == pytest.approx((0.001 + 10 * 0.002) / CONFIDENCE_LENGTH)


def test_following_stops_at_the_first_step_left_and_beyond_the_track():
    zigzag = np.array([[X_O + 0.001, 0.0], [X_O + 0.004, 0.001], [X_O + 0.007, 0.002],  # right, slope 1/3
                       [X_O + 0.005, 0.010], [X_O + 0.012, 0.020], [X_O + 0.016, 0.030]])  # left, then right again
    long = run((X_O + 0.002, 0.0), (0.0043, 0.0043), 14)  # 45 deg: leaves the track after 10 steps
    pose = truth(zigzag, long)
    assert pose.confidence[0] == pytest.approx(0.007 / CONFIDENCE_LENGTH)
    assert pose.angle[0] == pytest.approx(np.arctan(1 / 3))
    assert pose.confidence[1] == 1.0 and pose.angle[1] == pytest.approx(np.pi / 4)
    assert pose.y.tolist() == [0.0, 0.0]


def test_a_step_straight_across_is_not_rightward():
    # the entry's next index lies straight above it: walk the other way, where the cable heads right
    back = np.array([[X_O + 0.005, 0.001], [X_O + 0.001, 0.0], [X_O + 0.001, 0.010]])
    pose = truth(back)
    assert pose.y[0] == 0.0 and pose.confidence[0] == pytest.approx(0.005 / CONFIDENCE_LENGTH)
    assert pose.angle[0] == pytest.approx(np.arctan(0.25))
    # walking on, a step straight across ends the strand
    across = np.array([[X_O + 0.001, 0.0], [X_O + 0.004, 0.0], [X_O + 0.004, 0.003], [X_O + 0.008, 0.003]])
    assert truth(across).confidence[0] == pytest.approx(0.004 / CONFIDENCE_LENGTH)


def test_the_track_length_is_inclusive():
    gx = next(g for g in np.arange(0.0, 0.01, 0.0001) if (g + X_O + TRACK_LENGTH) - (g + X_O) == TRACK_LENGTH)
    x_o = gx + X_O
    cable = np.array([[x_o + 0.001, 0.0], [x_o + TRACK_LENGTH, 0.01], [x_o + TRACK_LENGTH + 0.004, 0.02]])
    pose = truth(cable, gripper=(gx, 0.0))
    assert pose.angle[0] == pytest.approx(np.arctan(0.01 / (TRACK_LENGTH - 0.001)))


def test_rows_of_a_batch_are_independent():
    a = run((X_O + 0.001, 0.002), (0.003, 0.0015), 3)
    b = run((X_O + 0.004, -0.001), (0.002, -0.002), 5)
    both = truth(a, b)
    for e, cable in enumerate((a, b)):
        alone = truth(cable, pad=len(b) - len(cable) if e == 0 else 0)
        assert (both.confidence[e], both.angle[e], both.y[e]) == pytest.approx(
            (alone.confidence[0], alone.angle[0], alone.y[0]))
    assert both.confidence == pytest.approx([0.007 / CONFIDENCE_LENGTH, 0.012 / CONFIDENCE_LENGTH])
    assert both.angle == pytest.approx([np.arctan(0.5), -np.pi / 4])


def test_line_slope_per_row():
    xs = np.array([[0.0, 1.0, 2.0, 3.0, 4.0], [5.0, 6.0, 7.0, 8.0, 9.0], [1.0, 1.0, 1.0, 1.0, 1.0]])
    ys = np.array([[1.0, 3.0, 5.0, 7.0, 100.0], [2.0, 1.5, 1.0, 0.5, 0.0], [0.0, 1.0, 2.0, 3.0, 4.0]])
    mask = np.array([[True, True, True, True, False], [True, True, False, False, False], [True] * 5])
    with np.errstate(all="raise"):
        assert line_slope(xs, ys, mask).tolist() == pytest.approx([2.0, -0.5, 0.0])  # 2 samples suffice
        one = np.zeros_like(mask)
        one[:, 0] = True
        assert line_slope(xs, ys, one).tolist() == [0.0, 0.0, 0.0]  # one sample: no slope
        assert line_slope(xs, ys, np.zeros_like(mask)).tolist() == [0.0, 0.0, 0.0]  # none
