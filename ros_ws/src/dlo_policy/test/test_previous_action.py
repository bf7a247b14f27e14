"""The env option ``previous_action`` (dlo_policy.observation.PreviousAction): the observation ends with the action the
policy gave at the step before (zeros at an episode's first step), the rest of the observation and the episode exactly
as without it; the action as given (before the action perturbations) and never delayed or noised by the observation
perturbations; a fresh episode of the vector env's auto-reset starts from zeros; a bad value is one line."""

import sys
from pathlib import Path

import numpy as np
import pytest
from dlo_policy.env import check_options, make_env, make_vec_env
from dlo_policy.observation import PREVIOUS_ACTION_LABELS, observation_bounds, observation_labels, observation_size

sys.path.insert(0, str(Path(__file__).resolve().parent))  # --import-mode=importlib: helper modules

from shared_simulator import SharedSimulator  # noqa: E402

N, SEED, STEPS = 3, 11, 12


@pytest.fixture(scope="module")
def simulator():
    """The simulator of every rollout of the module, built (its kernels compiled) once: each rollout resets all
    its envs from SEED before its first step (shared_simulator), so it runs the episodes a simulator of its own would."""
    return SharedSimulator()


def actions(steps=STEPS, n=N):
    rng = np.random.default_rng(5)
    return rng.uniform(-1.0, 1.0, (steps, n, 3)).astype(np.float32)


def rollout(simulator, **options):
    """Observations (T + 1, N, D) and rewards (T, N) of a fixed open-loop sequence from reset(SEED), no auto-reset."""
    env = make_vec_env(N, seed=SEED, autoreset=False, simulator=simulator, **options)
    observation, _ = env.reset(seed=SEED)
    seen, rewards = [observation], []
    for action in actions():
        observation, reward, *_ = env.step(action)
        seen.append(observation)
        rewards.append(reward)
    return np.array(seen), np.array(rewards), env


def test_the_observation_ends_with_the_previous_action_and_is_otherwise_unchanged(simulator):
    plain, plain_rewards, _ = rollout(simulator)
    with_action, rewards, env = rollout(simulator, previous_action=True)
    assert observation_size("All", previous_action=True) == observation_size("All") + 3 == with_action.shape[-1]
    assert observation_labels("All", previous_action=True)[-3:] == PREVIOUS_ACTION_LABELS
    low, high = observation_bounds("All", previous_action=True)
    assert env.single_observation_space.shape == (12,) and (low[-3:] == -1).all() and (high[-3:] == 1).all()
    assert np.array_equal(with_action[..., :9], plain) and np.array_equal(rewards, plain_rewards)  # to the last bit
    assert (with_action[0, :, 9:] == 0).all()  # an episode's first step: zeros
    assert np.array_equal(with_action[1:, :, 9:], actions())  # then the action given at the step before


def test_it_is_the_action_as_given_and_the_observation_perturbations_leave_it_alone(simulator):
    perturbations = "observation_delay=2,action_delay=1,velocity_gain=0.5,closure_lag=0.3,gripper_position_noise=4"
    plain, _, _ = rollout(simulator, perturbations=perturbations)
    with_action, _, _ = rollout(simulator, perturbations=perturbations, previous_action=True)
    assert np.array_equal(with_action[..., :9], plain)  # the perturbations act as without the option
    assert np.array_equal(with_action[1:, :, 9:], actions())  # not delayed, not scaled, not lagged, no noise


def test_an_auto_reset_episode_starts_from_zeros_and_its_final_observation_keeps_the_last_action():
    env = make_vec_env(2, seed=SEED, horizon=3, previous_action=True)
    env.reset(seed=SEED)
    for action in actions(6, 2):
        observation, _, terminated, truncated, info = env.step(action)
        done = terminated | truncated
        if done.any():
            break
    assert done.any()
    assert (observation[done, 9:] == 0).all()  # the next episodes' first observations
    assert np.array_equal(np.stack(info["final_obs"][done])[:, 9:], action[done])  # the ended episodes' last
    assert np.array_equal(observation[~done, 9:], action[~done])  # the others go on


def test_the_single_env_takes_it_and_a_bad_value_is_one_line():
    env = make_env(seed=SEED, previous_action=True)
    observation, _ = env.reset(seed=SEED)
    assert observation.shape == (12,) and env.observation_space.contains(observation)
    observation, *_ = env.step(np.array([0.5, -0.25, 0.75], np.float32))
    assert observation[9:].tolist() == [0.5, -0.25, 0.75]
    with pytest.raises(ValueError, match=r"^previous_action: expected true or false, got 'yes'$"):
        check_options({"previous_action": "yes"})
