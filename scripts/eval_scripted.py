#!/usr/bin/env python3
"""Outcome rates of the scripted policies (random, oracle follow, tactile-reactive) over seeded episodes.

Usage: python scripts/eval_scripted.py [--episodes 200] [--num-envs 50] [--seed 0]
                                       [--policies random,oracle,tactile,oracle-stop-at-10]
Prints a markdown table (outcome rates in %, paper-text rule / authors'-code rule (dlo_sim.task),
mean time at end [steps], mean how far [particles], mean return) and a JSON line last. Episodes use seeds seed .. seed + episodes - 1 in every row.
"""

import argparse
import json
import time

import numpy as np

from dlo_policy.env import make_vec_env
from dlo_policy.scripted import OracleFollow, RandomPolicy, TactileReactive, run_episodes
from dlo_sim import task

POLICIES = {"random": RandomPolicy, "oracle": OracleFollow, "tactile": TactileReactive,
            # stops as soon as it touches particle n_c - 10: "at the end" under the paper text only
            "oracle-stop-at-10": lambda: OracleFollow(stop_before_end=9)}
OUTCOMES = [name for code, name in sorted(task.OUTCOME_NAMES.items()) if code != task.OUTCOME_NONE]


def summarise(results) -> dict:
    """Outcome rates and mean metrics of a list of episode-end infos."""
    outcomes = [r["outcome"] for r in results]
    summary = {name: outcomes.count(name) / len(results) for name in OUTCOMES}
    authors = [r["outcome_authors"] for r in results]
    summary["authors_code"] = {name: authors.count(name) / len(results) for name in OUTCOMES}
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
    parser.add_argument("--policies", default="random,oracle,tactile,oracle-stop-at-10")
    args = parser.parse_args()
    env = make_vec_env(args.num_envs, modalities="All", seed=args.seed)
    table = {}
    print("outcomes: paper-text rule / authors'-code rule")
    print("| policy | hold the end | stop before | reach end but drop | drop before | time at end | how far | return |")
    print("|---|---|---|---|---|---|---|---|")
    for name in args.policies.split(","):
        start = time.perf_counter()
        table[name] = summarise(run_episodes(env, POLICIES[name](), args.episodes, seed=args.seed))
        s = table[name]
        a = s["authors_code"]
        print(f"| {name} | " + " | ".join(f"{100 * s[o]:.1f}% / {100 * a[o]:.1f}%" for o in OUTCOMES)
              + f" | {s['time_at_end']:.1f} | "
              f"{s['how_far']:.1f} | {s['episode_return']:.2f} |  ({time.perf_counter() - start:.0f} s)", flush=True)
    print(json.dumps({"episodes": args.episodes, "seed": args.seed, "policies": table}))


if __name__ == "__main__":
    main()
