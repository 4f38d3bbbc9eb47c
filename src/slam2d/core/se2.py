"""Rigid motions in the plane, SE(2), as plain numpy arrays.

A pose is an array ``[x, y, theta]`` (metres, metres, radians). Every function
takes a single pose of shape ``(3,)`` or a stack of shape ``(..., 3)`` and
broadcasts like numpy, so a whole trajectory is transformed in one call and no
Python loop runs per pose. Angles that come out are wrapped to ``[-pi, pi)``.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

Poses = NDArray[np.float64]

__all__ = [
    "wrap_angle",
    "wrap_scalar",
    "compose",
    "inverse",
    "relative",
    "interpolate",
    "transform_points",
    "yaw_to_quaternion",
    "quaternion_to_yaw",
    "as_poses",
]


def as_poses(poses: ArrayLike) -> Poses:
    """Return ``poses`` as a float64 array whose last axis has length 3."""
    arr = np.asarray(poses, dtype=np.float64)
    if arr.shape[-1:] != (3,):
        raise ValueError(f"a pose has 3 components (x, y, theta); got shape {arr.shape}")
    return arr


def _one(a) -> list[float] | None:
    """A single float64 pose as three Python floats (the per-scan case), else None.

    The scalar paths below do the array paths' arithmetic in the same order (and math's
    cos/sin/% give numpy's results), so they return the same numbers without the cost of
    numpy on three-element arrays.
    """
    if type(a) is np.ndarray and a.shape == (3,) and a.dtype == np.float64:
        return a.tolist()
    return None


def wrap_scalar(t: float) -> float:
    """Wrap one angle (a Python float, radians) to ``[-pi, pi)``: :func:`wrap_angle`'s arithmetic without numpy."""
    return (t + math.pi) % (2.0 * math.pi) - math.pi


def wrap_angle(angle: ArrayLike) -> NDArray[np.float64]:
    """Wrap angles (radians) to ``[-pi, pi)``."""
    a = np.asarray(angle, dtype=np.float64)
    return (a + np.pi) % (2.0 * np.pi) - np.pi


def compose(a: ArrayLike, b: ArrayLike) -> Poses:
    """``a ⊕ b``: the pose ``b``, given in the frame of ``a``, expressed in ``a``'s parent frame."""
    one_a, one_b = _one(a), _one(b)
    if one_a is not None and one_b is not None:
        (a0, a1, a2), (b0, b1, b2) = one_a, one_b
        c, s = math.cos(a2), math.sin(a2)
        return np.array([a0 + c * b0 - s * b1, a1 + s * b0 + c * b1, wrap_scalar(a2 + b2)])
    a = as_poses(a)
    b = as_poses(b)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    x = a[..., 0] + c * b[..., 0] - s * b[..., 1]
    y = a[..., 1] + s * b[..., 0] + c * b[..., 1]
    return np.stack([x, y, wrap_angle(a[..., 2] + b[..., 2])], axis=-1)


def inverse(a: ArrayLike) -> Poses:
    """``⊖a``: the parent frame's origin seen from ``a``."""
    a = as_poses(a)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    x = -c * a[..., 0] - s * a[..., 1]
    y = s * a[..., 0] - c * a[..., 1]
    return np.stack([x, y, wrap_angle(-a[..., 2])], axis=-1)


def relative(a: ArrayLike, b: ArrayLike) -> Poses:
    """``⊖a ⊕ b``: the pose ``b`` expressed in the frame of ``a`` (odometry increments, edges)."""
    one_a, one_b = _one(a), _one(b)
    if one_a is not None and one_b is not None:
        (a0, a1, a2), (b0, b1, b2) = one_a, one_b
        c, s = math.cos(a2), math.sin(a2)
        dx, dy = b0 - a0, b1 - a1
        return np.array([c * dx + s * dy, -s * dx + c * dy, wrap_scalar(b2 - a2)])
    a = as_poses(a)
    b = as_poses(b)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    dx = b[..., 0] - a[..., 0]
    dy = b[..., 1] - a[..., 1]
    return np.stack([c * dx + s * dy, -s * dx + c * dy, wrap_angle(b[..., 2] - a[..., 2])], axis=-1)


def interpolate(a: ArrayLike, b: ArrayLike, t: ArrayLike) -> Poses:
    """Poses a fraction ``t`` of the way from ``a`` to ``b``.

    Position is interpolated linearly and heading along the shorter arc, which
    is what odometry sampled at 10-100 Hz needs (the motion between two samples
    is small). ``t`` may lie outside [0, 1] to extrapolate.
    """
    a = as_poses(a)
    b = as_poses(b)
    t = np.asarray(t, dtype=np.float64)
    dtheta = wrap_angle(b[..., 2] - a[..., 2])
    x = a[..., 0] + t * (b[..., 0] - a[..., 0])
    y = a[..., 1] + t * (b[..., 1] - a[..., 1])
    return np.stack([x, y, wrap_angle(a[..., 2] + t * dtheta)], axis=-1)


def transform_points(pose: ArrayLike, points: ArrayLike) -> NDArray[np.float64]:
    """Map points ``(N, 2)`` from the frame of ``pose`` to its parent frame."""
    one = _one(pose)
    pts = np.asarray(points, dtype=np.float64)
    if one is not None and pts.ndim == 2 and pts.shape[1] == 2:
        x0, y0, t = one
        c, s = math.cos(t), math.sin(t)
        out = np.empty(pts.shape)
        px, py = pts[:, 0], pts[:, 1]
        out[:, 0] = x0 + c * px - s * py
        out[:, 1] = y0 + s * px + c * py
        return out
    pose = as_poses(pose)
    c, s = np.cos(pose[..., 2]), np.sin(pose[..., 2])
    x = pose[..., 0, None] + c[..., None] * pts[..., 0] - s[..., None] * pts[..., 1]
    y = pose[..., 1, None] + s[..., None] * pts[..., 0] + c[..., None] * pts[..., 1]
    return np.stack([x, y], axis=-1)


def yaw_to_quaternion(yaw: ArrayLike) -> NDArray[np.float64]:
    """Unit quaternions ``(qx, qy, qz, qw)`` of rotations by ``yaw`` about z."""
    half = 0.5 * np.asarray(yaw, dtype=np.float64)
    zeros = np.zeros_like(half)
    return np.stack([zeros, zeros, np.sin(half), np.cos(half)], axis=-1)


def quaternion_to_yaw(q: ArrayLike) -> NDArray[np.float64]:
    """Heading (rotation about z) of quaternions ``(qx, qy, qz, qw)``.

    Exact for rotations about z; for a general 3D rotation it is the yaw of the
    ZYX Euler decomposition, which is what a 2D method should use for a robot on
    a slightly tilted platform.
    """
    q = np.asarray(q, dtype=np.float64)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return wrap_angle(np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)))
