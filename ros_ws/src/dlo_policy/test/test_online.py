"""dlo_policy.online (the policy node's online training): a horizon cut-off is never stored as terminal,
only a drop is, and no transition links a skipped step or the end of an episode; updates start after
learning_starts, checkpoints are written every checkpoint_every transitions and a learner made on the
same directory continues the saved run."""

import numpy as np
import pytest
import torch
from dlo_policy.config import RunConfig, SACConfig
from dlo_policy.online import OnlineLearner

TINY = dict(hidden_sizes=(16, 16), batch_size=8, learning_starts=0, buffer_size=200, observation_scaling="none")


@pytest.fixture(autouse=True)
def one_thread():
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)


def test_online_learning_stores_horizon_cut_offs_as_not_terminal(tmp_path):
    config = RunConfig(sac=SACConfig(**{**TINY, "learning_starts": 1000}))
    learner = OnlineLearner(config, 9, tmp_path / "online", checkpoint_every=10_000)
    obs = lambda v: np.full(9, float(v), np.float32)  # noqa: E731
    # episode 0: steps 0..2, ended by the horizon (done, not dropped)
    for step, done in ((0, False), (1, False), (2, True)):
        learner.act(obs(step), reward=0.1, done=done, dropped=False, episode=0, step=step)
    # episode 1: step 0, a skipped step (no transition 0 -> 2), then dropped at step 3
    for step, done in ((0, False), (2, False), (3, True)):
        learner.act(obs(10 + step), reward=-0.5 if done else 0.1, done=done, dropped=done, episode=1, step=step)
    replay = learner.agent.replay
    assert len(replay) == 3  # (0,0)->(0,1), (0,1)->(0,2), (1,2)->(1,3)
    assert replay.terminated[:3].tolist() == [0.0, 0.0, 1.0]
    assert replay.obs[:3, 0].tolist() == [0.0, 1.0, 12.0]
    assert replay.next_obs[:3, 0].tolist() == [1.0, 2.0, 13.0]
    assert replay.rewards[:3].tolist() == pytest.approx([0.1, 0.1, -0.5])
    assert learner.agent.num_episodes == 2 and learner.agent.num_env_steps == 3


def test_online_learning_updates_after_learning_starts_and_checkpoints(tmp_path):
    config = RunConfig(sac=SACConfig(**{**TINY, "learning_starts": 1}))
    learner = OnlineLearner(config, 9, tmp_path / "online", checkpoint_every=2)
    obs = lambda v: np.full(9, float(v), np.float32)  # noqa: E731
    learner.act(obs(0), 0.0, False, False, episode=0, step=0)
    learner.act(obs(1), 0.1, False, False, episode=0, step=1)  # transition 1: learning_starts not passed yet
    assert learner.agent.num_updates == 0 and not (tmp_path / "online" / "checkpoint.pt").exists()
    learner.act(obs(2), 0.1, True, False, episode=0, step=2)  # transition 2: one update, a checkpoint
    assert learner.agent.num_updates == 1 and (tmp_path / "online" / "checkpoint.pt").exists()
    assert (tmp_path / "online" / "policy.pt").exists()
    learner.act(obs(3), 0.1, False, False, episode=0, step=3)  # nothing links across the episode's end
    assert len(learner.agent.replay) == 2
    resumed = OnlineLearner(config, 9, tmp_path / "online", checkpoint_every=2)  # continues the saved run
    assert resumed.agent.num_env_steps == 2 and len(resumed.agent.replay) == 2


def test_with_cutoff_as_terminal_only_the_last_step_of_an_episode_is_stored_terminal(tmp_path):
    """cutoff_as_terminal: the horizon cut-off is stored terminal as well, a step inside an episode never is."""
    config = RunConfig(sac=SACConfig(**{**TINY, "learning_starts": 1000, "cutoff_as_terminal": True}))
    learner = OnlineLearner(config, 9, tmp_path / "online", checkpoint_every=10_000)
    obs = lambda v: np.full(9, float(v), np.float32)  # noqa: E731
    for step, done in ((0, False), (1, False), (2, True)):  # episode 0: ended by the horizon
        learner.act(obs(step), reward=0.1, done=done, dropped=False, episode=0, step=step)
    for step, done in ((0, False), (1, False), (2, True)):  # episode 1: dropped at step 2
        learner.act(obs(10 + step), reward=0.1, done=done, dropped=done, episode=1, step=step)
    replay = learner.agent.replay
    assert len(replay) == 4
    assert replay.terminated[:4].tolist() == [0.0, 1.0, 0.0, 1.0]
