"""Mapping with known poses: integrate every scan of a recording at a given trajectory.

This is how a trajectory is turned into a map (from a SLAM method, a reference
file or raw odometry), and how map quality is compared between trajectories.
"""

from __future__ import annotations

import time
from collections.abc import Iterable
from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from slam2d.core.frames import Frame
from slam2d.errors import InputError
from slam2d.grids.occupancy import GridParams, OccupancyGrid
from slam2d.io.base import ProgressCallback
from slam2d.io.tum import by_time, poses_at_scans

__all__ = ["MappingStats", "map_from_poses"]

# Room left around the trajectory when the grid is first sized (it still grows).
_PRESIZE_MARGIN = 10.0


@dataclass
class MappingStats:
    """What :func:`map_from_poses` did."""

    frames: int = 0  # frames read
    scans_used: int = 0  # scans added to the map
    scans_skipped: int = 0  # scans without a pose: the sum of the next three
    outside_trajectory: int = 0  # scans before the first or after the last pose
    in_pose_gap: int = 0  # scans between two poses further apart than max_pose_gap
    no_odometry: int = 0  # scans without odometry (when mapping along odometry)
    beams: int = 0  # beams of the scans used
    poses_out_of_order: int = 0  # trajectory timestamps that stepped back (sorted before use)
    seconds: float = 0.0  # wall time, reading included

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


def _check_trajectory(
    pose_times: ArrayLike, poses: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64], int]:
    t = np.asarray(pose_times, dtype=np.float64).reshape(-1)
    p = np.asarray(poses, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError(
            f"expected an (N, 3) array of [x, y, theta], got shape {p.shape}", field="poses"
        )
    if p.shape[0] != t.shape[0]:
        raise InputError(f"{t.shape[0]} timestamps for {p.shape[0]} poses", field="pose_times")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(p))):
        raise InputError("the trajectory holds NaN or infinite values", field="poses")
    backwards = int(np.count_nonzero(np.diff(t) < 0.0)) if t.shape[0] > 1 else 0
    # Real logs step back a little (the Intel reference does, 4 times, like
    # its scans): sorted stably, every scan still finds its own pose.
    t, p = by_time(t, p)
    return t, p, backwards


def map_from_poses(
    frames: Iterable[Frame],
    pose_times: ArrayLike | None,
    poses: ArrayLike | None,
    *,
    params: GridParams | None = None,
    max_pose_gap: float = 1.0,
    progress: ProgressCallback | None = None,
) -> tuple[OccupancyGrid, MappingStats]:
    """Build an occupancy grid from scans and the robot's trajectory.

    For each frame, the robot base pose at the scan's timestamp comes from the
    trajectory (``pose_times`` (N,) seconds, ``poses`` (N, 3) ``[x, y, theta]``
    of the robot base in the map frame; see
    :func:`slam2d.io.tum.interpolate_poses`: a scan stamped exactly like a pose
    gets that pose exactly, others are interpolated), and the scan is
    integrated at ``pose ⊕ scan.mount``. Scans outside the trajectory's time
    span, or between two poses more than ``max_pose_gap`` seconds apart, are
    skipped and counted in the returned :class:`MappingStats`. A trajectory
    whose timestamps step back is sorted by time first (and the steps counted).

    With ``pose_times`` and ``poses`` both None, every scan is placed at its
    frame's odometry pose (scans without odometry are skipped and counted):
    the map along the raw odometry.

    ``progress(done, 0)`` is called with the number of frames read so far.
    """
    started = time.perf_counter()
    grid = OccupancyGrid(params)
    along_odometry = pose_times is None and poses is None
    if along_odometry:
        t = p = np.zeros((0,))
        stats = MappingStats()
    else:
        if pose_times is None or poses is None:
            raise InputError(
                "give both pose timestamps and poses, or neither (to map along odometry)",
                field="poses" if poses is None else "pose_times",
            )
        t, p, backwards = _check_trajectory(pose_times, poses)
        stats = MappingStats(poses_out_of_order=backwards)
        if t.shape[0]:
            # Size the grid for the whole trajectory once, so it rarely reallocates.
            margin = grid.params.max_range if grid.params.max_range is not None else _PRESIZE_MARGIN
            lo = p[:, :2].min(axis=0) - margin
            hi = p[:, :2].max(axis=0) + margin
            grid.ensure_contains(lo[0], lo[1], hi[0], hi[1])
    placed = ((frame, None) for frame in frames) if along_odometry else poses_at_scans(frames, t, p, max_pose_gap)
    for frame, pose in placed:
        stats.frames += 1
        scan = frame.scan
        if along_odometry:
            if frame.odometry is None:
                stats.no_odometry += 1
            else:
                pose = frame.odometry
        elif pose is None:
            if t.shape[0] and t[0] <= scan.timestamp <= t[-1]:
                stats.in_pose_gap += 1
            else:
                stats.outside_trajectory += 1
        if pose is not None:
            grid.integrate(scan, pose)
            stats.scans_used += 1
            stats.beams += scan.num_beams
        if progress is not None:
            progress(stats.frames, 0)
    stats.scans_skipped = stats.outside_trajectory + stats.in_pose_gap + stats.no_odometry
    stats.seconds = time.perf_counter() - started
    return grid, stats
