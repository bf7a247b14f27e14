"""How far the running observation normaliser moved during a run, from its replay buffer.

`dlo-normalizer-drift RUN_DIR [RUN_DIR ...] [--every 1000]`

A full checkpoint.pt holds every observation the agent stored (replay buffer, 100k > the run's
steps) in order, so the running mean m(t) and std s(t) the `running` scaling used at step t are
the statistics of obs[:t]. For each window (t - every, t] this prints the largest shift of the
normalised value of a fixed observation, max_i |m_i(t) - m_i(t - every)| / s_i(t) (in units of the
current std: how far the networks' inputs moved under them), the dimension it happened in, and
the run's hold-the-end rate over the evaluations of that window (eval.csv), so collapses can be
set against drift. A JSON line per run comes last. Exit 2 with one line when a run directory lacks
its checkpoint.pt, config.yaml or eval.csv or they cannot be read.
"""

from __future__ import annotations

import argparse
import json
import pickle
import sys
from pathlib import Path
from typing import Optional, Sequence

import numpy as np
from dlo_common.console import console_main

from .cli import OneLineErrorParser
from .rundir import CHECKPOINT_FILE, CONFIG_FILE, EVAL_FILE, read_config, read_eval_rows


class DriftError(Exception):
    """A run directory that cannot be read; the message is one line."""


def drift(run: Path, every: int) -> dict:
    """The windows of one run directory (see the module docstring); DriftError when it cannot be read."""
    import torch

    from .config import ConfigError
    from .observation import observation_labels

    for name in (CHECKPOINT_FILE, CONFIG_FILE, EVAL_FILE):
        if not (run / name).is_file():
            raise DriftError(f"{run / name} not found (a dlo-train run directory with its full checkpoint)")
    try:
        state = torch.load(run / CHECKPOINT_FILE, map_location="cpu", weights_only=True)
        steps = int(state["counters"]["env_steps"])
        obs = state["replay"]["obs"][:steps].double().numpy()
    except (OSError, RuntimeError, ValueError, KeyError, TypeError, IndexError, pickle.UnpicklingError) as error:
        raise DriftError(
            f"{run / CHECKPOINT_FILE}: not a full dlo-train checkpoint with its replay buffer "
            f"({type(error).__name__}: {str(error).splitlines()[0] if str(error) else ''})"
        ) from None
    try:
        config = read_config(run)
        labels = observation_labels(config.modalities, previous_action=bool(config.env_options.get("previous_action")))
    except (ConfigError, ValueError, OSError) as error:
        raise DriftError(f"{run / CONFIG_FILE}: {error}") from None
    rows = [r for r in read_eval_rows(run) if r.get("tested_without", "") == ""]
    windows = []
    for t in range(2 * every, steps + 1, every):
        before, now = obs[: t - every], obs[:t]
        std = now.std(0) + 1e-12
        shift = np.abs(now.mean(0) - before.mean(0)) / std
        i = int(np.argmax(shift))
        hold = [float(r["hold_the_end"]) for r in rows if t - every < int(r["step"]) <= t]
        windows.append(
            {
                "step": t,
                "shift": float(shift[i]),
                "dimension": labels[i],
                "hold_the_end": float(np.mean(hold)) if hold else float("nan"),
            }
        )
    return {"run": str(run), "steps": steps, "every": every, "windows": windows}


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineErrorParser(
        prog="dlo-normalizer-drift", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("runs", nargs="+", type=Path, metavar="RUN_DIR", help="dlo-train run directories with checkpoint.pt")
    parser.add_argument("--every", type=int, default=1000, help="window length [env steps] (default 1000)")
    return parser


@console_main("dlo-normalizer-drift")
def main(argv: Optional[Sequence[str]] = None) -> int:
    args = build_parser().parse_args(argv)
    if args.every < 1:
        print(f"dlo-normalizer-drift: error: --every must be >= 1, got {args.every}", file=sys.stderr)
        return 2
    results = []
    for run in args.runs:
        try:
            result = drift(run, args.every)
        except DriftError as error:
            print(f"dlo-normalizer-drift: error: {error}", file=sys.stderr)
            return 2
        results.append(result)
        print(f"{run}: window end, largest mean shift [current std] (dimension), hold the end in the window")
        for w in result["windows"]:
            print(f"  {w['step']:>6} {w['shift']:6.3f} ({w['dimension']:<7}) {w['hold_the_end']:5.0%}")
    for result in results:
        print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
