"""dlo_policy.evaluate (dlo-evaluate) with a trained agent, on a scripted vector env whose episodes are
known in advance: the seeds of every batch, the episodes of a last partial batch, returns summed only
until each env's first episode end, outcomes and metrics from that end's info (gymnasium's "_key"
masks), deterministic actions, NaN where the env reports no such info, and the JSON layout; ``--without
X`` blanks X's columns, and only those, before the agent sees them; the command line's counts, JSON,
threads and one-line errors. Its progress bar: test_evaluate_progress.py; the scripted baselines
(``--policy``): test_evaluate_scripted.py."""

import math
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from dlo_policy import evaluate
from dlo_policy.config import RunConfig

sys.path.insert(0, str(Path(__file__).resolve().parent))  # --import-mode=importlib: helper modules
import sac_reach_env  # noqa: E402

OUTCOMES = ("hold_the_end", "stop_before", "reach_end_but_drop", "drop_before")


@pytest.fixture(autouse=True)
def one_thread():
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)


class ScriptedVecEnv:
    """Env i of a reset with seed s plays episode seed s + i: it lasts 2 + (s + i) % 3 steps, earns
    reward (s + i) per step, ends with outcome OUTCOMES[(s + i) % 4] (authors' rule: the next one),
    time_at_end = s + i and how_far = 10 * (s + i); then it auto-resets and keeps earning 1000."""

    def __init__(self, num_envs, infos=True):
        self.num_envs, self.infos = num_envs, infos
        self.resets, self.actions = [], []

    def reset(self, seed=None):
        self.resets.append(seed)
        self.episode = seed + np.arange(self.num_envs)
        self.t = np.zeros(self.num_envs, int)
        self.ended = np.zeros(self.num_envs, bool)
        return np.tile(np.arange(9, dtype=np.float32), (self.num_envs, 1)), {}

    def step(self, actions):
        self.actions.append(np.array(actions, copy=True))
        self.t += 1
        length = 2 + self.episode % 3
        done = (self.t == length) & ~self.ended
        reward = np.where(self.ended, 1000.0, self.episode.astype(float))
        info = {}
        if done.any() and self.infos:
            info = {
                "outcome": np.array([OUTCOMES[e % 4] for e in self.episode], dtype=object),
                "outcome_authors": np.array([OUTCOMES[(e + 1) % 4] for e in self.episode], dtype=object),
                "time_at_end": self.episode.copy(),
                "how_far": 10.0 * self.episode,
                "n_held": np.full(self.num_envs, 3),
            }
            info.update({"_" + k: done.copy() for k in ("outcome", "outcome_authors", "time_at_end", "how_far")})
        self.ended |= done
        terminated = done & (self.episode % 2 == 0)
        truncated = done & ~terminated
        obs = np.tile(np.arange(9, dtype=np.float32), (self.num_envs, 1))
        return obs, reward, terminated, truncated, info


class Agent:
    def __init__(self):
        self.deterministic = []

    def predict(self, obs, deterministic=False):
        self.deterministic.append(deterministic)
        return np.zeros((len(obs), 3), np.float32)


def expected(first_seed, episodes):
    seeds = first_seed + np.arange(episodes)
    returns = [(2 + s % 3) * float(s) for s in seeds]
    return seeds, returns


def test_batches_seeds_partial_batch_returns_and_outcomes():
    env, agent = ScriptedVecEnv(3), Agent()
    result = evaluate.evaluate_agent(agent, env, first_seed=10, episodes=7)
    assert env.resets == [10, 13, 16]  # one reset per batch of 3, the last one partly used
    seeds, returns = expected(10, 7)
    assert result.episodes == 7
    assert result.episode_reward == pytest.approx(np.mean(returns))
    for k, name in enumerate(OUTCOMES):
        assert getattr(result, name) == pytest.approx(np.mean([s % 4 == k for s in seeds]))
        assert getattr(result, name + "_authors") == pytest.approx(np.mean([(s + 1) % 4 == k for s in seeds]))
    assert result.time_at_end == pytest.approx(np.mean(seeds))
    assert result.how_far == pytest.approx(10 * np.mean(seeds))
    assert agent.deterministic and all(d is True for d in agent.deterministic)
    # every batch runs until its wanted envs are done: the longest wanted episode of each batch
    assert len(env.actions) == sum(max(2 + s % 3 for s in seeds[b : b + 3]) for b in (0, 3, 6))


def test_one_env_at_a_time_and_more_envs_than_episodes():
    for n_envs, episodes in ((1, 3), (5, 2)):
        env = ScriptedVecEnv(n_envs)
        result = evaluate.evaluate_agent(Agent(), env, first_seed=4, episodes=episodes)
        seeds, returns = expected(4, episodes)
        assert result.episode_reward == pytest.approx(np.mean(returns))
        assert result.time_at_end == pytest.approx(np.mean(seeds))
        assert env.resets == [4 + k * n_envs for k in range(math.ceil(episodes / n_envs))]


def test_an_env_without_episode_infos_gives_nan():
    result = evaluate.evaluate_agent(Agent(), ScriptedVecEnv(2, infos=False), first_seed=0, episodes=2)
    assert all(math.isnan(getattr(result, name)) for name in (*OUTCOMES, "time_at_end", "how_far"))
    assert result.episode_reward == pytest.approx(np.mean(expected(0, 2)[1]))


def test_episode_end_info_reads_only_the_masked_entries():
    infos = {
        "outcome": np.array(["drop_before", "hold_the_end"], dtype=object),
        "_outcome": np.array([False, True]),
        "n_held": np.array([np.int64(3), np.int64(0)]),
    }
    assert evaluate._episode_end_info(infos, 1) == {"outcome": "hold_the_end", "n_held": 0}
    assert evaluate._episode_end_info(infos, 0) == {"n_held": 3}
    assert type(evaluate._episode_end_info(infos, 0)["n_held"]) is int
    assert (
        evaluate._fractions([{"outcome": "stop_before"}, {}], "outcome", "")["stop_before"]
        != evaluate._fractions([{"outcome": "stop_before"}, {}], "outcome", "")["stop_before"]
    )  # NaN: one is unknown
    assert evaluate._fractions([{"o": "stop_before"}, {"o": "drop_before"}], "o", "_x") == {
        "hold_the_end_x": 0.0,
        "stop_before_x": 0.5,
        "reach_end_but_drop_x": 0.0,
        "drop_before_x": 0.5,
    }
    assert math.isnan(evaluate._mean_of([{"how_far": 2.0}, {}], "how_far"))
    assert evaluate._mean_of([{"how_far": 2.0}, {"how_far": 4.0}], "how_far") == 3.0
    assert math.isnan(evaluate._mean_of([], "how_far"))


def test_json_layout_keeps_the_authors_rule_apart():
    result = evaluate.evaluate_agent(Agent(), ScriptedVecEnv(2), first_seed=1, episodes=4)
    payload = result.to_json()
    assert set(payload["authors_code"]) == set(OUTCOMES)
    assert payload["authors_code"]["hold_the_end"] == result.hold_the_end_authors
    assert payload["hold_the_end"] == result.hold_the_end
    assert not any(key.endswith("_authors") for key in payload)
    assert {"episodes", "episode_reward", "time_at_end", "how_far"} <= set(payload)


def test_progress_ticks_only_for_the_counted_envs_of_a_batch():
    """4 envs, 7 episodes: batch 2 counts envs 0-2; its env 3 ends together with env 0 and is not ticked."""
    ticks = []
    result = evaluate.evaluate_agent(Agent(), ScriptedVecEnv(4), first_seed=0, episodes=7, progress=ticks.append)
    # batch 1 (seeds 0-3, lengths 2 3 4 2): 2 at t=2, then 1, 1; batch 2 (seeds 4-7, lengths 3 4 2 3): 1 (env 2),
    # 1 (env 0; env 3 too but it is beyond the 7th episode), 1 (env 1)
    assert ticks == [2, 1, 1, 1, 1, 1] and result.episodes == 7


class NotingVecEnv(ScriptedVecEnv):
    modalities = ("K", "T", "V")


def test_evaluate_agent_notes_the_modalities_of_the_env_and_refuses_other_ones():
    from dlo_policy.config import SACConfig
    from dlo_policy.sac import SAC

    def agent(modalities):
        return SAC(9, -np.ones(3, np.float32), np.ones(3, np.float32), SACConfig(hidden_sizes=(8, 8)), modalities=modalities)

    unknown = agent(None)  # a checkpoint from before modalities were saved: learns them from the env
    evaluate.evaluate_agent(unknown, NotingVecEnv(2), first_seed=0, episodes=2)
    assert unknown.modalities == ("K", "T", "V")
    env = NotingVecEnv(2)
    with pytest.raises(ValueError, match="the agent observes K\\+T, the env gives K\\+T\\+V"):
        evaluate.evaluate_agent(agent(("K", "T")), env, first_seed=0, episodes=2)
    assert env.resets == []  # refused before any episode


# ---------------------------------------------------------------- --without: blanked columns
class RecordingAgent:
    """Stands in for a trained SAC: acts 0 and records every observation it is shown."""

    num_env_steps = 0

    def __init__(self):
        self.seen = []

    def predict(self, obs, deterministic=True):
        self.seen.append(np.array(obs, copy=True))
        return np.zeros((len(obs), 1), np.float32)


def test_evaluate_agent_blanks_only_the_given_columns():
    agent = RecordingAgent()
    vec_env = sac_reach_env.make_vec_env(3, "All")
    result = evaluate.evaluate_agent(agent, vec_env, first_seed=0, episodes=3, blank=[5, 6])
    seen = np.concatenate(agent.seen)
    assert np.all(seen[:, [5, 6]] == 0.0) and np.any(seen[:, 3] != 0.0) and np.any(seen[:, 1] != 0.0)
    assert result.episodes == 3 and result.stop_before + result.hold_the_end == pytest.approx(1.0)


@pytest.mark.parametrize(
    "without, blank", [([], []), (["T"], [3, 4]), (["V"], [5, 6, 7, 8]), (["K", "V"], [0, 1, 2, 5, 6, 7, 8])]
)
def test_dlo_evaluate_without_blanks_exactly_that_modality(monkeypatch, tmp_path, capsys, without, blank):
    agent = RecordingAgent()
    monkeypatch.setattr(evaluate, "SAC", type("StubSAC", (), {"load": staticmethod(lambda path: agent)}))
    monkeypatch.setattr(evaluate, "load_run_config", lambda path: RunConfig(modalities="All", env_module="sac_reach_env"))
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


# ---------------------------------------------------------------- the command line
class StubSAC:
    def __init__(self):
        self.agent = Agent()
        self.agent.num_env_steps = 123

    def load(self, path):
        return self.agent


def cli(monkeypatch, tmp_path, argv, modalities="All"):
    """dlo-evaluate's main with a stub agent, config and scripted env; returns (rc, envs built)."""
    built = []

    def make_env(config, num_envs, seed):
        env = ScriptedVecEnv(num_envs)
        env.closed = False
        env.close = lambda: setattr(env, "closed", True)
        built.append((env, num_envs, seed))
        return env

    stub = StubSAC()
    monkeypatch.setattr(evaluate, "SAC", stub)
    monkeypatch.setattr(evaluate, "load_run_config", lambda path: RunConfig(modalities=modalities))
    monkeypatch.setattr(evaluate, "make_vec_env_for", make_env)
    return evaluate.main(["--checkpoint", str(tmp_path / "policy.pt"), *argv]), built


@pytest.mark.parametrize("argv", [["--episodes", "0"], ["--num-envs", "0"], ["--episodes", "-3"]])
def test_cli_refuses_non_positive_counts(monkeypatch, tmp_path, capsys, argv):
    rc, built = cli(monkeypatch, tmp_path, argv)
    assert rc == 2 and built == []
    assert "--episodes and --num-envs must be >= 1" in capsys.readouterr().err


def test_cli_one_episode_json_threads_and_the_env_it_builds(monkeypatch, tmp_path, capsys):
    import json

    import torch

    previous = torch.get_num_threads()
    out = tmp_path / "eval.json"
    try:
        rc, built = cli(
            monkeypatch, tmp_path, ["--episodes", "1", "--num-envs", "1", "--seed", "7", "--threads", "2", "--json", str(out)]
        )
        assert torch.get_num_threads() == 2  # the fixture set 1
    finally:
        torch.set_num_threads(previous)
    assert rc == 0
    ((env, num_envs, seed),) = built
    assert (num_envs, seed, env.closed, env.resets) == (1, 7, True, [7])
    text = out.read_text()
    assert text.endswith("}\n") and text.startswith('{\n  "episodes": 1,')  # indented JSON, one final newline
    payload = json.loads(text)
    assert payload["env_steps"] == 123 and payload["seed"] == 7 and payload["without"] == []
    assert payload["episode_reward"] == pytest.approx((2 + 7 % 3) * 7.0)
    assert "seeds 7..7" in capsys.readouterr().out
    rc, built = cli(monkeypatch, tmp_path, ["--episodes", "3", "--num-envs", "10"])
    assert rc == 0 and built[0][1] == 3  # never more envs than episodes


def test_cli_errors_are_one_line_and_exit_2(monkeypatch, tmp_path, capsys):
    rc, built = cli(monkeypatch, tmp_path, ["--without", "V"], modalities="T+K")
    assert rc == 2 and built == [] and "cannot blank ['V']" in capsys.readouterr().err

    def missing(path):
        raise FileNotFoundError("config.yaml not found")

    monkeypatch.setattr(evaluate, "load_run_config", missing)
    assert evaluate.main(["--checkpoint", str(tmp_path / "policy.pt")]) == 2
    assert "config.yaml not found" in capsys.readouterr().err
