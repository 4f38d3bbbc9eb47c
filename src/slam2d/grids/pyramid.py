"""A pyramid of log-odds occupancy grids, each level half the resolution of the one below.

Multi-resolution scan matchers (Hector SLAM's) match a scan against a coarse
map first, where the basin of convergence is wide, then refine on the finer
levels. Level 0 is the finest (``params.resolution``); level ``i`` has cells
``2**i`` times as large. Every level is an :class:`OccupancyGrid` updated with
the same beams, so each grows on its own as the robot explores.

Matchers read occupancy *probability*, not log-odds, so each level keeps a
float32 probability array next to its grid (0.5 where unknown). After an
update only the window the scan touched is recomputed (the whole array when the grid grew), which
keeps a map update's cost proportional to the scan, not to the map.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from slam2d.grids.occupancy import GridParams, OccupancyGrid

__all__ = ["MapPyramid", "PyramidLevel"]


class PyramidLevel:
    """One level: the grid and its occupancy probability (``unknown`` where never observed)."""

    def __init__(self, grid: OccupancyGrid, unknown: float = 0.5) -> None:
        self.grid = grid
        self.unknown = float(unknown)
        self.probability = self._whole()

    def _whole(self) -> NDArray[np.float32]:
        prob = self.grid.probability()
        if self.unknown != 0.5:
            prob[~self.grid.observed] = self.unknown
        return prob

    @property
    def resolution(self) -> float:
        return self.grid.resolution

    @property
    def origin(self) -> tuple[float, float]:
        return self.grid.origin

    def _refresh(self, xmin: float, ymin: float, xmax: float, ymax: float, grew: bool) -> None:
        if grew or self.probability.shape != self.grid.shape:
            self.probability = self._whole()
            return
        (r0, c0), (r1, c1) = self.grid.world_to_cell([[xmin, ymin], [xmax, ymax]])
        rows, cols = self.grid.shape
        r0, c0 = max(int(r0) - 1, 0), max(int(c0) - 1, 0)
        r1, c1 = min(int(r1) + 2, rows), min(int(c1) + 2, cols)
        window = self.grid.logodds[r0:r1, c0:c1]
        prob = 1.0 / (1.0 + np.exp(-window))
        if self.unknown != 0.5:
            # the grid's own "observed" stamp, read for the window only
            prob[self.grid._stamp[r0:r1, c0:c1] == 0] = self.unknown
        self.probability[r0:r1, c0:c1] = prob


class MapPyramid:
    """``levels`` occupancy grids at ``resolution * 2**i``, updated together.

    ``params`` lays out the finest level; the coarser levels copy it with the
    resolution doubled per level. ``unknown`` is the probability matchers see
    in never-observed cells (0.5: what the log-odds say).
    """

    def __init__(self, params: GridParams | None = None, levels: int = 3, *, unknown: float = 0.5) -> None:
        if levels < 1:
            raise ValueError(f"levels: {levels} must be at least 1")
        params = params if params is not None else GridParams()
        self.levels = [
            PyramidLevel(OccupancyGrid(replace(params, resolution=params.resolution * 2**i)), unknown)
            for i in range(int(levels))
        ]

    def __len__(self) -> int:
        return len(self.levels)

    def __getitem__(self, i: int) -> PyramidLevel:
        return self.levels[i]

    @property
    def finest(self) -> OccupancyGrid:
        return self.levels[0].grid

    def integrate_points(
        self, laser_xy: ArrayLike, points: ArrayLike, *, hits: ArrayLike | None = None
    ) -> int:
        """Add beams from world ``laser_xy`` to world endpoints ``points`` ``(N, 2)`` on every level.

        Returns the number of cells updated on the finest level.
        """
        start = np.asarray(laser_xy, dtype=np.float64).reshape(2)
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        if pts.shape[0]:
            xmin = min(start[0], float(pts[:, 0].min()))
            xmax = max(start[0], float(pts[:, 0].max()))
            ymin = min(start[1], float(pts[:, 1].min()))
            ymax = max(start[1], float(pts[:, 1].max()))
        else:
            xmin = xmax = float(start[0])
            ymin = ymax = float(start[1])
        finest = 0
        for i, level in enumerate(self.levels):
            before = level.grid.shape, level.grid.origin
            n = level.grid.integrate_points(start, pts, hits=hits)
            grew = (level.grid.shape, level.grid.origin) != before
            level._refresh(xmin, ymin, xmax, ymax, grew)
            if i == 0:
                finest = n
        return finest

    def probabilities(self) -> list[NDArray[np.float32]]:
        return [level.probability for level in self.levels]
