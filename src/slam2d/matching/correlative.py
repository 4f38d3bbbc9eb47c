"""Correlative scan matching (Olson 2009; Karto's matcher): exhaustive search over x, y, angle.

The reference points (the scans being matched against, in the world frame)
are drawn into a *correlation grid*: every point is smeared by a Gaussian
``exp(-0.5 (d / sigma)^2)`` of its own sigma, cells keeping the largest value
(0..255 in a ``uint8`` grid, Karto keeps 0..100). A candidate pose of the
query scan scores the mean grid value under its points, the *response* in
[0, 1]: 1 means every point lies on a reference point.

The search is Karto's: per angle, the query points are rotated once and turned
into integer cells (the lookup table), then every x, y offset is an integer
shift. A *coarse* search covers the whole window at two cells per step and
the coarse angle step; a *fine* search covers one coarse step around the
coarse best at one cell per step and the fine angle step. With a penalty the
response is multiplied by ``max(1 - 0.2 d^2 / distance_variance_penalty,
minimum_distance_penalty) * max(1 - 0.2 dtheta^2 / angle_variance_penalty,
minimum_angle_penalty)`` (Karto's gains of 0.2), measured from the prior
pose. Equal best responses are averaged, so a corridor's flat response lands
in its middle rather than at a window edge.

Covariance, from the response surface as Karto computes it: x, y from the
coarse surface (for each x, y the best response over angles), the
response-weighted spread of every x, y within 0.1 of the best, floored at
0.1 coarse-step^2 and divided by the best response; theta from the spread of
the fine angles at the best x, y (floored at one fine step^2). The result also carries the
*coarse heading variance*, the same spread over the coarse angles (best response per angle): the
fine one cannot see an alternative heading beyond its +-1 deg window.

Wide windows (loop closure: 8 m at 5 cm is 81 x 81 x 21 poses) are searched
by *branch and bound* over blocks of translations: a max-pooled copy of the
grid gives, per block and angle, an upper bound of the response of every
translation in the block; blocks are scored exactly in decreasing bound order
until the bound falls more than 0.1 below the best found. Every pose whose
response can be within 0.1 of the best is thus scored exactly, so the result
and its covariance equal the exhaustive search's (a test checks it), at a
fraction of the lookups.

A match's own coarse search (narrow windows, searched exhaustively) skips angles the same
way: angles are scored from the prior's heading outwards, points in chunks, and an angle whose
sums so far plus a full cell for every point still to come (times its largest penalty) cannot
come within 0.1 of the best response scored so far is left unscored. Only the surface within
that band shapes the result, so the match is the exhaustive one bit for bit, with about two
thirds of the lookups on real scans.
"""

from __future__ import annotations

import copy
import math
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import NDArray

__all__ = ["CorrelativeMatcher", "GridCache", "MatchResult", "smear_points"]

# Response values are stored as 0..SCALE in a uint8 grid.
_SCALE = 255.0
# Karto's penalty gains (DISTANCE_PENALTY_GAIN, ANGLE_PENALTY_GAIN).
_PENALTY_GAIN = 0.2
# Poses within this much of the best response shape the covariance (Karto's 0.1).
_COVARIANCE_BAND = 0.1
# Branch and bound: translation blocks of this many search steps on a side.
_BLOCK = 8
# Windows with fewer translations than this are searched exhaustively.
_BNB_MIN_STEPS = 31
# Response bound: correlation cells per side of a block of the max-pooled bound grid.
_BOUND_BLOCK = 8
# Response bound: how many times a heading's translation window is quartered where the bound passes.
_BOUND_SPLITS = 3
# Exhaustive searches of at least this many lookups share their angles among threads.
_PARALLEL_LOOKUPS = 1_000_000
# Points scored between two checks of a coarse search's angle bound (see _score_poses_pruned).
_PRUNE_CHUNK = 32
# Smears of at least this many points are drawn in row bands, one per thread.
_PARALLEL_POINTS = 4000
# Pieces per thread a threaded smear or search is cut into; the threads take them in turn as they
# come free (see _split), so a worker that starts late (a busy machine) leaves its piece to this
# thread instead of keeping it waiting. More pieces (3 per thread) balance better but cost more than
# they save: each band re-reads the points near its edges (fr079: the banded smears 1.2 -> 1.8 s).
_PIECES_PER_THREAD = 1
# Threads the big searches and smears are shared among (SLAM2D_THREADS; 1 turns threading off).
_THREADS = max(1, int(os.environ.get(
    "SLAM2D_THREADS", min(len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1, 4))))
# Angle offsets that depend only on a matcher's settings, computed once (see _coarse_angles); never written to.
_ANGLES: dict = {}
# Interleaved point orders by point count, computed once (see _interleaved); never written to.
_INTERLEAVE_ORDERS: dict = {}
# Response bounds of at least this many points x headings share their headings among threads.
_PARALLEL_BOUND = 4000
# Karto's MAX_VARIANCE: the covariance of a match that found nothing.
MAX_VARIANCE = 500.0
# Poses responding within this of the best count towards a match's covariance (Karto's 0.1).
COVARIANCE_BAND = _COVARIANCE_BAND


@dataclass
class MatchResult:
    """The best pose of a query scan, with its response and covariance."""

    pose: NDArray[np.float64]  # [x, y, theta] of the query robot pose, world frame
    covariance: NDArray[np.float64]  # 3x3, world-frame x, y, theta
    response: float  # in [0, 1], penalised when the match was
    raw_response: float  # the same pose without the penalty
    evaluated: int  # point lookups done (for diagnostics)
    # Spread of the coarse angles whose best response is within 0.1 of the best (rad^2): wide
    # when the scan fits about as well at headings many coarse steps apart.
    heading_variance_coarse: float = 0.0
    # How far the best coarse response at the prior's own heading (over the x, y window) lies below
    # the best coarse response: whether the scan fits the prior's heading about as well (NaN: not searched).
    prior_heading_drop: float = math.nan


# --------------------------------------------------------------------------- compiled kernels


@njit(cache=True, inline="always")
def _kernel(s, resolution, ex, kern):
    """Fill ``kern`` with the smear of sigma ``s`` in 0..255 (``ex`` is scratch); returns its half-width in cells."""
    half = int(math.ceil(2.0 * s / resolution))
    n = 2 * half + 1
    inv = resolution / s
    # exp(-a k^2) by the recurrence e_k = e_(k-1) q_k, q_k = q_(k-1) exp(-2a): two exp() calls
    # instead of n. A sensor model gives every point its own sigma, so the kernel is built per
    # point and its exp() calls were most of a smear's time. The rounding to 0..255 comes out the
    # same as with exp() per cell (every kernel of 200,000 random sigmas compared; tested).
    a = 0.5 * inv * inv
    e = _SCALE
    q = math.exp(-a)
    r = math.exp(-2.0 * a)
    ex[half] = e
    for k in range(1, half + 1):
        e *= q
        q *= r
        ex[half - k] = e
        ex[half + k] = e
    # Rows i and n - 1 - i are the same (the kernel is symmetric): each value computed once.
    for i in range(half + 1):
        wy = ex[i] / _SCALE
        for j in range(n):
            v = np.uint8(wy * ex[j] + 0.5)
            kern[i, j] = v
            kern[n - 1 - i, j] = v
    return half


@njit(cache=True)
def smear_points(grid, origin_x, origin_y, resolution, px, py, sigma, skip_drawn=False):
    """Max-combine a Gaussian of each point's sigma into ``grid`` (uint8, 0..255).

    ``skip_drawn``: the caller knows every point ever drawn into ``grid`` had the
    same sigma, so a point whose cell already holds the full value (only a kernel's
    centre does) would draw the very same kernel again and is skipped. Overlapping
    scans put many points into the same 1 cm cell (a third of them on fr079).

    As in Karto, the point is snapped to its cell (which gets the full value)
    and the kernel, reaching 2 sigma, is evaluated at whole-cell distances, so
    a query point in the same cell as a reference point scores 1 and the
    response thresholds mean what they mean in Karto. The kernel is built
    once per distinct sigma (a separable product of exp() rows), then one comparison per cell.
    """
    _smear_band(grid, origin_x, origin_y, resolution, px, py, sigma, skip_drawn, 0, grid.shape[0])


@njit(cache=True, inline="always")
def _smear_band(grid, origin_x, origin_y, resolution, px, py, sigma, skip_drawn, band_lo, band_hi):
    """:func:`smear_points` writing only the grid rows [band_lo, band_hi) (and reading no other)."""
    rows, cols = grid.shape
    if px.shape[0] == 0:
        return
    widest = int(math.ceil(2.0 * sigma.max() / resolution))
    ex = np.empty(2 * widest + 1)
    # The kernel in 0..255 is rebuilt only when the sigma changes (once with no sensor model).
    kern = np.empty((2 * widest + 1, 2 * widest + 1), np.uint8)
    last = -1.0
    half = 0
    n = 1
    for k in range(px.shape[0]):
        s = sigma[k]
        if s != last:
            last = s
            half = _kernel(s, resolution, ex, kern)
            n = 2 * half + 1
        cu = int(math.floor((px[k] - origin_x) / resolution))
        cv = int(math.floor((py[k] - origin_y) / resolution))
        if skip_drawn and cv >= band_lo and cv < band_hi and cu >= 0 and cu < cols and grid[cv, cu] == 255:
            continue
        r0 = cv - half
        c0 = cu - half
        i_lo = max(band_lo - r0, 0)
        i_hi = min(n, band_hi - r0)
        j_lo = max(0, -c0)
        j_hi = min(n, cols - c0)
        m = j_hi - j_lo
        for i in range(i_lo, i_hi):
            # Slices from the first cell: no negative-index checks, so the loop vectorises.
            row = grid[r0 + i, c0 + j_lo:]
            kr = kern[i, j_lo:]
            for j in range(m):
                if kr[j] > row[j]:
                    row[j] = kr[j]


@njit(cache=True)
def _row_sort(grid, origin_x, origin_y, resolution, px, py, sigma):
    """The points in grid-row order (a counting sort, stable), one per cell, and where each row's points start.

    Points sharing a cell are merged into the first of them with the largest of their
    sigmas: the smear snaps a point to its cell, and at one centre a wider kernel is at
    least the narrower one everywhere (its exp() of a smaller argument, reaching further),
    so the merged point draws the same grid. Overlapping scans put many points into one
    1 cm cell (about half of a near chain's on fr079); a marker per column finds them in
    one pass, without sorting.

    Key r + 1 for row r, clamped to [0, rows + 1] (0: below the grid, rows + 1: above);
    ``start[key]`` is the first sorted point of that key, ``start[rows + 2]`` the count.
    """
    n = px.shape[0]
    rows, cols = grid.shape
    key = np.empty(n, np.int64)
    count = np.zeros(rows + 3, np.int64)
    for k in range(n):
        r = int(math.floor((py[k] - origin_y) / resolution)) + 1
        r = min(max(r, 0), rows + 1)
        key[k] = r
        count[r + 1] += 1
    for r in range(rows + 2):
        count[r + 1] += count[r]
    order = np.empty(n, np.int64)
    pos = count.copy()
    for k in range(n):
        order[pos[key[k]]] = k
        pos[key[k]] += 1
    # Per column: the row of the last point kept there and its index in the output.
    seen_row = np.full(cols, -(1 << 62), np.int64)
    seen_at = np.zeros(cols, np.int64)
    sx = np.empty(n)
    sy = np.empty(n)
    ss = np.empty(n)
    start = np.zeros(rows + 3, np.int64)
    m = 0
    for r in range(rows + 2):
        start[r] = m
        for t in range(count[r], count[r + 1]):
            k = order[t]
            cu = int(math.floor((px[k] - origin_x) / resolution))
            cv = int(math.floor((py[k] - origin_y) / resolution))
            if cu >= 0 and cu < cols:
                if seen_row[cu] == cv:
                    at = seen_at[cu]
                    if sigma[k] > ss[at]:
                        ss[at] = sigma[k]
                    continue
                seen_row[cu] = cv
                seen_at[cu] = m
            sx[m] = px[k]
            sy[m] = py[k]
            ss[m] = sigma[k]
            m += 1
    start[rows + 2] = m
    return sx[:m], sy[:m], ss[:m], start


@njit(cache=True)
def smear_in_row_order(grid, origin_x, origin_y, resolution, px, py, sigma, skip_drawn=False):
    """:func:`smear_points` over the points taken in grid-row order (a counting sort, stable).

    Row order keeps the smear's writes in cache: many scans overlap in space,
    not in memory. Points sharing a cell are drawn once (see :func:`_row_sort`).
    """
    sx, sy, ss, _ = _row_sort(grid, origin_x, origin_y, resolution, px, py, sigma)
    smear_points(grid, origin_x, origin_y, resolution, sx, sy, ss, skip_drawn)


@njit(cache=True)
def _band_edges(start, n, rows, bands):
    """Row edges of ``bands`` bands holding about equal numbers of row-sorted points (see :func:`_row_sort`)."""
    edge = np.empty(bands + 1, np.int64)
    edge[0] = 0
    edge[bands] = rows
    key = 0
    for b in range(1, bands):
        target = (b * n) // bands
        while start[key + 1] <= target:
            key += 1
        edge[b] = min(max(key - 1, edge[b - 1]), rows)
    return edge


@njit(cache=True, nogil=True)
def _smear_bands(grid, origin_x, origin_y, resolution, sx, sy, ss, start, edge, b0, b1, skip_drawn):
    """Smear the row-sorted points into the bands [b0, b1) of rows: band b writes only rows [edge[b], edge[b + 1])."""
    rows = grid.shape[0]
    if sx.shape[0] == 0:
        return
    widest = int(math.ceil(2.0 * ss.max() / resolution))
    for b in range(b0, b1):
        lo = edge[b]
        hi = edge[b + 1]
        if lo >= hi:
            continue
        # Keys (row + 1, clamped) of the points whose kernel can reach rows [lo, hi).
        k_lo = min(max(lo - widest + 1, 0), rows + 1)
        k_hi = min(max(hi + widest + 1, 0), rows + 2)
        a = start[k_lo]
        z = start[k_hi]
        _smear_band(grid, origin_x, origin_y, resolution, sx[a:z], sy[a:z], ss[a:z], skip_drawn, lo, hi)


def smear_in_row_bands(grid, origin_x, origin_y, resolution, px, py, sigma, skip_drawn=False, bands=2,
                       threads=None):
    """:func:`smear_in_row_order` with the grid cut into ``bands`` bands of rows, shared among threads.

    A band gets every point whose kernel reaches it and writes only its own rows, so no
    two threads write one cell; max-combining is order-free, so the grid is the serial
    one bit for bit, whichever thread draws which band. Bands hold about equal numbers of
    points; ``threads`` (default: as many as bands) take them in turn (see :func:`_split`).
    """
    if px.shape[0] == 0:
        return
    sx, sy, ss, start = _row_sort(grid, origin_x, origin_y, resolution, px, py, sigma)
    edge = _band_edges(start, sx.shape[0], grid.shape[0], bands)
    _split(lambda b0, b1: _smear_bands(grid, origin_x, origin_y, resolution, sx, sy, ss, start, edge, b0, b1,
                                       skip_drawn), bands, pieces=bands, threads=threads)


def _split(work, n, pieces=None, threads=None) -> None:
    """Run ``work(i0, i1)`` over [0, n) cut into ``pieces`` (default: one per thread), shared among threads.

    The pieces are compiled ``nogil`` kernels writing disjoint outputs, so Python threads run
    them side by side; they wait passively (no OpenMP spinning that would steal a busy
    machine's cores). Each thread, this one included, takes the next piece not yet taken
    until none is left, so a worker that wakes late (a busy machine) or a slower piece does
    not leave the others waiting; which thread runs which piece never changes the result.
    """
    parts = min(_THREADS if threads is None else threads, n)
    if parts <= 1:
        work(0, n)
        return
    pieces = min(max(parts, pieces or parts), n)
    cuts = [(k * n) // pieces for k in range(pieces + 1)]
    # next() on a shared range iterator hands each index out once (it runs under the GIL).
    todo = iter(range(pieces))

    def run():
        for k in todo:
            work(cuts[k], cuts[k + 1])

    futures = [_pool().submit(run) for _ in range(1, parts)]
    run()
    for f in futures:
        f.result()


_POOL: tuple[int, ThreadPoolExecutor] | None = None


def _pool() -> ThreadPoolExecutor:
    """The worker threads, made once per process (a forked child has none of its parent's threads)."""
    global _POOL
    if _POOL is None or _POOL[0] != os.getpid():
        _POOL = (os.getpid(), ThreadPoolExecutor(max_workers=max(_THREADS - 1, 1), thread_name_prefix="slam2d-match"))
    return _POOL[1]


def _smear(grid, origin_x, origin_y, resolution, px, py, sigma, skip_drawn) -> None:
    """:func:`smear_in_row_order`, in row bands on every thread when there are points enough to pay."""
    if _THREADS > 1 and px.shape[0] >= _PARALLEL_POINTS:
        smear_in_row_bands(grid, origin_x, origin_y, resolution, px, py, sigma, skip_drawn,
                           _THREADS * _PIECES_PER_THREAD, _THREADS)
    else:
        smear_in_row_order(grid, origin_x, origin_y, resolution, px, py, sigma, skip_drawn)


@njit(cache=True)
def _inside(px, py, lo_x, lo_y, hi_x, hi_y):
    """Indices of the points inside the box."""
    out = np.empty(px.shape[0], np.int64)
    m = 0
    for k in range(px.shape[0]):
        if px[k] >= lo_x and px[k] <= hi_x and py[k] >= lo_y and py[k] <= hi_y:
            out[m] = k
            m += 1
    return out[:m]


@njit(cache=True)
def _inside_not(px, py, lo_x, lo_y, hi_x, hi_y, old_lo_x, old_lo_y, old_hi_x, old_hi_y):
    """Indices of the points inside the first box and not inside the second."""
    out = np.empty(px.shape[0], np.int64)
    m = 0
    for k in range(px.shape[0]):
        x = px[k]
        y = py[k]
        if x >= lo_x and x <= hi_x and y >= lo_y and y <= hi_y and not (
            x >= old_lo_x and x <= old_hi_x and y >= old_lo_y and y <= old_hi_y
        ):
            out[m] = k
            m += 1
    return out[:m]


# A derived grid (see _derive_grid) marks where a dropped scan's kernels reach in blocks of this many cells a side.
_DERIVE_BLOCK = 8


@njit(cache=True)
def _derive_grid(dst, dox, doy, src, sox, soy, resolution, oc, orow, r0, r1, c0, c1,
                 wx, wy, wsig, wkept, xx, xy, xsig, lo_x, lo_y, hi_x, hi_y, block=_DERIVE_BLOCK):
    """Start a grid from another one drawn from mostly the same scans; returns (ok, the points still to draw).

    ``src`` holds, in its cells [r0, r1] x [c0, c1] (already clipped to ``dst``), the final values of
    a set of scans: the kept ones (``wkept`` per point of the wanted scans wx, wy, wsig) and dropped
    ones (xx, xy, xsig). A cell of ``dst`` is ``src``'s cell (row + ``orow``, col + ``oc``), which is
    exact only when every kept point snaps to the same cell in both grids (checked; ``ok`` False
    when not, and ``dst`` is left untouched). The copy is cleared in every block a dropped point's
    kernel reaches, so every copied cell is the max over kept points only. The points returned
    are the wanted ones inside the box (lo, hi) (the caller's box plus its smear reach) that are
    not kept, or whose kernel reaches a cleared block or leaves the copied cells: drawn, they make
    every cell whose kernels all come from inside the box final, and every other one at most
    final (max-combining is order-free), as drawing every wanted point inside the box would.
    """
    n = wx.shape[0]
    # The kept points' cells in dst (checked against src's) and kernel half-widths.
    cu = np.empty(n, np.int64)
    cv = np.empty(n, np.int64)
    hw = np.empty(n, np.int64)
    for k in range(n):
        cu[k] = int(math.floor((wx[k] - dox) / resolution))
        cv[k] = int(math.floor((wy[k] - doy) / resolution))
        hw[k] = int(math.ceil(2.0 * wsig[k] / resolution))
        if wkept[k] and (cu[k] != int(math.floor((wx[k] - sox) / resolution)) + oc
                         or cv[k] != int(math.floor((wy[k] - soy) / resolution)) + orow):
            return False, np.zeros(0, np.int64)
    # The copied cells in dst: rows [R0, R1], cols [C0, C1], in blocks of B x B.
    R0 = r0 + orow
    R1 = r1 + orow
    C0 = c0 + oc
    C1 = c1 + oc
    B = block
    copy = R0 <= R1 and C0 <= C1
    nbr = (R1 - R0) // B + 1 if copy else 0
    nbc = (C1 - C0) // B + 1 if copy else 0
    mark = np.zeros((nbr + 1, nbc + 1), np.int64)  # prefix sums of the cleared blocks
    if copy:
        # Blocks a dropped point's kernel reaches are cleared; of the others only those a kept
        # point's kernel reaches hold anything in src, so only those are copied (a grid is mostly
        # empty: copying it whole would cost about what drawing does).
        held = np.zeros((nbr, nbc), np.bool_)
        for k in range(xx.shape[0] + n):
            if k < xx.shape[0]:
                half = int(math.ceil(2.0 * xsig[k] / resolution))
                u = int(math.floor((xx[k] - sox) / resolution)) + oc
                v = int(math.floor((xy[k] - soy) / resolution)) + orow
            else:
                q = k - xx.shape[0]
                if not wkept[q]:
                    continue
                half = hw[q]
                u = cu[q]
                v = cv[q]
            a0 = max(v - half, R0)
            a1 = min(v + half, R1)
            b0 = max(u - half, C0)
            b1 = min(u + half, C1)
            if a0 > a1 or b0 > b1:
                continue
            for bi in range((a0 - R0) // B, (a1 - R0) // B + 1):
                for bj in range((b0 - C0) // B, (b1 - C0) // B + 1):
                    if k < xx.shape[0]:
                        mark[bi + 1, bj + 1] = 1
                    else:
                        held[bi, bj] = True
        for bi in range(nbr):
            bj = 0
            while bj < nbc:
                if not held[bi, bj] or mark[bi + 1, bj + 1]:
                    bj += 1
                    continue
                run = bj
                while run < nbc and held[bi, run] and not mark[bi + 1, run + 1]:
                    run += 1
                c_lo = C0 + bj * B
                c_hi = min(C0 + run * B, C1 + 1)
                for r in range(R0 + bi * B, min(R0 + (bi + 1) * B, R1 + 1)):
                    dst[r, c_lo:c_hi] = src[r - orow, c_lo - oc:c_hi - oc]
                bj = run
        for bi in range(1, nbr + 1):
            for bj in range(1, nbc + 1):
                mark[bi, bj] += mark[bi - 1, bj] + mark[bi, bj - 1] - mark[bi - 1, bj - 1]
    out = np.empty(n, np.int64)
    m = 0
    for k in range(n):
        x = wx[k]
        y = wy[k]
        if not (x >= lo_x and x <= hi_x and y >= lo_y and y <= hi_y):
            continue
        if wkept[k] and copy:
            half = hw[k]
            if cv[k] - half >= R0 and cv[k] + half <= R1 and cu[k] - half >= C0 and cu[k] + half <= C1:
                bi0 = (cv[k] - half - R0) // B
                bi1 = (cv[k] + half - R0) // B + 1
                bj0 = (cu[k] - half - C0) // B
                bj1 = (cu[k] + half - C0) // B + 1
                if mark[bi1, bj1] - mark[bi0, bj1] - mark[bi1, bj0] + mark[bi0, bj0] == 0:
                    continue  # its whole kernel is in the copy, untouched by a dropped scan
        out[m] = k
        m += 1
    return True, out[:m]


@njit(cache=True)
def _rotated_extent(c, s, q):
    """Bounding box of the points q rotated by every (cos, sin) pair, and their largest range."""
    x_lo = y_lo = np.inf
    x_hi = y_hi = -np.inf
    for a in range(c.shape[0]):
        for k in range(q.shape[0]):
            x = c[a] * q[k, 0] - s[a] * q[k, 1]
            y = s[a] * q[k, 0] + c[a] * q[k, 1]
            x_lo = min(x_lo, x)
            x_hi = max(x_hi, x)
            y_lo = min(y_lo, y)
            y_hi = max(y_hi, y)
    reach = 0.0
    for k in range(q.shape[0]):
        reach = max(reach, math.sqrt(q[k, 0] * q[k, 0] + q[k, 1] * q[k, 1]))
    return x_lo, y_lo, x_hi, y_hi, reach


@njit(cache=True)
def _query_cells(qx, qy, angles, x0, y0, theta0, origin_x, origin_y, resolution, first):
    """Cells (row, col) of the query points at every angle, for the translation index 0 corner.

    ``first`` is the (negative) number of cells from the prior position to the
    window's first translation.
    """
    na = angles.shape[0]
    n = qx.shape[0]
    rows = np.empty((na, n), np.int64)
    cols = np.empty((na, n), np.int64)
    for a in range(na):
        th = theta0 + angles[a]
        c = math.cos(th)
        s = math.sin(th)
        for k in range(n):
            wx = x0 + c * qx[k] - s * qy[k]
            wy = y0 + s * qx[k] + c * qy[k]
            cols[a, k] = int(math.floor((wx - origin_x) / resolution)) + first
            rows[a, k] = int(math.floor((wy - origin_y) / resolution)) + first
    return rows, cols


@njit(cache=True, inline="always")
def _add_rows(grid, out, r_base, c_base, ni, nj, step):
    """out[i, j] += grid[r_base + i step, c_base + j step], every cell inside the grid.

    The strides are literals in their own loops (1 and 2 are the fine and coarse
    steps) so the compiler vectorises the strided byte loads into int32 sums.
    """
    # Row slices start at index 0, so the loads need no negative-index wraparound check.
    if step == 2:
        for i in range(ni):
            row = grid[r_base + 2 * i, c_base:]
            for j in range(nj):
                out[i, j] += row[2 * j]
    elif step == 1:
        for i in range(ni):
            row = grid[r_base + i, c_base:]
            for j in range(nj):
                out[i, j] += row[j]
    else:
        for i in range(ni):
            row = grid[r_base + i * step, c_base:]
            for j in range(nj):
                out[i, j] += row[j * step]


@njit(cache=True, inline="always")
def _accumulate(grid, rows, cols, a, k0, k1, i0, j0, ni, nj, step, out):
    """out[i, j] += grid under the points [k0, k1) at angle ``a`` shifted by (i0 + i, j0 + j) steps."""
    g_rows, g_cols = grid.shape
    for k in range(k0, k1):
        r_base = rows[a, k] + i0 * step
        c_base = cols[a, k] + j0 * step
        r_last = r_base + (ni - 1) * step
        c_last = c_base + (nj - 1) * step
        if r_base >= 0 and c_base >= 0 and r_last < g_rows and c_last < g_cols:
            _add_rows(grid, out, r_base, c_base, ni, nj, step)
        elif r_last >= 0 and c_last >= 0 and r_base < g_rows and c_base < g_cols:
            for i in range(ni):
                r = r_base + i * step
                if r < 0 or r >= g_rows:
                    continue
                for j in range(nj):
                    c = c_base + j * step
                    if c >= 0 and c < g_cols:
                        out[i, j] += grid[r, c]


@njit(cache=True, inline="always")
def _score_window(grid, rows, cols, a, i0, j0, ni, nj, step, out):
    """out[i, j] = sum of grid under the points at angle ``a`` shifted by (i0 + i, j0 + j) steps (int32)."""
    for i in range(ni):
        for j in range(nj):
            out[i, j] = 0
    _accumulate(grid, rows, cols, a, 0, rows.shape[1], i0, j0, ni, nj, step, out)


@njit(cache=True)
def _score_all(grid, rows, cols, n_steps, step):
    """Exhaustive: responses (sums) of every angle and translation, (angles, n, n)."""
    na = rows.shape[0]
    out = np.zeros((na, n_steps, n_steps))
    buf = np.zeros((n_steps, n_steps), np.int32)
    for a in range(na):
        _score_window(grid, rows, cols, a, 0, 0, n_steps, n_steps, step, buf)
        for i in range(n_steps):
            for j in range(n_steps):
                out[a, i, j] = buf[i, j]
    return out


@njit(cache=True)
def _max_pool(grid, width):
    """pooled[r, c] = max of grid[r:r + width, c:c + width] (clipped at the edges).

    By doubling, one axis at a time: after k passes each cell holds the max of the
    next 2^k cells; a last pass combines two overlapping spans into ``width``. That
    is about 2 log2(width) row-order passes instead of 2 width, each written to a
    second buffer (no in-place reads ahead) so it vectorises.
    """
    a = grid.copy()
    b = grid.copy()
    span = 1
    while span < width:
        step = min(span, width - span)  # the last pass only needs to reach width
        _max_ahead_cols(a, b, step)
        a, b = b, a
        span += step
    span = 1
    while span < width:
        step = min(span, width - span)
        _max_ahead_rows(a, b, step)
        a, b = b, a
        span += step
    return a


@njit(cache=True, inline="always")
def _max_ahead_cols(src, dst, s):
    """dst[r, c] = max(src[r, c], src[r, c + s]) (src[r, c] where c + s is outside)."""
    rows, cols = src.shape
    for r in range(rows):
        a = src[r]
        d = dst[r]
        ahead = a[s:]
        for c in range(cols - s):
            d[c] = max(a[c], ahead[c])
        for c in range(max(cols - s, 0), cols):
            d[c] = a[c]


@njit(cache=True, inline="always")
def _max_ahead_rows(src, dst, s):
    """dst[r, c] = max(src[r, c], src[r + s, c]) (src[r, c] where r + s is outside)."""
    rows, cols = src.shape
    for r in range(rows):
        d = dst[r]
        a = src[r]
        if r + s < rows:
            ahead = src[r + s]
            for c in range(cols):
                d[c] = max(a[c], ahead[c])
        else:
            for c in range(cols):
                d[c] = a[c]


@njit(cache=True)
def _block_bounds(pooled, rows, cols, n_blocks, block_cells, width):
    """Upper bound (sum) of the response of every block of translations, (angles, nb, nb).

    ``pooled[r, c]`` is the max of ``grid[r:r + width, c:c + width]``; a block
    whose cells start before the grid's edge reads the pooled value at the
    edge, which still covers every cell of the block inside the grid.
    """
    na = rows.shape[0]
    g_rows, g_cols = pooled.shape
    out = np.zeros((na, n_blocks, n_blocks))
    for a in range(na):
        for k in range(rows.shape[1]):
            for bi in range(n_blocks):
                r = rows[a, k] + bi * block_cells
                if r + width <= 0 or r >= g_rows:
                    continue
                r = max(r, 0)
                for bj in range(n_blocks):
                    c = cols[a, k] + bj * block_cells
                    if c + width > 0 and c < g_cols:
                        out[a, bi, bj] += pooled[r, max(c, 0)]
    return out


@njit(cache=True)
def _score_blocks(grid, rows, cols, order, bounds_flat, n_blocks, block, n_steps, step, band, n_points, floor):
    """Branch and bound: score whole blocks in ``order`` until the bound drops below max(best, floor) - band.

    ``floor`` is the least response the caller will accept: blocks that cannot come
    within ``band`` of it are never needed, whatever the best turns out to be.

    Unscored poses are left at -1. Returns the (angles, n, n) sums and the lookups done.
    """
    na = rows.shape[0]
    out = np.full((na, n_steps, n_steps), -1.0)
    buf = np.zeros((block, block), np.int32)
    best = floor
    lookups = 0
    nbb = n_blocks * n_blocks
    for idx in range(order.shape[0]):
        flat = order[idx]
        if bounds_flat[flat] / n_points < best - band:
            break
        a = flat // nbb
        rem = flat % nbb
        bi = rem // n_blocks
        bj = rem % n_blocks
        i0 = bi * block
        j0 = bj * block
        ni = min(block, n_steps - i0)
        nj = min(block, n_steps - j0)
        _score_window(grid, rows, cols, a, i0, j0, ni, nj, step, buf)
        lookups += ni * nj * rows.shape[1]
        for i in range(ni):
            for j in range(nj):
                v = buf[i, j]
                out[a, i0 + i, j0 + j] = v
                if v / n_points > best:
                    best = v / n_points
    return out, lookups


@njit(cache=True)
def _pooled_smear(out, px, py, sigma_max, origin_x, origin_y, resolution, block, row0, col0):
    """Per block of ``block`` x ``block`` correlation cells, the largest value :func:`smear_points` can draw in it.

    Max-combines into ``out``: ``out[R - row0, C - col0]`` bounds the cells [R block, R block + block)
    x [C block, C block + block) of a grid with the given origin. The smear is a max over points
    of kernels that fall off in each axis, so a block's largest value from one point is the
    kernel at the block cell nearest to it: one write per block a kernel touches (a few)
    instead of one per cell. Every point is drawn with the widest sigma, which bounds the
    narrower ones.
    """
    rows, cols = out.shape
    if px.shape[0] == 0:
        return
    widest = int(math.ceil(2.0 * sigma_max / resolution))
    ex = np.empty(2 * widest + 1)
    kern = np.empty((2 * widest + 1, 2 * widest + 1), np.uint8)
    half = _kernel(sigma_max, resolution, ex, kern)
    # Per offset of a cell in its block: the blocks its kernel touches (relative) and the
    # nearest kernel cell in each.
    most = (2 * half + block - 1) // block + 1
    n_touch = np.zeros(block, np.int64)
    rel = np.zeros((block, most), np.int64)
    near = np.zeros((block, most), np.int64)
    for o in range(block):
        first = (o - half) // block
        last = (o + half) // block
        for t in range(last - first + 1):
            b = first + t
            lo = b * block - o
            hi = lo + block - 1
            rel[o, t] = b
            near[o, t] = half + (0 if lo <= 0 <= hi else min(abs(lo), abs(hi)))
        n_touch[o] = last - first + 1
    last_u = -(1 << 62)
    last_v = -(1 << 62)
    for k in range(px.shape[0]):
        cu = int(math.floor((px[k] - origin_x) / resolution))
        cv = int(math.floor((py[k] - origin_y) / resolution))
        if cu == last_u and cv == last_v:  # neighbouring beams often share a cell
            continue
        last_u = cu
        last_v = cv
        ov = cv % block
        ou = cu % block
        bv = cv // block - row0
        bu = cu // block - col0
        for t in range(n_touch[ov]):
            br = bv + rel[ov, t]
            if br < 0 or br >= rows:
                continue
            ki = near[ov, t]
            for t2 in range(n_touch[ou]):
                bc = bu + rel[ou, t2]
                if bc < 0 or bc >= cols:
                    continue
                v = kern[ki, near[ou, t2]]
                if v > out[br, bc]:
                    out[br, bc] = v


@njit(cache=True)
def _node_blocks(px, py, sigma_max, resolution, block):
    """One scan's :func:`_pooled_smear` in the lattice of origin 0, as its non-empty blocks: (rows, cols, values)."""
    if px.shape[0] == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.uint8)
    pad = int(math.ceil(2.0 * sigma_max / resolution)) + 1
    c_lo = (int(math.floor(px.min() / resolution)) - pad) // block
    c_hi = (int(math.floor(px.max() / resolution)) + pad) // block
    r_lo = (int(math.floor(py.min() / resolution)) - pad) // block
    r_hi = (int(math.floor(py.max() / resolution)) + pad) // block
    local = np.zeros((r_hi - r_lo + 1, c_hi - c_lo + 1), np.uint8)
    _pooled_smear(local, px, py, sigma_max, 0.0, 0.0, resolution, block, r_lo, c_lo)
    n = 0
    for v in local.ravel():
        if v:
            n += 1
    rows = np.empty(n, np.int64)
    cols = np.empty(n, np.int64)
    vals = np.empty(n, np.uint8)
    n = 0
    for i in range(local.shape[0]):
        for j in range(local.shape[1]):
            if local[i, j]:
                rows[n] = i + r_lo
                cols[n] = j + c_lo
                vals[n] = local[i, j]
                n += 1
    return rows, cols, vals


@njit(cache=True)
def _boxes_extent(box, idx):
    """(min x, min y, max x, max y, max reach) over the rows ``idx`` of :func:`_node_stats` boxes (idx not empty)."""
    out = np.empty(5)
    k = idx[0]
    out[0] = box[k, 0]
    out[1] = box[k, 1]
    out[2] = box[k, 2]
    out[3] = box[k, 3]
    out[4] = box[k, 4]
    for t in range(1, idx.shape[0]):
        k = idx[t]
        out[0] = min(out[0], box[k, 0])
        out[1] = min(out[1], box[k, 1])
        out[2] = max(out[2], box[k, 2])
        out[3] = max(out[3], box[k, 3])
        out[4] = max(out[4], box[k, 4])
    return out


@njit(cache=True)
def _boxes_sigma(box, idx):
    """(True, the one sigma) when every node of ``idx`` with points has the same one sigma (column 5), else (False, 0)."""
    first = np.inf
    for t in range(idx.shape[0]):
        u = box[idx[t], 5]
        if u == np.inf:
            continue  # a node without points adds no sigma
        if first == np.inf:
            if np.isnan(u):
                return False, 0.0
            first = u
        elif u != first:
            return False, 0.0
    if first == np.inf:
        return False, 0.0
    return True, first


@njit(cache=True)
def _node_stats(pts, sig, out):
    """out = (min x, min y, max x, max y, 2 max sigma, the one sigma or NaN); a scan without points:
    (inf, inf, -inf, -inf, 0, inf)."""
    n = pts.shape[0]
    if n == 0:
        out[0] = out[1] = out[5] = np.inf
        out[2] = out[3] = -np.inf
        out[4] = 0.0
        return
    lo_x = hi_x = pts[0, 0]
    lo_y = hi_y = pts[0, 1]
    s_lo = s_hi = sig[0]
    for k in range(1, n):
        lo_x = min(lo_x, pts[k, 0])
        hi_x = max(hi_x, pts[k, 0])
        lo_y = min(lo_y, pts[k, 1])
        hi_y = max(hi_y, pts[k, 1])
        s_lo = min(s_lo, sig[k])
        s_hi = max(s_hi, sig[k])
    out[0] = lo_x
    out[1] = lo_y
    out[2] = hi_x
    out[3] = hi_y
    out[4] = 2.0 * s_hi
    out[5] = s_lo if s_lo == s_hi else np.nan


@njit(cache=True)
def _scatter_max(out, rows, cols, vals, row0, col0):
    """out[rows - row0, cols - col0] = max(out there, vals), skipping what falls outside."""
    n_r, n_c = out.shape
    for k in range(rows.shape[0]):
        r = rows[k] - row0
        c = cols[k] - col0
        if r >= 0 and r < n_r and c >= 0 and c < n_c and vals[k] > out[r, c]:
            out[r, c] = vals[k]


@njit(cache=True)
def _range_max_levels(pooled, levels):
    """levels[k][r, c] = max of pooled[r:r + 2^k, c:c + 2^k] (clipped at the edges): a sparse table."""
    rows, cols = pooled.shape
    out = np.empty((levels, rows, cols), np.uint8)
    out[0] = pooled
    tmp = np.empty((rows, cols), np.uint8)
    for k in range(1, levels):
        s = 1 << (k - 1)
        _max_ahead_cols(out[k - 1], tmp, s)
        _max_ahead_rows(tmp, out[k], s)
    return out


@njit(cache=True, inline="always")
def _range_max(table, r_lo, r_hi, c_lo, c_hi):
    """Max of the pooled grid over blocks [r_lo, r_hi] x [c_lo, c_hi] (inclusive, inside the grid)."""
    size = min(r_hi - r_lo, c_hi - c_lo) + 1
    k = 0
    while (2 << k) <= size and k + 1 < table.shape[0]:
        k += 1
    s = 1 << k
    m = 0
    r = r_lo
    while True:
        rr = min(r, r_hi - s + 1)
        c = c_lo
        while True:
            cc = min(c, c_hi - s + 1)
            v = table[k, rr, cc]
            if v > m:
                m = v
            if cc + s > c_hi:
                break
            c += s
        if rr + s > r_hi:
            break
        r += s
    return m


@njit(cache=True, inline="always")
def _square_total(table, block, origin_x, origin_y, resolution, qx, qy, rng, wx0, wy0, half, delta, stop,
                  give_up=0):
    """Bound (sum) of the points at (wx0, wy0) each moved anywhere within ``half`` + r delta; stops at ``stop``,
    and gives up (returning the part summed, below ``give_up``) once a full cell for every point still
    to come could not lift it to ``give_up``."""
    rows, cols = table.shape[1], table.shape[2]
    n = qx.shape[0]
    total = 0
    for k in range(n):
        h = half + rng[k] * delta
        c_lo = max(int(math.floor((wx0[k] - h - origin_x) / resolution)) // block, 0)
        c_hi = min(int(math.floor((wx0[k] + h - origin_x) / resolution)) // block, cols - 1)
        r_lo = max(int(math.floor((wy0[k] - h - origin_y) / resolution)) // block, 0)
        r_hi = min(int(math.floor((wy0[k] + h - origin_y) / resolution)) // block, rows - 1)
        if c_lo <= c_hi and r_lo <= r_hi:
            total += _range_max(table, r_lo, r_hi, c_lo, c_hi)
        if total >= stop or total + 255 * (n - 1 - k) < give_up:
            break
    return total


@njit(cache=True)
def _pooled_response_bound(pooled, block, origin_x, origin_y, resolution, qx, qy, x0, y0, theta0, angles,
                           trans, slack, delta, stop, splits):
    """Upper bound (sum, 0..255 per point) of the score of every pose within ``trans`` (m) in x and y
    of (x0, y0) and within ``delta`` (rad) of a heading theta0 + angles[a] (``slack`` m more for
    rounding).

    A point at range r turned by at most delta moves at most r delta, so at each listed heading
    it lands in a square of half-side trans + slack + r delta around its place; its value is at
    most the largest pooled block that square touches (a range maximum, from a sparse table: a
    few lookups per point). A heading whose bound reaches ``stop`` is split into the four
    quarters of its translation window, ``splits`` times deep (a branch and bound on the bound).
    Returns ``stop`` early once a finest square reaches it (the caller
    only asks whether the bound stays below it); otherwise the bound.
    """
    rng, table = _bound_table(pooled, block, resolution, qx, qy, trans, slack, delta)
    return _bound_over(table, block, origin_x, origin_y, resolution, qx, qy, rng, x0, y0, theta0, angles, 0,
                       angles.shape[0], trans, slack, delta, stop, splits, np.zeros(1, np.int64), -1, stop)


@njit(cache=True)
def _bound_table(pooled, block, resolution, qx, qy, trans, slack, delta):
    """Per query point its range, and the sparse table of ``pooled`` that :func:`_bound_over` reads."""
    rng = _ranges(qx, qy)
    return rng, _range_max_levels(pooled, _bound_levels(rng, block, resolution, trans, slack, delta))


@njit(cache=True)
def _ranges(qx, qy):
    """Each query point's distance from the robot."""
    n = qx.shape[0]
    rng = np.empty(n)
    for k in range(n):
        rng[k] = math.sqrt(qx[k] * qx[k] + qy[k] * qy[k])
    return rng


@njit(cache=True)
def _bound_levels(rng, block, resolution, trans, slack, delta):
    """Levels of the sparse table that cover the widest square a query point can sweep.

    A table with more levels gives the same range maxima (:func:`_range_max` covers a range
    with fewer, larger overlapping squares), so a cached one with at least these will do.
    """
    r_max = 0.0
    for k in range(rng.shape[0]):
        r_max = max(r_max, rng[k])
    widest = int(2.0 * (trans + slack + r_max * delta) / (resolution * block)) + 2
    levels = 1
    while (1 << levels) <= widest:
        levels += 1
    return levels


@njit(cache=True, nogil=True)
def _bound_over(table, block, origin_x, origin_y, resolution, qx, qy, rng, x0, y0, theta0, angles, a0, a1,
                trans, slack, delta, stop, splits, reached, mark, top):
    """:func:`_pooled_response_bound` over the headings [a0, a1); returns ``stop`` as soon as it is
    reached (and sets ``reached[0]``), or stops, returning its best so far, once another thread set it.

    ``mark`` (0 <= mark <= top <= stop; negative: the bound itself) asks only on which side of
    ``mark`` and of ``top`` the bound lies: a square is summed only until it is known not to lift
    the best so far to the next of the two it has not reached (``mark`` until the best reaches
    it, then ``top``); a square that would reach it is summed in full, so the result is below
    ``mark``, in [mark, top) or at least ``top`` exactly when the bound is.
    """
    n = qx.shape[0]
    wx0 = np.empty(n)
    wy0 = np.empty(n)
    sx = np.empty(n)
    sy = np.empty(n)
    # Squares to examine: (x offset, y offset, half-width of the translations, depth).
    stack = np.empty((4 * splits + 1, 4))
    best = 0
    for a in range(a0, a1):
        if reached[0]:
            return best
        th = theta0 + angles[a]
        c = math.cos(th)
        s = math.sin(th)
        for k in range(n):
            wx0[k] = x0 + c * qx[k] - s * qy[k]
            wy0[k] = y0 + s * qx[k] + c * qy[k]
        stack[0, 0] = 0.0
        stack[0, 1] = 0.0
        stack[0, 2] = trans
        stack[0, 3] = 0.0
        top = 1
        while top > 0:
            top -= 1
            dx, dy, t, depth = stack[top, 0], stack[top, 1], stack[top, 2], stack[top, 3]
            for k in range(n):
                sx[k] = wx0[k] + dx
                sy[k] = wy0[k] + dy
            give_up = 0 if mark < 0 else (mark if best < mark else top)
            total = _square_total(table, block, origin_x, origin_y, resolution, qx, qy, rng, sx, sy,
                                  t + slack, delta, stop, give_up)
            if total < stop:
                if total > best:
                    best = total
            elif depth >= splits:
                reached[0] = 1
                return stop
            else:
                q = 0.5 * t
                for i in range(4):
                    stack[top, 0] = dx + (q if i & 1 else -q)
                    stack[top, 1] = dy + (q if i & 2 else -q)
                    stack[top, 2] = q
                    stack[top, 3] = depth + 1
                    top += 1
    return best


@njit(cache=True, inline="always")
def _distance_penalties(offs, cx, cy, px, py, dvp, min_dp, out):
    """out[i, j]: the distance penalty factor of the translation (offs[j], offs[i]) from (cx, cy), measured from (px, py)."""
    for i in range(offs.shape[0]):
        dy = (cy + offs[i]) - py
        for j in range(offs.shape[0]):
            dx = (cx + offs[j]) - px
            d2 = dx * dx + dy * dy
            out[i, j] = max(1.0 - _PENALTY_GAIN * d2 / dvp, min_dp)


@njit(cache=True)
def _responses(sums, norm, offs, angles, cx, cy, ctheta, px, py, ptheta, penalize, dvp, avp, min_dp, min_ap):
    """Raw and (with ``penalize``) penalised responses of a search, its best, how many poses tie
    with it (within 1e-12) and the first of them (angle, y, x).

    Element by element the arithmetic of :meth:`CorrelativeMatcher._penalty` in numpy, in the
    same order, so the values are the same bits; unscored poses (sum < 0) stay at -1.
    """
    na, ny, nx = sums.shape
    raw = np.empty((na, ny, nx))
    resp = np.empty((na, ny, nx))
    two_pi = 2 * np.pi
    best = -np.inf
    # The distance penalty is the same at every angle: once per translation.
    pdist = np.empty((ny, nx))
    if penalize:
        _distance_penalties(offs, cx, cy, px, py, dvp, min_dp, pdist)
    for a in range(na):
        pa = 1.0
        if penalize:
            dth = (ctheta + angles[a]) - ptheta
            dth = (dth + np.pi) % two_pi - np.pi
            pa = max(1.0 - _PENALTY_GAIN * dth * dth / avp, min_ap)
        for i in range(ny):
            for j in range(nx):
                r = sums[a, i, j] / norm
                raw[a, i, j] = r
                if penalize:
                    v = r * (pdist[i, j] * pa) if r >= 0 else -1.0
                else:
                    v = r
                resp[a, i, j] = v
                if v > best:
                    best = v
    ties = 0
    first = (0, 0, 0)
    for a in range(na):
        for i in range(ny):
            for j in range(nx):
                if resp[a, i, j] >= best - 1e-12:
                    if ties == 0:
                        first = (a, i, j)
                    ties += 1
    return raw, resp, best, ties, first


@njit(cache=True, inline="always")
def _pairwise_block(a, lo, n):
    """numpy's pairwise sum of a block of at most 128 values: 8 accumulators, then the rest in order."""
    if n < 8:
        res = 0.0
        for i in range(lo, lo + n):
            res += a[i]
        return res
    r0, r1, r2, r3 = a[lo], a[lo + 1], a[lo + 2], a[lo + 3]
    r4, r5, r6, r7 = a[lo + 4], a[lo + 5], a[lo + 6], a[lo + 7]
    i = 8
    while i < n - (n % 8):
        r0 += a[lo + i]
        r1 += a[lo + i + 1]
        r2 += a[lo + i + 2]
        r3 += a[lo + i + 3]
        r4 += a[lo + i + 4]
        r5 += a[lo + i + 5]
        r6 += a[lo + i + 6]
        r7 += a[lo + i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[lo + i]
        i += 1
    return res


@njit(cache=True)
def _pairwise_sum(a, lo, n):
    """numpy's pairwise summation of a[lo:lo + n] (blocks of up to 128 values, halves above, split
    at a multiple of 8), in its order, so a compiled sum equals ``ndarray.sum()`` bit for bit.

    Its recursion run on an explicit stack (numba's cache mishandles recursive functions).
    """
    if n <= 128:
        return _pairwise_block(a, lo, n)
    # Frames (lo, n, combine?) and a stack of the values of finished halves.
    frames = np.empty((128, 3), np.int64)
    values = np.empty(128)
    top = 0
    nv = 0
    frames[0, 0], frames[0, 1], frames[0, 2] = lo, n, 0
    top = 1
    while top > 0:
        top -= 1
        f_lo, f_n, combine = frames[top, 0], frames[top, 1], frames[top, 2]
        if combine:
            right = values[nv - 1]
            left = values[nv - 2]
            nv -= 2
            values[nv] = left + right
            nv += 1
        elif f_n <= 128:
            values[nv] = _pairwise_block(a, f_lo, f_n)
            nv += 1
        else:
            n2 = f_n // 2
            n2 -= n2 % 8
            # Popped in reverse: the left half, the right half, then their sum.
            frames[top, 0], frames[top, 1], frames[top, 2] = 0, 0, 1
            frames[top + 1, 0], frames[top + 1, 1], frames[top + 1, 2] = f_lo + n2, f_n - n2, 0
            frames[top + 2, 0], frames[top + 2, 1], frames[top + 2, 2] = f_lo, n2, 0
            top += 3
    return values[0]


@njit(cache=True, inline="always")
def _best_over_angles(resp, i, j):
    """max over angles of resp[:, i, j]."""
    v = resp[0, i, j]
    for a in range(1, resp.shape[0]):
        if resp[a, i, j] > v:
            v = resp[a, i, j]
    return v


@njit(cache=True)
def _spread_sums(resp, offs, cx, cy, px, py, threshold):
    """Sums of the positional covariance: w, w dx^2, w dy^2, w dx dy over the (y, x) surface of the
    best response over angles, w that response where it reaches ``threshold`` (else 0), dx, dy from
    (px, py); and whether any such cell is on the window's edge.

    The element products in numpy's order and numpy's pairwise sums (an all-axes sum of a
    C-ordered array is one of the flattened values after 0.0), so the values are its bits.
    """
    na, ny, nx = resp.shape
    n = ny * nx
    w = np.empty(n)
    txx = np.empty(n)
    tyy = np.empty(n)
    txy = np.empty(n)
    edge = False
    for i in range(ny):
        dy = (cy + offs[i]) - py
        for j in range(nx):
            v = _best_over_angles(resp, i, j)
            k = i * nx + j
            if v >= threshold:
                if i == 0 or i == ny - 1 or j == 0 or j == nx - 1:
                    edge = True
            else:
                v = 0.0
            dx = (cx + offs[j]) - px
            w[k] = v
            txx[k] = v * dx * dx
            tyy[k] = v * dy * dy
            txy[k] = v * dx * dy
    return (0.0 + _pairwise_sum(w, 0, n), 0.0 + _pairwise_sum(txx, 0, n), 0.0 + _pairwise_sum(tyy, 0, n),
            0.0 + _pairwise_sum(txy, 0, n), edge)


@njit(cache=True, inline="always")
def _cells_at(q, x0, y0, th, origin_x, origin_y, resolution, first, rows, cols):
    """rows[0], cols[0]: the cells of the points ``q`` at pose (x0, y0, th), plus ``first`` (:func:`_query_cells`' arithmetic)."""
    c = math.cos(th)
    s = math.sin(th)
    for k in range(q.shape[0]):
        wx = x0 + c * q[k, 0] - s * q[k, 1]
        wy = y0 + s * q[k, 0] + c * q[k, 1]
        cols[0, k] = int(math.floor((wx - origin_x) / resolution)) + first
        rows[0, k] = int(math.floor((wy - origin_y) / resolution)) + first


@njit(cache=True, nogil=True)
def _score_poses(grid, origin_x, origin_y, resolution, q, x0, y0, theta0, angles, half, step, a0, a1, sums):
    """sums[a] for the angles [a0, a1): the grid summed under the query points ``q`` (N, 2) rotated to
    ``theta0 + angles[a]`` at every translation of the window (float64 of integer sums).

    :func:`_query_cells` and :func:`_score_all` in one pass, one angle's cells at a time (the same
    arithmetic, so the same sums), with no per-angle tables to allocate.
    """
    n = q.shape[0]
    n_steps = 2 * half + 1
    first = -half * step
    rows = np.empty((1, n), np.int64)
    cols = np.empty((1, n), np.int64)
    buf = np.empty((n_steps, n_steps), np.int32)
    for a in range(a0, a1):
        _cells_at(q, x0, y0, theta0 + angles[a], origin_x, origin_y, resolution, first, rows, cols)
        _score_window(grid, rows, cols, 0, 0, 0, n_steps, n_steps, step, buf)
        for i in range(n_steps):
            for j in range(n_steps):
                sums[a, i, j] = buf[i, j]


@njit(cache=True, nogil=True)
def _score_poses_pruned(grid, origin_x, origin_y, resolution, q, x0, y0, theta0, angles, order, half, step, i_lo,
                        j_lo, n_part, px, py, pt, penalize, dvp, avp, min_dp, min_ap, floor, chunk, sums):
    """:func:`_score_poses` over the angles in ``order``, skipping those that cannot matter: (lookups done).

    Only the n_part x n_part translations from (i_lo, j_lo) of the window are scored (the
    whole window: 0, 0, 2 half + 1), with the whole window's cells, so with its sums; the rest
    of ``sums`` is left as it is.

    Angles are scored in ``order`` (the prior's heading first), their points in chunks of
    ``chunk``; after each chunk, the sums so far plus a full cell for every point still to
    come, times the largest penalty factor of the angle, bound the angle's (penalised)
    responses. Once that bound is below the best response scored so far (or ``floor``) less
    the covariance band, the angle is left unscored (sums -1): none of its poses can be the
    best, tie with it or weigh in the covariance (poses within the band of the best), so the
    match is the exhaustive one bit for bit. The arithmetic of the responses is
    :func:`_responses`', so the running best is the same number.
    """
    n = q.shape[0]
    na = angles.shape[0]
    n_steps = 2 * half + 1
    first = -half * step
    norm = float(n * _SCALE)
    rows = np.empty((1, n), np.int64)
    cols = np.empty((1, n), np.int64)
    buf = np.empty((n_part, n_part), np.int32)
    offs = (np.arange(n_steps) - half) * (step * resolution)
    two_pi = 2 * np.pi
    # The distance penalty of every translation and its largest value over the part.
    pdist = np.ones((n_steps, n_steps))
    pd_max = 1.0
    if penalize:
        _distance_penalties(offs, x0, y0, px, py, dvp, min_dp, pdist)
        pd_max = pdist[i_lo:i_lo + n_part, j_lo:j_lo + n_part].max()
    best = -np.inf
    band = _COVARIANCE_BAND + 1e-9
    lookups = 0
    for idx in range(order.shape[0]):
        a = order[idx]
        pa = 1.0
        if penalize:
            dth = (theta0 + angles[a]) - pt
            dth = (dth + np.pi) % two_pi - np.pi
            pa = max(1.0 - _PENALTY_GAIN * dth * dth / avp, min_ap)
        _cells_at(q, x0, y0, theta0 + angles[a], origin_x, origin_y, resolution, first, rows, cols)
        for i in range(n_part):
            for j in range(n_part):
                buf[i, j] = 0
        pruned = False
        k0 = 0
        while k0 < n:
            k1 = min(k0 + chunk, n)
            _accumulate(grid, rows, cols, 0, k0, k1, i_lo, j_lo, n_part, n_part, step, buf)
            lookups += (k1 - k0) * n_part * n_part
            k0 = k1
            if k0 < n:
                top = buf[0, 0]
                for i in range(n_part):
                    for j in range(n_part):
                        if buf[i, j] > top:
                            top = buf[i, j]
                bound = (float(top) + (n - k0) * _SCALE) / norm
                if penalize:
                    bound = bound * (pd_max * pa)
                if bound < max(best, floor) - band:
                    pruned = True
                    break
        if pruned:
            for i in range(n_part):
                for j in range(n_part):
                    sums[a, i_lo + i, j_lo + j] = -1.0
            continue
        for i in range(n_part):
            for j in range(n_part):
                v = buf[i, j]
                sums[a, i_lo + i, j_lo + j] = v
                r = v / norm
                if penalize:
                    r = r * (pdist[i_lo + i, j_lo + j] * pa) if r >= 0 else -1.0
                if r > best:
                    best = r
    return lookups


@njit(cache=True)
def _band_on_part_edge(resp, threshold, a_lo, n_a, i_lo, j_lo, n_xy):
    """Whether a response of the part ``resp[a_lo:a_lo + n_a, i_lo:i_lo + n_xy, j_lo:j_lo + n_xy]`` at or
    above ``threshold`` lies on a face of the part that is not a face of the whole window."""
    na, ny, nx = resp.shape
    for a in range(a_lo, a_lo + n_a):
        for i in range(i_lo, i_lo + n_xy):
            for j in range(j_lo, j_lo + n_xy):
                if resp[a, i, j] >= threshold:
                    if ((a == a_lo and a_lo > 0) or (a == a_lo + n_a - 1 and a < na - 1)
                            or (i == i_lo and i_lo > 0) or (i == i_lo + n_xy - 1 and i < ny - 1)
                            or (j == j_lo and j_lo > 0) or (j == j_lo + n_xy - 1 and j < nx - 1)):
                        return True
    return False


@njit(cache=True)
def _along_extent(resp, offs, cx, cy, px, py, threshold, vx, vy):
    """Least and largest ``dx vx + dy vy`` over the (y, x) cells whose best response over angles reaches
    ``threshold`` (dx, dy from (px, py)): the mask's extent along a direction, numpy's arithmetic."""
    na, ny, nx = resp.shape
    lo = np.inf
    hi = -np.inf
    for i in range(ny):
        dy = (cy + offs[i]) - py
        for j in range(nx):
            v = _best_over_angles(resp, i, j)
            if v >= threshold:
                dx = (cx + offs[j]) - px
                t = dx * vx + dy * vy
                lo = min(lo, t)
                hi = max(hi, t)
    return lo, hi


@njit(cache=True)
def _tie_mean(resp, best, offs, angles, cx, cy, ct):
    """Karto's pose of a search whose best response is shared: the mean offset of every pose within
    1e-12 of it (C order, numpy's pairwise mean, so the bits of ``offs[np.nonzero(...)].mean()``)."""
    na, ny, nx = resp.shape
    ox = np.empty(resp.size)
    oy = np.empty(resp.size)
    ot = np.empty(resp.size)
    m = 0
    for a in range(na):
        for i in range(ny):
            for j in range(nx):
                if resp[a, i, j] >= best - 1e-12:
                    ox[m] = offs[j]
                    oy[m] = offs[i]
                    ot[m] = angles[a]
                    m += 1
    pose = np.empty(3)
    pose[0] = cx + (0.0 + _pairwise_sum(ox, 0, m)) / m
    pose[1] = cy + (0.0 + _pairwise_sum(oy, 0, m)) / m
    pose[2] = ct + (0.0 + _pairwise_sum(ot, 0, m)) / m
    return pose


@njit(cache=True)
def _finish_search(sums, n_points, offs, angles, cx, cy, ct, px, py, pt, penalize, dvp, avp, min_dp, min_ap):
    """Responses of a scored window (:func:`_responses`) and its best pose (Karto's mean over ties):
    (pose, best, raw at the first best, responses)."""
    raw, resp, best, ties, first = _responses(sums, float(n_points * _SCALE), offs, angles, cx, cy, ct, px, py, pt,
                                              penalize, dvp, avp, min_dp, min_ap)
    a0, y0, x0 = first
    if ties == 1:
        pose = np.empty(3)
        pose[0] = cx + offs[x0]
        pose[1] = cy + offs[y0]
        pose[2] = ct + angles[a0]
    else:
        pose = _tie_mean(resp, best, offs, angles, cx, cy, ct)
    return pose, best, raw[a0, y0, x0], resp


@njit(cache=True)
def _search_window(grid, origin_x, origin_y, resolution, q, cx, cy, ct, px, py, pt, angles, half, step, penalize,
                   dvp, avp, min_dp, min_ap):
    """One exhaustive search phase in one call: (pose, best, raw, responses, offsets)."""
    n_steps = 2 * half + 1
    sums = np.empty((angles.shape[0], n_steps, n_steps))
    _score_poses(grid, origin_x, origin_y, resolution, q, cx, cy, ct, angles, half, step, 0, angles.shape[0], sums)
    offs = (np.arange(n_steps) - half) * (step * resolution)
    pose, best, raw, resp = _finish_search(sums, q.shape[0], offs, angles, cx, cy, ct, px, py, pt, penalize,
                                           dvp, avp, min_dp, min_ap)
    return pose, best, raw, resp, offs


@njit(cache=True)
def _heading_spread(resp, angles, best, floor):
    """The coarse heading variance of :class:`MatchResult`: the response-weighted spread of the angles
    whose best response is within the covariance band of the best, about the best angle (at least
    ``floor``); numpy's arithmetic and sums."""
    na = resp.shape[0]
    curve = np.empty(na)
    for a in range(na):
        v = resp[a, 0, 0]
        for i in range(resp.shape[1]):
            for j in range(resp.shape[2]):
                if resp[a, i, j] > v:
                    v = resp[a, i, j]
        curve[a] = v
    top = 0
    for a in range(1, na):
        if curve[a] > curve[top]:
            top = a
    w = np.empty(na)
    t = np.empty(na)
    for a in range(na):
        w[a] = max(curve[a], 0.0) if curve[a] >= best - _COVARIANCE_BAND else 0.0
        d = angles[a] - angles[top]
        t[a] = w[a] * d * d
    norm = 0.0 + _pairwise_sum(w, 0, na)
    var = (0.0 + _pairwise_sum(t, 0, na)) / norm if norm > 1e-12 else MAX_VARIANCE
    return max(var, floor)


@njit(cache=True)
def _argmax3(resp):
    """np.unravel_index(np.argmax(resp), resp.shape) (the first largest, C order)."""
    na, ny, nx = resp.shape
    best = resp[0, 0, 0]
    ba = bi = bj = 0
    for a in range(na):
        for i in range(ny):
            for j in range(nx):
                if resp[a, i, j] > best:
                    best = resp[a, i, j]
                    ba, bi, bj = a, i, j
    return ba, bi, bj


@njit(cache=True)
def _fine_stage(grid, origin_x, origin_y, resolution, q, pose, px, py, pt, angles, penalize, dvp, avp, min_dp, min_ap,
                recentre, floor, fallback):
    """The fine search of :meth:`CorrelativeMatcher.match` in one call: one cell and the fine angles
    around ``pose``, re-centred up to ``recentre`` times while its best lies on the window's edge and
    responds better, then the angular spread at the best x, y. Returns (pose, best, raw, theta
    variance (at least ``floor``; ``fallback`` when no angle responds), searches run)."""
    na = angles.shape[0]
    pose, best, raw, resp, _ = _search_window(grid, origin_x, origin_y, resolution, q, pose[0], pose[1], pose[2],
                                              px, py, pt, angles, 1, 1, penalize, dvp, avp, min_dp, min_ap)
    runs = 1
    for _ in range(recentre):
        a_b, i_b, j_b = _argmax3(resp)
        if 0 < i_b < 2 and 0 < j_b < 2 and 0 < a_b < na - 1:
            break
        pose2, best2, raw2, resp2, _ = _search_window(grid, origin_x, origin_y, resolution, q, pose[0], pose[1],
                                                      pose[2], px, py, pt, angles, 1, 1, penalize, dvp, avp,
                                                      min_dp, min_ap)
        runs += 1
        if best2 <= best + 1e-12:
            break
        pose, best, raw, resp = pose2, best2, raw2, resp2
    _, i_b, j_b = _argmax3(resp)
    curve = np.empty(na)
    for a in range(na):
        curve[a] = resp[a, i_b, j_b]
    top = 0
    for a in range(1, na):
        if curve[a] > curve[top]:
            top = a
    best_f = curve[top]
    w = np.empty(na)
    t = np.empty(na)
    for a in range(na):
        w[a] = curve[a] if curve[a] >= best_f - _COVARIANCE_BAND else 0.0
        d = angles[a] - angles[top]
        t[a] = w[a] * d * d
    norm = 0.0 + _pairwise_sum(w, 0, na)
    var = (0.0 + _pairwise_sum(t, 0, na)) / norm if norm > 1e-12 else fallback
    return pose, best, raw, max(var, floor), runs


def _interleaved(q: NDArray[np.float64]) -> NDArray[np.float64]:
    """``q`` reordered so that each chunk of :func:`_score_poses_pruned` spans the whole scan: points
    0, s, 2s, ..., then 1, s + 1, ... (s: the points over the chunk size). Integer sums do not
    depend on the order, so the scores are the same; a wrong heading misses over the whole scan at
    once instead of wall by wall, and its bound falls below the band sooner."""
    n = q.shape[0]
    stride = n // _PRUNE_CHUNK
    if stride < 2:
        return q
    order = _INTERLEAVE_ORDERS.get(n)
    if order is None:
        order = _INTERLEAVE_ORDERS[n] = np.argsort(np.arange(n) % stride, kind="stable")
    return np.ascontiguousarray(q[order])


@njit(cache=True)
def _spaced(q, spacing):
    """The points of ``q`` (N, 2, in scan order) at least ``spacing`` from the last one kept (the first
    always kept): the coarse search's points (see :attr:`CorrelativeMatcher.coarse_point_spacing`)."""
    n = q.shape[0]
    keep = np.empty(n, np.int64)
    m = 0
    s2 = spacing * spacing
    lx = ly = 0.0
    for k in range(n):
        dx = q[k, 0] - lx
        dy = q[k, 1] - ly
        if m == 0 or dx * dx + dy * dy >= s2:
            keep[m] = k
            m += 1
            lx = q[k, 0]
            ly = q[k, 1]
    out = np.empty((m, 2))
    for k in range(m):
        out[k, 0] = q[keep[k], 0]
        out[k, 1] = q[keep[k], 1]
    return out


# --------------------------------------------------------------------------- the matcher


class CorrelativeMatcher:
    """A correlative scan matcher with Karto's search: coarse window, then a fine step.

    Parameters (Karto's names in brackets):
        search_size: full side of the x, y window, m [CorrelationSearchSpaceDimension].
        resolution: correlation grid cell, m [CorrelationSearchSpaceResolution].
        smear_deviation: Gaussian sigma of a reference point, m [CorrelationSearchSpaceSmearDeviation];
            per-point sigmas given to :meth:`match` replace it.
        coarse_angle_offset: half-width of the angle window, rad [CoarseSearchAngleOffset].
        coarse_angle_resolution: coarse angle step, rad [CoarseAngleResolution].
        fine_angle_step: fine angle step, rad [FineSearchAngleOffset, which Karto uses as a step].
        distance_variance_penalty: m^2, already squared [DistanceVariancePenalty].
        angle_variance_penalty: rad^2, already squared [AngleVariancePenalty].
        minimum_distance_penalty, minimum_angle_penalty: floors of the penalty factors.
        response_expansion: widen the angle window by 20 deg up to 3 times when nothing matched.
    """

    def __init__(
        self,
        *,
        search_size: float = 0.3,
        resolution: float = 0.01,
        smear_deviation: float = 0.03,
        coarse_angle_offset: float = math.radians(20.0),
        coarse_angle_resolution: float = math.radians(2.0),
        fine_angle_step: float = math.radians(0.2),
        distance_variance_penalty: float = 0.3**2,
        angle_variance_penalty: float = math.radians(20.0) ** 2,
        minimum_distance_penalty: float = 0.5,
        minimum_angle_penalty: float = 0.9,
        response_expansion: bool = False,
    ) -> None:
        if not resolution > 0 or not search_size > 0:
            raise ValueError("resolution and search_size must be positive")
        if not coarse_angle_resolution > 0 or not fine_angle_step > 0:
            raise ValueError("angle steps must be positive")
        self.search_size = float(search_size)
        self.resolution = float(resolution)
        self.smear_deviation = float(smear_deviation)
        self.coarse_angle_offset = float(coarse_angle_offset)
        self.coarse_angle_resolution = float(coarse_angle_resolution)
        self.fine_angle_step = float(fine_angle_step)
        self.distance_variance_penalty = float(distance_variance_penalty)
        self.angle_variance_penalty = float(angle_variance_penalty)
        self.minimum_distance_penalty = float(minimum_distance_penalty)
        self.minimum_angle_penalty = float(minimum_angle_penalty)
        self.response_expansion = bool(response_expansion)
        # Coarse translations: two cells per step, covering half the window each way.
        self._coarse_half = max(1, int(round(0.5 * self.search_size / (2.0 * self.resolution))))
        self.branch_and_bound = True
        # Extra fine searches re-centred on a best pose that lies on the fine window's edge.
        self.fine_recentre = 0
        # The coarse search scores only the query points at least this far (m) from the last one kept
        # in scan order (0: every point); the fine stage scores them all (see :meth:`coarse_points`).
        self.coarse_point_spacing = 0.0

    def with_window(self, search_size: float) -> "CorrelativeMatcher":
        """The same matcher over a smaller (or larger) x, y window; its grids are interchangeable."""
        out = copy.copy(self)
        out.search_size = float(search_size)
        out._coarse_half = max(1, int(round(0.5 * out.search_size / (2.0 * out.resolution))))
        return out

    def coarse_points(self, q: NDArray[np.float64]) -> NDArray[np.float64]:
        """The query points the coarse search scores: with ``coarse_point_spacing`` only those at least
        that far from the last one kept (dense clutter near the robot is hit by dozens of beams a
        few millimetres apart, which a 2 cm lattice cannot tell apart), else all of them."""
        if self.coarse_point_spacing > 0 and q.shape[0] > 1:
            return _spaced(np.ascontiguousarray(q, dtype=np.float64), float(self.coarse_point_spacing))
        return q

    # ----------------------------------------------------------------- pieces

    def sigmas_for(self, beam_sigma: NDArray[np.float64] | None, n: int) -> NDArray[np.float64]:
        """Smear sigma per reference point: the smear combined with the beam's own range sigma.

        Clamped to Karto's allowed [0.5, 10] cells so the kernel stays resolvable.
        """
        base = np.full(n, self.smear_deviation)
        if beam_sigma is not None:
            b = np.nan_to_num(np.asarray(beam_sigma, dtype=np.float64), nan=0.0)
            base = np.sqrt(base * base + b * b)
        return np.clip(base, 0.5 * self.resolution, 10.0 * self.resolution)

    def query_box(
        self, query_points: NDArray[np.float64], prior: NDArray[np.float64], angle_offset: float
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """World box (lo, hi) every query point can reach in the search window around ``prior``."""
        q = np.asarray(query_points, dtype=np.float64).reshape(-1, 2)
        key = ("box", angle_offset)
        lin = _ANGLES.get(key)
        if lin is None:
            n = max(2, int(math.ceil(angle_offset / math.radians(10.0))))
            lin = _ANGLES[key] = np.linspace(-angle_offset, angle_offset, 2 * n + 1)
        angles = prior[2] + lin
        x_lo, y_lo, x_hi, y_hi, reach = _rotated_extent(np.cos(angles), np.sin(angles), np.ascontiguousarray(q))
        # Between the sampled angles an arc bulges by at most r (1 - cos(step / 2)).
        pad = 0.5 * self.search_size + reach * (1.0 - math.cos(0.5 * (angles[1] - angles[0]))) + self.resolution
        lo = np.array([x_lo, y_lo]) + prior[:2] - pad
        hi = np.array([x_hi, y_hi]) + prior[:2] + pad
        return lo, hi

    def search_box(self, query_points: NDArray[np.float64], prior: NDArray[np.float64]):
        """The world box the query can reach in this matcher's full window (with response expansion)."""
        widest = self.coarse_angle_offset + (math.radians(60.0) if self.response_expansion else 0.0)
        return self.query_box(query_points, np.asarray(prior, dtype=np.float64), widest)

    def _sig(self, ref, ref_sigmas):
        if ref_sigmas is None:
            return self.sigmas_for(None, ref.shape[0])
        return np.asarray(ref_sigmas, dtype=np.float64)

    def correlation_grid(
        self,
        ref_points: NDArray[np.float64],
        ref_sigmas: NDArray[np.float64],
        lo: NDArray[np.float64],
        hi: NDArray[np.float64],
        *,
        clip: bool = True,
    ) -> tuple[NDArray[np.uint8], float, float]:
        """The smeared grid of the reference points inside the world box (lo, hi): (grid, origin_x, origin_y).

        ``clip`` shrinks the box to the reference points' own extent (smaller
        grid); a grid that will be extended later (:class:`GridCache`) keeps it.
        """
        res = self.resolution
        margin = 2.0 * float(ref_sigmas.max(initial=self.smear_deviation)) + 2.0 * res
        lo = np.asarray(lo, dtype=np.float64).copy()
        hi = np.asarray(hi, dtype=np.float64).copy()
        if ref_points.shape[0]:
            px = np.ascontiguousarray(ref_points[:, 0])
            py = np.ascontiguousarray(ref_points[:, 1])
            keep = _inside(px, py, lo[0] - margin, lo[1] - margin, hi[0] + margin, hi[1] + margin)
            if keep.size < px.size:
                px, py, ref_sigmas = px[keep], py[keep], ref_sigmas[keep]
        else:
            px = py = np.zeros(0)
        if px.size and clip:
            lo = np.maximum(lo, np.array([px.min(), py.min()]) - margin)
            hi = np.minimum(hi, np.array([px.max(), py.max()]) + margin)
        ox, oy, rows, cols = self._geometry(lo, hi)
        grid = np.zeros((rows, cols), dtype=np.uint8)
        origin = (ox, oy)
        if px.size:
            _smear(grid, float(origin[0]), float(origin[1]), res, px, py,
                               np.ascontiguousarray(ref_sigmas, dtype=np.float64), _uniform(ref_sigmas) is not None)
        return grid, float(origin[0]), float(origin[1])

    def _geometry(self, lo, hi) -> tuple[float, float, int, int]:
        res = self.resolution
        hi = np.maximum(hi, lo + res)
        origin = np.floor(lo / res) * res
        shape = np.ceil((hi - origin) / res).astype(np.int64) + 1
        return float(origin[0]), float(origin[1]), int(shape[1]), int(shape[0])

    def grid_geometry(self, ref_sigmas, lo, hi) -> tuple[float, float, int, int]:
        """(origin x, origin y, rows, cols) of ``correlation_grid(..., lo, hi, clip=False)``, without drawing it."""
        return self._geometry(np.asarray(lo, dtype=np.float64).copy(), np.asarray(hi, dtype=np.float64).copy())

    def response_bound(self, ref_points, ref_sigmas, query_points, prior, *, stop: float = 2.0) -> float:
        """An upper bound of :meth:`match`'s response on any grid drawn from at most these reference points.

        Exact (never below the response), with or without penalty and refinement: it covers
        every translation the coarse and fine searches can try (the window plus one fine
        step) and every heading within the larger of half a coarse step and the fine window
        of a coarse angle, on a grid max-pooled over ``_BOUND_BLOCK`` cells a side
        (:func:`_pooled_smear`, drawn without drawing the correlation grid). A caller that only
        needs to know that a match cannot reach a threshold (a near chain out of view) can skip
        the grid and the search. ``stop``: return as soon as the bound is known to reach it
        (some value >= ``stop``). With response expansion (angles beyond the window) it returns 1.
        """
        ref = np.asarray(ref_points, dtype=np.float64).reshape(-1, 2)
        prior = np.asarray(prior, dtype=np.float64).reshape(3)
        if self.response_expansion:
            return 1.0
        if np.asarray(query_points).size == 0 or ref.shape[0] == 0 or not np.all(np.isfinite(prior)):
            return 0.0
        lo, hi = self.query_box(query_points, prior, self.coarse_angle_offset + self._bound_angles()[1])
        reach = sum(self._bound_window())
        ox, oy, rows, cols = self._geometry(lo - reach - 1.0, hi + reach + 1.0)
        pooled = self.pooled_grid(ref, self._sig(ref, ref_sigmas), ox, oy, rows, cols)
        return self.pooled_bound(pooled, ox, oy, query_points, prior, stop=stop)

    def pooled_grid(self, ref_points, ref_sigmas, origin_x, origin_y, rows, cols, out=None):
        """The bound grid of :meth:`pooled_bound` for the correlation grid (origin, rows x cols) of these points.

        ``out`` (a bound grid of the same geometry) is extended instead of a new one drawn.
        """
        b = _BOUND_BLOCK
        if out is None:
            out = np.zeros((rows // b + 1, cols // b + 1), np.uint8)
        ref = np.asarray(ref_points, dtype=np.float64).reshape(-1, 2)
        if ref.shape[0]:
            _pooled_smear(out, np.ascontiguousarray(ref[:, 0]), np.ascontiguousarray(ref[:, 1]),
                          float(np.max(ref_sigmas)), origin_x, origin_y, self.resolution, b, 0, 0)
        return out

    def _bound_angles(self):
        """The coarse angles and the largest heading any search tries away from the nearest one."""
        n_half = int(round(self.coarse_angle_offset / self.coarse_angle_resolution))
        angles = np.arange(-n_half, n_half + 1) * self.coarse_angle_resolution
        n_fine = int(round(0.5 * self.coarse_angle_resolution / self.fine_angle_step))
        return angles, max(0.5 * self.coarse_angle_resolution, n_fine * self.fine_angle_step) + 1e-9

    def _bound_window(self) -> tuple[float, float]:
        """(translations a search tries each way: the coarse window plus one fine step; slack for
        the cell rounding of the lookup table, its centre possibly a mean of offsets, and of a grid
        whose origin is another multiple of the cell), m."""
        return (2 * self._coarse_half + 1) * self.resolution, 4 * self.resolution

    def pooled_bound(self, pooled, origin_x, origin_y, query_points, prior, *, stop: float = 2.0,
                     tables: dict | None = None, mark: float | None = None) -> float:
        """:meth:`response_bound` on a bound grid from :meth:`pooled_grid` (origin: its correlation grid's).

        ``tables``: where the bound grid's sparse table is kept between calls (the caller empties
        it when the bound grid changes); without it the table is built for this call.
        ``mark`` (at most ``stop``): the caller only asks whether the bound is below ``mark``, in
        [mark, stop) or at least ``stop``; the value returned answers that as the bound itself
        would (compared as ``bound < mark``, ``bound < stop``) but may be lower, which lets most
        squares of the bound be summed in part.
        """
        q = np.asarray(query_points, dtype=np.float64).reshape(-1, 2)
        prior = np.asarray(prior, dtype=np.float64).reshape(3)
        if self.response_expansion:
            return 1.0
        if q.shape[0] == 0 or not np.all(np.isfinite(prior)):
            return 0.0
        key = ("bound", self.coarse_angle_offset, self.coarse_angle_resolution, self.fine_angle_step)
        got = _ANGLES.get(key)
        if got is None:
            angles, delta = self._bound_angles()
            # The prior's heading first, then outwards: a bound that reaches ``stop`` mostly reaches it
            # near there, and returns at once (below ``stop`` every heading is bounded, in any order).
            got = _ANGLES[key] = (angles[np.argsort(np.abs(angles), kind="stable")], delta)
        angles, delta = got
        n = q.shape[0] * _SCALE
        qx, qy = np.ascontiguousarray(q[:, 0]), np.ascontiguousarray(q[:, 1])
        trans, slack = self._bound_window()
        cut = int(math.ceil(stop * n))
        if tables is None:
            rng, table = _bound_table(pooled, _BOUND_BLOCK, self.resolution, qx, qy, trans, slack, delta)
        else:
            rng = _ranges(qx, qy)
            levels = _bound_levels(rng, _BOUND_BLOCK, self.resolution, trans, slack, delta)
            table = tables.get("table")
            if table is None or table.shape[0] < levels:
                table = tables["table"] = _range_max_levels(pooled, levels)
        reached = np.zeros(1, np.int64)
        parts = {}
        # The least sums the caller's comparisons (sum / n against mark and stop) put at or above them.
        low, top = (-1, cut) if mark is None else (_least_total(min(mark, stop), n), _least_total(stop, n))

        def over(a0, a1):
            parts[a0] = _bound_over(table, _BOUND_BLOCK, origin_x, origin_y, self.resolution, qx, qy, rng,
                                    float(prior[0]), float(prior[1]), float(prior[2]), angles, a0, a1, trans, slack,
                                    delta, cut, _BOUND_SPLITS, reached, low, top)

        # Among threads when it pays: a part that reaches ``stop`` stops the others, and the
        # result (``stop``, or the best over every heading) does not depend on which did.
        if q.shape[0] * angles.shape[0] >= _PARALLEL_BOUND:
            _split(over, angles.shape[0], pieces=_THREADS * _PIECES_PER_THREAD)
        else:
            over(0, angles.shape[0])
        return float(max(parts.values())) / n

    def _penalty(self, dx, dy, dth):
        d2 = dx * dx + dy * dy
        pd = np.maximum(1.0 - _PENALTY_GAIN * d2 / self.distance_variance_penalty, self.minimum_distance_penalty)
        pa = np.maximum(1.0 - _PENALTY_GAIN * dth * dth / self.angle_variance_penalty, self.minimum_angle_penalty)
        return pd * pa

    def _search(self, grid, origin, q, center, prior, angles, half, step, penalize, allow_bnb, floor=-1.0,
                prune=False):
        """One search phase around ``center``: (best pose, best response, raw, surface, lookups).

        ``prune``: the surface is needed only within the covariance band of the best (a match's
        coarse search, not :meth:`places`): angles that cannot come within it are left unscored.
        """
        res = self.resolution
        n_steps = 2 * half + 1
        n_points = q.shape[0]
        # The bound is on the raw response, so it prunes exactly only without a penalty.
        exhaustive = penalize or not (allow_bnb and self.branch_and_bound and n_steps >= _BNB_MIN_STEPS)
        if exhaustive and prune:
            q = np.ascontiguousarray(q, dtype=np.float64)
            sums = np.empty((angles.shape[0], n_steps, n_steps))
            cx, cy, ct = float(center[0]), float(center[1]), float(center[2])
            args = (float(prior[0]), float(prior[1]), float(prior[2]), penalize, self.distance_variance_penalty,
                    self.angle_variance_penalty, self.minimum_distance_penalty, self.minimum_angle_penalty)
            lookups = _score_poses_pruned(grid, origin[0], origin[1], res, _interleaved(q), cx, cy, ct, angles,
                                          np.argsort(np.abs(angles), kind="stable"), half, step, 0, 0, n_steps,
                                          *args[:8], -1.0, _PRUNE_CHUNK, sums)
            offs = (np.arange(n_steps) - half) * (step * res)
            pose, best, raw_best, resp = _finish_search(sums, n_points, offs, angles, cx, cy, ct, *args)
            return pose, best, float(raw_best), resp, offs, int(lookups)
        if exhaustive:
            q = np.ascontiguousarray(q, dtype=np.float64)
            lookups = angles.shape[0] * n_steps * n_steps * n_points
            # Threads pay only on searches big enough to outweigh waking them (the coarse one).
            if _THREADS > 1 and lookups >= _PARALLEL_LOOKUPS:
                sums = np.empty((angles.shape[0], n_steps, n_steps))
                cx, cy, ct = float(center[0]), float(center[1]), float(center[2])
                _split(lambda a0, a1: _score_poses(grid, origin[0], origin[1], res, q, cx, cy, ct, angles, half, step,
                                                   a0, a1, sums), angles.shape[0],
                       pieces=_THREADS * _PIECES_PER_THREAD)
                offs = (np.arange(n_steps) - half) * (step * res)
                pose, best, raw_best, resp = _finish_search(
                    sums, n_points, offs, angles, cx, cy, ct, float(prior[0]), float(prior[1]), float(prior[2]),
                    penalize, self.distance_variance_penalty, self.angle_variance_penalty,
                    self.minimum_distance_penalty, self.minimum_angle_penalty)
            else:
                pose, best, raw_best, resp, offs = _search_window(
                    grid, origin[0], origin[1], res, q, float(center[0]), float(center[1]), float(center[2]),
                    float(prior[0]), float(prior[1]), float(prior[2]), angles, half, step, penalize,
                    self.distance_variance_penalty, self.angle_variance_penalty, self.minimum_distance_penalty,
                    self.minimum_angle_penalty)
            return pose, best, float(raw_best), resp, offs, lookups
        rows, cols = _query_cells(
            q[:, 0], q[:, 1], angles, center[0], center[1], center[2],
            origin[0], origin[1], res, -half * step,
        )
        block = _BLOCK
        n_blocks = (n_steps + block - 1) // block
        width = (block - 1) * step + 1
        pooled = _max_pool(grid, width)
        bounds = _block_bounds(pooled, rows, cols, n_blocks, block * step, width)
        flat = bounds.reshape(-1)
        order = np.argsort(-flat, kind="stable")
        band = _COVARIANCE_BAND + 1e-9
        sums, lookups = _score_blocks(
            grid, rows, cols, order, flat, n_blocks, block, n_steps, step, band, float(n_points) * _SCALE, float(floor)
        )
        lookups += flat.size * n_points
        offs = (np.arange(n_steps) - half) * (step * res)
        pose, best, raw_best, resp = _finish_search(
            sums, n_points, offs, angles, float(center[0]), float(center[1]), float(center[2]),
            float(prior[0]), float(prior[1]), float(prior[2]), penalize, self.distance_variance_penalty,
            self.angle_variance_penalty, self.minimum_distance_penalty, self.minimum_angle_penalty)
        return pose, best, float(raw_best), resp, offs, lookups

    def _positional_covariance(self, resp, offs, center, pose, best, step_m, own=0.0):
        """Karto's x, y covariance of the surface about ``pose`` (see the module docstring).

        ``own`` is the weight of ``pose`` itself as one more sample (a refined place that the
        lattice ``resp`` sampled low; 0 for the lattice's own best). The usual case (the lattice's
        own best, no good response on the window's edge) runs in one compiled pass whose sums are
        numpy's, bit for bit (:func:`_spread_sums`); the others in numpy below.
        """
        if own == 0.0 and resp.ndim == 3:
            norm, sxx, syy, sxy, edge = _spread_sums(resp, offs, float(center[0]), float(center[1]),
                                                     float(pose[0]), float(pose[1]), best - _COVARIANCE_BAND)
            if norm <= 1e-12 or best <= 0:
                return np.diag([MAX_VARIANCE, MAX_VARIANCE])
            floor = 0.1 * step_m * step_m
            cov = np.zeros((2, 2))
            cov[0, 0] = max(sxx / norm, floor)
            cov[1, 1] = max(syy / norm, floor)
            cov[0, 1] = cov[1, 0] = sxy / norm
            cov /= best
            if edge:
                # As in the general case below, with the same sums (the mask's extent along the
                # main axis compiled too).
                vals, vecs = np.linalg.eigh(cov)
                lo, hi = _along_extent(resp, offs, float(center[0]), float(center[1]), float(pose[0]),
                                       float(pose[1]), best - _COVARIANCE_BAND, float(vecs[0, -1]), float(vecs[1, -1]))
                if hi - lo >= 0.5 * self.search_size:
                    vals[-1] = max(vals[-1], self.search_size**2)
                    cov = (vecs * vals) @ vecs.T
            return cov
        return self._positional_covariance_general(resp, offs, center, pose, best, step_m, own)

    def _positional_covariance_general(self, resp, offs, center, pose, best, step_m, own=0.0):
        surface = resp.max(axis=0) if resp.ndim == 3 else resp  # best response over angles, per (y, x)
        mask = surface >= best - _COVARIANCE_BAND
        w = np.where(mask, surface, 0.0)
        norm = w.sum() + own
        cov = np.zeros((2, 2))
        floor = 0.1 * step_m * step_m
        if norm <= 1e-12 or best <= 0:
            return np.diag([MAX_VARIANCE, MAX_VARIANCE])
        dx = (center[0] + offs)[None, :] - pose[0]
        dy = (center[1] + offs)[:, None] - pose[1]
        cov[0, 0] = max((w * dx * dx).sum() / norm, floor)
        cov[1, 1] = max((w * dy * dy).sum() / norm, floor)
        cov[0, 1] = cov[1, 0] = (w * dx * dy).sum() / norm
        cov /= best
        if mask[0, :].any() or mask[-1, :].any() or mask[:, 0].any() or mask[:, -1].any():
            # The good responses run along the spread's main axis through at least half the
            # window and into its edge (a corridor): the spread seen inside the window
            # understates the uncertainty, so along that axis it is taken as at least the whole
            # window (Karto keeps the truncated spread). A peak that merely sits near the edge
            # is left alone.
            vals, vecs = np.linalg.eigh(cov)
            along = (dx * vecs[0, -1] + dy * vecs[1, -1])[mask]
            if along.max() - along.min() >= 0.5 * self.search_size:
                vals[-1] = max(vals[-1], self.search_size**2)
                cov = (vecs * vals) @ vecs.T
        return cov

    # ----------------------------------------------------------------- the match

    def match(
        self,
        ref_points: NDArray[np.float64] | None,
        ref_sigmas: NDArray[np.float64] | None,
        query_points: NDArray[np.float64],
        prior: NDArray[np.float64],
        *,
        penalize: bool = True,
        refine: bool = True,
        grid: tuple[NDArray[np.uint8], float, float] | None = None,
        min_response: float = -1.0,
    ) -> MatchResult:
        """Best pose of the query scan (points ``(N, 2)`` in its robot frame) against world points.

        ``prior`` is the predicted robot pose: the window's centre and the
        penalty's zero. ``ref_sigmas`` (one per reference point, m) replace the
        smear deviation; None uses it for all. A prebuilt ``grid`` (from
        :meth:`correlation_grid`) skips building one. ``min_response`` is the least
        response the caller accepts: a branch-and-bound search skips every pose that
        cannot come within the covariance band of it, so a match that reaches it is the
        exhaustive one (pose, response, covariance) and one that cannot returns some
        response below it, early.
        """
        prior = np.asarray(prior, dtype=np.float64).reshape(3)
        q = np.asarray(query_points, dtype=np.float64).reshape(-1, 2)
        ref = np.zeros((0, 2)) if ref_points is None else np.asarray(ref_points, dtype=np.float64).reshape(-1, 2)
        empty = grid is None and ref.shape[0] == 0
        if q.shape[0] == 0 or empty or not np.all(np.isfinite(prior)):
            return MatchResult(prior.copy(), np.diag([MAX_VARIANCE, MAX_VARIANCE, MAX_VARIANCE]), 0.0, 0.0, 0)
        if grid is None:
            grid = self.correlation_grid(ref, self._sig(ref, ref_sigmas), *self.search_box(q, prior))
        g, ox, oy = grid
        origin = (ox, oy)
        res = self.resolution
        offset = self.coarse_angle_offset
        lookups = 0
        qc = self.coarse_points(q)
        for _ in range(4 if self.response_expansion else 1):
            n_half = int(round(offset / self.coarse_angle_resolution))
            angles, _ = _coarse_angles(offset, self.coarse_angle_resolution)
            pose, best, raw, resp, offs, n = self._search(
                g, origin, qc, prior, prior, angles, self._coarse_half, 2, penalize, True, min_response, prune=True
            )
            lookups += n
            if best > 0.0:
                break
            offset += math.radians(20.0)
        cov = np.zeros((3, 3))
        cov[:2, :2] = self._positional_covariance(resp, offs, prior, pose, best, 2.0 * res)
        heading_var = _heading_spread(resp, angles, best, self.coarse_angle_resolution**2 / 12.0)
        # The coarse angles are offsets from the prior's heading, which the pruned search scores
        # first and in full; an angle it leaves unscored (only with min_response) is over the band below.
        prior_drop = float(best - max(resp[n_half].max(), 0.0))
        return self._finish_match(g, ox, oy, q, prior, pose, best, raw, cov, heading_var, prior_drop, penalize,
                                  refine, lookups)

    def _finish_match(self, g, ox, oy, q, prior, pose, best, raw, cov, heading_var, prior_drop, penalize, refine,
                      lookups) -> MatchResult:
        """The fine stage after a coarse search (``cov`` holds its x, y covariance) and the result."""
        cov[2, 2] = 1.0  # Karto's placeholder when there is no fine angular search
        if refine and best > 0.0:
            angles, _ = _fine_angles(self.coarse_angle_resolution, self.fine_angle_step)
            # One coarse step of the fine search around the coarse best, in one compiled call: while
            # its best lies on its window's edge and responds better it is re-centred there (up to
            # fine_recentre times): the coarse pose is 1-2 cells and up to half a coarse angle step
            # off; at the wrong angle the best x, y is off too (far points move r * dtheta), and the
            # fine step cannot leave its +-1 cell. The heading variance is the spread of the fine
            # angles at the best x, y.
            pose, best, raw, cov[2, 2], runs = _fine_stage(
                g, float(ox), float(oy), self.resolution, np.ascontiguousarray(q), pose, float(prior[0]),
                float(prior[1]), float(prior[2]), angles, penalize, self.distance_variance_penalty,
                self.angle_variance_penalty, self.minimum_distance_penalty, self.minimum_angle_penalty,
                int(self.fine_recentre), self.fine_angle_step**2, 1000.0 * self.fine_angle_step**2)
            lookups += runs * angles.shape[0] * 9 * q.shape[0]
        elif best <= 0.0:
            cov = np.diag([MAX_VARIANCE, MAX_VARIANCE, MAX_VARIANCE])
        pose[2] = (pose[2] + np.pi) % (2 * np.pi) - np.pi
        return MatchResult(pose, cov, max(best, 0.0), max(raw, 0.0), int(lookups), heading_var, prior_drop)

    def match_near(
        self,
        query_points: NDArray[np.float64],
        prior: NDArray[np.float64],
        seed: NDArray[np.float64],
        grid: tuple[NDArray[np.uint8], float, float],
        *,
        half_steps: int,
        angle_steps: int,
        penalize: bool = True,
    ) -> MatchResult | None:
        """:meth:`match` (refined) with its coarse search cut to the part of its window nearest ``seed``;
        None when that part cannot stand for the whole window.

        The part is +-``half_steps`` coarse x, y steps and +-``angle_steps`` coarse angles of the
        full search's own lattice (centred on ``prior``, the penalty's zero) around the lattice
        pose nearest ``seed``, scored with the full search's arithmetic; the rest of the window
        counts as unscored. When the full surface's best and every pose within the covariance
        band of it lie in the part, the result is :meth:`match`'s bit for bit. The part cannot
        see a better pose outside it, so it gives up (None: search the whole window) when a pose
        within the band of its best lies on an edge of the part inside the window (a peak
        running out of it, a corridor) or nothing responds; the caller also rejects a weak best.
        """
        prior = np.asarray(prior, dtype=np.float64).reshape(3)
        seed = np.asarray(seed, dtype=np.float64).reshape(3)
        q = np.ascontiguousarray(np.asarray(query_points, dtype=np.float64).reshape(-1, 2))
        p0, p1, p2 = prior.tolist()
        s0, s1, s2 = seed.tolist()
        if q.shape[0] == 0 or not all(map(math.isfinite, (p0, p1, p2, s0, s1, s2))):
            return None
        g, ox, oy = grid
        res = self.resolution
        step_m = 2.0 * res
        big = self._coarse_half
        n_half = int(round(self.coarse_angle_offset / self.coarse_angle_resolution))
        h, k = min(int(half_steps), big), min(int(angle_steps), n_half)
        # The part's lowest lattice indices (x, y, angle), kept inside the window.
        j_lo = min(max(int(round((s0 - p0) / step_m)), h - big), big - h) + big - h
        i_lo = min(max(int(round((s1 - p1) / step_m)), h - big), big - h) + big - h
        d_theta = math.remainder(s2 - p2, 2.0 * math.pi)
        a_seed = min(max(int(round(d_theta / self.coarse_angle_resolution)), -n_half), n_half) + n_half
        a_lo = min(max(a_seed - n_half, k - n_half), n_half - k) + n_half - k
        angles, _ = _coarse_angles(self.coarse_angle_offset, self.coarse_angle_resolution)
        n_steps = 2 * big + 1
        sums = np.full((angles.shape[0], n_steps, n_steps), -1.0)
        # The part's angles nearest the seed's first: the best found early prunes the others (kept per part).
        key = ("part", a_lo, k, a_seed, big, step_m)
        got = _ANGLES.get(key)
        if got is None:
            part = np.arange(a_lo, a_lo + 2 * k + 1)
            got = _ANGLES[key] = (part[np.argsort(np.abs(part - a_seed), kind="stable")],
                                  (np.arange(n_steps) - big) * step_m)
        order, offs = got
        qc = self.coarse_points(q)
        lookups = _score_poses_pruned(g, ox, oy, res, _interleaved(qc), p0, p1, p2, angles,
                                      order, big, 2, i_lo, j_lo, 2 * h + 1, p0, p1,
                                      p2, penalize, self.distance_variance_penalty,
                                      self.angle_variance_penalty, self.minimum_distance_penalty,
                                      self.minimum_angle_penalty, -1.0, _PRUNE_CHUNK, sums)
        pose, best, raw, resp = _finish_search(
            sums, qc.shape[0], offs, angles, p0, p1, p2, p0, p1, p2, penalize, self.distance_variance_penalty,
            self.angle_variance_penalty, self.minimum_distance_penalty, self.minimum_angle_penalty)
        if not best > 0.0:
            return None
        # Edges of the part that are the window's own edges hide nothing.
        if _band_on_part_edge(resp, best - _COVARIANCE_BAND, a_lo, 2 * k + 1, i_lo, j_lo, 2 * h + 1):
            return None
        cov = np.zeros((3, 3))
        cov[:2, :2] = self._positional_covariance(resp, offs, prior, pose, best, step_m)
        heading_var = _heading_spread(resp, angles, best, self.coarse_angle_resolution**2 / 12.0)
        # The prior's heading over the whole window is not known: over any drop unless its best is in the band.
        at_prior = float(resp[n_half].max())
        prior_drop = float(best - at_prior) if at_prior >= best - _COVARIANCE_BAND else math.inf
        return self._finish_match(g, ox, oy, q, prior, pose, best, raw, cov, heading_var, prior_drop, penalize,
                                  True, lookups)

    def places(
        self,
        query_points: NDArray[np.float64],
        prior: NDArray[np.float64],
        grid: tuple[NDArray[np.uint8], float, float],
        *,
        floor: float,
        count: int = 16,
        about: bool = False,
    ):
        """The distinct places the query fits in this matcher's window, each refined: [(pose, response)], best first.

        The unpenalised coarse search over the whole window (exhaustive: every pose is
        scored) is reduced to the best response over headings per x, y; a place is an x, y
        whose response is at least each of its 8 neighbours' and at least ``floor`` (at most
        ``count`` of them, best first). Each is then searched one coarse step each way in
        x, y at one cell and in heading at the fine step, so that a peak lying between
        lattice poses is found wherever it is in the lattice's cell: on a 5 cm grid with a
        3 cm smear a wall seen across a corridor gives a peak one cell wide in x and a
        degree in heading, which the 2-cell, 2 deg lattice can sample 0.3 below its value
        while a look-alike place happens to sit on a lattice pose.

        With ``about`` it returns ``(places, covariance)``, where ``covariance(pose, response)``
        is Karto's positional covariance of this coarse surface taken about a refined place:
        the lattice poses responding within the covariance band (0.1) of that place's
        response, and the place itself, response-weighted, divided by its response. Where the
        lattice sampled the place's peak low only the place itself counts; where the lattice
        holds poses about as good (a corridor's ridge) they spread it as Karto's test would.
        """
        prior = np.asarray(prior, dtype=np.float64).reshape(3)
        q = np.asarray(query_points, dtype=np.float64).reshape(-1, 2)
        if q.shape[0] == 0 or not np.all(np.isfinite(prior)):
            return ([], lambda pose, response: np.diag([MAX_VARIANCE, MAX_VARIANCE])) if about else []
        g, ox, oy = grid
        n_half = int(round(self.coarse_angle_offset / self.coarse_angle_resolution))
        angles = np.arange(-n_half, n_half + 1) * self.coarse_angle_resolution
        _, _, _, resp, offs, _ = self._search(g, (ox, oy), q, prior, prior, angles, self._coarse_half, 2, False, False)
        surface = resp.max(axis=0)  # (y, x)
        padded = np.pad(surface, 1, constant_values=-np.inf)
        n = surface.shape[0]
        peak = surface >= floor
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                if dy or dx:
                    peak &= surface >= padded[1 + dy : 1 + dy + n, 1 + dx : 1 + dx + n]
        iy, ix = np.nonzero(peak)
        order = np.argsort(-surface[iy, ix], kind="stable")[:count]
        heading = resp.argmax(axis=0)
        n_fine = int(round(self.coarse_angle_resolution / self.fine_angle_step))
        fine = np.arange(-n_fine, n_fine + 1) * self.fine_angle_step
        out = []
        for k in order:
            y, x = int(iy[k]), int(ix[k])
            center = np.array([prior[0] + offs[x], prior[1] + offs[y], prior[2] + angles[heading[y, x]]])
            pose, best, _, _, _, _ = self._search(g, (ox, oy), q, center, center, fine, 2, 1, False, False)
            pose[2] = (pose[2] + np.pi) % (2 * np.pi) - np.pi
            out.append((pose, float(best)))
        out.sort(key=lambda t: -t[1])
        if not about:
            return out
        step_m = 2.0 * self.resolution

        def covariance(pose, response):
            return self._positional_covariance(surface, offs, prior, pose, response, step_m, own=response)

        return out, covariance


def _coarse_angles(offset: float, step: float):
    """The coarse search's angle offsets (``np.arange(-n, n + 1) * step``) and the order that scores the
    prior's heading first and then outwards; kept per (offset, step), never written to."""
    key = ("coarse", offset, step)
    got = _ANGLES.get(key)
    if got is None:
        n_half = int(round(offset / step))
        angles = np.arange(-n_half, n_half + 1) * step
        got = _ANGLES[key] = (angles, np.argsort(np.abs(angles), kind="stable"))
    return got


def _fine_angles(coarse_step: float, fine_step: float):
    """The fine stage's angle offsets (one coarse step of fine steps), as :func:`_coarse_angles`."""
    return _coarse_angles(0.5 * coarse_step, fine_step)


def _least_total(x: float, n: float) -> int:
    """The least integer t >= 0 with ``t / n >= x`` in floating point (the division is monotone in t)."""
    t = max(int(math.ceil(x * n)), 0)
    while t > 0 and (t - 1) / n >= x:
        t -= 1
    while t / n < x:
        t += 1
    return t


def _uniform(sigmas: NDArray[np.float64]) -> float | None:
    """The one sigma every point has, or None when they differ (or there are none)."""
    if sigmas.size == 0 or sigmas.min() != sigmas.max():
        return None
    return float(sigmas[0])


class GridCache:
    """Correlation grids kept between matches, extended scan by scan instead of rebuilt.

    The sequential matcher's reference set (the running scans) and a near
    chain change by a scan or two from one kept scan to the next, while
    smearing them costs as much as the search. An entry holds a grid, the
    nodes drawn into it and the bounding box of all their points (``ext``,
    including points that fell outside the grid). A request for a node set
    which differs from the entry only by nodes to add, and by at most
    ``max_extra`` nodes drawn but no longer asked for, smears just the new
    nodes, provided every reference point the query can reach (the part of
    ``ext`` inside the query's box) lies in the grid. Cells outside a grid
    read as empty, exactly as empty cells do, so the grid need only hold the
    reference points the query can reach: it is sized by the points' extent
    plus ``margin`` (clipped to the query's box plus ``query_margin``), not by the query's reach,
    and a robot moving along its reference scans rarely needs a new one.
    The grid is thus a superset of the asked-for scans by at most
    ``max_extra`` neighbouring scans (Karto rebuilds it every time; the
    difference is a slightly longer buffer). ``invalidate()`` (after an
    optimisation moved the nodes) drops everything.
    """

    def __init__(self, matcher: CorrelativeMatcher, points_of, *, margin: float = 3.0,
                 max_extra: int = 10, max_entries: int = 8, query_margin: float = 10.0) -> None:
        self.matcher = matcher
        self.points_of = points_of  # node -> (world points (N, 2), sigmas (N,))
        self.margin = float(margin)
        self.query_margin = float(query_margin)
        self.max_extra = int(max_extra)
        self.max_entries = int(max_entries)
        self.draw_margin = 1.0  # m drawn beyond a request's box (see materialize)
        self._entries: list[dict] = []
        # Per node: bounding box (lo x, lo y, hi x, hi y) of its points and 2 sigma of its widest smear.
        self._box = np.zeros((0, 6))
        self._known = np.zeros(0, dtype=bool)
        self._blocks: dict = {}  # node -> its share of a bound grid (see bound())
        self.builds = 0  # entries made (book-keeping; a pruned request may never draw its grid)
        self.extensions = 0
        self.draws = 0  # grids actually drawn
        self.smeared = 0  # points smeared into grids (book-keeping)
        self.kept = 0  # entries kept across an optimisation (see invalidate)
        # A new entry's grid starts as a copy of a drawn entry's holding most of its scans (see
        # materialize); False draws every new grid afresh (the same grids, tested).
        self.derive = True
        self.derived = 0  # new grids started from a drawn one
        self._epoch = 0  # optimisations seen: a grid drawn before one holds scans at old poses

    def invalidate(self, moved=None) -> None:
        """Forget grids drawn at poses that have changed: all of them, or those holding a ``moved`` node.

        ``moved`` (bool per node; nodes past its end count as moved) lets the caller keep the
        entries whose scans all moved less than it tolerates: their grids and bounds stay as
        drawn, scans added later are drawn at their new poses.
        """
        self._epoch += 1
        if moved is None:
            self._entries.clear()
            self._known[:] = False
            self._blocks.clear()
            return
        moved = np.asarray(moved, dtype=bool)

        def stale(n: int) -> bool:
            return n >= moved.size or bool(moved[n])

        keep = [e for e in self._entries if not any(stale(n) for n in e["nodes"])]
        self.kept += len(keep)
        self._entries[:] = keep
        k = min(moved.size, self._known.size)
        self._known[:k] &= ~moved[:k]
        self._known[k:] = False
        for n in [n for n in self._blocks if stale(n)]:
            del self._blocks[n]

    def _extent(self, nodes) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
        """Bounding box of the nodes' points and their largest smear reach (2 sigma + 2 cells)."""
        if len(nodes) == 1 and isinstance(nodes, list):
            # One node (a kept scan joining an entry): its own box, without the reductions below.
            n = int(nodes[0])
            if n < self._known.size and self._known[n]:
                b = self._box[n]
                return b[:2].copy(), b[2:4].copy(), float(b[4]) + 2.0 * self.matcher.resolution
        idx = np.asarray(nodes, dtype=np.int64)
        if idx.size == 0:
            return np.full(2, np.inf), np.full(2, -np.inf), 2.0 * self.matcher.resolution
        top = int(idx.max()) + 1
        if top > self._known.size:
            grow = max(top, 2 * self._known.size)
            self._known = np.concatenate([self._known, np.zeros(grow - self._known.size, bool)])
            self._box = np.concatenate([self._box, np.zeros((grow - self._box.shape[0], 6))])
        # Each node's box is computed once (until the next invalidate), the rest is array work.
        for n in idx[~self._known[idx]].tolist():
            pts, sig = self.points_of(n)
            _node_stats(pts, sig, self._box[n])
            self._known[n] = True
        # One compiled pass over the nodes' boxes (min and max are exact in any order).
        out = _boxes_extent(self._box, idx)
        return out[0:2], out[2:4], float(out[4]) + 2.0 * self.matcher.resolution

    def _sigma_of(self, nodes) -> float | None:
        """The one sigma of every point of these nodes (as :func:`_uniform` of their sigmas; after :meth:`_extent`)."""
        ok, u = _boxes_sigma(self._box, np.asarray(nodes, dtype=np.int64))
        return float(u) if ok else None

    def get(self, nodes, lo: NDArray[np.float64], hi: NDArray[np.float64]) -> tuple[NDArray[np.uint8], float, float]:
        """The grid of (a superset of) ``nodes`` holding every point a query inside (lo, hi) can reach."""
        return self.materialize(self.reserve(nodes, lo, hi), lo, hi)

    def reserve(self, nodes, lo: NDArray[np.float64], hi: NDArray[np.float64], *, max_extra: int | None = None) -> dict:
        """The entry :meth:`get` would return, with its book-keeping done but its smearing deferred.

        Which entry serves a request, and which nodes it then holds, depend only on
        earlier requests, never on whether their grids were drawn: a caller that can
        tell from the entry's points alone that it need not match (:meth:`bound`)
        leaves the cache exactly as :meth:`get` would, so later matches read the same
        grids. :meth:`materialize` draws what is pending (max-combining is
        order-free, so the grid equals the one drawn at once).
        """
        wanted = set(nodes.tolist() if isinstance(nodes, np.ndarray) else nodes)
        extra = self.max_extra if max_extra is None else int(max_extra)  # a caller may accept a looser superset
        wmin, wmax = (min(wanted), max(wanted)) if wanted else (0, -1)
        lx, ly, hx, hy = float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])
        for k, e in enumerate(self._entries):
            if e["span"][1] < wmin or e["span"][0] > wmax:
                continue  # no node in common (a cheap test first: up to 32 entries per request)
            have = e["nodes"]
            common = len(have & wanted)
            if not common or len(have) - common > extra:
                continue
            missing = sorted(wanted - have)
            if missing:
                xlo, xhi, reach = self._extent(missing)
                xlo = np.minimum(xlo, e["ext_lo"])
                xhi = np.maximum(xhi, e["ext_hi"])
                reach = max(reach, e["reach"])
            else:  # what _extent of nothing (inf, -inf, 2 cells) leaves the entry's at
                xlo, xhi, reach = e["ext_lo"], e["ext_hi"], e["reach"]
            # The reference points (with their smear) the query can reach must lie in the grid
            # (in Python floats: the same comparisons as on the 2-vectors, without numpy's per-call cost).
            nlx, nly = max(lx, float(xlo[0]) - reach), max(ly, float(xlo[1]) - reach)
            nhx, nhy = min(hx, float(xhi[0]) + reach), min(hy, float(xhi[1]) + reach)
            empty = nlx > nhx or nly > nhy
            if not empty and not (nlx >= e["lo"][0] and nly >= e["lo"][1] and nhx <= e["hi"][0] and nhy <= e["hi"][1]):
                continue
            if missing:
                # Repeated cells are skipped only while every point drawn has had one sigma.
                same = e["sigma"] is not None and self._sigma_of(missing) == e["sigma"]
                if not same:
                    e["sigma"] = None
                e["order"].extend(missing)
                have.update(missing)
                e["span"] = (min(e["span"][0], missing[0]), max(e["span"][1], missing[-1]))
                e["ext_lo"], e["ext_hi"], e["reach"] = xlo, xhi, reach
                self.extensions += 1
            self._entries.insert(0, self._entries.pop(k))
            return e
        order_nodes = sorted(wanted)
        donor = self._donor(wanted, wmin, wmax) if self.derive else None
        xlo, xhi, reach = self._extent(order_nodes)
        # Room to grow by ``margin`` around the points (the next scans extend them), but never
        # far beyond the query's reach (a long buffer in open space would make a huge grid).
        blo = np.maximum(lo - self.query_margin, xlo - reach - self.margin)
        bhi = np.minimum(hi + self.query_margin, xhi + reach + self.margin)
        ox, oy, rows, cols = self.matcher.grid_geometry(None, blo, bhi)
        res = self.matcher.resolution
        e = {"grid": None, "box": (blo, bhi), "nodes": wanted, "lo": np.array([ox, oy]),
             "hi": np.array([ox + (cols - 1) * res, oy + (rows - 1) * res]),
             "ext_lo": xlo, "ext_hi": xhi, "reach": reach, "sigma": self._sigma_of(order_nodes),
             "parts": [], "order": list(order_nodes),
             "span": (order_nodes[0], order_nodes[-1]) if order_nodes else (0, -1),  # least and most node
             "epoch": self._epoch, "donor": donor}
        self._entries.insert(0, e)
        if len(self._entries) > self.max_entries:
            del self._entries[self.max_entries:]
            # An entry not drawn yet keeps its donor only while the donor is cached (memory).
            live = {id(x) for x in self._entries}
            for x in self._entries:
                if x.get("donor") is not None and id(x["donor"]) not in live:
                    x["donor"] = None
        self.builds += 1
        return e

    def _donor(self, wanted: set, wmin: int, wmax: int) -> dict | None:
        """A drawn entry of this epoch whose drawn scans are at least half of ``wanted`` (the most shared), or None."""
        best, most = None, (len(wanted) + 1) // 2 - 1
        for e in self._entries:
            if e["grid"] is None or not e["n_drawn"] or e["epoch"] != self._epoch:
                continue
            if e["span"][1] < wmin or e["span"][0] > wmax:
                continue
            common = len(wanted.intersection(e["order"][: e["n_drawn"]]))
            if common > most:
                best, most = e, common
        return best

    def _derive(self, e: dict, new) -> bool:
        """Start the new entry's grid from its donor's (see :func:`_derive_grid`) and draw the rest; False if it cannot."""
        d = e.pop("donor", None)
        if d is None or d["epoch"] != self._epoch or d["epoch"] != e["epoch"] or d["grid"] is None:
            return False
        res = self.matcher.resolution
        g, ox, oy = e["grid"]
        sg, sox, soy = d["grid"]
        oc = int(round((sox - ox) / res))
        orow = int(round((soy - oy) / res))
        m = e["reach"] + 2.0 * res
        # The donor's exact cells (inside its drawn box), clipped to the new grid and its box plus the reach.
        dlo, dhi = d["drawn"]
        c0 = max(int(math.floor((dlo[0] - sox) / res)) + 1, -oc, int(math.floor((new[0][0] - m - sox) / res)))
        r0 = max(int(math.floor((dlo[1] - soy) / res)) + 1, -orow, int(math.floor((new[0][1] - m - soy) / res)))
        c1 = min(int(math.floor((dhi[0] - sox) / res)) - 1, g.shape[1] - 1 - oc, sg.shape[1] - 1,
                 int(math.floor((new[1][0] + m - sox) / res)))
        r1 = min(int(math.floor((dhi[1] - soy) / res)) - 1, g.shape[0] - 1 - orow, sg.shape[0] - 1,
                 int(math.floor((new[1][1] + m - soy) / res)))
        c0, r0 = max(c0, 0), max(r0, 0)
        drawn = set(d["order"][: d["n_drawn"]])
        parts = self._parts(e)
        px, py, sig = self._columns(e, 0, len(parts))
        kept = np.repeat(np.array([n in drawn for n in e["order"]], dtype=np.bool_), np.diff(e["starts"]))
        # The donor's drawn scans the new entry does not hold, from the donor's columns.
        dx, dy, ds = self._columns(d, 0, d["n_drawn"])
        dst = d["starts"]
        gone = [(dst[k], dst[k + 1]) for k, n in enumerate(d["order"][: d["n_drawn"]]) if n not in e["nodes"]]
        if len(gone) == 1:
            xpx, xpy, xsig = dx[gone[0][0]:gone[0][1]], dy[gone[0][0]:gone[0][1]], ds[gone[0][0]:gone[0][1]]
        elif gone:
            xpx = np.concatenate([dx[a:b] for a, b in gone])
            xpy = np.concatenate([dy[a:b] for a, b in gone])
            xsig = np.concatenate([ds[a:b] for a, b in gone])
        else:
            xpx, xpy, xsig = np.zeros(0), np.zeros(0), np.zeros(0)
        ok, todo = _derive_grid(g, ox, oy, sg, sox, soy, res, oc, orow, r0, r1, c0, c1, px, py, sig, kept,
                                xpx, xpy, xsig, new[0][0] - m, new[0][1] - m, new[1][0] + m, new[1][1] + m)
        if not ok:
            return False
        if todo.size:
            _smear(g, ox, oy, res, px[todo], py[todo], np.ascontiguousarray(sig[todo]), False)
            self.smeared += int(todo.size)
        # A full cell (a kernel's centre) no longer means its whole kernel is drawn (the clearing may
        # have cut it), so repeated cells are never skipped in this grid.
        e["sigma"] = None
        self.derived += 1
        return True

    def materialize(self, e: dict, lo: NDArray[np.float64], hi: NDArray[np.float64]) -> tuple[NDArray[np.uint8], float, float]:
        """The entry's grid, drawn where a query inside (lo, hi) can read it.

        A cell holds its final value once every point whose smear reaches it is drawn. The
        entry keeps the box where that holds (``drawn``) and grows it to each request plus
        ``draw_margin`` (which also covers the fine search's degree beyond the coarse angles,
        0.2 m at 12 m), drawing only the points near the part that is new, and new scans only
        inside it: a chain's grid is drawn where its matches look, not over all its scans.
        Max-combining is order-free, so every cell a match reads equals the grid drawn at once.
        """
        res = self.matcher.resolution
        grid = e["grid"]
        if grid is None:
            blo, bhi = e["box"]
            ox, oy, rows, cols = self.matcher.grid_geometry(None, blo, bhi)
            grid = e["grid"] = (np.zeros((rows, cols), np.uint8), ox, oy)
            e["drawn"] = None
            e["n_drawn"] = 0
            self.draws += 1
        old = e["drawn"]
        parts = self._parts(e)
        # (Python floats: the same comparisons as np.all on the 2-vectors, without its per-call cost.)
        inside = old is not None and (float(lo[0]) >= float(old[0][0]) and float(lo[1]) >= float(old[0][1])
                                      and float(hi[0]) <= float(old[1][0]) and float(hi[1]) <= float(old[1][1]))
        if inside and e["n_drawn"] == len(parts):
            return grid
        new = old if inside else (lo - self.draw_margin, hi + self.draw_margin)
        if old is not None and not inside:
            new = (np.minimum(new[0], old[0]), np.maximum(new[1], old[1]))
        # A point further than its smear's reach (plus a cell's rounding) from a box draws nothing in it.
        m = e["reach"] + 2.0 * res
        same = e["sigma"] is not None  # one sigma for every point: repeated cells can be skipped
        g, ox, oy = grid
        if old is None and e.get("donor") is not None and self._derive(e, new):
            e["drawn"] = (np.asarray(new[0], dtype=np.float64), np.asarray(new[1], dtype=np.float64))
            e["n_drawn"] = len(parts)
            e["drawn_reach"] = m
            return grid
        e.pop("donor", None)  # drawn without it: let its grid go
        if old is not None and not inside and e["n_drawn"]:
            px, py, sig = self._columns(e, 0, e["n_drawn"])
            # The points drawn before are those within the old box plus the reach of then (scans
            # added since can have widened it): the rest of the old scans' points near the new box.
            m_old = e["drawn_reach"]
            keep = _inside_not(px, py, new[0][0] - m, new[0][1] - m, new[1][0] + m, new[1][1] + m,
                               old[0][0] - m_old, old[0][1] - m_old, old[1][0] + m_old, old[1][1] + m_old)
            if keep.size:
                _smear(g, ox, oy, res, px[keep], py[keep], np.ascontiguousarray(sig[keep]), same)
                self.smeared += int(keep.size)
        if e["n_drawn"] < len(parts):
            px, py, sig = self._columns(e, e["n_drawn"], len(parts))
            keep = _inside(px, py, new[0][0] - m, new[0][1] - m, new[1][0] + m, new[1][1] + m)
            if keep.size:
                _smear(g, ox, oy, res, px[keep], py[keep], np.ascontiguousarray(sig[keep]), same)
                self.smeared += int(keep.size)
        e["drawn"] = (np.asarray(new[0], dtype=np.float64), np.asarray(new[1], dtype=np.float64))
        e["n_drawn"] = len(parts)
        if not inside:
            # Every scan is now drawn to here; a request inside the box draws only new scans, to the
            # reach of then, so the old ones keep the reach they were drawn with (the least counts).
            e["drawn_reach"] = m
        return grid

    def bound(self, e: dict, query_points, prior, *, stop: float = 2.0, mark: float | None = None,
              matcher: CorrelativeMatcher | None = None) -> float:
        """:meth:`CorrelativeMatcher.response_bound` of a match on the entry's grid, drawn or not.

        The entry keeps its bound grid and extends it as scans are added, as it does the
        correlation grid. Each scan's share (its blocks in a lattice of origin 0, a few hundred)
        is computed once per scan until :meth:`invalidate`, so a new entry costs a scatter of
        those, not a smear of every point. The lattice differs from the correlation grid's by at
        most a cell's rounding, which the bound's reach allows for. ``matcher``: the match's own
        (the cache's by default; another window or angle offset at the same resolution and smear).
        """
        m = self.matcher
        searcher = matcher or m
        res = m.resolution
        b = _BOUND_BLOCK
        if e.get("pooled") is None:
            row0 = int(math.floor(float(e["lo"][1]) / res)) // b - 1
            col0 = int(math.floor(float(e["lo"][0]) / res)) // b - 1
            rows = int(math.floor(float(e["hi"][1]) / res)) // b + 2 - row0
            cols = int(math.floor(float(e["hi"][0]) / res)) // b + 2 - col0
            e["pooled"] = (np.zeros((rows, cols), np.uint8), row0, col0)
            e["pooled_nodes"] = 0
        pooled, row0, col0 = e["pooled"]
        order = e["order"]
        if e["pooled_nodes"] < len(order):
            parts = [self._node_blocks(n) for n in order[e["pooled_nodes"]:]]
            _scatter_max(pooled, np.concatenate([q[0] for q in parts]), np.concatenate([q[1] for q in parts]),
                         np.concatenate([q[2] for q in parts]), row0, col0)
            e["pooled_nodes"] = len(order)
            e["pooled_tables"] = {}  # the bound grid changed: its sparse table is built again
        return searcher.pooled_bound(pooled, col0 * b * res, row0 * b * res, query_points, prior, stop=stop,
                                     tables=e.setdefault("pooled_tables", {}), mark=mark)

    def _node_blocks(self, n: int):
        got = self._blocks.get(n)
        if got is None:
            pts, sig = self.points_of(n)
            sigma_max = float(sig.max()) if sig.size else self.matcher.smear_deviation
            got = _node_blocks(np.ascontiguousarray(pts[:, 0]), np.ascontiguousarray(pts[:, 1]), sigma_max,
                               self.matcher.resolution, _BOUND_BLOCK)
            self._blocks[n] = got
        return got

    def _parts(self, e: dict) -> list:
        """Per node of the entry, its (world points, sigmas), fetched when first needed."""
        parts, order = e["parts"], e["order"]
        if len(parts) < len(order):
            parts.extend(self.points_of(n) for n in order[len(parts):])
        return parts

    def _columns(self, e: dict, k0: int, k1: int):
        """x, y and sigma (contiguous, read-only use) of the points of the entry's nodes ``order[k0:k1]``.

        The entry keeps its nodes' points as three growing columns (``starts``: where each node's
        begin), filled as :meth:`_parts` fetches them, so a range of nodes is a slice, not a copy.
        """
        parts = e["parts"] if len(e["parts"]) >= k1 else self._parts(e)
        cols = e.get("cols")
        if cols is None:
            cols = e["cols"] = [np.empty(0), np.empty(0), np.empty(0)]
            e["starts"] = [0]
        starts = e["starts"]
        done = len(starts) - 1
        if done < len(parts):
            size = starts[-1] + sum(p[0].shape[0] for p in parts[done:])
            if size > cols[0].shape[0]:
                cap = max(size, 2 * cols[0].shape[0])
                for k in range(3):
                    grown = np.empty(cap)
                    grown[: starts[-1]] = cols[k][: starts[-1]]
                    cols[k] = grown
            new = parts[done:]
            a = starts[-1]
            pts, sig = _concat(new)  # one copy of the new nodes' points, then three column writes (not three per node)
            cols[0][a:size] = pts[:, 0]
            cols[1][a:size] = pts[:, 1]
            cols[2][a:size] = sig
            for q in new:
                a += q[0].shape[0]
                starts.append(a)
        a, b = starts[k0], starts[k1]
        return cols[0][a:b], cols[1][a:b], cols[2][a:b]



def _concat(parts) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(points, sigmas) of a list of per-node (points, sigmas); a lone part's own arrays (read them only)."""
    if not parts:
        return np.zeros((0, 2)), np.zeros(0)
    if len(parts) == 1:
        return parts[0]
    return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])
