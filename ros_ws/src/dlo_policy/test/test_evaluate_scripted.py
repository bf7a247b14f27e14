"""dlo-evaluate --policy oracle|tactile_reactive|random: the scripted baselines through the evaluation
protocol (it replaced scripts/eval_scripted.py). Exactly one of --checkpoint and --policy;
one-line errors on options that do not fit; per seed the same episodes as ``scripted.run_episodes``
(what the baseline table was made with), the policy's memory cleared for every batch; the JSON with
both outcome rules."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from dlo_policy import evaluate
from dlo_policy.env import make_vec_env
from dlo_policy.scripted import OracleFollow, TactileReactive, run_episodes

sys.path.insert(0, str(Path(__file__).resolve().parent))  # --import-mode=importlib: helper modules

from shared_simulator import SharedSimulator  # noqa: E402

INSTALL_BIN = Path(__file__).resolve().parents[3] / "ros_ws" / "install" / "dlo_policy" / "lib" / "dlo_policy"


def executable(*args, timeout=600):
    env = {**os.environ, "PATH": f"{INSTALL_BIN}:{os.environ['PATH']}"}
    return subprocess.run(["dlo-evaluate", *args], capture_output=True, text=True, timeout=timeout, env=env)


def one_line_error(capsys, argv) -> str:
    with pytest.raises(SystemExit) as exit_:
        rc = evaluate.main(argv)
        raise SystemExit(rc)
    err = capsys.readouterr().err.strip()
    assert exit_.value.code == 2 and len(err.splitlines()) == 1, err
    assert err.startswith("dlo-evaluate: error: "), err
    return err


def test_help_names_both_ways_and_the_scripted_policies():
    result = executable("--help", timeout=120)
    assert result.returncode == 0, result.stderr
    for word in ("--checkpoint", "--policy", "oracle", "tactile_reactive", "random", "--task-rules", "--stop-before-end"):
        assert word in result.stdout


@pytest.mark.parametrize(
    "argv, message",
    [
        ([], "one of the arguments --checkpoint --policy is required"),
        (["--policy", "oracle", "--checkpoint", "policy.pt"], "not allowed with argument"),
        (["--policy", "sac"], "argument --policy: invalid choice: 'sac'"),
        (["--checkpoint", "policy.pt", "--task-rules", "paper_text"], "--task-rules is for --policy"),
        (["--policy", "tactile_reactive", "--stop-before-end", "9"], "--stop-before-end is for --policy oracle"),
        (["--policy", "oracle", "--stop-before-end", "-1"], "--stop-before-end must be >= 0, got -1"),
        (["--policy", "random", "--episodes", "0"], "--episodes and --num-envs must be >= 1"),
        (["--policy", "oracle", "--task-rules", "mine"], "argument --task-rules: invalid choice: 'mine'"),
    ],
)
def test_options_that_do_not_fit_are_one_line_errors(capsys, argv, message):
    assert message in one_line_error(capsys, argv)


def test_the_real_executable_refuses_both_ways_in_one_line():
    result = executable("--policy", "random", "--checkpoint", "policy.pt", timeout=120)
    assert result.returncode == 2 and result.stdout == "" and len(result.stderr.strip().splitlines()) == 1
    assert "Traceback" not in result.stderr


OUTCOMES = evaluate.OUTCOMES


class KnownVecEnv:
    """Env i of a reset with seed s plays episode s + i: it ends after 1 + (s + i) % 3 steps with outcome
    OUTCOMES[(s + i) % 4] (authors' rule: the next one), then keeps running (auto-reset)."""

    def __init__(self, num_envs):
        self.num_envs = num_envs

    def reset(self, seed=None):
        self.episode, self.t = seed + np.arange(self.num_envs), 0
        return np.zeros((self.num_envs, 9), np.float32), {}

    def step(self, actions):
        self.t += 1
        done = 1 + self.episode % 3 == self.t
        info = {
            "outcome": np.array([OUTCOMES[e % 4] for e in self.episode], dtype=object),
            "outcome_authors": np.array([OUTCOMES[(e + 1) % 4] for e in self.episode], dtype=object),
            "time_at_end": np.zeros(self.num_envs),
            "how_far": np.zeros(self.num_envs),
        }
        info.update({"_" + key: done.copy() for key in list(info)})
        return np.zeros((self.num_envs, 9), np.float32), np.ones(self.num_envs), done, np.zeros_like(done), info

    def close(self):
        pass


class CountingPolicy:
    """A scripted policy that acts 0 and counts how often its memory is cleared."""

    def __init__(self):
        self.resets = 0

    def reset(self, env_ids=None):
        self.resets += 1

    def __call__(self, observation, env):
        return np.zeros((env.num_envs, 3), np.float32)


def test_every_batch_starts_the_policy_afresh_and_the_json_has_both_rules(monkeypatch, tmp_path, capsys):
    policy, built = CountingPolicy(), []

    def make_env(num_envs, seed, task_rules):
        built.append((num_envs, seed, task_rules))
        return KnownVecEnv(num_envs)

    monkeypatch.setattr(evaluate, "scripted_policy", lambda name, seed, stop_before_end: policy)
    monkeypatch.setattr(evaluate, "make_scripted_vec_env", make_env)
    out = tmp_path / "eval.json"
    assert (
        evaluate.main(
            [
                "--policy",
                "tactile_reactive",
                "--episodes",
                "5",
                "--num-envs",
                "2",
                "--seed",
                "3",
                "--task-rules",
                "paper_text",
                "--json",
                str(out),
                "--quiet",
            ]
        )
        == 0
    )
    assert built == [(2, 3, "paper_text")] and policy.resets == 3  # batches of seeds 3-4, 5-6, 7
    payload = json.loads(out.read_text())
    assert payload["episodes"] == 5 and payload["policy"] == "tactile_reactive"
    assert payload["task_rules"] == "paper_text"
    # KnownVecEnv: episode seed s ends with OUTCOMES[s % 4] (paper rule), OUTCOMES[(s + 1) % 4] (authors' rule)
    assert payload["hold_the_end"] == pytest.approx(1 / 5) and payload["stop_before"] == pytest.approx(1 / 5)
    assert payload["authors_code"]["hold_the_end"] == pytest.approx(2 / 5)
    printed = capsys.readouterr().out
    assert printed.startswith("scripted tactile_reactive on All, task rules paper_text, seeds 3..7")


@pytest.fixture(scope="module")
def simulator():
    """The simulator of the module's envs of two, built (its kernels compiled) once: run_episodes and
    evaluate_agent reset every env from its seed before they step (shared_simulator)."""
    return SharedSimulator()


@pytest.mark.parametrize("make_policy", [OracleFollow, TactileReactive], ids=["oracle", "tactile_reactive"])
def test_the_same_episodes_as_run_episodes_seed_by_seed(make_policy, simulator):
    """Two batches of two envs vs run_episodes (auto-reset over the seeds): equal outcomes under both
    rules and equal metrics, so the baseline table of run_episodes is reproduced by dlo-evaluate."""
    reference = run_episodes(make_vec_env(2, modalities="All", seed=40, simulator=simulator), make_policy(), 4, seed=40)
    policy = make_policy()
    env = make_vec_env(2, modalities="All", seed=40, simulator=simulator)
    result = evaluate.evaluate_agent(
        evaluate.ScriptedAgent(policy, env), evaluate._ResetsPolicy(env, policy), first_seed=40, episodes=4
    )
    assert [r["episode_seed"] for r in reference] == [40, 41, 42, 43]
    for rule, key in (("", "outcome"), (evaluate.AUTHORS_SUFFIX, "outcome_authors")):
        for name in evaluate.OUTCOMES:
            expected = np.mean([r[key] == name for r in reference])
            assert getattr(result, name + rule) == pytest.approx(expected), name + rule
    assert result.how_far == pytest.approx(np.mean([r["how_far"] for r in reference]))
    assert result.time_at_end == pytest.approx(np.mean([r["time_at_end"] for r in reference]))
    assert result.episode_reward == pytest.approx(np.mean([r["episode_return"] for r in reference]), abs=1e-4)


def test_a_tiny_real_run_of_the_executable(tmp_path):
    out = tmp_path / "oracle.json"
    result = executable(
        "--policy",
        "oracle",
        "--stop-before-end",
        "9",
        "--episodes",
        "2",
        "--num-envs",
        "2",
        "--seed",
        "5",
        "--threads",
        "1",
        "--json",
        str(out),
    )
    assert result.returncode == 0, result.stderr[-3000:]
    assert "scripted oracle (stops 9 before the end) on All, task rules authors_code, seeds 5..6" in result.stdout
    payload = json.loads(out.read_text())
    assert payload["episodes"] == 2 and payload["stop_before_end"] == 9 and payload["modalities"] == "All"
    for rule in (payload, payload["authors_code"]):
        assert sum(rule[name] for name in evaluate.OUTCOMES) == pytest.approx(1.0)


def test_stdout_is_only_the_title_and_the_table(tmp_path):
    """dlo-evaluate --help: stdout carries only the table (its title first), so that it can be piped: no line
    of Taichi's ("[Taichi] Starting on arch=x64") before it."""
    result = executable("--policy", "random", "--episodes", "1", "--num-envs", "1", "--seed", "5", "--threads", "1")
    assert result.returncode == 0, result.stderr[-3000:]
    lines = result.stdout.splitlines()
    assert lines[0] == "scripted random on All, task rules authors_code, seeds 5..5", result.stdout
    assert lines[1].split() == ["outcome", "paper", "rule", "authors", "rule"] and len(lines) == 12
