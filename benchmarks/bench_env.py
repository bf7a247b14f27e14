#!/usr/bin/env python3
"""Env-steps/s of the full observation pipeline vs the bare simulator, for N = 1, 10, 64.

Full pipeline = CableFollowingVecEnv.step with modalities "All": sim.step (8 x 0.01 s) + the
snapshot read-back (positions, held set, gripper, render) + tactile + vision + task + auto-reset.
Bare = RopeSim.step alone with the same actions, and ``RopeSim.reset`` of the same environments,
with the same seeds, at the same steps as the full arm's auto-resets: both arms run the same
physics, the same number of resets (printed as "resets"). One env-step = one control step of one
environment. Overhead = t_full / t_bare - 1, the time the pipeline adds on top of the bare
simulator. Each arm is timed ``--repeats`` times from the same start state; the best is kept.
Usage: python benchmarks/run.py env -- [--steps 60] [--repeats 3] [--sizes 1,10,64] [--action 0.1,0,0.6]
(the default action ends no episode, so both arms run without resets; --action 0.5,0,0.6 slides
off the end and gives resets, the same in both arms).
The JSON line last has env_steps_per_s {N: full}, bare_steps_per_s {N: bare},
obs_pipeline_overhead {N: fraction}, obs_pipeline_overhead_max, resets {N: count per arm} and the
load average it ran under.
"""

import argparse
import json
import os
import time

import numpy as np
from dlo_policy.env import make_vec_env

ACTION = "0.1,0,0.6"  # slide right at 0.25 mm per 0.01 s, closure 0.8: no episode ends in 63 steps


def full_run(env, actions):
    """Seconds of ``env.step`` over ``actions`` from the seed-0 start, and the done mask of every step."""
    env.reset(seed=0)
    dones = []
    start = time.perf_counter()
    for a in actions:
        _, _, terminated, truncated, _ = env.step(a)
        dones.append(terminated | truncated)
    return time.perf_counter() - start, dones


def bare_run(env, actions, dones):
    """Seconds of ``sim.step`` over ``actions`` from the same start, resetting the envs the full arm
    auto-reset, with the same seeds, after the same steps."""
    env.reset(seed=0)
    sim, next_seed = env.sim, env.num_envs
    start = time.perf_counter()
    for a, done in zip(actions, dones):
        sim.step(a)
        if done.any():
            ids = np.flatnonzero(done)
            sim.reset(next_seed + np.arange(len(ids)), ids)
            next_seed += len(ids)
    return time.perf_counter() - start


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=60)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--sizes", default="1,10,64")
    parser.add_argument("--action", default=ACTION, help="dx,dy,c in [-1, 1], the same every step")
    args = parser.parse_args()
    action = [float(a) for a in args.action.split(",")]
    full, bare, overhead, resets = {}, {}, {}, {}
    for n in (int(s) for s in args.sizes.split(",")):
        env = make_vec_env(n, modalities="All", seed=0)
        actions = [np.tile(np.array(action, np.float32), (n, 1))] * args.steps
        _, dones = full_run(env, actions[:3])  # compile every kernel
        bare_run(env, actions[:3], dones)
        full_s, bare_s = np.inf, np.inf
        for _ in range(args.repeats):
            seconds, dones = full_run(env, actions)
            full_s = min(full_s, seconds)
            bare_s = min(bare_s, bare_run(env, actions, dones))
        full[n], bare[n] = n * args.steps / full_s, n * args.steps / bare_s
        overhead[n] = full_s / bare_s - 1.0
        resets[n] = int(np.sum(dones))
        print(
            f"N={n:3d}: full {full[n]:8.0f} env-steps/s, bare sim {bare[n]:8.0f} env-steps/s, "
            f"overhead {100 * overhead[n]:.1f}% on top, {resets[n]} resets in each arm",
            flush=True,
        )
    print(
        json.dumps(
            {
                "env_steps_per_s": full,
                "bare_steps_per_s": bare,
                "obs_pipeline_overhead": overhead,
                "obs_pipeline_overhead_max": max(overhead.values()),
                "resets": resets,
                "overhead_definition": "t_full / t_bare - 1, same resets in both arms",
                "action": action,
                "steps": args.steps,
                "repeats": args.repeats,
                "cpus": os.cpu_count(),
                "load_average": os.getloadavg(),
                "note": "shared machine: timings are noisy",
            }
        )
    )


if __name__ == "__main__":
    main()
