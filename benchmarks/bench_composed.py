#!/usr/bin/env python3
"""Benchmark the one-process graph (launch_graph.sh --composed) against the graph of processes: closed-loop steps/s.

Runs scripts/launch_graph.sh step-locked for the same episodes (seed, policy) twice per round, once with a process
per node and once with --composed, the order swapped every round (A B, B A: the machine's load drifts). Each run is
measured from outside, the same way for both: a probe node in this process subscribes to /dlo/gripper/state (which
the graph publishes anyway; it carries the episode and step) on the run's domain, best effort, and notes when each
step first arrives. The loop rate is taken within episodes (resets
and the first episode, which compiles the kernels, left out): the median step period, as benchmarks/bench_graph.py
gives it, and the mean. Also each run's CPU time (all its processes, start-up included) and whether every run's
episodes (outcomes.jsonl) are the same. Prints a JSON line last.

    python benchmarks/run.py composed -- [--episodes 4] [--rounds 2] [--policy sac] [--record] [--target 300]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
MODES = ("processes", "composed")


class StepProbe:
    """A node on ``domain`` that notes the wall time (time.monotonic) each (episode, step) of /dlo/gripper/state first
    arrives, spun in a thread of its own until :meth:`close`."""

    def __init__(self, domain: int):
        import rclpy
        from dlo_msgs.msg import GripperState
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from rclpy.signals import SignalHandlerOptions

        self.rclpy = rclpy
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain, signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node("bench_composed_probe", context=self.context)
        self.arrived: dict = {}  # (episode, step) -> monotonic time
        self.node.create_subscription(
            GripperState, "/dlo/gripper/state", self.on_state, QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT)
        )
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self.spin, daemon=True)
        self.thread.start()

    def on_state(self, msg) -> None:
        self.arrived.setdefault((int(msg.episode), int(msg.step)), time.monotonic())

    def spin(self) -> None:
        while not self.stop.is_set() and self.context.ok():
            self.executor.spin_once(timeout_sec=0.1)

    def close(self) -> None:
        self.stop.set()
        self.thread.join()
        self.executor.shutdown()
        self.node.destroy_node()
        self.rclpy.try_shutdown(context=self.context)


def step_periods(arrived: dict) -> list:
    """The wall time [s] between consecutive steps of one episode, for every episode but the first."""
    periods = []
    for (episode, step), t in arrived.items():
        after = arrived.get((episode, step + 1))
        if episode > 0 and after is not None:
            periods.append(after - t)
    return periods


def free_domain() -> int:
    """A domain no participant on this machine uses (the launcher then locks it for the run)."""
    from dlo_bringup.domain import free_domain as find

    found = find()
    if found is None:
        raise SystemExit("bench_composed: no free ROS_DOMAIN_ID in 10..99")
    domain, fd = found
    if fd >= 0:
        os.close(fd)  # (released: the launcher takes it)
    return domain


def run_graph(mode: str, args, work: Path) -> dict:
    """One launch_graph.sh run in ``mode``; its figures."""
    domain = free_domain()
    logs = work / f"{mode}_{len(list(work.iterdir()))}"
    command = ["bash", str(ROOT / "scripts" / "launch_graph.sh"), "--episodes", str(args.episodes), "--seed", str(args.seed)]
    command += ["--policy", args.policy, "--logs", str(logs), "--domain-id", str(domain), "--status-period", "0"]
    command += ["--record", str(logs / "bag")] if args.record else []
    command += ["--composed"] if mode == "composed" else []
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    started = time.monotonic()
    proc = subprocess.Popen(
        command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env={**os.environ, "DLO_USE_ROS2RUN": "1"}
    )
    output = []
    for line in proc.stdout:  # up to the domain line: the launcher holds the domain now
        output.append(line)
        if line.startswith("[launch] ROS_DOMAIN_ID="):
            break
    probe = StepProbe(domain)
    output += proc.stdout.readlines()
    rc = proc.wait()
    wall = time.monotonic() - started
    probe.close()
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if rc != 0:
        raise SystemExit(f"bench_composed: the {mode} graph failed (exit {rc}):\n" + "".join(output[-30:]))
    periods = np.asarray(step_periods(probe.arrived))
    if periods.size == 0:
        raise SystemExit(f"bench_composed: no step of the {mode} graph after its first episode was seen")
    outcomes = [json.loads(line) for line in (logs / "outcomes.jsonl").read_text().splitlines() if line.strip()]
    run = {
        "mode": mode,
        "steps_per_s": round(1.0 / float(np.median(periods)), 1),
        "steps_per_s_mean": round(periods.size / float(periods.sum()), 1),
        "steps_timed": int(periods.size),
        "wall_s": round(wall, 1),
        "cpu_s": round(after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime, 1),
        "load_average_1min": round(os.getloadavg()[0], 2),
    }
    print(json.dumps(run), flush=True)  # progress: one line per run
    return {**run, "outcomes": outcomes}


def pooled(runs: list, mode: str, key: str) -> float:
    return round(float(np.median([r[key] for r in runs if r["mode"] == mode])), 1)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=4, help="episodes per run, the first not timed (default 4)")
    parser.add_argument("--rounds", type=int, default=2, help="rounds of one run per mode, order swapped each (default 2)")
    parser.add_argument("--seed", type=int, default=7005)
    parser.add_argument("--policy", default="sac", choices=("sac", "tactile_reactive", "oracle", "random"))
    parser.add_argument("--record", action="store_true", help="with the recorder (--record) in both modes")
    parser.add_argument("--target", type=float, default=300.0, help="the composed graph's target [steps/s] (default 300)")
    args = parser.parse_args()
    if args.episodes < 2 or args.rounds < 1:
        parser.error("--episodes must be >= 2 (the first is not timed) and --rounds >= 1")

    work = Path(tempfile.mkdtemp(prefix="bench_composed_"))
    runs = []
    try:
        for i in range(args.rounds):
            for mode in MODES if i % 2 == 0 else MODES[::-1]:
                runs.append(run_graph(mode, args, work))
    finally:
        shutil.rmtree(work, ignore_errors=True)
    first = runs[0]["outcomes"]
    composed, processes = pooled(runs, "composed", "steps_per_s"), pooled(runs, "processes", "steps_per_s")
    result = {
        "closed_loop_steps_per_s": {"processes": processes, "composed": composed},
        "closed_loop_steps_per_s_mean": {mode: pooled(runs, mode, "steps_per_s_mean") for mode in MODES},
        "speedup": round(composed / processes, 2),
        "target_steps_per_s": args.target,
        "target_met": composed >= args.target,
        "outcomes_identical": all(run["outcomes"] == first for run in runs),
        "episodes": [[e["seed"], e["outcome"], e["episode_length"]] for e in first],
        "runs": [{k: v for k, v in run.items() if k != "outcomes"} for run in runs],
        "policy": args.policy,
        "record": args.record,
        "nice": os.nice(0),
        "cpus": os.cpu_count(),
        "load_average_1min": round(os.getloadavg()[0], 2),
    }
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
