"""Vision distillation O_V = [v_V, q_V, theta_V, y_V] of the cable just right of the gripper.

Definition (DESIGN.md section 9, after the authors' code): the gripper hides the cable up to
``x_o = x_G + OCCLUSION_RADIUS``. Entering the region right of it within ``SEARCH_HALF_WIDTH`` of
the gripper in y, the strand closest to the gripper in y is followed to the right while it keeps
heading right, for at most ``TRACK_LENGTH``:

- ``visible`` v_V: such a strand exists.
- ``confidence`` q_V = min(1, dx / CONFIDENCE_LENGTH), dx [m] how far right of ``x_o`` it goes.
- ``angle`` theta_V [rad]: angle to gripper x (counter-clockwise about +z) of a line y(x) fitted
  to the followed strand.
- ``y`` y_V [m]: the strand's y where it enters, relative to y_G, within +-SEARCH_HALF_WIDTH.
Not visible -> confidence = angle = y = 0.

``visual_pose`` measures it from the top-view image (what a real camera gives);
``visual_pose_ground_truth`` from the particles (to validate the image pipeline).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dlo_perception.camera import TopCamera

IMAGE_CABLE = 255  # pixel value of the cable in the rendered top view
IMAGE_GRIPPER = 128  # pixel value of the gripper
GRIPPER_MARGIN_PIXELS = 4  # columns searched for gripper pixels beyond the occlusion radius
OCCLUSION_RADIUS = 0.0125 + 0.002  # m, finger radius + 2 mm: the gripper hides x <= x_G + this
SEARCH_HALF_WIDTH = 0.03  # m, |y - y_G| window in which the strand must enter
CONFIDENCE_LENGTH = 0.024  # m, dx giving q_V = 1
TRACK_LENGTH = 0.043  # m, at most 10 particle spacings of the strand are followed
ENTRY_BAND = 0.006  # m, ground truth: first particle beyond x_o lies within this band (> spacing)
CABLE_RADIUS = 0.008  # m, drawn cable radius: the image strand ends this far past the last centre


@dataclass
class VisualPose:
    """Visual reading; arrays of shape (N,) for a batch."""

    visible: np.ndarray  # bool
    confidence: np.ndarray  # q_V in [0, 1]
    angle: np.ndarray  # theta_V [rad]
    y: np.ndarray  # y_V [m]


def visual_pose(images, camera: TopCamera, gripper_xy, plane_z: float) -> VisualPose:
    """O_V from top-view images.

    images: (N, H, W) uint8 (cable 255, gripper 128, background 0). camera: the TopCamera that took
    them. gripper_xy: (N, >=2) gripper position [m]. plane_z: height [m] of the gripper and of the
    cable next to it (the gripper's height): pixel offsets are converted to metres at this plane.
    Pixel (row v, column u) covers continuous pixel coordinates [u, u+1) x [v, v+1).
    """
    images = np.asarray(images)
    n, height, width = images.shape
    gripper = np.asarray(gripper_xy, dtype=np.float64).reshape(n, -1)[:, :2]
    metres_per_pixel = camera.metres_per_pixel(plane_z)
    uv = camera.world_to_pixel(np.concatenate([gripper, np.full((n, 1), plane_z)], axis=1))
    u_occluded = uv[:, 0] + OCCLUSION_RADIUS / metres_per_pixel  # right edge of the occlusion [px]
    num_columns = int(np.ceil(TRACK_LENGTH / metres_per_pixel))
    half_rows = int(np.ceil((SEARCH_HALF_WIDTH + TRACK_LENGTH) / metres_per_pixel))
    centre_row = np.floor(uv[:, 1]).astype(np.int64)
    centre_column = np.floor(uv[:, 0]).astype(np.int64)
    margin_columns = int(np.ceil(OCCLUSION_RADIUS / metres_per_pixel)) + GRIPPER_MARGIN_PIXELS

    # Patch from the gripper centre rightwards: (N, rows, columns); outside the image = background.
    row_offsets = np.arange(-half_rows, half_rows + 1)
    rows = centre_row[:, None] + row_offsets
    cols = centre_column[:, None] + np.arange(margin_columns + num_columns)
    inside = ((rows >= 0) & (rows < height))[:, :, None] & ((cols >= 0) & (cols < width))[:, None, :]
    patch = images[np.arange(n)[:, None, None], np.clip(rows, 0, height - 1)[:, :, None],
                   np.clip(cols, 0, width - 1)[:, None, :]]
    patch = np.where(inside, patch, 0)
    # The strand starts in the first column centred beyond the occlusion edge and past every gripper
    # pixel (the drawn finger sits higher and may look wider than the occlusion radius).
    first_column = np.ceil(u_occluded - 0.5).astype(np.int64) - centre_column
    is_gripper = (patch == IMAGE_GRIPPER).any(axis=1)
    last_gripper = np.where(is_gripper.any(axis=1), patch.shape[2] - 1 - np.argmax(is_gripper[:, ::-1], axis=1), -1)
    first_column = np.maximum(first_column, last_gripper + 1)
    column_index = first_column[:, None] + np.arange(num_columns)  # (N, columns) into the patch
    column_valid = column_index < patch.shape[2]
    strip = np.take_along_axis(patch, np.minimum(column_index, patch.shape[2] - 1)[:, None, :], axis=2)
    cable = (strip == IMAGE_CABLE) & column_valid[:, None, :]
    # Vertical runs of cable pixels per column: run_id increases at every run start.
    starts = cable & ~np.concatenate([np.zeros_like(cable[:, :1]), cable[:, :-1]], axis=1)
    run_id = np.cumsum(starts, axis=1)

    row_pos = (row_offsets + 0.5)[None, :] + (centre_row - uv[:, 1])[:, None]  # row centre - v_G [px]
    gate_half = SEARCH_HALF_WIDTH / metres_per_pixel
    gate_lo, gate_hi = np.full(n, -gate_half), np.full(n, gate_half)  # rows the next run must touch
    predicted = np.zeros(n)
    slope = np.zeros(n)  # rows per column of the followed strand
    radius_pixels = CABLE_RADIUS / metres_per_pixel
    tracking = np.ones(n, dtype=bool)
    centroids = np.zeros((n, num_columns))
    tracked = np.zeros((n, num_columns), dtype=bool)
    for k in range(num_columns):
        column = cable[:, :, k]
        candidate = column & (row_pos >= gate_lo[:, None] - 1) & (row_pos <= gate_hi[:, None] + 1)
        found = tracking & candidate.any(axis=1)
        nearest = np.argmin(np.where(candidate, np.abs(row_pos - predicted[:, None]), np.inf), axis=1)
        in_run = column & (run_id[:, :, k] == run_id[np.arange(n), nearest, k][:, None])
        # A run much longer than one strand (another strand crossing here) is cut to the part
        # around the prediction: half a strand's vertical extent at the current slope.
        half_extent = radius_pixels * np.sqrt(1.0 + slope ** 2) + 0.5
        merged = (in_run.sum(axis=1) > 2.0 * half_extent + 2.0) & (k > 0)
        strand = in_run & (~merged[:, None] | (np.abs(row_pos - predicted[:, None]) <= half_extent[:, None]))
        strand |= ~strand.any(axis=1)[:, None] & (np.arange(len(row_offsets)) == nearest[:, None])
        strand_size = np.maximum(strand.sum(axis=1), 1)
        centroid = np.where(found, (strand * row_pos).sum(axis=1) / strand_size, 0.0)
        gate_lo = np.where(found, np.where(strand, row_pos, np.inf).min(axis=1), gate_lo)
        gate_hi = np.where(found, np.where(strand, row_pos, -np.inf).max(axis=1), gate_hi)
        centroids[:, k] = centroid
        tracked[:, k] = found
        slope = np.where(found, (centroid - centroids[:, 0]) / max(k, 1), slope)
        predicted = np.where(found, centroid + slope, predicted)
        tracking = found

    visible = tracked[:, 0]
    length = tracked.sum(axis=1)
    # From the occlusion edge to the centre of the last strand column, less the drawn cable radius.
    dx = (centre_column + first_column + length - 0.5 - u_occluded) * metres_per_pixel - CABLE_RADIUS
    confidence = np.where(visible, np.clip(dx / CONFIDENCE_LENGTH, 0.0, 1.0), 0.0)
    # World y grows with -row, so world slope = -(row slope) and y_V = -row offset.
    column_x = np.broadcast_to(np.arange(num_columns, dtype=np.float64), (n, num_columns))
    angle = np.arctan(-line_slope(column_x, centroids, tracked))
    y = np.where(visible, np.clip(-centroids[:, 0] * metres_per_pixel, -SEARCH_HALF_WIDTH, SEARCH_HALF_WIDTH), 0.0)
    return VisualPose(visible, confidence, np.where(visible, angle, 0.0), y)


def visual_pose_ground_truth(positions, num_particles, gripper_xy) -> VisualPose:
    """O_V from particle positions (N, P, >=2) [m], num_particles (N,) and gripper_xy (N, >=2) [m].

    Entry = among particles with x in [x_o, x_o + ENTRY_BAND] and |y - y_G| <= SEARCH_HALF_WIDTH the
    one closest to y_G; from it the cable is walked by index (towards the side that heads right) for
    up to 10 particles while x keeps increasing and x - x_o <= TRACK_LENGTH.
    """
    positions = np.asarray(positions, dtype=np.float64)
    n, p_max = positions.shape[:2]
    num_particles = np.asarray(num_particles).reshape(n)
    gripper = np.asarray(gripper_xy, dtype=np.float64).reshape(n, -1)[:, :2]
    x, y = positions[..., 0], positions[..., 1]
    x_occluded = gripper[:, 0] + OCCLUSION_RADIUS
    dy = y - gripper[:, 1:2]
    index = np.arange(p_max)
    valid = index[None, :] < num_particles[:, None]
    rel_x = x - x_occluded[:, None]
    candidate = valid & (rel_x >= 0) & (rel_x <= ENTRY_BAND) & (np.abs(dy) <= SEARCH_HALF_WIDTH)
    visible = candidate.any(axis=1)
    entry = np.argmin(np.where(candidate, np.abs(dy), np.inf), axis=1)

    rows = np.arange(n)
    last = num_particles - 1
    forward_x = x[rows, np.minimum(entry + 1, p_max - 1)]
    heads_forward = (entry < last) & (forward_x > x[rows, entry])
    direction = np.where(heads_forward, 1, -1)
    steps = np.arange(11)
    walk = entry[:, None] + direction[:, None] * steps[None, :]
    in_cable = (walk >= 0) & (walk <= last[:, None])
    walk = np.clip(walk, 0, p_max - 1)
    walk_x, walk_y = x[rows[:, None], walk], y[rows[:, None], walk]
    rightward = np.concatenate([np.ones((n, 1), bool), np.diff(walk_x, axis=1) > 0], axis=1)
    near = walk_x - x_occluded[:, None] <= TRACK_LENGTH
    followed = np.cumprod(in_cable & rightward & near, axis=1).astype(bool) & visible[:, None]

    dx = np.max(np.where(followed, walk_x, -np.inf), axis=1) - x_occluded
    confidence = np.where(visible, np.clip(dx / CONFIDENCE_LENGTH, 0.0, 1.0), 0.0)
    angle = np.arctan(line_slope(walk_x, walk_y, followed))
    y_entry = y[rows, entry] - gripper[:, 1]
    return VisualPose(visible, confidence, np.where(visible, angle, 0.0), np.where(visible, y_entry, 0.0))


def line_slope(xs, ys, mask) -> np.ndarray:
    """Least-squares slope dy/dx per row of (N, K) samples where mask; 0 with < 2 samples or no x spread."""
    count = mask.sum(axis=1)
    safe_count = np.maximum(count, 1)
    mean_x = np.where(mask, xs, 0.0).sum(axis=1) / safe_count
    mean_y = np.where(mask, ys, 0.0).sum(axis=1) / safe_count
    dx = np.where(mask, xs - mean_x[:, None], 0.0)
    dy = np.where(mask, ys - mean_y[:, None], 0.0)
    sxx = (dx * dx).sum(axis=1)
    sxy = (dx * dy).sum(axis=1)
    return np.where((count >= 2) & (sxx > 0), sxy / np.where(sxx > 0, sxx, 1.0), 0.0)
