"""The particle cloud layout of ``/dlo/rope/particles`` (sensor_msgs/PointCloud2), both ways.

Points are the cable's particles in index order (0 = fixed end), fields ``x, y, z`` [m] and
``held`` (1.0 = between the fingers, else 0.0), all FLOAT32, little endian, point_step 16. The
functions work on rclpy and rosbags messages alike (same field names), so nodes and bag analysis
share them.
"""

from __future__ import annotations

import numpy as np

FIELD_NAMES = ("x", "y", "z", "held")
FLOAT32 = 7  # sensor_msgs/PointField.FLOAT32
POINT_STEP = 16
POINT_DTYPE = np.dtype([(name, "<f4") for name in FIELD_NAMES])


def pack_particles(positions, held) -> bytes:
    """(P, 3) positions [m] and (P,) held flags -> the cloud's data bytes."""
    positions = np.asarray(positions, dtype=np.float32)
    points = np.empty(len(positions), dtype=POINT_DTYPE)
    points["x"], points["y"], points["z"] = positions[:, 0], positions[:, 1], positions[:, 2]
    points["held"] = np.asarray(held, dtype=np.float32)
    return points.tobytes()


def particle_cloud(positions, held):
    """A sensor_msgs/PointCloud2 of the particles in this layout (header left to the caller)."""
    from sensor_msgs.msg import PointCloud2, PointField  # message types only, no rclpy

    cloud = PointCloud2(
        height=1,
        width=len(positions),
        is_bigendian=False,
        point_step=POINT_STEP,
        row_step=POINT_STEP * len(positions),
        is_dense=True,
        data=pack_particles(positions, held),
    )
    cloud.fields = [PointField(name=n, offset=4 * i, datatype=FLOAT32, count=1) for i, n in enumerate(FIELD_NAMES)]
    return cloud


def unpack_particles(msg):
    """A particle cloud message -> ((P, 3) float32 positions [m], (P,) bool held)."""
    names = [f.name for f in msg.fields]
    if tuple(names) != FIELD_NAMES or int(msg.point_step) != POINT_STEP:
        raise ValueError(f"not a dlo particle cloud: fields {names}, point_step {msg.point_step}")
    points = np.frombuffer(bytes(msg.data), dtype=POINT_DTYPE, count=int(msg.width) * int(msg.height))
    positions = np.stack([points["x"], points["y"], points["z"]], axis=1)
    return positions, points["held"] > 0.5
