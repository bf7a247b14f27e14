"""dlo_policy.replay: the replay buffer stores every field of a transition, wraps around when full,
round-trips through its state dict, and samples with the generator it is given (never the global torch
stream)."""

import numpy as np
import torch
from dlo_policy.replay import ReplayBuffer


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
