"""``odometry``: dead reckoning. The map is drawn along the raw odometry.

The baseline every SLAM method must beat: it shows how far the odometry
drifts, and costs nothing but the map update.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from slam2d.core import se2
from slam2d.core.frames import Frame
from slam2d.grids.occupancy import GridParams, OccupancyGrid
from slam2d.methods.base import SlamMethod
from slam2d.methods.registry import register

__all__ = ["OdometryParams", "Odometry"]


@dataclass
class OdometryParams(GridParams):
    """Only the map's layout: the poses come from the odometry as recorded."""


@register
class Odometry(SlamMethod):
    name = "odometry"
    Params = OdometryParams
    summary = "dead reckoning: scans placed at the raw odometry (the baseline to beat)"
    DIAGNOSTICS = {"cells_updated": "grid cells the scan changed [cells]"}

    def __init__(self, params: OdometryParams | None = None, **kwargs) -> None:
        super().__init__(params, **kwargs)
        self._grid = OccupancyGrid(self.params)
        self._pose: NDArray[np.float64] | None = None
        self._offset: NDArray[np.float64] | None = None  # map <- odometry, after a relocation
        self._put_at: NDArray[np.float64] | None = None

    def _relocate(self, pose: NDArray[np.float64]) -> None:
        self._put_at = pose

    def update(self, frame: Frame) -> Mapping[str, float] | None:
        if frame.odometry is None:
            self._pose = None
            self.diagnostics.count("frames_without_odometry")
            return None
        odom = np.asarray(frame.odometry, dtype=np.float64)
        if self._put_at is not None:
            self._offset, self._put_at = se2.compose(self._put_at, se2.inverse(odom)), None
        self._pose = odom if self._offset is None else se2.compose(self._offset, odom)
        return {"cells_updated": self._grid.integrate(frame.scan, self._pose)}

    def current_pose(self) -> NDArray[np.float64] | None:
        return self._pose

    def map(self) -> OccupancyGrid:
        return self._grid
