"""dlo_perception.tactile beyond its statistics (issue 14, found by tools/mutation_check.sh): the
exact noise model (one draw for the angle, then one for y, scaled by 1 - c_G, c_G clipped to [0, 1]),
each sigma on its own, the generator used as given and untouched without noise, the y range, full
gripper states as input, scalar results for one sample, and no invalid arithmetic without contact."""

import warnings

import numpy as np
import pytest

from dlo_perception.tactile import Y_LIMIT, tactile_pose, wrap_line_angle

G = np.array([0.05, -0.02])


def line(angle, offset, count=5, spacing=0.0043):
    s = (np.arange(count) - (count - 1) / 2) * spacing + 0.001
    return G + [0.0, offset] + s[:, None] * np.array([np.cos(angle), np.sin(angle)])


POINTS = np.stack([line(0.3, 0.002), line(-0.5, -0.004), line(1.2, 0.001)])
HELD = np.ones((3, 5), bool)
GRIPPERS = np.tile(G, (3, 1))


def exact():
    return tactile_pose(POINTS, HELD, GRIPPERS, np.zeros(3))


def test_noise_is_one_draw_for_the_angle_then_one_for_y_scaled_by_the_opening():
    closure = np.array([0.0, 0.25, 0.8])
    pose = tactile_pose(POINTS, HELD, GRIPPERS, closure, sigma=(0.3, 0.004), rng=np.random.default_rng(7))
    reference = np.random.default_rng(7)
    d_angle = reference.normal(0.0, 0.3, 3)
    d_y = reference.normal(0.0, 0.004, 3)
    base = exact()
    np.testing.assert_allclose(pose.angle, wrap_line_angle(base.angle + (1 - closure) * d_angle), atol=1e-12)
    np.testing.assert_allclose(pose.y, np.clip(base.y + (1 - closure) * d_y, -Y_LIMIT, Y_LIMIT), atol=1e-12)


@pytest.mark.parametrize("closure", [1.0, 1.5])
def test_a_closed_gripper_has_no_noise_even_past_1(closure):
    pose = tactile_pose(POINTS, HELD, GRIPPERS, np.full(3, closure), sigma="full", rng=np.random.default_rng(1))
    np.testing.assert_allclose(pose.angle, exact().angle, atol=1e-12)
    np.testing.assert_allclose(pose.y, exact().y, atol=1e-12)


def test_a_negative_closure_counts_as_open():
    a = tactile_pose(POINTS, HELD, GRIPPERS, np.full(3, -0.5), sigma="full", rng=np.random.default_rng(2))
    b = tactile_pose(POINTS, HELD, GRIPPERS, np.zeros(3), sigma="full", rng=np.random.default_rng(2))
    np.testing.assert_array_equal(a.angle, b.angle)
    np.testing.assert_array_equal(a.y, b.y)


def test_each_sigma_acts_alone():
    only_y = tactile_pose(POINTS, HELD, GRIPPERS, np.zeros(3), sigma=(0.0, 0.001), rng=np.random.default_rng(3))
    np.testing.assert_allclose(only_y.angle, exact().angle, atol=1e-12)
    assert np.all(np.abs(only_y.y - exact().y) > 1e-7)
    only_angle = tactile_pose(POINTS, HELD, GRIPPERS, np.zeros(3), sigma=(0.1, 0.0), rng=np.random.default_rng(3))
    np.testing.assert_allclose(only_angle.y, exact().y, atol=1e-12)
    assert np.all(np.abs(only_angle.angle - exact().angle) > 1e-7)


def test_the_generator_is_the_one_given_and_untouched_without_noise():
    rng = np.random.default_rng(4)
    state = rng.bit_generator.state
    tactile_pose(POINTS, HELD, GRIPPERS, np.zeros(3), sigma="none", rng=rng)
    assert rng.bit_generator.state == state  # the env's noise stream is not consumed
    a = tactile_pose(POINTS, HELD, GRIPPERS, np.zeros(3), sigma="full", rng=np.random.default_rng(9))
    b = tactile_pose(POINTS, HELD, GRIPPERS, np.zeros(3), sigma="full", rng=np.random.default_rng(9))
    np.testing.assert_array_equal(a.angle, b.angle)
    unseeded = tactile_pose(POINTS, HELD, GRIPPERS, np.zeros(3), sigma="full")  # rng=None: a fresh generator
    assert np.all(np.isfinite(unseeded.angle)) and np.all(np.abs(unseeded.y) <= Y_LIMIT)


def test_y_stays_within_its_limit_with_noise_and_for_lines_along_the_finger():
    along = tactile_pose(line(np.pi / 2, 0.0) + [0.004, 0.0], np.ones(5, bool), G, 1.0)  # parallel to the finger
    assert abs(along.angle) == pytest.approx(np.pi / 2) and abs(along.y) == Y_LIMIT
    near_edge = np.stack([line(0.0, 0.028)] * 200)
    noisy = tactile_pose(near_edge, np.ones((200, 5), bool), np.tile(G, (200, 1)), np.zeros(200), sigma=(0.0, 0.05),
                         rng=np.random.default_rng(5))
    assert np.all(np.abs(noisy.y) <= Y_LIMIT) and np.any(noisy.y == Y_LIMIT) and np.any(noisy.y < 0.0)


def test_full_gripper_states_and_single_samples():
    full_state = np.column_stack([GRIPPERS, np.full(3, 0.1), np.ones(3)])  # x, y, z, c
    pose = tactile_pose(POINTS, HELD, full_state, np.ones(3))
    np.testing.assert_allclose(pose.angle, exact().angle, atol=1e-12)
    np.testing.assert_allclose(pose.y, exact().y, atol=1e-12)
    single = tactile_pose(POINTS[1], HELD[1], G, 1.0)
    assert type(single.angle) is float and type(single.y) is float
    assert type(single.contact) is bool and type(single.count) is int
    assert single.angle == pytest.approx(-0.5) and single.y == pytest.approx(-0.004) and single.count == 5


def test_no_contact_needs_no_invalid_arithmetic():
    held = np.zeros((3, 5), bool)
    held[1, 0] = True
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with np.errstate(all="raise"):
            pose = tactile_pose(POINTS, held, GRIPPERS, np.zeros(3))
    assert pose.contact.tolist() == [False, False, False] and pose.count.tolist() == [0, 1, 0]
