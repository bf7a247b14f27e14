"""The simulator backend: what the gym environment steps, and how it finds one (a Python entry point).

The gym environment (``dlo_policy.env``) does not import a simulator. It asks this module for a *factory*,

    factory(num_envs, *, horizon, end_particles, task_rules, move_spacing, config, camera, render[, camera_per_env])
        -> Simulator

and steps what it returns. A backend registers its factory as an entry point of the group ``ENTRY_POINT_GROUP``
in its package's ``setup.py``; the reference backend, ``dlo_sim``'s Taichi rope, is registered as ``taichi``::

    entry_points={"dlo_interface.simulators": ["taichi = dlo_sim.episode:TaskSim"]}

The env option ``simulator`` (``dlo-train env_options.simulator=NAME``) names the backend, ``DEFAULT_SIMULATOR``
when it is not given; a factory (any callable) may be passed to the env in its place (tests, experiments).
docs/ARCHITECTURE.md#simulator-backends says what a new backend must provide and how to plug it in.

``task_rules`` and ``move_spacing`` are the task's (``dlo_interface.task``): the backend hands them to the
``EpisodeTracker`` it builds. ``Simulator`` and ``Physics`` state what the env, the observation modalities
(``dlo_policy.modalities``), the scripted baselines and the evaluation read: the task's bookkeeping is
``dlo_interface.task.EpisodeTracker``, the same object for every backend, so rewards, episode ends and outcomes
cannot differ between them.
"""

from __future__ import annotations

from functools import lru_cache
from importlib.metadata import entry_points
from typing import Any, Callable, Optional, Protocol, Union

import numpy as np

ENTRY_POINT_GROUP = "dlo_interface.simulators"
DEFAULT_SIMULATOR = "taichi"  # dlo_sim.episode:TaskSim, the reference simulator


class Physics(Protocol):
    """The batched physics of N environments, as the observation and the baselines read its ground truth.

    num_particles   (N,) int, the particles of each environment's cable (rows beyond it are padding)
    cable_length    (N,) float, m
    config          the ``dlo_interface.sim_config.SimConfig`` it runs
    camera          the ``dlo_interface.camera.TopCamera`` it renders through
    params          {name: (N,) array} the physics each episode drew (``friction``, ``stretch``, ``bending``,
                    ``num_particles``, ``particle_mass``): read by domain randomisation to record them
    """

    num_envs: int
    num_particles: np.ndarray
    cable_length: np.ndarray
    config: Any
    camera: Any
    params: dict

    def positions(self) -> np.ndarray:
        """(N, P_MAX, 3) float32 particle positions [m] (padding rows 0)."""

    def held_mask(self) -> np.ndarray:
        """(N, P_MAX) bool, the particles between the fingers (the physics' held rule)."""

    def gripper_state(self) -> np.ndarray:
        """(N, 4) float32: x, y, z [m] and closure c [0, 1]."""

    def render(self) -> np.ndarray:
        """(N, height, width) uint8 top view in the encoding of ``dlo_interface.camera`` (IMAGE_*)."""

    def set_camera(self, env_ids, offsets, yaws) -> None:
        """Only when built with ``camera_per_env=True`` (a randomised camera family): environment ``env_ids[k]``
        renders through ``camera`` moved by ``offsets[k]`` (x, y) [m] and turned by ``yaws[k]`` [rad]."""


class Simulator(Protocol):
    """N environments of the task: physics plus the task's bookkeeping, stepped one control step at a time.

    state                    the current snapshot: ``positions`` (N, P_MAX, 3), ``held`` (N, P_MAX) bool,
                             ``gripper`` (N, 4) x, y, z, c, ``image`` (N, H, W) uint8 when ``render`` else None
    n_held, mean_held_index  (N,) held statistics of ``state.held`` (``dlo_interface.task.held_statistics``)
    mean_held_index_authors  (N,) the same for the authors' held set (``dlo_interface.task.held_mask_authors``)
    held_task                (N, P_MAX) bool, the held set the task rules use (reward, end, tactile input)
    tracker                  the ``dlo_interface.task.EpisodeTracker`` of the episodes
    sim                      the ``Physics``
    render                   whether ``state.image`` is rendered
    """

    num_envs: int
    state: Any
    n_held: np.ndarray
    mean_held_index: np.ndarray
    mean_held_index_authors: np.ndarray
    held_task: np.ndarray
    tracker: Any
    sim: Physics
    render: bool

    def reset(self, seeds, env_ids=None) -> None:
        """Start new episodes from ``seeds`` (one per environment of ``env_ids``, all if None)."""

    def step(self, actions) -> tuple:
        """One control step of every environment (actions (N, 3) in [-1, 1], ``dlo_interface.command``) ->
        (reward, terminated, truncated, unstable), (N,) each; an environment the physics had to reset
        (``unstable``) ends its episode as truncated."""


SimulatorFactory = Callable[..., Simulator]


class UnknownSimulator(ValueError):
    """No simulator backend of that name is registered (one line, naming the registered ones)."""


@lru_cache(maxsize=None)
def registered() -> dict:
    """{name: entry point} of every registered simulator backend."""
    return {point.name: point for point in entry_points(group=ENTRY_POINT_GROUP)}


def check_simulator(name) -> str:
    """``name`` if a backend of that name is registered, else UnknownSimulator with a one-line reason."""
    known = registered()
    if name not in known:
        found = ", ".join(sorted(known)) or "none (build the workspace: bash scripts/setup.sh)"
        raise UnknownSimulator(f"simulator: no backend {name!r} registered in {ENTRY_POINT_GROUP}; registered: {found}")
    return name


def simulator_factory(simulator: Union[str, SimulatorFactory, None] = None) -> SimulatorFactory:
    """The factory of ``simulator``: a registered backend's name, a factory itself, or None (DEFAULT_SIMULATOR)."""
    if callable(simulator):
        return simulator
    return registered()[check_simulator(DEFAULT_SIMULATOR if simulator is None else simulator)].load()


def make_simulator(num_envs: int, simulator: Optional[Union[str, SimulatorFactory]] = None, **options) -> Simulator:
    """``num_envs`` environments of the backend ``simulator`` (``simulator_factory``), built with ``options``."""
    return simulator_factory(simulator)(num_envs, **options)
