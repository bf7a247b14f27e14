#!/usr/bin/env python3
"""Which randomised families cut a domain-randomised run's training episodes short.

    tools/randomised_effects.py RUN_DIR [--from-step N] [--json OUT]

Reads RUN_DIR/randomised.csv (one row per training episode: the env step it ended on and the magnitude of each
randomised family; written by dlo-train with ``env_options.randomise``), takes each episode's length as the steps
since the previous episode ended, keeps the episodes that ended after ``--from-step`` (default: half the run's last
step, where the policy has learned what it will) and fits by least squares

    length = b0 + sum_f b_f * m_f,    m_f = the family's magnitude scaled to [0, 1] over its range

(the range from the run's config.yaml ``env_options.randomise``). b_f is the change in episode length (control
steps; the horizon is 150) from the low to the high end of family f's range, the others held; also fitted for the
share of episodes that run the whole horizon. Prints one row per family, most harmful first, and last one JSON line.
A diagnostic for docs/RESULTS.md, not a product command.
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path

import numpy as np
import yaml
from dlo_interface.perturbations import parse_ranges
from dlo_interface.task import HORIZON


def effects(run: Path, from_step: int | None = None) -> dict:
    rows = list(csv.DictReader((run / "randomised.csv").open()))
    if not rows:
        raise ValueError(f"{run / 'randomised.csv'}: no episodes")
    # as the run read them: {family: [low, high]} or the text "observation_delay=0:1,..." of a command line
    ranges = parse_ranges(yaml.safe_load((run / "config.yaml").read_text())["env_options"]["randomise"])
    families = [name for name in rows[0] if name in ranges]
    ends = np.array([int(r["step"]) for r in rows])
    lengths = np.diff(np.concatenate([[0], ends]))
    start = ends[-1] // 2 if from_step is None else from_step
    keep = ends > start
    scaled = np.array([[(float(r[f]) - ranges[f][0]) / max(ranges[f][1] - ranges[f][0], 1e-12) for f in families] for r in rows])[
        keep
    ]
    design = np.c_[np.ones(int(keep.sum())), scaled]
    fits = {}
    for name, y in (("length", lengths[keep].astype(float)), ("full_horizon", (lengths[keep] >= HORIZON).astype(float))):
        coef, *_ = np.linalg.lstsq(design, y, rcond=None)
        fits[name] = {
            "mean": float(y.mean()),
            "intercept": float(coef[0]),
            **{f: float(c) for f, c in zip(families, coef[1:], strict=True)},
        }
    return {"run": str(run), "episodes": int(keep.sum()), "from_step": int(start), "families": families, "fits": fits}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run", type=Path, help="a dlo-train run directory with randomised.csv and config.yaml")
    parser.add_argument("--from-step", type=int, default=None, help="episodes that ended after this step (default: half the run)")
    parser.add_argument("--json", type=Path, default=None, help="also write the result here")
    args = parser.parse_args(argv)
    try:
        result = effects(args.run, args.from_step)
    except (OSError, KeyError, ValueError) as error:
        print(f"randomised_effects: {error}", file=sys.stderr)
        return 2
    fit = result["fits"]
    print(
        f"{result['episodes']} training episodes ending after step {result['from_step']}: length "
        f"{fit['length']['mean']:.1f} steps on average, {fit['full_horizon']['mean']:.0%} run the whole horizon"
    )
    print("family: change from the low to the high end of its range, in episode length (steps) / share of full episodes")
    for f in sorted(result["families"], key=lambda f: fit["length"][f]):
        print(f"  {f:24s} {fit['length'][f]:+7.1f} / {fit['full_horizon'][f]:+.2f}")
    if args.json:
        args.json.write_text(json.dumps(result, indent=1) + "\n")
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
