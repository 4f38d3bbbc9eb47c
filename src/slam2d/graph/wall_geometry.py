"""Geometry of scans and lines shared by the wall refinement and the dense refinement.

:mod:`slam2d.graph.wall_refinement` and :mod:`slam2d.graph.dense_refinement` both take the returns a
scan can use, their range sigmas, the total-least-squares line through a run of points and the
points placed by their frames' poses from here.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit
from numpy.typing import NDArray

from slam2d.core import se2

__all__ = ["tls_line", "usable_returns", "floored_sigmas", "place_points"]


@njit(cache=True)
def tls_line(x, y, s, e):
    """The total-least-squares line of points ``s..e`` (inclusive): normal angle, centroid x, y, RMS distance."""
    cnt = e - s + 1
    cx = 0.0
    cy = 0.0
    for j in range(s, e + 1):
        cx += x[j]
        cy += y[j]
    cx /= cnt
    cy /= cnt
    sxx = 0.0
    syy = 0.0
    sxy = 0.0
    for j in range(s, e + 1):
        ux = x[j] - cx
        uy = y[j] - cy
        sxx += ux * ux
        syy += uy * uy
        sxy += ux * uy
    sxx /= cnt
    syy /= cnt
    sxy /= cnt
    half = 0.5 * (sxx - syy)
    lam = 0.5 * (sxx + syy) - math.sqrt(half * half + sxy * sxy)
    a = 0.5 * math.atan2(2.0 * sxy, sxx - syy) + 0.5 * math.pi  # the normal: least spread
    return a, cx, cy, math.sqrt(max(lam, 0.0))


def usable_returns(scan: Any, range_limit: float = math.inf):
    """(beams, their unit directions in the laser frame (K, 2), their points in the base frame (K, 2)) of the
    returns within the laser's limits and ``range_limit``."""
    r = scan.ranges
    with np.errstate(invalid="ignore"):
        use = scan.valid & (r < scan.range_max) & (r >= scan.range_min) & (r <= range_limit)
    beams = np.flatnonzero(use)
    a = scan.angles[beams]
    local = np.stack([np.cos(a), np.sin(a)], -1)
    return beams, local, se2.transform_points(scan.mount, local * r[beams, None])


def floored_sigmas(sigma: NDArray[np.float64] | None, beams: NDArray[np.int64], floor: float) -> NDArray[np.float64]:
    """Per beam of ``beams`` its range sigma (None, NaN or infinite: none), but at least ``floor``."""
    if sigma is None:
        return np.full(beams.size, float(floor))
    s = sigma[beams]
    return np.fmax(np.where(np.isfinite(s), s, 0.0), floor)


def place_points(pose: NDArray[np.float64], q: NDArray[np.float64]) -> NDArray[np.float64]:
    """Point ``q[k]`` (base frame) placed by pose ``pose[k]``: (K, 2)."""
    return se2.transform_points(pose, q[:, None, :])[:, 0, :]
