"""Taichi particle-rope simulator of a cable with a two-finger tactile gripper, and its ROS 2 sim node.

The reference simulator of the contract ``dlo_interface`` (its world, task, grip law, camera and commands):
``dlo_sim.episode.TaskSim`` is registered as the simulator backend ``taichi`` (``dlo_interface.simulator``).
``RopeSim`` is imported on first use, so importing the package starts no Taichi.
"""

__all__ = ["RopeSim"]


def __getattr__(name):
    if name == "RopeSim":
        from .rope import RopeSim

        return RopeSim
    raise AttributeError(f"module 'dlo_sim' has no attribute {name!r}")
