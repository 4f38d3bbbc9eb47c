"""``hector``: Hector SLAM's scan-to-map matching, with optional odometry and degeneracy detection.

Each scan is matched against a log-odds map pyramid by coarse-to-fine
Gauss-Newton (:mod:`slam2d.matching.gauss_newton`); the map is updated only
after the pose moved past a distance or angle threshold
(:mod:`slam2d.grids.pyramid`). No odometry by default, as the original; with
``use_odometry`` it predicts the pose, enters the match as a prior and decides
the directions the scan cannot (a featureless corridor).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from slam2d.core import se2
from slam2d.core.frames import Frame
from slam2d.grids.occupancy import GridParams, OccupancyGrid
from slam2d.grids.pyramid import MapPyramid
from slam2d.matching.odometry_gaps import GapCheck, OdometryGapParams
from slam2d.matching.gauss_newton import GaussNewtonMatcher, MatchSettings
from slam2d.methods.base import SlamMethod
from slam2d.methods.registry import register
from slam2d.params import param
from slam2d.sensors.beam_model import beam_sigmas, surface_tangents

__all__ = ["HectorParams", "Hector"]


@dataclass
class HectorParams(GridParams, OdometryGapParams):
    """Hector's defaults (``hector_mapping``'s ROS node) where the original has the parameter.

    Except ``resolution`` (0.05 m, not 0.025 m), the map update thresholds (0.1 m / 0.1 rad, not
    0.4 m / 0.9 rad) and what the matcher reads in unknown cells (0.3, not 0.5), and the starting
    guess (constant velocity, not the last pose): see docs/methods/hector.md for the measurements.
    """

    resolution: float = param(0.05, unit="m", low=0.001, high=10.0,
                              help="cell size of the finest map level (original: map_resolution, 0.025; "
                              "0.05 suits 1-3 cm range noise, see the method page)")
    p_hit: float = param(0.9, low=0.501, high=0.999,
                         help="occupancy probability one beam ending in a cell gives it "
                         "(original: update_factor_occupied)")
    p_miss: float = param(0.4, low=0.001, high=0.499,
                          help="occupancy probability one beam crossing a cell gives it "
                          "(original: update_factor_free)")
    map_multi_res_levels: int = param(3, low=1, high=8,
                                      help="map pyramid levels, each half the resolution of the one below")
    unknown_probability: float = param(
        0.3, low=0.0, high=1.0,
        help="occupancy the matcher reads in never-observed cells (the original: 0.5, which pulls scans "
        "back towards the explored part of the map; see the method page)")
    map_update_distance_thresh: float = param(
        0.1, unit="m", low=0.0,
        help="update the map only after the robot moved this far since the last update (the original: 0.4)")
    map_update_angle_thresh: float = param(
        0.1, unit="rad", low=0.0, help="... or turned this far since the last update (the original: 0.9)")
    laser_min_dist: float = param(0.4, unit="m", low=0.0, help="returns shorter than this are ignored")
    laser_max_dist: float = param(30.0, unit="m", low=0.0, help="returns longer than this are ignored")
    iterations_coarse: int = param(10, low=1, high=1000,
                                   help="most Gauss-Newton steps on each coarse level (the original: 3, fixed)",
                                   advanced=True, group="scan matching")
    iterations_fine: int = param(10, low=1, high=1000,
                                 help="most Gauss-Newton steps on the finest level (the original: 5, fixed)",
                                 advanced=True, group="scan matching")
    convergence_xy: float = param(1e-4, unit="m", low=0.0,
                                  help="a level stops when a step moves less than this and ...",
                                  advanced=True, group="scan matching")
    convergence_theta: float = param(1e-4, unit="rad", low=0.0, help="... turns less than this",
                                     advanced=True, group="scan matching")
    max_angle_step: float = param(0.2, unit="rad", low=0.001, help="largest heading change of one step",
                                  advanced=True, group="scan matching")
    max_step_cells: float = param(2.0, low=0.01,
                                  help="longest translation of one step, in cells of the level being matched",
                                  advanced=True, group="scan matching")
    range_sigma: float = param(0.01, unit="m", low=1e-6,
                               help="range noise of every beam when no sensor model is given; a beam's "
                               "residual weight is (range_sigma / its sigma)^2", advanced=True, group="scan matching")
    degeneracy_threshold: float = param(
        0.01, low=0.0, high=1.0,
        help="a match is degenerate when an eigenvalue of its Hessian (heading scaled by the scan's RMS "
        "point distance) is below this fraction of the largest", advanced=True, group="degeneracy")
    normal_baseline: float = param(
        0.2, unit="m", low=0.0,
        help="surface normals for the geometric degeneracy test come from endpoints about this far apart",
        advanced=True, group="degeneracy")
    constant_velocity: bool = param(
        True, help="without (usable) odometry, start each match from the last pose plus the last scan-to-scan "
        "motion (the original starts from the last pose)")
    use_odometry: bool = param(False, help="predict with odometry, use it as a prior and along "
                                           "degenerate directions")
    odometry_sigma_xy: float = param(0.05, unit="m", low=1e-6,
                                     help="prior standard deviation of the odometry's position increment per scan",
                                     advanced=True, group="odometry")
    odometry_sigma_theta: float = param(0.05, unit="rad", low=1e-6,
                                        help="prior standard deviation of the odometry's heading increment per scan",
                                        advanced=True, group="odometry")
    odometry_max_step: float = param(2.0, unit="m", low=0.0,
                                     help="an odometry increment longer than this is a jump and is ignored",
                                     advanced=True, group="odometry")
    min_points: int = param(10, low=3, help="scans with fewer usable returns are not matched",
                            advanced=True, group="scan matching")


@register
class Hector(SlamMethod):
    name = "hector"
    Params = HectorParams
    summary = "Hector SLAM: multi-resolution Gauss-Newton scan-to-map matching, odometry optional"
    uses_odometry = True
    optional_odometry = True
    # Gauss-Newton finds only what lies in its basin: a 10 deg heading error of one step (intel's odometry, a
    # scan a metre) is outside it, so the scans' own increment replaces the odometry's where that fits poorly
    gap_check = GapCheck(refine=True)
    DIAGNOSTICS = {
        "score": "mean occupancy probability at the matched scan points (1 = every point on a wall)",
        "inverse_condition": "smallest / largest eigenvalue of the match Hessian, heading scaled "
        "by the RMS point distance (near 0 = under-constrained)",
        "geometric_condition": "the same for the scan's point-to-line information (surface normals from "
        "neighbouring beams): blind to map texture",
        "degenerate": "1 when the match was under-constrained (either condition below degeneracy_threshold)",
        "sigma_x": "standard deviation of x from the match covariance [m]",
        "sigma_y": "standard deviation of y from the match covariance [m]",
        "sigma_theta": "standard deviation of the heading from the match covariance [rad]",
        "iterations": "Gauss-Newton steps over all levels",
        "points": "returns matched [beams]",
        "map_updated": "1 when the scan was added to the map",
    }

    def __init__(self, params: HectorParams | None = None, **kwargs) -> None:
        super().__init__(params, **kwargs)
        p = self.params
        self.pyramid = MapPyramid(p, p.map_multi_res_levels, unknown=p.unknown_probability)
        self.matcher = GaussNewtonMatcher(MatchSettings(
            iterations_coarse=p.iterations_coarse, iterations_fine=p.iterations_fine,
            tolerance_xy=p.convergence_xy, tolerance_theta=p.convergence_theta,
            max_angle_step=p.max_angle_step, max_step_cells=p.max_step_cells,
            degeneracy_threshold=p.degeneracy_threshold,
        ))
        self._pose: NDArray[np.float64] | None = None
        self._last_odom: NDArray[np.float64] | None = None
        self._map_pose: NDArray[np.float64] | None = None
        self._previous: NDArray[np.float64] | None = None  # the pose one scan before
        #: Covariance (3, 3) of the last match; None before the first.
        self.covariance: NDArray[np.float64] | None = None

    def _relocate(self, pose: NDArray[np.float64]) -> None:
        self._pose, self._previous, self._last_odom = pose.copy(), None, None

    def _prediction(self, frame: Frame) -> tuple[NDArray[np.float64], NDArray[np.float64] | None]:
        """Where the robot should be, and the prior's information (None: no odometry prior)."""
        p = self.params
        if p.use_odometry:
            odom = self.usable_odometry(frame)
            if odom is None:
                self.diagnostics.count("frames_without_odometry")
            else:
                last, self._last_odom = self._last_odom, odom
                if last is not None:
                    # a jump (counted and warned) gives no prior: the match starts as without odometry
                    step, _, is_motion = self.odometry_step(last, odom, p.odometry_max_step, frame.timestamp)
                    if is_motion:
                        sx, st = p.odometry_sigma_xy, p.odometry_sigma_theta
                        return se2.compose(self._pose, step), np.diag([sx**-2, sx**-2, st**-2])
        # No usable odometry: the last pose, or the last pose plus the last motion.
        if p.constant_velocity and self._previous is not None:
            return se2.compose(self._pose, se2.relative(self._previous, self._pose)), None
        return self._pose, None

    def update(self, frame: Frame) -> Mapping[str, float] | None:
        p = self.params
        scan = frame.scan
        r = scan.ranges
        with np.errstate(invalid="ignore"):
            ok = (r >= p.laser_min_dist) & (r <= p.laser_max_dist)
        a = scan.angles[ok]
        points = se2.transform_points(scan.mount, np.stack([r[ok] * np.cos(a), r[ok] * np.sin(a)], axis=-1))
        values: dict[str, float] = {"points": float(points.shape[0]), "map_updated": 0.0}
        enough = points.shape[0] >= p.min_points
        if not enough:
            self.diagnostics.count("scans_too_few_points")
        if self._pose is None:
            # The first scan defines the map frame (at the first odometry pose when odometry is used).
            odom = self.usable_odometry(frame)
            self._pose = np.array(odom if p.use_odometry and odom is not None else np.zeros(3), dtype=np.float64)
            self._last_odom = odom
        else:
            before = self._pose
            self._pose, info = self._prediction(frame)
            self._previous = before
            if not enough:
                return values
            matched = self._match(scan, points, ok, info)
            if matched is None:
                return values
            values.update(matched)
        if enough:
            values["map_updated"] = float(self._update_map(scan, points, ok))
        return values

    def _match(self, scan, points, ok, info) -> dict[str, float] | None:
        """Match the scan from the predicted pose; the values to log, None when the match failed."""
        p = self.params
        sigma = beam_sigmas(scan, self.sensor_model, p.range_sigma)[ok]
        weights = np.where(np.isfinite(sigma) & (sigma > 0), (p.range_sigma / sigma) ** 2, 0.0)
        result = self.matcher.match(self.pyramid, points, weights, self._pose,
                                    prior=None if info is None else self._pose, prior_information=info,
                                    normals=_normals(scan, p.normal_baseline)[ok])
        if not (np.all(np.isfinite(result.pose)) and np.all(np.isfinite(result.covariance))):
            self.diagnostics.count("match_failures")
            return None
        self._pose = result.pose
        self.covariance = result.covariance
        if result.degenerate:
            self.diagnostics.count("degenerate_matches")
        return {
            "score": result.score,
            "inverse_condition": result.inverse_condition,
            "geometric_condition": result.geometric_condition,
            "degenerate": float(result.degenerate),
            "sigma_x": float(np.sqrt(result.covariance[0, 0])),
            "sigma_y": float(np.sqrt(result.covariance[1, 1])),
            "sigma_theta": float(np.sqrt(result.covariance[2, 2])),
            "iterations": float(result.iterations),
        }

    def _update_map(self, scan, points: NDArray[np.float64], ok: NDArray[np.bool_]) -> bool:
        p = self.params
        if self._map_pose is not None:
            moved = se2.relative(self._map_pose, self._pose)
            if np.hypot(moved[0], moved[1]) < p.map_update_distance_thresh and abs(moved[2]) < p.map_update_angle_thresh:
                return False
        world = se2.transform_points(self._pose, points)
        hits = np.ones(world.shape[0], dtype=bool)
        laser = se2.compose(self._pose, scan.mount)
        if p.max_range is not None:
            # No return or too long: clear free space up to max_range (as GridParams.max_range says).
            far = ~ok & ~(scan.ranges < p.laser_min_dist)
            if far.any():
                ang = laser[2] + scan.angles[far]
                free = laser[:2] + p.max_range * np.stack([np.cos(ang), np.sin(ang)], axis=-1)
                world = np.concatenate([world, free])
                hits = np.concatenate([hits, np.zeros(free.shape[0], dtype=bool)])
        self.pyramid.integrate_points(laser[:2], world, hits=hits)
        self._map_pose = self._pose.copy()
        self.diagnostics.count("map_updates")
        return True

    def current_pose(self) -> NDArray[np.float64] | None:
        return self._pose

    def map(self) -> OccupancyGrid:
        return self.pyramid.finest


def _normals(scan, baseline: float) -> NDArray[np.float64]:
    """Surface normal at every beam's endpoint in the robot frame, ``(n, 2)``; NaN where unknown."""
    tx, ty, usable = surface_tangents(scan.ranges, scan.angles, baseline)
    c, s = np.cos(scan.mount[2]), np.sin(scan.mount[2])
    nx, ny = -ty, tx  # the tangent turned a quarter: a normal (its sign does not matter)
    out = np.stack([c * nx - s * ny, s * nx + c * ny], axis=-1)
    out[~usable] = np.nan
    return out
