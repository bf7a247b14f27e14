"""dlo_perception.vision: the visual pose distilled from synthetic top-view images drawn with TopCamera
(crossing and parallel strands, occlusion by the gripper, a short visible end; an image alone equals its
row of a batch), and its particle ground truth (visual_pose_ground_truth, line_slope) on hand-placed
particles, rule by rule and at the rules' edges: which particle is the entry, which way the cable is
walked, where following stops, what is padding, and the line fit."""

import numpy as np
import pytest
from dlo_interface.camera import TopCamera
from dlo_perception.vision import (
    CONFIDENCE_LENGTH,
    ENTRY_BAND,
    OCCLUSION_RADIUS,
    SEARCH_HALF_WIDTH,
    TRACK_LENGTH,
    line_slope,
    visual_pose,
    visual_pose_ground_truth,
)

CAMERA = TopCamera.covering_workspace(128)
PLANE_Z = 0.1  # m, gripper height; the synthetic cable lies in this plane too
CABLE_RADIUS = 0.008  # m
FINGER_RADIUS = 0.0125  # m
FINGER_HALF_LENGTH = 0.0075  # m


def segment_distance(points, a, b):
    """Distance [m] from points (..., 2) to the segment a-b (2,)."""
    ab = b - a
    t = np.clip(((points - a) @ ab) / max(ab @ ab, 1e-12), 0.0, 1.0)
    return np.linalg.norm(points - (a + t[..., None] * ab), axis=-1)


def draw(polylines, gripper_xy, camera=CAMERA, plane_z=PLANE_Z):
    """uint8 (H, W) image: cable polylines (list of (K, 2) arrays [m]) 255, gripper capsule 128 on top."""
    v, u = np.mgrid[0 : camera.height, 0 : camera.width]
    world = camera.pixel_to_world(np.stack([u + 0.5, v + 0.5], axis=-1), plane_z)
    image = np.zeros((camera.height, camera.width), np.uint8)
    for line in polylines:
        line = np.asarray(line, dtype=float)
        for a, b in zip(line[:-1], line[1:]):
            image[segment_distance(world, a, b) <= CABLE_RADIUS] = 255
    g = np.asarray(gripper_xy, dtype=float)
    finger = segment_distance(world, g + [0, -FINGER_HALF_LENGTH], g + [0, FINGER_HALF_LENGTH])
    image[finger <= FINGER_RADIUS] = 128
    return image


def polyline(start, angle, length, spacing=0.0043):
    """Points [m] of a straight cable from start (2,) at angle [rad] to world x, spaced like particles."""
    s = np.arange(0.0, length + 1e-9, spacing)
    return np.asarray(start, float) + s[:, None] * np.array([np.cos(angle), np.sin(angle)])


GRIPPER = np.array([0.02, -0.03])


def held_then_bent(angle, offset=0.0):
    """Cable along x through the gripper (y_G + offset) that bends by angle [rad] at x_G."""
    start = GRIPPER + [0.0, offset]
    return np.vstack([polyline(start - [0.27, 0.0], 0.0, 0.27), polyline(start, angle, 0.2)[1:]])


SCENES = {
    "straight": ([polyline(GRIPPER + [-0.27, 0.005], 0.0, 0.4)], (True, 1.0, 0.0, 0.005)),
    "tilted_up": ([held_then_bent(0.4)], (True, 1.0, 0.4, 0.0165 * np.tan(0.4))),
    "tilted_down": ([held_then_bent(-0.6, 0.004)], (True, 1.0, -0.6, 0.004 - 0.0165 * np.tan(0.6))),
    # Crossing strands right of the gripper: keep following the held strand, no jump onto the other.
    "crossing_steep": ([held_then_bent(0.0), polyline(GRIPPER + [0.01, -0.05], np.pi / 3, 0.12)], (True, 1.0, 0.0, 0.0)),
    "crossing_back": ([held_then_bent(0.0), polyline(GRIPPER + [0.05, -0.05], np.pi / 2 + 0.3, 0.12)], (True, 1.0, 0.0, 0.0)),
    # Another part of the cable farther from the gripper in y: the nearer strand wins.
    "parallel_far_part": ([held_then_bent(0.0), polyline(GRIPPER + [-0.1, 0.025], 0.0, 0.3)], (True, 1.0, 0.0, 0.0)),
    # The cable ends under the gripper: hidden by it.
    "occluded_by_gripper": ([polyline(GRIPPER - [0.27, 0.0], 0.0, 0.275)], (False, 0.0, 0.0, 0.0)),
    "cable_far_away": ([polyline(GRIPPER + [0.03, 0.13], 0.0, 0.2)], (False, 0.0, 0.0, 0.0)),
    "absent": ([], (False, 0.0, 0.0, 0.0)),
}
PIXEL = CAMERA.metres_per_pixel(PLANE_Z)  # ~4.2 mm


@pytest.fixture(scope="module")
def batch():
    images = np.stack([draw(lines, GRIPPER) for lines, _ in SCENES.values()])
    return images, visual_pose(images, CAMERA, np.tile(GRIPPER, (len(images), 1)), PLANE_Z)


@pytest.mark.parametrize("index, name", list(enumerate(SCENES)))
def test_image_pose_on_synthetic_scenes(batch, index, name):
    _, pose = batch
    visible, confidence, angle, y = SCENES[name][1]
    assert bool(pose.visible[index]) == visible
    assert pose.confidence[index] == pytest.approx(confidence, abs=0.05)
    assert pose.angle[index] == pytest.approx(angle, abs=0.08)
    assert pose.y[index] == pytest.approx(y, abs=0.5 * PIXEL)


def test_single_image_equals_its_row_in_the_batch(batch):
    images, pose = batch
    one = visual_pose(images[2:3], CAMERA, GRIPPER[None], PLANE_Z)
    assert one.angle[0] == pose.angle[2] and one.y[0] == pose.y[2] and one.confidence[0] == pose.confidence[2]


def test_an_empty_batch_gives_empty_readings(batch):
    images, _ = batch
    pose = visual_pose(images[:0], CAMERA, np.empty((0, 2)), PLANE_Z)
    assert [np.shape(field) for field in (pose.visible, pose.confidence, pose.angle, pose.y)] == [(0,)] * 4


def test_short_visible_end_gives_low_confidence():
    cable = polyline(GRIPPER - [0.27, 0.0], 0.0, 0.292)  # ends ~20 mm right of the gripper centre
    image_pose = visual_pose(draw([cable], GRIPPER)[None], CAMERA, GRIPPER[None], PLANE_Z)
    truth = visual_pose_ground_truth(cable[None], [len(cable)], GRIPPER[None])
    assert image_pose.visible[0] and truth.visible[0]
    assert truth.confidence[0] < 0.3
    assert image_pose.confidence[0] == pytest.approx(truth.confidence[0], abs=0.25)


@pytest.mark.parametrize("name", ["straight", "tilted_up", "tilted_down", "crossing_steep", "occluded_by_gripper"])
def test_ground_truth_from_particles(name):
    lines, (visible, confidence, angle, y) = SCENES[name]
    cable = lines[0]
    truth = visual_pose_ground_truth(np.pad(cable, ((0, 5), (0, 1)))[None], [len(cable)], GRIPPER[None])
    assert bool(truth.visible[0]) == visible
    assert truth.confidence[0] == pytest.approx(confidence)
    assert truth.angle[0] == pytest.approx(angle, abs=1e-6)
    assert truth.y[0] == pytest.approx(y, abs=0.0043 * abs(np.tan(angle)) + 1e-6)


def test_ground_truth_of_an_empty_batch_is_empty():
    truth = visual_pose_ground_truth(np.empty((0, 8, 3)), np.empty(0, int), np.empty((0, 2)))
    assert [np.shape(field) for field in (truth.visible, truth.confidence, truth.angle, truth.y)] == [(0,)] * 4


def test_ground_truth_follows_the_cable_backwards_when_indices_run_leftwards():
    cable = held_then_bent(0.2)[::-1]  # fixed end on the right
    truth = visual_pose_ground_truth(cable[None], [len(cable)], GRIPPER[None])
    assert truth.visible[0] and truth.confidence[0] == 1.0
    assert truth.angle[0] == pytest.approx(0.2)


# ---------------------------------------------------------------- the ground truth rule by rule
X_O = OCCLUSION_RADIUS  # occlusion edge for a gripper at the origin


def truth(*cables, pad=0, gripper=(0.0, 0.0)):
    """Ground truth of one env per cable ((K, 2) [m] points in index order), padded to a common size."""
    size = max(len(c) for c in cables) + pad
    positions = np.full((len(cables), size, 3), 0.0)
    for e, cable in enumerate(cables):
        positions[e, : len(cable), :2] = cable
    return visual_pose_ground_truth(positions, [len(c) for c in cables], np.tile(gripper, (len(cables), 1)))


def run(start, step, count):
    return np.asarray(start, float) + np.arange(count)[:, None] * np.asarray(step, float)


def test_the_entry_is_the_candidate_nearest_the_gripper_in_y():
    upper = run((X_O + 0.002, 0.004), (0.004, 0.0), 4)  # |dy| = 0.004
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
    for outside in (
        [X_O - 1e-6, 0.0],
        [X_O + ENTRY_BAND + 1e-6, 0.0],
        [X_O + 0.001, SEARCH_HALF_WIDTH + 1e-6],
        [X_O + 0.001, -0.05],
    ):
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
    zigzag = np.array(
        [
            [X_O + 0.001, 0.0],
            [X_O + 0.004, 0.001],
            [X_O + 0.007, 0.002],  # right, slope 1/3
            [X_O + 0.005, 0.010],
            [X_O + 0.012, 0.020],
            [X_O + 0.016, 0.030],
        ]
    )  # left, then right again
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
        assert (both.confidence[e], both.angle[e], both.y[e]) == pytest.approx((alone.confidence[0], alone.angle[0], alone.y[0]))
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
