"""dlo_perception.tactile: the line fit of the held particles (angle and offset, only held particles,
batches and single samples, full gripper states as input, the y range, defined values and no invalid
arithmetic without contact), the noise model both statistically and exactly (one draw for the angle,
then one for y, scaled by 1 - c_G with c_G clipped to [0, 1]; each sigma on its own; the generator used
as given and untouched without noise), and the noise settings in every form, their labels and their ``-p``
form (what the launcher checks ``--tactile-noise`` with: tests/test_tactile_noise_setting.py)."""

import warnings

import numpy as np
import pytest
from dlo_perception.tactile import (
    NOISE_FORMS,
    TACTILE_NOISE,
    Y_LIMIT,
    noise_label,
    noise_parameter_value,
    noise_setting,
    noise_sigma,
    tactile_pose,
    wrap_line_angle,
)


def line_particles(angle, offset, gripper=(0.05, -0.02), count=5, spacing=0.0043):
    """Particles on a line through (x_G, y_G + offset) at angle [rad], centred on the gripper."""
    s = (np.arange(count) - (count - 1) / 2) * spacing + 0.001
    g = np.asarray(gripper)
    return g + [0.0, offset] + s[:, None] * np.array([np.cos(angle), np.sin(angle)])


G = np.array([0.05, -0.02])


def line(angle, offset, count=5, spacing=0.0043):
    """line_particles around the gripper G."""
    return line_particles(angle, offset, G, count, spacing)


POINTS = np.stack([line(0.3, 0.002), line(-0.5, -0.004), line(1.2, 0.001)])
HELD = np.ones((3, 5), bool)
GRIPPERS = np.tile(G, (3, 1))


def exact():
    return tactile_pose(POINTS, HELD, GRIPPERS, np.zeros(3))


# ---------------------------------------------------------------- the line fit
@pytest.mark.parametrize("angle, offset", [(0.0, 0.0), (0.0, 0.004), (0.3, -0.003), (-0.7, 0.006), (1.4, 0.0)])
def test_line_fit_recovers_angle_and_offset(angle, offset):
    points = line_particles(angle, offset)
    pose = tactile_pose(points, np.ones(len(points), bool), (0.05, -0.02), 1.0)
    assert pose.contact and pose.count == len(points)
    assert pose.angle == pytest.approx(angle, abs=1e-9)
    assert pose.y == pytest.approx(offset, abs=1e-9)


def test_only_held_particles_count_and_batch_matches_single():
    gripper = np.array([[0.05, -0.02], [0.1, 0.03]])
    held_line = line_particles(0.2, 0.002, gripper[0])
    far = np.array([[0.2, 0.2], [0.21, 0.25], [0.0, 0.0]])
    points = np.stack([np.vstack([held_line, far]), np.vstack([line_particles(-0.4, -0.005, gripper[1]), far])])
    held = np.zeros((2, 8), bool)
    held[:, :5] = True
    batch = tactile_pose(points, held, gripper, np.array([1.0, 0.9]))
    assert batch.angle == pytest.approx([0.2, -0.4])
    assert batch.y == pytest.approx([0.002, -0.005])
    assert batch.count.tolist() == [5, 5]
    single = tactile_pose(points[1], held[1], gripper[1], 0.9)
    assert single.angle == pytest.approx(batch.angle[1]) and single.y == pytest.approx(batch.y[1])


def test_full_gripper_states_and_single_samples():
    full_state = np.column_stack([GRIPPERS, np.full(3, 0.1), np.ones(3)])  # x, y, z, c
    pose = tactile_pose(POINTS, HELD, full_state, np.ones(3))
    np.testing.assert_allclose(pose.angle, exact().angle, atol=1e-12)
    np.testing.assert_allclose(pose.y, exact().y, atol=1e-12)
    single = tactile_pose(POINTS[1], HELD[1], G, 1.0)
    assert type(single.angle) is float and type(single.y) is float
    assert type(single.contact) is bool and type(single.count) is int
    assert single.angle == pytest.approx(-0.5) and single.y == pytest.approx(-0.004) and single.count == 5


def test_y_stays_within_its_limit_with_noise_and_for_lines_along_the_finger():
    along = tactile_pose(line(np.pi / 2, 0.0) + [0.004, 0.0], np.ones(5, bool), G, 1.0)  # parallel to the finger
    assert abs(along.angle) == pytest.approx(np.pi / 2) and abs(along.y) == Y_LIMIT
    near_edge = np.stack([line(0.0, 0.028)] * 200)
    noisy = tactile_pose(
        near_edge, np.ones((200, 5), bool), np.tile(G, (200, 1)), np.zeros(200), sigma=(0.0, 0.05), rng=np.random.default_rng(5)
    )
    assert np.all(np.abs(noisy.y) <= Y_LIMIT) and np.any(noisy.y == Y_LIMIT) and np.any(noisy.y < 0.0)


def test_no_contact_gives_defined_values_never_nan():
    points = np.zeros((3, 4, 3))
    held = np.array([[False] * 4, [True, False, False, False], [True, True, False, False]])
    pose = tactile_pose(points, held, np.zeros((3, 2)), np.zeros(3), sigma="full", rng=np.random.default_rng(0))
    assert pose.contact.tolist() == [False, False, True]
    assert pose.count.tolist() == [0, 1, 2]
    assert pose.angle[:2].tolist() == [0.0, 0.0] and pose.y[:2].tolist() == [0.0, 0.0]
    assert np.all(np.isfinite(pose.angle)) and np.all(np.isfinite(pose.y))


def test_no_contact_needs_no_invalid_arithmetic():
    held = np.zeros((3, 5), bool)
    held[1, 0] = True
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with np.errstate(all="raise"):
            pose = tactile_pose(POINTS, held, GRIPPERS, np.zeros(3))
    assert pose.contact.tolist() == [False, False, False] and pose.count.tolist() == [0, 1, 0]


# ---------------------------------------------------------------- the noise model
@pytest.mark.parametrize("closure", [0.0, 0.5, 0.8, 1.0])
def test_noise_scales_with_one_minus_closure(closure):
    n = 20000
    points = np.broadcast_to(line_particles(0.0, 0.0, (0.0, 0.0)), (n, 5, 2))
    pose = tactile_pose(
        points, np.ones((n, 5), bool), np.zeros((n, 2)), np.full(n, closure), sigma="full", rng=np.random.default_rng(1)
    )
    sigma_theta, sigma_y = TACTILE_NOISE["full"]
    assert np.std(pose.y) == pytest.approx((1 - closure) * sigma_y, rel=0.05, abs=1e-12)
    # The angle is wrapped to (-pi/2, pi/2]; at sigma 0.5 the wrap hardly changes the spread.
    assert np.std(pose.angle) == pytest.approx((1 - closure) * sigma_theta, rel=0.05, abs=1e-12)


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


# ---------------------------------------------------------------- the noise settings
def test_noise_presets_and_values():
    assert noise_sigma("none") == (0.0, 0.0)
    assert noise_sigma("full") == (0.5, 0.002)
    low, high = noise_sigma("partial")
    assert 0 < low < 0.5 and 0 < high < 0.002
    assert noise_sigma((0.1, 0.001)) == (0.1, 0.001)
    with pytest.raises(ValueError):
        noise_sigma("loud")
    with pytest.raises(ValueError):
        noise_sigma((-0.1, 0.0))


def test_noise_settings_in_every_form():
    """One reading for the env option, the node parameter and the launcher: a preset name, or a pair as
    a sequence or as text; the pair as floats, the preset as its name."""
    for preset in TACTILE_NOISE:
        assert noise_setting(preset) == preset
    for value in (
        (0.1, 0.001),
        [0.1, 0.001],
        ["0.1", "0.001"],
        np.array([0.1, 0.001]),
        "0.1,0.001",
        "[0.1, 0.001]",
        "(0.1,0.001)",
        " 0.1 ,0.001 ",
    ):
        got = noise_setting(value)
        assert got == (0.1, 0.001) and type(got) is tuple and all(type(s) is float for s in got), value
    assert noise_setting([0, 1]) == (0.0, 1.0) and noise_sigma("0,0") == (0.0, 0.0)
    for bad, shown in [
        ("loud", "'loud'"),
        ("custom", "'custom'"),
        ("", "''"),
        ("0.1", "'0.1'"),
        ([0.1], "[0.1]"),
        ((0.1, 0.2, 0.3), "[0.1, 0.2, 0.3]"),
        ("-0.1,0", "'-0.1,0'"),
        ((0.0, -1e-9), "[0.0, -1e-09]"),
        ((float("nan"), 0.0), "[nan, 0.0]"),
        ((0.0, float("inf")), "[0.0, inf]"),
        ((True, 0.0), "[True, 0.0]"),
        (None, "None"),
        (3, "3"),
        ("a,b", "'a,b'"),
        ("[0.1", "'[0.1'"),
    ]:
        with pytest.raises(ValueError) as error:
            noise_setting(bad)
        assert str(error.value) == f"expected {NOISE_FORMS}, got {shown}", bad


def test_noise_labels_and_parameter_values():
    assert noise_label("none") == "none"
    assert noise_label("partial") == "partial (sigma_theta 0.25 rad, sigma_y 0.001 m)"
    assert noise_label("[0.1,0.001]") == noise_label((0.1, 0.001)) == "sigma_theta 0.1 rad, sigma_y 0.001 m"
    assert noise_label((1e-5, 2)) == "sigma_theta 0.00001 rad, sigma_y 2.0 m"  # numbers, never an exponent
    assert noise_parameter_value("full") == "full"
    assert noise_parameter_value("0.1,0.001") == "[0.1,0.001]" and noise_parameter_value((0, 1e-5)) == "[0.0,0.00001]"
    with pytest.raises(ValueError):
        noise_label("loud")
