"""Episodes of the task on the simulator: one RopeSim + one EpisodeTracker, stepped together.

The gym environment and the ROS sim node both run episodes through ``TaskSim``, so a control
step (physics, reward, ending) is the same code in-process and in the graph.
"""

from __future__ import annotations

import numpy as np
from dlo_interface.task import (
    DEFAULT_MOVE_SPACING,
    DEFAULT_TASK_RULES,
    END_PARTICLES,
    HORIZON,
    EpisodeTracker,
    held_mask_authors,
    held_statistics,
)
from dlo_interface.task import task_rules as task_rules_record

from dlo_sim.rope import RopeSim, Snapshot


class TaskSim:
    """``num_envs`` environments of the cable-following task (physics + task bookkeeping).

    ``state`` is the ``Snapshot`` of the current state (after the last reset or step): positions,
    held mask, gripper and, if ``render``, the top view, read back with the step in one kernel
    launch for the task and reusable by the observation; ``n_held`` and ``mean_held_index`` (N,)
    are its held statistics (n_h, p_i); ``held_authors`` (N, P_MAX), ``n_held_authors`` and
    ``mean_held_index_authors`` (N,) the same for the authors' narrower held set (the second outcome
    definition). ``task_rules`` (``dlo_interface.task.TASK_RULES``) says which of the two the task's reward,
    termination and the tactile input use: ``held_task`` is that mask. ``move_spacing``: the move reward's particle
    spacing [m] (``dlo_interface.task``; 0, the default: the cable's own).
    """

    def __init__(
        self,
        num_envs: int,
        horizon: int = HORIZON,
        end_particles: int = END_PARTICLES,
        render: bool = False,
        task_rules: str = DEFAULT_TASK_RULES,
        move_spacing: float = DEFAULT_MOVE_SPACING,
        **sim_options,
    ):
        self.rules = task_rules_record(task_rules)
        self.sim = RopeSim(num_envs, **sim_options)
        self.tracker = EpisodeTracker(
            self.sim.num_envs, horizon=horizon, end_particles=end_particles, task_rules=task_rules, move_spacing=move_spacing
        )
        self.task_rules = task_rules
        self.render = bool(render)
        self.state: Snapshot | None = None
        self.n_held = self.mean_held_index = None
        self.held_authors = self.n_held_authors = self.mean_held_index_authors = None

    @property
    def num_envs(self) -> int:
        return self.sim.num_envs

    @property
    def held(self) -> np.ndarray:
        """(N, P_MAX) bool held-particle mask of the current state."""
        return self.state.held

    @property
    def held_task(self) -> np.ndarray:
        """(N, P_MAX) bool: the held set the task rules use (reward, termination, tactile input)."""
        return self.rules.select(self.state.held, self.held_authors)

    def reset(self, seeds, env_ids=None) -> None:
        """Start new episodes from ``seeds`` in ``env_ids`` (all if None)."""
        ids = np.arange(self.num_envs) if env_ids is None else np.asarray(env_ids)
        self.sim.reset(seeds, ids)
        self.state = self.sim.snapshot(self.render)
        self._held_statistics()
        self.tracker.reset(
            ids,
            self.mean_held_index[ids],
            self.max_held_index[ids],
            self.sim.num_particles[ids],
            self.mean_held_index_authors[ids],
        )

    def step(self, actions):
        """One control step (8 x 0.01 s) of every environment -> (reward, terminated, truncated, unstable), (N,) each.

        An environment the simulator had to reset (NaN or explosion, ``unstable``) ends its episode
        as truncated."""
        self.state = self.sim.step_snapshot(actions, self.render)
        self._held_statistics()
        reward, terminated, truncated = self.tracker.step(
            self.mean_held_index,
            self.n_held,
            self.max_held_index,
            self.sim.num_particles,
            self.sim.cable_length,
            self.mean_held_index_authors,
            self.n_held_authors,
        )
        unstable = self.sim.unstable()
        return reward, terminated, truncated | (unstable & ~terminated), unstable

    def _held_statistics(self) -> None:
        """Held statistics of the current snapshot under both held rules."""
        self.n_held, self.mean_held_index, self.max_held_index = held_statistics(self.state.held)
        self.held_authors = held_mask_authors(self.state.positions, self.sim.num_particles, self.state.gripper)
        self.n_held_authors, self.mean_held_index_authors, _ = held_statistics(self.held_authors)
