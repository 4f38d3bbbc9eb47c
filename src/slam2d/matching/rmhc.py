"""Random-mutation hill climbing (RMHC) on a tinySLAM hole map, as BreezySLAM searches.

The search (one compiled call per scan):

1. Draw a candidate around the last accepted pose: ``x, y ~ N(last, sigma_xy)``,
   ``theta ~ N(last, sigma_theta)``; score it with
   :func:`~slam2d.grids.hole_map.hole_distance` (lower is better).
2. A candidate better than the best so far becomes the best; otherwise a
   failure counter goes up.
3. When the counter passes a third of ``max_iter`` and the best improved on
   the last accepted pose, the best is accepted as the new centre, the
   counter restarts and both sigmas halve: the spread shrinks as it converges.
4. The search ends when the counter reaches ``max_iter``.

Random numbers come from :mod:`slam2d.matching.random_numbers`, seeded from
the method's seed, so a run repeats bit for bit.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

from slam2d.grids.hole_map import HoleMap, hole_distance, hole_distance_inside
from slam2d.matching.random_numbers import normal_pair

__all__ = ["rmhc_search", "pattern_refine", "RmhcResult", "rmhc_match"]


@njit(cache=True)
def rmhc_search(values, origin_x, origin_y, resolution, qx, qy, x0, y0, theta0,
                sigma_xy, sigma_theta, max_iter, state):
    """``(x, y, theta, distance, evaluations, halvings)`` of the RMHC search from ``(x0, y0, theta0)``.

    ``state`` is a :mod:`~slam2d.matching.random_numbers` generator state (advanced in place).
    """
    inv = 1.0 / resolution
    # candidates are kept within 3 initial sigmas of the start, where the caller made the map hold the
    # whole scan, so the unchecked distance is safe (a draw beyond 3 sigma, 0.3 % of them, is clamped)
    reach = 3.0 * sigma_xy
    xlo, xhi, ylo, yhi = x0 - reach, x0 + reach, y0 - reach, y0 + reach
    bx, by, bt = x0, y0, theta0  # best so far
    lx, ly, lt = x0, y0, theta0  # last accepted centre
    best = hole_distance(values, origin_x, origin_y, inv, qx, qy, x0, y0, theta0)
    last_best = best
    evaluations = 1
    halvings = 0
    counter = 0
    spare = 0.0
    have_spare = False
    while counter < max_iter:
        # three normals per candidate from Box-Muller pairs; the fourth is kept for the next one
        if have_spare:
            n1 = spare
            n2, n3 = normal_pair(state)
            have_spare = False
        else:
            n1, n2 = normal_pair(state)
            n3, spare = normal_pair(state)
            have_spare = True
        cx = min(max(lx + sigma_xy * n1, xlo), xhi)
        cy = min(max(ly + sigma_xy * n2, ylo), yhi)
        ct = lt + sigma_theta * n3
        d = hole_distance_inside(values, origin_x, origin_y, inv, qx, qy, cx, cy, ct)
        evaluations += 1
        if d < best:
            best = d
            bx, by, bt = cx, cy, ct
        else:
            counter += 1
        if counter > max_iter // 3 and best < last_best:
            lx, ly, lt = bx, by, bt
            last_best = best
            counter = 0
            sigma_xy *= 0.5
            sigma_theta *= 0.5
            halvings += 1
    return bx, by, bt, best, evaluations, halvings


@njit(cache=True)
def pattern_refine(values, origin_x, origin_y, resolution, qx, qy, x, y, theta, best, step_xy, step_theta,
                   min_step_xy, max_rounds):
    """Deterministic compass search from ``(x, y, theta)`` (score ``best``): ``(x, y, theta, distance, evaluations)``.

    Tries the six moves of ``step_xy`` / ``step_theta`` along each axis, takes
    the best that improves, and halves both steps when none does, until
    ``step_xy < min_step_xy`` or ``max_rounds`` rounds. Why: RMHC ends after
    ``max_iter`` failed random draws, and when its first, widest draws
    (0.1 m, 20 degrees) find nothing better than the start, it never narrows
    and returns the start unchanged: a small correction is then missed, and a
    moving robot's pose lags a whole step. The compass search finds those
    corrections for a few dozen evaluations.
    """
    inv = 1.0 / resolution
    evaluations = 0
    for _ in range(max_rounds):
        if step_xy < min_step_xy:
            break
        cx, cy, ct, cbest = x, y, theta, best
        for m in range(6):
            tx = x + (step_xy if m == 0 else -step_xy if m == 1 else 0.0)
            ty = y + (step_xy if m == 2 else -step_xy if m == 3 else 0.0)
            tt = theta + (step_theta if m == 4 else -step_theta if m == 5 else 0.0)
            d = hole_distance(values, origin_x, origin_y, inv, qx, qy, tx, ty, tt)
            evaluations += 1
            if d < cbest:
                cx, cy, ct, cbest = tx, ty, tt, d
        if cbest < best:
            x, y, theta, best = cx, cy, ct, cbest
        else:
            step_xy *= 0.5
            step_theta *= 0.5
    return x, y, theta, best, evaluations


class RmhcResult:
    """Outcome of one search: ``pose``, ``distance`` (mean cell value, lower better), ``evaluations``, ``halvings``."""

    __slots__ = ("pose", "distance", "evaluations", "halvings")

    def __init__(self, pose: NDArray[np.float64], distance: float, evaluations: int, halvings: int) -> None:
        self.pose = pose
        self.distance = distance
        self.evaluations = evaluations
        self.halvings = halvings


def rmhc_match(
    hole_map: HoleMap,
    points: NDArray[np.float64],
    start: NDArray[np.float64],
    *,
    sigma_xy: float,
    sigma_theta: float,
    max_iter: int,
    state: NDArray[np.uint64],
    refine: bool = False,
) -> RmhcResult:
    """Search the pose near ``start`` where the robot-frame ``points`` (N, 2) sit deepest in the holes.

    The map is first grown to hold the scan around ``start`` (plus three
    sigmas), so candidates see unexplored cells as unknown (BreezySLAM's map
    is one large square) instead of dropping points.
    """
    reach = float(np.sqrt((points**2).sum(axis=1)).max()) + 3.0 * sigma_xy
    hole_map.ensure_contains(start[0] - reach, start[1] - reach, start[0] + reach, start[1] + reach)
    ox, oy = hole_map.origin
    x, y, t, d, n, h = rmhc_search(
        hole_map.values, ox, oy, hole_map.resolution,
        np.ascontiguousarray(points[:, 0], dtype=np.float32), np.ascontiguousarray(points[:, 1], dtype=np.float32),
        float(start[0]), float(start[1]), float(start[2]),
        float(sigma_xy), float(sigma_theta), int(max_iter), state,
    )
    if refine and math.isfinite(d):
        res = hole_map.resolution
        # steps from one cell and the heading that moves a point 3 m away by one cell, down to 1/8 of them
        x, y, t, d, m = pattern_refine(
            hole_map.values, ox, oy, res, np.ascontiguousarray(points[:, 0], dtype=np.float32),
            np.ascontiguousarray(points[:, 1], dtype=np.float32), x, y, t, d, res, res / 3.0, res / 8.0, 100,
        )
        n += m
    theta = math.atan2(math.sin(t), math.cos(t))
    return RmhcResult(np.array([x, y, theta]), float(d), int(n), int(h))
