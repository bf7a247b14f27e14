"""dlo_sim.task at its edges (issue 14, found by tools/mutation_check.sh): held statistics of single
and batched masks, rewards when only particle 0 or one particle is held, the ends of both outcome
rules at small indices, the authors' held set around a gripper away from the origin and at its
exact boundaries, and a tracker reused across episodes."""

import numpy as np
import pytest

from dlo_sim import task
from dlo_sim.config import FINGER_AXIS_OFFSET
from dlo_sim.task import EpisodeTracker, held_statistics, step_reward

N_C, L_C = 40, 39 * 0.0043


def test_held_statistics_of_one_particle_and_of_a_batch():
    held = np.zeros((3, 8), bool)
    held[0, 3] = True  # one particle
    held[1, [0, 1]] = True
    with np.errstate(all="raise"):  # no 0/0 for the row holding nothing
        n_h, p_i, max_held = held_statistics(held)
    assert n_h.tolist() == [1, 2, 0]
    assert p_i.tolist() == [3.0, 0.5, -1.0]
    assert max_held.tolist() == [3, 1, -1]


def test_rewards_when_particle_0_or_a_single_particle_is_held():
    # held before: only particle 0 (p_i = 0): a move is rewarded
    assert step_reward(0.0, 2.0, 2, N_C, L_C) == pytest.approx(10 * 2 * L_C / N_C)
    # one particle held now: still holding, no fall penalty
    assert step_reward(4.0, 5.0, 1, N_C, L_C) == pytest.approx(10 * L_C / N_C)


def test_at_the_end_from_index_0_on_short_cables():
    assert task.at_end([0, -1, 4], 5, end_particles=10).tolist() == [True, False, True]
    assert task.at_end_authors([0.0, -1.0], 5).tolist() == [True, False]


GRIPPER = np.array([[0.07, -0.04, 0.1 + FINGER_AXIS_OFFSET, 1.0]])  # lower finger axis at z = 0.1


def authors(points, gripper=GRIPPER, n=None):
    positions = np.asarray(points, dtype=np.float64)[None]
    return task.held_mask_authors(positions, [len(points) if n is None else n], gripper)[0].tolist()


def test_authors_held_set_follows_the_gripper():
    g = GRIPPER[0]
    rest = g[2] - FINGER_AXIS_OFFSET + 0.0165
    assert authors([(g[0], g[1], rest), (g[0] + 0.017, g[1], rest), (g[0] - 0.017, g[1] + 0.007, rest)]) == [True] * 3
    # the same points around a gripper at the origin are far away
    assert authors([(g[0], g[1], rest)], gripper=np.array([[0.0, 0.0, g[2], 1.0]])) == [False]
    assert authors([(g[0] + 0.025, g[1], rest), (g[0], g[1] + 0.0076, rest), (g[0], g[1] - 0.0076, rest)]) == [False] * 3
    # x and y are not mixed up: an offset along y that would be fine along x
    assert authors([(g[0], g[1] + 0.019, rest)]) == [False]


def test_authors_held_set_boundaries_are_strict():
    origin = np.array([[0.0, 0.0, FINGER_AXIS_OFFSET, 1.0]])  # lower axis exactly at z = 0
    assert authors([(0.0, 0.0075, 0.02), (0.0, -0.0075, 0.02)], origin) == [False, False]  # |dy| < 0.0075
    assert authors([(0.0, 0.0, 0.0245)], origin) == [False]  # distance < 0.0245
    assert authors([(0.0, 0.0, 0.0125)], origin) == [False]  # more than 0.0125 above
    assert authors([(0.0, 0.0074, 0.0244), (0.0, 0.0, 0.0126)], origin) == [True, True]


def test_a_tracker_reused_for_the_next_episode_starts_from_its_reset():
    tracker = EpisodeTracker(1, horizon=3, task_rules="paper_text")
    tracker.reset(None, [0.5], [1], [N_C], [0.5])
    for p_i in (10.0, 36.0, 38.0):  # reaches the end, first three steps
        tracker.step([p_i], [2], [int(p_i) + 1], [N_C], [L_C], [p_i], [2])
    assert tracker.outcome[0] == task.OUTCOME_HOLD_THE_END
    assert tracker.outcome_authors[0] == task.OUTCOME_HOLD_THE_END
    # next episode, another cable: everything from the reset's values
    tracker.reset(None, [2.0], [5], [30], [-1.0])
    assert tracker.how_far().tolist() == [30 - 1 - 5]
    assert tracker.outcome[0] == task.OUTCOME_NONE and tracker.outcome_authors[0] == task.OUTCOME_NONE
    reward, terminated, truncated = tracker.step([3.0], [2], [4], [30], [29 * 0.0043], [-1.0], [0])
    assert reward[0] == pytest.approx(10 * 1.0 * 29 * 0.0043 / 30)  # from the reset's p_i = 2
    reward, _, _ = tracker.step([3.5], [2], [4], [30], [29 * 0.0043], [-1.0], [0])
    assert reward[0] == pytest.approx(10 * 0.5 * 29 * 0.0043 / 30)  # from the previous step's p_i
    reward, terminated, truncated = tracker.step([-1.0], [0], [-1], [30], [29 * 0.0043], [-1.0], [0])  # dropped
    assert terminated[0] and not truncated[0] and reward[0] == -0.5
    summary = tracker.summary(0)
    assert summary["episode_return"] == pytest.approx(10 * 1.5 * 29 * 0.0043 / 30 - 0.5)
    assert summary["time_at_end"] == 0 and summary["how_far"] == 30 - 1 - 5  # best index kept from the reset
    assert summary["outcome"] == "drop_before"  # the previous episode's visit to the end does not count
    assert summary["outcome_authors"] == "drop_before"  # nor its authors'-set mean index
    assert summary["episode_length"] == 3


def test_a_tracker_reset_with_nothing_held_and_its_first_steps():
    tracker = EpisodeTracker(1, horizon=5, task_rules="paper_text")
    tracker.reset(None, [-1.0], [-1], [N_C], [-1.0])
    assert tracker.how_far().tolist() == [N_C - 1]
    reward, _, _ = tracker.step([3.0], [2], [4], [N_C], [L_C], [0.0], [2])
    assert reward[0] == 0.0  # nothing held before: no move reward
    # the authors' set holding only particle 0 on the last step: held, not at the end of 40 particles
    for _ in range(4):
        tracker.step([3.0], [2], [4], [N_C], [L_C], [0.0], [2])
    assert tracker.outcome_authors[0] == task.OUTCOME_STOP_BEFORE


def test_a_new_tracker_counts_nothing_held_before_its_first_step():
    tracker = EpisodeTracker(2, task_rules="paper_text")
    reward, _, _ = tracker.step([3.0, 3.0], [2, 2], [4, 4], [N_C, N_C], [L_C, L_C], [3.0, 3.0], [2, 2])
    assert reward.tolist() == [0.0, 0.0]
    assert tracker.how_far().tolist() == [N_C - 1 - 4] * 2  # the cable of the step, not of a reset
    # a 5-particle cable dropped at once: the authors' set never held
    short = EpisodeTracker(1, horizon=1, task_rules="paper_text")
    short.step([-1.0], [0], [-1], [5], [4 * 0.0043], [-1.0], [0])
    assert short.outcome_authors[0] == task.OUTCOME_DROP_BEFORE
