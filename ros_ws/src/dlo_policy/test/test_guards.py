"""Guards found by mutation testing (issue 14): each test fails when one known, realistic bug is put
back into the library (tools/mutation_check.sh; docs/MUTATION.md names the bug each one catches).

- the actor loss uses the MIN of the twin critics and alpha * log pi, exactly;
- a horizon cut-off (truncated) is never stored as terminal, in dlo-train's loop and online learning;
- ``dlo-evaluate --without X`` blanks X's columns, and only those, before the agent sees them;
- the observation ablation zeroes exactly the ablated block and never reads its input.
"""
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch

from dlo_perception.tactile import TactilePose
from dlo_perception.vision import VisualPose
from dlo_policy import evaluate
from dlo_policy.config import RunConfig, SACConfig
from dlo_policy.observation import build_observation, observation_bounds, parse_modalities
from dlo_policy.online import OnlineLearner
from dlo_policy.sac import SAC

sys.path.insert(0, str(Path(__file__).resolve().parent))  # --import-mode=importlib: helper modules
import sac_reach_env  # noqa: E402

TINY = dict(hidden_sizes=(16, 16), batch_size=8, learning_starts=0, buffer_size=200, observation_scaling="none")


@pytest.fixture(autouse=True)
def one_thread():
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)


def constant_critics(agent: SAC, q1: float, q2: float) -> None:
    """Both online critics output constants (whatever the input) and stay so (learning rate 0)."""
    with torch.no_grad():
        for head, value in ((agent.critic.q1[-1], q1), (agent.critic.q2[-1], q2)):
            head.weight.zero_()
            head.bias.fill_(value)
    for group in agent.critic_optimizer.param_groups:
        group["lr"] = 0.0


@pytest.mark.parametrize("q1, q2", [(3.0, 7.0), (7.0, -2.0)])
def test_actor_loss_is_alpha_log_pi_minus_the_smaller_critic(q1, q2):
    agent = SAC(9, -np.ones(3), np.ones(3), SACConfig(**TINY, autotune_alpha=False, initial_alpha=0.5,
                                                      policy_update_every=1), seed=3)
    rng = np.random.default_rng(0)
    for _ in range(40):
        agent.store(rng.normal(size=9), rng.uniform(-1, 1, 3), rng.normal(), rng.normal(size=9), False)
    constant_critics(agent, q1, q2)
    # Replay the update's random draws on a copy of the agent's generator: batch, a' ~ pi(s'), a~ ~ pi(s).
    generator = torch.Generator().manual_seed(0)
    generator.set_state(agent.generator.get_state())
    batch = agent.replay.sample(agent.config.batch_size, generator)
    with torch.no_grad():
        agent.actor.sample(batch.next_obs, generator)
        _, log_pi = agent.actor.sample(batch.obs, generator)
    losses = agent.update()
    expected = (0.5 * log_pi - min(q1, q2)).mean().item()
    assert losses["actor_loss"] == pytest.approx(expected, abs=1e-5)


class ScriptedEnv(gym.Env):
    """Episodes of 3 steps cut by the horizon (truncated); the 7th step of the run ends one in a
    terminal state instead. Observations count the steps, so stored transitions can be checked."""

    observation_space = gym.spaces.Box(-1e6, 1e6, (9,), np.float32)
    action_space = gym.spaces.Box(-1.0, 1.0, (3,), np.float32)

    def __init__(self):
        self.total, self.t = 0, 0

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.t = 0
        return np.full(9, -1.0, np.float32), {}

    def step(self, action):
        self.total += 1
        self.t += 1
        terminated = self.total == 7
        truncated = not terminated and self.t >= 3
        return np.full(9, float(self.total), np.float32), 1.0, terminated, truncated, {}


def test_training_stores_horizon_cut_offs_as_not_terminal():
    agent = SAC(9, -np.ones(3), np.ones(3), SACConfig(**{**TINY, "learning_starts": 1000}), seed=0)
    agent.learn(ScriptedEnv(), total_steps=10)
    # steps 1-3 (truncated at 3), 4-6 (truncated at 6), 7 (terminal), 8-10
    assert agent.replay.terminated[:10].tolist() == [0, 0, 0, 0, 0, 0, 1, 0, 0, 0]
    assert agent.replay.next_obs[:10, 0].tolist() == list(range(1, 11))  # the true next state, not the reset
    assert agent.num_episodes == 4  # ended at steps 3, 6, 7 and 10


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


class RecordingAgent:
    """Stands in for a trained SAC: acts 0 and records every observation it is shown."""

    num_env_steps = 0

    def __init__(self):
        self.seen = []

    def predict(self, obs, deterministic=True):
        self.seen.append(np.array(obs, copy=True))
        return np.zeros((len(obs), 1), np.float32)


@pytest.mark.parametrize("without, blank", [([], []), (["T"], [3, 4]), (["V"], [5, 6, 7, 8]),
                                            (["K", "V"], [0, 1, 2, 5, 6, 7, 8])])
def test_dlo_evaluate_without_blanks_exactly_that_modality(monkeypatch, tmp_path, capsys, without, blank):
    agent = RecordingAgent()
    monkeypatch.setattr(evaluate, "SAC", type("StubSAC", (), {"load": staticmethod(lambda path: agent)}))
    monkeypatch.setattr(evaluate, "load_run_config",
                        lambda path: RunConfig(modalities="All", env_module="sac_reach_env"))
    argv = ["--checkpoint", str(tmp_path / "policy.pt"), "--episodes", "4", "--num-envs", "2", "--threads", "1"]
    for modality in without:
        argv += ["--without", modality]
    assert evaluate.main(argv) == 0
    seen = np.concatenate(agent.seen)
    assert len(seen) == 4 * sac_reach_env.HORIZON  # 2 batches of 2 envs, acting 0: never leaves, runs to the horizon
    kept = [c for c in range(9) if c not in blank]
    assert np.all(seen[:, blank] == 0.0)
    # what the reach env shows in the kept columns: K = (x, target, 0), T = (error, 0), V = (error, 1, 0, 0)
    informative = {1: "target", 3: "error", 5: "error", 6: "one"}
    for column in kept:
        if column in informative:
            assert np.any(seen[:, column] != 0.0), (column, informative[column])
    if 6 in kept:
        assert np.all(seen[:, 6] == 1.0)
    printed = capsys.readouterr().out
    assert ("without " + "+".join(without) in printed) == bool(without), printed


def test_evaluate_agent_blanks_only_the_given_columns():
    agent = RecordingAgent()
    vec_env = sac_reach_env.make_vec_env(3, "All")
    result = evaluate.evaluate_agent(agent, vec_env, first_seed=0, episodes=3, blank=[5, 6])
    seen = np.concatenate(agent.seen)
    assert np.all(seen[:, [5, 6]] == 0.0) and np.any(seen[:, 3] != 0.0) and np.any(seen[:, 1] != 0.0)
    assert result.episodes == 3 and result.stop_before + result.hold_the_end == pytest.approx(1.0)


class Unreadable:
    """An input that must not be read (its modality is ablated)."""

    def __getattr__(self, name):
        raise AssertionError(f"the ablated input was read ({name})")


@pytest.mark.parametrize("without, zero", [(("K",), [0, 1, 2]), (("T",), [3, 4]), (("V",), [5, 6, 7, 8]),
                                           (("T", "V"), [3, 4, 5, 6, 7, 8]), ("V+K", [0, 1, 2, 5, 6, 7, 8])])
def test_ablation_zeroes_exactly_the_ablated_block_and_never_reads_it(without, zero):
    kinematic = np.array([[0.1, -0.2, 0.7], [0.05, 0.02, 0.9]])
    tactile = TactilePose(np.array([0.3, -0.1]), np.array([0.004, -0.002]), np.array([True, True]), np.array([3, 4]))
    visual = VisualPose(np.array([True, False]), np.array([0.5, 0.0]), np.array([-0.2, 0.0]), np.array([0.01, 0.0]))
    full = build_observation("All", kinematic, tactile, visual)
    inputs = {"K": kinematic, "T": tactile, "V": visual}
    for name in parse_modalities(without):
        inputs[name] = Unreadable()
    ablated = build_observation("All", inputs["K"], inputs["T"], inputs["V"], without=without)
    assert ablated.shape == (2, 9) and ablated.dtype == np.float32
    keep = [c for c in range(9) if c not in zero]
    assert np.all(ablated[:, zero] == 0.0)
    np.testing.assert_array_equal(ablated[:, keep], full[:, keep])


def test_observation_layout_and_bounds():
    kinematic = np.array([[0.1, -0.2, 0.7]])
    tactile = TactilePose(np.array([0.3]), np.array([0.004]), np.array([True]), np.array([3]))
    visual = VisualPose(np.array([True]), np.array([0.5]), np.array([-0.2]), np.array([0.01]))
    assert build_observation("V+K", kinematic, tactile, visual)[0] == pytest.approx([0.1, -0.2, 0.7, 1.0, 0.5, -0.2, 0.01])
    assert build_observation("T", kinematic, tactile, visual)[0] == pytest.approx([0.3, 0.004])
    assert build_observation(("T", "V"), None, tactile, visual)[0] == pytest.approx([0.3, 0.004, 1.0, 0.5, -0.2, 0.01])
    # everything ablated: a zero row of the full width
    assert build_observation("T+K", without="T+K").tolist() == [[0.0] * 5]
    assert parse_modalities("all") == ("K", "T", "V") and parse_modalities(" v + k ") == ("K", "V")
    for bad in ("", "X", "K+X"):
        with pytest.raises(ValueError):
            parse_modalities(bad)
    with pytest.raises(ValueError):
        build_observation("K+T", kinematic, tactile, without=("V",))
    low, high = observation_bounds("All")
    np.testing.assert_allclose(low, [-0.3, -0.3, 0.0, -np.pi / 2, -0.03, 0.0, 0.0, -np.pi / 2, -0.03], rtol=1e-6)
    np.testing.assert_allclose(high, [0.3, 0.3, 1.0, np.pi / 2, 0.03, 1.0, 1.0, np.pi / 2, 0.03], rtol=1e-6)
    assert observation_bounds("T")[0].dtype == np.float32


def test_batched_observation_rows_keep_their_own_values():
    kinematic = np.array([[0.1, -0.2, 0.7], [0.05, 0.02, 0.9]])
    tactile = TactilePose(np.array([0.3, -0.1]), np.array([0.004, -0.002]), np.array([True, True]), np.array([3, 4]))
    visual = VisualPose(np.array([True, False]), np.array([0.5, 0.0]), np.array([-0.2, 0.0]), np.array([0.01, 0.0]))
    observation = build_observation("All", kinematic, tactile, visual)
    np.testing.assert_allclose(observation, [[0.1, -0.2, 0.7, 0.3, 0.004, 1.0, 0.5, -0.2, 0.01],
                                             [0.05, 0.02, 0.9, -0.1, -0.002, 0.0, 0.0, 0.0, 0.0]], rtol=1e-6)


def test_replay_stores_every_field_and_samples_with_the_given_generator():
    from dlo_policy.replay import ReplayBuffer

    replay = ReplayBuffer(8, 2, 3)
    for i in range(5):
        replay.add([i, -i], [0.1 * i, 0.2, -0.3], float(i) / 2, [i + 1, -i - 1], i == 3)
    state = torch.get_rng_state()
    a = replay.sample(16, torch.Generator().manual_seed(4))
    b = replay.sample(16, torch.Generator().manual_seed(4))
    assert torch.equal(torch.get_rng_state(), state)  # the global torch stream is untouched
    assert torch.equal(a.obs, b.obs) and torch.equal(a.actions, b.actions)
    index = a.obs[:, 0].long()
    assert set(index.tolist()) <= set(range(5)) and len(set(index.tolist())) > 1
    torch.testing.assert_close(a.actions, torch.stack([torch.tensor([0.1 * i, 0.2, -0.3]) for i in index.tolist()]))
    torch.testing.assert_close(a.rewards, index.float() / 2)
    torch.testing.assert_close(a.next_obs[:, 0], index.float() + 1)
    assert a.terminated.tolist() == [float(i == 3) for i in index.tolist()]


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
