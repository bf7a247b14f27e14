"""dlo-evaluate's progress bar (issue 12): one tick per counted episode as it ends, on stderr only when
forced (--progress) or stderr is a terminal, never with --quiet; stdout (the table) stays the same."""

import numpy as np
import pytest
from dlo_policy import evaluate
from dlo_policy.config import RunConfig


class EndingVecEnv:
    """Env i of a reset with seed s ends its episode after 1 + (s + i) % 3 steps (outcome hold_the_end under
    both rules), then keeps running (auto-reset) without further ends reported."""

    def __init__(self, num_envs):
        self.num_envs = num_envs

    def reset(self, seed=None):
        self.length = 1 + (seed + np.arange(self.num_envs)) % 3
        self.t = 0
        return np.zeros((self.num_envs, 9), np.float32), {}

    def step(self, actions):
        self.t += 1
        done = self.length == self.t
        info = {
            "outcome": np.array(["hold_the_end"] * self.num_envs, dtype=object),
            "_outcome": done.copy(),
            "outcome_authors": np.array(["hold_the_end"] * self.num_envs, dtype=object),
            "_outcome_authors": done.copy(),
        }
        return np.zeros((self.num_envs, 9), np.float32), np.ones(self.num_envs), done, np.zeros_like(done), info

    def close(self):
        pass


class Agent:
    num_env_steps = 0

    def predict(self, obs, deterministic=False):
        return np.zeros((len(obs), 3), np.float32)

    @classmethod
    def load(cls, path):
        return cls()


@pytest.fixture
def stubbed(monkeypatch):
    monkeypatch.setattr(evaluate, "SAC", Agent)
    monkeypatch.setattr(evaluate, "load_run_config", lambda path: RunConfig(modalities="All"))
    monkeypatch.setattr(evaluate, "make_vec_env_for", lambda config, num_envs, seed: EndingVecEnv(num_envs))


def test_progress_counts_each_counted_episode_once_as_it_ends():
    ticks = []
    result = evaluate.evaluate_agent(Agent(), EndingVecEnv(4), first_seed=0, episodes=6, progress=ticks.append)
    assert result.hold_the_end == 1.0
    assert sum(ticks) == 6  # the 2 envs of the last batch beyond episode 6 are not counted
    assert len(ticks) > 1 and all(t >= 1 for t in ticks)  # ticks as episodes end, not once at the end


def run(capsys, *argv):
    rc = evaluate.main(["--checkpoint", "policy.pt", "--episodes", "5", "--num-envs", "2", *argv])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    return captured.out, captured.err


def test_forced_progress_bar_goes_to_stderr_and_leaves_stdout_unchanged(stubbed, capsys):
    out_quiet, err_quiet = run(capsys, "--quiet")
    out_bar, err_bar = run(capsys, "--progress")
    assert "5/5" in err_bar and "dlo-evaluate" in err_bar and "episode" in err_bar
    assert err_quiet == "" and out_bar == out_quiet
    assert "hold_the_end" in out_bar and "seeds 0..4" in out_bar


def test_no_progress_bar_when_stderr_is_not_a_terminal(stubbed, capsys):
    out, err = run(capsys)  # pytest's captured stderr is not a TTY
    assert err == "" and "hold_the_end" in out


def test_progress_and_quiet_exclude_each_other(stubbed, capsys):
    with pytest.raises(SystemExit) as stopped:
        evaluate.main(["--checkpoint", "policy.pt", "--progress", "--quiet"])
    assert stopped.value.code == 2 and "not allowed with" in capsys.readouterr().err
