"""Vision distillation O_V = [v_V, q_V, theta_V, y_V] of the cable just right of the gripper.

Definition (after the authors' code, docs/ARCHITECTURE.md#constants): the gripper hides the cable up to
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

``visual_pose_particles`` is the other source (``VISION_SOURCES``, env option and vision node
parameter ``vision_source``): the paper's simplified scalars, computed as the authors' environment
computes them (SoftSlidingGym ``rope_sliding_env.py`` ``_get_obs``, docs/FIDELITY.md row 11), by
walking particle indices from the task rules' held set instead of looking at the cable:

- edge: from the highest held index, at most ``WALK_STEPS`` indices up, the first particle right of
  ``x_G + OCCLUSION_RADIUS``, or the one whose next index reaches the authors' segment count
  s = n_c - 1 (their last index check); the highest held index if neither happens.
- ``visible``: the edge's next index is below s (0 near the end: the edge at n_c - 2 or beyond).
  ``y``: that next particle's y relative to y_G.
- from the edge, at most ``WALK_STEPS`` indices up while x does not fall back more than
  ``BACKTRACK`` below the edge's and the index stays below s - 1: the last one reached, r.
  ``confidence`` = min(1, (x_r - x_edge) / CONFIDENCE_LENGTH) if x_r > x_edge, else 0;
  ``angle`` = atan of the slope of a line y(x) through edge .. r - 1 (0 with fewer than two of them;
  the authors' fit of one point is ill-posed), else 0.
Fewer than two held particles (no contact, as the tactile reading): not visible, all zeros.
"""

from dataclasses import dataclass

import numpy as np
from dlo_common import taichi_runtime  # before taichi: no "[Taichi] version" banner on stdout (see there)

# isort: split
import taichi as ti
from dlo_interface.camera import IMAGE_CABLE, IMAGE_GRIPPER, TopCamera
from dlo_interface.world import FINGER_RADIUS, PARTICLE_RADIUS

from dlo_perception.vision_source import DEFAULT_VISION_SOURCE, VISION_SOURCES, check_vision_source  # noqa: F401

GRIPPER_MARGIN_PIXELS = 4  # columns searched for gripper pixels beyond the occlusion radius
OCCLUSION_RADIUS = FINGER_RADIUS + 0.002  # m, finger radius + 2 mm: the gripper hides x <= x_G + this
SEARCH_HALF_WIDTH = 0.03  # m, |y - y_G| window in which the strand must enter
CONFIDENCE_LENGTH = 0.024  # m, dx giving q_V = 1
TRACK_LENGTH = 0.043  # m, at most 10 particle spacings of the strand are followed
ENTRY_BAND = 0.006  # m, ground truth: first particle beyond x_o lies within this band (> spacing)
CABLE_RADIUS = PARTICLE_RADIUS  # m, drawn cable radius: the image strand ends this far past the last centre
WALK_STEPS = 10  # particles, particles-source: how far each index walk goes (the authors' range(10))
BACKTRACK = 0.25 * 0.008  # m, particles-source: the walk right stops where x falls back more than this


@dataclass
class VisualPose:
    """Visual reading; arrays of shape (N,) for a batch."""

    visible: np.ndarray  # bool
    confidence: np.ndarray  # q_V in [0, 1]
    angle: np.ndarray  # theta_V [rad]
    y: np.ndarray  # y_V [m]


def visual_pose(images, camera: TopCamera, gripper_xy, plane_z: float) -> VisualPose:
    """O_V from top-view images (numpy, from the renderer or a real camera); one Taichi kernel.

    images: (N, H, W) uint8 (cable 255, gripper 128, background 0). camera: the TopCamera that took
    them. gripper_xy: (N, >=2) gripper position [m]. plane_z: height [m] of the gripper and of the
    cable next to it (the gripper's height): pixel offsets are converted to metres at this plane.
    Pixel (row v, column u) covers continuous pixel coordinates [u, u+1) x [v, v+1).
    """
    taichi_runtime.init()
    images = np.ascontiguousarray(images, dtype=np.uint8)
    n = images.shape[0]
    gripper = np.asarray(gripper_xy, dtype=np.float64).reshape(n, -1)[:, :2] if n else np.empty((0, 2))
    metres_per_pixel = camera.metres_per_pixel(plane_z)
    uv = camera.world_to_pixel(np.concatenate([gripper, np.full((n, 1), plane_z)], axis=1))
    pose = np.empty((n, 4))
    if n > 0:
        _track_strands(images, uv, pose, metres_per_pixel, n == 1)
    return VisualPose(pose[:, 0] > 0.0, pose[:, 1], pose[:, 2], pose[:, 3])


@ti.func
def _patch_pixel(images: ti.template(), e, row, column) -> ti.i32:
    """Pixel value of image e at (row, column); 0 (background) outside the image."""
    value = 0
    if 0 <= row < images.shape[1] and 0 <= column < images.shape[2]:
        value = ti.cast(images[e, row, column], ti.i32)
    return value


@ti.func
def _strand_start(images: ti.template(), e, centre_row, centre_column, patch_columns, half_rows, first_column) -> ti.i32:
    """The patch column (relative to the gripper's) where the strand starts: ``first_column`` (the first centred
    beyond the occlusion edge), moved past every gripper pixel in the patch's ``patch_columns`` columns."""
    start = first_column
    for c in range(patch_columns):
        for r in range(-half_rows, half_rows + 1):
            if _patch_pixel(images, e, centre_row + r, centre_column + c) == IMAGE_GRIPPER:
                start = ti.max(start, c + 1)
    return start


@ti.func
def _nearest_cable_row(images: ti.template(), e, centre_row, column, half_rows, row_shift, gate_lo, gate_hi, predicted) -> ti.i32:
    """The patch row (relative to ``centre_row``) of ``column``'s cable pixel nearest to the ``predicted`` row
    position among those whose position lies within the gate (+-1); ``half_rows + 1`` when there is none."""
    nearest = half_rows + 1  # none
    best = ti.f64(0.0)
    for r in range(-half_rows, half_rows + 1):
        pos = r + row_shift
        if _patch_pixel(images, e, centre_row + r, column) == IMAGE_CABLE and gate_lo - 1.0 <= pos <= gate_hi + 1.0:
            if nearest > half_rows or ti.abs(pos - predicted) < best:
                nearest = r
                best = ti.abs(pos - predicted)
    return nearest


@ti.kernel
def _track_strands(
    images: ti.types.ndarray(dtype=ti.u8, ndim=3),
    gripper_uv: ti.types.ndarray(dtype=ti.f64, ndim=2),
    pose: ti.types.ndarray(dtype=ti.f64, ndim=2),
    metres_per_pixel: ti.f64,
    serial: ti.template(),
):
    """O_V of every image into ``pose`` (N, 4): visible (1/0), confidence, angle [rad], y [m].

    Per image, in a patch of rows centre +- ``half_rows`` and columns from the gripper's rightwards:
    the strand starts in the first column centred beyond the occlusion edge and past every gripper
    pixel (the drawn finger sits higher and may look wider than the occlusion radius); column by
    column, the vertical run of cable pixels touching the previous strand's rows (+-1) nearest to
    the predicted row is followed; a run much longer than one strand (another strand crossing
    there) is cut to half a strand's vertical extent around the prediction. Row positions are
    relative to the gripper's v [px]. ``serial``: a lone image skips the thread pool."""
    occlusion_radius, search_half_width = ti.f64(OCCLUSION_RADIUS), ti.f64(SEARCH_HALF_WIDTH)
    cable_radius, confidence_length = ti.f64(CABLE_RADIUS), ti.f64(CONFIDENCE_LENGTH)
    num_columns = ti.cast(ti.ceil(ti.f64(TRACK_LENGTH) / metres_per_pixel), ti.i32)
    half_rows = ti.cast(ti.ceil((search_half_width + ti.f64(TRACK_LENGTH)) / metres_per_pixel), ti.i32)
    margin_columns = ti.cast(ti.ceil(occlusion_radius / metres_per_pixel), ti.i32) + GRIPPER_MARGIN_PIXELS
    ti.loop_config(serialize=serial)
    for e in range(images.shape[0]):
        u_occluded = gripper_uv[e, 0] + occlusion_radius / metres_per_pixel  # right edge of the occlusion [px]
        centre_row = ti.cast(ti.floor(gripper_uv[e, 1]), ti.i32)
        centre_column = ti.cast(ti.floor(gripper_uv[e, 0]), ti.i32)
        row_shift = (centre_row - gripper_uv[e, 1]) + 0.5  # row offset -> row centre - v_G [px]
        patch_columns = margin_columns + num_columns
        first_column = ti.cast(ti.ceil(u_occluded - 0.5), ti.i32) - centre_column
        first_column = _strand_start(images, e, centre_row, centre_column, patch_columns, half_rows, first_column)

        gate_half = search_half_width / metres_per_pixel
        gate_lo, gate_hi = -gate_half, gate_half  # rows the next run must touch
        predicted = ti.f64(0.0)
        slope = ti.f64(0.0)  # rows per column of the followed strand
        radius_pixels = cable_radius / metres_per_pixel
        tracking = True
        length = 0
        first_centroid = ti.f64(0.0)
        sum_y = ti.f64(0.0)  # sums over the followed columns k of centroid and k * centroid
        sum_ky = ti.f64(0.0)
        for k in range(num_columns):
            column = centre_column + first_column + k
            if tracking and first_column + k < patch_columns:
                nearest = _nearest_cable_row(images, e, centre_row, column, half_rows, row_shift, gate_lo, gate_hi, predicted)
                if nearest > half_rows:
                    tracking = False
                else:
                    lo, hi = nearest, nearest  # the run of cable pixels containing the nearest
                    while lo > -half_rows and _patch_pixel(images, e, centre_row + lo - 1, column) == IMAGE_CABLE:
                        lo -= 1
                    while hi < half_rows and _patch_pixel(images, e, centre_row + hi + 1, column) == IMAGE_CABLE:
                        hi += 1
                    half_extent = radius_pixels * ti.sqrt(1.0 + slope * slope) + 0.5
                    merged = k > 0 and hi - lo + 1 > 2.0 * half_extent + 2.0
                    count = 0
                    total = ti.f64(0.0)
                    for r in range(lo, hi + 1):
                        pos = r + row_shift
                        if not merged or ti.abs(pos - predicted) <= half_extent:
                            if count == 0:
                                gate_lo = pos
                            gate_hi = pos
                            count += 1
                            total += pos
                    if count == 0:
                        count = 1
                        total = nearest + row_shift
                        gate_lo, gate_hi = total, total
                    centroid = total / count
                    if k == 0:
                        first_centroid = centroid
                    slope = (centroid - first_centroid) / ti.max(k, 1)
                    predicted = centroid + slope
                    length += 1
                    sum_y += centroid
                    sum_ky += k * centroid
            else:
                tracking = False

        visible = length > 0
        # From the occlusion edge to the centre of the last strand column, less the drawn cable radius.
        dx = (centre_column + first_column + length - 0.5 - u_occluded) * metres_per_pixel - cable_radius
        # Least-squares line of the centroids over columns k = 0..length-1 (line_slope); world y
        # grows with -row, so world slope = -(row slope) and y_V = -row offset.
        count_f = ti.cast(length, ti.f64)
        mean_k = 0.5 * (count_f - 1.0)
        sxx = count_f * (count_f * count_f - 1.0) / 12.0
        sxy = sum_ky - mean_k * sum_y
        row_slope = ti.f64(0.0)
        if length >= 2:
            row_slope = sxy / sxx
        pose[e, 0] = 1.0 if visible else 0.0
        pose[e, 1] = ti.min(ti.max(dx / confidence_length, 0.0), 1.0) if visible else 0.0
        pose[e, 2] = ti.atan2(-row_slope, 1.0) if visible else 0.0
        pose[e, 3] = ti.min(ti.max(-first_centroid * metres_per_pixel, -search_half_width), search_half_width) if visible else 0.0


def visual_pose_ground_truth(positions, num_particles, gripper_xy) -> VisualPose:
    """O_V from particle positions (N, P, >=2) [m], num_particles (N,) and gripper_xy (N, >=2) [m].

    Entry = among particles with x in [x_o, x_o + ENTRY_BAND] and |y - y_G| <= SEARCH_HALF_WIDTH the
    one closest to y_G; from it the cable is walked by index (towards the side that heads right) for
    up to 10 particles while x keeps increasing and x - x_o <= TRACK_LENGTH.
    """
    positions = np.asarray(positions, dtype=np.float64)
    n, p_max = positions.shape[:2]
    num_particles = np.asarray(num_particles).reshape(n)
    gripper = np.asarray(gripper_xy, dtype=np.float64).reshape(n, -1)[:, :2] if n else np.empty((0, 2))
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


def visual_pose_particles(positions, held, num_particles, gripper_xy) -> VisualPose:
    """O_V as the authors' environment computes it (module docstring), batched.

    positions: (N, P, >=2) particle positions [m]; held: (N, P) bool, the task rules' held set;
    num_particles: (N,) n_c; gripper_xy: (N, >=2) [m]."""
    positions = np.asarray(positions, dtype=np.float64)
    n, p_max = positions.shape[:2]
    x, y = positions[..., 0], positions[..., 1]
    held = np.asarray(held, dtype=bool).reshape(n, p_max)
    segments = np.asarray(num_particles).reshape(n).astype(np.int64) - 1  # the authors' segment count
    gripper = np.asarray(gripper_xy, dtype=np.float64).reshape(n, -1)[:, :2] if n else np.empty((0, 2))
    rows = np.arange(n)
    count = held.sum(axis=1)
    contact = count >= 2
    last_held = np.where(count > 0, p_max - 1 - np.argmax(held[:, ::-1], axis=1), 0)
    x_side = gripper[:, 0] + OCCLUSION_RADIUS

    def x_at(index):
        return x[rows, np.clip(index, 0, p_max - 1)]

    edge, found = last_held.copy(), np.zeros(n, bool)
    for j in range(WALK_STEPS):
        index = last_held + j
        hit = ~found & ((x_at(index) > x_side) | (index + 1 >= segments))
        edge = np.where(hit, index, edge)
        found |= hit
    visible = contact & (edge + 1 < segments)
    y_out = y[rows, np.clip(edge + 1, 0, p_max - 1)] - gripper[:, 1]

    right, stopped = edge.copy(), np.zeros(n, bool)
    x_edge = x_at(edge)
    for j in range(WALK_STEPS):
        index = edge + j
        right = np.where(stopped, right, index)
        stopped |= (x_at(index) - x_edge < -BACKTRACK) | (index + 1 >= segments)
    dx = x_at(right) - x_edge
    extends = contact & (dx > 0)
    walk = edge[:, None] + np.arange(WALK_STEPS)[None, :]
    fitted = walk < right[:, None]
    walk = np.clip(walk, 0, p_max - 1)
    slope = line_slope(x[rows[:, None], walk], y[rows[:, None], walk], fitted)
    return VisualPose(
        visible,
        np.where(extends, np.minimum(dx / CONFIDENCE_LENGTH, 1.0), 0.0),
        np.where(extends, np.arctan(slope), 0.0),
        np.where(visible, y_out, 0.0),
    )
