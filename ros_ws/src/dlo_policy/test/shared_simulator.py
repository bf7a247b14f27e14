"""A simulator factory for a test module that builds several vector envs alike, one after the other: the rope
simulator is built once per set of arguments and handed to every env built with them.

Building a rope simulator compiles its Taichi kernels (seconds, each time: dlo_sim.kernels), and an env's reset
restarts every env it resets from its episode seed alone (dlo_sim.rope: the same seed gives a bit-identical
episode), so an env that is reset before it steps runs the episodes that a simulator of its own would. Give it
to make_vec_env as the option ``simulator`` (dlo_interface.simulator: a backend's factory). For envs used one
at a time only: they share one simulator state.
"""

from typing import Any

from dlo_interface.simulator import DEFAULT_SIMULATOR, simulator_factory


class SharedSimulator:
    """``simulator``: the default backend's simulator, one per set of arguments (``num_envs`` and options)."""

    def __init__(self) -> None:
        self.built: dict[str, Any] = {}

    def __call__(self, num_envs: int, **options: Any) -> Any:
        key = repr((num_envs, sorted(options.items())))
        if key not in self.built:
            self.built[key] = simulator_factory(DEFAULT_SIMULATOR)(num_envs, **options)
        return self.built[key]
