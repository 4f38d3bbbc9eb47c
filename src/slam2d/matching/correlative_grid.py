"""Drawing correlation grids: the Gaussian smear of reference points, in row bands on threads.

Every reference point is smeared into a ``uint8`` grid by a Gaussian of its own sigma, cells keeping
the largest value (:func:`smear_points`); big smears are drawn in row bands shared among threads
(:func:`smear_in_row_bands`, :func:`_split`); a new grid can start as a copy of a drawn one holding
most of its points (:func:`_derive_grid`). The matcher that reads these grids is
:mod:`slam2d.matching.correlative`; the cache that keeps them is :mod:`slam2d.matching.grid_cache`.
"""

from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from numba import njit

__all__ = ["smear_points", "smear_in_row_bands", "smear_in_row_order"]


# Response values are stored as 0..SCALE in a uint8 grid.
_SCALE = 255.0


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
def _smear_sigmas(smear, sig, use, ranges, spacing, increment, lo, hi):
    """The smear sigma of each beam in ``use`` (see :meth:`CorrelativeMatcher.reference_sigmas`): ``smear`` and
    the beam's range sigma ``sig`` (NaN: none; inf: the largest float, as np.nan_to_num gives) in quadrature,
    clamped to [lo, hi]; with ``spacing`` > 0 then ``spacing * ranges * increment`` (the share of the beam gap)
    added in quadrature, clamped to ``hi``."""
    n = 0
    for k in range(use.shape[0]):
        if use[k]:
            n += 1
    out = np.empty(n)
    m = 0
    big = 1.7976931348623157e308  # np.nan_to_num's stand-in for an infinite sigma
    for k in range(use.shape[0]):
        if not use[k]:
            continue
        b = sig[k]
        if np.isnan(b):
            b = 0.0
        elif b == np.inf:
            b = big
        elif b == -np.inf:
            b = -big
        v = math.sqrt(smear * smear + b * b)
        v = min(max(v, lo), hi)
        if spacing > 0:
            gap = spacing * ranges[k] * increment
            v = min(math.sqrt(v * v + gap * gap), hi)
        out[m] = v
        m += 1
    return out


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
