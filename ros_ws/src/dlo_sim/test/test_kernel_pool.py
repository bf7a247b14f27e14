"""dlo_sim.kernels.kernels_for: a simulator that is gone gives its Taichi fields and compiled kernels back, and the
next simulator with the same compile-time constants takes them in the state of new ones (no second compilation)."""

import gc

import numpy as np
from dlo_interface.sim_config import SimConfig
from dlo_sim import kernels
from dlo_sim.rope import RopeSim


def rollout(sim: RopeSim, seed: int = 1, steps: int = 25) -> list:
    rng = np.random.default_rng(seed)
    sim.reset(np.arange(sim.num_envs) + 300)
    out = []
    for _ in range(steps):
        sim.step(rng.uniform(-1, 1, (sim.num_envs, 3)).astype(np.float32))
        out.append((sim.positions().copy(), sim.gripper_state().copy(), sim.render().copy()))
    return out


def identical(a: list, b: list) -> bool:
    return len(a) == len(b) and all(
        all(np.array_equal(p, q) for p, q in zip(x, y, strict=True)) for x, y in zip(a, b, strict=True)
    )


def test_a_released_simulators_kernels_serve_the_next_one_which_runs_as_a_new_one():
    first = RopeSim(2)
    used = first._k
    reference = rollout(first)
    del first
    gc.collect()
    second = RopeSim(2)
    assert second._k is used  # the same Taichi objects: nothing compiled again
    assert identical(rollout(second), reference)  # left in the state of new ones
    third = RopeSim(2)  # while the second is alive: its own
    assert third._k is not used and identical(rollout(third), reference)
    other = RopeSim(2, SimConfig(substeps=SimConfig().substeps + 1))  # other compile-time constants: its own
    assert other._k is not used and other._k.substeps != used.substeps


def test_a_released_state_is_cleared_cameras_included():
    """Whatever the released simulator left (other episodes, its per-env cameras moved and turned), the next one
    starts as a new one."""
    sim = RopeSim(2, camera_per_env=True)
    reference = rollout(sim, seed=2, steps=10)
    sim.set_camera([0, 1], np.array([[0.003, -0.002], [0.0, 0.004]]), np.array([0.05, -0.03]))
    moved = rollout(sim, seed=5, steps=10)
    assert not identical(moved[-1:], reference[-1:])
    used = sim._k
    del sim
    gc.collect()
    again = RopeSim(2, camera_per_env=True)
    assert again._k is used
    assert identical(rollout(again, seed=2, steps=10), reference)
    assert kernels.baked_in(2, SimConfig(), again.camera, True)["cam_per_env"] is True
