#!/usr/bin/env python3
"""Outcome rates of the scripted policies (random, oracle follow, tactile-reactive) over seeded episodes.

Usage: python scripts/eval_scripted.py [--episodes 200] [--num-envs 50] [--seed 0] [--policies random,oracle,tactile]
Prints a markdown table (outcome rates in %, mean time at end [steps], mean how far [particles],
mean return) and a JSON line last. Episodes use seeds seed .. seed + episodes - 1 in every row.
"""

import argparse
import json
import time

import numpy as np

from dlo_policy.env import make_vec_env
from dlo_policy.scripted import OracleFollow, RandomPolicy, TactileReactive, run_episodes
from dlo_sim import task

POLICIES = {"random": RandomPolicy, "oracle": OracleFollow, "tactile": TactileReactive}
OUTCOMES = [name for code, name in sorted(task.OUTCOME_NAMES.items()) if code != task.OUTCOME_NONE]


def summarise(results) -> dict:
    """Outcome rates and mean metrics of a list of episode-end infos."""
    outcomes = [r["outcome"] for r in results]
    summary = {name: outcomes.count(name) / len(results) for name in OUTCOMES}
    summary["unstable"] = float(np.mean([r["unstable"] for r in results]))
    for key in ("time_at_end", "how_far", "episode_return"):
        summary[key] = float(np.mean([r[key] for r in results]))
    summary["episodes"] = len(results)
    return summary


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--num-envs", type=int, default=50)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--policies", default="random,oracle,tactile")
    args = parser.parse_args()
    env = make_vec_env(args.num_envs, modalities="All", seed=args.seed)
    table = {}
    print("| policy | hold the end | stop before | reach end but drop | drop before | time at end | how far | return |")
    print("|---|---|---|---|---|---|---|---|")
    for name in args.policies.split(","):
        start = time.perf_counter()
        table[name] = summarise(run_episodes(env, POLICIES[name](), args.episodes, seed=args.seed))
        s = table[name]
        print(f"| {name} | {100 * s['hold_the_end']:.1f}% | {100 * s['stop_before']:.1f}% | "
              f"{100 * s['reach_end_but_drop']:.1f}% | {100 * s['drop_before']:.1f}% | {s['time_at_end']:.1f} | "
              f"{s['how_far']:.1f} | {s['episode_return']:.2f} |  ({time.perf_counter() - start:.0f} s)", flush=True)
    print(json.dumps({"episodes": args.episodes, "seed": args.seed, "policies": table}))


if __name__ == "__main__":
    main()
