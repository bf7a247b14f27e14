#!/usr/bin/env python3
"""SAC gradient updates per second: ours vs Stable-Baselines3, and a matmul roofline (JSON last).

    python benchmarks/run.py sac -- [--threads 2] [--updates 100] [--rounds 3] [--device cpu|cuda|auto] [--no-sb3]

Same problem for both: obs dim 9, action dim 3, MLPs 2 x 1024 ReLU, batch 128, replay filled with
learning_starts = 1000 random transitions, one gradient step per call, torch.set_num_threads
equal. SB3 gets its best matching settings: train_freq=1, gradient_steps=1, target_update_interval=2
(our schedule; its actor is updated every step, which SB3 does not let one change), ent_coef
auto_0.1, fp32. Timed: SB3's `train(gradient_steps=N)` and our `update()` x N, no env stepping.
Roofline: the GEMM FLOPs of one of our updates (forward + backward, counted layer by layer)
divided by the speed of plain torch.mm at the dominant shape (128 x 1024 @ 1024 x 1024).
Rounds alternate the three measurements and the median is reported; on a shared machine the
numbers are noisy, the per-round values are printed too.

--device cuda puts everything on the GPU (our networks, replay buffer and sampling; SB3's
policy and buffer sampling; the roofline's torch.mm), with a CUDA synchronise before each clock
read; "auto" is cuda when torch sees one. --device cuda without a CUDA device: exit 2, one line.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from typing import Callable

import gymnasium as gym
import numpy as np
import torch
from dlo_policy.config import SACConfig
from dlo_policy.sac import SAC, resolve_device

OBS_DIM, ACT_DIM, HIDDEN, BATCH, LEARNING_STARTS = 9, 3, 1024, 128, 1000


def gemm_flops(layers: list[tuple[int, int]], batch: int) -> int:
    return sum(2 * batch * fan_in * fan_out for fan_in, fan_out in layers)


def flops_per_update(config: SACConfig) -> float:
    """Matmul FLOPs of one `SAC.update()` (elementwise work and Adam not counted)."""
    b, h = config.batch_size, config.hidden_sizes
    actor = list(zip((OBS_DIM, *h), (*h, 2 * ACT_DIM)))
    critic = list(zip((OBS_DIM + ACT_DIM, *h), (*h, 1)))
    f_actor, f_q = gemm_flops(actor, b), gemm_flops(critic, b)
    first_actor, first_q = gemm_flops(actor[:1], b), gemm_flops(critic[:1], b)
    critic_step = (
        f_actor
        + 2 * f_q  # target: actor on s', two target critics
        + 2 * f_q  # online critics
        + 2 * (f_q + f_q - first_q)
    )  # backward: weight grads + input grads (not for the input layer)
    actor_step = (
        f_actor
        + 2 * f_q  # actor on s, critics on (s, a~)
        + 2 * f_q  # critics backward to the action only (weights frozen)
        + f_actor
        + f_actor
        - first_actor
    )  # actor backward
    return critic_step + actor_step / config.policy_update_every


def fill(add, rng: np.random.Generator, n: int) -> None:
    for _ in range(n):
        add(
            rng.normal(size=OBS_DIM).astype(np.float32),
            rng.uniform(-1, 1, ACT_DIM).astype(np.float32),
            float(rng.normal()),
            rng.normal(size=OBS_DIM).astype(np.float32),
            bool(rng.random() < 0.05),
        )


def synchronize(device: torch.device) -> None:
    """Wait for the device's queued work (CUDA runs asynchronously): before reading the clock."""
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def ours(device: torch.device) -> tuple[Callable[[int], float], SACConfig]:
    """A timer of N of our updates on a filled replay buffer, and the agent's config."""
    config = SACConfig()
    agent = SAC(OBS_DIM, -np.ones(ACT_DIM), np.ones(ACT_DIM), config, seed=0, device=device)
    fill(agent.store, np.random.default_rng(0), LEARNING_STARTS)

    def run(n: int) -> float:
        synchronize(device)
        start = time.perf_counter()
        for _ in range(n):
            agent.update()
        synchronize(device)
        return n / (time.perf_counter() - start)

    return run, config


class BoxEnv(gym.Env):
    observation_space = gym.spaces.Box(-np.inf, np.inf, (OBS_DIM,), np.float32)
    action_space = gym.spaces.Box(-1.0, 1.0, (ACT_DIM,), np.float32)

    def reset(self, *, seed=None, options=None):
        return np.zeros(OBS_DIM, np.float32), {}

    def step(self, action):
        return np.zeros(OBS_DIM, np.float32), 0.0, False, False, {}


def sb3(device: torch.device) -> Callable[[int], float]:
    """A timer of N SB3 gradient steps (`SAC.train`) on a filled replay buffer."""
    from stable_baselines3 import SAC as SB3SAC
    from stable_baselines3.common.logger import configure

    model = SB3SAC(
        "MlpPolicy",
        BoxEnv(),
        learning_rate=1e-3,
        buffer_size=100_000,
        learning_starts=LEARNING_STARTS,
        batch_size=BATCH,
        tau=0.01,
        gamma=0.99,
        train_freq=1,
        gradient_steps=1,
        ent_coef="auto_0.1",
        target_update_interval=2,
        policy_kwargs=dict(net_arch=[HIDDEN, HIDDEN]),
        device=device,
        seed=0,
    )
    model.set_logger(configure(None, []))
    rng = np.random.default_rng(0)
    fill(
        lambda o, a, r, o2, d: model.replay_buffer.add(o[None], o2[None], a[None], np.array([r]), np.array([d]), [{}]),
        rng,
        LEARNING_STARTS,
    )

    def run(n: int) -> float:
        synchronize(device)
        start = time.perf_counter()
        model.train(gradient_steps=n, batch_size=BATCH)
        synchronize(device)
        return n / (time.perf_counter() - start)

    return run


def matmul_gflops(device: torch.device, seconds: float = 1.0) -> float:
    a, w = torch.randn(BATCH, HIDDEN, device=device), torch.randn(HIDDEN, HIDDEN, device=device)
    for _ in range(10):
        torch.mm(a, w)
    synchronize(device)
    n, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        for _ in range(20):
            torch.mm(a, w)
        n += 20
        synchronize(device)
    return 2 * BATCH * HIDDEN * HIDDEN * n / (time.perf_counter() - start) / 1e9


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--updates", type=int, default=100, help="gradient updates per timed measurement")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--device", default="cpu", help="cpu (default), cuda or auto (cuda if torch sees one)")
    parser.add_argument("--no-sb3", action="store_true", help="time only ours and the roofline")
    args = parser.parse_args()
    try:
        device = resolve_device(args.device)
    except ValueError as error:
        print(f"bench_sac: error: {error}", file=sys.stderr)
        return 2
    torch.set_num_threads(args.threads)

    run_ours, config = ours(device)
    run_sb3 = None if args.no_sb3 else sb3(device)
    run_ours(10)  # warm-up
    if run_sb3 is not None:
        run_sb3(10)
    flops = flops_per_update(config)
    rates: dict[str, list[float]] = {"ours": [], "sb3": [], "gflops": []}
    for round_index in range(args.rounds):
        rates["ours"].append(run_ours(args.updates))
        if run_sb3 is not None:
            rates["sb3"].append(run_sb3(args.updates))
        rates["gflops"].append(matmul_gflops(device))
        sb3_text = f", SB3 {rates['sb3'][-1]:.1f} updates/s" if run_sb3 is not None else ""
        print(
            f"round {round_index}: ours {rates['ours'][-1]:.1f} updates/s{sb3_text}, torch.mm {rates['gflops'][-1]:.0f} GFLOP/s",
            flush=True,
        )
    ours_rate, gflops = (statistics.median(rates[k]) for k in ("ours", "gflops"))
    sb3_rate = statistics.median(rates["sb3"]) if rates["sb3"] else None
    roofline = gflops * 1e9 / flops
    print(
        json.dumps(
            {
                "updates_per_s": round(ours_rate, 2),
                "sb3_updates_per_s": sb3_rate and round(sb3_rate, 2),
                "ratio_vs_sb3": sb3_rate and round(ours_rate / sb3_rate, 3),
                "roofline_updates_per_s": round(roofline, 2),
                "roofline_fraction": round(ours_rate / roofline, 3),
                "matmul_gflops": round(gflops, 1),
                "gflop_per_update": round(flops / 1e9, 3),
                "device": str(device),
                "device_name": torch.cuda.get_device_name(device) if device.type == "cuda" else "cpu",
                "threads": args.threads,
                "rounds": args.rounds,
                "updates_per_round": args.updates,
                "hidden": [HIDDEN, HIDDEN],
                "batch": BATCH,
                "per_round": {k: [round(v, 2) for v in vals] for k, vals in rates.items()},
            }
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
