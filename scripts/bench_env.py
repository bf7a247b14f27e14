#!/usr/bin/env python3
"""Env-steps/s of the full observation pipeline vs the bare simulator, for N = 1, 10, 64.

Full pipeline = CableFollowingVecEnv.step with modalities "All": sim.step (8 x 0.01 s) + held set
+ render + tactile + vision + task + auto-reset. Bare = RopeSim.step alone with the same actions.
One env-step = one control step of one environment. Overhead = 1 - full / bare (fraction of time
the pipeline adds). Usage: python scripts/bench_env.py [--steps 60] [--sizes 1,10,64]
The JSON line last has env_steps_per_s {N: full}, bare_steps_per_s {N: bare}, obs_pipeline_overhead
{N: fraction} and obs_pipeline_overhead_max.
"""

import argparse
import json
import os
import time

import numpy as np

from dlo_policy.env import make_vec_env


def timed(step, steps):
    """Seconds for ``steps`` calls of ``step`` after 3 warm-up calls."""
    for _ in range(3):
        step()
    start = time.perf_counter()
    for _ in range(steps):
        step()
    return time.perf_counter() - start


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=60)
    parser.add_argument("--sizes", default="1,10,64")
    args = parser.parse_args()
    full, bare, overhead = {}, {}, {}
    for n in (int(s) for s in args.sizes.split(",")):
        env = make_vec_env(n, modalities="All", seed=0)
        env.reset()
        actions = np.tile(np.array([0.6, 0.0, 0.4], np.float32), (n, 1))
        full_s = timed(lambda: env.step(actions), args.steps)
        env.reset(seed=0)
        bare_s = timed(lambda: env.sim.step(actions), args.steps)
        full[n], bare[n] = n * args.steps / full_s, n * args.steps / bare_s
        overhead[n] = 1.0 - full[n] / bare[n]
        print(f"N={n:3d}: full {full[n]:8.0f} env-steps/s, bare sim {bare[n]:8.0f} env-steps/s, "
              f"overhead {100 * overhead[n]:.1f}%", flush=True)
    print(json.dumps({"env_steps_per_s": full, "bare_steps_per_s": bare, "obs_pipeline_overhead": overhead,
                      "obs_pipeline_overhead_max": max(overhead.values()), "steps": args.steps,
                      "cpus": os.cpu_count(), "note": "shared machine: timings are noisy"}))


if __name__ == "__main__":
    main()
