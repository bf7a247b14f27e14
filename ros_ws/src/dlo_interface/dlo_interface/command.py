"""Gripper commands: the policy's normalised action <-> the ROS command in SI units, with checks.

An action ``a`` in [-1, 1]^3 means: move ``a0 * MAX_DISPLACEMENT`` m in x and ``a1 * ...`` in y
per 0.01 s step (so velocity ``a * 0.25`` m/s), closure ``c = (a2 + 1) / 2`` in [0, 1].
``/dlo/gripper/cmd`` carries the velocity [m/s] and the closure.
"""

from __future__ import annotations

import math

import numpy as np

from dlo_interface.world import CONTROL_PERIOD, DT, MAX_DISPLACEMENT

MAX_SPEED = MAX_DISPLACEMENT / DT  # m/s, |vx|, |vy| limit (0.25)
SPEED_TOLERANCE = 1e-6  # m/s, rounding allowance on the limit


class CommandError(ValueError):
    """A gripper command that must not be executed (non-finite or out of range).

    ``cause`` names the rule it breaks: 'non-finite', 'speed' or 'closure'.
    """

    def __init__(self, message: str, cause: str = "invalid") -> None:
        super().__init__(message)
        self.cause = cause


def action_to_command(action) -> tuple:
    """Normalised action (3,) -> (vx [m/s], vy [m/s], closure [0, 1])."""
    a = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
    return float(a[0] * MAX_SPEED), float(a[1] * MAX_SPEED), float((a[2] + 1.0) / 2.0)


def command_to_action(vx: float, vy: float, closure: float) -> np.ndarray:
    """(vx, vy [m/s], closure) -> normalised action (3,) float32; raises CommandError when invalid."""
    values = (vx, vy, closure)
    if not all(math.isfinite(v) for v in values):
        raise CommandError(f"non-finite command vx={vx}, vy={vy}, closure={closure}", "non-finite")
    if abs(vx) > MAX_SPEED + SPEED_TOLERANCE or abs(vy) > MAX_SPEED + SPEED_TOLERANCE:
        raise CommandError(f"speed out of range: vx={vx}, vy={vy} (limit {MAX_SPEED} m/s)", "speed")
    if not 0.0 <= closure <= 1.0:
        raise CommandError(f"closure out of range: {closure} (must be in [0, 1])", "closure")
    return np.clip(np.array([vx / MAX_SPEED, vy / MAX_SPEED, 2.0 * closure - 1.0], np.float32), -1.0, 1.0)


def hold_action(closure: float) -> np.ndarray:
    """The safe action: stand still, keep the current closure."""
    return np.array([0.0, 0.0, 2.0 * float(closure) - 1.0], np.float32)


def command_mismatch(
    mode: str,
    episode: int,
    step: int,
    cmd_episode: int,
    cmd_step: int,
    *,
    period: float = CONTROL_PERIOD,
    command_timeout: float = 0.5,
    previous_final: tuple[int, int] | None = None,
) -> tuple[str, str] | None:
    """Why a command stamped (``cmd_episode``, ``cmd_step``) must not act on the sim's current
    (``episode``, ``step``): ``(cause, text)``, or None when it matches (docs/ARCHITECTURE.md#topics).

    It must answer the current episode and, in ``step_locked`` mode, the current step; in
    ``real_time`` mode a step not ahead of the current one and not older than
    ``command_timeout`` seconds (``period`` = wall seconds per step). An answer to the previous
    episode's final state (``previous_final``), which a policy sends while the next episode
    starts, is expected: cause 'previous episode', to be ignored quietly.
    """
    if cmd_episode != episode:
        if previous_final is not None and (cmd_episode, cmd_step) == tuple(previous_final):
            return "previous episode", f"for the final step of the previous episode {cmd_episode}"
        return "episode", f"for episode {cmd_episode} (current episode {episode})"
    if cmd_step > step:
        return "future step", f"for step {cmd_step}, ahead of the current step {step} of episode {episode}"
    if mode == "step_locked":
        if cmd_step != step:
            return "old step", f"for step {cmd_step}, not the current step {step} of episode {episode}"
        return None
    age = (step - cmd_step) * period
    if age > command_timeout:
        return "stale", (f"for step {cmd_step}, {age:.2f} s old (current step {step}, command_timeout {command_timeout:g} s)")
    return None


class RejectionLog:
    """At most one line per ``interval`` seconds per cause, with the count of rejections since.

    ``note(cause, text, now)`` returns the line to log now (the first of a cause at once) or None
    (counted); ``due(now)`` returns the pending summaries whose interval has passed.
    """

    def __init__(self, interval: float = 1.0) -> None:
        self.interval = interval
        self._last: dict[str, float] = {}
        self._pending: dict[str, tuple[int, str, float]] = {}  # cause -> (count, latest text, first time)
        self.total: dict[str, int] = {}

    def note(self, cause: str, text: str, now: float) -> str | None:
        self.total[cause] = self.total.get(cause, 0) + 1
        count, _, first = self._pending.get(cause, (0, "", now))
        self._pending[cause] = (count + 1, text, first)
        last = self._last.get(cause)
        if last is None or now - last >= self.interval:
            return self._line(cause, now)
        return None

    def due(self, now: float) -> list[str]:
        return [self._line(cause, now) for cause in list(self._pending) if now - self._last.get(cause, -1e18) >= self.interval]

    def _line(self, cause: str, now: float) -> str:
        count, text, first = self._pending.pop(cause)
        self._last[cause] = now
        if count == 1:
            return f"rejected command: {text}"
        return f"rejected command: {text} ({count} such commands in {max(now - first, 0.0):.1f} s)"
