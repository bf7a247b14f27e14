#!/usr/bin/env python3
"""Where a trained policy's episodes end, particle by particle: what separates the two outcome rules.

    tools/stop_short.py RUN_DIR [--episodes 100] [--seed 5000] [--json OUT]

Runs the run's best policy (RUN_DIR/best_policy.pt, deterministic, one environment, the run's task rules and
grip) on episodes seed .. seed + episodes - 1 (default: the held-out test's) and records at each episode's end
the outcome under both rules, the authors' narrow held set's mean index counted from the last particle (their
rule asks < 5), the largest index held on the last step from the last particle, and the sizes of both held sets. Prints the
outcome pairs and, for the episodes both rules count as holding and those only the paper rule counts, the
medians and ranges. A diagnostic for docs/RESULTS.md, not a product command.
"""

from __future__ import annotations

import argparse
import collections
import json
import sys
from pathlib import Path

import numpy as np
import torch
from dlo_policy.env import make_vec_env
from dlo_policy.rundir import read_trained_config
from dlo_policy.sac import SAC


def episode_ends(run: Path, episodes: int, seed: int) -> list[dict]:
    config = read_trained_config(run)
    agent = SAC.load(run / "best_policy.pt")
    env = make_vec_env(1, modalities=config.modalities, seed=seed, autoreset=False, **config.env_options)
    ends = []
    observation, _ = env.reset(seed=seed)
    while len(ends) < episodes:
        observation, _, terminated, truncated, info = env.step(agent.predict(observation, deterministic=True))
        if terminated[0] or truncated[0]:
            tracker, task, n_c = env.tracker, env.task, int(env.tracker.num_particles[0])
            ends.append(
                {
                    "seed": seed + len(ends),
                    "paper": str(info["outcome"][0]),
                    "authors": str(info["outcome_authors"][0]),
                    "authors_mean_from_end": float(n_c - 1 - tracker.last_p_i_authors[0]),
                    "largest_held_from_end": int(n_c - 1 - task.max_held_index[0]),
                    "narrow_held": int(task.n_held_authors[0]),
                    "wide_held": int(task.n_held[0]),
                }
            )
            observation, _ = env.reset()
    env.close()
    return ends


def describe(ends: list[dict]) -> str:
    lines = [
        f"{n:3d} episodes: paper rule {p}, authors' rule {a}"
        for (p, a), n in collections.Counter((e["paper"], e["authors"]) for e in ends).most_common()
    ]
    for pair in (("hold_the_end", "hold_the_end"), ("hold_the_end", "stop_before")):
        chosen = [e for e in ends if (e["paper"], e["authors"]) == pair]
        if not chosen:
            continue
        parts = []
        for key in ("authors_mean_from_end", "largest_held_from_end", "narrow_held", "wide_held"):
            values = np.array([e[key] for e in chosen], dtype=float)
            parts.append(f"{key} {np.median(values):g} [{values.min():g}, {values.max():g}]")
        lines.append(f"{pair[0]} / {pair[1]} ({len(chosen)}), median [range]: " + ", ".join(parts))
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="tools/stop_short.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("run", type=Path, help="a dlo-train run directory with best_policy.pt and config.yaml")
    parser.add_argument("--episodes", type=int, default=100, help="episodes (default 100)")
    parser.add_argument("--seed", type=int, default=5000, help="first episode seed (default 5000, the held-out test's)")
    parser.add_argument("--json", type=Path, help="also write every episode's end to this JSON file")
    args = parser.parse_args(argv)
    if not (args.run / "best_policy.pt").is_file():
        parser.error(f"{args.run}/best_policy.pt not found (a dlo-train run directory?)")
    if args.episodes < 1:
        parser.error(f"--episodes must be >= 1, got {args.episodes}")
    torch.set_num_threads(1)
    ends = episode_ends(args.run, args.episodes, args.seed)
    print(describe(ends))
    if args.json:
        args.json.write_text(json.dumps({"run": str(args.run), "seed": args.seed, "episodes": ends}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
