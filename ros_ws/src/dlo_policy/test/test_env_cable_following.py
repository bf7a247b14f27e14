"""The gymnasium environments: checker, spaces, seeding, auto-reset, ablation, episode-end info."""

import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from dlo_perception.tactile import TactilePose
from dlo_perception.vision import VisualPose
from dlo_policy.env import make_env, make_vec_env
from dlo_policy.observation import build_observation, observation_labels, parse_modalities
from gymnasium.utils.env_checker import check_env

sys.path.insert(0, str(Path(__file__).resolve().parent))  # --import-mode=importlib: helper modules

from shared_simulator import SharedSimulator  # noqa: E402


@pytest.fixture(scope="module")
def simulator():
    """The module's simulators, one per set of arguments, each built (its kernels compiled) once, for envs used one
    at a time that reset all their envs before they step (shared_simulator): they run the episodes a simulator of
    their own would."""
    return SharedSimulator()


def test_single_env_passes_the_gymnasium_checker(simulator):
    """The single env with every modality passes gymnasium's env checker (its simulator: the module's, which the
    tactile-noise test below reuses)."""
    env = make_env("All", seed=0, simulator=simulator)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        check_env(env, skip_render_check=True)
    assert env.observation_space.shape == (9,) and env.action_space.shape == (3,)


@pytest.mark.parametrize(
    "modalities, expected",
    [
        ("T", ("theta_T", "y_T")),
        ("K", ("x_G", "y_G", "c_G")),
        ("V", ("v_V", "q_V", "theta_V", "y_V")),
        ("T+K", ("x_G", "y_G", "c_G", "theta_T", "y_T")),
        ("V+K", ("x_G", "y_G", "c_G", "v_V", "q_V", "theta_V", "y_V")),
        ("T+V", ("theta_T", "y_T", "v_V", "q_V", "theta_V", "y_V")),
        ("All", ("x_G", "y_G", "c_G", "theta_T", "y_T", "v_V", "q_V", "theta_V", "y_V")),
    ],
)
def test_modality_subsets_keep_the_fixed_order(modalities, expected):
    assert observation_labels(modalities) == expected


def test_build_observation_orders_and_ablates():
    kinematic = np.array([[0.1, -0.2, 0.7]])
    tactile = TactilePose(np.array([0.3]), np.array([0.004]), np.array([True]), np.array([3]))
    visual = VisualPose(np.array([True]), np.array([0.5]), np.array([-0.2]), np.array([0.01]))
    full = build_observation("All", kinematic, tactile, visual)
    assert full.dtype == np.float32
    assert full[0] == pytest.approx([0.1, -0.2, 0.7, 0.3, 0.004, 1.0, 0.5, -0.2, 0.01])
    ablated = build_observation("All", kinematic, None, visual, without=("T",))
    assert ablated[0] == pytest.approx([0.1, -0.2, 0.7, 0.0, 0.0, 1.0, 0.5, -0.2, 0.01])
    with pytest.raises(ValueError):
        build_observation("K", kinematic, without=("V",))
    with pytest.raises(ValueError):
        parse_modalities("X+K")


def rollout(env, seed, steps=12):
    """Observations and rewards of a fixed action sequence from reset(seed)."""
    observation, _ = env.reset(seed=seed)
    observations, rewards = [observation], []
    for t in range(steps):
        action = np.array([1.0, 0.3 * np.sin(t), 0.4], np.float32)
        observation, reward, terminated, truncated, _ = env.step(action)
        observations.append(observation)
        rewards.append(reward)
        if terminated or truncated:
            break
    return np.array(observations), np.array(rewards)


def test_same_seed_same_episode_with_tactile_noise(simulator):
    """reset(seed) replays the episode of that seed, tactile noise included; another seed starts another one."""
    env = make_env("All", seed=0, tactile_noise="full", simulator=simulator)
    first = rollout(env, seed=7)
    other = rollout(env, seed=8)
    again = rollout(env, seed=7)
    assert np.array_equal(first[0], again[0]) and np.array_equal(first[1], again[1])
    assert not np.array_equal(first[0][0], other[0][0])


def test_vector_env_batches_autoresets_and_reports_episode_end():
    env = make_vec_env(3, modalities="T+K", seed=5, horizon=4, without=("T",))
    observation, info = env.reset()
    assert observation.shape == (3, 5) and info["episode_seed"].tolist() == [5, 6, 7]
    assert np.all(observation[:, 3:] == 0.0)  # T ablated
    for _ in range(4):
        observation, reward, terminated, truncated, info = env.step(np.tile([0.5, 0.0, 0.4], (3, 1)))
    assert np.all(terminated | truncated) and reward.shape == (3,)
    assert info["_outcome"].all() and set(info["outcome"]) <= {"hold_the_end", "stop_before", "reach_end_but_drop", "drop_before"}
    assert info["_outcome_authors"].all() and set(info["outcome_authors"]) <= {
        "hold_the_end",
        "stop_before",
        "reach_end_but_drop",
        "drop_before",
    }
    for key in ("outcome_code", "time_at_end", "how_far", "episode_return"):
        assert info[key].shape == (3,)
    assert info["_final_obs"].all() and info["final_obs"][0].shape == (5,)
    assert env.episode_seed.tolist() == [8, 9, 10]  # auto-reset with the next seeds
    assert env.tracker.steps.tolist() == [0, 0, 0]


def test_single_env_info_at_episode_end():
    env = make_env("K", seed=0, horizon=3)
    env.reset(seed=1)
    done, info = False, {}
    while not done:
        _, _, terminated, truncated, info = env.step(np.array([0.0, 0.0, 0.4], np.float32))
        done = terminated or truncated
    assert isinstance(info["outcome"], str) and isinstance(info["outcome_code"], int)
    assert isinstance(info["outcome_authors"], str)
    assert {"time_at_end", "how_far", "episode_return"} <= set(info)


def test_single_particle_grip_option_reaches_the_simulator_and_a_bad_value_is_a_one_line_error():
    """env_options.single_particle_grip (docs/FIDELITY.md row 5): off by default; on, the env's simulator
    runs the single-particle grip (dlo_sim test_rope_physics / test_kernel_rules test what it does), also
    with a sim_config of one's own; anything but true or false is refused before a simulator is built."""
    from dlo_interface.sim_config import SimConfig
    from dlo_policy.config import ConfigError, check_env_options, load_config

    assert make_env("K", seed=0).sim.config.single_particle_grip is False
    env = make_vec_env(1, "K", seed=0, sim_config=SimConfig(damping=3.0), single_particle_grip=True)
    assert env.sim.config == SimConfig(damping=3.0, single_particle_grip=True) and env.sim._k.single_particle_grip
    for bad in ("maybe", 1, None):
        with pytest.raises(ValueError, match="single_particle_grip: expected true or false"):
            make_env("K", single_particle_grip=bad)
    with pytest.raises(ConfigError, match=r"^env_options: single_particle_grip: expected true or false, got 'maybe'$"):
        check_env_options(load_config(None, ["env_options.single_particle_grip=maybe"]))
    check_env_options(load_config(None, ["env_options.single_particle_grip=true"]))


def test_physics_seed_option_reaches_the_simulator_and_a_bad_value_is_a_one_line_error():
    """env_options.physics_seed (docs/FIDELITY.md row 8): absent or -1, physics drawn per episode; >= 0, the
    env's simulator gives every episode the physics of that seed (test_rope_physics tests what it does), also
    with a sim_config of one's own; anything else is refused before a simulator is built."""
    from dlo_interface.sim_config import SimConfig
    from dlo_policy.config import ConfigError, check_env_options, load_config

    assert make_env("K", seed=0).sim.config.physics_seed == -1
    env = make_vec_env(1, "K", seed=0, sim_config=SimConfig(damping=3.0), physics_seed=3)
    assert env.sim.config == SimConfig(damping=3.0, physics_seed=3)
    for bad in ("x", -2, 1.5, True):
        with pytest.raises(ValueError, match="physics_seed: expected an integer >= 0"):
            make_env("K", physics_seed=bad)
    with pytest.raises(
        ConfigError,
        match=r"^env_options: physics_seed: expected an integer >= 0 \(or -1: drawn per "
        r"episode\), got -5$",
    ):
        check_env_options(load_config(None, ["env_options.physics_seed=-5"]))
    check_env_options(load_config(None, ["env_options.physics_seed=0"]))


def test_fidelity_lever_options_reach_the_simulator_and_bad_values_are_one_line_errors():
    """env_options carry_law, contact_radius and vision_source (docs/FIDELITY.md): absent, today's physics and the
    image; given, the simulator's config carries them (a particles-source env renders nothing); anything else is
    refused with one line before a simulator is built."""
    from dlo_interface.sim_config import SimConfig
    from dlo_policy.config import ConfigError, check_env_options, load_config

    plain = make_vec_env(1, "V", seed=0)
    assert (plain.sim.config.carry_law, plain.sim.config.contact_radius, plain.vision_source) == ("paper", 0.004, "image")
    assert plain.task.render
    env = make_vec_env(
        1,
        "V",
        seed=0,
        sim_config=SimConfig(damping=3.0),
        carry_law="authors",
        contact_radius=0.005,
        vision_source="particles",
        start_pose="authors",
    )
    assert env.sim.config == SimConfig(damping=3.0, carry_law="authors", contact_radius=0.005, start_pose="authors")
    assert not env.task.render and env.vision_source == "particles"
    observation, _ = env.reset(seed=0)
    assert observation.shape == (1, 4) and np.isfinite(observation).all()
    for options, message in (
        ({"carry_law": "flex"}, "carry_law: expected one of paper, authors, got 'flex'"),
        ({"contact_radius": 0.007}, r"contact_radius: expected a number in \(0, 0.006\] m"),
        ({"contact_radius": "0.005"}, r"contact_radius: expected a number in \(0, 0.006\] m"),
        ({"vision_source": "camera"}, "vision_source: expected one of image, particles"),
        ({"start_pose": "theirs"}, "start_pose: expected one of ours, authors, got 'theirs'"),
    ):
        with pytest.raises(ValueError, match=message):
            make_env("V", **options)
    with pytest.raises(ConfigError, match=r"^env_options: vision_source: expected one of image, particles, got 'x'$"):
        check_env_options(load_config(None, ["env_options.vision_source=x"]))
    check_env_options(
        load_config(
            None, ["env_options.vision_source=particles", "env_options.carry_law=authors", "env_options.contact_radius=0.005"]
        )
    )


def test_move_spacing_reaches_the_reward_and_bad_values_are_one_line_errors(simulator):
    """env_options.move_spacing (docs/FIDELITY.md): absent or 0, the cable's own spacing; 0.004 (the authors'), the
    same episodes (observations, ends) with the move term on 4 mm particles under either task rule: every step's
    reward differs by ALPHA_MOVE x the mean held index gained x (4 mm - the cable's own spacing); anything else is
    refused with one line before a simulator is built. The envs of a rule play the same actions from the same reset
    one after the other (the module's simulators: absent and 0 hand the simulator the same options, so share one)."""
    from dlo_interface import task
    from dlo_policy.config import ConfigError, check_env_options, load_config

    actions = np.tile(np.array([[0.5, 0.0, 0.2]], np.float32), (2, 1))  # forward, sliding grip: it moves along

    def play(env, rules):
        """Per step: what env.step returned but the info, the mean held index under ``rules`` before and after it,
        and the particle count and cable length after it."""
        held = "mean_held_index_authors" if rules == "authors_code" else "mean_held_index"
        env.reset(seed=3)
        steps = []
        for _ in range(6):
            before = getattr(env.task, held).copy()
            returned = env.step(actions)[:4]
            steps.append((returned, before, getattr(env.task, held).copy(), env.sim.num_particles, env.sim.cable_length))
        return steps

    for rules in task.TASK_RULES:
        plain, zero, spaced = (
            make_vec_env(2, "K", seed=3, task_rules=rules, simulator=simulator, **options)
            for options in ({}, {"move_spacing": 0}, {"move_spacing": 0.004})
        )
        assert (plain.tracker.move_spacing, zero.tracker.move_spacing, spaced.tracker.move_spacing) == (0.0, 0.0, 0.004)
        gained = 0.0
        for (a, before, held, n_c, L_c), (b, *_), (c, *_) in zip(
            play(plain, rules), play(zero, rules), play(spaced, rules), strict=True
        ):
            assert np.array_equal(a[0], c[0]) and np.array_equal(a[2], c[2])  # the same episodes
            assert np.array_equal(a[1], b[1])  # 0: the cable's own spacing, bit for bit
            own = L_c / (n_c - 1) if rules == "authors_code" else L_c / n_c
            ended = a[2] | a[3]  # a drop (the fall penalty either way) or a new episode's first index
            moved = np.where((before >= 0) & (held >= 0) & ~ended, held - before, 0.0)
            assert c[1] - a[1] == pytest.approx(10 * moved * (0.004 - own), abs=1e-9), rules
            gained += np.abs(moved).sum()
        assert gained > 0, rules  # the gripper moved along the cable: the spacing showed
    for bad in (-0.001, 0.02, float("nan"), "0.004", True):
        with pytest.raises(ValueError, match=r"^move_spacing: expected a number in \[0, 0\.01\] m"):
            make_env("K", move_spacing=bad)
    with pytest.raises(ConfigError, match=r"^env_options: move_spacing: expected a number in \[0, 0\.01\] m"):
        check_env_options(load_config(None, ["env_options.move_spacing=0.5"]))
    check_env_options(load_config(None, ["env_options.move_spacing=0.004"]))


def test_the_authors_start_pose_starts_8_mm_behind_and_2_25_mm_lower_and_the_image_is_read_at_that_height():
    """start_pose=authors (their Picker.reset): the gripper starts 8 mm behind the fixed end and 2.25 mm below it and
    moves in that plane; the image source reads V at the gripper's own height, as the vision node does with the
    published gripper z."""
    from dlo_interface.world import FIXED_END, GRIPPER_HEIGHT
    from dlo_perception.vision import visual_pose

    env = make_vec_env(1, "V", seed=0, start_pose="authors")
    observation, _ = env.reset(seed=0)
    gripper = env.task.state.gripper[0]
    np.testing.assert_allclose(gripper[:3], [FIXED_END[0] - 0.008, FIXED_END[1], GRIPPER_HEIGHT - 0.00225], atol=1e-7)
    differs = 0
    rng = np.random.default_rng(4)
    for _ in range(40):
        observation, _, terminated, truncated, _ = env.step(np.array([[0.8, rng.uniform(-0.5, 0.5), 0.6]], np.float32))
        if terminated[0] or truncated[0]:
            break
        state = env.task.state
        assert state.gripper[0, 2] == np.float32(GRIPPER_HEIGHT - 0.00225)  # it moves in that plane
        node = visual_pose(state.image, env.sim.camera, state.gripper[:, :2], float(state.gripper[0, 2]))
        np.testing.assert_array_equal(
            observation[0], np.array([node.visible[0], node.confidence[0], node.angle[0], node.y[0]], np.float32)
        )
        at_default = visual_pose(state.image, env.sim.camera, state.gripper[:, :2], GRIPPER_HEIGHT)
        differs += not np.array_equal(
            observation[0],
            np.array([at_default.visible[0], at_default.confidence[0], at_default.angle[0], at_default.y[0]], np.float32),
        )
    assert differs >= 1  # the height matters: read at the default height, V would differ


def test_the_env_steps_the_simulator_backend_it_is_given(simulator):
    """The env imports no simulator (tests/test_package_graph.py): by default it builds the backend registered as
    ``taichi`` (dlo_sim's TaskSim, an entry point of dlo_interface.simulators); a factory given in its place is
    called with the env's settings and stepped, with the same episodes for the same backend; an unknown name is a
    one-line error before anything is built. The factory given hands out the module's taichi simulator of the
    settings it is called with (the move-spacing test's; a new one when none was built yet)."""
    from dlo_policy.config import ConfigError, check_env_options, load_config

    default = make_vec_env(2, "K+T", seed=4)
    assert type(default.task).__module__ == "dlo_sim.episode" and type(default.task).__name__ == "TaskSim"
    calls = []

    def recording(num_envs, **options):
        calls.append((num_envs, sorted(options)))
        return simulator(num_envs, **options)

    given = make_vec_env(2, "K+T", seed=4, simulator=recording)
    assert calls == [(2, ["camera", "config", "end_particles", "horizon", "move_spacing", "render", "task_rules"])]
    actions = np.tile(np.array([[0.6, 0.1, 0.2]], np.float32), (2, 1))
    for env in (default, given):
        env.reset(seed=4)
    for _ in range(3):
        a, b = default.step(actions), given.step(actions)
        assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    with pytest.raises(
        ValueError, match=r"^simulator: no backend 'mujoco' registered in dlo_interface\.simulators; registered: "
    ):
        make_env("K", simulator="mujoco")
    with pytest.raises(ConfigError, match=r"^env_options: simulator: no backend 'nope' registered"):
        check_env_options(load_config(None, ["env_options.simulator=nope"]))
    check_env_options(load_config(None, ["env_options.simulator=taichi"]))
