#!/usr/bin/env python3
"""How far the running observation normaliser moved during a run, from its replay buffer.

Usage: python scripts/normalizer_drift.py RUN_DIR [RUN_DIR ...] [--every 1000]

A full checkpoint.pt holds every observation the agent stored (replay buffer, 100k > the run's
steps) in order, so the running mean m(t) and std s(t) the `running` scaling used at step t are
the statistics of obs[:t]. For each window (t - every, t] this prints the largest shift of the
normalised value of a fixed observation, max_i |m_i(t) - m_i(t - every)| / s_i(t) (in units of the
current std: how far the networks' inputs moved under them), the dimension it happened in, and
the run's hold-the-end rate over the evaluations of that window (eval.csv), so collapses can be
set against drift. A JSON line per run comes last.
"""
import argparse
import csv
import json
import sys
from pathlib import Path

import numpy as np
import torch

from dlo_policy.config import load_config
from dlo_policy.observation import observation_labels


def drift(run: Path, every: int) -> dict:
    state = torch.load(run / "checkpoint.pt", map_location="cpu", weights_only=True)
    steps = state["counters"]["env_steps"]
    obs = state["replay"]["obs"][:steps].double().numpy()
    labels = observation_labels(load_config(run / "config.yaml").modalities)
    with (run / "eval.csv").open(newline="") as f:
        rows = [r for r in csv.DictReader(f) if r["tested_without"] == ""]
    windows = []
    for t in range(2 * every, steps + 1, every):
        before, now = obs[:t - every], obs[:t]
        std = now.std(0) + 1e-12
        shift = np.abs(now.mean(0) - before.mean(0)) / std
        i = int(np.argmax(shift))
        hold = [float(r["hold_the_end"]) for r in rows if t - every < int(r["step"]) <= t]
        windows.append({"step": t, "shift": float(shift[i]), "dimension": labels[i],
                        "hold_the_end": float(np.mean(hold)) if hold else float("nan")})
    return {"run": str(run), "steps": steps, "every": every, "windows": windows}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0], epilog=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("runs", nargs="+", type=Path, help="dlo-train run directories with checkpoint.pt")
    parser.add_argument("--every", type=int, default=1000, help="window length [env steps] (default 1000)")
    args = parser.parse_args()
    results = []
    for run in args.runs:
        if not (run / "checkpoint.pt").exists():
            print(f"normalizer_drift: {run}/checkpoint.pt not found", file=sys.stderr)
            return 2
        result = drift(run, args.every)
        results.append(result)
        print(f"{run}: window end, largest mean shift [current std] (dimension), hold the end in the window")
        for w in result["windows"]:
            print(f"  {w['step']:>6} {w['shift']:6.3f} ({w['dimension']:<7}) {w['hold_the_end']:5.0%}")
    for result in results:
        print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
