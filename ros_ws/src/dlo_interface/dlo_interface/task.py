"""The cable-following task: reward, episode end, outcome and metrics (paper: Reward, Evaluation Metrics).

Pure numpy, batched over environments; shared by the gym env, the ROS sim node and bag analysis.

Reward per control step (n_h held particles, p_i their mean index, n_c particles, L_c length [m]):
    R = ALPHA_MOVE (d_t - d_{t-1}) + R_end  while n_h > 0,   d_t = p_i L_c / n_c  [m]
    R_end = ALPHA_END (p_i + END_REWARD_WINDOW - n_c)  if p_i > n_c - END_REWARD_WINDOW else 0
    R = FALL_PENALTY and the episode ends when n_h = 0.
When nothing was held before the step (p_{t-1} < 0) there is no d_{t-1}: R_move = 0.
Move spacing (``move_spacing``, env option / sim node parameter, off by default): > 0 replaces the cable's own
particle spacing in d_t under either task rule, d_t = p_i move_spacing [m]; AUTHORS_MOVE_SPACING (4 mm) is the
authors' fixed one (SoftSlidingGym ``rope_follow.py`` compute_reward: rope_length = segment x 0.004 m). 0 (the
default): the cable's own, L_c / n_c (paper_text) or L_c / (n_c - 1) (authors_code). R_end is unchanged.

Outcomes (codes equal dlo_msgs/TaskState.OUTCOME_*), decided when the episode ends, under two
definitions that are both always computed (docs/ARCHITECTURE.md#task):

**paper text** (``classify_outcome``): "at the end" = holding any of the last ``end_particles``
(paper: 10) particles, held set = the physics' held rule (docs/ARCHITECTURE.md#physics).
    HOLD_THE_END        not dropped and at the end on the last step (horizon)
    STOP_BEFORE         not dropped and not at the end on the last step
    REACH_END_BUT_DROP  dropped after having been at the end at some step
    DROP_BEFORE         dropped without ever being at the end

**authors' code** (``classify_outcome_authors``; SoftSlidingGym ``rope_follow.py``, what produced
the paper's numbers): held set ``held_mask_authors`` (narrower: |y - y_G| < 0.0075 m, distance to
the lower finger's axis in x-z < 0.0245 m, z above that axis + 0.0125 m); p_a = mean index of
that set on the last step it was non-empty; "at the end" = (n_c - 1) - p_a < 5.
    HOLD_THE_END        the authors' held set is non-empty on the last step and p_a is at the end
    STOP_BEFORE         it is non-empty on the last step and p_a is not at the end
    REACH_END_BUT_DROP  it is empty on the last step and the last p_a was at the end
    DROP_BEFORE         it is empty on the last step and the last p_a was not at the end
Task rules (``TASK_RULES``, env option / sim node parameter ``task_rules``): what the episode
itself (reward, termination, the tactile input) is computed from.
    paper_text    the physics' held set; reward as above; the episode ends when it is empty.
    authors_code  (default, DEFAULT_TASK_RULES) the authors' held set (SoftSlidingGym ``action_space_sliding.py`` get_hold_idx,
                  ``rope_sliding_env.py`` _get_obs, ``rope_follow.py`` compute_reward): reward from
                  the mean index p_a of that set with their segment count s = n_c - 1,
                  R = ALPHA_MOVE (d_t - d_{t-1}) + R_end, d_t = p_a L_c / s,
                  R_end = ALPHA_END (p_a + END_REWARD_WINDOW - s) if p_a > s - END_REWARD_WINDOW,
                  R = FALL_PENALTY when the set is empty; the episode ends when it holds <= 1
                  particle (their ``self.done`` when fewer than two points are left to fit).
Both outcome rules are computed under either task rule; "dropped" in the paper-text outcome is
"the episode ended by the task rule's drop" (terminated).
Metrics: time at end = number of control steps at the end; how far = particles from the end,
n_c - 1 - (largest held index reached in the episode), 0 = it held the last particle.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np

from dlo_interface.world import FINGER_AXIS_OFFSET

ALPHA_MOVE = 10.0
ALPHA_END = 1.0 / 20.0
END_REWARD_WINDOW = 20  # particles
FALL_PENALTY = -0.5
END_PARTICLES = 10  # "at the end" = any of the last 10 held (the authors' code used 5)
HORIZON = 150  # control steps per episode
AUTHORS_DROP_AT = 1  # authors' rules: the episode ends when their held set has at most this many particles
AUTHORS_HELD_HALF_WIDTH = 0.0075  # m, authors' held set: |y - y_G| below this (the finger axis segment)
AUTHORS_HELD_DISTANCE = 0.0245  # m, authors' held set: distance to the lower finger's axis in x-z below this
AUTHORS_HELD_ABOVE = 0.0125  # m, authors' held set: z above the lower finger's axis by more than this
AUTHORS_END_WINDOW = 5  # authors' "at the end": (n_c - 1) - mean held index < this
AUTHORS_MOVE_SPACING = 0.004  # m, the authors' fixed particle spacing of the move reward (module docstring)
MAX_MOVE_SPACING = 0.01  # m, the largest move_spacing accepted (2.5 x theirs, 2.3 x our cables' longest spacing)
DEFAULT_MOVE_SPACING = 0.0  # the cable's own spacing (module docstring)

OUTCOME_NONE = 0
OUTCOME_HOLD_THE_END = 1
OUTCOME_STOP_BEFORE = 2
OUTCOME_REACH_END_BUT_DROP = 3
OUTCOME_DROP_BEFORE = 4
OUTCOME_NAMES = {
    OUTCOME_NONE: "none",
    OUTCOME_HOLD_THE_END: "hold_the_end",
    OUTCOME_STOP_BEFORE: "stop_before",
    OUTCOME_REACH_END_BUT_DROP: "reach_end_but_drop",
    OUTCOME_DROP_BEFORE: "drop_before",
}
OUTCOME_CODES = {name: code for code, name in OUTCOME_NAMES.items()}


def held_statistics(held_mask):
    """(N, P) bool held particles -> n_h (N,) int, p_i (N,) mean held index (-1 if none), largest held index (-1)."""
    held = np.asarray(held_mask, dtype=bool)
    n_h = held.sum(axis=1)
    index = np.arange(held.shape[1])
    p_i = np.where(n_h > 0, (held * index).sum(axis=1) / np.maximum(n_h, 1), -1.0)
    max_held_index = np.where(n_h > 0, held.shape[1] - 1 - np.argmax(held[:, ::-1], axis=1), -1)
    return n_h.astype(np.int32), p_i, max_held_index


def check_move_spacing(value) -> float:
    """``value`` as a float if it is a move spacing (module docstring): a number in [0, MAX_MOVE_SPACING] m, 0 = the
    cable's own spacing; else ValueError with a one-line reason."""
    if (
        isinstance(value, bool)
        or not isinstance(value, (int, float, np.integer, np.floating))
        or not (0.0 <= float(value) <= MAX_MOVE_SPACING)
    ):
        raise ValueError(
            f"move_spacing: expected a number in [0, {MAX_MOVE_SPACING}] m (0: the cable's own spacing, "
            f"{AUTHORS_MOVE_SPACING}: the authors'), got {value!r}"
        )
    return float(value)


def step_reward(prev_p_i, p_i, n_h, n_c, L_c, move_spacing=DEFAULT_MOVE_SPACING):
    """Reward of one control step (batched or scalar); see the module docstring."""
    prev_p_i, p_i = np.asarray(prev_p_i, dtype=np.float64), np.asarray(p_i, dtype=np.float64)
    n_c, L_c = np.asarray(n_c, dtype=np.float64), np.asarray(L_c, dtype=np.float64)
    moved = ALPHA_MOVE * (p_i - prev_p_i)
    move = np.where(prev_p_i >= 0, moved * move_spacing if move_spacing > 0 else moved * L_c / n_c, 0.0)
    end = np.where(p_i > n_c - END_REWARD_WINDOW, ALPHA_END * (p_i + END_REWARD_WINDOW - n_c), 0.0)
    return np.where(np.asarray(n_h) > 0, move + end, FALL_PENALTY)


def step_reward_authors(prev_p_a, p_a, n_h_a, n_c, L_c, move_spacing=DEFAULT_MOVE_SPACING):
    """Reward of one control step under the authors' task rules (module docstring), batched or scalar."""
    prev_p_a, p_a = np.asarray(prev_p_a, dtype=np.float64), np.asarray(p_a, dtype=np.float64)
    segments = np.asarray(n_c, dtype=np.float64) - 1.0
    spacing = move_spacing if move_spacing > 0 else np.asarray(L_c, dtype=np.float64) / segments
    move = np.where(prev_p_a >= 0, ALPHA_MOVE * (p_a - prev_p_a) * spacing, 0.0)
    end = np.where(p_a > segments - END_REWARD_WINDOW, ALPHA_END * (p_a + END_REWARD_WINDOW - segments), 0.0)
    return np.where(np.asarray(n_h_a) > 0, move + end, FALL_PENALTY)


@dataclass(frozen=True)
class TaskRules:
    """One variant of the task (module docstring): which held set the episode is computed from, its reward and its
    end; everything else asks the record instead of comparing names.

    name           how configs, parameters and messages write it ("authors_code")
    authors_set    True: the authors' narrow held set (``held_mask_authors``); False: the physics' held set
    drop_at        the episode ends (a drop) when that set holds at most this many particles
    reward         (previous mean index, mean index, n_held, n_c, L_c, move_spacing) of that set -> the step's reward
    outcome_key    the evaluation column of the outcome rule that goes with it: what chooses a run's best policy
    """

    name: str
    authors_set: bool
    drop_at: int
    reward: Callable
    outcome_key: str

    def select(self, physics, authors):
        """The value of the held set these rules use, from the pair (physics' set, authors' set)."""
        return authors if self.authors_set else physics

    def dropped(self, n_h, n_h_authors):
        """True where these rules end the episode as a drop."""
        return np.asarray(self.select(n_h, n_h_authors)) <= self.drop_at


RULES = {
    rules.name: rules
    for rules in (
        TaskRules("paper_text", authors_set=False, drop_at=0, reward=step_reward, outcome_key="hold_the_end"),
        TaskRules(
            "authors_code",
            authors_set=True,
            drop_at=AUTHORS_DROP_AT,
            reward=step_reward_authors,
            outcome_key="hold_the_end_authors",
        ),
    )
}
TASK_RULES = tuple(RULES)  # their names: what reward, termination and the tactile input use
DEFAULT_TASK_RULES = "authors_code"  # the study's variant: its results come closest to the paper (docs/FIDELITY.md)
LEGACY_TASK_RULES = "paper_text"  # what runs, bags and outcome files from before the switch existed used


def check_task_rules(rules) -> str:
    """``rules`` if it is one of TASK_RULES, else ValueError with a one-line reason."""
    if rules not in RULES:
        raise ValueError(f"task_rules: expected one of {', '.join(TASK_RULES)}, got {rules!r}")
    return rules


def task_rules(name) -> TaskRules:
    """The record of ``name`` (ValueError with a one-line reason for an unknown one)."""
    return RULES[check_task_rules(name)]


def recorded_task_rules(name: Optional[str]) -> TaskRules:
    """The record a run directory, bag or outcome file names; one from before the field existed (None or '')
    ran under LEGACY_TASK_RULES. The one place old records are mapped."""
    return task_rules(name or LEGACY_TASK_RULES)


def dropped(rules, n_h, n_h_authors):
    """True where the task rules (a name) end the episode as a drop: paper_text n_h = 0, authors_code n_h_a <= 1."""
    return task_rules(rules).dropped(n_h, n_h_authors)


def at_end(max_held_index, n_c, end_particles=END_PARTICLES):
    """True where any of the last ``end_particles`` particles is held (max_held_index -1 = none held)."""
    max_held_index = np.asarray(max_held_index)
    return (max_held_index >= 0) & (max_held_index >= np.asarray(n_c) - end_particles)


def held_mask_authors(positions, num_particles, gripper):
    """(N, P) bool held set of the authors' code (module docstring) from positions (N, P, 3) [m],
    num_particles (N,) and the gripper (N, >=3): x_G, y_G, z_G [m] (rows beyond n_c are False)."""
    positions = np.asarray(positions, dtype=np.float64)
    gripper = np.asarray(gripper, dtype=np.float64)
    g = gripper[:, None, :3]
    dx = positions[..., 0] - g[..., 0]
    dy = positions[..., 1] - g[..., 1]
    dz = positions[..., 2] - (g[..., 2] - FINGER_AXIS_OFFSET)
    inside = np.arange(positions.shape[1])[None, :] < np.asarray(num_particles)[:, None]
    return (
        inside
        & (np.abs(dy) < AUTHORS_HELD_HALF_WIDTH)
        & (dx * dx + dz * dz < AUTHORS_HELD_DISTANCE**2)
        & (dz > AUTHORS_HELD_ABOVE)
    )


def at_end_authors(mean_index, n_c):
    """Authors' "at the end": a mean held index (-1 = none) within AUTHORS_END_WINDOW of the last index."""
    mean_index = np.asarray(mean_index, dtype=np.float64)
    return (mean_index >= 0) & (np.asarray(n_c) - 1 - mean_index < AUTHORS_END_WINDOW)


def classify_outcome_authors(holding_now, last_mean_index, n_c):
    """Authors' outcome code of finished episodes from: their held set non-empty on the last step,
    the mean index of that set on the last step it was non-empty (-1 = never), n_c."""
    holding_now = np.asarray(holding_now, dtype=bool)
    end = at_end_authors(last_mean_index, n_c)
    kept = np.where(end, OUTCOME_HOLD_THE_END, OUTCOME_STOP_BEFORE)
    lost = np.where(end, OUTCOME_REACH_END_BUT_DROP, OUTCOME_DROP_BEFORE)
    return np.where(holding_now, kept, lost).astype(np.int64)


def classify_outcome(dropped, reached_end, at_end_now):
    """Outcome code of finished episodes from: dropped (n_h = 0 ended it), ever at the end, at the end on the last step."""
    dropped, reached_end, at_end_now = (np.asarray(a, dtype=bool) for a in (dropped, reached_end, at_end_now))
    kept = np.where(at_end_now, OUTCOME_HOLD_THE_END, OUTCOME_STOP_BEFORE)
    lost = np.where(reached_end, OUTCOME_REACH_END_BUT_DROP, OUTCOME_DROP_BEFORE)
    return np.where(dropped, lost, kept).astype(np.int64)


def _rules(rules) -> TaskRules:
    """A TaskRules record from a record or a name."""
    return rules if isinstance(rules, TaskRules) else task_rules(rules)


class EpisodeTracker:
    """Per-environment running task state for N environments.

    Call ``reset(env_ids, ...)`` after the simulator reset those environments, then ``step(...)``
    after every control step. ``step`` returns (reward, terminated, truncated): terminated = dropped,
    truncated = horizon reached while holding. Finished episodes keep their ``outcome`` (paper
    text) and ``outcome_authors`` (authors' code) and metrics until the next ``reset`` of that
    environment. ``p_i_authors``: mean index of ``held_mask_authors`` (-1 when it is empty). ``move_spacing``: the
    move reward's particle spacing [m], 0 = the cable's own (module docstring; ValueError for a bad one).
    """

    def __init__(
        self,
        num_envs,
        horizon=HORIZON,
        end_particles=END_PARTICLES,
        task_rules=DEFAULT_TASK_RULES,
        move_spacing=DEFAULT_MOVE_SPACING,
    ):
        self.num_envs, self.horizon, self.end_particles = int(num_envs), int(horizon), int(end_particles)
        self.rules = _rules(task_rules)
        self.task_rules = self.rules.name
        self.move_spacing = check_move_spacing(move_spacing)
        n = self.num_envs
        self.prev_p_i = np.full(n, -1.0)
        self.steps = np.zeros(n, np.int64)
        self.episode_return = np.zeros(n)
        self.time_at_end = np.zeros(n, np.int64)
        self.best_index = np.zeros(n, np.int64)  # largest held particle index reached
        self.reached_end = np.zeros(n, bool)
        self.num_particles = np.zeros(n, np.int64)
        self.outcome = np.full(n, OUTCOME_NONE, np.int64)
        self.last_p_i_authors = np.full(n, -1.0)  # authors' mean held index on the last step it was defined
        self.prev_p_i_authors = np.full(n, -1.0)  # authors' mean held index on the previous step (their reward)
        self.outcome_authors = np.full(n, OUTCOME_NONE, np.int64)

    def reset(self, env_ids, p_i, max_held_index, n_c, p_i_authors):
        """Start new episodes in ``env_ids`` from the state right after the simulator reset."""
        ids = np.arange(self.num_envs) if env_ids is None else np.asarray(env_ids)
        self.prev_p_i[ids] = p_i
        self.steps[ids] = 0
        self.episode_return[ids] = 0.0
        self.time_at_end[ids] = 0
        self.best_index[ids] = np.maximum(max_held_index, 0)
        self.reached_end[ids] = False
        self.num_particles[ids] = n_c
        self.outcome[ids] = OUTCOME_NONE
        self.last_p_i_authors[ids] = p_i_authors
        self.prev_p_i_authors[ids] = p_i_authors
        self.outcome_authors[ids] = OUTCOME_NONE

    def step(self, p_i, n_h, max_held_index, n_c, L_c, p_i_authors, n_h_authors):
        """Account one control step of all environments; arrays (N,). Returns reward, terminated, truncated."""
        rules = self.rules
        reward = rules.reward(
            rules.select(self.prev_p_i, self.prev_p_i_authors),
            rules.select(p_i, p_i_authors),
            rules.select(n_h, n_h_authors),
            n_c,
            L_c,
            self.move_spacing,
        )
        end_now = at_end(max_held_index, n_c, self.end_particles)
        self.steps += 1
        self.episode_return += reward
        self.time_at_end += end_now
        self.best_index = np.maximum(self.best_index, max_held_index)
        self.reached_end |= end_now
        self.num_particles[:] = n_c
        self.prev_p_i = np.asarray(p_i, dtype=np.float64).copy()
        terminated = rules.dropped(n_h, n_h_authors)
        truncated = ~terminated & (self.steps >= self.horizon)
        done = terminated | truncated
        self.outcome = np.where(done, classify_outcome(terminated, self.reached_end, end_now), self.outcome)
        p_i_authors = np.asarray(p_i_authors, dtype=np.float64)
        self.prev_p_i_authors = p_i_authors.copy()
        holding_authors = p_i_authors >= 0
        self.last_p_i_authors = np.where(holding_authors, p_i_authors, self.last_p_i_authors)
        self.outcome_authors = np.where(
            done, classify_outcome_authors(holding_authors, self.last_p_i_authors, n_c), self.outcome_authors
        )
        return reward, terminated, truncated

    def how_far(self):
        """Particles from the end reached so far (N,): n_c - 1 - largest held index."""
        return np.maximum(self.num_particles - 1 - self.best_index, 0)

    def summary(self, env_id) -> dict:
        """Metrics of one environment's (finished) episode, as plain Python values."""
        code = int(self.outcome[env_id])
        return {
            "outcome": OUTCOME_NAMES[code],
            "outcome_code": code,
            "outcome_authors": OUTCOME_NAMES[int(self.outcome_authors[env_id])],
            "time_at_end": int(self.time_at_end[env_id]),
            "how_far": int(self.how_far()[env_id]),
            "episode_return": float(self.episode_return[env_id]),
            "episode_length": int(self.steps[env_id]),
            "task_rules": self.task_rules,
            "move_spacing": self.move_spacing,
        }
