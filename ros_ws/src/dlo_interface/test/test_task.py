"""dlo_interface.task on hand-made trajectories and hand-placed particles: rewards (also when only particle 0
or a single particle is held), held statistics of single and batched masks, episode end and outcomes
under both rules (also at small indices), the authors' held set around a gripper at and away from the
origin and at its exact boundaries, and trackers that are new, reset with nothing held, or reused
across episodes."""

import numpy as np
import pytest
from dlo_interface import task
from dlo_interface.task import EpisodeTracker, classify_outcome, held_statistics, step_reward
from dlo_interface.world import FINGER_AXIS_OFFSET

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


def test_rewards_when_particle_0_or_a_single_particle_is_held():
    # held before: only particle 0 (p_i = 0): a move is rewarded
    assert step_reward(0.0, 2.0, 2, N_C, L_C) == pytest.approx(10 * 2 * L_C / N_C)
    # one particle held now: still holding, no fall penalty
    assert step_reward(4.0, 5.0, 1, N_C, L_C) == pytest.approx(10 * L_C / N_C)


def test_outcome_codes_match_task_state_message():
    msg = open(__file__.rsplit("/ros_ws/", 1)[0] + "/ros_ws/src/dlo_msgs/msg/TaskState.msg").read()
    for code, name in task.OUTCOME_NAMES.items():
        assert f"uint8 OUTCOME_{name.upper()} = {code}" in msg
    assert classify_outcome([False, False, True, True], [True, False, True, False], [True, False, False, False]).tolist() == [
        1,
        2,
        3,
        4,
    ]


def run(trajectory, n_c=N_C, horizon=task.HORIZON):
    """Drive one tracker with a list of (p_i, n_h, max_held_index[, p_i_authors]) steps (p_i_authors
    defaults to p_i); returns rewards and summary."""
    tracker = EpisodeTracker(1, horizon=horizon, task_rules="paper_text")
    tracker.reset(None, [0.5], [1], [n_c], [0.5])
    rewards = []
    for p_i, n_h, max_held, *authors in trajectory:
        p_a = authors[0] if authors else p_i
        reward, terminated, truncated = tracker.step(
            [p_i], [n_h], [max_held], [n_c], [(n_c - 1) * 0.0043], [p_a], [2 if p_a >= 0 else 0]
        )
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
    tracker = EpisodeTracker(2, horizon=3, end_particles=5, task_rules="paper_text")
    tracker.reset(None, [0.5, 0.5], [1, 1], [40, 40], [0.5, 0.5])
    for _ in range(3):
        _, terminated, truncated = tracker.step([33.0, 36.0], [2, 2], [34, 36], [40, 40], [0.17, 0.17], [33.0, 36.0], [2, 2])
    assert truncated.tolist() == [True, True] and not terminated.any()
    assert [tracker.summary(i)["outcome"] for i in range(2)] == ["stop_before", "hold_the_end"]
    tracker.reset([1], [0.5], [1], [40], [0.5])
    assert tracker.outcome.tolist() == [task.OUTCOME_STOP_BEFORE, task.OUTCOME_NONE]
    assert tracker.steps.tolist() == [3, 0]


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


def test_held_statistics():
    held = np.zeros((2, 6), bool)
    held[0, [2, 3, 5]] = True
    n_h, p_i, max_held = task.held_statistics(held)
    assert n_h.tolist() == [3, 0] and p_i.tolist() == [pytest.approx(10 / 3), -1.0] and max_held.tolist() == [5, -1]


def test_held_statistics_of_one_particle_and_of_a_batch():
    held = np.zeros((3, 8), bool)
    held[0, 3] = True  # one particle
    held[1, [0, 1]] = True
    with np.errstate(all="raise"):  # no 0/0 for the row holding nothing
        n_h, p_i, max_held = held_statistics(held)
    assert n_h.tolist() == [1, 2, 0]
    assert p_i.tolist() == [3.0, 0.5, -1.0]
    assert max_held.tolist() == [3, 1, -1]


def test_at_the_end_from_index_0_on_short_cables():
    assert task.at_end([0, -1, 4], 5, end_particles=10).tolist() == [True, False, True]
    assert task.at_end_authors([0.0, -1.0], 5).tolist() == [True, False]


# ---------------------------------------------------------------- the authors'-code rule
G = np.array([[0.0, 0.0, 0.1, 1.0]])  # gripper x, y, z [m], closure
AXIS_Z = 0.1 - task.FINGER_AXIS_OFFSET  # the lower finger's axis
GRIPPER = np.array([[0.07, -0.04, 0.1 + FINGER_AXIS_OFFSET, 1.0]])  # lower finger axis at z = 0.1


def authors(points, gripper=GRIPPER, n=None):
    """held_mask_authors of the particles at ``points`` ((x, y, z) [m], the first ``n`` of them real) around
    ``gripper``."""
    positions = np.asarray(points, dtype=np.float64)[None]
    return task.held_mask_authors(positions, [len(points) if n is None else n], gripper)[0].tolist()


def authors_held(*points):
    """held_mask_authors of single particles at the given (x, y, z) around the gripper G."""
    return authors(points, G)


def test_authors_held_set_is_the_narrow_box_of_their_code():
    resting = AXIS_Z + 0.0165  # a particle resting on the lower finger (radius 0.0125 + cable 0.004)
    assert authors_held((0.0, 0.0, resting)) == [True]
    # along the finger: |dy| < 0.0075 only (the paper-text rule takes the rounded ends up to 0.02)
    assert authors_held((0.0, 0.0074, resting), (0.0, 0.0076, resting), (0.0, -0.0076, resting)) == [True, False, False]
    # height: more than 0.0125 above the axis
    assert authors_held((0.0, 0.0, AXIS_Z + 0.0126), (0.0, 0.0, AXIS_Z + 0.0124)) == [True, False]
    # distance to the axis in x-z below 0.0245
    assert authors_held((0.0, 0.0, AXIS_Z + 0.0244), (0.0, 0.0, AXIS_Z + 0.0246)) == [True, False]
    assert authors_held((0.0195, 0.0, AXIS_Z + 0.0145), (0.02, 0.0, AXIS_Z + 0.0145)) == [True, False]
    # padded rows beyond n_c never count
    positions = np.array([[[0.0, 0.0, resting], [0.0, 0.0, resting]]])
    assert task.held_mask_authors(positions, [1], G).tolist() == [[True, False]]


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


def test_authors_held_set_lies_inside_the_paper_text_one():
    rng = np.random.default_rng(0)
    points = rng.uniform([-0.03, -0.03, AXIS_Z - 0.01], [0.03, 0.03, AXIS_Z + 0.03], (1, 20000, 3))
    authors = task.held_mask_authors(points, [20000], G)[0]
    dx, dy, dz = points[0, :, 0], points[0, :, 1], points[0, :, 2] - AXIS_Z
    paper = (np.abs(dy) <= 0.0075 + 0.0125) & (dx**2 + dz**2 <= (0.008 + 0.0125 + 0.0043) ** 2) & (dz > 0)
    assert authors.sum() > 100 and not (authors & ~paper).any()


def test_authors_at_end_is_the_mean_held_index_within_5_of_the_last():
    # n_c = 40: last index 39; (39 - p) < 5  <=>  p > 34
    assert task.at_end_authors([34.0, 34.01, 39.0, -1.0], 40).tolist() == [False, True, True, False]
    assert task.classify_outcome_authors([True, True, False, False], [36.0, 20.0, 36.0, 20.0], [40] * 4).tolist() == [1, 2, 3, 4]


def test_oracle_touching_particle_n_c_minus_10_holds_the_end_only_under_the_paper_rule():
    """Slide until the largest held index is n_c - 10 (mean index ~ n_c - 11) and stop there."""
    slide = [(0.5 + i, 2, 1 + i) for i in range(30)]  # max held index reaches 30 = n_c - 10
    stop = [(29.5, 2, 30)] * (task.HORIZON - len(slide))
    summary = run(slide + stop)[1]
    assert summary["outcome"] == "hold_the_end" and summary["outcome_authors"] == "stop_before"


def test_authors_outcomes_over_episodes():
    # at the end under both rules until the horizon
    to_end = [(0.5 + i, 2, 1 + i) for i in range(39)] + [(38.5, 2, 39)] * 111
    assert run(to_end)[1]["outcome_authors"] == "hold_the_end"
    # paper set still holds at the horizon, the authors' narrower set lost the cable: their drop,
    # classified by the last mean index their set had (at the end -> reach end but drop)
    lost = [(0.5 + i, 2, 1 + i) for i in range(39)] + [(38.5, 2, 39, -1.0)] * 111
    summary = run(lost)[1]
    assert summary["outcome"] == "hold_the_end" and summary["outcome_authors"] == "reach_end_but_drop"
    # dropped far from the end: drop before under both rules
    dropped = [(5.5, 2, 6)] * 10 + [(-1.0, 0, -1)]
    summary = run(dropped)[1]
    assert summary["outcome"] == summary["outcome_authors"] == "drop_before"
    # reached the end, slid back and dropped: the paper rule remembers the visit, the authors' rule
    # only the last held mean index
    back = [(0.5 + i, 2, 1 + i) for i in range(39)] + [(10.0, 2, 11)] * 5 + [(-1.0, 0, -1)]
    summary = run(back)[1]
    assert summary["outcome"] == "reach_end_but_drop" and summary["outcome_authors"] == "drop_before"


def test_authors_reward_uses_their_segment_count_and_the_fall_penalty():
    n_c, L_c = 41, 40 * 0.004  # 40 segments of 4 mm
    assert task.step_reward_authors(5.0, 7.0, 3, n_c, L_c) == pytest.approx(10 * 2 * 0.004)
    assert task.step_reward_authors(20.0, 20.0, 2, n_c, L_c) == 0.0  # p_a = s - 20: not yet
    assert task.step_reward_authors(30.0, 30.0, 2, n_c, L_c) == pytest.approx((30 + 20 - 40) / 20)
    assert task.step_reward_authors(40.0, 40.0, 1, n_c, L_c) == pytest.approx(1.0)  # one particle: still a reward
    assert task.step_reward_authors(10.0, -1.0, 0, n_c, L_c) == -0.5
    assert task.step_reward_authors(-1.0, 3.0, 2, n_c, L_c) == 0.0  # nothing held before: no move term


def test_task_rules_decide_the_drop():
    assert task.dropped("paper_text", [0, 1, 5], [0, 0, 0]).tolist() == [True, False, False]
    assert task.dropped("authors_code", [5, 5, 5], [0, 1, 2]).tolist() == [True, True, False]
    with pytest.raises(ValueError, match="task_rules: expected one of paper_text, authors_code, got 'authors'"):
        task.dropped("authors", [1], [1])


def test_authors_rules_end_the_episode_when_their_set_holds_one_particle_while_the_wide_set_holds():
    tracker = EpisodeTracker(1, horizon=10, task_rules="authors_code")
    tracker.reset(None, [3.0], [4], [40], [3.0])
    reward, terminated, truncated = tracker.step([4.0], [3], [5], [40], [0.16], [4.0], [2])
    assert not terminated[0] and not truncated[0]
    assert reward[0] == pytest.approx(task.step_reward_authors(3.0, 4.0, 2, 40, 0.16))
    reward, terminated, _ = tracker.step([5.0], [3], [6], [40], [0.16], [5.0], [1])
    assert terminated[0]  # the wide set still holds 3: the paper-text rules would go on
    summary = tracker.summary(0)
    assert summary["outcome"] == "drop_before" and summary["outcome_authors"] == "stop_before"
    assert summary["task_rules"] == "authors_code"
    paper = EpisodeTracker(1, horizon=10, task_rules="paper_text")
    paper.reset(None, [3.0], [4], [40], [3.0])
    assert not paper.step([5.0], [3], [6], [40], [0.16], [5.0], [1])[1][0]


def test_authors_rewards_when_particle_0_was_held_before():
    """The authors' reward, like the paper-text one: a mean held index of 0 before the step is held (only -1 is
    'nothing held'), so a move from it is rewarded."""
    n_c, L_c = 41, 40 * 0.004
    assert task.step_reward_authors(0.0, 2.0, 2, n_c, L_c) == pytest.approx(10 * 2 * 0.004)
    assert task.step_reward_authors(0.5, 1.5, 2, n_c, L_c) == pytest.approx(10 * 1 * 0.004)


def test_an_authors_code_tracker_rewards_each_step_from_the_previous_one():
    """Under the authors' task rules the move reward of every step is measured from the authors' mean held index
    of the step before (not from the reset's), and a new tracker counts nothing held before its first step."""
    n_c, L_c = 41, 40 * 0.004
    tracker = EpisodeTracker(1, horizon=10, task_rules="authors_code")
    tracker.reset(None, [3.0], [4], [n_c], [3.0])
    rewards = [tracker.step([p], [3], [int(p) + 1], [n_c], [L_c], [p], [3])[0][0] for p in (4.0, 6.0, 5.0)]
    assert rewards == pytest.approx([10 * 1 * 0.004, 10 * 2 * 0.004, -10 * 1 * 0.004])
    new = EpisodeTracker(2, task_rules="authors_code")
    reward, terminated, _ = new.step([3.0, 3.0], [2, 2], [4, 4], [n_c, n_c], [L_c, L_c], [3.0, 0.0], [2, 2])
    assert reward.tolist() == [0.0, 0.0] and not terminated.any()


def test_move_spacing_replaces_the_cables_own_spacing_in_the_move_term_under_both_task_rules():
    """move_spacing > 0 (the authors' fixed 4 mm): the move term is ALPHA_MOVE (p - p_prev) move_spacing under either
    task rule, whatever the cable's length; 0 is the cable's own spacing, bit for bit what it was; the end term and
    the fall penalty do not change. A tracker given one rewards with it and says it in its summary."""
    n_c, L_c = 41, 40 * 0.0043  # 4.3 mm particles: the two spacings differ
    for reward, own in ((task.step_reward, L_c / n_c), (task.step_reward_authors, L_c / (n_c - 1))):
        assert reward(5.0, 7.0, 3, n_c, L_c, move_spacing=0.004) == pytest.approx(10 * 2 * 0.004)
        assert reward(5.0, 7.0, 3, n_c, L_c, move_spacing=0.004) != pytest.approx(10 * 2 * own)
        assert reward(5.0, 7.0, 3, n_c, L_c, move_spacing=0.0) == reward(5.0, 7.0, 3, n_c, L_c)
        assert reward(5.0, 7.0, 3, n_c, L_c) == pytest.approx(10 * 2 * own)
        # the end term is the same with either spacing: only the move term (here 10 x 1 particle) scales
        with_end = reward(35.0, 36.0, 3, n_c, L_c, move_spacing=0.004) - reward(35.0, 36.0, 3, n_c, L_c)
        assert with_end == pytest.approx(10 * (0.004 - own))
        assert reward(10.0, -1.0, 0, n_c, L_c, move_spacing=0.004) == -0.5
        assert reward(-1.0, 3.0, 2, n_c, L_c, move_spacing=0.004) == 0.0
    batch = task.step_reward([1.0, 1.0], [2.0, 3.0], [2, 2], [30, 60], [0.12, 0.26], move_spacing=0.004)
    assert batch == pytest.approx([10 * 0.004, 10 * 2 * 0.004])  # both cables: the same spacing
    for rules in task.TASK_RULES:
        spaced, plain = EpisodeTracker(1, task_rules=rules, move_spacing=0.004), EpisodeTracker(1, task_rules=rules)
        for tracker in (spaced, plain):
            tracker.reset(None, [3.0], [4], [n_c], [3.0])
        rewards = [t.step([5.0], [3], [6], [n_c], [L_c], [5.0], [3])[0][0] for t in (spaced, plain)]
        assert rewards[0] == pytest.approx(10 * 2 * 0.004) and rewards[0] != pytest.approx(rewards[1]), rules
        assert (spaced.summary(0)["move_spacing"], plain.summary(0)["move_spacing"]) == (0.004, 0.0)


@pytest.mark.parametrize("bad", [-0.001, float("nan"), float("inf"), 0.0101, True, "0.004", None])
def test_a_bad_move_spacing_is_a_one_line_error(bad):
    with pytest.raises(ValueError, match=r"^move_spacing: expected a number in \[0, 0\.01\] m \(0: the cable's own"):
        task.check_move_spacing(bad)
    with pytest.raises(ValueError, match="^move_spacing: "):
        EpisodeTracker(1, move_spacing=bad)
    assert (task.check_move_spacing(0), task.check_move_spacing(0.01), task.check_move_spacing(np.float64(0.004))) == (
        0.0,
        0.01,
        0.004,
    )


def test_task_rules_are_records_that_say_their_held_set_end_and_outcome_rule():
    """dlo_interface.task.RULES: one record per variant; callers ask it (held set, drop, reward, outcome column) instead of
    comparing names; records of old runs and bags without the field read as the legacy rules, in one place."""
    from dlo_interface import task as t

    paper, authors = t.task_rules("paper_text"), t.task_rules("authors_code")
    assert t.TASK_RULES == ("paper_text", "authors_code") and t.DEFAULT_TASK_RULES in t.RULES
    assert (paper.select("physics", "authors"), authors.select("physics", "authors")) == ("physics", "authors")
    assert paper.dropped(np.array([0, 1, 2]), np.array([5, 5, 5])).tolist() == [True, False, False]
    assert authors.dropped(np.array([0, 0, 0]), np.array([0, 1, 2])).tolist() == [True, True, False]
    assert (paper.reward, authors.reward) == (t.step_reward, t.step_reward_authors)
    assert (paper.outcome_key, authors.outcome_key) == ("hold_the_end", "hold_the_end_authors")
    assert t.recorded_task_rules(None) is t.recorded_task_rules("") is t.task_rules(t.LEGACY_TASK_RULES)
    assert t.recorded_task_rules("authors_code") is authors
    with pytest.raises(ValueError, match="task_rules: expected one of paper_text, authors_code, got 'flex'"):
        t.task_rules("flex")


def test_no_module_compares_task_rule_names_outside_the_registry():
    """Task rules as records: no product module branches on a task-rule name (``== "authors_code"``); they ask the
    record (dlo_interface.task)."""
    import pathlib
    import re

    src = pathlib.Path(__file__).resolve().parents[2]
    compare = re.compile(r"""[=!]= *["'](authors_code|paper_text)["']|["'](authors_code|paper_text)["'] *[=!]=""")
    offenders = [
        str(path.relative_to(src))
        for path in src.glob("*/*/*.py")
        if "/test/" not in str(path) and compare.search(path.read_text())
    ]
    assert offenders == []
