"""The cable-following task: reward, episode end, outcome and metrics (paper: Reward, Evaluation Metrics).

Pure numpy, batched over environments; shared by the gym env, the ROS sim node and bag analysis.

Reward per control step (n_h held particles, p_i their mean index, n_c particles, L_c length [m]):
    R = ALPHA_MOVE (d_t - d_{t-1}) + R_end  while n_h > 0,   d_t = p_i L_c / n_c  [m]
    R_end = ALPHA_END (p_i + END_REWARD_WINDOW - n_c)  if p_i > n_c - END_REWARD_WINDOW else 0
    R = FALL_PENALTY and the episode ends when n_h = 0.
When nothing was held before the step (p_{t-1} < 0) there is no d_{t-1}: R_move = 0.

"At the end" = holding any of the last ``end_particles`` (paper: 10) particles.
Outcomes (codes equal dlo_msgs/TaskState.OUTCOME_*):
    HOLD_THE_END        not dropped and at the end on the last step (horizon)
    STOP_BEFORE         not dropped and not at the end on the last step
    REACH_END_BUT_DROP  dropped after having been at the end at some step
    DROP_BEFORE         dropped without ever being at the end
Metrics: time at end = number of control steps at the end; how far = particles from the end,
n_c - 1 - (largest held index reached in the episode), 0 = it held the last particle.
"""

from __future__ import annotations

import numpy as np

ALPHA_MOVE = 10.0
ALPHA_END = 1.0 / 20.0
END_REWARD_WINDOW = 20  # particles
FALL_PENALTY = -0.5
END_PARTICLES = 10  # "at the end" = any of the last 10 held (the authors' code used 5)
HORIZON = 150  # control steps per episode

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


def step_reward(prev_p_i, p_i, n_h, n_c, L_c):
    """Reward of one control step (batched or scalar); see the module docstring."""
    prev_p_i, p_i = np.asarray(prev_p_i, dtype=np.float64), np.asarray(p_i, dtype=np.float64)
    n_c, L_c = np.asarray(n_c, dtype=np.float64), np.asarray(L_c, dtype=np.float64)
    move = np.where(prev_p_i >= 0, ALPHA_MOVE * (p_i - prev_p_i) * L_c / n_c, 0.0)
    end = np.where(p_i > n_c - END_REWARD_WINDOW, ALPHA_END * (p_i + END_REWARD_WINDOW - n_c), 0.0)
    return np.where(np.asarray(n_h) > 0, move + end, FALL_PENALTY)


def at_end(max_held_index, n_c, end_particles=END_PARTICLES):
    """True where any of the last ``end_particles`` particles is held (max_held_index -1 = none held)."""
    max_held_index = np.asarray(max_held_index)
    return (max_held_index >= 0) & (max_held_index >= np.asarray(n_c) - end_particles)


def classify_outcome(dropped, reached_end, at_end_now):
    """Outcome code of finished episodes from: dropped (n_h = 0 ended it), ever at the end, at the end on the last step."""
    dropped, reached_end, at_end_now = (np.asarray(a, dtype=bool) for a in (dropped, reached_end, at_end_now))
    kept = np.where(at_end_now, OUTCOME_HOLD_THE_END, OUTCOME_STOP_BEFORE)
    lost = np.where(reached_end, OUTCOME_REACH_END_BUT_DROP, OUTCOME_DROP_BEFORE)
    return np.where(dropped, lost, kept).astype(np.int64)


class EpisodeTracker:
    """Per-environment running task state for N environments.

    Call ``reset(env_ids, ...)`` after the simulator reset those environments, then ``step(...)``
    after every control step. ``step`` returns (reward, terminated, truncated): terminated = dropped,
    truncated = horizon reached while holding. Finished episodes keep their ``outcome`` and metrics
    until the next ``reset`` of that environment.
    """

    def __init__(self, num_envs, horizon=HORIZON, end_particles=END_PARTICLES):
        self.num_envs, self.horizon, self.end_particles = int(num_envs), int(horizon), int(end_particles)
        n = self.num_envs
        self.prev_p_i = np.full(n, -1.0)
        self.steps = np.zeros(n, np.int64)
        self.episode_return = np.zeros(n)
        self.time_at_end = np.zeros(n, np.int64)
        self.best_index = np.zeros(n, np.int64)  # largest held particle index reached
        self.reached_end = np.zeros(n, bool)
        self.num_particles = np.zeros(n, np.int64)
        self.outcome = np.full(n, OUTCOME_NONE, np.int64)

    def reset(self, env_ids, p_i, max_held_index, n_c):
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

    def step(self, p_i, n_h, max_held_index, n_c, L_c):
        """Account one control step of all environments; arrays (N,). Returns reward, terminated, truncated."""
        reward = step_reward(self.prev_p_i, p_i, n_h, n_c, L_c)
        end_now = at_end(max_held_index, n_c, self.end_particles)
        self.steps += 1
        self.episode_return += reward
        self.time_at_end += end_now
        self.best_index = np.maximum(self.best_index, max_held_index)
        self.reached_end |= end_now
        self.num_particles[:] = n_c
        self.prev_p_i = np.asarray(p_i, dtype=np.float64).copy()
        terminated = np.asarray(n_h) == 0
        truncated = ~terminated & (self.steps >= self.horizon)
        done = terminated | truncated
        self.outcome = np.where(done, classify_outcome(terminated, self.reached_end, end_now), self.outcome)
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
            "time_at_end": int(self.time_at_end[env_id]),
            "how_far": int(self.how_far()[env_id]),
            "episode_return": float(self.episode_return[env_id]),
            "episode_length": int(self.steps[env_id]),
        }
