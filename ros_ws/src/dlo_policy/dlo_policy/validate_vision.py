"""Image-based vision distillation vs its particle ground truth over many random simulator states.

`dlo-validate-vision [--num-envs 32] [--rounds 2] [--steps 60] [--seed 1000]`

States: seeded episodes (rounds x num-envs of them, seeds seed ..) driven by a mix of the oracle
follower and random actions (half the environments get random perturbations), sampled every
control step for `--steps` steps. For every state: visual_pose(sim.render(), ...) vs
visual_pose_ground_truth(positions). Prints the agreement of v_V and, where both see the cable, the
error distribution (median, 90th, 99th percentile of |error|, and the bias) of q_V, theta_V [rad]
and y_V [m]; a JSON line last. The defaults give 3,840 states (docs/RESULTS.md). In dlo_policy, not
dlo_perception: it drives the gym environment with the scripted policies.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Optional, Sequence

import numpy as np
from dlo_common.console import console_main

from .cli import OneLineErrorParser

FIELDS = ("visible", "confidence", "angle", "y")


def collect_poses(num_envs: int, rounds: int, steps: int, seed: int) -> tuple[dict, dict]:
    """(from the image, ground truth): each field of FIELDS over every sampled state, concatenated."""
    from dlo_interface.world import GRIPPER_HEIGHT
    from dlo_perception.vision import visual_pose, visual_pose_ground_truth

    from .env import make_vec_env
    from .scripted import OracleFollow, RandomPolicy

    env = make_vec_env(num_envs, modalities="K", seed=seed)
    oracle, random = OracleFollow(), RandomPolicy(seed=seed)
    rng = np.random.default_rng(seed)
    image_poses, true_poses = [], []
    try:
        for round_index in range(rounds):
            observation, _ = env.reset(seed=seed + round_index * num_envs)
            noisy = rng.uniform(size=num_envs) < 0.5  # half the envs get random perturbations
            for _ in range(steps):
                sim = env.sim
                gripper = sim.gripper_state()
                image_poses.append(visual_pose(sim.render(), sim.camera, gripper[:, :2], GRIPPER_HEIGHT))
                true_poses.append(visual_pose_ground_truth(sim.positions(), sim.num_particles, gripper[:, :2]))
                actions = oracle(observation, env)
                actions[noisy] = 0.5 * actions[noisy] + 0.5 * random(observation, env)[noisy]
                observation, *_ = env.step(actions)
    finally:
        env.close()
    image = {k: np.concatenate([getattr(p, k) for p in image_poses]) for k in FIELDS}
    truth = {k: np.concatenate([getattr(p, k) for p in true_poses]) for k in FIELDS}
    return image, truth


def compare(image: dict, truth: dict) -> dict:
    """v_V agreement and, over the states where both see the cable, the error statistics per quantity
    (None where no state has both)."""
    both = image["visible"] & truth["visible"]
    result = {
        "states": int(len(both)),
        "visible_agreement": float(np.mean(image["visible"] == truth["visible"])),
        "visible_false_positive": float(np.mean(image["visible"] & ~truth["visible"])),
        "visible_false_negative": float(np.mean(~image["visible"] & truth["visible"])),
        "both_visible": int(both.sum()),
    }
    for key in FIELDS[1:]:
        error = image[key][both] - truth[key][both]
        if not len(error):
            result[key] = None
            continue
        p50, p90, p99 = np.percentile(np.abs(error), [50, 90, 99])
        result[key] = {"median": float(p50), "p90": float(p90), "p99": float(p99), "bias": float(error.mean())}
    return result


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineErrorParser(
        prog="dlo-validate-vision", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--num-envs", type=int, default=32, help="environments stepped together (default 32)")
    parser.add_argument("--rounds", type=int, default=2, help="batches of num-envs episodes (default 2)")
    parser.add_argument("--steps", type=int, default=60, help="control steps sampled per episode (default 60)")
    parser.add_argument("--seed", type=int, default=1000, help="first episode seed (default 1000)")
    return parser


@console_main("dlo-validate-vision")
def main(argv: Optional[Sequence[str]] = None) -> int:
    args = build_parser().parse_args(argv)
    if min(args.num_envs, args.rounds, args.steps) < 1:
        print("dlo-validate-vision: error: --num-envs, --rounds and --steps must be >= 1", file=sys.stderr)
        return 2
    result = compare(*collect_poses(args.num_envs, args.rounds, args.steps, args.seed))
    print(
        f"states {result['states']}, v_V agreement {100 * result['visible_agreement']:.1f}% "
        f"(image-only {100 * result['visible_false_positive']:.1f}%, truth-only "
        f"{100 * result['visible_false_negative']:.1f}%), both visible {result['both_visible']}"
    )
    print("| quantity | median abs error | 90th pct | 99th pct | mean error (bias) |")
    print("|---|---|---|---|---|")
    for key, unit in (("confidence", ""), ("angle", " rad"), ("y", " m")):
        s = result[key]
        if s is None:
            print(f"| {key}{unit} | - | - | - | - |")
        else:
            print(f"| {key}{unit} | {s['median']:.4f} | {s['p90']:.4f} | {s['p99']:.4f} | {s['bias']:+.4f} |")
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
