"""The motion between two consecutive scans, from the scans alone (no map): an independent turn estimate.

Why: a scan-to-map match is biased where the map is young. Walls seen once
score less than walls seen often, so while the robot turns into new space the
best fit leans back onto the old walls and under-turns by a few percent
(crsm on the mines logs, docs/methods/crsm.md). Two consecutive scans are
equally mature and overlap almost wholly, so their relative motion carries
no such bias; it is noisier per scan, but its errors do not build into the
map when it only serves as a prediction the map match is tested against.

How: the previous scan's endpoints are smeared into a coarse field
(:func:`slam2d.matching.correlative_grid.smear_points`, a Gaussian per point); a
sweep over headings (with a few translations around the guess) on it picks
the start. The sweep is what lets a 15 degree turn be found from a guess of
none: far points move out of a Gaussian's reach after a few degrees. Then
Gauss-Newton on point-to-line distances (each current point to the local line
through its nearest previous point, the pairs re-found every step, a Cauchy
weight) refines it until the step is below 1e-5 rad and 0.1 mm.

Why lines for the refinement: the earlier Gauss-Newton on a smeared fine
field shrank turns by 3-4 % on mines-exp1 (-0.12 degrees per left-turning
scan against hector's; 40.8 degrees net where hector turns 64.5). A smeared
point falls off along a wall as well as across it, so where the current scan
sees a wall a little further than the previous one did (each segment's end on
the side the robot turns to) the field pulls the point back along the wall.
More iterations (3, 10, 30), other starts or the field's cell size did not
remove it; a narrower Gaussian shrank it, the line distance, which has no
component along the wall, does (49.2 degrees net, -0.07 / +0.02 per scan).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

from slam2d.matching.correlative_grid import smear_points

__all__ = ["consecutive_motion", "registration_fit"]

# (cell size m, smear sigma m) of the coarse field (the heading sweep) and the fine one (Gauss-Newton)
_COARSE = (0.10, 0.15)
_ITERATIONS = 20  # Gauss-Newton steps at most; it stops when a step is below 1e-5 rad and 0.1 mm (5 on mines-exp1)
_NEIGHBOUR = 0.3  # m: previous points closer than this in beam order span a local line
_SPAN = 3  # neighbours each way a point's line is drawn through
_WINDOW = 4  # previous points either side in bearing order searched for the nearest
_MAX_DISTANCE = 0.3  # m: a current point further from every previous candidate has no counterpart
_HUBER = 0.05  # m: the Cauchy weight's scale
_DAMPING = 1.0  # added to the normal equations' diagonal (sum of weights ~ points, so a whisper)
_MARGIN = 0.6  # m around the previous scan's points: the current scan may reach a little further


@njit(cache=True)
def _field(px, py, resolution, sigma):
    """The points smeared (a Gaussian of ``sigma`` each) into a 0..1 field: ``(field, origin x, origin y)``."""
    lo_x = px.min() - _MARGIN
    lo_y = py.min() - _MARGIN
    cols = int(math.ceil((px.max() + _MARGIN - lo_x) / resolution)) + 1
    rows = int(math.ceil((py.max() + _MARGIN - lo_y) / resolution)) + 1
    grid = np.zeros((rows, cols), dtype=np.uint8)
    smear_points(grid, lo_x, lo_y, resolution, px, py, np.full(px.shape[0], sigma))
    return grid.astype(np.float64) / 255.0, lo_x, lo_y


@njit(cache=True)
def _score(field, ox, oy, inv, qx, qy, x, y, t):
    """The field summed (nearest cell) under the points placed at ``(x, y, t)``."""
    rows, cols = field.shape
    c = math.cos(t)
    s = math.sin(t)
    cx = (x - ox) * inv
    cy = (y - oy) * inv
    total = 0.0
    for p in range(qx.shape[0]):
        col = int(math.floor(cx + (c * qx[p] - s * qy[p]) * inv))
        row = int(math.floor(cy + (s * qx[p] + c * qy[p]) * inv))
        if 0 <= row < rows and 0 <= col < cols:
            total += field[row, col]
    return total


@njit(cache=True)
def _sweep(field, ox, oy, resolution, qx, qy, gx, gy, gt, half_turn, turn_step, shift):
    """Best ``(x, y, theta)`` of the summed field over headings ``gt +- half_turn`` and 3 x 3 shifts of ``shift`` m
    around the guess; the guess wins ties.

    Two passes: the headings at the guessed position alone, then the 3 x 3 shifts at the best heading and its two
    neighbours (a fifth of the full grid's cost). Why this suffices: the smear (1.5 cells) is wider than the shift is
    far, so the guessed position already ranks the headings; the shifts only pick the basin Gauss-Newton starts in.
    """
    inv = 1.0 / resolution
    n_turn = int(round(half_turn / turn_step))
    best = -1.0
    bk = 0
    for k in range(-n_turn, n_turn + 1):
        total = _score(field, ox, oy, inv, qx, qy, gx, gy, gt + k * turn_step)
        if total > best + 1e-9 or (abs(total - best) <= 1e-9 and k == 0):
            best = total
            bk = k
    best = -1.0
    bx, by, bt = gx, gy, gt + bk * turn_step
    for k in range(max(bk - 1, -n_turn), min(bk + 1, n_turn) + 1):
        t = gt + k * turn_step
        for i in range(-1, 2):
            for j in range(-1, 2):
                total = _score(field, ox, oy, inv, qx, qy, gx + i * shift, gy + j * shift, t)
                if total > best + 1e-9 or (abs(total - best) <= 1e-9 and k == bk and i == 0 and j == 0):
                    best = total
                    bx, by, bt = gx + i * shift, gy + j * shift, t
    return bx, by, bt


@njit(cache=True)
def _normals(px, py):
    """Unit normals of the previous scan's points from their neighbours in beam order (a wall's local line);
    ``valid`` is False for a point with no neighbour within ``_NEIGHBOUR`` m (no line to lie on)."""
    n = px.shape[0]
    nx = np.zeros(n)
    ny = np.zeros(n)
    valid = np.zeros(n, dtype=np.bool_)
    for i in range(n):
        # up to _SPAN neighbours each way, while each is near the last: a baseline longer than a cell, so the
        # points' truncation to cells does not tilt the line
        lo = i
        while lo > 0 and i - lo < _SPAN and math.hypot(px[lo - 1] - px[lo], py[lo - 1] - py[lo]) < _NEIGHBOUR:
            lo -= 1
        hi = i
        while hi + 1 < n and hi - i < _SPAN and math.hypot(px[hi + 1] - px[hi], py[hi + 1] - py[hi]) < _NEIGHBOUR:
            hi += 1
        ax, ay = px[lo], py[lo]
        bx, by = px[hi], py[hi]
        tx, ty = bx - ax, by - ay
        norm = math.hypot(tx, ty)
        if norm > 1e-9:
            nx[i] = -ty / norm
            ny[i] = tx / norm
            valid[i] = True
    return nx, ny, valid


@njit(cache=True)
def _point_to_line(px, py, qx, qy, x, y, t):
    """Gauss-Newton on the point-to-line distances of the current points to the previous scan's local lines, from
    ``(x, y, t)``; correspondences re-found every step (the nearest previous point among a few in bearing order).

    Why lines, not the smeared field: a smeared point falls off along the wall as well as across it, so where the
    current scan sees a wall further than the previous one did (every segment's end on the side the robot turns
    to) the field pulls the point back along the wall, against the turn: the turn shrinks by a few percent. The
    distance to a line has no component along the wall.
    """
    nx, ny, valid = _normals(px, py)
    bearing = np.arctan2(py, px)
    order = np.argsort(bearing)
    sb = bearing[order]
    m = px.shape[0]
    for _ in range(_ITERATIONS):
        c = math.cos(t)
        s = math.sin(t)
        h = np.zeros((3, 3))
        b = np.zeros(3)
        used = 0
        for k in range(qx.shape[0]):
            wx = x + c * qx[k] - s * qy[k]
            wy = y + s * qx[k] + c * qy[k]
            j = np.searchsorted(sb, math.atan2(wy, wx))
            best = _MAX_DISTANCE * _MAX_DISTANCE
            bi = -1
            for jj in range(max(j - _WINDOW, 0), min(j + _WINDOW, m)):
                i = order[jj]
                d2 = (px[i] - wx) ** 2 + (py[i] - wy) ** 2
                if d2 < best:
                    best = d2
                    bi = i
            if bi < 0 or not valid[bi]:
                continue
            r = nx[bi] * (wx - px[bi]) + ny[bi] * (wy - py[bi])
            w = 1.0 / (1.0 + (r / _HUBER) ** 2)  # Cauchy: a few points on the wrong wall do not drag the pose
            jt = nx[bi] * (-s * qx[k] - c * qy[k]) + ny[bi] * (c * qx[k] - s * qy[k])
            jac = (nx[bi], ny[bi], jt)
            for a in range(3):
                b[a] -= w * jac[a] * r
                for e in range(3):
                    h[a, e] += w * jac[a] * jac[e]
            used += 1
        if used < 10:
            break
        for a in range(3):
            h[a, a] += _DAMPING  # a corridor leaves the motion along it unseen: keep it where the sweep put it
        step = np.linalg.solve(h, b)
        x += step[0]
        y += step[1]
        t += step[2]
        if abs(step[2]) < 1e-5 and math.hypot(step[0], step[1]) < 1e-4:
            break
    return np.array([x, y, t])


@njit(cache=True)
def _register(px, py, qx, qy, current, guess, half_turn):
    coarse, cox, coy = _field(px, py, _COARSE[0], _COARSE[1])
    # every second point: the sweep only has to land in the fine field's basin
    x, y, t = _sweep(coarse, cox, coy, _COARSE[0], qx[::2].copy(), qy[::2].copy(), guess[0], guess[1], guess[2],
                     half_turn, 0.02, 0.1)
    return _point_to_line(px, py, qx, qy, x, y, t)


def consecutive_motion(previous: NDArray[np.float64], current: NDArray[np.float64], guess: NDArray[np.float64],
                       half_turn: float = 0.25) -> NDArray[np.float64]:
    """The pose of the current scan in the previous scan's frame, ``(x, y, theta)``.

    ``previous``, ``current``: (n, 2) endpoints in each scan's robot frame (m);
    ``guess``: the motion to start from (e.g. the last one); ``half_turn``
    (rad): the heading sweep's reach around the guess. Deterministic.
    """
    guess = np.asarray(guess, dtype=np.float64)
    if previous.shape[0] < 3 or current.shape[0] < 3:
        return guess.copy()
    current = np.ascontiguousarray(current, dtype=np.float64)
    return _register(np.ascontiguousarray(previous[:, 0]), np.ascontiguousarray(previous[:, 1]),
                     np.ascontiguousarray(current[:, 0]), np.ascontiguousarray(current[:, 1]), current, guess,
                     float(half_turn))


@njit(cache=True)
def _fits(px, py, qx, qy, poses):
    coarse, cox, coy = _field(px, py, _COARSE[0], _COARSE[1])
    inv = 1.0 / _COARSE[0]
    out = np.empty(poses.shape[0])
    for k in range(poses.shape[0]):
        out[k] = _score(coarse, cox, coy, inv, qx, qy, poses[k, 0], poses[k, 1], poses[k, 2]) / qx.shape[0]
    return out


def registration_fit(previous: NDArray[np.float64], current: NDArray[np.float64],
                     poses: NDArray[np.float64]) -> NDArray[np.float64]:
    """How well the current scan's points lie on the previous scan's at each pose ``(k, 3)``: the mean of the
    previous points' coarse smeared field (0: nowhere near, 1: on them) under the current points. Compares
    candidate motions of one scan pair; its level depends on how much the two scans overlap."""
    poses = np.atleast_2d(np.asarray(poses, dtype=np.float64))
    if previous.shape[0] < 3 or current.shape[0] < 3:
        return np.zeros(poses.shape[0])
    return _fits(np.ascontiguousarray(previous[:, 0]), np.ascontiguousarray(previous[:, 1]),
                 np.ascontiguousarray(current[:, 0]), np.ascontiguousarray(current[:, 1]), poses)
