"""Episodes of the task on the simulator: one RopeSim + one EpisodeTracker, stepped together.

The gym environment and the ROS sim node both run episodes through ``TaskSim``, so a control
step (physics, reward, ending) is the same code in-process and in the graph.
"""

from __future__ import annotations

import numpy as np

from dlo_sim.rope import RopeSim
from dlo_sim.task import HORIZON, EpisodeTracker


class TaskSim:
    """``num_envs`` environments of the cable-following task (physics + task bookkeeping)."""

    def __init__(self, num_envs: int, horizon: int = HORIZON, sim: RopeSim | None = None, **sim_options):
        self.sim = sim if sim is not None else RopeSim(num_envs, **sim_options)
        self.tracker = EpisodeTracker(self.sim.num_envs, horizon=horizon)

    @property
    def num_envs(self) -> int:
        return self.sim.num_envs

    def held_summary(self):
        """(p_i, n_h, largest held index (-1 = none)) per environment, each (N,)."""
        held = self.sim.held_mask()
        max_index = np.where(held.any(axis=1), held.shape[1] - 1 - np.argmax(held[:, ::-1], axis=1), -1)
        return self.sim.mean_held_index(), held.sum(axis=1), max_index

    def reset(self, seeds, env_ids=None) -> None:
        """Start new episodes from ``seeds`` in ``env_ids`` (all if None)."""
        self.sim.reset(seeds, env_ids)
        ids = np.arange(self.num_envs) if env_ids is None else np.asarray(env_ids)
        p_i, _, max_index = self.held_summary()
        self.tracker.reset(ids, p_i[ids], max_index[ids], self.sim.num_particles[ids])

    def step(self, actions):
        """One control step (8 x 0.01 s) of every environment -> (reward, terminated, truncated), each (N,)."""
        self.sim.step(actions)
        p_i, n_h, max_index = self.held_summary()
        return self.tracker.step(p_i, n_h, max_index, self.sim.num_particles, self.sim.cable_length)
