#!/usr/bin/env python3
"""Benchmark the step-locked ROS 2 graph: closed-loop control steps/s, per-hop latency, recorder drops.

Runs scripts/launch_graph.sh (sim, tactile, vision, policy, recorder: five processes) for a few
episodes, then reads the recorded bag: the recorder's receive time of each message gives the
hops of one control step (state -> tactile pose, state -> visual pose, last pose -> command,
command -> next state) and the loop rate within episodes (resets excluded). Prints a JSON line last.

    python benchmarks/run.py graph -- [--episodes 3] [--policy sac|tactile_reactive|random]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from collections import defaultdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
TOPICS = ("/dlo/gripper/state", "/dlo/tactile/pose", "/dlo/vision/pose", "/dlo/gripper/cmd", "/dlo/task/state")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=3)
    parser.add_argument("--seed", type=int, default=500)
    parser.add_argument("--policy", default="tactile_reactive", choices=("sac", "tactile_reactive", "random"))
    args = parser.parse_args()

    from dlo_bag.reader import read_messages
    from dlo_perception.sync import stamp_to_ns

    work = Path(tempfile.mkdtemp(prefix="bench_graph_"))
    bag, logs = work / "bag", work / "logs"
    launch = subprocess.run(
        [
            "bash",
            str(ROOT / "scripts" / "launch_graph.sh"),
            "--episodes",
            str(args.episodes),
            "--seed",
            str(args.seed),
            "--policy",
            args.policy,
            "--record",
            str(bag),
            "--logs",
            str(logs),
        ],
        capture_output=True,
        text=True,
        env={**os.environ, "DLO_USE_ROS2RUN": "1"},
    )
    if launch.returncode != 0:
        print(launch.stdout + launch.stderr, file=sys.stderr)
        return 1

    first_seen = defaultdict(dict)  # topic -> stamp -> first receive time [ns]
    step_of = {}  # stamp -> (episode, step) from the task state
    counts = defaultdict(int)
    for item in read_messages(bag, topics=TOPICS):
        stamp = stamp_to_ns(item.msg.header.stamp)
        counts[item.topic] += 1
        first_seen[item.topic].setdefault(stamp, item.timestamp)
        if item.topic == "/dlo/task/state":
            step_of[stamp] = (item.msg.episode, item.msg.step)

    state, tactile, vision, cmd = (first_seen[t] for t in TOPICS[:4])
    stamps = sorted(s for s in state if s in tactile and s in vision and s in cmd)
    hops = {"state_to_tactile": [], "state_to_vision": [], "poses_to_cmd": [], "cmd_to_next_state": []}
    loop_periods = []
    for s in stamps:
        hops["state_to_tactile"].append(tactile[s] - state[s])
        hops["state_to_vision"].append(vision[s] - state[s])
        hops["poses_to_cmd"].append(cmd[s] - max(tactile[s], vision[s]))
    for a, b in zip(stamps, stamps[1:]):
        (ea, sa), (eb, sb) = step_of.get(a, (-1, -1)), step_of.get(b, (-2, -2))
        if ea == eb and sb == sa + 1:  # consecutive steps of one episode: a full control loop
            hops["cmd_to_next_state"].append(state[b] - cmd[a])
            loop_periods.append(state[b] - state[a])
    summary_file = logs / "recorder_summary.json"
    recorder = json.loads(summary_file.read_text()) if summary_file.exists() else {}
    all_hops = np.concatenate([np.asarray(v, float) for v in hops.values()]) / 1e6
    result = {
        "closed_loop_steps_per_s": round(1e9 / float(np.median(loop_periods)), 1),
        "closed_loop_steps_per_s_mean": round(1e9 * len(loop_periods) / float(np.sum(loop_periods)), 1),
        "hop_latency_p50_ms": round(float(np.percentile(all_hops, 50)), 3),
        "hop_latency_p99_ms": round(float(np.percentile(all_hops, 99)), 3),
        "hops_ms": {
            k: {
                "p50": round(float(np.percentile(np.asarray(v) / 1e6, 50)), 3),
                "p99": round(float(np.percentile(np.asarray(v) / 1e6, 99)), 3),
            }
            for k, v in hops.items()
        },
        "recorder_dropped": recorder.get("dropped"),
        "recorded_messages": dict(counts),
        "control_steps": len(loop_periods),
        "policy": args.policy,
        "processes": 5,
        "load_average_1min": os.getloadavg()[0],
    }
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
