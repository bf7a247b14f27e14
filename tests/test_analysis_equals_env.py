"""Bag analysis recomputes what the env computed, to the last bit, under both task rules.

The env's episodes (the shipped policy on a few seeds, and a gripper that lets go at once, so that
every rule's early end is in: the policy's own drops depend on the last bits of the CPU's float
arithmetic, a released cable falls on every machine) are turned into the TaskState messages the sim
node would publish for them; dlo-analyze's ``recompute_episode`` must give the env's outcomes under
both rules, return and length exactly, and a TaskState without ``task_rules`` (bags recorded before
the field) reads as paper_text. The same for episodes with the authors' 4 mm move spacing (``move_spacing``, recorded
in the TaskState; without the field: 0, the cable's own spacing). A real bag of such a graph run:
tests/test_graph_equals_env.py.
"""

from types import SimpleNamespace

import numpy as np
import pytest
from dlo_bag.analysis import recompute_episode
from dlo_interface.task import OUTCOME_CODES

SEEDS = (7001, 7005, 7006, 7007)
LET_GO = np.array([0.0, 1.0, -1.0], dtype=np.float32)  # sideways, grip fully open (closure 0): it loses the cable


def task_states(env, act, seed, rules_field, spacing_field=None):
    """{step: TaskState-like} of one env episode, as the sim node fills them, and the env's final info."""
    task = env.vec.task
    observation, _ = env.reset(seed=seed)

    def message(step, done, info):
        n_c = int(task.sim.num_particles[0])
        held = np.flatnonzero(task.state.held[0, :n_c]).astype(np.int32)
        authors = np.flatnonzero(task.held_authors[0, :n_c]).astype(np.int32)
        fields = dict(
            step=step,
            seed=seed,
            held_indices=held,
            held_indices_authors=authors,
            num_particles=n_c,
            cable_length=float(task.sim.cable_length[0]),
            done=done,
            outcome=OUTCOME_CODES[info["outcome"]] if done else 0,
            outcome_authors=OUTCOME_CODES[info["outcome_authors"]] if done else 0,
            episode_return=float(task.tracker.episode_return[0]),
        )
        if rules_field is not None:
            fields["task_rules"] = rules_field
        if spacing_field is not None:
            fields["move_spacing"] = spacing_field
        return SimpleNamespace(**fields)

    states, step, done, info = {0: message(0, False, {})}, 0, False, {}
    while not done:
        observation, _, terminated, truncated, info = env.step(act(observation))
        done = terminated or truncated
        step += 1
        states[step] = message(step, done, info)
    return states, info


@pytest.fixture(scope="module")
def episodes():
    """{rules: [(seed, TaskState-likes, env info)]}: the shipped policy's episodes under both task rules, the last
    one a gripper letting go."""
    from dlo_policy.env import make_env
    from dlo_policy.policy_node import shipped_policy_path
    from dlo_policy.rundir import trained_sim_settings
    from dlo_policy.sac import SAC

    agent = SAC.load(shipped_policy_path())
    grip = trained_sim_settings(shipped_policy_path())["single_particle_grip"]  # the grip it was trained with
    policy = lambda observation: agent.predict(observation[None], deterministic=True)[0]  # noqa: E731
    result = {}
    for rules in ("paper_text", "authors_code"):
        env = make_env("All", seed=0, task_rules=rules, single_particle_grip=grip)
        result[rules] = [(seed, *task_states(env, policy, seed, rules)) for seed in SEEDS]
        result[rules].append((SEEDS[0], *task_states(env, lambda observation: LET_GO, SEEDS[0], rules)))
    # the authors' 4 mm move spacing (env option / sim node parameter move_spacing), recorded in the TaskState
    env = make_env("All", seed=0, task_rules="authors_code", single_particle_grip=grip, move_spacing=SPACING)
    result[SPACED] = [(seed, *task_states(env, policy, seed, "authors_code", SPACING)) for seed in SEEDS[:2]]
    return result


SPACED = "authors_code, move_spacing 0.004"
SPACING = 0.004


@pytest.mark.parametrize("rules", ["paper_text", "authors_code"])
def test_recomputed_episodes_equal_the_env_under_both_task_rules(episodes, rules):
    for seed, states, info in episodes[rules]:
        summary = recompute_episode(states)
        assert summary["task_rules"] == rules
        assert (summary["outcome"], summary["outcome_authors"]) == (info["outcome"], info["outcome_authors"]), seed
        assert summary["episode_return"] == info["episode_return"], seed
        assert summary["episode_length"] == info["episode_length"], seed
    _, _, let_go = episodes[rules][-1]  # the rule's early end (a drop) is among the episodes compared
    assert (
        let_go["episode_length"] < 150 and let_go["outcome" if rules == "paper_text" else "outcome_authors"] == "drop_before"
    ), let_go


def test_a_task_state_without_task_rules_reads_as_paper_text(episodes):
    _, states, info = episodes["paper_text"][0]
    for msg in states.values():
        del msg.task_rules
    summary = recompute_episode(states)
    assert summary["task_rules"] == "paper_text"
    assert summary["episode_return"] == info["episode_return"]


def test_the_two_task_rules_give_different_episodes(episodes):
    """The switch reaches the episode: the same seeds and policy end with other returns."""
    returns = {rules: [info["episode_return"] for _, _, info in runs] for rules, runs in episodes.items()}
    assert returns["paper_text"] != returns["authors_code"]


def test_a_recorded_move_spacing_is_recomputed_with_and_a_task_state_without_it_reads_as_0(episodes):
    """An episode the sim ran with move_spacing 0.004 (recorded in every TaskState): the recomputed episode is the
    env's to the last bit; the same messages without the field (bags recorded before it) are recomputed with the
    cable's own spacing, which gives another return: the recorded value is what reproduces the rewards."""
    for seed, states, info in episodes[SPACED]:
        summary = recompute_episode(states)
        assert (summary["task_rules"], summary["move_spacing"]) == ("authors_code", SPACING)
        assert (summary["outcome"], summary["outcome_authors"]) == (info["outcome"], info["outcome_authors"]), seed
        assert summary["episode_return"] == info["episode_return"], seed
        assert summary["episode_length"] == info["episode_length"], seed
    _, states, info = episodes[SPACED][0]
    for msg in states.values():
        del msg.move_spacing
    summary = recompute_episode(states)
    assert summary["move_spacing"] == 0.0 and summary["episode_return"] != info["episode_return"]
