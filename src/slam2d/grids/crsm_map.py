"""The CRSM SLAM map: 8-bit cells, 127 unknown, towards 255 free and towards 0 occupied.

The update (CRSM's ``updateMapProbabilities``) walks each beam one cell length
at a time, ``R = 1 .. r + 2`` (``r`` the measured range in cells), and

* raises cells before the endpoint (``R < r``) by ``g``,
* lowers the cells at ``R = r - 1`` and ``R = r`` by ``g * obstacle_density``
  (so ``r - 1`` gets both, a net decrease),

with ``g = (1 - sqrt(|v - 127| / 128)) * mean_density * density``: a cell far
from 127 (already sure) moves little, and ``mean_density`` (the scan's mean
jump between neighbouring ranges, clamped to [0.04, 0.2]) makes a structured,
jagged scan write harder than a smooth one. Cells are integers and every
step truncates, as the original's ``int += float`` does, so small gains on
sure cells vanish and free cells settle below 255.

Beams whose endpoint falls in the same laser-frame cell as an earlier beam's
are skipped (the original keeps a set of them); beams with no return are
skipped.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

from slam2d.core.arrays import lookup_by_band
from slam2d.grids.value_grid import ValueGrid

__all__ = ["CrsmMap", "UNKNOWN", "crsm_update", "GAIN_TABLE", "first_beam_per_cell", "marked_endpoints"]

UNKNOWN = 127

#: 1 - sqrt(|v - 127| / 128) for every cell value v: the certainty damping of the update.
GAIN_TABLE = 1.0 - np.sqrt(np.abs(np.arange(256, dtype=np.float64) - 127.0) / 128.0)


@njit(cache=True)
def crsm_update(values, origin_x, origin_y, resolution, lx, ly, ltheta, ranges, angles, use, gain,
                mean_density, density, obstacle_density):
    """Apply one scan to ``values`` (uint8, in place) from the laser pose; returns the cells walked."""
    rows, cols = values.shape
    inv = 1.0 / resolution
    bx = (lx - origin_x) * inv
    by = (ly - origin_y) * inv
    free_gain = mean_density * density
    walked = 0
    for i in range(ranges.shape[0]):
        if not use[i]:
            continue
        d_cells = int(ranges[i] * inv)
        a = ltheta + angles[i]
        ca = math.cos(a)
        sa = math.sin(a)
        for step in range(1, d_cells + 3):
            col = int(math.floor(step * ca + bx))
            row = int(math.floor(step * sa + by))
            if row < 0 or col < 0 or row >= rows or col >= cols:
                break
            tt = np.int64(values[row, col])
            g = gain[tt] * free_gain
            if d_cells > step:
                tt = np.int64(tt + g)  # truncation, as the original's int += float
            if d_cells - 2 < step < d_cells + 1:
                tt = np.int64(tt - g * obstacle_density)
            values[row, col] = min(max(tt, 0), 255)
            walked += 1
    return walked


@njit(cache=True)
def first_beam_per_cell(d, cos_a, sin_a, resolution):
    """The beams the update walks: those with a return (``d > 0``) whose laser-frame endpoint cell
    (``trunc(d cos / resolution)``, ``trunc(d sin / resolution)``) no earlier beam's is (the original keeps a set).

    ``cos_a``, ``sin_a``: the beam angles' cosines and sines. A stable sort of the cell keys finds each cell's
    first beam without a Python-level set.
    """
    n = d.shape[0]
    low = np.iinfo(np.int64).min
    keys = np.empty(n, dtype=np.int64)
    for i in range(n):
        if d[i] > 0:
            keys[i] = np.int64(np.trunc(d[i] * cos_a[i] / resolution)) * 1_000_003 + np.int64(
                np.trunc(d[i] * sin_a[i] / resolution))
        else:
            keys[i] = low
    order = np.argsort(keys, kind="mergesort")
    use = np.zeros(n, dtype=np.bool_)
    for j in range(n):
        i = order[j]
        if d[i] > 0 and (j == 0 or keys[i] != keys[order[j - 1]]):
            use[i] = True
    return use


@njit(cache=True)
def marked_endpoints(d, cos_a, sin_a, resolution, mount_x, mount_y, mount_cos, mount_sin):
    """Robot-frame endpoints ``(x, y)`` of every beam, truncated to whole cells in the laser frame as the update
    marks them (``trunc(d / resolution * cos) * resolution``, then the laser's mount pose applied).

    The same floating-point steps as :func:`slam2d.methods.crsm.ray_points`, in one pass over the beams.
    """
    n = d.shape[0]
    x = np.empty(n)
    y = np.empty(n)
    for i in range(n):
        r = d[i] / resolution
        px = np.trunc(r * cos_a[i]) * resolution
        py = np.trunc(r * sin_a[i]) * resolution
        x[i] = mount_x + mount_cos * px - mount_sin * py
        y[i] = mount_y + mount_sin * px + mount_cos * py
    return x, y


class CrsmMap(ValueGrid):
    """A growing CRSM map (uint8; 127 unknown, 255 free, low values occupied)."""

    def __init__(self, resolution: float, *, grow_margin: int = 100, max_extent: float = 2000.0) -> None:
        super().__init__(resolution, UNKNOWN, np.uint8, grow_margin=grow_margin, max_extent=max_extent)

    def draw_patch(self, pose: NDArray[np.float64], length: float, width: float, value: int = 200) -> None:
        """Mark the robot's footprint (axis-aligned at ``pose``) as nearly free, as CRSM's initial patch."""
        x, y = float(pose[0]), float(pose[1])
        self.ensure_contains(x - length / 2, y - width / 2, x + length / 2, y + width / 2)
        ox, oy = self.origin
        r = self.resolution
        c0, c1 = math.floor((x - length / 2 - ox) / r), math.floor((x + length / 2 - ox) / r)
        r0, r1 = math.floor((y - width / 2 - oy) / r), math.floor((y + width / 2 - oy) / r)
        self.values[r0 : r1 + 1, c0 : c1 + 1] = value

    def update(
        self,
        laser_pose: NDArray[np.float64],
        ranges: NDArray[np.float64],
        angles: NDArray[np.float64],
        use: NDArray[np.bool_],
        *,
        mean_density: float,
        density: float,
        obstacle_density: float,
        margin: int = 50,
    ) -> int:
        """Apply one scan (laser-frame ``ranges``, ``angles``; ``use`` the beams to walk); returns cells walked."""
        if not use.any():
            return 0
        lx, ly, lt = (float(v) for v in laser_pose)
        reach = float(ranges[use].max()) + 3.0 * self.resolution
        self.ensure_contains(lx - reach, ly - reach, lx + reach, ly + reach, margin=margin)
        ox, oy = self.origin
        return int(
            crsm_update(
                self.values, ox, oy, self.resolution, lx, ly, lt,
                np.ascontiguousarray(ranges, dtype=np.float64), np.ascontiguousarray(angles, dtype=np.float64),
                np.ascontiguousarray(use), GAIN_TABLE, float(mean_density), float(density), float(obstacle_density),
            )
        )

    def occupancy_of(self, values: NDArray) -> NDArray[np.int8]:
        """The original's published map: above 128 free (0), below 126 occupied (100), else unknown (-1)."""
        table = np.full(256, -1, dtype=np.int8)
        table[129:] = 0
        table[:126] = 100
        return lookup_by_band(table, values)
