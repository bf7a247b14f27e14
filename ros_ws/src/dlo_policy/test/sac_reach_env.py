"""A tiny 1-D reach task with the rope env's interface, for fast SAC / training tests.

The agent moves a point x (|x| < 1) by 0.2 * a per step towards a random target; leaving the
interval terminates the episode ("drop_before"). Episode-end info mimics the rope env: `outcome`
("hold_the_end" within 0.1 of the target at the end, else "stop_before"), `time_at_end`,
`how_far`, `episode_return`. The observation has the rope env's modality blocks (K 3, T 2, V 4),
each carrying the position error, so any modality subset can solve it.

`step_delay` (env_options.step_delay) sleeps that many seconds in every step, to give a test time to signal
or kill a run. Where it is not given, the environment variable STEP_DELAY_VARIABLE gives it (default 0): a
test hands it to the one process it stops, so that the run's config.yaml, and the runs it is compared with,
are the same as without it (and do not sleep).
"""

from __future__ import annotations

import os
import time

import gymnasium as gym
import numpy as np
from dlo_policy.observation import MODALITY_SIZES, parse_modalities

HORIZON = 20
NEAR = 0.1
STEP_DELAY_VARIABLE = "SAC_REACH_STEP_DELAY"  # seconds slept per step where step_delay is not given


class ReachEnv(gym.Env):
    def __init__(self, modalities: str = "All", horizon: int = HORIZON, crash_after: int = 0, step_delay: float | None = None):
        self.modalities = parse_modalities(modalities)
        size = sum(MODALITY_SIZES[m] for m in self.modalities)
        self.observation_space = gym.spaces.Box(-2.0, 2.0, (size,), np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
        self.horizon = horizon
        self.crash_after = crash_after  # > 0: raise after this many steps (simulates an interrupted run)
        self.steps_taken = 0
        if step_delay is None:
            step_delay = float(os.environ.get(STEP_DELAY_VARIABLE, "0"))
        self.step_delay = step_delay  # seconds slept per step (gives a test time to kill the run)

    def _obs(self) -> np.ndarray:
        error = self.target - self.x
        blocks = {"K": [self.x, self.target, 0.0], "T": [error, 0.0], "V": [error, 1.0, 0.0, 0.0]}
        return np.concatenate([blocks[m] for m in self.modalities]).astype(np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.x = 0.0
        self.target = float(self.np_random.uniform(-0.6, 0.6))
        self.t, self.time_at_end, self.episode_return = 0, 0, 0.0
        return self._obs(), {}

    def step(self, action):
        if self.step_delay:
            time.sleep(self.step_delay)
        self.steps_taken += 1
        if self.crash_after and self.steps_taken > self.crash_after:
            raise InterruptedError(f"reach env: simulated crash after {self.crash_after} steps")
        self.x += 0.2 * float(np.clip(action[0], -1, 1))
        self.t += 1
        distance = abs(self.target - self.x)
        terminated = abs(self.x) >= 1.0
        reward = -1.0 if terminated else -distance
        self.time_at_end += distance < NEAR
        self.episode_return += reward
        truncated = self.t >= self.horizon
        info = {}
        if terminated or truncated:
            outcome = "drop_before" if terminated else ("hold_the_end" if distance < NEAR else "stop_before")
            # the authors' rule is stricter: within half the distance
            strict = "drop_before" if terminated else ("hold_the_end" if distance < NEAR / 2 else "stop_before")
            info = {
                "outcome": outcome,
                "outcome_authors": strict,
                "time_at_end": self.time_at_end,
                "how_far": 1.0 - distance,
                "episode_return": self.episode_return,
            }
        return self._obs(), reward, terminated, truncated, info


def make_env(modalities: str = "All", seed: int = 0, **options) -> ReachEnv:
    return ReachEnv(modalities, **options)


def make_vec_env(num_envs: int, modalities: str = "All", seed: int = 0, **options) -> gym.vector.VectorEnv:
    return gym.vector.SyncVectorEnv([lambda: ReachEnv(modalities, **options) for _ in range(num_envs)])
