"""dlo_policy.sac: the SAC agent learns a reach task; exactly, against references computed here: the
policy's squashed log-std, its reparameterised sample and log-probability, exploration, the TD target,
the critic/actor/temperature losses of one update from replayed random draws (the actor's with the min
of the twin critics), gradients that do not accumulate, the update schedule, target tracking and
entropy tuning; the training loop's counters, seeds and callback, with horizon cut-offs stored as not
terminal (unless sac.cutoff_as_terminal); observation scaling, persistence (checkpoints, policy files,
old and other-device checkpoints) and devices."""

import math
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from dlo_policy.config import SACConfig
from dlo_policy.evaluate import evaluate_agent
from dlo_policy.sac import SAC, CheckpointError, frozen

sys.path.insert(0, str(Path(__file__).resolve().parent))  # --import-mode=importlib: helper modules
from sac_reach_env import ReachEnv, make_vec_env  # noqa: E402

SMALL = dict(hidden_sizes=(64, 64), batch_size=64, learning_starts=200, buffer_size=5000)
TINY = dict(hidden_sizes=(16, 16), batch_size=8, learning_starts=0, buffer_size=200, observation_scaling="none")


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


def agent_with(n=40, seed=3, **overrides) -> SAC:
    agent = SAC(9, -np.ones(3), np.ones(3), SACConfig(**{**TINY, **overrides}), seed=seed)
    rng = np.random.default_rng(0)
    for i in range(n):
        agent.store(rng.normal(size=9), rng.uniform(-1, 1, 3), rng.normal(), rng.normal(size=9), i % 7 == 6)
    return agent


def copy_of(generator: torch.Generator) -> torch.Generator:
    clone = torch.Generator().manual_seed(0)
    clone.set_state(generator.get_state())
    return clone


def constant_heads(critic, q1, q2):
    """Both heads of ``critic`` output the constants q1 and q2, whatever the input."""
    with torch.no_grad():
        for head, value in ((critic.q1[-1], q1), (critic.q2[-1], q2)):
            head.weight.zero_()
            head.bias.fill_(value)


def constant_critics(agent: SAC, q1: float, q2: float) -> None:
    """Both online critics output constants (whatever the input) and stay so (learning rate 0)."""
    constant_heads(agent.critic, q1, q2)
    for group in agent.critic_optimizer.param_groups:
        group["lr"] = 0.0


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
    entropy_bonus = agent.td_target(rewards, torch.zeros(3, 9), terminated, torch.tensor(1.0)) - agent.td_target(
        rewards, torch.zeros(3, 9), terminated, tiny_alpha
    )
    assert entropy_bonus[1] == 0 and entropy_bonus[0] != 0  # -gamma * alpha * log pi, only when bootstrapping


def test_actor_log_prob_is_the_tanh_gaussian_density():
    agent = filled_agent(n=0)
    obs = torch.randn(64, 9)
    actions, log_prob = agent.actor.sample(obs, torch.Generator().manual_seed(3))
    mean, log_std = agent.actor(obs)
    squashed = torch.distributions.TransformedDistribution(
        torch.distributions.Normal(mean, log_std.exp()), torch.distributions.TanhTransform(cache_size=1)
    )
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


def test_frozen_scaling_keeps_the_statistics_of_the_random_action_phase():
    agent = SAC(
        2, -np.ones(1), np.ones(1), SACConfig(**{**SMALL, "observation_scaling": "frozen", "learning_starts": 100}), seed=0
    )
    rng = np.random.default_rng(2)
    for step in range(300):  # store() is called before the step counter moves, as in learn()
        agent.store(rng.normal(1.0 if step < 100 else 50.0, 1.0, 2), np.zeros(1), 0.0, np.zeros(2), False)
        agent.num_env_steps += 1
    assert agent.normalizer.count == 100 and agent.normalizer.frozen
    np.testing.assert_allclose(agent.normalizer.mean.numpy(), [1.0, 1.0], atol=0.3)


def test_bounds_scaling_maps_the_observation_box_onto_minus_one_one_and_survives_save_load(tmp_path):
    low, high = np.array([-0.3, 0.0, -0.002]), np.array([0.3, 1.0, 0.002])
    agent = SAC(
        3,
        -np.ones(1),
        np.ones(1),
        SACConfig(**{**SMALL, "observation_scaling": "bounds"}),
        seed=0,
        observation_low=low,
        observation_high=high,
    )
    corners = torch.tensor(np.stack([low, high, (low + high) / 2]), dtype=torch.float32)
    np.testing.assert_allclose(agent.normalizer(corners).numpy(), [[-1, -1, -1], [1, 1, 1], [0, 0, 0]], atol=1e-6)
    agent.store(np.array([5.0, 5.0, 5.0]), np.zeros(1), 0.0, np.zeros(3), False)  # never moves the map
    np.testing.assert_allclose(agent.normalizer(corners).numpy()[1], [1, 1, 1], atol=1e-6)
    agent.save_policy(tmp_path / "policy.pt")
    loaded = SAC.load(tmp_path / "policy.pt")
    assert loaded.config.observation_scaling == "bounds"
    np.testing.assert_allclose(loaded.normalizer(corners).numpy(), agent.normalizer(corners).numpy())


def test_a_checkpoint_whose_config_has_an_unknown_key_is_refused_in_one_line(tmp_path):
    """A SAC config key the agent does not have (normalize_observations, the name observation_scaling had
    before it was released) is refused with the file and the key, not a TypeError."""
    agent = filled_agent(observation_scaling="running")
    state = agent.state_dict(include_replay=False)
    config = dict(state["config"])
    del config["observation_scaling"]
    config["normalize_observations"] = True
    state["config"] = config
    path = tmp_path / "old.pt"
    torch.save(state, path)
    with pytest.raises(CheckpointError) as raised:
        SAC.load(path)
    assert str(raised.value) == f"not a dlo-vitac policy file: {path} (unknown SAC config key(s) normalize_observations)"


def test_diagnostics_leave_the_training_stream_untouched():
    probed, plain = filled_agent(), filled_agent()
    for step in range(3):
        health = probed.diagnostics(batch_size=256, seed=step)
        assert probed.update() == plain.update()
    assert set(health) == {"alpha", "entropy", "q_value", "saturated"} and 0 <= health["saturated"] <= 1
    assert health["alpha"] == pytest.approx(probed.alpha) and np.isfinite(health["entropy"])
    for p, q in zip(probed.actor.parameters(), plain.actor.parameters()):
        assert torch.equal(p, q)


def test_log_std_is_squashed_into_its_range():
    agent = agent_with(n=0, log_std_min=-6.0, log_std_max=1.0)
    obs = torch.zeros(3, 9)
    head = agent.actor.net[-1]
    with torch.no_grad():
        head.weight.zero_()
        head.bias[3:] = torch.tensor([50.0, 0.0, -50.0])  # raw log-std: far above, midpoint, far below
    mean, log_std = agent.actor(obs)
    assert log_std[0].tolist() == pytest.approx([1.0, -2.5, -6.0])
    single_mean, single_log_std = agent.actor(obs[0])  # one observation, no batch dimension
    assert single_mean.shape == (3,) and single_log_std.tolist() == pytest.approx([1.0, -2.5, -6.0])
    assert agent.predict(np.zeros(9)).shape == (3,)


def test_sample_and_log_prob_against_a_reference():
    agent = agent_with(n=0)
    obs = torch.randn(6, 9, generator=torch.Generator().manual_seed(1))
    generator = torch.Generator().manual_seed(5)
    reference = copy_of(generator)
    global_state = torch.get_rng_state()
    actions, log_prob = agent.actor.sample(obs, generator)
    assert torch.equal(torch.get_rng_state(), global_state)  # only the given generator is drawn from
    with torch.no_grad():
        mean, log_std = agent.actor(obs)
    eps = torch.randn(mean.shape, generator=reference)
    pre = (mean + log_std.exp() * eps).double()
    expected_actions = torch.tanh(pre)
    gaussian = (-0.5 * eps.double() ** 2 - log_std.double() - 0.5 * math.log(2 * math.pi)).sum(-1)
    expected_log_prob = gaussian - torch.log(1 - torch.tanh(pre) ** 2).sum(-1)
    torch.testing.assert_close(actions.double(), expected_actions, rtol=0, atol=1e-6)
    torch.testing.assert_close(log_prob.double(), expected_log_prob, rtol=0, atol=1e-4)
    torch.testing.assert_close(agent.actor.deterministic(obs), torch.tanh(mean))


def test_exploration_is_uniform_from_the_agent_generator_until_learning_starts():
    agent = agent_with(n=0, learning_starts=5)
    obs = np.linspace(-1, 1, 9)
    agent.num_env_steps = 4
    reference = copy_of(agent.generator)
    action = agent.explore(obs)
    np.testing.assert_array_equal(action, (torch.rand(3, generator=reference) * 2 - 1).numpy())
    agent.num_env_steps = 5  # from learning_starts on: a sample of the policy (not its mean)
    reference = copy_of(agent.generator)
    action = agent.explore(obs)
    expected, _ = agent.actor.sample(torch.as_tensor(obs, dtype=torch.float32), reference)
    np.testing.assert_allclose(action, expected.detach().numpy(), atol=1e-6)
    assert not np.allclose(action, agent.actor.deterministic(torch.as_tensor(obs, dtype=torch.float32)).detach().numpy())


def test_one_update_exactly():
    agent = agent_with(
        policy_update_every=1, target_update_every=1000, reward_scale=50.0, gamma=0.9, initial_alpha=0.3, target_entropy=-2.0
    )
    constant_heads(agent.critic, 1.5, -0.5)
    constant_heads(agent.critic_target, 4.0, 2.0)
    for group in agent.critic_optimizer.param_groups:
        group["lr"] = 0.0  # the critics stay constant through the update
    generator = copy_of(agent.generator)
    batch = agent.replay.sample(agent.config.batch_size, generator)
    with torch.no_grad():
        _, next_log_pi = agent.actor.sample(batch.next_obs, generator)
        _, log_pi = agent.actor.sample(batch.obs, generator)
    alpha = 0.3
    target = 50.0 * batch.rewards + 0.9 * (1 - batch.terminated) * (2.0 - alpha * next_log_pi)
    losses = agent.update()
    expected_critic = ((1.5 - target) ** 2).mean() + ((-0.5 - target) ** 2).mean()
    assert losses["critic_loss"] == pytest.approx(expected_critic.item(), rel=1e-5)
    assert losses["actor_loss"] == pytest.approx((alpha * log_pi - (-0.5)).mean().item(), abs=1e-5)
    assert losses["alpha_loss"] == pytest.approx(-(alpha * (log_pi - 2.0)).mean().item(), abs=1e-5)
    assert agent.num_updates == 1 and agent.alpha != pytest.approx(0.3, abs=1e-9)  # the temperature moved
    assert batch.terminated.sum() > 0  # the batch had terminal transitions (no bootstrap there)


@pytest.mark.parametrize("q1, q2", [(3.0, 7.0), (7.0, -2.0)])
def test_actor_loss_is_alpha_log_pi_minus_the_smaller_critic(q1, q2):
    agent = SAC(
        9, -np.ones(3), np.ones(3), SACConfig(**TINY, autotune_alpha=False, initial_alpha=0.5, policy_update_every=1), seed=3
    )
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


def test_update_schedule_and_that_every_network_learns():
    agent = agent_with(policy_update_every=2, target_update_every=3)
    before = {
        name: [p.clone() for p in net.parameters()]
        for name, net in (("actor", agent.actor), ("critic", agent.critic), ("target", agent.critic_target))
    }
    alpha = agent.alpha
    keys = [sorted(agent.update()) for _ in range(3)]
    assert keys == [["critic_loss"], ["actor_loss", "alpha_loss", "critic_loss"], ["critic_loss"]]
    assert agent.num_updates == 3 and agent.alpha != alpha
    for name, net in (("actor", agent.actor), ("critic", agent.critic), ("target", agent.critic_target)):
        assert any(not torch.equal(a, b) for a, b in zip(before[name], net.parameters())), name
    fixed = agent_with(policy_update_every=1, autotune_alpha=False)
    assert "alpha_loss" not in fixed.update()


def test_gradients_do_not_accumulate_across_updates():
    """Each update's gradients are its own losses' (learning rates 0: nothing moves, so a second
    update can be replayed exactly and its gradients computed here)."""
    agent = agent_with(policy_update_every=1, target_update_every=1000, initial_alpha=0.2)
    constant_heads(agent.critic_target, 1.0, 2.0)
    for optimizer in (agent.critic_optimizer, agent.actor_optimizer, agent.alpha_optimizer):
        for group in optimizer.param_groups:
            group["lr"] = 0.0
    agent.update()
    generator = copy_of(agent.generator)
    batch = agent.replay.sample(agent.config.batch_size, generator)
    alpha = agent.log_alpha.detach().exp()
    with torch.no_grad():
        next_actions, next_log_pi = agent.actor.sample(batch.next_obs, generator)
        target = agent.config.reward_scale * batch.rewards + agent.config.gamma * (1 - batch.terminated) * (
            torch.min(*agent.critic_target(batch.next_obs, next_actions)) - alpha * next_log_pi
        )
    q1, q2 = agent.critic(batch.obs, batch.actions)
    critic_grads = torch.autograd.grad(((q1 - target) ** 2).mean() + ((q2 - target) ** 2).mean(), list(agent.critic.parameters()))
    actions, log_pi = agent.actor.sample(batch.obs, generator)
    q = torch.min(*agent.critic(batch.obs, actions))
    actor_grads = torch.autograd.grad((alpha * log_pi - q).mean(), list(agent.actor.parameters()))
    alpha_grad = torch.autograd.grad(
        -(agent.log_alpha.exp() * (log_pi.detach() + agent.target_entropy)).mean(), [agent.log_alpha]
    )[0]
    agent.update()
    for expected, p in zip(critic_grads, agent.critic.parameters()):
        torch.testing.assert_close(p.grad, expected, rtol=1e-4, atol=1e-6)
    for expected, p in zip(actor_grads, agent.actor.parameters()):
        torch.testing.assert_close(p.grad, expected, rtol=1e-4, atol=1e-6)
    torch.testing.assert_close(agent.log_alpha.grad, alpha_grad, rtol=1e-4, atol=1e-7)


class CountingEnv(gym.Env):
    observation_space = gym.spaces.Box(-1e6, 1e6, (9,), np.float32)
    action_space = gym.spaces.Box(-1.0, 1.0, (3,), np.float32)

    def __init__(self):
        self.seeds, self.t = [], 0

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.seeds.append(seed)
        self.t = 0
        return np.zeros(9, np.float32), {}

    def step(self, action):
        self.t += 1
        return np.full(9, float(self.t), np.float32), 0.5, False, self.t >= 4, {}


def test_learn_counts_steps_updates_episodes_and_seeds_each_episode():
    agent = SAC(9, -np.ones(3), np.ones(3), SACConfig(**{**TINY, "learning_starts": 3}), seed=2)
    env = CountingEnv()
    agent.learn(env, total_steps=10)
    assert (agent.num_env_steps, agent.num_updates, agent.num_episodes, len(agent.replay)) == (10, 7, 2, 10)
    assert env.seeds == [agent.episode_seed(k) for k in range(3)]
    assert agent.replay.rewards[:10].tolist() == [0.5] * 10


def test_learn_stops_when_the_callback_says_so():
    agent = SAC(9, -np.ones(3), np.ones(3), SACConfig(**{**TINY, "learning_starts": 100}), seed=2)
    seen = []

    def callback(learner, result):
        seen.append((result.reward, result.terminated, result.truncated))
        return False if learner.num_env_steps == 6 else None

    agent.learn(CountingEnv(), total_steps=50, callback=callback)
    assert agent.num_env_steps == 6 and len(seen) == 6 and seen[3] == (0.5, False, True)


def test_learn_notes_the_env_modalities_and_refuses_other_ones():
    class ModalEnv(CountingEnv):
        modalities = ("K", "T")

    agent = SAC(9, -np.ones(3), np.ones(3), SACConfig(**{**TINY, "learning_starts": 100}), seed=2)
    assert agent.modalities is None
    agent.learn(ModalEnv(), total_steps=2)
    assert agent.modalities == ("K", "T")  # saved with its checkpoints
    other = SAC(9, -np.ones(3), np.ones(3), SACConfig(**{**TINY, "learning_starts": 100}), seed=2, modalities=("V",))
    env = ModalEnv()
    with pytest.raises(ValueError, match="observes V"):
        other.learn(env, total_steps=2)
    assert env.seeds == [] and other.num_env_steps == 0  # refused before the first reset


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


def _stored_done_flags(cutoff_as_terminal: bool):
    """(terminated, truncated) of every step of a 400-step random-action run on the reach task (horizon
    20: most episodes are cut off, some leave the interval) and the done flag each was stored with."""
    agent = SAC(
        9,
        -np.ones(1),
        np.ones(1),
        SACConfig(**{**SMALL, "learning_starts": 10_000, "cutoff_as_terminal": cutoff_as_terminal}),
        seed=3,
    )
    ends = []
    agent.learn(
        ReachEnv("All"), total_steps=400, callback=lambda _agent, result: ends.append((result.terminated, result.truncated))
    )
    stored = agent.replay.terminated[: agent.replay.size].cpu().numpy()
    return np.array(ends, dtype=bool).reshape(-1, 2), stored


def test_cutoff_as_terminal_stores_horizon_cutoffs_as_terminal_only_when_switched_on():
    """docs/FIDELITY.md row 7: with sac.cutoff_as_terminal a cut-off transition (truncated, not
    terminated) is stored with done = 1 (no bootstrap); without it, done = 0. Terminated transitions are
    done = 1 and every other one done = 0 either way."""
    for switched_on in (False, True):
        ends, stored = _stored_done_flags(switched_on)
        terminated, truncated = ends[:, 0], ends[:, 1]
        cut_off = truncated & ~terminated
        assert len(stored) == len(ends) == 400 and cut_off.sum() >= 5 and terminated.sum() >= 1
        assert np.all(stored[terminated] == 1.0)
        assert np.all(stored[cut_off] == (1.0 if switched_on else 0.0)), switched_on
        assert np.all(stored[~terminated & ~truncated] == 0.0)
    assert SACConfig().cutoff_as_terminal is False  # off by default


def test_stored_terminal_is_the_one_rule_the_online_learner_uses_too(tmp_path):
    from dlo_policy.config import RunConfig
    from dlo_policy.online import OnlineLearner

    on = SAC(9, -np.ones(3), np.ones(3), SACConfig(**{**SMALL, "cutoff_as_terminal": True}), seed=0)
    off = SAC(9, -np.ones(3), np.ones(3), SACConfig(**SMALL), seed=0)
    cases = [(False, False), (True, False), (False, True), (True, True)]  # (terminated, truncated)
    assert [on.stored_terminal(*c) for c in cases] == [False, True, True, True]
    assert [off.stored_terminal(*c) for c in cases] == [False, True, False, True]
    for cutoff, expected in ((False, 0.0), (True, 1.0)):
        config = RunConfig(sac=SACConfig(**{**SMALL, "cutoff_as_terminal": cutoff}))
        learner = OnlineLearner(config, 9, tmp_path / str(cutoff))
        learner.act(np.zeros(9), 0.0, False, False, episode=0, step=0)
        learner.act(np.ones(9), 1.0, True, False, episode=0, step=1)  # the horizon cut the episode
        learner.act(np.zeros(9), 0.0, False, False, episode=1, step=0)
        learner.act(np.ones(9), -0.5, True, True, episode=1, step=1)  # dropped: terminal either way
        assert learner.agent.replay.size == 2
        assert learner.agent.replay.terminated[:2].tolist() == [expected, 1.0], cutoff


@pytest.mark.parametrize("value", ["maybe", "1", "[true]"])
def test_a_bad_cutoff_as_terminal_value_is_a_one_line_config_error(value, tmp_path, capsys):
    from dlo_policy import train
    from dlo_policy.config import ConfigError, load_config

    with pytest.raises(ConfigError, match="sac.cutoff_as_terminal: expected true or false"):
        load_config(None, [f"sac.cutoff_as_terminal={value}"])
    assert load_config(None, ["sac.cutoff_as_terminal=true"]).sac.cutoff_as_terminal is True
    assert (
        train.main(
            ["--out", str(tmp_path / "run"), "--no-progress", "env_module=sac_reach_env", f"sac.cutoff_as_terminal={value}"]
        )
        == 2
    )
    err = capsys.readouterr().err.strip()
    assert "sac.cutoff_as_terminal: expected true or false" in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / "run").exists()
