"""``known-poses``: scans placed at a given trajectory (ground truth or a reference).

Not SLAM: the upper bound of map quality for a trajectory, and the way to turn
a reference trajectory into a map next to the methods' maps.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from slam2d.core.frames import Frame
from slam2d.errors import InputError
from slam2d.grids.occupancy import GridParams, OccupancyGrid
from slam2d.io.tum import by_time, interpolate_poses, read_tum
from slam2d.methods.base import SlamMethod
from slam2d.methods.registry import register
from slam2d.params import param

__all__ = ["KnownPosesParams", "KnownPoses"]


@dataclass
class KnownPosesParams(GridParams):
    """The trajectory to map along, and the map's layout."""

    poses: str | None = param(
        None,
        help="TUM trajectory of the robot base (t x y z qx qy qz qw); 'slam2d compare' fills in the "
        "truth or reference it is given",
    )
    max_pose_gap: float = param(
        1.0, unit="s", low=0.0,
        help="a scan further than this from the nearest pose, or between two poses further apart, is skipped",
    )


@register
class KnownPoses(SlamMethod):
    name = "known-poses"
    Params = KnownPosesParams
    summary = "scans placed at a given trajectory: the map a perfect method would make"
    uses_odometry = False
    DIAGNOSTICS = {"cells_updated": "grid cells the scan changed [cells]"}

    def __init__(self, params: KnownPosesParams | None = None, **kwargs) -> None:
        super().__init__(params, **kwargs)
        if not self.params.poses:
            raise InputError("known-poses needs a trajectory: set poses=FILE.tum", field="poses")
        times, poses = read_tum(self.params.poses)
        self._given_times, self._given_poses = by_time(times, poses)
        self._grid = OccupancyGrid(self.params)
        self._pose: NDArray[np.float64] | None = None

    def update(self, frame: Frame) -> Mapping[str, float] | None:
        pose, valid = interpolate_poses(self._given_times, self._given_poses, frame.timestamp, self.params.max_pose_gap)
        if not valid[0]:
            self._pose = None
            self.diagnostics.count("frames_without_pose")
            return None
        self._pose = pose[0]
        return {"cells_updated": self._grid.integrate(frame.scan, self._pose)}

    def current_pose(self) -> NDArray[np.float64] | None:
        return self._pose

    def map(self) -> OccupancyGrid:
        return self._grid
