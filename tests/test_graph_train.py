"""Policy node modes beyond a fixed policy: online SAC training through the graph, the ground-truth oracle."""

import json
import os
import pathlib

from dlo_policy import rundir
from dlo_policy.evaluate import load_run_config
from dlo_policy.sac import SAC

ROOT = pathlib.Path(__file__).resolve().parents[1]


def test_online_training_through_the_graph_writes_dlo_train_checkpoints(tmp_path, launch_in_own_group):
    config = tmp_path / "tiny.yaml"
    config.write_text("sac:\n  hidden_sizes: [32, 32]\n  batch_size: 16\n  learning_starts: 3\n")
    out, logs = tmp_path / "online", tmp_path / "logs"
    result = launch_in_own_group(
        [
            "bash",
            str(ROOT / "scripts" / "launch_graph.sh"),
            "--policy",
            "sac",
            "--episodes",
            "2",
            "--seed",
            "3",
            "--train-out",
            str(out),
            "--train-config",
            str(config),
            "--logs",
            str(logs),
        ],
        timeout=600,
        env={**os.environ, "DLO_USE_ROS2RUN": "1"},
    )
    assert result.returncode == 0, result.stdout + result.stderr
    agent = SAC.load(out / rundir.CHECKPOINT_FILE)
    episodes = [json.loads(line) for line in (logs / "outcomes.jsonl").read_text().splitlines()]
    steps = sum(e["episode_length"] for e in episodes)
    assert agent.num_env_steps == steps  # every transition of both episodes was stored once
    assert steps > 3 and agent.num_updates == steps - 3 and agent.num_episodes == 2
    assert load_run_config(out / rundir.POLICY_FILE).sac.hidden_sizes == (32, 32)
    SAC.load(out / rundir.POLICY_FILE).predict([0.0] * 9)


def test_oracle_baseline_runs_in_the_graph_from_ground_truth(tmp_path, launch_in_own_group):
    logs = tmp_path / "logs"
    result = launch_in_own_group(
        [
            "bash",
            str(ROOT / "scripts" / "launch_graph.sh"),
            "--policy",
            "oracle",
            "--episodes",
            "2",
            "--seed",
            "21",
            "--logs",
            str(logs),
        ],
        timeout=600,
        env={**os.environ, "DLO_USE_ROS2RUN": "1"},
    )
    assert result.returncode == 0, result.stdout + result.stderr
    episodes = [json.loads(line) for line in (logs / "outcomes.jsonl").read_text().splitlines()]
    assert [e["outcome"] for e in episodes] == ["hold_the_end", "hold_the_end"]
