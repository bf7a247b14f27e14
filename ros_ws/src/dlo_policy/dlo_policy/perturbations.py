"""Perturbations: the registry of named families (``dlo_interface.perturbations``, re-exported here: ``FAMILIES``,
``parse``, ``parse_ranges``, ``sim_config``, ``cameras``, ...) and the observation and action families applied over the
observation and the action (:class:`Perturber`: the gym env and the policy node). No rclpy.

A perturbation setting maps family names to magnitudes, e.g. ``{"observation_delay": 2, "friction": 0.6}``,
written as text ``observation_delay=2,friction=0.6`` (one reading, :func:`parse`, wherever it is given: the gym
env's option ``perturbations``, dlo-train's ``env_options.perturbations``, the policy node's and the sim node's
parameter ``perturbations``, ``dlo-robustness``). A family left out, or given its ``off`` value, is off, and then
nothing about the env or the node changes (no random number is drawn). ``python -m dlo_policy.perturbations`` lists
them.

Each family is applied in ONE place, by its ``side``:

- ``observation`` (over the observation vector, :class:`Perturber`; the gym env and the policy node both run it):
  ``observation_delay`` the policy sees the observation of ``d`` control steps before (an episode's first
  observation until then); sensor noise, ``N(0, sigma)`` added to a reading (units of the magnitude: mm, degrees):
  ``tactile_angle_noise`` theta_T, ``tactile_offset_noise`` y_T, ``vision_angle_noise`` theta_V and
  ``vision_offset_noise`` y_V (on a visible detection only), ``gripper_position_noise`` x_G and y_G;
  ``gripper_position_bias`` a constant offset of x_G, y_G as K reports them (length in mm, its direction drawn
  per episode); ``vision_dropout`` a visible detection reported as not visible (V all zeros) with this
  probability; ``vision_false_visible`` a missing detection reported as visible, with this probability, as a
  spurious strand (q_V uniform in [0, 1], theta_V uniform in [-pi/2, pi/2], y_V uniform in the search window).
  Angles are re-wrapped as line angles, offsets clipped to the sensors' ranges (the observation bounds).
- ``action`` (over the action, :class:`Perturber`): ``action_delay`` the simulator gets the action of ``d``
  control steps before (an episode's first action until then); ``velocity_gain`` the gripper moves at this
  multiple of the commanded velocity (saturating at the 0.25 m/s limit); ``closure_lag`` the closure follows
  the command as a first-order lag of this time constant [s] (from the episode's first command).
- ``physics`` and ``camera`` (the simulator's: :func:`sim_config`, :func:`cameras`; the gym env and the sim node
  both apply them from ``dlo_interface.perturbations``, whose docstring says what each does).

The noise of an environment comes from a generator of its own, seeded per episode from the episode's seed
(``episode_rng``), and each control step draws the same block of numbers whichever families are on: the same
episode gives the same noise in a batch of any size and in the graph (the policy node reads the episode's seed
from ``/dlo/task/state``), and a magnitude scales the same draws (common random numbers across a grid).

Domain randomisation (training, :func:`parse_ranges`, :func:`randomised`): ``dlo_interface.perturbations``.
"""

from __future__ import annotations

import math
import sys
from typing import Iterable, Mapping, Optional, Sequence

import numpy as np
from dlo_interface.perturbations import (  # noqa: F401  (the registry's public names, re-exported)
    ACTION,
    CAMERA,
    CHOICE_STREAM,
    DEFAULT_DRAW,
    DRAWS,
    FAMILIES,
    FORMS,
    OBSERVATION,
    OWNERS,
    PHYSICS,
    RANDOMISE_STREAM,
    RANGE_FORMS,
    SIDES,
    Family,
    cameras,
    check_draw,
    family,
    names,
    of_side,
    owned,
    parse,
    parse_ranges,
    randomised,
    range_text,
    sim_config,
    text,
)
from dlo_interface.world import CONTROL_PERIOD

STREAM = 0x9E37  # mixed into each episode's seed: the perturbation noise is a stream of its own
NORMALS = 6  # standard normals each control step draws (x_G, y_G, theta_T, y_T, theta_V, y_V)
UNIFORMS = 5  # uniforms each control step draws (dropout, false visible, its q_V, theta_V, y_V)


# ---------------------------------------------------------------------------------------------- observation, action
def episode_rng(seed: int) -> np.random.Generator:
    """The perturbation noise generator of the episode with this seed (env and policy node alike)."""
    return np.random.default_rng([STREAM, int(seed)])


def wrap_line_angle(angle):
    """Angle of an undirected line [rad] -> (-pi/2, pi/2] (as dlo_perception.tactile)."""
    return np.pi / 2 - np.mod(np.pi / 2 - np.asarray(angle), np.pi)


class _Magnitudes:
    """The observation and action families' constants of one setting (what an episode runs under)."""

    def __init__(self, s: Mapping):
        self.obs_delay = int(s.get("observation_delay", 0))
        self.action_delay = int(s.get("action_delay", 0))
        self.gain = float(s.get("velocity_gain", 1.0))
        lag = float(s.get("closure_lag", 0.0))
        self.closure_rate = 1.0 if lag == 0 else -math.expm1(-CONTROL_PERIOD / lag)
        self.sigma = {
            "x_G": 0.001 * s.get("gripper_position_noise", 0.0),
            "theta_T": math.radians(s.get("tactile_angle_noise", 0.0)),
            "y_T": 0.001 * s.get("tactile_offset_noise", 0.0),
            "theta_V": math.radians(s.get("vision_angle_noise", 0.0)),
            "y_V": 0.001 * s.get("vision_offset_noise", 0.0),
        }
        self.bias_length = 0.001 * s.get("gripper_position_bias", 0.0)
        self.dropout = float(s.get("vision_dropout", 0.0))
        self.false_visible = float(s.get("vision_false_visible", 0.0))


class _Episode:
    """One environment's perturbation state within an episode: its magnitudes ``m`` (_Magnitudes)."""

    def __init__(self, seed: int, m: _Magnitudes):
        self.m = m
        self.rng = episode_rng(seed)
        direction = self.rng.uniform(0.0, 2.0 * np.pi)  # the first draw of the episode, whatever is on
        self.bias = m.bias_length * np.array([np.cos(direction), np.sin(direction)])
        self.observations: list = []  # observation_delay: the last d + 1 observations
        self.actions: list = []  # action_delay: the last d + 1 actions
        self.closure: Optional[float] = None  # closure_lag: the applied closure command a2


class Perturber:
    """The observation and action families of a setting over ``num_envs`` environments (gym env, policy node).

    ``start(env_ids, seeds)`` begins new episodes; ``observe(obs, env_ids)`` perturbs one control step's
    observations (N', D) of those envs (all by default) and ``act(actions)`` the actions (N, 3) of every env, in
    float64, returning float32. ``modalities``/``without``: the observation's layout (dlo_policy.observation);
    a family whose modality is not observed (or ablated) does nothing. ``ranges``: a randomisation
    (:func:`parse_ranges`), its observation and action families drawn per episode (:func:`randomised`, with the
    randomisation's ``draw``: under ``one`` the choice is among all its non-physics families, camera ones included, as
    the env's) on top of the fixed ``setting``. ``active``: any family of these sides on or randomised (else the
    caller need not call it: nothing would change)."""

    def __init__(
        self,
        setting: Mapping,
        modalities,
        without=(),
        num_envs: int = 1,
        ranges: Optional[Mapping] = None,
        draw: str = DEFAULT_DRAW,
    ):
        from dlo_interface.world import WORKSPACE_HALF_WIDTH
        from dlo_perception.tactile import Y_LIMIT
        from dlo_perception.vision import SEARCH_HALF_WIDTH

        from dlo_policy.observation import observation_labels, parse_modalities

        self.setting = of_side(parse(setting), OBSERVATION, ACTION)
        self.randomise = parse_ranges(ranges, self.setting)  # every family: a "one" draw chooses among them all
        self.draw = check_draw(draw)
        self.ranges = of_side(self.randomise, OBSERVATION, ACTION)
        self.observes = bool(of_side({**self.setting, **self.ranges}, OBSERVATION))
        self.acts = bool(of_side({**self.setting, **self.ranges}, ACTION))
        self.active = self.observes or self.acts
        present = parse_modalities(modalities)
        ablated = parse_modalities(without) if without else ()
        labels = observation_labels(present)
        seen = set(observation_labels([m for m in present if m not in ablated])) if len(ablated) < len(present) else set()
        self.column = {label: i for i, label in enumerate(labels) if label in seen}
        self.limits = {"x_G": WORKSPACE_HALF_WIDTH, "y_G": WORKSPACE_HALF_WIDTH, "y_T": Y_LIMIT, "y_V": SEARCH_HALF_WIDTH}
        self.episodes: list = [None] * int(num_envs)
        self.fixed = _Magnitudes(self.setting)

    def start(self, env_ids: Iterable[int], seeds: Iterable[int]) -> None:
        """New episodes in ``env_ids`` with these episode seeds: fresh generators, empty delay lines, and the
        randomised families' magnitudes of each episode."""
        for i, seed in zip(np.asarray(env_ids).reshape(-1), np.asarray(seeds).reshape(-1), strict=True):
            if self.ranges:
                drawn = of_side(randomised(self.randomise, int(seed), self.draw), OBSERVATION, ACTION)
                m = _Magnitudes({**self.setting, **drawn})
            else:
                m = self.fixed
            self.episodes[int(i)] = _Episode(int(seed), m)

    def _episode(self, i: int) -> _Episode:
        episode = self.episodes[i]
        if episode is None:
            raise RuntimeError(f"Perturber: environment {i} has no episode (call start first)")
        return episode

    def observe(self, observations, env_ids: Optional[Sequence[int]] = None) -> np.ndarray:
        """One control step's observations of ``env_ids`` (all envs if None), perturbed (float32, same shape)."""
        obs = np.asarray(observations, dtype=np.float32)
        if not self.observes:
            return obs
        ids = range(len(self.episodes)) if env_ids is None else [int(i) for i in env_ids]
        out = np.array(obs, dtype=np.float64)
        for row, i in enumerate(ids):
            episode = self._episode(i)
            measured = self._measure(out[row], episode)
            delay = episode.m.obs_delay
            if delay:
                if not episode.observations:
                    episode.observations = [measured] * (delay + 1)
                else:
                    episode.observations = episode.observations[1:] + [measured]
                measured = episode.observations[0]
            out[row] = measured
        return out.astype(np.float32)

    def _measure(self, o: np.ndarray, episode: _Episode) -> np.ndarray:
        """One environment's reading with noise, bias, dropout and false detections (every step draws the same
        NORMALS + UNIFORMS numbers from the episode's generator, whatever is on)."""
        z = episode.rng.standard_normal(NORMALS)
        u = episode.rng.random(UNIFORMS)
        o = o.copy()
        col, m = self.column, episode.m
        sigma = m.sigma
        if m.bias_length or sigma["x_G"]:
            for k, label in enumerate(("x_G", "y_G")):
                if label in col:
                    o[col[label]] += episode.bias[k] + sigma["x_G"] * z[k]
        if "theta_T" in col:
            if sigma["theta_T"]:
                o[col["theta_T"]] = wrap_line_angle(o[col["theta_T"]] + sigma["theta_T"] * z[2])
            if sigma["y_T"]:
                o[col["y_T"]] += sigma["y_T"] * z[3]
        if "v_V" in col:
            v, q, theta, y = (col[k] for k in ("v_V", "q_V", "theta_V", "y_V"))
            if o[v] > 0.5:
                if sigma["theta_V"]:
                    o[theta] = wrap_line_angle(o[theta] + sigma["theta_V"] * z[4])
                if sigma["y_V"]:
                    o[y] += sigma["y_V"] * z[5]
                if u[0] < m.dropout:
                    o[[v, q, theta, y]] = 0.0
            elif u[1] < m.false_visible:
                o[v], o[q] = 1.0, u[2]
                o[theta] = (u[3] - 0.5) * np.pi
                o[y] = (2.0 * u[4] - 1.0) * self.limits["y_V"]
        for label, limit in self.limits.items():  # within the sensors' ranges (unperturbed readings are)
            if label in col:
                o[col[label]] = min(max(o[col[label]], -limit), limit)
        return o

    def act(self, actions) -> np.ndarray:
        """The actions (N, 3) of every env as the simulator gets them (float32): delayed, then the actuator's
        velocity gain (clipped to [-1, 1]) and closure lag."""
        a = np.asarray(actions, dtype=np.float32)
        if not self.acts:
            return a
        out = np.array(a, dtype=np.float64).reshape(len(self.episodes), 3)
        for i in range(len(self.episodes)):
            episode = self._episode(i)
            m = episode.m
            command = out[i].copy()
            if m.action_delay:
                if not episode.actions:
                    episode.actions = [command] * (m.action_delay + 1)
                else:
                    episode.actions = episode.actions[1:] + [command]
                command = episode.actions[0].copy()
            if m.gain != 1.0:
                command[:2] = np.clip(m.gain * command[:2], -1.0, 1.0)
            if episode.closure is None or m.closure_rate == 1.0:
                episode.closure = command[2]
            else:
                episode.closure += m.closure_rate * (command[2] - episode.closure)
            command[2] = episode.closure
            out[i] = command
        return out.astype(np.float32).reshape(a.shape)


# ---------------------------------------------------------------------------------------------- the registry, listed
def main(argv=None) -> int:
    """``python -m dlo_policy.perturbations [--check VALUE]``: the registry as a table, or check a setting (its
    canonical text on stdout; one line on stderr and exit 2 when bad)."""
    import argparse

    parser = argparse.ArgumentParser(prog="python -m dlo_policy.perturbations", description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", metavar="VALUE", default=None, help=f"check a setting: {FORMS}")
    args = parser.parse_args(argv)
    if args.check is not None:
        try:
            print(text(parse(args.check)))
        except ValueError as error:
            print(error, file=sys.stderr)
            return 2
        return 0
    for f in FAMILIES:
        nominal = f"training {f.training[0]:g}-{f.training[1]:g}" if f.off is None else f"off {f.off:g}"
        grid = ", ".join(f"{m:g}" for m in f.grid)
        print(f"{f.name:<24} {f.side:<12} {f.unit:<20} {nominal:<18} grid {grid:<32} {f.perturbs}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
