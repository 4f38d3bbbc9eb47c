"""Copy-on-write tiled maps: many particle maps sharing unchanged tiles.

A Rao-Blackwellised particle filter keeps one map per particle, but after
resampling most particles descend from a few ancestors, and their maps differ
only where the robot has been since. :class:`TiledMaps` stores every map as a
table of tile indices into one shared pool of fixed-size tiles
(``TILE`` x ``TILE`` cells) with reference counts:

* resampling copies the index tables (a few hundred KB) and adjusts the
  reference counts -- no cell is copied;
* writing to a tile another map also uses copies it first (copy-on-write), so
  memory grows with what the particles changed, not particles x map size;
* a tile no map uses any more goes back to a free list.

Cells hold what GMapping's ``PointAccumulator`` holds: ``hits``, ``visits``
and the sum of the hit points (stored relative to the cell centre, so float32
keeps sub-millimetre precision). Occupancy is ``hits / visits``; a cell never
visited is unknown. The whole structure is plain arrays so compiled kernels
(:mod:`slam2d.matching.hill_climb`) read every particle's map at once.

Cell ``(row, col)`` covers world ``[ox + col*res, ox + (col+1)*res) x
[oy + row*res, ...)``, like :class:`~slam2d.grids.occupancy.OccupancyGrid`;
the table grows (by whole tiles, data keeps its world position) when a scan
reaches its border.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

from slam2d.core.memory import check_allocation
from slam2d.grids.raycast import trace_ray

__all__ = ["TiledMaps", "TILE_SHIFT", "TILE", "HITS", "VISITS", "SUM_X", "SUM_Y", "FULLNESS"]

# 16 x 16 cells: 4 KB a tile, 0.8 m at 5 cm. A particle copies a whole tile to change one cell
# of it, so smaller tiles copy less; trajectories do not depend on the size (bit for bit).
# slam2d.matching.hill_climb compiles TILE_SHIFT in as a constant and numba's cache only
# checks that file's own timestamp: after changing it, touch hill_climb.py.
TILE_SHIFT = 4
TILE = 1 << TILE_SHIFT
_MASK = TILE - 1
HITS, VISITS, SUM_X, SUM_Y = 0, 1, 2, 3
FULLNESS = 0.1  # GMapping m_fullnessThreshold: a cell with hits/visits above it is occupied


@njit(cache=True, inline="always")
def cell_tile(table, p, row, col):
    """Pool index of the tile holding cell ``(row, col)`` of map ``p``; -1 unknown or outside."""
    tr = row >> TILE_SHIFT
    tc = col >> TILE_SHIFT
    if row < 0 or col < 0 or tr >= table.shape[1] or tc >= table.shape[2]:
        return -1
    return table[p, tr, tc]


@njit(cache=True)
def _make_writable(pool, occ, refs, free, n_free, table, p, tr, tc):
    """Give map ``p`` a tile at ``(tr, tc)`` it owns alone; returns the new free count."""
    t = table[p, tr, tc]
    if t >= 0 and refs[t] == 1:
        return n_free
    n_free -= 1
    new = free[n_free]
    if t >= 0:
        pool[new] = pool[t]
        occ[new] = occ[t]
        refs[t] -= 1
    else:
        pool[new] = 0.0
        occ[new] = 0
    refs[new] = 1
    table[p, tr, tc] = new
    return n_free


@njit(cache=True)
def _register(
    pool, occ, refs, free, n_free, table, mark, touched,
    part, laser_poses, ranges, cos_a, sin_a,
    ox, oy, res, max_range, usable_range, generate_map, start, rows_buf, cols_buf,
):
    """Add scan ``m`` (``ranges[m]`` from ``laser_poses[m]``) to map ``part[m]`` for m >= start.

    GMapping's ``registerScan``: beams beyond ``max_range`` (or NaN) are
    skipped; longer than ``usable_range`` they are cut there and give no hit.
    With ``generate_map`` the cells a beam crosses get a visit (free space),
    else only end cells are touched (what the filter's particles do).
    Returns ``(next m to do, n_free, tiles that scan needs)``: it stops before
    a scan whose tiles would not fit in the free list, so the caller can grow
    the pool.
    """
    M = laser_poses.shape[0]
    B = cos_a.shape[0]
    end_x = np.empty(B)
    end_y = np.empty(B)
    for m in range(start, M):
        p = part[m]
        lx, ly, lth = laser_poses[m, 0], laser_poses[m, 1], laser_poses[m, 2]
        c, s = math.cos(lth), math.sin(lth)
        # beam end points (cut at the usable range); NaN for beams not used
        for j in range(B):
            r = ranges[m, j]
            if not (r > 0.0) or r > max_range:
                end_x[j] = np.nan
                continue
            d = min(r, usable_range)
            end_x[j] = lx + d * (c * cos_a[j] - s * sin_a[j])
            end_y[j] = ly + d * (s * cos_a[j] + c * sin_a[j])
        # pass 1: tiles this scan writes, and how many need a fresh tile
        n_touched = 0
        need = 0
        for j in range(B):
            ex, ey, r = end_x[j], end_y[j], ranges[m, j]
            if math.isnan(ex):
                continue
            if generate_map:
                count = trace_ray(lx, ly, ex, ey, ox, oy, res, rows_buf, cols_buf)
            else:
                rows_buf[0] = int(math.floor((ey - oy) / res))
                cols_buf[0] = int(math.floor((ex - ox) / res))
                count = 1 if r < usable_range else 0
            for k in range(count):
                tr = rows_buf[k] >> TILE_SHIFT
                tc = cols_buf[k] >> TILE_SHIFT
                if mark[tr, tc] == 0:
                    mark[tr, tc] = 1
                    touched[n_touched, 0] = tr
                    touched[n_touched, 1] = tc
                    n_touched += 1
                    t = table[p, tr, tc]
                    if t < 0 or refs[t] > 1:
                        need += 1
        for k in range(n_touched):
            mark[touched[k, 0], touched[k, 1]] = 0
        if need > n_free:
            return m, n_free, need
        for k in range(n_touched):
            n_free = _make_writable(pool, occ, refs, free, n_free, table, p, touched[k, 0], touched[k, 1])
        # pass 2: the updates
        for j in range(B):
            ex, ey, r = end_x[j], end_y[j], ranges[m, j]
            if math.isnan(ex):
                continue
            if generate_map:
                count = trace_ray(lx, ly, ex, ey, ox, oy, res, rows_buf, cols_buf)
                for k in range(count - 1):
                    row, col = rows_buf[k], cols_buf[k]
                    t = table[p, row >> TILE_SHIFT, col >> TILE_SHIFT]
                    cell = pool[t, row & _MASK, col & _MASK]
                    cell[VISITS] += 1.0
                    occ[t, row & _MASK, col & _MASK] = cell[HITS] > FULLNESS * cell[VISITS]
            if r < usable_range:
                row = int(math.floor((ey - oy) / res))
                col = int(math.floor((ex - ox) / res))
                t = table[p, row >> TILE_SHIFT, col >> TILE_SHIFT]
                cell = pool[t, row & _MASK, col & _MASK]
                cell[HITS] += 1.0
                cell[VISITS] += 1.0
                cell[SUM_X] += ex - (ox + (col + 0.5) * res)
                cell[SUM_Y] += ey - (oy + (row + 0.5) * res)
                occ[t, row & _MASK, col & _MASK] = cell[HITS] > FULLNESS * cell[VISITS]
    return M, n_free, 0


@njit(cache=True)
def _resample(table, refs, free, n_free, indices):
    """Tables of the particles ``indices`` (with repeats), reference counts adjusted."""
    n, tr, tc = table.shape
    new = np.empty((indices.shape[0], tr, tc), dtype=table.dtype)
    for i in range(indices.shape[0]):
        new[i] = table[indices[i]]
        for a in range(tr):
            for b in range(tc):
                t = new[i, a, b]
                if t >= 0:
                    refs[t] += 1
    for i in range(n):
        for a in range(tr):
            for b in range(tc):
                t = table[i, a, b]
                if t >= 0:
                    refs[t] -= 1
                    if refs[t] == 0:
                        free[n_free] = t
                        n_free += 1
    return new, n_free


@njit(cache=True)
def _dense(pool, table, p, r0, c0, rows, cols):
    """``hits`` and ``visits`` of map ``p`` over cells ``[r0, r0+rows) x [c0, c0+cols)``."""
    hits = np.zeros((rows, cols), dtype=np.float32)
    visits = np.zeros((rows, cols), dtype=np.float32)
    for a in range(table.shape[1]):
        for b in range(table.shape[2]):
            t = table[p, a, b]
            if t < 0:
                continue
            for i in range(TILE):
                row = (a << TILE_SHIFT) + i - r0
                if row < 0 or row >= rows:
                    continue
                for j in range(TILE):
                    col = (b << TILE_SHIFT) + j - c0
                    if 0 <= col < cols:
                        hits[row, col] = pool[t, i, j, HITS]
                        visits[row, col] = pool[t, i, j, VISITS]
    return hits, visits


class TiledMaps:
    """``n`` GMapping-style maps (hits, visits, mean hit point per cell) sharing tiles copy-on-write.

    Args:
        n: number of maps (particles).
        resolution: cell size, metres.
        bounds: ``(xmin, ymin, xmax, ymax)`` the table covers at first (it grows).
        capacity: tiles allocated in the pool at first (it doubles when full).
    """

    def __init__(
        self, n: int, resolution: float, bounds: tuple[float, float, float, float], capacity: int = 256
    ) -> None:
        self.resolution = float(resolution)
        span = TILE * self.resolution
        xmin, ymin, xmax, ymax = bounds
        # the origin sits on a tile boundary of a lattice anchored at world 0
        tx0, ty0 = math.floor(xmin / span), math.floor(ymin / span)
        tx1, ty1 = math.floor(xmax / span), math.floor(ymax / span)
        self.origin = (tx0 * span, ty0 * span)
        check_allocation(self.estimate_bytes(n, resolution, bounds, capacity),
                         f"{n} particle maps in {resolution:g} m cells", "particles, delta")
        self.table = np.full((n, ty1 - ty0 + 1, tx1 - tx0 + 1), -1, dtype=np.int32)
        self.pool = np.zeros((capacity, TILE, TILE, 4), dtype=np.float32)
        # occupied flags (hits/visits > FULLNESS) beside the pool: the matcher tests these
        # for every cell it looks at, and 1 KB a tile stays in cache where 16 KB would not
        self.occ = np.zeros((capacity, TILE, TILE), dtype=np.bool_)
        self.refs = np.zeros(capacity, dtype=np.int32)
        self.free = np.arange(capacity - 1, -1, -1, dtype=np.int32)
        self.n_free = capacity
        self._mark = np.zeros(self.table.shape[1:], dtype=np.uint8)
        self._touched = np.zeros((self._mark.size, 2), dtype=np.int64)
        self.peak_tiles = 0

    @staticmethod
    def estimate_bytes(n: int, resolution: float, bounds: tuple[float, float, float, float],
                       capacity: int = 256) -> int:
        """Bytes the maps take at first: each particle's tile table over ``bounds`` and the first tiles."""
        span = TILE * float(resolution)
        xmin, ymin, xmax, ymax = bounds
        cols = math.floor(xmax / span) - math.floor(xmin / span) + 1
        rows = math.floor(ymax / span) - math.floor(ymin / span) + 1
        return n * rows * cols * 4 + capacity * TILE * TILE * 17

    # ----------------------------------------------------------------- size and sharing

    @property
    def n(self) -> int:
        return int(self.table.shape[0])

    @property
    def tiles_in_use(self) -> int:
        return int(self.pool.shape[0] - self.n_free)

    @property
    def tile_references(self) -> int:
        """Table entries pointing at a tile: the tiles the maps would hold if none were shared."""
        return int(np.count_nonzero(self.table >= 0))

    @property
    def nbytes(self) -> int:
        return int(self.pool.nbytes + self.occ.nbytes + self.table.nbytes + self.refs.nbytes + self.free.nbytes)

    def _grow_pool(self, at_least: int) -> None:
        cap = self.pool.shape[0]
        extra = max(at_least, cap, 64)
        per_tile = TILE * TILE * (4 * 4 + 1) + 8
        check_allocation((cap + extra) * per_tile,
                         f"{cap + extra} map tiles of {TILE * self.resolution:g} m for {self.n} particles",
                         "particles, delta")
        # np.zeros takes zero pages the OS maps on first write: the unused part of the new
        # pool costs no memory until tiles are handed out (np.concatenate would write it all)
        pool = np.zeros((cap + extra,) + self.pool.shape[1:], np.float32)
        pool[:cap] = self.pool
        occ = np.zeros((cap + extra,) + self.occ.shape[1:], np.bool_)
        occ[:cap] = self.occ
        refs = np.zeros(cap + extra, np.int32)
        refs[:cap] = self.refs
        self.pool, self.occ, self.refs = pool, occ, refs
        # new tiles go on the stack below the free ones (order does not matter)
        free = np.empty(cap + extra, dtype=np.int32)
        free[:extra] = np.arange(cap + extra - 1, cap - 1, -1, dtype=np.int32)
        free[extra : extra + self.n_free] = self.free[: self.n_free]
        self.free = free
        self.n_free += extra

    def ensure_covers(self, xmin: float, ymin: float, xmax: float, ymax: float) -> bool:
        """Grow every table so the world box is inside; True if it grew."""
        span = TILE * self.resolution
        ox, oy = self.origin
        _, rows, cols = self.table.shape
        tx0, ty0 = math.floor((xmin - ox) / span), math.floor((ymin - oy) / span)
        tx1, ty1 = math.floor((xmax - ox) / span), math.floor((ymax - oy) / span)
        if tx0 >= 0 and ty0 >= 0 and tx1 < cols and ty1 < rows:
            return False
        # grow by at least a quarter of the size on a side that must grow (few reallocations)
        left = max(0, -tx0) and max(-tx0, cols // 4 + 1)
        below = max(0, -ty0) and max(-ty0, rows // 4 + 1)
        right = max(0, tx1 - cols + 1) and max(tx1 - cols + 1, cols // 4 + 1)
        above = max(0, ty1 - rows + 1) and max(ty1 - rows + 1, rows // 4 + 1)
        n, rows, cols = self.table.shape
        check_allocation(n * (rows + below + above) * (cols + left + right) * 4,
                         f"the tile tables of {n} particles over {(cols + left + right) * span:.4g} m x "
                         f"{(rows + below + above) * span:.4g} m", "particles, delta")
        self.table = np.pad(self.table, ((0, 0), (below, above), (left, right)), constant_values=-1)
        self.origin = (ox - left * span, oy - below * span)
        self._mark = np.zeros(self.table.shape[1:], dtype=np.uint8)
        self._touched = np.zeros((self._mark.size, 2), dtype=np.int64)
        return True

    # ----------------------------------------------------------------- updates

    def register(
        self,
        particles: NDArray[np.int64],
        laser_poses: NDArray[np.float64],
        ranges: NDArray[np.float64],
        angles: NDArray[np.float64],
        *,
        max_range: float,
        usable_range: float,
        generate_map: bool,
    ) -> None:
        """Add scan ``ranges[m]`` seen from ``laser_poses[m]`` to map ``particles[m]``, for every m.

        ``ranges`` is ``(M, beams)`` (a broadcast view of one scan is fine).
        See :func:`_register` for the GMapping rules.
        """
        laser_poses = np.ascontiguousarray(laser_poses, dtype=np.float64).reshape(-1, 3)
        if laser_poses.shape[0] == 0:
            return
        reach = min(float(np.nanmax(np.where(ranges <= max_range, ranges, 0.0), initial=0.0)), usable_range)
        self.ensure_covers(
            float(laser_poses[:, 0].min()) - reach - 1.0, float(laser_poses[:, 1].min()) - reach - 1.0,
            float(laser_poses[:, 0].max()) + reach + 1.0, float(laser_poses[:, 1].max()) + reach + 1.0,
        )
        cells = int(math.ceil(reach / self.resolution)) + 2
        rows_buf = np.empty(2 * cells + 4, dtype=np.int64)
        cols_buf = np.empty(2 * cells + 4, dtype=np.int64)
        part = np.ascontiguousarray(particles, dtype=np.int64)
        a = np.asarray(angles, dtype=np.float64)
        cos_a, sin_a = np.cos(a), np.sin(a)
        r = np.nan_to_num(np.asarray(ranges, dtype=np.float64), nan=-1.0)
        start = 0
        while True:
            start, self.n_free, need = _register(
                self.pool, self.occ, self.refs, self.free, self.n_free, self.table, self._mark, self._touched,
                part, laser_poses, r, cos_a, sin_a, self.origin[0], self.origin[1], self.resolution,
                float(max_range), float(usable_range), bool(generate_map), start, rows_buf, cols_buf,
            )
            if start >= part.shape[0]:
                break
            self._grow_pool(need)
        self.peak_tiles = max(self.peak_tiles, self.tiles_in_use)

    def resample(self, indices: NDArray[np.int64]) -> None:
        """Map ``i`` becomes a (shared) copy of old map ``indices[i]``."""
        idx = np.ascontiguousarray(indices, dtype=np.int64)
        self.table, self.n_free = _resample(self.table, self.refs, self.free, self.n_free, idx)

    # ----------------------------------------------------------------- reading

    def dense(self, p: int) -> tuple[NDArray[np.float32], NDArray[np.float32], tuple[float, float]]:
        """``(hits, visits, origin)`` of map ``p`` cropped to its allocated tiles (empty if none)."""
        used = np.argwhere(self.table[p] >= 0)
        if used.size == 0:
            return np.zeros((0, 0), np.float32), np.zeros((0, 0), np.float32), self.origin
        (a0, b0), (a1, b1) = used.min(axis=0), used.max(axis=0)
        r0, c0 = int(a0) * TILE, int(b0) * TILE
        rows, cols = (int(a1) - int(a0) + 1) * TILE, (int(b1) - int(b0) + 1) * TILE
        hits, visits = _dense(self.pool, self.table, int(p), r0, c0, rows, cols)
        ox, oy = self.origin
        return hits, visits, (ox + c0 * self.resolution, oy + r0 * self.resolution)
