"""Online SAC learning from a stream of control steps (the ROS graph, or a real robot).

The in-process trainer drives the gym environment itself (``SAC.learn``); a node cannot: the
steps come to it. ``OnlineLearner.act`` takes one step's observation with the reward and ending
that the task reported for reaching it, stores the transition from the previous step, makes one
gradient update (as ``SAC.learn`` does per env step) and returns the next exploratory action.
Checkpoints have the same format as dlo-train's, so dlo-evaluate and the policy node read them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dlo_policy.config import RunConfig, check_modalities, save_config
from dlo_policy.rundir import CHECKPOINT_FILE, CONFIG_FILE, POLICY_FILE
from dlo_policy.sac import SAC


class OnlineLearner:
    """Learns while acting; one ``act`` call per control step, in step order."""

    def __init__(self, config: RunConfig, obs_dim: int, run_dir: str | Path, checkpoint_every: int = 1000):
        self.run_dir = Path(run_dir)
        self.run_dir.mkdir(parents=True, exist_ok=True)
        checkpoint = self.run_dir / CHECKPOINT_FILE
        if checkpoint.exists():
            self.agent = SAC.load(checkpoint)  # continue an earlier online run
        else:
            self.agent = SAC(
                obs_dim,
                -np.ones(3, np.float32),
                np.ones(3, np.float32),
                config.sac,
                seed=config.seed,
                modalities=check_modalities(config.modalities),
            )  # stored with its checkpoints
            save_config(config, self.run_dir / CONFIG_FILE)
        self.checkpoint_every = int(checkpoint_every)
        self.previous = None  # (episode, step, observation, action) awaiting its successor

    def act(self, observation, reward: float, done: bool, dropped: bool, episode: int, step: int) -> np.ndarray:
        """Observation (D,) of (episode, step) reached with ``reward`` -> action (3,) in [-1, 1]."""
        agent = self.agent
        if self.previous is not None and self.previous[:2] == (episode, step - 1):
            _, _, previous_obs, previous_action = self.previous
            agent.store(previous_obs, previous_action, reward, observation, agent.stored_terminal(dropped, done and not dropped))
            agent.num_env_steps += 1
            if agent.num_env_steps > agent.config.learning_starts:
                agent.update()
            if agent.num_env_steps % self.checkpoint_every == 0:
                self.save()
            agent.num_episodes += int(done)
        action = agent.explore(observation)
        self.previous = None if done else (episode, step, np.asarray(observation, np.float32), action)
        return action

    def save(self) -> None:
        """Full checkpoint (resumable) and the acting-only policy file."""
        self.agent.save(self.run_dir / CHECKPOINT_FILE)
        self.agent.save_policy(self.run_dir / POLICY_FILE)
