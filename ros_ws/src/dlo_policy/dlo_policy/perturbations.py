"""Perturbations: named families, each off by default, in one registry (``FAMILIES``). No rclpy.

A perturbation setting maps family names to magnitudes, e.g. ``{"observation_delay": 2, "friction": 0.6}``,
written as text ``observation_delay=2,friction=0.6`` (one reading, :func:`parse`, wherever it is given: the gym
env's option ``perturbations``, dlo-train's ``env_options.perturbations``, the policy node's parameter
``perturbations``, ``dlo-robustness``). A family left out, or given its ``off`` value, is off, and then nothing
about the env or the node changes (no random number is drawn). ``python -m dlo_policy.perturbations`` lists them.

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
- ``physics`` (``dlo_interface.sim_config.SimConfig`` ranges, drawn per episode by ``dlo_sim.rope``): ``friction``,
  ``stretch_stiffness``, ``bending_stiffness``, ``cable_length`` (particles, 4.3 mm apart) and ``particle_mass``
  [kg] fixed at the magnitude (a pair [low, high]: drawn uniformly per episode) instead of the training ranges.
- ``camera`` (``dlo_interface.camera.TopCamera``): the image is rendered by a camera moved ``camera_offset``
  mm along world +y or turned ``camera_yaw`` degrees about its optical axis, while the vision computation assumes
  the nominal camera (an extrinsic calibration error).

The noise of an environment comes from a generator of its own, seeded per episode from the episode's seed
(``episode_rng``), and each control step draws the same block of numbers whichever families are on: the same
episode gives the same noise in a batch of any size and in the graph (the policy node reads the episode's seed
from ``/dlo/task/state``), and a magnitude scales the same draws (common random numbers across a grid).

Domain randomisation (training): a *randomisation* maps families to ranges, ``{"observation_delay": [0, 2],
"friction": [0.02, 1.2]}``, as text ``observation_delay=0:2,friction=0.02:1.2`` (:func:`parse_ranges`: the gym env's
option ``randomise``, dlo-train's ``env_options.randomise``). Every episode takes each family's magnitude uniformly
from its range (an integer family: each whole number alike): an observation, action or camera family from the
episode's own generator (:func:`randomised`, seeded from the episode's seed on a stream of its own, one uniform per
registered family whatever is randomised: the same episode gets the same magnitudes in any batch and whichever
other families are randomised), a physics family by the simulator's own per-episode draw, its range replacing the
training range (``dlo_sim.rope``). A family is either fixed (``perturbations``) or randomised, not both; with no
randomisation nothing is drawn.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import sys
from dataclasses import dataclass
from typing import Any, Iterable, Mapping, Optional, Sequence

import numpy as np
from dlo_interface.world import CONTROL_PERIOD

OBSERVATION, ACTION, PHYSICS, CAMERA = "observation", "action", "physics", "camera"
SIDES = (OBSERVATION, ACTION, PHYSICS, CAMERA)
STREAM = 0x9E37  # mixed into each episode's seed: the perturbation noise is a stream of its own
RANDOMISE_STREAM = 0x5EED  # mixed into each episode's seed: its randomised magnitudes, another stream
NORMALS = 6  # standard normals each control step draws (x_G, y_G, theta_T, y_T, theta_V, y_V)
UNIFORMS = 5  # uniforms each control step draws (dropout, false visible, its q_V, theta_V, y_V)


@dataclass(frozen=True)
class Family:
    """One perturbation family (module docstring).

    ``off``: the magnitude that changes nothing (0; 1 for a gain); None for a physics family, whose nominal is
    its training range ``training`` (dlo_interface.sim_config.SimConfig). ``grid``: the magnitudes dlo-robustness evaluates.
    ``low``/``high``: the magnitudes it takes. ``integer``: whole numbers only (control steps, particles)."""

    name: str
    unit: str
    side: str
    perturbs: str
    grid: tuple
    off: Optional[float] = 0.0
    low: float = 0.0
    high: float = math.inf
    integer: bool = False
    training: Optional[tuple] = None  # physics: the SimConfig range the policies are trained on
    sim_range: str = ""  # physics: the SimConfig field it sets
    sim_param: str = ""  # physics: the simulator's per-episode parameter it is (dlo_sim.RopeSim.params)

    def __post_init__(self):
        if self.side not in SIDES:
            raise ValueError(f"family {self.name}: side must be one of {SIDES}")
        if len(self.grid) < 5 or any(not self.low <= m <= self.high for m in self.grid):
            raise ValueError(f"family {self.name}: a grid of >= 5 valid magnitudes")

    def check(self, value) -> Any:
        """A magnitude (or, for a physics family, a pair [low, high]) as this family takes it; ValueError in one
        line otherwise."""
        if self.side == PHYSICS and isinstance(value, (list, tuple)):
            if len(value) != 2:
                raise ValueError(f"{self.name}: expected a number or a pair [low, high], got {list(value)!r}")
            low, high = (self.check(v) for v in value)
            if low > high:
                raise ValueError(f"{self.name}: expected low <= high, got {list(value)!r}")
            return (low, high)
        if isinstance(value, str):
            try:
                value = float(value)
            except ValueError:
                raise ValueError(f"{self.name}: expected {self.accepts()}, got {value!r}") from None
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
            raise ValueError(f"{self.name}: expected {self.accepts()}, got {value!r}")
        value = float(value)
        if not math.isfinite(value) or not self.low <= value <= self.high or (self.integer and value != int(value)):
            raise ValueError(f"{self.name}: expected {self.accepts()}, got {value:g}")
        return int(value) if self.integer else value

    def accepts(self) -> str:
        """Its magnitudes in words."""
        kind = "an integer" if self.integer else "a number"
        bound = f"in [{self.low:g}, {self.high:g}]" if math.isfinite(self.high) else f">= {self.low:g}"
        return f"{kind} {bound} ({self.unit})" + (" or a pair [low, high]" if self.side == PHYSICS else "")

    def is_off(self, value) -> bool:
        return self.off is not None and not isinstance(value, tuple) and value == self.off


def _physics(name, unit, perturbs, grid, sim_range, low, high=math.inf, integer=False):
    from dlo_interface.sim_config import SimConfig  # the training ranges: what a policy has seen

    training = tuple(getattr(SimConfig, sim_range))
    sim_param = "num_particles" if sim_range == "num_particles_range" else sim_range[: -len("_range")]
    return Family(name, unit, PHYSICS, perturbs, grid, None, low, high, integer, training, sim_range, sim_param)


FAMILIES = (
    Family(
        "observation_delay",
        "control steps",
        OBSERVATION,
        "the whole observation, d steps (0.08 s each) late",
        (1, 2, 3, 4, 6),
        high=50,
        integer=True,
    ),
    Family("tactile_angle_noise", "deg", OBSERVATION, "theta_T + N(0, sigma)", (2.0, 5.0, 10.0, 20.0, 40.0, 80.0)),
    Family("tactile_offset_noise", "mm", OBSERVATION, "y_T + N(0, sigma)", (0.5, 1.0, 2.0, 4.0, 8.0)),
    Family(
        "vision_angle_noise",
        "deg",
        OBSERVATION,
        "theta_V + N(0, sigma) on a visible detection",
        (2.0, 5.0, 10.0, 20.0, 40.0, 80.0),
    ),
    Family(
        "vision_offset_noise", "mm", OBSERVATION, "y_V + N(0, sigma) on a visible detection", (1.0, 2.0, 4.0, 8.0, 16.0, 32.0)
    ),
    Family(
        "vision_dropout",
        "probability",
        OBSERVATION,
        "a visible detection reported as not visible",
        (0.1, 0.2, 0.4, 0.6, 0.8, 0.95),
        high=1.0,
    ),
    Family(
        "vision_false_visible",
        "probability",
        OBSERVATION,
        "a missing detection reported as a visible, spurious strand",
        (0.01, 0.02, 0.05, 0.1, 0.2, 0.4),
        high=1.0,
    ),
    Family("gripper_position_noise", "mm", OBSERVATION, "x_G, y_G + N(0, sigma) each", (1.0, 2.0, 4.0, 8.0, 16.0)),
    Family(
        "gripper_position_bias",
        "mm",
        OBSERVATION,
        "x_G, y_G as K reports them, offset by this length (direction drawn per episode)",
        (1.0, 2.0, 5.0, 10.0, 20.0, 40.0),
    ),
    Family(
        "action_delay", "control steps", ACTION, "the action, d steps (0.08 s each) late", (1, 2, 3, 4, 6), high=50, integer=True
    ),
    Family(
        "velocity_gain",
        "x commanded",
        ACTION,
        "the gripper's velocity (saturating at 0.25 m/s)",
        (0.25, 0.5, 0.75, 1.25, 1.5, 2.0, 3.0),
        off=1.0,
        high=10.0,
    ),
    Family(
        "closure_lag",
        "s",
        ACTION,
        "the closure, a first-order lag of this time constant",
        (0.04, 0.08, 0.16, 0.32, 0.64),
        high=60.0,
    ),
    _physics(
        "friction",
        "Coulomb coefficient",
        "table and finger friction, every episode",
        (0.0, 0.02, 0.45, 0.6, 0.9, 1.2),
        "friction_range",
        0.0,
    ),
    _physics(
        "stretch_stiffness",
        "paper's stiffness",
        "stretch stiffness (compliance ~ s^-4), every episode",
        (0.25, 0.4, 0.6, 2.0, 4.0, 8.0),
        "stretch_range",
        0.05,
        20.0,
    ),
    _physics(
        "bending_stiffness",
        "paper's stiffness",
        "bending stiffness (compliance ~ b^-3), every episode",
        (0.1, 0.2, 0.4, 3.5, 5.0, 8.0),
        "bending_range",
        0.05,
        40.0,
    ),
    _physics(
        "cable_length",
        "particles",
        "particle count (4.3 mm apart), every episode",
        (10, 15, 20, 25, 29),
        "num_particles_range",
        2,
        60,
        integer=True,
    ),
    _physics(
        "particle_mass",
        "kg",
        "every particle's mass (nominal 0.5 kg), every episode",
        (0.05, 0.125, 0.25, 1.0, 2.0, 5.0),
        "particle_mass_range",
        0.001,
        100.0,
    ),
    Family(
        "camera_offset",
        "mm",
        CAMERA,
        "the rendering camera moved along world +y; the vision assumes it is not",
        (2.0, 5.0, 10.0, 20.0, 40.0),
        high=300.0,
    ),
    Family(
        "camera_yaw",
        "deg",
        CAMERA,
        "the rendering camera turned about its optical axis; the vision assumes not",
        (1.0, 2.0, 5.0, 10.0, 20.0),
        high=90.0,
    ),
)
_BY_NAME = {f.name: f for f in FAMILIES}
assert len(_BY_NAME) == len(FAMILIES)
FORMS = "name=value pairs joined by ',' (e.g. observation_delay=2,friction=0.6), '' for none"


def names(side: Optional[str] = None) -> tuple:
    """The families' names (of one side), in registry order."""
    return tuple(f.name for f in FAMILIES if side is None or f.side == side)


def family(name: str) -> Family:
    """The record of family ``name``; ValueError naming the known ones for an unknown one."""
    try:
        return _BY_NAME[name]
    except KeyError:
        closest = difflib.get_close_matches(name, list(_BY_NAME), n=1, cutoff=0.0)
        raise ValueError(
            f"unknown perturbation {name!r}"
            + (f"; did you mean {closest[0]!r}?" if closest else "")
            + f" (known: {', '.join(_BY_NAME)})"
        ) from None


def parse(value) -> dict:
    """A perturbation setting -> {family: magnitude}, the families that are on, in registry order.

    ``value``: None, '' or {} (none); a mapping {name: magnitude}; or text ``name=value,name=value`` (a physics
    family's pair as ``name=low:high``). ValueError in one line for an unknown family or a bad magnitude."""
    if value is None:
        return {}
    value = _mapping(value, "perturbations", FORMS)
    checked = {}
    for name, magnitude in value.items():
        f = family(str(name))
        m = f.check(magnitude)
        if not f.is_off(m):
            checked[f.name] = m
    return {f.name: checked[f.name] for f in FAMILIES if f.name in checked}


def _mapping(value, what: str, forms: str) -> Mapping:
    """A setting's text ``name=value,name=low:high`` (or a mapping, as it is) -> {name: value or [low, high]}."""
    if isinstance(value, str):
        items = {}
        for part in filter(None, (p.strip() for p in value.strip().split(","))):
            name, sep, magnitude = part.partition("=")
            if not sep:
                raise ValueError(f"{what}: expected {forms}, got {value!r}")
            name = name.strip()
            if name in items:
                raise ValueError(f"{what}: {name} given twice in {value!r}")
            items[name] = magnitude.strip().split(":") if ":" in magnitude else magnitude.strip()
        value = items
    if not isinstance(value, Mapping):
        raise ValueError(f"{what}: expected {forms} or a mapping, got {value!r}")
    return value


RANGE_FORMS = "name=low:high pairs joined by ',' (e.g. observation_delay=0:2,friction=0.02:1.2), '' for none"


def parse_ranges(value, fixed: Optional[Mapping] = None) -> dict:
    """A randomisation -> {family: (low, high)}, in registry order (module docstring).

    ``value``: None, '' or {} (none); a mapping {name: [low, high]}; or text ``name=low:high,...``. ``fixed``: the
    fixed perturbations given beside it (a family may be in one of them only). ValueError in one line, prefixed
    ``randomise:``, for an unknown family (with the likely one), a value that is not a range, an end the family does
    not take or low > high."""
    if value is None:
        return {}
    value = _mapping(value, "randomise", RANGE_FORMS)
    checked = {}
    for name, pair in value.items():
        try:
            f = family(str(name))
        except ValueError as error:
            raise ValueError(f"randomise: {error}") from None
        if isinstance(pair, str) or not isinstance(pair, (list, tuple)) or len(pair) != 2:
            raise ValueError(
                f"randomise: {f.name}: expected a range [low, high] (as text {f.name}=low:high), got {pair!r}"
                " (a fixed magnitude is a perturbation: env_options.perturbations)"
            )
        try:
            low, high = (f.check(v) for v in pair)
        except ValueError as error:
            raise ValueError(f"randomise: {error} (in the range {list(pair)!r})") from None
        if low > high:
            raise ValueError(f"randomise: {f.name}: expected low <= high, got [{low:g}, {high:g}]")
        checked[f.name] = (low, high)
    both = [name for name in checked if name in parse(fixed)] if fixed else []
    if both:
        raise ValueError(f"randomise: {', '.join(both)} also fixed in perturbations: give a family in one of them only")
    return {f.name: checked[f.name] for f in FAMILIES if f.name in checked}


def range_text(ranges: Mapping) -> str:
    """A randomisation as :func:`parse_ranges` reads it back (``observation_delay=0:2,friction=0.02:1.2``)."""
    return ",".join(f"{name}={low:g}:{high:g}" for name, (low, high) in parse_ranges(ranges).items())


def randomised(ranges: Mapping, seed: int) -> dict:
    """The magnitudes the episode with this seed takes from a (parsed) randomisation, for its observation, action
    and camera families (a physics family is drawn by the simulator, from its range: :func:`sim_config`): uniform
    in [low, high], an integer family each whole number alike. One uniform per registered family from the
    episode's own generator, whatever is randomised."""
    u = np.random.default_rng([RANDOMISE_STREAM, int(seed)]).random(len(FAMILIES))
    drawn = {}
    for k, f in enumerate(FAMILIES):
        if f.name not in ranges or f.side == PHYSICS:
            continue
        low, high = ranges[f.name]
        if f.integer:
            drawn[f.name] = int(low + min(int(u[k] * (high - low + 1)), high - low))
        else:
            drawn[f.name] = float(low + u[k] * (high - low))
    return drawn


def text(setting: Mapping) -> str:
    """A setting as :func:`parse` reads it back (``observation_delay=2,friction=0.6``; '' for none)."""

    def number(v):
        return ":".join(number(x) for x in v) if isinstance(v, tuple) else f"{v:g}"

    return ",".join(f"{name}={number(m)}" for name, m in parse(setting).items())


def of_side(setting: Mapping, *sides: str) -> dict:
    """The entries of a (parsed) setting whose families are of these sides."""
    return {name: m for name, m in setting.items() if family(name).side in sides}


# ---------------------------------------------------------------------------------------------- physics, camera
def sim_config(setting: Mapping, config=None, ranges: Optional[Mapping] = None):
    """``config`` (a dlo_interface.sim_config.SimConfig, default SimConfig()) with the physics families' ranges (of a setting, a
    magnitude or a pair, and of a parsed randomisation ``ranges``); ``config`` itself (possibly None) when none is
    on."""
    physics = {**of_side(setting, PHYSICS), **of_side(ranges or {}, PHYSICS)}
    if not physics:
        return config
    from dlo_interface.sim_config import SimConfig

    changes = {}
    for name, m in physics.items():
        f = family(name)
        changes[f.sim_range] = tuple(m) if isinstance(m, tuple) else (m, m)
    return dataclasses.replace(config or SimConfig(), **changes)


def cameras(setting: Mapping, camera):
    """(the camera that renders, the camera the vision computation assumes): ``camera`` moved by ``camera_offset``
    [mm] along world +y and turned by ``camera_yaw`` [deg], and ``camera`` itself."""
    offset, yaw = setting.get("camera_offset", 0.0), setting.get("camera_yaw", 0.0)
    if not offset and not yaw:
        return camera, camera
    x, y, z = camera.position
    rendering = dataclasses.replace(camera, position=(x, y + 0.001 * offset, z), yaw=math.radians(yaw))
    return rendering, camera


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
    (:func:`parse_ranges`), its observation and action families drawn per episode (:func:`randomised`) on top of
    the fixed ``setting``. ``active``: any family of these sides on or randomised (else the caller need not call
    it: nothing would change)."""

    def __init__(self, setting: Mapping, modalities, without=(), num_envs: int = 1, ranges: Optional[Mapping] = None):
        from dlo_interface.world import WORKSPACE_HALF_WIDTH
        from dlo_perception.tactile import Y_LIMIT
        from dlo_perception.vision import SEARCH_HALF_WIDTH

        from dlo_policy.observation import observation_labels, parse_modalities

        self.setting = of_side(parse(setting), OBSERVATION, ACTION)
        self.ranges = of_side(parse_ranges(ranges, self.setting), OBSERVATION, ACTION)
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
        for i, seed in zip(np.asarray(env_ids).reshape(-1), np.asarray(seeds).reshape(-1)):
            m = _Magnitudes({**self.setting, **randomised(self.ranges, int(seed))}) if self.ranges else self.fixed
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
