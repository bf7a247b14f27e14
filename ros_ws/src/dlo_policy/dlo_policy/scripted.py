"""Scripted policies for the cable-following env: sanity checks and classical baselines.

Every policy is called as ``policy(observation, env) -> actions (N, 3)`` on a batched env
(``CableFollowingVecEnv``) and may keep per-env memory that ``reset(env_ids)`` clears.

- ``RandomPolicy``: uniform actions in [-1, 1]^3.
- ``OracleFollow``: ground truth from the simulator (particles, held set): moves toward a particle
  a few indices ahead of the held ones with the closure in the sliding band, and stops and holds
  firmly once it holds particles near the free end. Proves the task is solvable in our physics.
- ``TactileReactive``: after She et al. 2021 (docs/ARCHITECTURE.md#baselines), observations only (K, T, V):
  a pose loop steering along the cable as felt by the fingers (angle, offset) plus the cable's
  direction from its fixed end, a grip loop in the sliding band, and a stop by vision.
"""

from __future__ import annotations

import numpy as np
from dlo_interface.task import held_statistics
from dlo_interface.world import FIXED_END

from dlo_policy.observation import observation_labels

HOLD_FIRMLY = 1.0  # action a2 for c = 1
MIN_REACH = 0.02  # m, x distance from the fixed end below which its direction is taken as +x


def closure_action(closure):
    """Closure c in [0, 1] -> action component a2 in [-1, 1]."""
    return 2.0 * np.asarray(closure) - 1.0


def unit(vectors):
    """Rows of (N, 2) scaled to length 1 (zero rows stay ~0)."""
    return vectors / np.maximum(np.linalg.norm(vectors, axis=1, keepdims=True), 1e-9)


class RandomPolicy:
    """Uniform random actions; seeded."""

    def __init__(self, seed=0):
        self.rng = np.random.default_rng(seed)

    def reset(self, env_ids=None):
        """Stateless."""

    def __call__(self, observation, env):
        return self.rng.uniform(-1.0, 1.0, (env.num_envs, 3)).astype(np.float32)


class OracleFollow:
    """Ground-truth follower: slides toward particle (max held index + lookahead), then holds the end.

    slide_closure: c while sliding (grip law: 0.5..0.9 slides). stop_before_end: stop once the
    largest held index reaches n_c - 1 - this. speed: fraction of the maximum gripper speed.
    """

    def __init__(self, slide_closure=0.7, hold_closure=0.9, lookahead=3, stop_before_end=2, speed=1.0):
        self.slide_closure, self.hold_closure, self.lookahead = slide_closure, hold_closure, lookahead
        self.stop_before_end, self.speed = stop_before_end, speed

    def reset(self, env_ids=None):
        """Stateless."""

    def __call__(self, observation, env):
        sim = env.sim
        positions = sim.positions()
        _, _, max_held = held_statistics(sim.held_mask())
        max_held = np.maximum(max_held, 0)
        n_c = sim.num_particles
        gripper = sim.gripper_state()
        rows = np.arange(len(n_c))
        target = positions[rows, np.minimum(max_held + self.lookahead, n_c - 1), :2]
        along_cable = unit(target - gripper[:, :2])
        away_from_fixed_end = unit(target - np.asarray(FIXED_END[:2]))
        # Never head back towards the fixed end: that only pushes the cable into the fingers.
        direction = unit(along_cable + away_from_fixed_end)
        at_end = max_held >= n_c - 1 - self.stop_before_end
        move = np.where(at_end[:, None], 0.0, self.speed * direction)
        grip = closure_action(np.where(at_end, self.hold_closure, self.slide_closure))
        return np.concatenate([move, grip[:, None]], axis=1).astype(np.float32)


class TactileReactive:
    """She et al. 2021 style controller on observations only (needs K, T and V in the observation).

    Pose loop: heading = alpha + gain_angle * theta_T + gain_offset * y_T, clipped to +-pi/3, where
    alpha is the direction from the cable's fixed end to the gripper; constant speed.
    Grip loop: c = slide_closure + gain_slip * |change of theta_T| (closing fast, opening with leak
    ``release``). Stop: hold firmly once vision sees no cable continuing right (q_V < stop_confidence),
    after ``min_steps`` control steps (at the start the cable hangs steeply from its fixed end).
    """

    def __init__(
        self,
        gain_angle=0.5,
        gain_offset=40.0,
        slide_closure=0.7,
        gain_slip=0.5,
        release=0.05,
        stop_confidence=0.5,
        min_steps=10,
        speed=1.0,
    ):
        self.gain_angle, self.gain_offset = gain_angle, gain_offset
        self.slide_closure, self.gain_slip, self.release = slide_closure, gain_slip, release
        self.stop_confidence, self.min_steps, self.speed = stop_confidence, min_steps, speed
        self.steps = None
        self.previous_angle = None
        self.closure = None
        self.stopped = None

    def reset(self, env_ids=None):
        """Forget the memory of the given envs (all if None)."""
        if self.previous_angle is None:
            return
        ids = slice(None) if env_ids is None else env_ids
        self.steps[ids] = 0
        self.previous_angle[ids] = 0.0
        self.closure[ids] = self.slide_closure
        self.stopped[ids] = False

    def __call__(self, observation, env):
        labels = observation_labels(env.modalities)
        value = {label: observation[:, labels.index(label)] for label in labels}
        n = len(observation)
        if self.previous_angle is None or len(self.previous_angle) != n:
            self.steps = np.zeros(n, np.int64)
            self.previous_angle = np.zeros(n)
            self.closure = np.full(n, self.slide_closure)
            self.stopped = np.zeros(n, bool)
        theta_t, y_t = value["theta_T"], value["y_T"]
        # Direction of the cable from its fixed end; the gripper starts just behind that end.
        alpha = np.arctan2(value["y_G"] - FIXED_END[1], np.maximum(value["x_G"] - FIXED_END[0], MIN_REACH))
        heading = np.clip(alpha + self.gain_angle * theta_t + self.gain_offset * y_t, -np.pi / 3, np.pi / 3)
        slip = np.abs(theta_t - self.previous_angle)
        self.previous_angle = theta_t.copy()
        target = self.slide_closure + self.gain_slip * slip
        self.closure = np.clip(np.where(target > self.closure, target, self.closure - self.release), self.slide_closure, 0.89)
        self.steps += 1
        end_seen = (value["v_V"] < 0.5) | (value["q_V"] < self.stop_confidence)
        self.stopped |= end_seen & (self.steps > self.min_steps)
        move = self.speed * np.stack([np.cos(heading), np.sin(heading)], axis=1)
        move = np.where(self.stopped[:, None], 0.0, move)
        grip = np.where(self.stopped, HOLD_FIRMLY, closure_action(self.closure))
        return np.concatenate([move, grip[:, None]], axis=1).astype(np.float32)


EPISODE_END_KEYS = (
    "outcome",
    "outcome_code",
    "outcome_authors",
    "time_at_end",
    "how_far",
    "episode_return",
    "episode_length",
    "episode_seed",
    "unstable",
)


def run_episodes(env, policy, num_episodes, seed=0):
    """Run ``policy`` on a batched env for the episodes of seeds ``seed .. seed + num_episodes - 1``.

    Returns their episode-end info dicts (see EPISODE_END_KEYS), sorted by seed. Episodes of later
    seeds, started by auto-reset while the last ones run, are discarded.
    """
    observation, _ = env.reset(seed=seed)
    policy.reset()
    results = {}
    while len(results) < num_episodes:
        observation, _, _, _, info = env.step(policy(observation, env))
        if "_outcome" in info:
            done = np.flatnonzero(info["_outcome"])
            for i in done:
                if info["episode_seed"][i] < seed + num_episodes:
                    results[int(info["episode_seed"][i])] = {key: info[key][i] for key in EPISODE_END_KEYS}
            policy.reset(done)
    return [results[s] for s in sorted(results)]
