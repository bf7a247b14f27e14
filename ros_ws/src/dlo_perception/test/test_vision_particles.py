"""The particles vision source (``visual_pose_particles``) against a literal, one-environment reading of
the authors' index walk (SoftSlidingGym ``rope_sliding_env.py`` ``_get_obs``), on hand-made and random
cables: every entry, every branch."""

import numpy as np
import pytest
from dlo_perception.vision import (
    BACKTRACK,
    CONFIDENCE_LENGTH,
    OCCLUSION_RADIUS,
    VISION_SOURCES,
    WALK_STEPS,
    check_vision_source,
    line_slope,
    visual_pose_particles,
)

P = 60


def reference(positions, held, n_c, gripper):
    """One environment, loop by loop as the authors wrote it (their segment count s = n_c - 1)."""
    idx = np.flatnonzero(held)
    if idx.size < 2:
        return 0.0, 0.0, 0.0, 0.0
    s = n_c - 1
    x, y = positions[:, 0], positions[:, 1]
    side = gripper[0] + OCCLUSION_RADIUS
    edge = idx[-1]
    for j in range(WALK_STEPS):
        if x[idx[-1] + j] - side > 0 or idx[-1] + j + 1 >= s:
            edge = idx[-1] + j
            break
    if edge + 1 >= s:
        visible, y_out = 0.0, 0.0
    else:
        visible, y_out = 1.0, y[edge + 1] - gripper[1]
    for j in range(WALK_STEPS):
        right = edge + j
        if x[right] - x[edge] < -BACKTRACK or right + 1 >= s:
            break
    if x[right] <= x[edge]:
        return visible, 0.0, 0.0, y_out
    confidence = min(1.0, (x[right] - x[edge]) / CONFIDENCE_LENGTH)
    xs, ys = x[edge:right], y[edge:right]
    slope = line_slope(xs[None], ys[None], np.ones((1, xs.size), bool))[0]
    return visible, confidence, np.arctan(slope), y_out


def cable(n_c, step=(0.0043, 0.0), start=(-0.25, 0.0), bend=0.0, rng=None):
    """(P, 3) positions of a cable of n_c particles: a chain of steps turning by ``bend`` rad each,
    with random jitter when ``rng`` is given; padding 0."""
    positions = np.zeros((P, 3))
    angle = np.arctan2(step[1], step[0])
    length = np.hypot(*step)
    point = np.array(start, float)
    for i in range(n_c):
        positions[i, :2] = point
        positions[i, 2] = 0.1
        if rng is not None:
            angle += rng.normal(0.0, 0.6)
        angle += bend
        point = point + length * np.array([np.cos(angle), np.sin(angle)])
    return positions


def run_both(positions, held, n_c, gripper):
    pose = visual_pose_particles(positions[None], held[None], [n_c], np.asarray(gripper)[None])
    ours = (float(pose.visible[0]), pose.confidence[0], pose.angle[0], pose.y[0])
    return ours, reference(positions, held, n_c, gripper)


def held_at(indices):
    held = np.zeros(P, bool)
    held[list(indices)] = True
    return held


def test_a_straight_cable_is_visible_with_full_confidence_and_no_angle():
    positions = cable(40)
    gripper = positions[10, :2]
    ours, theirs = run_both(positions, held_at([9, 10, 11]), 40, gripper)
    assert ours == pytest.approx(theirs)
    assert ours[0] == 1.0 and ours[1] == 1.0 and abs(ours[2]) < 1e-9
    assert ours[3] == pytest.approx(0.0, abs=1e-12)


def test_near_the_end_the_cable_is_no_longer_visible():
    """The authors' last-index check uses their segment count: the edge at n_c - 2 already hides the cable."""
    positions = cable(40)
    for last_held, visible in ((36, 1.0), (37, 1.0), (38, 0.0), (39, 0.0)):
        gripper = positions[last_held, :2] - [0.02, 0.0]  # the held particles all right of the occlusion edge
        ours, theirs = run_both(positions, held_at([last_held - 1, last_held]), 40, gripper)
        assert ours == pytest.approx(theirs)
        assert ours[0] == visible, last_held


def test_fewer_than_two_held_particles_see_nothing():
    positions = cable(40)
    for held in (held_at([]), held_at([12])):
        ours, theirs = run_both(positions, held, 40, positions[12, :2])
        assert ours == (0.0, 0.0, 0.0, 0.0) == theirs


def test_a_cable_that_turns_back_right_after_the_edge_has_no_confidence():
    positions = cable(40, bend=0.9)  # curls back within a few particles
    ours, theirs = run_both(positions, held_at([5, 6]), 40, positions[6, :2])
    assert ours == pytest.approx(theirs)
    assert ours[1] == 0.0 and ours[2] == 0.0


def test_a_bent_cable_gives_the_angle_of_the_fitted_line():
    positions = cable(40, step=(0.0043 * np.cos(0.3), 0.0043 * np.sin(0.3)))
    ours, theirs = run_both(positions, held_at([8, 9, 10]), 40, positions[10, :2])
    assert ours == pytest.approx(theirs)
    assert ours[2] == pytest.approx(0.3, abs=1e-9)


@pytest.mark.parametrize("seed", range(5))
def test_random_cables_match_the_reference_entry_by_entry(seed):
    rng = np.random.default_rng(seed)
    batch, rows = [], []
    for _ in range(200):
        n_c = int(rng.integers(30, 61))
        positions = cable(n_c, rng=rng)
        first = int(rng.integers(1, n_c))
        held = held_at(range(first, min(first + int(rng.integers(0, 5)), n_c)))
        gripper = positions[first, :2] + rng.normal(0.0, 0.005, 2)
        batch.append((positions, held, n_c, gripper))
        rows.append(reference(positions, held, n_c, gripper))
    positions, held, n_c, gripper = (np.array(v) for v in zip(*batch))
    pose = visual_pose_particles(positions, held, n_c, gripper)
    ours = np.stack([pose.visible.astype(float), pose.confidence, pose.angle, pose.y], axis=1)
    np.testing.assert_allclose(ours, np.array(rows), rtol=0, atol=1e-12)
    assert 0 < pose.visible.sum() < len(rows)  # both branches seen
    assert 0 < (pose.confidence > 0).sum() < len(rows)


def test_an_empty_batch_gives_empty_readings():
    pose = visual_pose_particles(np.zeros((0, P, 3)), np.zeros((0, P), bool), np.zeros(0, int), np.zeros((0, 2)))
    assert pose.visible.shape == pose.confidence.shape == pose.angle.shape == pose.y.shape == (0,)


def test_vision_source_is_checked():
    assert [check_vision_source(s) for s in VISION_SOURCES] == list(VISION_SOURCES)
    with pytest.raises(ValueError, match="vision_source: expected one of image, particles, got 'camera'"):
        check_vision_source("camera")
