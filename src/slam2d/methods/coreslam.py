"""``coreslam``: tinySLAM as BreezySLAM runs it: a hole map matched by random-mutation hill climbing.

Per scan: predict the pose (the last estimate, plus the odometry increment
when ``use_odometry`` is on), search around it with RMHC
(:mod:`slam2d.matching.rmhc`) for the pose where the scan's endpoints sit
deepest in the map's holes, then blend the scan into the map
(:mod:`slam2d.grids.hole_map`) at that pose. No loop closure, no particles.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slam2d.core import se2
from slam2d.core.frames import Frame
from slam2d.grids.hole_map import FREE, HoleMap
from slam2d.grids.occupancy import GridParams, OccupancyGrid
from slam2d.io.tum import interpolate_poses
from slam2d.matching.odometry_gaps import OdometryGapParams
from slam2d.matching.random_numbers import new_state
from slam2d.matching.rmhc import rmhc_match
from slam2d.methods.base import SlamMethod
from slam2d.methods.registry import register
from slam2d.params import param
from slam2d.sensors.beam_model import beam_sigmas

__all__ = ["CoreSlamParams", "CoreSlam"]

# Fewer endpoints than this cannot pin a pose down: the scan is placed at the prediction.
_MIN_POINTS = 10
# An odometry increment longer than this between two scans is a reset or corruption, not motion.
_MAX_ODOMETRY_STEP = 5.0  # m
# The de-skew takes the step between two frames for one sweep's motion: true of a laser's consecutive scans,
# and no scanning laser takes longer than this per turn (an RPLidar A1 at 5.5 Hz: 0.18 s). Frames further
# apart were thinned (a CARMEN log keeps about one scan a metre; fr079 one in 0.24 s of a 75 Hz SICK) and are
# not de-skewed: de-skewing by the whole step put coreslam 23 m off on intel and 4.4 m on fr079.
_LONGEST_SWEEP = 0.2  # s


@dataclass
class CoreSlamParams(OdometryGapParams):
    """BreezySLAM's ``RMHC_SLAM`` defaults, in metres and radians."""

    resolution: float = param(
        0.04, unit="m", low=0.005, high=1.0,
        help="cell size (BreezySLAM's examples: 800 pixels for 32 m)",
    )
    map_quality: int = param(
        50, low=1, high=255,
        help="weight (of 256) a scan gets when blended into a cell; beams with no return use a quarter",
    )
    hole_width: float = param(
        0.6, unit="m", low=0.01, high=10.0,
        help="width of the V-shaped valley drawn around each obstacle (BreezySLAM hole_width_mm = 600)",
    )
    hole_sigmas: float = param(
        3.0, low=0.0, high=20.0,
        help="with a sensor model: a beam's hole half-width is sqrt((hole_width/2)^2 + (hole_sigmas*sigma)^2)",
        advanced=True, group="sensor model",
    )
    sigma_xy: float = param(0.1, unit="m", low=0.0, high=10.0, help="initial spread of the position mutations")
    sigma_theta: float = param(
        math.radians(20.0), unit="rad", low=0.0, high=math.pi, help="initial spread of the heading mutations"
    )
    max_search_iter: int = param(
        1000, low=1, high=10_000_000,
        help="failed mutations that end the search (a third of them, with progress, halve the spread)",
    )
    use_odometry: bool = param(
        False, help="predict each pose with the odometry increment (else: the last pose, BreezySLAM's default)"
    )
    odometry_delay: float = param(
        0.0, unit="s", low=0.0, high=10.0,
        help="how much later than its scan each odometry reading was taken (a laser stamped late): the "
        "prediction and the de-skew use the odometry interpolated this long before each scan's stamp "
        "('slam2d calibrate odometry-lag' measures it)",
        advanced=True, group="prediction",
    )
    motion_model: str = param(
        "none", choices=("none", "constant_velocity"),
        help="prediction without odometry: the last pose (BreezySLAM) or the last pose plus the last matched motion",
        advanced=True, group="prediction",
    )
    refine: bool = param(
        True, help="end each search with a deterministic compass search (one cell and 1/3 cell per 3 m of heading, "
        "halving to 1/8); not in BreezySLAM",
    )
    deskew: str = param(
        "odometry", choices=("none", "odometry", "motion"),
        help="undo the robot's motion during the laser's sweep (one mirror turn per scan period assumed; frames "
        "over 0.2 s apart, a thinned log, are left as they are): "
        "with the odometry increment when it predicts the pose (BreezySLAM), also with the last matched motion "
        "without odometry (motion), or never (none)",
    )
    min_range: float = param(
        0.02, unit="m", low=0.0,
        help="shorter readings are error codes, not returns (the URG-04LX reports errors as 0-20 mm); "
        "the scan's own range_min applies too",
    )
    no_return_range: float | None = param(
        None, unit="m", low=0.0,
        help="beams with no return clear free space up to this range (BreezySLAM's distance_no_detection); "
        "unset: they are skipped",
    )
    grow_margin: int = param(64, unit="cells", low=1, help="the least the map grows by on a side when it must grow",
                             advanced=True, group="map growth")
    max_extent: float = param(
        2000.0, unit="m", low=1.0, help="largest width or height the map may grow to (beyond: corrupt data)",
        advanced=True, group="map growth",
    )


def _endpoints(beams: NDArray[np.float64], ranges: NDArray[np.float64]) -> NDArray[np.float64]:
    """Robot-frame endpoints ``(N, 2)`` of beams with poses ``beams`` (heading = beam direction) and ``ranges``."""
    return np.stack([beams[:, 0] + ranges * np.cos(beams[:, 2]), beams[:, 1] + ranges * np.sin(beams[:, 2])], axis=-1)


@register
class CoreSlam(SlamMethod):
    name = "coreslam"
    Params = CoreSlamParams
    summary = "tinySLAM/BreezySLAM: hole map + random-mutation hill climbing, odometry optional"
    uses_odometry = True
    optional_odometry = True
    stochastic = True
    DIAGNOSTICS = {
        "score": "mean map value under the matched endpoints, 0 = all on obstacles, 1 = all in free space [-]",
        "iterations": "candidate poses scored by the search [-]",
        "halvings": "times the search spread was halved [-]",
        "points": "endpoints matched [-]",
        "cells_updated": "cell writes of the map update [cells]",
    }

    def __init__(self, params: CoreSlamParams | None = None, **kwargs) -> None:
        super().__init__(params, **kwargs)
        p = self.params
        self._map = HoleMap(p.resolution, grow_margin=p.grow_margin, max_extent=p.max_extent)
        self._pose: NDArray[np.float64] | None = None
        self._last_odom: NDArray[np.float64] | None = None  # the odometry at the last scan (delay applied)
        self._odom_times: list[float] = []  # recent odometry readings, for ``odometry_delay``
        self._odom_poses: list[NDArray[np.float64]] = []
        self._step = np.zeros(3)  # the last matched motion, robot frame (constant-velocity prediction)
        self._sweep_step = np.zeros(3)  # the motion over one scan period used to de-skew this scan
        self._last_time: float | None = None  # the last frame's stamp (the step's duration, for the de-skew)
        self._scans_in_map = 0
        self._random = new_state(self.rng)

    def _delayed_odometry(self, frame: Frame) -> NDArray[np.float64] | None:
        """The frame's odometry, or with ``odometry_delay`` the odometry interpolated at its stamp minus the delay."""
        odom = self.usable_odometry(frame)
        delay = self.params.odometry_delay
        if odom is None or delay <= 0.0:
            return odom
        times, poses = self._odom_times, self._odom_poses
        if times and frame.timestamp <= times[-1]:  # time went back or stood still: start the history again
            times.clear()
            poses.clear()
        times.append(float(frame.timestamp))
        poses.append(odom)
        when = frame.timestamp - delay
        while len(times) > 2 and times[1] <= when:  # keep one reading at or before the wanted time
            del times[0], poses[0]
        if when <= times[0]:
            return poses[0]  # the history starts later (the first scans): its oldest reading
        return interpolate_poses(times, poses, when, math.inf)[0][0]

    def _relocate(self, pose: NDArray[np.float64]) -> None:
        self._pose, self._last_odom, self._step = pose.copy(), None, np.zeros(3)
        self._odom_times.clear()
        self._odom_poses.clear()

    def _predict(self, frame: Frame) -> NDArray[np.float64]:
        odom = self._delayed_odometry(frame)
        if self._pose is None:
            start = odom if (self.params.use_odometry and odom is not None) else np.zeros(3)
            pred = np.array(start, dtype=np.float64)
        elif self.params.use_odometry and odom is not None and self._last_odom is not None:
            step, _, is_motion = self.odometry_step(self._last_odom, odom, _MAX_ODOMETRY_STEP, frame.timestamp)
            if is_motion:
                pred = se2.compose(self._pose, step)
                self._sweep_step = step
            else:  # a reset or corrupt reading (counted and warned): predict no motion
                pred = self._pose.copy()
        else:
            if self.params.use_odometry:
                self.diagnostics.count("frames_without_odometry")
            if self.params.motion_model == "constant_velocity":
                pred = se2.compose(self._pose, self._step)
            else:
                pred = self._pose.copy()
        if odom is not None:
            self._last_odom = odom
        return pred

    def update(self, frame: Frame) -> Mapping[str, float] | None:
        p = self.params
        scan = frame.scan
        previous = self._pose
        # without odometry BreezySLAM has no velocity and does not de-skew; "motion" uses the last matched one
        self._sweep_step = self._step if self.params.deskew == "motion" else np.zeros(3)
        pose = self._predict(frame)
        self._sweep_step = self._one_sweep(self._sweep_step, frame.timestamp)
        ranges = scan.ranges
        short = ranges < max(p.min_range, scan.range_min)  # NaN compares False
        if short.any():
            # error codes as no return: as endpoints at the laser they would score the robot's own cell
            self.diagnostics.count("short_readings", int(short.sum()))
            ranges = np.where(short, np.nan, ranges)
        valid = ~np.isnan(ranges)
        n_points = int(valid.sum())
        values: dict[str, float] = {"points": float(n_points)}
        if n_points < _MIN_POINTS:
            self.diagnostics.count("scans_too_few_returns")
            self._set_pose(previous, pose)
            return values
        beams = self._beam_poses(scan)
        points = _endpoints(beams[valid], ranges[valid])
        if self._scans_in_map > 0:
            result = rmhc_match(
                self._map, points, pose, sigma_xy=p.sigma_xy, sigma_theta=p.sigma_theta,
                max_iter=p.max_search_iter, state=self._random, refine=p.refine,
            )
            if math.isfinite(result.distance):
                pose = result.pose
                values.update(score=result.distance / FREE, iterations=result.evaluations, halvings=result.halvings)
            else:
                self.diagnostics.count("match_failures")  # no endpoint on the map
        self._set_pose(previous, pose)
        values["cells_updated"] = self._integrate(scan, ranges, pose, beams)
        self._scans_in_map += 1
        return values

    def _one_sweep(self, step: NDArray[np.float64], stamp: float) -> NDArray[np.float64]:
        """``step`` (the motion since the last frame) when the frames are consecutive sweeps, else no motion."""
        last, self._last_time = self._last_time, float(stamp)
        if last is None or float(stamp) - last <= _LONGEST_SWEEP or not np.any(step != 0.0):
            return step
        self.diagnostics.count("scans_not_deskewed")
        return np.zeros(3)

    def _set_pose(self, previous: NDArray[np.float64] | None, pose: NDArray[np.float64]) -> None:
        self._step = np.zeros(3) if previous is None else se2.relative(previous, pose)
        self._pose = pose

    def _beam_poses(self, scan) -> NDArray[np.float64]:
        """Each beam's laser pose in the robot frame at the scan's timestamp ``(N, 3)``, heading with the beam angle.

        With ``deskew``, beam ``i`` of ``N`` was measured ``i / (N - 1)`` of the way through the sweep, which
        (a rotating mirror turns once per scan period) takes ``N * angle_increment / 2 pi`` of the period: its
        laser pose is the mount moved by that fraction of the motion over one period.
        """
        n = scan.num_beams
        step = self._sweep_step
        if self.params.deskew != "none" and n > 1 and np.any(step != 0.0) and np.all(np.isfinite(step)):
            share = min(1.0, n * scan.angle_increment / (2.0 * math.pi))
            frac = share * np.arange(n, dtype=np.float64) / (n - 1)
            poses = se2.compose(se2.interpolate(np.zeros(3), step, frac), scan.mount)
        else:
            poses = np.broadcast_to(np.asarray(scan.mount, dtype=np.float64), (n, 3)).copy()
        poses[:, 2] = poses[:, 2] + scan.angles
        return poses

    def _integrate(self, scan, ranges: NDArray[np.float64], pose: NDArray[np.float64],
                   beams: NDArray[np.float64]) -> float:
        p = self.params
        laser = se2.compose(pose, scan.mount)
        hit = ~np.isnan(ranges)
        if p.no_return_range is not None:
            ranges = np.where(hit, ranges, p.no_return_range)
            use = np.ones(ranges.shape[0], dtype=bool)
        else:
            use = hit
        r = ranges[use]
        # the rays are drawn from the laser's pose at the scan's start: the sweep moves it by centimetres
        ends = se2.transform_points(pose, _endpoints(beams[use], r))
        half = 0.5 * p.hole_width
        if self.sensor_model is not None:
            sigma = beam_sigmas(scan, self.sensor_model, 0.0)[use]
            width = np.sqrt(half * half + (p.hole_sigmas * np.nan_to_num(sigma)) ** 2)
        else:
            width = np.full(r.shape[0], half)
        return float(self._map.update((laser[0], laser[1]), ends, width, hit[use], p.map_quality))

    def current_pose(self) -> NDArray[np.float64] | None:
        return self._pose

    def map(self) -> OccupancyGrid:
        return self._map.to_occupancy_grid(GridParams(resolution=self.params.resolution))

    def written_map(self) -> Any:
        return self._map.crop_to_observed()

    def finish(self) -> None:
        # the map grows by half its size at a time: give back the unwritten part (crsm on fr101: 130 MB -> 43 MB);
        # it grows again if more scans come
        self._map = self._map.crop_to_observed()
