"""Taichi particle-rope simulator of a cable with a two-finger tactile gripper, and its ROS 2 sim node.

``RopeSim`` is imported on first use, so the pure-numpy modules (``dlo_sim.task``,
``dlo_sim.command``) load without starting Taichi.
"""

from .config import SimConfig

__all__ = ["RopeSim", "SimConfig"]


def __getattr__(name):
    if name == "RopeSim":
        from .rope import RopeSim

        return RopeSim
    raise AttributeError(f"module 'dlo_sim' has no attribute {name!r}")
