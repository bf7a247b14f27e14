"""``RopeSim``: the numpy-facing batched rope simulator (no rclpy).

One ``RopeSim`` holds ``num_envs`` independent environments, each a cable of 30-60 particles
pinned at the fixed end and a two-finger gripper. Environment ``e`` depends only on its own seed
and actions: the same seed gives a bit-identical episode in any batch.

Invalid input (documented behaviour):
- bad ``SimConfig`` values (negative stiffness, zero particles, ...) and ``num_envs < 1``: ValueError;
- actions containing NaN or inf, or of the wrong shape: ValueError;
- actions outside [-1, 1]: clipped, with one ``RuntimeWarning`` per simulator;
- an environment whose state becomes NaN/inf or explodes: flagged in ``unstable()`` and reset
  cleanly with its own seed; the other environments continue untouched.
"""

from __future__ import annotations

import warnings
import weakref
from dataclasses import dataclass

import numpy as np
from dlo_interface.camera import TopCamera
from dlo_interface.sim_config import SimConfig
from dlo_interface.world import DT, P_MAX, PARTICLE_MASS, REST_SPACING, SUBSTEPS_PER_ACTION

from .kernels import kernels_for, release

PARAM_KEYS = ("stretch", "bending", "friction", "num_particles", "particle_mass")


def physics_draw(config: SimConfig) -> dict:
    """The stretch, bending and friction every episode gets under ``config.physics_seed`` >= 0 (the authors'
    one physics draw) and the particle mass: uniform in the config's ranges, from the generator of that seed alone."""
    rng = np.random.default_rng(config.physics_seed)
    return {
        "stretch": rng.uniform(*config.stretch_range),
        "bending": rng.uniform(*config.bending_range),
        "friction": rng.uniform(*config.friction_range),
        "particle_mass": rng.uniform(*config.particle_mass_range),
    }


@dataclass
class Snapshot:
    """What the task and the observations read of the current state, from one kernel launch."""

    positions: np.ndarray  # (N, P_MAX, 3) float32 [m], padded rows 0
    held: np.ndarray  # (N, P_MAX) bool, particles between the fingers (held rule: docs/ARCHITECTURE.md#constants)
    gripper: np.ndarray  # (N, 4) float32: x_G, y_G, z_G [m], c_G in [0, 1]
    image: np.ndarray | None  # (N, H, W) uint8 top view (as ``render``), None if not asked for


class RopeSim:
    """Batched Taichi cable simulator. Positions in metres (world frame, z up), time step 0.01 s."""

    def __init__(
        self, num_envs: int, config: SimConfig | None = None, camera: TopCamera | None = None, camera_per_env: bool = False
    ):
        if int(num_envs) < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        self.num_envs = int(num_envs)
        self.config = config if config is not None else SimConfig()
        self.config.validate()
        self.camera = camera if camera is not None else TopCamera.covering_workspace(128)
        self.camera_per_env = bool(camera_per_env)  # each env renders through its own camera: set_camera
        # the Taichi state and kernels: a released one of the same compile-time constants where this process has one
        # (compiled once: dlo_sim.kernels.kernels_for), given back when this simulator is gone
        self._k = kernels_for(self.num_envs, self.config, self.camera, self.camera_per_env)
        weakref.finalize(self, release, self._k)
        n = self.num_envs
        self._params = {
            "stretch": np.zeros(n, np.float32),
            "bending": np.zeros(n, np.float32),
            "friction": np.zeros(n, np.float32),
            "num_particles": np.zeros(n, np.int32),
            "particle_mass": np.full(n, PARTICLE_MASS, np.float32),
            "seed": np.full(n, -1, np.int64),
        }
        self._pick = np.full(n, -1, np.int32)
        self._pick_vel = np.zeros((n, 3), np.float32)
        self._unstable = np.zeros(n, bool)
        self._clip_warned = False
        self._no_actions = np.zeros((1, 3), np.float32)  # stand-in for a read-back without steps
        self._no_image = np.zeros((1, 1, 1), np.uint8)  # stand-in for a read-back without render

    # ------------------------------------------------------------------ episodes
    def reset(self, seeds, env_ids=None, params: dict | None = None) -> None:
        """Randomise, lay out (pick-and-drop x4) and settle the given environments (all if None).

        ``seeds``: non-negative ints, one per reset environment. ``params`` optionally overrides
        drawn values per environment (keys "stretch", "bending", "friction", "num_particles", "particle_mass"; arrays
        of len(env_ids)); the random stream is drawn first, so other draws are unchanged.
        Environments not listed keep their state."""
        ids = self._env_ids(env_ids)
        seeds = np.asarray(seeds).reshape(-1)
        if seeds.shape[0] != ids.shape[0] or not np.issubdtype(seeds.dtype, np.integer) or np.any(seeds < 0):
            raise ValueError(f"seeds must be {ids.shape[0]} non-negative integers, got {seeds!r}")
        draws = [self._draw(int(s)) for s in seeds]
        values = {key: np.array([d[key] for d in draws]) for key in PARAM_KEYS}
        for key, given in (params or {}).items():
            if key not in PARAM_KEYS:
                raise ValueError(f"unknown parameter override {key!r}; valid: {PARAM_KEYS}")
            values[key] = np.broadcast_to(np.asarray(given), ids.shape).copy()
        self._check_params(values)
        for key in PARAM_KEYS:
            self._params[key][ids] = values[key]
        self._params["seed"][ids] = seeds
        self._push_params()

        mask = np.zeros(self.num_envs, np.int32)
        mask[ids] = 1
        k = self._k
        k.lay_straight(mask)
        still = np.tile(np.float32([0.0, 0.0, -1.0]), (self.num_envs, 1))  # gripper still and open
        k.active.from_numpy(mask)
        cfg = self.config
        for move in range(cfg.pick_moves):
            self._pick[ids] = [d["pick"][move] for d in draws]
            self._pick_vel[ids] = [d["pick_vel"][move] for d in draws]
            k.pick.from_numpy(self._pick)
            k.pick_vel.from_numpy(self._pick_vel)
            k.advance(still, cfg.pick_steps)
            self._pick[ids] = -1
            k.pick.from_numpy(self._pick)
            k.advance(still, cfg.drop_steps)
        k.advance(still, cfg.settle_steps)
        k.active.fill(1)
        self._unstable[ids] = False

    def set_camera(self, env_ids, offsets, yaws) -> None:
        """The cameras ``env_ids`` render through from now on (``camera_per_env`` only): ``camera`` moved by
        ``offsets`` (K, 2) [m] in world x, y and turned by ``yaws`` (K,) [rad] about its optical axis."""
        if not self.camera_per_env:
            raise ValueError("set_camera: this simulator renders through one camera (camera_per_env=False)")
        ids = self._env_ids(env_ids)
        shift, turn = self._k.cam_shift.to_numpy(), self._k.cam_yaw.to_numpy()
        shift[ids] = np.asarray(offsets, np.float32).reshape(len(ids), 2)
        yaws = np.asarray(yaws, np.float64).reshape(len(ids))
        turn[ids] = np.stack([np.cos(yaws), np.sin(yaws)], axis=1)
        self._k.cam_shift.from_numpy(shift.astype(np.float32))
        self._k.cam_yaw.from_numpy(turn.astype(np.float32))

    def step(self, actions) -> None:
        """One action: ``SUBSTEPS_PER_ACTION`` (8) steps of 0.01 s with the same ``actions`` (N, 3)."""
        self.step_physics(actions, SUBSTEPS_PER_ACTION)

    def step_physics(self, actions, n: int = 1) -> None:
        """``n`` steps of 0.01 s. ``actions`` (N, 3) in [-1, 1]: dx, dy (x 0.0025 m per step) and
        closure c = (a2 + 1) / 2. Exploded environments are flagged and reset with their seed."""
        self._advance(actions, int(n))

    def step_snapshot(self, actions, render: bool = True) -> Snapshot:
        """``step(actions)`` and ``snapshot(render)`` of the resulting state in one kernel launch."""
        out = self._new_snapshot(render)
        if self._advance(actions, SUBSTEPS_PER_ACTION, out):
            out = self.snapshot(render)  # some envs were reset after the read-back
        return out

    # ------------------------------------------------------------------ ground truth
    def positions(self) -> np.ndarray:
        """(N, P_MAX, 3) float32 [m]; rows beyond ``num_particles`` are 0."""
        return self._k.x.to_numpy()

    def velocities(self) -> np.ndarray:
        """(N, P_MAX, 3) float32 [m/s]; rows beyond ``num_particles`` are 0."""
        return self._k.v.to_numpy()

    @property
    def num_particles(self) -> np.ndarray:
        """(N,) int32, n_c."""
        return self._params["num_particles"].copy()

    def particle_mask(self) -> np.ndarray:
        """(N, P_MAX) bool, True for particles in use."""
        return np.arange(P_MAX)[None, :] < self._params["num_particles"][:, None]

    @property
    def cable_length(self) -> np.ndarray:
        """(N,) float32 [m], L_c = (n_c - 1) * rest spacing."""
        return ((self._params["num_particles"] - 1) * REST_SPACING).astype(np.float32)

    def snapshot(self, render: bool = True) -> Snapshot:
        """Positions, held mask, gripper state and (if ``render``) the top view, in one kernel launch."""
        out = self._new_snapshot(render)
        self._read(self._no_actions, 0, out)
        return out

    def held_mask(self) -> np.ndarray:
        """(N, P_MAX) bool: particles between the fingers now (held rule: docs/ARCHITECTURE.md#constants)."""
        return self.snapshot(render=False).held

    def n_held(self) -> np.ndarray:
        """(N,) int32, n_h."""
        return self.held_mask().sum(axis=1).astype(np.int32)

    def mean_held_index(self) -> np.ndarray:
        """(N,) float32, p_i = mean index of the held particles; -1.0 when none is held."""
        held = self.held_mask()
        count = held.sum(axis=1)
        total = (held * np.arange(P_MAX)[None, :]).sum(axis=1)
        return np.where(count > 0, total / np.maximum(count, 1), -1.0).astype(np.float32)

    def gripper_state(self) -> np.ndarray:
        """(N, 4) float32: x_G, y_G, z_G [m], c_G in [0, 1]."""
        return self.snapshot(render=False).gripper

    @property
    def params(self) -> dict:
        """Per-env randomised parameters, (N,) arrays: stretch, bending, friction, num_particles, particle_mass [kg],
        seed."""
        return {key: value.copy() for key, value in self._params.items()}

    def unstable(self) -> np.ndarray:
        """(N,) bool: NaN/inf/explosion detected in the last ``step``/``step_physics`` (env was reset)."""
        return self._unstable.copy()

    def render(self) -> np.ndarray:
        """(N, H, W) uint8 top-camera view: 0 background, 255 cable, 128 gripper (drawn over the cable)."""
        return self.snapshot(render=True).image

    def set_positions(self, positions, env_ids=None) -> None:
        """Overwrite the particle positions [m] of some environments and zero their velocities
        (tests and experiments). ``positions``: (len(env_ids), P_MAX, 3); particle 0 stays pinned
        wherever it is put."""
        ids = self._env_ids(env_ids)
        x = self._k.x.to_numpy()
        x[ids] = np.asarray(positions, np.float32).reshape(len(ids), P_MAX, 3)
        x[~self.particle_mask()] = 0.0
        v = self._k.v.to_numpy()
        v[ids] = 0.0
        self._k.x.from_numpy(x)
        self._k.x_old.from_numpy(x)
        self._k.v.from_numpy(v)

    # ------------------------------------------------------------------ helpers
    def _advance(self, actions, n: int, out: Snapshot | None = None) -> bool:
        """``n`` physics steps (+ read-back into ``out`` if given); resets exploded envs; True if any was."""
        if np.any(self._params["seed"] < 0):
            raise RuntimeError("reset() every environment before stepping")
        actions = self._check_actions(actions)
        self._unstable[:] = False
        n_bad = self._k.advance(actions, n) if out is None else self._read(actions, n, out)
        if n_bad == 0:
            return False
        bad = self._k.bad.to_numpy() != 0
        self.reset(self._params["seed"][bad], env_ids=np.flatnonzero(bad))
        self._unstable[:] = bad
        return True

    def _read(self, actions, n: int, out: Snapshot) -> int:
        """``n`` steps, then the read-back into ``out``, in one launch; returns how many envs exploded."""
        image = self._no_image if out.image is None else out.image
        return self._k.advance_and_read(
            actions, n, out.positions, out.held.view(np.uint8), out.gripper, image, int(out.image is not None)
        )

    def _new_snapshot(self, render: bool) -> Snapshot:
        """Uninitialised read-back arrays; the image zeroed (the renderer draws on background; fresh
        zero pages from the OS cost less than clearing the image in the kernel)."""
        n = self.num_envs
        image = np.zeros((n, self.camera.height, self.camera.width), np.uint8) if render else None
        return Snapshot(np.empty((n, P_MAX, 3), np.float32), np.empty((n, P_MAX), bool), np.empty((n, 4), np.float32), image)

    def _draw(self, seed: int) -> dict:
        """All random draws of one episode, from its own generator (independent of the batch)."""
        cfg = self.config
        rng = np.random.default_rng(seed)
        n = int(rng.integers(cfg.num_particles_range[0], cfg.num_particles_range[1] + 1))
        draw = {
            "num_particles": n,
            "stretch": rng.uniform(*cfg.stretch_range),
            "bending": rng.uniform(*cfg.bending_range),
            "friction": rng.uniform(*cfg.friction_range),
        }
        if cfg.physics_seed >= 0:  # one physics for every episode; the episode's stream is drawn as without
            draw.update(physics_draw(cfg))
        picks = rng.integers(n // 2, n, size=cfg.pick_moves)
        azimuth = rng.uniform(0.0, 2.0 * np.pi, size=cfg.pick_moves)
        rise = rng.uniform(0.2, 1.0, size=cfg.pick_moves)  # upward bias: sine of the elevation
        speed = rng.uniform(0.5, 1.0, size=cfg.pick_moves) * cfg.pick_max_speed / DT
        flat = np.sqrt(1.0 - rise**2)
        draw["pick"] = np.minimum(picks, n - 1)
        draw["pick_vel"] = speed[:, None] * np.stack([flat * np.cos(azimuth), flat * np.sin(azimuth), rise], 1)
        if cfg.physics_seed < 0:  # the last draw: every draw above is as it was without it
            draw["particle_mass"] = rng.uniform(*cfg.particle_mass_range)
        return draw

    def _check_params(self, values: dict) -> None:
        if np.any(~(values["stretch"] > 0)) or np.any(~(values["bending"] > 0)):
            raise ValueError("stretch and bending stiffness must be positive")
        if np.any(~(values["friction"] >= 0)):
            raise ValueError("friction must be >= 0")
        if np.any(~(values["particle_mass"] > 0)):
            raise ValueError("particle_mass must be positive")
        n = values["num_particles"]
        if np.any(n < 2) or np.any(n > P_MAX):
            raise ValueError(f"num_particles must be in [2, {P_MAX}], got {n}")

    def _push_params(self) -> None:
        p, cfg, k = self._params, self.config, self._k
        k.n.from_numpy(p["num_particles"])
        # particles k times the nominal mass: the same solves with both compliances x k (config.particle_mass_range);
        # at the nominal mass the factor is exactly 1
        heavier = (p["particle_mass"] / np.float32(PARTICLE_MASS)).astype(np.float32)
        k.alpha_stretch.from_numpy((cfg.stretch_compliance(p["stretch"]) * heavier).astype(np.float32))
        k.alpha_bend.from_numpy((cfg.bending_compliance(p["bending"]) * heavier).astype(np.float32))
        k.mu.from_numpy(p["friction"])

    def _env_ids(self, env_ids) -> np.ndarray:
        if env_ids is None:
            return np.arange(self.num_envs)
        ids = np.asarray(env_ids, dtype=np.int64).reshape(-1)
        if np.any(ids < 0) or np.any(ids >= self.num_envs) or len(np.unique(ids)) != len(ids):
            raise ValueError(f"env_ids must be distinct indices in [0, {self.num_envs}), got {env_ids!r}")
        return ids

    def _check_actions(self, actions) -> np.ndarray:
        a = np.ascontiguousarray(actions, dtype=np.float32)
        if a.shape != (self.num_envs, 3):
            raise ValueError(f"actions must have shape ({self.num_envs}, 3), got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError("actions contain NaN or inf")
        if np.any(np.abs(a) > 1.0):
            if not self._clip_warned:
                warnings.warn("actions outside [-1, 1] are clipped (warned once)", RuntimeWarning, stacklevel=3)
                self._clip_warned = True
            a = np.clip(a, -1.0, 1.0)
        return a
