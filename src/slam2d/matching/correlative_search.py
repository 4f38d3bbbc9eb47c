"""The compiled search kernels of the correlative matcher (:mod:`slam2d.matching.correlative`).

Per angle the query points become integer cells (the lookup table) and every x, y offset an integer
shift: exhaustive window scores, the pruned coarse search (angles dropped once they cannot reach the
covariance band), branch and bound over blocks of translations on a max-pooled grid, the response
bound of a match before its grid is drawn, Karto's penalties, the response surface's covariance and
heading spread, and the fine stage.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

from slam2d.matching.correlative_grid import _kernel, _SCALE

__all__ = ["MAX_VARIANCE"]


# Karto's MAX_VARIANCE: the covariance of a match that found nothing.
MAX_VARIANCE = 500.0


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


# Response bounds of at least this many points x headings share their headings among threads.
_PARALLEL_BOUND = 4000


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
def _block_at(flat, n_blocks, block, n_steps):
    """Angle, first translation steps and size (a, i0, j0, ni, nj) of block ``flat`` (angle-major, then rows of blocks)."""
    a = flat // (n_blocks * n_blocks)
    rem = flat % (n_blocks * n_blocks)
    i0 = (rem // n_blocks) * block
    j0 = (rem % n_blocks) * block
    return a, i0, j0, min(block, n_steps - i0), min(block, n_steps - j0)


@njit(cache=True, nogil=True)
def _score_blocks_stride(grid, rows, cols, order, bounds_flat, n_blocks, block, n_steps, step, band, n_points, floor,
                         first, stride, out):
    """Branch and bound over the blocks ``order[first::stride]``: score whole blocks into ``out`` until the bound
    drops below max(best of this stride, floor) - band.

    ``floor`` is the least response the caller will accept: blocks that cannot come within ``band`` of it are
    never needed, whatever the best turns out to be. Strides run side by side on threads (disjoint blocks of
    ``out``); each prunes with its own best, never above the best over all blocks before the same place in
    ``order``, so together they score every block the one-stride search scores, and some more
    (:func:`_serial_blocks` unscores those).
    """
    buf = np.zeros((block, block), np.int32)
    best = floor
    for idx in range(first, order.shape[0], stride):
        flat = order[idx]
        if bounds_flat[flat] / n_points < best - band:
            break
        a, i0, j0, ni, nj = _block_at(flat, n_blocks, block, n_steps)
        _score_window(grid, rows, cols, a, i0, j0, ni, nj, step, buf)
        for i in range(ni):
            for j in range(nj):
                v = buf[i, j]
                out[a, i0 + i, j0 + j] = v
                if v / n_points > best:
                    best = v / n_points


@njit(cache=True)
def _serial_blocks(out, n_query, order, bounds_flat, n_blocks, block, n_steps, band, n_points, floor):
    """Reset to -1 the blocks of ``out`` the one-stride branch and bound would not have scored (it stops at the
    first block, in ``order``, whose bound is below the best so far less ``band``), so the result does not
    depend on how the blocks were shared; returns that search's lookups (``n_query`` points a pose)."""
    best = floor
    lookups = 0
    stop = order.shape[0]
    for idx in range(order.shape[0]):
        flat = order[idx]
        if bounds_flat[flat] / n_points < best - band:
            stop = idx
            break
        a, i0, j0, ni, nj = _block_at(flat, n_blocks, block, n_steps)
        lookups += ni * nj * n_query
        for i in range(ni):
            for j in range(nj):
                v = out[a, i0 + i, j0 + j]
                if v / n_points > best:
                    best = v / n_points
    for idx in range(stop, order.shape[0]):
        a, i0, j0, ni, nj = _block_at(order[idx], n_blocks, block, n_steps)
        for i in range(ni):
            for j in range(nj):
                out[a, i0 + i, j0 + j] = -1.0
    return lookups


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
    """(min x, min y, max x, max y, max sigma) over the rows ``idx`` of :func:`_node_stats` boxes (idx not empty)."""
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
    """out = (min x, min y, max x, max y, max sigma, the one sigma or NaN); a scan without points:
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
    out[4] = s_hi
    out[5] = s_lo if s_lo == s_hi else np.nan


@njit(cache=True)
def _scatter_max_nodes(out, rows, cols, vals, span, nodes, row0, col0):
    """out[rows[k] - row0, cols[k] - col0] = max(out there, vals[k]) for k in each of ``nodes``' ``span[node]``.

    Blocks falling outside ``out`` are skipped.
    """
    n_r, n_c = out.shape
    for t in range(nodes.shape[0]):
        n = nodes[t]
        for k in range(span[n, 0], span[n, 1]):
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
    # The order ``np.argsort(np.arange(n) % stride, kind="stable")`` gathered in one compiled pass.
    return _interleave_rows(q, stride)


@njit(cache=True)
def _interleave_rows(q, stride):
    """``q[np.argsort(np.arange(n) % stride, kind="stable")]`` (contiguous): rows 0, s, 2s, ..., then 1, s + 1, ..."""
    n = q.shape[0]
    out = np.empty((n, q.shape[1]), q.dtype)
    m = 0
    for r in range(stride):
        for k in range(r, n, stride):
            for c in range(q.shape[1]):
                out[m, c] = q[k, c]
            m += 1
    return out


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


@njit(cache=True)
def _peaks(surface, floor):
    """Cells of ``surface`` (2-D) at least ``floor`` and at least each of their 8 neighbours, a cell beyond
    the edge reading -inf: ``surface >= floor`` and-ed with ``surface >= `` each shifted copy of
    ``np.pad(surface, 1, constant_values=-np.inf)``, the same comparisons."""
    ny, nx = surface.shape
    out = np.empty((ny, nx), np.bool_)
    for i in range(ny):
        for j in range(nx):
            v = surface[i, j]
            ok = v >= floor
            for di in range(-1, 2):
                for dj in range(-1, 2):
                    if di == 0 and dj == 0:
                        continue
                    a, b = i + di, j + dj
                    w = surface[a, b] if 0 <= a < ny and 0 <= b < nx else -np.inf
                    ok = ok and v >= w
            out[i, j] = ok
    return out


@njit(cache=True)
def _unknown_nodes(known, idx):
    """(``idx.max() + 1``, ``idx[~known[idx]]``) with nodes past ``known``'s end counted as unknown (``idx`` not empty)."""
    top = idx[0]
    out = np.empty(idx.shape[0], np.int64)
    m = 0
    for k in range(idx.shape[0]):
        n = idx[k]
        if n > top:
            top = n
        if n >= known.shape[0] or not known[n]:
            out[m] = n
            m += 1
    return top + 1, out[:m]


@njit(cache=True)
def _plane_max(resp, a):
    """``float(resp[a].max())`` of a (angles, y, x) surface: the largest, or NaN if any is NaN (as numpy's)."""
    best = -np.inf
    for i in range(resp.shape[1]):
        for j in range(resp.shape[2]):
            v = resp[a, i, j]
            if np.isnan(v):
                return v
            if v > best:
                best = v
    return best


@njit(cache=True)
def _max_argmax0(resp):
    """``resp.max(axis=0)`` and ``resp.argmax(axis=0)`` of a (angles, y, x) surface in one pass (NaN wins, the
    first on ties, as numpy's)."""
    na, ny, nx = resp.shape
    best = np.empty((ny, nx))
    at = np.empty((ny, nx), np.int64)
    for i in range(ny):
        for j in range(nx):
            b = resp[0, i, j]
            k = 0
            if not np.isnan(b):
                for a in range(1, na):
                    v = resp[a, i, j]
                    if np.isnan(v):
                        b = v
                        k = a
                        break
                    if v > b:
                        b = v
                        k = a
            best[i, j] = b
            at[i, j] = k
    return best, at


@njit(cache=True)
def _node_blocks_of(pts, sig, default_sigma, resolution, block):
    """:func:`_node_blocks` of a scan's (N, 2) points at the largest of its sigmas (NaN if any is, as
    ``float(sig.max())``; ``default_sigma`` when there are none)."""
    s = default_sigma
    if sig.shape[0]:
        s = sig[0]
        for k in range(1, sig.shape[0]):
            v = sig[k]
            if np.isnan(s):
                break
            if np.isnan(v) or v > s:
                s = v
    return _node_blocks(np.ascontiguousarray(pts[:, 0]), np.ascontiguousarray(pts[:, 1]), s, resolution, block)


@njit(cache=True)
def _point_columns(q):
    """``q[:, 0]``, ``q[:, 1]`` (contiguous copies) of (N, 2) points and :func:`_ranges` of them."""
    n = q.shape[0]
    qx = np.empty(n)
    qy = np.empty(n)
    for k in range(n):
        qx[k] = q[k, 0]
        qy[k] = q[k, 1]
    return qx, qy, _ranges(qx, qy)
