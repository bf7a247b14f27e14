"""Reward, episode end and outcomes of the task module on hand-made trajectories."""

import numpy as np
import pytest

from dlo_sim import task
from dlo_sim.task import EpisodeTracker, classify_outcome, step_reward

N_C, L_C = 40, 39 * 0.0043


def test_move_reward_is_ten_times_distance_gained():
    assert step_reward(5.0, 7.0, 3, N_C, L_C) == pytest.approx(10 * 2 * L_C / N_C)
    assert step_reward(7.0, 5.0, 3, N_C, L_C) == pytest.approx(-10 * 2 * L_C / N_C)


def test_end_reward_grows_linearly_in_the_last_20_particles():
    assert step_reward(20.0, 20.0, 2, N_C, L_C) == 0.0  # p_i = n_c - 20: not yet
    assert step_reward(30.0, 30.0, 2, N_C, L_C) == pytest.approx((30 + 20 - 40) / 20)
    assert step_reward(39.0, 39.0, 2, N_C, L_C) == pytest.approx(19 / 20)


def test_drop_gives_fall_penalty_and_nothing_held_before_gives_no_move_reward():
    assert step_reward(10.0, -1.0, 0, N_C, L_C) == -0.5
    assert step_reward(-1.0, 3.0, 2, N_C, L_C) == 0.0
    batch = step_reward([1.0, 1.0], [2.0, -1.0], [2, 0], [N_C, N_C], [L_C, L_C])
    assert batch == pytest.approx([10 * L_C / N_C, -0.5])


def test_outcome_codes_match_task_state_message():
    msg = open(__file__.rsplit("/ros_ws/", 1)[0] + "/ros_ws/src/dlo_msgs/msg/TaskState.msg").read()
    for code, name in task.OUTCOME_NAMES.items():
        assert f"uint8 OUTCOME_{name.upper()} = {code}" in msg
    assert classify_outcome([False, False, True, True], [True, False, True, False],
                            [True, False, False, False]).tolist() == [1, 2, 3, 4]


def run(trajectory, n_c=N_C, horizon=task.HORIZON):
    """Drive one tracker with a list of (p_i, n_h, max_held_index) steps; returns rewards and summary."""
    tracker = EpisodeTracker(1, horizon=horizon)
    tracker.reset(None, [0.5], [1], [n_c])
    rewards = []
    for p_i, n_h, max_held in trajectory:
        reward, terminated, truncated = tracker.step([p_i], [n_h], [max_held], [n_c], [(n_c - 1) * 0.0043])
        rewards.append(float(reward[0]))
        if terminated[0] or truncated[0]:
            break
    return rewards, tracker.summary(0)


def test_hold_the_end_with_time_at_end_and_how_far():
    slide = [(0.5 + i, 2, 1 + i) for i in range(39)]  # max held index reaches 39 = last particle
    rest = [(38.5, 2, 39)] * (task.HORIZON - len(slide))
    rewards, summary = run(slide + rest)
    assert len(rewards) == task.HORIZON
    assert summary["outcome"] == "hold_the_end" and summary["outcome_code"] == task.OUTCOME_HOLD_THE_END
    assert summary["how_far"] == 0
    assert summary["time_at_end"] == len(rest) + 10  # steps with max held index >= 30
    assert summary["episode_return"] == pytest.approx(sum(rewards))


def test_stop_before_and_drop_outcomes():
    assert run([(5.5, 2, 6)] * 150)[1]["outcome"] == "stop_before"
    assert run([(5.5, 2, 6)] * 150)[1]["how_far"] == N_C - 1 - 6
    rewards, summary = run([(5.5, 2, 6)] * 10 + [(-1.0, 0, -1)] + [(5.5, 2, 6)] * 10)
    assert summary["outcome"] == "drop_before" and summary["episode_length"] == 11 and rewards[-1] == -0.5
    reached = [(0.5 + i, 2, 1 + i) for i in range(35)] + [(-1.0, 0, -1)]
    assert run(reached)[1]["outcome"] == "reach_end_but_drop"
    # Was at the end, slid back and kept holding: not at the end on the last step -> stop before.
    back = [(0.5 + i, 2, 1 + i) for i in range(35)] + [(10.0, 2, 11)] * 115
    assert run(back)[1]["outcome"] == "stop_before"


def test_end_is_a_parameter_and_batched_envs_are_independent():
    tracker = EpisodeTracker(2, horizon=3, end_particles=5)
    tracker.reset(None, [0.5, 0.5], [1, 1], [40, 40])
    for _ in range(3):
        _, terminated, truncated = tracker.step([33.0, 36.0], [2, 2], [34, 36], [40, 40], [0.17, 0.17])
    assert truncated.tolist() == [True, True] and not terminated.any()
    assert [tracker.summary(i)["outcome"] for i in range(2)] == ["stop_before", "hold_the_end"]
    tracker.reset([1], [0.5], [1], [40])
    assert tracker.outcome.tolist() == [task.OUTCOME_STOP_BEFORE, task.OUTCOME_NONE]
    assert tracker.steps.tolist() == [3, 0]


def test_held_statistics():
    held = np.zeros((2, 6), bool)
    held[0, [2, 3, 5]] = True
    n_h, p_i, max_held = task.held_statistics(held)
    assert n_h.tolist() == [3, 0] and p_i.tolist() == [pytest.approx(10 / 3), -1.0] and max_held.tolist() == [5, -1]
