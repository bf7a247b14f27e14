"""Vision distillation on synthetic top-view images drawn with TopCamera, and its particle ground truth."""

import numpy as np
import pytest
from dlo_perception.camera import TopCamera
from dlo_perception.vision import visual_pose, visual_pose_ground_truth

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
    v, u = np.mgrid[0:camera.height, 0:camera.width]
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
    "crossing_steep": ([held_then_bent(0.0), polyline(GRIPPER + [0.01, -0.05], np.pi / 3, 0.12)],
                       (True, 1.0, 0.0, 0.0)),
    "crossing_back": ([held_then_bent(0.0), polyline(GRIPPER + [0.05, -0.05], np.pi / 2 + 0.3, 0.12)],
                      (True, 1.0, 0.0, 0.0)),
    # Another part of the cable farther from the gripper in y: the nearer strand wins.
    "parallel_far_part": ([held_then_bent(0.0), polyline(GRIPPER + [-0.1, 0.025], 0.0, 0.3)],
                          (True, 1.0, 0.0, 0.0)),
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


def test_ground_truth_follows_the_cable_backwards_when_indices_run_leftwards():
    cable = held_then_bent(0.2)[::-1]  # fixed end on the right
    truth = visual_pose_ground_truth(cable[None], [len(cable)], GRIPPER[None])
    assert truth.visible[0] and truth.confidence[0] == 1.0
    assert truth.angle[0] == pytest.approx(0.2)
