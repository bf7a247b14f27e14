"""Perturbation families (dlo_policy.perturbations): the registry, each family doing what it says in the gym env
(against the same env unperturbed, on the same episodes and actions), off meaning unchanged, and the Perturber's
noise depending on the episode's seed alone (any batch, any env index: what makes the graph equal the env)."""

import dataclasses
import math
import sys
from pathlib import Path

import numpy as np
import pytest
from dlo_policy import perturbations as P
from dlo_policy.env import make_vec_env

sys.path.insert(0, str(Path(__file__).resolve().parent))  # --import-mode=importlib: helper modules

from shared_simulator import SharedSimulator  # noqa: E402

N = 4
SEED = 3
ALONG, SIDEWAYS = 8, 8  # control steps along the cable (visible), then sideways away from it (not visible)
COLUMNS = {label: i for i, label in enumerate(("x_G", "y_G", "c_G", "theta_T", "y_T", "v_V", "q_V", "theta_V", "y_V"))}


def actions():
    """A fixed open-loop sequence: along the cable with a sliding grip, then sideways and open (the cable leaves the
    camera's window), the same in every run."""
    rng = np.random.default_rng(0)
    along = np.stack(
        [rng.uniform(0.2, 1.0, (ALONG, N)), rng.uniform(-0.3, 0.3, (ALONG, N)), rng.uniform(0.1, 0.7, (ALONG, N))], -1
    )
    sideways = np.tile(np.array([0.2, 1.0, -1.0]), (SIDEWAYS, N, 1))
    return np.concatenate([along, sideways]).astype(np.float32)


@pytest.fixture(scope="module")
def rollout():
    """``rollout(perturbations=None, sequence=None)``: observations (T + 1, N, D) of the open-loop sequence from
    reset(SEED), no auto-reset, and the env. The observation and action families act outside the simulator, so the
    envs of every rollout step one simulator, built (its kernels compiled) once: each rollout resets all its envs
    from SEED before its first step (shared_simulator), so it runs the episodes a simulator of its own would."""
    simulator = SharedSimulator()

    def run(perturbations=None, sequence=None):
        env = make_vec_env(N, seed=SEED, autoreset=False, perturbations=perturbations, simulator=simulator)
        observation, _ = env.reset(seed=SEED)
        seen = [observation]
        for action in actions() if sequence is None else sequence:
            observation, *_ = env.step(action)
            seen.append(observation)
        return np.array(seen), env

    return run


@pytest.fixture(scope="module")
def plain(rollout):
    observations, env = rollout()
    visible = observations[..., COLUMNS["v_V"]] > 0.5
    assert visible.any() and (~visible).any()  # the sequence shows the cable and loses it
    return observations


def other_columns_equal(perturbed, plain, *changed):
    keep = [c for label, c in COLUMNS.items() if label not in changed]
    np.testing.assert_array_equal(perturbed[..., keep], plain[..., keep])


# ------------------------------------------------------------------------------------------------ registry
def test_every_family_is_one_record_with_unit_side_grid_and_off_by_default():
    assert len(P.FAMILIES) == len(set(P.names())) >= 19
    assert set(P.names(P.OBSERVATION)) >= {
        "observation_delay",
        "tactile_angle_noise",
        "vision_dropout",
        "vision_false_visible",
        "gripper_position_bias",
    }
    assert set(P.names(P.ACTION)) == {"action_delay", "velocity_gain", "closure_lag"}
    assert set(P.names(P.PHYSICS)) == {"friction", "stretch_stiffness", "bending_stiffness", "cable_length", "particle_mass"}
    assert set(P.names(P.CAMERA)) == {"camera_offset", "camera_yaw"}
    for f in P.FAMILIES:
        assert f.unit and f.perturbs and len(f.grid) >= 5
        if f.side == P.PHYSICS:  # a value beyond the training range on at least one side
            assert f.off is None and any(m < f.training[0] or m > f.training[1] for m in f.grid)
        else:
            assert P.parse({f.name: f.off}) == {}  # its off value is off
    assert P.parse(None) == P.parse("") == P.parse({}) == {}


def test_settings_are_read_one_way_from_text_or_mapping_and_bad_ones_are_one_line():
    setting = P.parse("friction=0.2:0.5, observation_delay=2,velocity_gain=1")
    assert setting == {"observation_delay": 2, "friction": (0.2, 0.5)}  # registry order, off entries dropped
    assert P.parse(P.text(setting)) == setting == P.parse({"friction": [0.2, 0.5], "observation_delay": 2.0})
    for bad, message in [
        ("obs_delay=2", "did you mean 'observation_delay'"),
        ("observation_delay=1.5", "integer"),
        ("vision_dropout=2", r"in \[0, 1\]"),
        ("friction", "name=value"),
        ("friction=0.5:0.2", "low <= high"),
        ("closure_lag=-1", r"in \[0, 60\]"),
        ("action_delay=1,action_delay=2", "twice"),
        ("velocity_gain=nan", "expected"),
    ]:
        with pytest.raises(ValueError, match=message) as error:
            P.parse(bad)
        assert "\n" not in str(error.value)


def test_off_changes_nothing_and_draws_nothing(rollout, plain):
    observations, env = rollout("observation_delay=0,velocity_gain=1,vision_dropout=0")
    assert env.perturbations == {} and not env.perturber.active
    np.testing.assert_array_equal(observations, plain)


# ------------------------------------------------------------------------------------------------ observation side
def test_observation_delay_shows_the_observation_of_d_steps_before(rollout, plain):
    observations, _ = rollout({"observation_delay": 2})
    expected = np.concatenate([plain[:1], plain[:1], plain[:-2]])  # the episode's first until then
    np.testing.assert_array_equal(observations, expected)


@pytest.mark.parametrize(
    "name, magnitude, label, scale",
    [
        ("tactile_angle_noise", 10.0, "theta_T", math.radians(1)),
        ("tactile_offset_noise", 2.0, "y_T", 0.001),
        ("gripper_position_noise", 4.0, "x_G", 0.001),
    ],
)
def test_sensor_noise_is_gaussian_on_its_reading_only(rollout, plain, name, magnitude, label, scale):
    observations, _ = rollout({name: magnitude})
    changed = (label, "y_G") if label == "x_G" else (label,)
    other_columns_equal(observations, plain, *changed)
    for column in changed:
        added = (observations - plain)[..., COLUMNS[column]].astype(np.float64)
        if column.startswith("theta"):
            added = P.wrap_line_angle(added)
        assert np.all(added != 0.0)
        assert 0.6 < added.std() / (magnitude * scale) < 1.4 and abs(added.mean()) < 0.5 * magnitude * scale


@pytest.mark.parametrize(
    "name, magnitude, label, scale",
    [("vision_angle_noise", 10.0, "theta_V", math.radians(1)), ("vision_offset_noise", 2.0, "y_V", 0.001)],
)
def test_vision_noise_is_on_visible_detections_only(rollout, plain, name, magnitude, label, scale):
    observations, _ = rollout({name: magnitude})
    other_columns_equal(observations, plain, label)
    visible = plain[..., COLUMNS["v_V"]] > 0.5
    added = (observations - plain)[..., COLUMNS[label]].astype(np.float64)
    assert np.all(added[~visible] == 0.0) and np.mean(added[visible] != 0.0) > 0.9  # (clipped at the window's edge)
    if label == "theta_V":
        added = P.wrap_line_angle(added)
    assert 0.6 < added[visible].std() / (magnitude * scale) < 1.4


def test_gripper_position_bias_is_one_offset_of_that_length_per_episode(rollout, plain):
    observations, _ = rollout({"gripper_position_bias": 10.0})
    other_columns_equal(observations, plain, "x_G", "y_G")
    offset = (observations - plain)[..., [COLUMNS["x_G"], COLUMNS["y_G"]]].astype(np.float64)
    np.testing.assert_allclose(offset, np.broadcast_to(offset[:1], offset.shape), atol=1e-6)  # constant in time
    np.testing.assert_allclose(np.hypot(offset[0, :, 0], offset[0, :, 1]), 0.010, atol=1e-6)
    assert len({tuple(np.round(o, 5)) for o in offset[0]}) == N  # its direction drawn per episode


def test_vision_dropout_reports_visible_detections_as_missing(rollout, plain):
    observations, _ = rollout({"vision_dropout": 0.5})
    other_columns_equal(observations, plain, "v_V", "q_V", "theta_V", "y_V")
    vision = [COLUMNS[k] for k in ("v_V", "q_V", "theta_V", "y_V")]
    visible = plain[..., COLUMNS["v_V"]] > 0.5
    dropped = visible & (observations[..., COLUMNS["v_V"]] == 0.0)
    assert np.all(observations[dropped][:, vision] == 0.0)
    kept = visible & ~dropped
    np.testing.assert_array_equal(observations[kept], plain[kept])
    np.testing.assert_array_equal(observations[~visible], plain[~visible])  # nothing made up
    assert 0.3 < dropped.sum() / visible.sum() < 0.7


def test_vision_false_visible_reports_missing_detections_as_spurious_strands(rollout, plain):
    observations, _ = rollout({"vision_false_visible": 0.5})
    other_columns_equal(observations, plain, "v_V", "q_V", "theta_V", "y_V")
    visible = plain[..., COLUMNS["v_V"]] > 0.5
    np.testing.assert_array_equal(observations[visible], plain[visible])
    made_up = ~visible & (observations[..., COLUMNS["v_V"]] == 1.0)
    assert 0.25 < made_up.sum() / (~visible).sum() < 0.75
    strands = observations[made_up]
    assert np.all((0 <= strands[:, COLUMNS["q_V"]]) & (strands[:, COLUMNS["q_V"]] <= 1))
    assert np.all(np.abs(strands[:, COLUMNS["theta_V"]]) <= np.pi / 2)
    assert np.all(np.abs(strands[:, COLUMNS["y_V"]]) <= 0.03) and len(set(strands[:, COLUMNS["y_V"]])) > 1


# ------------------------------------------------------------------------------------------------ action side
def test_action_delay_gives_the_simulator_the_action_of_d_steps_before(rollout, plain):
    sequence = actions()
    delayed, _ = rollout({"action_delay": 1})
    by_hand, _ = rollout(sequence=np.concatenate([sequence[:1], sequence[:-1]]))  # the first until then
    np.testing.assert_array_equal(delayed, by_hand)
    assert not np.array_equal(delayed, plain)


def test_velocity_gain_scales_the_gripper_motion(rollout, plain):
    sequence = actions()
    scaled, _ = rollout({"velocity_gain": 0.5})
    by_hand = sequence.copy()
    by_hand[..., :2] *= 0.5
    np.testing.assert_array_equal(scaled, rollout(sequence=by_hand)[0])
    moved = np.diff(scaled[..., COLUMNS["y_G"]], axis=0)[ALONG:]  # sideways and open: the gripper moves freely
    np.testing.assert_allclose(moved, 0.5 * 8 * 0.0025, rtol=1e-3)
    saturated, _ = rollout({"velocity_gain": 3.0})  # 3 x 1.0 is the 0.25 m/s limit
    np.testing.assert_allclose(np.diff(saturated[..., COLUMNS["y_G"]], axis=0)[ALONG:], 8 * 0.0025, rtol=1e-3)


def test_closure_lag_makes_the_closure_follow_the_command_as_a_first_order_lag(rollout, plain):
    tau = 0.16
    lagged, _ = rollout({"closure_lag": tau})
    rate = 1.0 - math.exp(-0.08 / tau)
    command = actions()[..., 2].astype(np.float64)
    applied = [command[0]]
    for c in command[1:]:
        applied.append(applied[-1] + rate * (c - applied[-1]))
    closure = lagged[1:, :, COLUMNS["c_G"]]  # c_G = (a2 + 1) / 2 of the applied command
    np.testing.assert_allclose(closure, (np.array(applied) + 1) / 2, atol=1e-6)
    assert np.abs(closure - (command + 1) / 2).max() > 0.1  # not the command itself


# ------------------------------------------------------------------------------------------------ physics, camera
def test_physics_families_fix_each_episode_beyond_the_training_ranges():
    heavy = make_vec_env(
        N,
        seed=SEED,
        perturbations={
            "friction": 0.9,
            "stretch_stiffness": 3.0,
            "bending_stiffness": 5.0,
            "cable_length": 20,
            "particle_mass": 5.0,
        },
    )
    light = make_vec_env(
        N, seed=SEED, perturbations="cable_length=20,particle_mass=0.05,friction=0.9,stretch_stiffness=3,bending_stiffness=5"
    )
    heavy.reset(seed=SEED)
    light.reset(seed=SEED)
    params = heavy.sim.params
    for key, value in (("friction", 0.9), ("stretch", 3.0), ("bending", 5.0), ("num_particles", 20), ("particle_mass", 5.0)):
        assert np.all(params[key] == np.float32(value)), key
    assert np.all(light.sim.params["particle_mass"] == np.float32(0.05))

    def length(env):  # along the cable: heavier particles against the same compliance stretch it more
        x = env.sim.positions()[:, :20]
        return np.linalg.norm(np.diff(x, axis=1), axis=2).sum(axis=1)

    assert np.all(length(heavy) > length(light))
    ranged = make_vec_env(8, seed=SEED, perturbations={"friction": [0.5, 0.7]})
    ranged.reset(seed=SEED)
    friction = ranged.sim.params["friction"]
    assert np.all((friction >= 0.5) & (friction <= 0.7)) and len(set(friction)) == 8  # a pair: drawn per episode


def test_camera_families_move_the_camera_that_renders_not_the_one_the_vision_assumes():
    from dlo_interface.camera import IMAGE_GRIPPER, TopCamera
    from dlo_interface.world import FINGER_AXIS_OFFSET
    from dlo_perception.vision import visual_pose

    env = make_vec_env(2, seed=SEED, perturbations={"camera_offset": 20.0, "camera_yaw": 10.0})
    observation, _ = env.reset(seed=SEED)
    nominal = TopCamera.covering_workspace(128)
    assert env.vision_camera == nominal
    rendering = env.sim.camera
    assert rendering.position == pytest.approx((0.0, 0.020, 1.0)) and rendering.yaw == pytest.approx(math.radians(10))
    state = env.task.state
    for e in range(2):  # the gripper's pixels are where the moved, turned camera sees it
        rows, cols = np.nonzero(state.image[e] == IMAGE_GRIPPER)
        centre = np.array([cols.mean() + 0.5, rows.mean() + 0.5])
        gripper = [*state.gripper[e, :2], state.gripper[e, 2] + FINGER_AXIS_OFFSET]
        assert np.linalg.norm(centre - rendering.world_to_pixel(gripper)) < 0.75
        assert np.linalg.norm(centre - nominal.world_to_pixel(gripper)) > 3
    vision = visual_pose(state.image, nominal, state.gripper[:, :2], float(np.float32(0.1)))  # read as if nominal
    np.testing.assert_array_equal(
        observation[:, 5:], np.stack([vision.visible, vision.confidence, vision.angle, vision.y], -1).astype(np.float32)
    )


def test_top_camera_yaw_round_trips_and_turns_the_view():
    from dlo_interface.camera import TopCamera

    camera = dataclasses.replace(TopCamera.covering_workspace(128), yaw=math.radians(90))
    points = np.array([[0.1, 0.0, 0.1], [0.0, 0.05, 0.1]])
    uv = camera.world_to_pixel(points)
    np.testing.assert_allclose(camera.pixel_to_world(uv, 0.1), points[:, :2], atol=1e-12)
    straight = TopCamera.covering_workspace(128)
    # turned a quarter counter-clockwise, the camera sees world +x where it saw world -y (down the image)
    np.testing.assert_allclose(uv[0], straight.world_to_pixel([0.0, -0.1, 0.1]), atol=1e-9)


# ------------------------------------------------------------------------------------------------ the Perturber
def test_the_noise_depends_on_the_episode_seed_alone_not_on_the_batch_or_the_env_index():
    setting = {
        "observation_delay": 1,
        "vision_angle_noise": 5.0,
        "gripper_position_noise": 2.0,
        "vision_false_visible": 0.3,
        "action_delay": 1,
        "closure_lag": 0.1,
        "velocity_gain": 0.8,
    }
    rng = np.random.default_rng(1)
    observations = rng.uniform(-0.01, 0.01, (12, 3, 9)).astype(np.float32)
    observations[..., 5] = rng.integers(0, 2, (12, 3))
    acts = rng.uniform(-1, 1, (12, 3, 3)).astype(np.float32)
    batch = P.Perturber(setting, "All", num_envs=3)
    batch.start([0, 1, 2], [70, 71, 72])
    together = [(batch.observe(o), batch.act(a)) for o, a in zip(observations, acts)]
    alone = P.Perturber(setting, "All", num_envs=1)
    for i, seed in ((2, 72), (0, 70)):
        alone.start([0], [seed])
        for t, (o, a) in enumerate(zip(observations, acts)):
            np.testing.assert_array_equal(alone.observe(o[i : i + 1]), together[t][0][i : i + 1])
            np.testing.assert_array_equal(alone.act(a[i : i + 1]), together[t][1][i : i + 1])
    other = P.Perturber(setting, "All", num_envs=1)
    other.start([0], [73])
    assert not np.array_equal(other.observe(observations[0][:1]), together[0][0][:1])


def test_a_family_of_an_ablated_or_absent_modality_does_nothing():
    observation = np.array([[0.01, 0.02, 0.5, 0.1, 0.002, 1.0, 0.5, 0.2, 0.003]], np.float32)
    perturber = P.Perturber({"tactile_angle_noise": 20.0, "vision_dropout": 1.0}, "All", without=("T", "V"))
    perturber.start([0], [5])
    ablated = observation.copy()
    ablated[:, 3:] = 0.0
    np.testing.assert_array_equal(perturber.observe(ablated), ablated)
    only_k = P.Perturber({"tactile_angle_noise": 20.0}, "K")
    only_k.start([0], [5])
    np.testing.assert_array_equal(only_k.observe(observation[:, :3]), observation[:, :3])
    with pytest.raises(RuntimeError, match="start"):
        P.Perturber({"action_delay": 1}, "All").act(np.zeros((1, 3)))
