#!/usr/bin/env python3
"""Benchmark of the dlo_sim Taichi rope against MuJoCo's cable; prints a JSON line last.

One env-step = 0.01 s of simulated time with full physics (stretch, bending, gravity, table
friction, self-collision, finger capsules, grip law). Ours is timed through the public API,
``RopeSim.step`` (one action = 8 env-steps in one kernel launch), with random actions, rendering
off and on (``render()`` once per action, as the policy sees it), for batch sizes 1, 16, 64, 256.
No resets happen inside the timed windows (every env is reset before timing; the actions keep the
closure >= 0.5). Each figure is the best of ``--repeats`` windows. The machine is shared, so the
process's CPU time is recorded too: ``cpu_utilisation`` (CPU seconds per wall second; up to the
thread count when the cores are free) and env-steps per CPU-second (``per_cpu_second``).

Peer: MuJoCo (>= 3.3, < 4) ``composite type="cable"`` of 50 segments (elasticity.cable plugin),
first body fixed 0.1 m above a floor, timestep 0.01 / 8 s (8 MuJoCo steps = 1 env-step, as our
XPBD runs 4 sub-steps), self-collision on, given its fastest setting here: ``jacobian="dense"``
with ``solver="CG"`` (about 3x the default sparse/Newton on this cable).

Usage: python benchmarks/run.py sim -- [--seconds 2] [--repeats 3] [--batches 1 16 64 256]
"""

import argparse
import json
import os
import time

import numpy as np
from dlo_interface.simulator import make_simulator
from dlo_interface.world import DT, SUBSTEPS_PER_ACTION

MUJOCO_CABLE = """
<mujoco model="cable">
  <extension><plugin plugin="mujoco.elasticity.cable"/></extension>
  <option timestep="{timestep}" jacobian="dense" solver="CG"/>
  <worldbody>
    <geom type="plane" size="1 1 0.1"/>
    <composite type="cable" curve="s" count="51 1 1" size="0.2537" offset="-0.25 0 0.1" initial="none">
      <plugin plugin="mujoco.elasticity.cable">
        <config key="twist" value="1e6"/>
        <config key="bend" value="2e6"/>
        <config key="vmax" value="0"/>
      </plugin>
      <joint kind="main" damping="0.01"/>
      <geom type="capsule" size="0.004" density="1000"/>
    </composite>
  </worldbody>
</mujoco>
"""


def time_ours(sim, seconds: float, render: bool) -> tuple:
    """(env-steps per wall second, per CPU second) of ``RopeSim.step`` (+ ``render`` per action if asked)."""
    num_envs = sim.num_envs
    sim.reset(np.arange(num_envs))
    rng = np.random.default_rng(0)
    acts = rng.uniform(-1.0, 1.0, (64, num_envs, 3)).astype(np.float32)
    acts[..., 2] = rng.uniform(0.0, 1.0, (64, num_envs))  # closure 0.5..1: the cable stays in hand
    sim.step(acts[0])
    if render:
        sim.render()
    actions_done = 0
    start, cpu_start = time.perf_counter(), time.process_time()
    while True:
        for _ in range(8):
            sim.step(acts[actions_done % 64])
            if render:
                sim.render()
            actions_done += 1
        elapsed = time.perf_counter() - start
        if elapsed > seconds:
            steps = num_envs * actions_done * SUBSTEPS_PER_ACTION
            return steps / elapsed, steps / (time.process_time() - cpu_start)


def time_mujoco(seconds: float) -> float:
    """MuJoCo cable env-steps (0.01 s = 8 steps) per second, single environment."""
    import mujoco

    model = mujoco.MjModel.from_xml_string(MUJOCO_CABLE.format(timestep=DT / 8))
    data = mujoco.MjData(model)
    steps = 0
    start = time.perf_counter()
    while True:
        for _ in range(800):
            mujoco.mj_step(model, data)
        steps += 800
        elapsed = time.perf_counter() - start
        if elapsed > seconds:
            return steps / 8 / elapsed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=2.0, help="timing window per measurement [s]")
    parser.add_argument("--repeats", type=int, default=3, help="timing windows per measurement; the best is kept")
    parser.add_argument("--batches", type=int, nargs="+", default=[1, 16, 64, 256])
    args = parser.parse_args()

    per_batch = {}
    for n in args.batches:
        sim = make_simulator(n, "taichi").sim  # the Taichi rope (dlo_sim.RopeSim), built as the gym env builds it
        off = max(time_ours(sim, args.seconds, render=False) for _ in range(args.repeats))
        on = max(time_ours(sim, args.seconds, render=True) for _ in range(args.repeats))
        per_batch[n] = {
            "render_off": round(off[0]),
            "render_on": round(on[0]),
            "render_overhead": round(off[0] / on[0] - 1.0, 3),
            "per_cpu_second_render_off": round(off[1]),
            "cpu_utilisation": round(off[0] / off[1], 2),
        }
        print(
            f"batch {n:4d}: {off[0]:10.0f} env-steps/s render off, {on[0]:10.0f} render on; "
            f"{off[1]:10.0f} per CPU-second, CPU utilisation {off[0] / off[1]:.2f}",
            flush=True,
        )
    mujoco_rate = max(time_mujoco(args.seconds) for _ in range(args.repeats))
    print(f"mujoco cable (50 segments, dense/CG, 8 x 1.25 ms per env-step): {mujoco_rate:.0f} env-steps/s", flush=True)

    largest = max(args.batches)
    single = per_batch.get(1, {}).get("render_off")
    result = {
        "batched_env_steps_per_s": max(v["render_off"] for v in per_batch.values()),
        "batched_num_envs": max(per_batch, key=lambda n: per_batch[n]["render_off"]),
        "single_env_steps_per_s": single,
        "mujoco_single_env_steps_per_s": round(mujoco_rate, 1),
        "ratio_vs_mujoco_single": round(single / mujoco_rate, 1) if single else None,
        "render_overhead": per_batch[largest]["render_overhead"],
        "render_overhead_batch": largest,
        "per_batch": per_batch,
        "mujoco_settings": "composite cable 50 segments, jacobian=dense, solver=CG, timestep=0.00125",
        "cpu_threads": os.cpu_count(),
        "load_average": os.getloadavg(),
        "note": "shared machine: wall figures depend on the load; best of --repeats windows",
    }
    print(json.dumps(result))


if __name__ == "__main__":
    main()
