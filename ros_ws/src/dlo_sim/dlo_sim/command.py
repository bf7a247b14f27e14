"""Gripper commands: the policy's normalised action <-> the ROS command in SI units, with checks.

An action ``a`` in [-1, 1]^3 means: move ``a0 * MAX_DISPLACEMENT`` m in x and ``a1 * ...`` in y
per 0.01 s step (so velocity ``a * 0.25`` m/s), closure ``c = (a2 + 1) / 2`` in [0, 1].
``/dlo/gripper/cmd`` carries the velocity [m/s] and the closure.
"""

from __future__ import annotations

import math

import numpy as np

from dlo_sim.config import DT, MAX_DISPLACEMENT

MAX_SPEED = MAX_DISPLACEMENT / DT  # m/s, |vx|, |vy| limit (0.25)
SPEED_TOLERANCE = 1e-6  # m/s, rounding allowance on the limit


class CommandError(ValueError):
    """A gripper command that must not be executed (non-finite or out of range)."""


def action_to_command(action) -> tuple:
    """Normalised action (3,) -> (vx [m/s], vy [m/s], closure [0, 1])."""
    a = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
    return float(a[0] * MAX_SPEED), float(a[1] * MAX_SPEED), float((a[2] + 1.0) / 2.0)


def command_to_action(vx: float, vy: float, closure: float) -> np.ndarray:
    """(vx, vy [m/s], closure) -> normalised action (3,) float32; raises CommandError when invalid."""
    values = (vx, vy, closure)
    if not all(math.isfinite(v) for v in values):
        raise CommandError(f"non-finite command vx={vx}, vy={vy}, closure={closure}")
    if abs(vx) > MAX_SPEED + SPEED_TOLERANCE or abs(vy) > MAX_SPEED + SPEED_TOLERANCE:
        raise CommandError(f"speed out of range: vx={vx}, vy={vy} (limit {MAX_SPEED} m/s)")
    if not 0.0 <= closure <= 1.0:
        raise CommandError(f"closure out of range: {closure} (must be in [0, 1])")
    return np.clip(np.array([vx / MAX_SPEED, vy / MAX_SPEED, 2.0 * closure - 1.0], np.float32), -1.0, 1.0)


def hold_action(closure: float) -> np.ndarray:
    """The safe action: stand still, keep the current closure."""
    return np.array([0.0, 0.0, 2.0 * float(closure) - 1.0], np.float32)
