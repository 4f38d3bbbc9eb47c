"""A growing grid of small integer cell values: the map store of CoreSLAM and CRSM.

Both lightweight methods keep their map as plain integers (CoreSLAM 16-bit,
CRSM 8-bit) rather than log-odds, and read it in their compiled matchers. This
class holds such an array with the layout the rest of slam2d uses
(``values[row, col]``, row along world y, ``origin`` = world position of the
lower-left corner of cell ``[0, 0]``) and grows it when the robot nears an
edge. The origin always moves by whole cells from world ``(0, 0)``, so a cell
keeps its world position when the grid grows.

:meth:`ValueGrid.to_occupancy_grid` turns the values into the
:class:`~slam2d.grids.occupancy.OccupancyGrid` every method hands out.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from slam2d.core.memory import check_allocation
from slam2d.errors import InputError
from slam2d.grids.occupancy import GridParams, OccupancyGrid

__all__ = ["ValueGrid"]


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

        A side that grows gains at least ``grow_margin`` cells and half the
        grid's size, so a robot driving off an edge causes few copies.
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
            gr = max(self.grow_margin, rows // 2)
            gc = max(self.grow_margin, cols // 2)
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

    def to_occupancy_grid(self, occupancy: NDArray[np.int8], params: GridParams | None = None) -> OccupancyGrid:
        """An :class:`OccupancyGrid` from per-cell occupancy (0..100, -1 unknown) laid out like this grid."""
        params = params if params is not None else GridParams(resolution=self.resolution)
        return OccupancyGrid.from_occupancy(occupancy, self.resolution, self.origin, params)
