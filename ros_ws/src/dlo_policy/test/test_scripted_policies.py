"""Scripted policies: the oracle proves the task solvable; it must beat random by far."""

import numpy as np
import pytest
from dlo_policy.env import make_vec_env
from dlo_policy.scripted import OracleFollow, RandomPolicy, TactileReactive, run_episodes


@pytest.fixture(scope="module")
def env():
    return make_vec_env(12, modalities="All", seed=0)


def hold_rate(results):
    return np.mean([r["outcome"] == "hold_the_end" for r in results])


def test_oracle_holds_the_end_far_more_often_than_random(env):
    oracle = run_episodes(env, OracleFollow(), 12, seed=100)
    random = run_episodes(env, RandomPolicy(seed=1), 12, seed=100)
    assert [r["episode_seed"] for r in oracle] == list(range(100, 112))
    assert hold_rate(oracle) >= 0.6
    assert hold_rate(random) <= 0.1
    assert np.mean([r["how_far"] for r in oracle]) < np.mean([r["how_far"] for r in random])


def test_tactile_reactive_uses_observations_only_and_makes_progress(env):
    results = run_episodes(env, TactileReactive(), 12, seed=200)
    assert np.mean([r["how_far"] for r in results]) < 20
    assert all(np.isfinite(r["episode_return"]) for r in results)
