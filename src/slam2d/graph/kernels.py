"""The graph front end's compiled helpers: runs of scans, graph and distance queries, scan points.

Each does in one compiled pass what a short numpy expression (named in its docstring) would, with
the same arithmetic in the same order, so the results are bit for bit those of the expression.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from numba import njit

# ----------------------------------------------------------------- runs of scans, graph and distance queries


def _runs(mask: NDArray[np.bool_]) -> list[tuple[int, int]]:
    """Half-open index ranges ``[a, b)`` of the runs of True in ``mask``."""
    if mask.size == 0:
        return []
    return _run_bounds(np.ascontiguousarray(mask, dtype=np.bool_)).tolist()


def _runs_counted(mask: NDArray[np.bool_], flags: NDArray[np.bool_]) -> list[list[int]]:
    """:func:`_runs` of ``mask``, each with how many of ``flags[a:b]`` are True: ``[a, b, count]``."""
    if mask.size == 0:
        return []
    return _run_counts(np.ascontiguousarray(mask, dtype=np.bool_), np.ascontiguousarray(flags, dtype=np.bool_)).tolist()


@njit(cache=True)
def _run_counts(mask, flags):
    """(runs, 3): start, end (half-open) and the number of True ``flags`` of each run of True in ``mask``."""
    runs = _run_bounds(mask)
    out = np.empty((runs.shape[0], 3), np.int64)
    for k in range(runs.shape[0]):
        c = 0
        for i in range(runs[k, 0], runs[k, 1]):
            if flags[i]:
                c += 1
        out[k, 0] = runs[k, 0]
        out[k, 1] = runs[k, 1]
        out[k, 2] = c
    return out


@njit(cache=True)
def _run_bounds(mask):
    """(runs, 2): start and end (half-open) of each run of True in ``mask``, in order."""
    n = mask.shape[0]
    out = np.empty((n // 2 + 1, 2), np.int64)
    m = 0
    k = 0
    while k < n:
        if mask[k]:
            a = k
            while k < n and mask[k]:
                k += 1
            out[m, 0] = a
            out[m, 1] = k
            m += 1
        else:
            k += 1
    return out[:m]


@njit(cache=True)
def _within(ref_xy, node, limit2):
    """Per node, whether its squared distance to ``node``'s (numpy's ``((d) ** 2).sum(axis=1)``) is below ``limit2``."""
    n = ref_xy.shape[0]
    out = np.empty(n, np.bool_)
    x0 = ref_xy[node, 0]
    y0 = ref_xy[node, 1]
    for i in range(n):
        dx = ref_xy[i, 0] - x0
        dy = ref_xy[i, 1] - y0
        out[i] = dx * dx + dy * dy < limit2
    return out

@njit(cache=True)
def _reachable(start, near, ei, ej, n):
    """Nodes reachable from ``start`` over edges whose both ends are ``near`` (breadth first)."""
    deg = np.zeros(n + 1, np.int64)
    for k in range(ei.shape[0]):
        if near[ei[k]] and near[ej[k]]:
            deg[ei[k] + 1] += 1
            deg[ej[k] + 1] += 1
    for i in range(n):
        deg[i + 1] += deg[i]
    adj = np.empty(deg[n], np.int64)
    fill = deg[:n].copy()
    for k in range(ei.shape[0]):
        if near[ei[k]] and near[ej[k]]:
            adj[fill[ei[k]]] = ej[k]
            fill[ei[k]] += 1
            adj[fill[ej[k]]] = ei[k]
            fill[ej[k]] += 1
    out = np.zeros(n, np.bool_)
    queue = np.empty(n, np.int64)
    out[start] = True
    queue[0] = start
    head, tail = 0, 1
    while head < tail:
        v = queue[head]
        head += 1
        for k in range(deg[v], deg[v + 1]):
            w = adj[k]
            if not out[w]:
                out[w] = True
                queue[tail] = w
                tail += 1
    return out


@njit(cache=True)
def _edge_between(ei, ej, i, j):
    """Whether some edge k joins i and j either way (``ei[k], ej[k]`` is ``i, j`` or ``j, i``)."""
    for k in range(ei.shape[0]):
        if (ei[k] == i and ej[k] == j) or (ei[k] == j and ej[k] == i):
            return True
    return False


@njit(cache=True)
def _closest_row(ref, idx, tx, ty):
    """``np.argmin(((ref[idx] - (tx, ty)) ** 2).sum(axis=1))``: the first smallest (the first NaN if any)."""
    best = np.inf
    at = 0
    for k in range(idx.shape[0]):
        dx = ref[idx[k], 0] - tx
        dy = ref[idx[k], 1] - ty
        d = dx * dx + dy * dy
        if np.isnan(d):
            return k
        if d < best:
            best = d
            at = k
    return at


@njit(cache=True)
def _equal_rows(a, b):
    """How many leading rows of ``a`` and ``b`` (both (n, 3)) are equal element by element (``==``: NaN never is)."""
    n = min(a.shape[0], b.shape[0])
    for i in range(n):
        if not (a[i, 0] == b[i, 0] and a[i, 1] == b[i, 1] and a[i, 2] == b[i, 2]):
            return i
    return n


@njit(cache=True)
def _transform_rows(poses, base, cos, sin, first, out):
    """Rows ``first:`` of ``out``: ``base[i]`` mapped by ``poses[i]`` (heading's cos and sin from ``first``),
    with se2.transform_points' products and sums in its order."""
    for i in range(first, poses.shape[0]):
        c = cos[i - first]
        s = sin[i - first]
        px = base[i, 0]
        py = base[i, 1]
        out[i, 0] = poses[i, 0] + c * px - s * py
        out[i, 1] = poses[i, 1] + s * px + c * py


@njit(cache=True)
def _column_means(p):
    """``p.mean(axis=0)`` of a C-contiguous (n >= 1, 2) array as numpy reduces it: the first row, then each
    next row added in order, divided by n."""
    n = p.shape[0]
    sx = p[0, 0]
    sy = p[0, 1]
    for k in range(1, n):
        sx += p[k, 0]
        sy += p[k, 1]
    out = np.empty(2)
    out[0] = sx / n
    out[1] = sy / n
    return out


# ----------------------------------------------------------------- scan points


def _in_range(scan, threshold: float) -> tuple[NDArray[np.bool_], bool]:
    """(``scan.valid & (scan.ranges <= threshold)``, whether any beam is in it): one compiled pass for
    float64 ranges, numpy otherwise."""
    r = scan.ranges
    if type(r) is np.ndarray and r.dtype == np.float64 and r.ndim == 1:
        use, count = _valid_within(r, float(threshold))
        return use, count > 0
    with np.errstate(invalid="ignore"):
        use = scan.valid & (r <= threshold)
    return use, bool(use.any())


@njit(cache=True)
def _valid_within(ranges, threshold):
    """``~np.isnan(ranges) & (ranges <= threshold)`` and how many beams it holds."""
    out = np.empty(ranges.shape[0], np.bool_)
    count = 0
    for k in range(ranges.shape[0]):
        r = ranges[k]
        ok = not np.isnan(r) and r <= threshold
        out[k] = ok
        count += ok
    return out, count


@njit(cache=True)
def _transform_xy(x0, y0, c, s, pts):
    """se2.transform_points of (N, 2) points by the pose (x0, y0) with heading cos c, sin s (same arithmetic)."""
    out = np.empty((pts.shape[0], 2))
    for k in range(pts.shape[0]):
        px = pts[k, 0]
        py = pts[k, 1]
        out[k, 0] = x0 + c * px - s * py
        out[k, 1] = y0 + s * px + c * py
    return out


@njit(cache=True)
def _beam_points(x0, y0, c, s, ranges, cos, sin, use):
    """The points (mount pose x0, y0, cos c, sin s) of the beams in ``use``: Scan.points()' arithmetic."""
    n = 0
    for k in range(use.shape[0]):
        if use[k]:
            n += 1
    out = np.empty((n, 2))
    m = 0
    for k in range(use.shape[0]):
        if use[k]:
            px = ranges[k] * cos[k]
            py = ranges[k] * sin[k]
            out[m, 0] = x0 + c * px - s * py
            out[m, 1] = y0 + s * px + c * py
            m += 1
    return out
