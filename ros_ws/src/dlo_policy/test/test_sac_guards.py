"""SAC, exactly (issue 14, found by tools/mutation_check.sh): the policy's squashed log-std, its
reparameterised sample and log-probability against a reference computed here, exploration, the TD
target and the critic/actor/temperature losses of one update from replayed random draws, the update
schedule, and the training loop's counters, seeds and callback."""

import math

import gymnasium as gym
import numpy as np
import pytest
import torch

from dlo_policy.config import SACConfig
from dlo_policy.sac import SAC

TINY = dict(hidden_sizes=(16, 16), batch_size=8, learning_starts=0, buffer_size=200, observation_scaling="none")


@pytest.fixture(autouse=True)
def one_thread():
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)


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
    with torch.no_grad():
        for head, value in ((critic.q1[-1], q1), (critic.q2[-1], q2)):
            head.weight.zero_()
            head.bias.fill_(value)


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
    agent = agent_with(policy_update_every=1, target_update_every=1000, reward_scale=50.0, gamma=0.9,
                       initial_alpha=0.3, target_entropy=-2.0)
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


def test_update_schedule_and_that_every_network_learns():
    agent = agent_with(policy_update_every=2, target_update_every=3)
    before = {name: [p.clone() for p in net.parameters()]
              for name, net in (("actor", agent.actor), ("critic", agent.critic), ("target", agent.critic_target))}
    alpha = agent.alpha
    keys = [sorted(agent.update()) for _ in range(3)]
    assert keys == [["critic_loss"], ["actor_loss", "alpha_loss", "critic_loss"], ["critic_loss"]]
    assert agent.num_updates == 3 and agent.alpha != alpha
    for name, net in (("actor", agent.actor), ("critic", agent.critic), ("target", agent.critic_target)):
        assert any(not torch.equal(a, b) for a, b in zip(before[name], net.parameters())), name
    fixed = agent_with(policy_update_every=1, autotune_alpha=False)
    assert "alpha_loss" not in fixed.update()


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
            torch.min(*agent.critic_target(batch.next_obs, next_actions)) - alpha * next_log_pi)
    q1, q2 = agent.critic(batch.obs, batch.actions)
    critic_grads = torch.autograd.grad(((q1 - target) ** 2).mean() + ((q2 - target) ** 2).mean(),
                                       list(agent.critic.parameters()))
    actions, log_pi = agent.actor.sample(batch.obs, generator)
    q = torch.min(*agent.critic(batch.obs, actions))
    actor_grads = torch.autograd.grad((alpha * log_pi - q).mean(), list(agent.actor.parameters()))
    alpha_grad = torch.autograd.grad(-(agent.log_alpha.exp() * (log_pi.detach() + agent.target_entropy)).mean(),
                                     [agent.log_alpha])[0]
    agent.update()
    for expected, p in zip(critic_grads, agent.critic.parameters()):
        torch.testing.assert_close(p.grad, expected, rtol=1e-4, atol=1e-6)
    for expected, p in zip(actor_grads, agent.actor.parameters()):
        torch.testing.assert_close(p.grad, expected, rtol=1e-4, atol=1e-6)
    torch.testing.assert_close(agent.log_alpha.grad, alpha_grad, rtol=1e-4, atol=1e-7)
