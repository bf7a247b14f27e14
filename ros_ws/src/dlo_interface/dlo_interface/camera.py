"""The top-view camera: its pinhole model, its image encoding and its CameraInfo. Shared by the renderer of a
simulator, a real camera's driver and the vision distillation.

The camera hangs at ``position`` (world frame, metres) and looks straight down (-z). Its optical
frame (REP-103 camera convention: x right, y down, z forward) has x along world +x and y along
world -y, so the image reads like a map: image column u grows with world x, image row v grows
with -world y. A real top camera publishes the same model as ``sensor_msgs/CameraInfo`` (K) plus
its mounting pose; ``TopCamera.from_camera_info`` rebuilds it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dlo_interface.world import WORKSPACE_HALF_WIDTH

# the image encoding of /dlo/camera/image (mono8): what the vision reads, a renderer draws and a camera driver delivers
IMAGE_CABLE = 255  # pixel value of the cable in the top view
IMAGE_GRIPPER = 128  # pixel value of the gripper (drawn over the cable)
IMAGE_BACKGROUND = 0  # pixel value of everything else


@dataclass(frozen=True)
class TopCamera:
    """Pinhole camera looking down -z. Units: metres and pixels."""

    width: int = 128
    height: int = 128
    fx: float = 0.0
    fy: float = 0.0
    cx: float = 0.0
    cy: float = 0.0
    position: tuple = (0.0, 0.0, 1.0)  # camera centre in the world frame [m]
    # rad, the camera turned about its optical axis (world z), counter-clockwise seen from above: an extrinsic error
    # (dlo_policy.perturbations camera_yaw renders through such a camera); 0 for every camera the graph uses
    yaw: float = 0.0

    @classmethod
    def covering_workspace(
        cls, resolution: int = 128, camera_height: float = 1.0, half_width: float = WORKSPACE_HALF_WIDTH
    ) -> "TopCamera":
        """A square camera centred over the workspace whose view spans ``2 * half_width`` m at the table."""
        if resolution < 8:
            raise ValueError(f"camera resolution must be >= 8 pixels, got {resolution}")
        if camera_height <= 0.2:
            raise ValueError(f"camera height must be above the cable (> 0.2 m), got {camera_height}")
        f = 0.5 * resolution * camera_height / half_width
        c = 0.5 * resolution
        return cls(resolution, resolution, f, f, c, c, (0.0, 0.0, float(camera_height)))

    @classmethod
    def from_camera_info(cls, width: int, height: int, k, position) -> "TopCamera":
        """From a CameraInfo K (row-major 3x3, 9 numbers) and the camera's world position."""
        k = np.asarray(k, dtype=float).reshape(3, 3)
        return cls(
            int(width),
            int(height),
            float(k[0, 0]),
            float(k[1, 1]),
            float(k[0, 2]),
            float(k[1, 2]),
            tuple(float(p) for p in position),
        )

    @property
    def k_matrix(self) -> np.ndarray:
        """The 3x3 intrinsic matrix K (as in sensor_msgs/CameraInfo.k)."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def world_to_pixel(self, points) -> np.ndarray:
        """World points ``(..., 3)`` [m] -> continuous pixel coordinates ``(..., 2)`` as (u, v)."""
        p = np.asarray(points, dtype=np.float64)
        depth = self.position[2] - p[..., 2]
        dx, dy = p[..., 0] - self.position[0], p[..., 1] - self.position[1]
        if self.yaw:
            c, s = np.cos(self.yaw), np.sin(self.yaw)
            dx, dy = c * dx + s * dy, c * dy - s * dx
        u = self.cx + self.fx * dx / depth
        v = self.cy - self.fy * dy / depth
        return np.stack([u, v], axis=-1)

    def pixel_to_world(self, uv, plane_z: float) -> np.ndarray:
        """Pixel coordinates ``(..., 2)`` -> world x, y ``(..., 2)`` [m] on the plane z = ``plane_z``."""
        uv = np.asarray(uv, dtype=np.float64)
        depth = self.position[2] - plane_z
        dx = (uv[..., 0] - self.cx) * depth / self.fx
        dy = -(uv[..., 1] - self.cy) * depth / self.fy
        if self.yaw:
            c, s = np.cos(self.yaw), np.sin(self.yaw)
            dx, dy = c * dx - s * dy, s * dx + c * dy
        return np.stack([self.position[0] + dx, self.position[1] + dy], axis=-1)

    def metres_per_pixel(self, plane_z: float) -> float:
        """Size of one pixel [m] on the plane z = ``plane_z``."""
        return (self.position[2] - plane_z) / self.fx


CAMERA_FRAME = "top_camera_optical"  # frame_id of /dlo/camera/image and /dlo/camera/camera_info


def camera_info(camera: TopCamera, frame_id: str = CAMERA_FRAME):
    """The sensor_msgs/CameraInfo of ``camera``: undistorted pinhole, K, R = I, P = [K | 0] (header
    stamp left to the caller). Used by the simulator and the driver template alike."""
    from sensor_msgs.msg import CameraInfo  # message type only, no rclpy

    info = CameraInfo(width=camera.width, height=camera.height, distortion_model="plumb_bob")
    info.header.frame_id = frame_id
    info.k = camera.k_matrix.reshape(-1).tolist()
    info.d = [0.0] * 5
    info.r = np.eye(3).reshape(-1).tolist()
    info.p = np.hstack([camera.k_matrix, np.zeros((3, 1))]).reshape(-1).tolist()
    return info
