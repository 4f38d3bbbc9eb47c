"""The motion between two consecutive scans, from the scans alone (no map): an independent turn estimate.

Why: a scan-to-map match is biased where the map is young. Walls seen once
score less than walls seen often, so while the robot turns into new space the
best fit leans back onto the old walls and under-turns by a few percent
(crsm on the mines logs, docs/methods/crsm.md). Two consecutive scans are
equally mature and overlap almost wholly, so their relative motion carries
no such bias; it is noisier per scan, but its errors do not build into the
map when it only serves as a prediction the map match is tested against.

How: the previous scan's endpoints are smeared into a small field
(:func:`slam2d.matching.correlative.smear_points`, a Gaussian per point),
coarse and fine. On the coarse field a sweep over headings (with a few
translations around the guess) picks the start; Gauss-Newton
(:func:`slam2d.matching.gauss_newton.gauss_newton_level`, Hector's step on a
bilinearly interpolated field) then refines it on the fine field. The sweep is what lets a 15 degree turn be found from a guess of
none: far points move out of a Gaussian's reach after a few degrees.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

from slam2d.matching.correlative import smear_points
from slam2d.matching.gauss_newton import gauss_newton_level

__all__ = ["consecutive_motion"]

# (cell size m, smear sigma m) of the coarse field (the heading sweep) and the fine one (Gauss-Newton)
_COARSE = (0.10, 0.15)
_FINE = (0.05, 0.05)
_ITERATIONS = 3  # Gauss-Newton steps; more change nothing measurable on the mines logs
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
def _register(px, py, qx, qy, current, guess, half_turn):
    coarse, cox, coy = _field(px, py, _COARSE[0], _COARSE[1])
    # every second point: the sweep only has to land in the fine field's basin
    x, y, t = _sweep(coarse, cox, coy, _COARSE[0], qx[::2].copy(), qy[::2].copy(), guess[0], guess[1], guess[2],
                     half_turn, 0.02, 0.1)
    fine, fox, foy = _field(px, py, _FINE[0], _FINE[1])
    start = np.array([x, y, t])
    return gauss_newton_level(fine, fox, foy, _FINE[0], current, np.ones(qx.shape[0]), start, _ITERATIONS, 1e-4, 1e-4,
                              0.1, 0.2, start, np.zeros((3, 3)))[0]


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
