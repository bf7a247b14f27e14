"""Taichi particle-rope simulator of a cable with a two-finger tactile gripper, and its ROS 2 sim node."""

from .config import SimConfig
from .rope import RopeSim

__all__ = ["RopeSim", "SimConfig"]
