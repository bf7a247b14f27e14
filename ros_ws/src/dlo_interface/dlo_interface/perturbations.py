"""Perturbations: named families, each off by default, in one registry (``FAMILIES``). Pure Python (numpy).

The contract's part of the robustness perturbations (issue 40): the families, their magnitudes and how a setting
is read (:func:`parse`, :func:`parse_ranges`), and what a simulator does with the physics and camera families
(:func:`sim_config`, :func:`cameras`). The gym env (``dlo_policy.env``) and the sim node (``dlo_sim.sim_node``, its
``perturbations`` parameter) both apply those from here; the observation and action families are applied over the
observation and the action by ``dlo_policy.perturbations.Perturber`` (the gym env and the policy node), which
re-exports every name of this module. ``python -m dlo_policy.perturbations`` lists the families.

A perturbation setting maps family names to magnitudes, e.g. ``{"observation_delay": 2, "friction": 0.6}``,
written as text ``observation_delay=2,friction=0.6`` (one reading, :func:`parse`, wherever it is given: the gym
env's option ``perturbations``, dlo-train's ``env_options.perturbations``, the policy node's and the sim node's
parameter ``perturbations`` (each takes the families it owns, :func:`owned`), ``dlo-robustness``). A family left
out, or given its ``off`` value, is off, and then nothing about the env or the node changes (no random number is
drawn).

Each family is applied in ONE place, by its ``side``:

- ``observation`` and ``action``: over the observation vector and the action (``dlo_policy.perturbations``, whose
  docstring says what each family does); in the graph the policy node's.
- ``physics`` (``dlo_interface.sim_config.SimConfig`` ranges, :func:`sim_config`, drawn per episode by the
  simulator): ``friction``, ``stretch_stiffness``, ``bending_stiffness``, ``cable_length`` (particles, 4.3 mm apart)
  and ``particle_mass`` [kg] fixed at the magnitude (a pair [low, high]: drawn uniformly per episode) instead of
  the training ranges; in the graph the sim node's.
- ``camera`` (``dlo_interface.camera.TopCamera``, :func:`cameras`): the image is rendered by a camera moved
  ``camera_offset`` mm along world +y or turned ``camera_yaw`` degrees about its optical axis, while the vision
  computation assumes the nominal camera (an extrinsic calibration error); in the graph the sim node renders
  through the moved camera and publishes the nominal one's ``camera_info``.

Domain randomisation (training): a *randomisation* maps families to ranges, ``{"observation_delay": [0, 2],
"friction": [0.02, 1.2]}``, as text ``observation_delay=0:2,friction=0.02:1.2`` (:func:`parse_ranges`: the gym env's
option ``randomise``, dlo-train's ``env_options.randomise``). Every episode takes each family's magnitude uniformly
from its range (an integer family: each whole number alike): an observation, action or camera family from the
episode's own generator (:func:`randomised`, seeded from the episode's seed on a stream of its own, one uniform per
registered family whatever is randomised: the same episode gets the same magnitudes in any batch and whichever
other families are randomised), a physics family by the simulator's own per-episode draw, its range replacing the
training range. A family is either fixed (``perturbations``) or randomised, not both; with no randomisation
nothing is drawn.

How the observation, action and camera families are drawn is the randomisation's *draw* (``DRAWS``; the gym env's
option ``randomise_draw``, :func:`check_draw`): ``all`` (the default) as above, every one of them every episode;
``one``: each episode takes ONE of the n randomised observation, action and camera families, or none, each of the
n + 1 choices alike (from a generator of its own, seeded from the episode's seed on the stream ``CHOICE_STREAM``, so
that the ``all`` draws stay what they were), at the magnitude ``all`` gives it in that episode; the others are off
(their ``off`` value) in that episode. The physics families are drawn by the simulator every episode either way.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
from dataclasses import dataclass
from typing import Any, Mapping, Optional

import numpy as np

OBSERVATION, ACTION, PHYSICS, CAMERA = "observation", "action", "physics", "camera"
SIDES = (OBSERVATION, ACTION, PHYSICS, CAMERA)
RANDOMISE_STREAM = 0x5EED  # mixed into each episode's seed: its randomised magnitudes, another stream
CHOICE_STREAM = 0xC40E  # mixed into each episode's seed: which family a "one" draw takes, a stream of its own
DRAWS = ("all", "one")  # how a randomisation draws its non-physics families (module docstring)
DEFAULT_DRAW = "all"


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
    sim_param: str = ""  # physics: the simulator's per-episode parameter it is (a simulator's ``params``)

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


def check_draw(value) -> str:
    """A randomisation's draw (``DRAWS``, module docstring) as given; ValueError in one line otherwise."""
    if not isinstance(value, str) or value not in DRAWS:
        raise ValueError(f"randomise_draw: expected {' or '.join(DRAWS)}, got {value!r}")
    return value


def randomised(ranges: Mapping, seed: int, draw: str) -> dict:
    """The magnitudes the episode with this seed takes from a (parsed) randomisation, for its observation, action
    and camera families (a physics family is drawn by the simulator, from its range: :func:`sim_config`): uniform
    in [low, high], an integer family each whole number alike. One uniform per registered family from the
    episode's own generator, whatever is randomised. ``draw`` (``DRAWS``, every caller says which): ``all``, each
    family at its magnitude; ``one``, one of them (or none, each of the n + 1 choices alike, from the episode's
    generator on ``CHOICE_STREAM``) at its magnitude, every other family at its ``off`` value: each randomised
    family is in the result either way."""
    check_draw(draw)
    u = np.random.default_rng([RANDOMISE_STREAM, int(seed)]).random(len(FAMILIES))
    on = [f.name for f in FAMILIES if f.name in ranges and f.side != PHYSICS]  # the families this episode perturbs
    if draw == "one":
        choice = int(np.random.default_rng([CHOICE_STREAM, int(seed)]).integers(len(on) + 1))
        on = on[choice : choice + 1]  # choice n: none
    drawn = {}
    for k, f in enumerate(FAMILIES):
        if f.name not in ranges or f.side == PHYSICS:
            continue
        low, high = ranges[f.name]
        if f.name not in on:
            drawn[f.name] = int(f.off) if f.integer else float(f.off)
        elif f.integer:
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
    """``config`` (a dlo_interface.sim_config.SimConfig, default SimConfig()) with the physics families' ranges (of
    a setting, a magnitude or a pair, and of a parsed randomisation ``ranges``); ``config`` itself (possibly None)
    when none is on. The gym env and the sim node build their simulator's config so."""
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
    [mm] along world +y and turned by ``camera_yaw`` [deg], and ``camera`` itself (the gym env renders through the
    first and hands the vision the second; the sim node renders through the first and publishes the second's
    camera_info)."""
    offset, yaw = setting.get("camera_offset", 0.0), setting.get("camera_yaw", 0.0)
    if not offset and not yaw:
        return camera, camera
    x, y, z = camera.position
    rendering = dataclasses.replace(camera, position=(x, y + 0.001 * offset, z), yaw=math.radians(yaw))
    return rendering, camera


# ---------------------------------------------------------------------------------------------- the graph's owners
# which node of the graph applies which sides (the gym env applies all of them): the sim node renders and steps the
# physics, the policy node sees the observation and sends the action
OWNERS = {"simulator": (PHYSICS, CAMERA), "policy node": (OBSERVATION, ACTION)}


def owned(value, owner: str) -> dict:
    """A node's ``perturbations`` parameter (text, :func:`parse`) -> the setting of the families ``owner`` (a key of
    ``OWNERS``) applies; ValueError in one line for a bad setting or a family another node owns."""
    if not isinstance(value, str):
        raise ValueError(f"expected {FORMS}, got {value!r}")
    setting = parse(value)
    sides = OWNERS[owner]
    elsewhere = [name for name in setting if family(name).side not in sides]
    if elsewhere:
        other = next(o for o, s in OWNERS.items() if family(elsewhere[0]).side in s)
        raise ValueError(
            f"{', '.join(elsewhere)}: {' and '.join(OWNERS[other])} perturbations belong to the {other}, not the "
            f"{owner} (here: {', '.join(n for side in sides for n in names(side))})"
        )
    return setting
