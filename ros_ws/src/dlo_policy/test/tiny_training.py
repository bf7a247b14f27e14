"""What test_train.py and test_train_cli.py share: the tiny dlo-train configuration on sac_reach_env, and a
fixture that gives back torch's thread count a test's training changed (import it into the test module)."""

import pytest
import torch

TINY = [
    "env_module=sac_reach_env",
    "sac.hidden_sizes=[32,32]",
    "sac.batch_size=32",
    "sac.learning_starts=50",
    "sac.buffer_size=2000",
    "train.eval_every=100",
    "train.checkpoint_every=100",
    "train.num_threads=1",
]


@pytest.fixture(autouse=True)
def restore_threads():
    previous = torch.get_num_threads()
    yield
    torch.set_num_threads(previous)
