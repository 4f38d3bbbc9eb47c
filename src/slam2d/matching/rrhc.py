"""CRSM's random-restart hill climbing (RRHC) over the critical rays, in map cells.

A candidate is an offset ``(dx, dy, dtheta)`` from the current pose: whole
cells in x and y, and multiples of 1/180 rad in heading (the original draws
``(rand() % d - d / 2) / 90`` rad). Its fitness is, over the selected rays'
endpoints,

    sum (10 (255 - m) + the four neighbours' (255 - m)) / 255 / (14 N)

(``m`` the 8-bit map value; endpoints on unknown cells, 127, add nothing):
higher is better. Starting from the zero offset:

* a candidate better than the best so far becomes the best and the climb
  continues from it: ``dx, dy += rand in [-d/8, d/8)``, ``dtheta += [-d/2, d/2)/90``;
* otherwise the climb restarts at random: ``dx, dy in [-d/4, d/4)``,
  ``dtheta in [-d/2, d/2)/45`` (``d`` = ``hill_climbing_disparity``),

for ``max_iter`` candidates. This is not BreezySLAM's RMHC
(:mod:`slam2d.matching.rmhc`): there the spread halves around an accepted
centre and the search ends on failures; here every failure restarts around
the current pose and the budget is fixed, so the two stay separate.

Speed: because x and y move by whole cells, a ray's cell is its cell at the
candidate's heading plus ``(dy, dx)``. The cells of every ray at each heading
the search visits are computed once per scan and reused, so scoring a
candidate is integer additions and five lookups per ray. Every restart
candidate's fitness is tabulated once per scan (:func:`_restart_table`), and
once the best beats the whole table no later candidate can change anything:
the loop stops there and skips the generator past the draws it would have
made (on mines-exp1 after a fifth of the budget in the median scan), so
results stay bit for bit those of the full loop.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from slam2d.matching.random_numbers import randint, skip

__all__ = ["rrhc_search", "refine_offset", "near_known", "paired_gain", "HEADING_STEP"]

#: Heading lattice of the search, rad.
HEADING_STEP = 1.0 / 180.0


@njit(cache=True, inline="always")
def _cells_at(k, rows_k, cols_k, ready, kmax, bx, by, theta, qx, qy, out_r, out_c):
    """Cells of every ray at heading offset ``k`` steps; cached in ``rows_k/cols_k`` when ``|k| <= kmax``."""
    n = qx.shape[0]
    cached = -kmax <= k <= kmax
    if cached and ready[k + kmax]:
        return rows_k[k + kmax], cols_k[k + kmax]
    t = theta + k * HEADING_STEP
    c = math.cos(t)
    s = math.sin(t)
    if cached:
        r_out = rows_k[k + kmax]
        c_out = cols_k[k + kmax]
    else:
        r_out = out_r
        c_out = out_c
    for j in range(n):
        c_out[j] = int(math.floor(bx + c * qx[j] - s * qy[j]))
        r_out[j] = int(math.floor(by + s * qx[j] + c * qy[j]))
    if cached:
        ready[k + kmax] = True
    return r_out, c_out


@njit(cache=True)
def _fitness(values, r_k, c_k, dx, dy):
    """Integer fitness sum (before the 255 * 14 * N normalisation) of the rays' cells shifted by ``(dx, dy)``."""
    rmax, cmax = values.shape
    total = 0
    for j in range(r_k.shape[0]):
        r = r_k[j] + dy
        c = c_k[j] + dx
        if r < 1 or c < 1 or r >= rmax - 1 or c >= cmax - 1:
            continue  # the original skips endpoints at the map's edge
        v = np.int64(values[r, c])
        if v == 127:
            continue
        total += 10 * (255 - v) + (1020 - np.int64(values[r - 1, c]) - np.int64(values[r + 1, c])
                                   - np.int64(values[r, c - 1]) - np.int64(values[r, c + 1]))
    return total


@njit(cache=True)
def _restart_table(values, cells_r, cells_c, lo, width):
    """Fitness of every restart offset: ``table[i, dy - lo, dx - lo]`` for heading ``i`` of the restart lattice.

    ``cells_r[i, j], cells_c[i, j]`` are ray ``j``'s cells at restart heading
    ``i``. The per-cell fitness ``10 (255 - m) + neighbours`` (0 on unknown
    cells and on the map's border, which the direct score skips) is computed
    once over the region the windows cover, then each ray adds its
    ``width x width`` window of it: the same integers :func:`_fitness` sums,
    for every restart candidate at once.

    Speed (most of a scan's CPU time is here): int32 cells and sums, and rows
    walked through slices, so both loops compile to SIMD adds (int64 sums and
    indexed rows took three times as long). A cell's fitness is at most 3570,
    so int32 sums hold for up to 600 000 rays.
    """
    nk, n = cells_r.shape
    if n > 600_000:
        raise ValueError("too many rays for the int32 restart table")
    rmax, cmax = values.shape
    r0 = cells_r.min() + lo
    c0 = cells_c.min() + lo
    r1 = cells_r.max() + lo + width
    c1 = cells_c.max() + lo + width
    # zeroed only where the loop below does not write (off the map and its border): the region is ~0.4 MB
    g = np.empty((r1 - r0, c1 - c0), dtype=np.int32)
    ca = max(c0, 1)
    cb = max(min(c1, cmax - 1), ca)
    ra = max(r0, 1)
    rb = max(min(r1, rmax - 1), ra)
    g[: min(ra - r0, r1 - r0)] = 0
    g[max(rb - r0, 0):] = 0
    g[:, : min(ca - c0, c1 - c0)] = 0
    g[:, max(cb - c0, 0):] = 0
    for r in range(ra, rb):
        up = values[r - 1, ca:cb]
        mid = values[r, ca:cb]
        left = values[r, ca - 1:cb - 1]
        right = values[r, ca + 1:cb + 1]
        down = values[r + 1, ca:cb]
        out = g[r - r0, ca - c0:cb - c0]
        for c in range(cb - ca):
            v = np.int32(mid[c])
            f = 3570 - 10 * v - np.int32(up[c]) - np.int32(down[c]) - np.int32(left[c]) - np.int32(right[c])
            out[c] = np.int32(f) if v != 127 else np.int32(0)
    table = np.zeros((nk, width, width), dtype=np.int32)
    for i in range(nk):
        for j in range(n):
            br = cells_r[i, j] + lo - r0
            bc = cells_c[i, j] + lo - c0
            for a in range(width):
                src = g[br + a, bc:bc + width]
                dst = table[i, a]
                for b in range(width):
                    dst[b] += src[b]
    return table


@njit(cache=True)
def _setup(origin_x, origin_y, resolution, qx, qy, x, y, kmax):
    """What a search around pose ``(x, y)`` needs: the pose and the rays in cells, and the per-heading cell caches.

    Returns ``(bx, by, qx cells, qy cells, rows_k, cols_k, ready, tmp_r, tmp_c)``
    for :func:`_cells_at` with headings ``|k| <= kmax`` cached.
    """
    n = qx.shape[0]
    inv = 1.0 / resolution
    rows_k = np.empty((2 * kmax + 1, n), dtype=np.int64)
    cols_k = np.empty((2 * kmax + 1, n), dtype=np.int64)
    ready = np.zeros(2 * kmax + 1, dtype=np.bool_)
    return ((x - origin_x) * inv, (y - origin_y) * inv, qx * inv, qy * inv, rows_k, cols_k, ready,
            np.empty(n, dtype=np.int64), np.empty(n, dtype=np.int64))


@njit(cache=True)
def rrhc_search(values, origin_x, origin_y, resolution, qx, qy, x, y, theta, disparity, max_iter, state):
    """Search offsets from pose ``(x, y, theta)`` (m, rad) for the rays' endpoints ``(qx, qy)`` (robot frame, m).

    Returns ``(dx cells, dy cells, dtheta steps, fitness, evaluations, restarts, improvements)``.
    """
    n = qx.shape[0]
    kmax = 4 * disparity + 2 * disparity  # restarts reach 2d steps; climbs wander a few d further
    bx, by, qxc, qyc, rows_k, cols_k, ready, tmp_r, tmp_c = _setup(origin_x, origin_y, resolution, qx, qy, x, y, kmax)
    # restarts: dx, dy = rand(d) // 2 - d // 4 in [lo, lo + width); k = 4 rand(d) - 2 d
    lo = -(disparity // 4)
    width = (disparity - 1) // 2 + 1
    cells_r = np.empty((disparity, n), dtype=np.int64)
    cells_c = np.empty((disparity, n), dtype=np.int64)
    for i in range(disparity):
        r_k, c_k = _cells_at(4 * i - 2 * disparity, rows_k, cols_k, ready, kmax, bx, by, theta, qxc, qyc,
                             tmp_r, tmp_c)
        cells_r[i] = r_k
        cells_c[i] = c_k
    table = _restart_table(values, cells_r, cells_c, lo, width)
    norm = 255.0 * 14.0 * max(n, 1)
    best = 0
    bdx, bdy, bk = 0, 0, 0
    dx, dy, k = 0, 0, 0
    restart_index = -1  # >= 0: the candidate is a restart, its fitness is in the table
    restarts = 0
    improvements = 0
    evaluations = 0
    counter = 0
    top = table.max()
    while True:
        if restart_index >= 0:
            if best >= top:
                # No restart can beat the best any more, so no climb starts again: every remaining candidate is a
                # failed restart. Count them and advance the generator past their draws (3 each) as drawing would:
                # the result, the counts and the next scan's numbers are the same, at a fraction of the time.
                remaining = max_iter + 2 - counter
                evaluations += remaining
                restarts += remaining
                skip(state, 3 * remaining)
                break
            f = table[restart_index, dy - lo, dx - lo]
        else:
            r_k, c_k = _cells_at(k, rows_k, cols_k, ready, kmax, bx, by, theta, qxc, qyc, tmp_r, tmp_c)
            f = _fitness(values, r_k, c_k, dx, dy)
        evaluations += 1
        if f > best:
            best = f
            bdx, bdy, bk = dx, dy, k
            improvements += 1
            dx += randint(state, disparity) // 4 - disparity // 8
            dy += randint(state, disparity) // 4 - disparity // 8
            k += 2 * randint(state, disparity) - disparity
            restart_index = -1
        else:
            dx = randint(state, disparity) // 2 - disparity // 4
            dy = randint(state, disparity) // 2 - disparity // 4
            restart_index = randint(state, disparity)
            k = 4 * restart_index - 2 * disparity
            restarts += 1
        if counter > max_iter:
            break
        counter += 1
    return bdx, bdy, bk, best / norm, evaluations, restarts, improvements


@njit(cache=True)
def _refine(values, rows_k, cols_k, ready, kmax, bx, by, theta, qxc, qyc, tmp_r, tmp_c, dx, dy, k, best, rounds):
    """Steepest ascent over the 26 neighbours (one cell, one heading step) until none improves.

    Why: restarts land on a 1/45 rad heading lattice and the climb's random
    steps (up to d/8 cells, d/2/90 rad) are too coarse to settle in a wall's
    two-cell basin, so most scans end on the lattice. A heading off by half a
    lattice step (0.64 degrees) misses walls a few metres away by more than a
    cell, and the best translation then compensates sideways: per-scan
    errors of several centimetres and a drifting heading. The neighbours of
    the 1/180 rad lattice fix that in a few rounds of 26 evaluations.
    Returns ``(dx, dy, k, fitness, rounds that moved, evaluations)``.
    """
    moved = 0
    evaluations = 0
    for _ in range(rounds):
        cdx, cdy, ck, cbest = dx, dy, k, best
        for dk in (-1, 0, 1):
            r_k, c_k = _cells_at(k + dk, rows_k, cols_k, ready, kmax, bx, by, theta, qxc, qyc, tmp_r, tmp_c)
            for ex in (-1, 0, 1):
                for ey in (-1, 0, 1):
                    if dk == 0 and ex == 0 and ey == 0:
                        continue
                    f = _fitness(values, r_k, c_k, dx + ex, dy + ey)
                    evaluations += 1
                    if f > cbest:
                        cbest = f
                        cdx, cdy, ck = dx + ex, dy + ey, k + dk
        if cbest <= best:
            break
        dx, dy, k, best = cdx, cdy, ck, cbest
        moved += 1
    return dx, dy, k, best, moved, evaluations


@njit(cache=True)
def refine_offset(values, origin_x, origin_y, resolution, qx, qy, x, y, theta, dx, dy, k, rounds):
    """:func:`_refine` from offset ``(dx, dy, k)`` for another set of points (e.g. every beam, not the critical rays).

    Returns ``(dx, dy, k, fitness, rounds that moved)``, fitness normalised as :func:`rrhc_search`'s.
    """
    kmax = abs(k) + rounds + 1
    bx, by, qxc, qyc, rows_k, cols_k, ready, tmp_r, tmp_c = _setup(origin_x, origin_y, resolution, qx, qy, x, y, kmax)
    r_k, c_k = _cells_at(k, rows_k, cols_k, ready, kmax, bx, by, theta, qxc, qyc, tmp_r, tmp_c)
    best = _fitness(values, r_k, c_k, dx, dy)
    dx, dy, k, best, moved, _ = _refine(values, rows_k, cols_k, ready, kmax, bx, by, theta, qxc, qyc, tmp_r, tmp_c,
                                        dx, dy, k, best, rounds)
    return dx, dy, k, best / (255.0 * 14.0 * max(qx.shape[0], 1)), moved


@njit(cache=True)
def near_known(values, origin_x, origin_y, resolution, qx, qy, x, y, theta, margin):
    """Whether each point ``(qx, qy)`` (robot frame, m), placed at pose ``(x, y, theta)``, has a known cell (not 127)
    within ``margin`` cells: the rays that can be judged against the map from this pose."""
    n = qx.shape[0]
    rmax, cmax = values.shape
    out = np.zeros(n, dtype=np.bool_)
    c = math.cos(theta)
    s = math.sin(theta)
    inv = 1.0 / resolution
    for j in range(n):
        col = int(math.floor((x + c * qx[j] - s * qy[j] - origin_x) * inv))
        row = int(math.floor((y + s * qx[j] + c * qy[j] - origin_y) * inv))
        for r in range(max(row - margin, 0), min(row + margin + 1, rmax)):
            for cc in range(max(col - margin, 0), min(col + margin + 1, cmax)):
                if values[r, cc] != 127:
                    out[j] = True
                    break
            if out[j]:
                break
    return out


@njit(cache=True)
def _point_fitness(values, bx, by, c, s, qx, qy, out):
    """Per-point fitness (the summand of :func:`_fitness`) of points ``qx, qy`` (cells) at a pose in cells."""
    rmax, cmax = values.shape
    for j in range(qx.shape[0]):
        col = int(math.floor(bx + c * qx[j] - s * qy[j]))
        row = int(math.floor(by + s * qx[j] + c * qy[j]))
        out[j] = 0
        if row < 1 or col < 1 or row >= rmax - 1 or col >= cmax - 1:
            continue
        v = np.int64(values[row, col])
        if v == 127:
            continue
        out[j] = 10 * (255 - v) + (1020 - np.int64(values[row - 1, col]) - np.int64(values[row + 1, col])
                                   - np.int64(values[row, col - 1]) - np.int64(values[row, col + 1]))


@njit(cache=True)
def paired_gain(values, origin_x, origin_y, resolution, qx, qy, xa, ya, ta, xb, yb, tb):
    """How much better points ``(qx, qy)`` (robot frame, m) fit at pose a than at pose b, beam by beam.

    A paired test over the beams: with ``g_j`` ray ``j``'s fitness at a minus
    at b (normalised as :func:`rrhc_search`'s, so the mean is the fitness
    gain), returns ``(mean gain, z, n)`` where ``z = mean / (sd / sqrt(n))``.
    Why: a few dozen returns leave near-equal maxima far apart, and the
    search's best can beat another pose by chance; ``z`` asks whether the gain
    stands out from the beams' scatter, so a sparse scan needs a larger gain
    than a dense one for the same ``z``. ``z`` is +inf for a gain with no
    scatter, 0 with no gain.
    """
    n = qx.shape[0]
    inv = 1.0 / resolution
    qxc = qx * inv
    qyc = qy * inv
    fa = np.empty(n, dtype=np.int64)
    fb = np.empty(n, dtype=np.int64)
    _point_fitness(values, (xa - origin_x) * inv, (ya - origin_y) * inv, math.cos(ta), math.sin(ta), qxc, qyc, fa)
    _point_fitness(values, (xb - origin_x) * inv, (yb - origin_y) * inv, math.cos(tb), math.sin(tb), qxc, qyc, fb)
    if n < 2:
        return 0.0, 0.0, n
    norm = 255.0 * 14.0
    total = 0.0
    for j in range(n):
        total += (fa[j] - fb[j]) / norm
    mean = total / n
    var = 0.0
    for j in range(n):
        e = (fa[j] - fb[j]) / norm - mean
        var += e * e
    var /= n - 1
    if var <= 0.0:
        return mean, (math.inf if mean > 0.0 else 0.0), n
    return mean, mean / math.sqrt(var / n), n
