#!/usr/bin/env python3
"""Image-based vision distillation vs its particle ground truth over many random simulator states.

States: seeded episodes driven by a mix of the oracle follower and random actions, sampled every
control step. For every state: visual_pose(sim.render(), ...) vs visual_pose_ground_truth(positions).
Prints the agreement of v_V and, where both see the cable, the error distribution (median, 90th,
99th percentile of |error|) of q_V, theta_V [rad] and y_V [m]; JSON line last.
Usage: python scripts/validate_vision.py [--episodes 64] [--num-envs 32] [--steps 60] [--seed 1000]
"""

import argparse
import json

import numpy as np

from dlo_perception.vision import visual_pose, visual_pose_ground_truth
from dlo_policy.env import make_vec_env
from dlo_policy.scripted import OracleFollow, RandomPolicy
from dlo_sim.config import GRIPPER_HEIGHT


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--num-envs", type=int, default=32)
    parser.add_argument("--rounds", type=int, default=2, help="batches of num-envs episodes")
    parser.add_argument("--steps", type=int, default=60, help="control steps per episode sampled")
    parser.add_argument("--seed", type=int, default=1000)
    args = parser.parse_args()
    env = make_vec_env(args.num_envs, modalities="K", seed=args.seed)
    oracle, random = OracleFollow(), RandomPolicy(seed=args.seed)
    rng = np.random.default_rng(args.seed)
    image_poses, true_poses = [], []
    for round_index in range(args.rounds):
        observation, _ = env.reset(seed=args.seed + round_index * args.num_envs)
        noisy = rng.uniform(size=args.num_envs) < 0.5  # half the envs get random perturbations
        for _ in range(args.steps):
            sim = env.sim
            gripper = sim.gripper_state()
            image_poses.append(visual_pose(sim.render(), sim.camera, gripper[:, :2], GRIPPER_HEIGHT))
            true_poses.append(visual_pose_ground_truth(sim.positions(), sim.num_particles, gripper[:, :2]))
            actions = oracle(observation, env)
            actions[noisy] = 0.5 * actions[noisy] + 0.5 * random(observation, env)[noisy]
            observation, *_ = env.step(actions)
    image = {k: np.concatenate([getattr(p, k) for p in image_poses]) for k in ("visible", "confidence", "angle", "y")}
    truth = {k: np.concatenate([getattr(p, k) for p in true_poses]) for k in ("visible", "confidence", "angle", "y")}
    both = image["visible"] & truth["visible"]
    result = {"states": int(len(both)), "visible_agreement": float(np.mean(image["visible"] == truth["visible"])),
              "visible_false_positive": float(np.mean(image["visible"] & ~truth["visible"])),
              "visible_false_negative": float(np.mean(~image["visible"] & truth["visible"])),
              "both_visible": int(both.sum())}
    print(f"states {result['states']}, v_V agreement {100 * result['visible_agreement']:.1f}% "
          f"(image-only {100 * result['visible_false_positive']:.1f}%, truth-only "
          f"{100 * result['visible_false_negative']:.1f}%), both visible {result['both_visible']}")
    print("| quantity | median abs error | 90th pct | 99th pct | mean error (bias) |")
    print("|---|---|---|---|---|")
    for key, unit in (("confidence", ""), ("angle", " rad"), ("y", " m")):
        error = image[key][both] - truth[key][both]
        p50, p90, p99 = np.percentile(np.abs(error), [50, 90, 99])
        result[key] = {"median": p50, "p90": p90, "p99": p99, "bias": float(error.mean())}
        print(f"| {key}{unit} | {p50:.4f} | {p90:.4f} | {p99:.4f} | {error.mean():+.4f} |")
    print(json.dumps(result))


if __name__ == "__main__":
    main()
