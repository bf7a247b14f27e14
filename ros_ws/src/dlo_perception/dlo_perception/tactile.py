"""Tactile distillation O_T = [theta_T, y_T] from the cable particles between the fingers.

A line is fitted (total least squares, so a cable lying along the finger is fine too) through the
centres of the held particles in the gripper frame. At the fixed gripper orientation used here the
gripper frame is the world frame shifted to the gripper centre: gripper x = world x (direction of
travel), gripper y = world y (along the fingers).

- ``angle`` theta_T [rad]: angle of the line to gripper x, counter-clockwise about +z, in (-pi/2, pi/2].
  (The authors' ``-atan(slope)`` is the same angle: their SoftGym plane is x-z with y up.)
- ``y`` y_T [m]: where the line crosses the gripper y axis (x = x_G), relative to y_G, clipped to
  +-``Y_LIMIT`` (only reached by lines nearly parallel to the finger).
- ``contact``: at least 2 held particles; otherwise angle = y = 0 (never NaN).
- ``count``: number of held particles.

Sensor noise (paper, Tactile sensors): ``angle += (1 - c_G) N(0, sigma_theta)`` and
``y += (1 - c_G) N(0, sigma_y)`` on contact (angle re-wrapped, y re-clipped). ``TACTILE_NOISE`` holds the sensitivity presets.

The noise setting has one name, ``tactile_noise``, and one reading, :func:`noise_setting`, wherever it is
given: the gym env's option (and dlo-train's ``env_options.tactile_noise``), the tactile node's
parameter and ``scripts/launch_graph.sh --tactile-noise``, which checks its value first and passes on its
``-p`` form (:func:`noise_parameter_value`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# (sigma_theta [rad], sigma_y [m]) per sensitivity preset. "full" is the paper's "full randomisation
# when no grip"; "partial" (our choice, the paper gives no number) is half of it: an open gripper
# still gives a usable angle (about +-14 deg) and a position to about +-1 mm.
TACTILE_NOISE = {
    "none": (0.0, 0.0),
    "partial": (0.25, 0.001),
    "full": (0.5, 0.002),
}
# What a tactile noise setting can be, in words (error messages, the node's --help, the docs).
NOISE_FORMS = "none, partial, full or a pair [sigma_theta, sigma_y] (rad, m; >= 0) such as [0.1,0.001]"
Y_LIMIT = 0.03  # m, |y_T| bound (beyond the fingers' reach of ~0.02 m)


@dataclass
class TactilePose:
    """Tactile reading; arrays of shape (N,) for a batch, scalars for one sample."""

    angle: np.ndarray  # theta_T [rad]
    y: np.ndarray  # y_T [m]
    contact: np.ndarray  # bool
    count: np.ndarray  # int, number of held particles


def noise_setting(value) -> str | tuple[float, float]:
    """Read a tactile noise setting, the same wherever it is given (env option ``tactile_noise``, the
    tactile node's ``tactile_noise`` parameter, ``launch_graph.sh --tactile-noise``): a preset name of
    ``TACTILE_NOISE`` ("none", "partial", "full"), or a pair sigma_theta [rad], sigma_y [m] of finite
    numbers >= 0, as a sequence (``[0.1, 0.001]``, a ROS double array) or as text (``"0.1,0.001"``,
    ``"[0.1,0.001]"``). Returns the preset name or the pair as two floats; ValueError in one line
    ("expected ..., got ...") otherwise."""
    if isinstance(value, str) and value in TACTILE_NOISE:
        return value
    if isinstance(value, str):
        text = value.strip()
        if text[:1] + text[-1:] in ("[]", "()"):
            text = text[1:-1]
        items = text.split(",")
        shown = repr(value)
    else:
        try:
            items = list(value)
        except TypeError:
            raise ValueError(f"expected {NOISE_FORMS}, got {value!r}") from None
        shown = repr(items)
    try:
        if len(items) != 2 or any(isinstance(v, (bool, np.bool_)) for v in items):
            raise ValueError
        pair = (float(items[0]), float(items[1]))
    except (TypeError, ValueError):
        raise ValueError(f"expected {NOISE_FORMS}, got {shown}") from None
    if not all(np.isfinite(s) and s >= 0 for s in pair):
        raise ValueError(f"expected {NOISE_FORMS}, got {shown}")
    return pair


def noise_sigma(sigma) -> tuple:
    """A tactile noise setting (:func:`noise_setting`: a preset name or a pair) -> the pair
    (sigma_theta [rad], sigma_y [m]); ValueError in one line for anything else."""
    setting = noise_setting(sigma)
    return TACTILE_NOISE[setting] if isinstance(setting, str) else setting


def _number(value: float) -> str:
    """0.1 -> '0.1', 1e-05 -> '0.00001', 0 -> '0.0': always a decimal point, never an exponent (YAML reads
    it as a float)."""
    return np.format_float_positional(float(value), trim="0")


def noise_label(setting) -> str:
    """A tactile noise setting in words, for the run header and the tactile node's start line:
    ``none``, ``partial (sigma_theta 0.25 rad, sigma_y 0.001 m)``, and a custom pair as its numbers,
    ``sigma_theta 0.1 rad, sigma_y 0.001 m``."""
    setting = noise_setting(setting)
    if setting == "none":
        return setting
    sigma_theta, sigma_y = noise_sigma(setting)
    numbers = f"sigma_theta {_number(sigma_theta)} rad, sigma_y {_number(sigma_y)} m"
    return f"{setting} ({numbers})" if isinstance(setting, str) else numbers


def noise_parameter_value(setting) -> str:
    """A tactile noise setting as written after ``-p tactile_noise:=`` (and in YAML): the preset's name,
    or the pair as ``[0.1,0.001]``."""
    setting = noise_setting(setting)
    return setting if isinstance(setting, str) else "[" + ",".join(_number(s) for s in setting) + "]"


def tactile_pose(points_xy, held_mask, gripper_xy, closure, sigma=(0.0, 0.0), rng=None) -> TactilePose:
    """Fit the held cable line in the gripper frame.

    points_xy: (N, P, >=2) particle positions [m] (only x, y are used) or (P, >=2) for one sample.
    held_mask: (N, P) bool, particles between the fingers. gripper_xy: (N, >=2) [m]. closure: (N,) c_G.
    sigma: noise preset name or (sigma_theta [rad], sigma_y [m]); rng: numpy Generator for the noise.
    """
    points = np.asarray(points_xy, dtype=np.float64)
    single = points.ndim == 2
    points = points[None] if single else points
    held = np.asarray(held_mask, dtype=bool).reshape(points.shape[:2])
    gripper = np.asarray(gripper_xy, dtype=np.float64).reshape(len(points), -1)[:, :2]
    closure = np.broadcast_to(np.asarray(closure, dtype=np.float64).reshape(-1), (len(points),))

    count = held.sum(axis=1)
    contact = count >= 2
    weights = held / np.maximum(count, 1)[:, None]
    rel = points[..., :2] - gripper[:, None, :]
    mean = np.einsum("np,npk->nk", weights, rel)
    dev = (rel - mean[:, None, :]) * held[..., None]
    sxx = np.einsum("np,np->n", dev[..., 0], dev[..., 0])
    syy = np.einsum("np,np->n", dev[..., 1], dev[..., 1])
    sxy = np.einsum("np,np->n", dev[..., 0], dev[..., 1])
    angle = wrap_line_angle(0.5 * np.arctan2(2.0 * sxy, sxx - syy))
    y = np.clip(mean[:, 1] - mean[:, 0] * np.tan(angle), -Y_LIMIT, Y_LIMIT)

    sigma_theta, sigma_y = noise_sigma(sigma)
    if sigma_theta > 0 or sigma_y > 0:
        rng = np.random.default_rng() if rng is None else rng
        scale = 1.0 - np.clip(closure, 0.0, 1.0)
        angle = wrap_line_angle(angle + scale * rng.normal(0.0, sigma_theta, len(points)))
        y = np.clip(y + scale * rng.normal(0.0, sigma_y, len(points)), -Y_LIMIT, Y_LIMIT)
    angle = np.where(contact, angle, 0.0)
    y = np.where(contact, y, 0.0)
    if single:
        return TactilePose(float(angle[0]), float(y[0]), bool(contact[0]), int(count[0]))
    return TactilePose(angle, y, contact, count.astype(np.int32))


def wrap_line_angle(angle):
    """Angle of an undirected line [rad] -> (-pi/2, pi/2]."""
    return np.pi / 2 - np.mod(np.pi / 2 - np.asarray(angle), np.pi)
