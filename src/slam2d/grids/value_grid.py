"""A growing grid of small integer cell values: the map store of CoreSLAM and CRSM.

Both lightweight methods keep their map as plain integers (CoreSLAM 16-bit,
CRSM 8-bit) rather than log-odds, and read it in their compiled matchers. This
class holds such an array with the layout the rest of slam2d uses
(``values[row, col]``, row along world y, ``origin`` = world position of the
lower-left corner of cell ``[0, 0]``) and grows it when the robot nears an
edge. The origin always moves by whole cells from world ``(0, 0)``, so a cell
keeps its world position when the grid grows.

:meth:`ValueGrid.to_occupancy_grid` turns the values, cropped to the cells
ever written, into the :class:`~slam2d.grids.occupancy.OccupancyGrid` every
method hands out.
"""

from __future__ import annotations

import copy
import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

from slam2d.core.memory import check_allocation
from slam2d.errors import InputError
from slam2d.grids.occupancy import GridParams, OccupancyGrid, growth_step

__all__ = ["ValueGrid"]


@njit(cache=True)
def _written_box(values, fill):
    """``(r0, r1, c0, c1)`` (end exclusive) of the cells not equal to ``fill``; r0 = r1 = 0 when none."""
    rows, cols = values.shape
    r0, r1, c0, c1 = rows, -1, cols, -1
    for r in range(rows):
        for c in range(cols):
            if values[r, c] != fill:
                r0 = min(r0, r)
                r1 = max(r1, r)
                c0 = min(c0, c)
                c1 = max(c1, c)
    if r1 < 0:
        return 0, 0, 0, 0
    return r0, r1 + 1, c0, c1 + 1


class ValueGrid:
    """A growing ``(rows, cols)`` integer array, filled with ``fill`` where nothing was seen.

    Args:
        resolution: cell size, metres.
        fill: the value of a cell never updated ("unknown").
        dtype: numpy integer dtype of the cells.
        grow_margin: cells added beyond a requested box when the grid must grow.
        max_extent: largest width or height in metres; beyond it an :class:`InputError`
            (corrupt poses or ranges).
    """

    def __init__(
        self, resolution: float, fill: int, dtype: type, *, grow_margin: int = 64, max_extent: float = 2000.0
    ) -> None:
        self.resolution = float(resolution)
        self.fill = int(fill)
        self.grow_margin = int(grow_margin)
        self.max_extent = float(max_extent)
        self.values: NDArray = np.full((0, 0), fill, dtype=dtype)
        self._row0 = 0  # cell [0, 0]'s offset from world (0, 0), in cells
        self._col0 = 0

    @property
    def origin(self) -> tuple[float, float]:
        """World ``(x, y)`` of the lower-left corner of cell ``[0, 0]``, metres."""
        return self._col0 * self.resolution, self._row0 * self.resolution

    @property
    def shape(self) -> tuple[int, int]:
        return self.values.shape  # type: ignore[return-value]

    def ensure_contains(self, xmin: float, ymin: float, xmax: float, ymax: float, margin: int = 2) -> bool:
        """Grow so the world box plus ``margin`` cells lies inside; True if the grid grew.

        A side that grows gains :func:`~slam2d.grids.occupancy.growth_step` cells
        (at least ``grow_margin``, half the grid's size up to a cap), so a robot
        driving off an edge causes few copies.
        """
        if not all(math.isfinite(v) for v in (xmin, ymin, xmax, ymax)):
            raise ValueError(f"bounds {(xmin, ymin, xmax, ymax)!r} are not finite")
        res = self.resolution
        r0 = math.floor(ymin / res) - margin
        c0 = math.floor(xmin / res) - margin
        r1 = math.floor(ymax / res) + margin
        c1 = math.floor(xmax / res) + margin
        rows, cols = self.shape
        h0, w0 = self._row0, self._col0
        h1, w1 = h0 + rows - 1, w0 + cols - 1
        if rows and cols and r0 >= h0 and c0 >= w0 and r1 <= h1 and c1 <= w1:
            return False
        if rows and cols:
            gr = growth_step(rows, self.grow_margin, res)
            gc = growth_step(cols, self.grow_margin, res)
            n_r0 = r0 - gr if r0 < h0 else h0
            n_c0 = c0 - gc if c0 < w0 else w0
            n_r1 = r1 + gr if r1 > h1 else h1
            n_c1 = c1 + gc if c1 > w1 else w1
        else:
            n_r0, n_c0, n_r1, n_c1 = r0, c0, r1, c1
        n_rows, n_cols = n_r1 - n_r0 + 1, n_c1 - n_c0 + 1
        if max(n_rows, n_cols) * res > self.max_extent:
            raise InputError(
                f"the map would grow to {n_cols * res:.6g} m x {n_rows * res:.6g} m, beyond the limit of "
                f"{self.max_extent:g} m (poses or ranges are probably corrupt; raise max_extent if they are not)",
                field="max_extent",
            )
        check_allocation(n_rows * n_cols * self.values.dtype.itemsize,
                         f"a map of {n_cols * res:.4g} m x {n_rows * res:.4g} m in {res:g} m cells", "resolution")
        values = np.full((n_rows, n_cols), self.fill, dtype=self.values.dtype)
        if rows and cols:
            dr, dc = h0 - n_r0, w0 - n_c0
            values[dr : dr + rows, dc : dc + cols] = self.values
        self.values = values
        self._row0, self._col0 = n_r0, n_c0
        return True

    def occupancy_of(self, values: NDArray) -> NDArray[np.int8]:
        """Occupancy (0..100, -1 unknown) of cell values; each map kind says how."""
        raise NotImplementedError

    def occupancy(self) -> NDArray[np.int8]:
        """Occupancy (0..100, -1 unknown) of every cell."""
        return self.occupancy_of(self.values)

    @property
    def observed(self) -> NDArray[np.bool_]:
        """True for cells ever written."""
        return self.values != self.values.dtype.type(self.fill)

    def occupied(self, threshold: float = 0.65) -> NDArray[np.bool_]:
        """True for cells whose occupancy (0..100) is at least ``100 * threshold``."""
        occ = self.occupancy()
        return (occ >= 100.0 * threshold) & (occ <= 100)

    def crop_to_observed(self, margin: int = 1) -> ValueGrid:
        """A copy trimmed to the cells ever written plus ``margin`` unwritten cells around them.

        What a run folder writes of a CoreSLAM or CRSM map: a diverged run grows the map to hundreds of
        metres a side, and the written part is a fraction (crsm on fr101: 43 of 130 million cells).
        """
        rows, cols = self.shape
        r0, r1, c0, c1 = _written_box(self.values, self.values.dtype.type(self.fill)) if rows and cols else (0,) * 4
        out = copy.copy(self)  # (a shallow copy: the subclasses' own settings come along)
        if r1 == 0:
            out.values = np.full((0, 0), self.fill, dtype=self.values.dtype)
            return out
        r0, r1, c0, c1 = r0 - margin, r1 + margin, c0 - margin, c1 + margin
        if (r0, r1, c0, c1) == (0, rows, 0, cols):
            return self  # already cropped: no copy
        out.values = np.full((r1 - r0, c1 - c0), self.fill, dtype=self.values.dtype)
        sr0, sr1, sc0, sc1 = max(r0, 0), min(r1, rows), max(c0, 0), min(c1, cols)
        out.values[sr0 - r0 : sr1 - r0, sc0 - c0 : sc1 - c0] = self.values[sr0:sr1, sc0:sc1]
        out._row0, out._col0 = self._row0 + r0, self._col0 + c0
        return out

    def to_occupancy_grid(self, params: GridParams | None = None, margin: int = 1) -> OccupancyGrid:
        """An :class:`OccupancyGrid` of the cells ever written plus ``margin`` around them.

        Cropped before it is converted: the float copies of all of a diverged map took 2.5 GB (crsm on fr101).
        """
        params = params if params is not None else GridParams(resolution=self.resolution)
        cropped = self.crop_to_observed(margin)
        if not cropped.values.size:
            return OccupancyGrid.from_occupancy(np.full((0, 0), -1, np.int8), self.resolution, self.origin, params)
        return OccupancyGrid.from_occupancy(cropped.occupancy(), self.resolution, cropped.origin, params)
