"""SAC agent: learning, target tracking, entropy tuning, persistence, replay buffer."""
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from dlo_policy.config import SACConfig
from dlo_policy.evaluate import evaluate_agent
from dlo_policy.replay import ReplayBuffer
from dlo_policy.sac import SAC, frozen

sys.path.insert(0, str(Path(__file__).resolve().parent))  # --import-mode=importlib: helper modules
from sac_reach_env import ReachEnv, make_vec_env  # noqa: E402

SMALL = dict(hidden_sizes=(64, 64), batch_size=64, learning_starts=200, buffer_size=5000)


@pytest.fixture(autouse=True)
def one_thread():
    previous = torch.get_num_threads()
    torch.set_num_threads(1)  # tiny networks: threading only adds overhead on a shared 2-core machine
    yield
    torch.set_num_threads(previous)


def filled_agent(n: int = 300, **overrides) -> SAC:
    agent = SAC(9, -np.ones(3), np.ones(3), SACConfig(**{**SMALL, **overrides}), seed=0)
    rng = np.random.default_rng(0)
    for _ in range(n):
        agent.store(rng.normal(size=9), rng.uniform(-1, 1, 3), rng.normal(), rng.normal(size=9), rng.random() < 0.1)
    agent.num_env_steps = n
    return agent


def test_sac_learns_reach_task():
    env = ReachEnv("K")
    agent = SAC(9 - 6, env.action_space.low, env.action_space.high, SACConfig(**SMALL), seed=1)
    random_policy = evaluate_agent(agent, make_vec_env(10, "K"), first_seed=100, episodes=10)
    agent.learn(env, total_steps=1000)
    assert agent.num_env_steps == 1000 and agent.num_updates == 800
    trained = evaluate_agent(agent, make_vec_env(10, "K"), first_seed=100, episodes=10)
    assert trained.hold_the_end >= 0.8, trained
    assert trained.episode_reward > -1.5 > random_policy.episode_reward


def test_td_target_bootstraps_from_the_smaller_target_critic_unless_terminal():
    agent = filled_agent(reward_scale=50.0, gamma=0.9)
    with torch.no_grad():  # target critics output the constants 3 and 7, whatever the input
        for head, value in ((agent.critic_target.q1[-1], 3.0), (agent.critic_target.q2[-1], 7.0)):
            head.weight.zero_()
            head.bias.fill_(value)
    rewards, terminated = torch.tensor([1.0, 1.0, -2.0]), torch.tensor([0.0, 1.0, 0.0])
    tiny_alpha = torch.tensor(1e-9)
    target = agent.td_target(rewards, torch.randn(3, 9), terminated, tiny_alpha)
    torch.testing.assert_close(target, torch.tensor([50 + 0.9 * 3, 50.0, -100 + 0.9 * 3]))
    entropy_bonus = agent.td_target(rewards, torch.zeros(3, 9), terminated, torch.tensor(1.0)) - \
        agent.td_target(rewards, torch.zeros(3, 9), terminated, tiny_alpha)
    assert entropy_bonus[1] == 0 and entropy_bonus[0] != 0  # -gamma * alpha * log pi, only when bootstrapping


def test_actor_log_prob_is_the_tanh_gaussian_density():
    agent = filled_agent(n=0)
    obs = torch.randn(64, 9)
    actions, log_prob = agent.actor.sample(obs, torch.Generator().manual_seed(3))
    mean, log_std = agent.actor(obs)
    squashed = torch.distributions.TransformedDistribution(
        torch.distributions.Normal(mean, log_std.exp()), torch.distributions.TanhTransform(cache_size=1))
    reference = squashed.log_prob(actions.clamp(-1 + 1e-6, 1 - 1e-6)).sum(-1)
    torch.testing.assert_close(log_prob, reference, rtol=1e-3, atol=1e-2)


def test_target_critics_track_by_polyak_averaging():
    agent = filled_agent(target_update_every=2, tau=0.05)
    before = [p.clone() for p in agent.critic_target.parameters()]
    agent.update()  # update 1: not a target step
    for old, new in zip(before, agent.critic_target.parameters()):
        assert torch.equal(old, new)
    agent.update()  # update 2: target <- (1 - tau) target + tau critic
    for old, target, online in zip(before, agent.critic_target.parameters(), agent.critic.parameters()):
        assert torch.allclose(target, 0.95 * old + 0.05 * online, atol=1e-6)
        assert not torch.equal(target, old)


@pytest.mark.parametrize("target_entropy, direction", [(10.0, +1), (-100.0, -1)])
def test_entropy_tuning_moves_alpha_toward_target(target_entropy, direction):
    agent = filled_agent(target_entropy=target_entropy, policy_update_every=1)
    alpha0 = agent.alpha
    for _ in range(20):
        agent.update()
    assert np.sign(agent.alpha - alpha0) == direction


def test_fixed_alpha_stays_fixed():
    agent = filled_agent(autotune_alpha=False, initial_alpha=0.2, policy_update_every=1)
    for _ in range(5):
        agent.update()
    assert agent.alpha == pytest.approx(0.2)


def test_actor_loss_computes_no_critic_weight_gradients():
    agent = filled_agent()
    obs = torch.randn(8, 9)
    actions = torch.zeros(8, 3, requires_grad=True)
    with frozen(agent.critic):
        q = torch.min(*agent.critic(obs, actions)).sum()
    q.backward()
    assert actions.grad is not None and actions.grad.abs().sum() > 0
    assert all(p.grad is None for p in agent.critic.parameters())
    assert all(p.requires_grad for p in agent.critic.parameters())


def test_save_load_gives_identical_actions_and_state(tmp_path):
    agent = filled_agent()
    for _ in range(3):
        agent.update()
    agent.save(tmp_path / "agent.pt")
    loaded = SAC.load(tmp_path / "agent.pt")
    obs = np.random.default_rng(5).normal(size=(16, 9)).astype(np.float32)
    np.testing.assert_array_equal(agent.predict(obs), loaded.predict(obs))
    # the RNG state travels too: the same stochastic actions and the same next update
    np.testing.assert_array_equal(agent.predict(obs, deterministic=False), loaded.predict(obs, deterministic=False))
    assert agent.update() == loaded.update()
    assert (loaded.num_env_steps, loaded.num_updates, len(loaded.replay)) == (300, 4, 300)


def test_policy_file_is_actor_only_and_acts_identically(tmp_path):
    agent = filled_agent(observation_scaling="running")
    agent.save(tmp_path / "full.pt")
    agent.save_policy(tmp_path / "policy.pt")
    policy = SAC.load(tmp_path / "policy.pt")
    obs = np.random.default_rng(6).normal(size=(4, 9)).astype(np.float32)
    np.testing.assert_array_equal(agent.predict(obs), policy.predict(obs))
    assert len(policy.replay) == 0
    assert (tmp_path / "policy.pt").stat().st_size < (tmp_path / "full.pt").stat().st_size / 2


def test_predict_maps_to_the_env_action_box():
    agent = SAC(2, np.array([-2.0]), np.array([4.0]), SACConfig(**SMALL), seed=0)
    actions = agent.predict(np.random.default_rng(0).normal(size=(64, 2)) * 100, deterministic=False)
    assert actions.shape == (64, 1) and actions.min() >= -2.0 and actions.max() <= 4.0


def test_observation_normalizer_tracks_mean_and_variance():
    agent = filled_agent(n=0, observation_scaling="running")
    data = np.random.default_rng(1).normal(3.0, 2.0, size=(500, 9))
    for row in data:
        agent.normalizer.update(row)
    np.testing.assert_allclose(agent.normalizer.mean.numpy(), data.mean(0), atol=1e-9)
    np.testing.assert_allclose(agent.normalizer.var.numpy(), data.var(0), atol=1e-9)


def test_replay_buffer_wraps_and_round_trips():
    buffer = ReplayBuffer(4, obs_dim=1, act_dim=1)
    for i in range(6):
        buffer.add(np.array([i]), np.array([0.5]), float(i), np.array([i + 1]), i == 5)
    assert len(buffer) == 4 and buffer.position == 2
    assert sorted(buffer.rewards.tolist()) == [2.0, 3.0, 4.0, 5.0]
    copy = ReplayBuffer(4, obs_dim=1, act_dim=1)
    copy.load_state_dict(buffer.state_dict())
    batch = copy.sample(32, torch.Generator().manual_seed(0))
    assert torch.equal(batch.next_obs.squeeze(1), batch.obs.squeeze(1) + 1)
    assert torch.equal(batch.terminated, (batch.rewards == 5).float())


def test_frozen_scaling_keeps_the_statistics_of_the_random_action_phase():
    agent = SAC(2, -np.ones(1), np.ones(1), SACConfig(**{**SMALL, "observation_scaling": "frozen",
                                                         "learning_starts": 100}), seed=0)
    rng = np.random.default_rng(2)
    for step in range(300):  # store() is called before the step counter moves, as in learn()
        agent.store(rng.normal(1.0 if step < 100 else 50.0, 1.0, 2), np.zeros(1), 0.0, np.zeros(2), False)
        agent.num_env_steps += 1
    assert agent.normalizer.count == 100 and agent.normalizer.frozen
    np.testing.assert_allclose(agent.normalizer.mean.numpy(), [1.0, 1.0], atol=0.3)


def test_bounds_scaling_maps_the_observation_box_onto_minus_one_one_and_survives_save_load(tmp_path):
    low, high = np.array([-0.3, 0.0, -0.002]), np.array([0.3, 1.0, 0.002])
    agent = SAC(3, -np.ones(1), np.ones(1), SACConfig(**{**SMALL, "observation_scaling": "bounds"}), seed=0,
                observation_low=low, observation_high=high)
    corners = torch.tensor(np.stack([low, high, (low + high) / 2]), dtype=torch.float32)
    np.testing.assert_allclose(agent.normalizer(corners).numpy(), [[-1, -1, -1], [1, 1, 1], [0, 0, 0]], atol=1e-6)
    agent.store(np.array([5.0, 5.0, 5.0]), np.zeros(1), 0.0, np.zeros(3), False)  # never moves the map
    np.testing.assert_allclose(agent.normalizer(corners).numpy()[1], [1, 1, 1], atol=1e-6)
    agent.save_policy(tmp_path / "policy.pt")
    loaded = SAC.load(tmp_path / "policy.pt")
    assert loaded.config.observation_scaling == "bounds"
    np.testing.assert_allclose(loaded.normalizer(corners).numpy(), agent.normalizer(corners).numpy())


def test_checkpoints_of_the_boolean_normalize_observations_era_still_load(tmp_path):
    agent = filled_agent(observation_scaling="running")
    state = agent.state_dict(include_replay=False)
    legacy = dict(state["config"])
    del legacy["observation_scaling"]
    legacy["normalize_observations"] = True
    state["config"] = legacy
    torch.save(state, tmp_path / "old.pt")
    loaded = SAC.load(tmp_path / "old.pt")
    assert loaded.config.observation_scaling == "running"
    obs = np.random.default_rng(3).normal(size=(4, 9)).astype(np.float32)
    np.testing.assert_array_equal(agent.predict(obs), loaded.predict(obs))


def test_diagnostics_leave_the_training_stream_untouched():
    probed, plain = filled_agent(), filled_agent()
    for step in range(3):
        health = probed.diagnostics(batch_size=256, seed=step)
        assert probed.update() == plain.update()
    assert set(health) == {"alpha", "entropy", "q_value", "saturated"} and 0 <= health["saturated"] <= 1
    assert health["alpha"] == pytest.approx(probed.alpha) and np.isfinite(health["entropy"])
    for p, q in zip(probed.actor.parameters(), plain.actor.parameters()):
        assert torch.equal(p, q)


def _tensors(value):
    if isinstance(value, torch.Tensor):
        yield value
    elif isinstance(value, dict):
        for v in value.values():
            yield from _tensors(v)
    elif isinstance(value, (list, tuple)):
        for v in value:
            yield from _tensors(v)


@pytest.mark.skipif(torch.cuda.is_available(), reason="a CUDA device is present")
def test_device_names_resolve_and_cuda_without_a_gpu_is_a_clear_error():
    from dlo_policy.sac import resolve_device
    assert resolve_device("auto") == torch.device("cpu") and resolve_device("cpu") == torch.device("cpu")
    with pytest.raises(ValueError, match="sees no CUDA device"):
        resolve_device("cuda")
    with pytest.raises(ValueError, match="expected auto, cpu or cuda"):
        resolve_device("tpu")


def test_checkpoints_hold_cpu_tensors_and_load_onto_a_named_device(tmp_path):
    agent = SAC(9, -np.ones(3), np.ones(3), SACConfig(**SMALL), seed=0, device="cpu")
    agent.save(tmp_path / "a.pt")
    state = torch.load(tmp_path / "a.pt", weights_only=True)
    assert all(t.device.type == "cpu" for t in _tensors(state)) and state["rng"]["agent_device"] == "cpu"
    loaded = SAC.load(tmp_path / "a.pt", device="auto")
    assert all(p.device == loaded.device for p in loaded.actor.parameters())
    assert loaded.replay.obs.device == loaded.device and loaded.generator.device == loaded.device


def test_a_checkpoint_from_another_device_gets_a_reproducible_fresh_generator(tmp_path):
    agent = filled_agent()
    agent.save(tmp_path / "a.pt")
    state = torch.load(tmp_path / "a.pt", weights_only=True)
    state["rng"]["agent"] = torch.zeros(16, dtype=torch.uint8)  # a CUDA (Philox) generator state
    state["rng"]["agent_device"] = "cuda"
    torch.save(state, tmp_path / "b.pt")
    first, second = SAC.load(tmp_path / "b.pt"), SAC.load(tmp_path / "b.pt")
    assert first.update() == second.update()
