"""``crsm``: Critical Rays Scan Match SLAM (Tsardoulias & Petrou), odometry-free.

Per scan: pick the critical rays (:mod:`slam2d.matching.critical_rays`),
find the offset from the last pose that best fits them to the map by
random-restart hill climbing (:mod:`slam2d.matching.rrhc`), settle it with a
short neighbour climb scored with every beam (not in the original: a few
dozen rays leave several near-equal fits), then update the
8-bit map along every beam (:mod:`slam2d.grids.crsm_map`) with a gain set by
how jagged the scan is. Between the search and the update a turn test (not in
the original) keeps the match's turn only if every beam bears it out against
a prediction: by default the motion that registers the scan on the previous
scan alone (:mod:`slam2d.matching.scan_to_scan`), which a young map cannot
bias. As in the original, the first scans build the map at
the start pose; unlike the original, the warm-up ends early as soon as the
matcher sees the robot move (the original assumes it stands still).
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
from slam2d.grids.crsm_map import CrsmMap, first_beam_per_cell, marked_endpoints
from slam2d.grids.occupancy import GridParams, OccupancyGrid
from slam2d.matching.critical_rays import critical_rays
from slam2d.matching.random_numbers import new_state
from slam2d.matching.scan_to_scan import consecutive_motion
from slam2d.matching.rrhc import HEADING_STEP, near_known, paired_gain, refine_offset, rrhc_search
from slam2d.methods.base import SlamMethod
from slam2d.methods.registry import register
from slam2d.params import param

__all__ = ["CrsmParams", "Crsm", "ray_points"]

# The original's mean density during the first scans (then clamped to the update's range).
_WARMUP_DENSITY = 0.5
_DENSITY_RANGE = (0.04, 0.2)
_MIN_RAYS = 3  # fewer critical rays cannot place a scan


@dataclass
class CrsmParams:
    """crsm_slam's parameters (``crsm_slam_parameters.yaml``), with units."""

    resolution: float = param(
        0.02, unit="m", low=0.005, high=1.0, help="cell size (slam_occupancy_grid_dimentionality)"
    )
    hill_climbing_disparity: int = param(
        40, unit="cells", low=8, high=1000,
        help="d: climbs step [-d/8, d/8) cells and [-d/2, d/2)/90 rad; restarts land in [-d/4, d/4) cells "
        "and [-d/2, d/2)/45 rad around the last pose",
    )
    max_hill_climbing_iterations: int = param(
        40000, low=1, high=10_000_000, help="candidate transformations scored per scan"
    )
    desired_number_of_picked_rays: int = param(
        120, low=1, high=100_000,
        help="rays the density walk aims to pick per scan (kept within +-25 %); the original's 40 leaves the "
        "URG-04LX's mines maps less consistent (docs/methods/what-was-tried.md)",
    )
    scan_density_lower_boundary: float = param(
        0.3, unit="m", low=0.0, help="range jump between neighbouring beams that makes both critical"
    )
    map_update_density: float = param(40.0, low=0.0, high=1000.0, help="gain of the map update")
    map_update_obstacle_density: float = param(
        3.0, low=0.0, high=100.0, help="how much more an endpoint cell is lowered than a crossed cell is raised"
    )
    slam_container_size: int = param(500, unit="cells", low=10, help="side of the initial square map")
    robot_width: float = param(0.6, unit="m", low=0.0, help="width of the initial free patch under the robot")
    robot_length: float = param(0.75, unit="m", low=0.0, help="length of the initial free patch under the robot")
    warmup_scans: int = param(
        40, low=0, help="first scans whose pose is held at the start while the map builds (the original's 40)",
        advanced=True, group="warm-up",
    )
    warmup_density_scans: int = param(
        10, low=0, help="first scans written with the strongest update gain (the original's 10)",
        advanced=True, group="warm-up",
    )
    warmup_end_translation: float = param(
        0.04, unit="m", low=0.0,
        help="the warm-up ends early when a match moves the robot further than this from the start",
        advanced=True, group="warm-up",
    )
    warmup_end_rotation: float = param(
        0.035, unit="rad", low=0.0,
        help="the warm-up ends early when a match turns the robot more than this",
        advanced=True, group="warm-up",
    )
    warmup_end_confirm: int = param(
        2, low=1, help="consecutive scans that must see the motion before the warm-up ends early "
        "(a match on a one-scan map can jump spuriously)",
        advanced=True, group="warm-up",
    )
    min_range: float = param(
        0.02, unit="m", low=0.0,
        help="shorter readings are error codes, not returns (the URG-04LX reports errors as 0-20 mm); "
        "the scan's own range_min applies too",
    )
    dense_refine_rounds: int = param(
        10, low=0, high=1000,
        help="rounds of a final neighbour climb (1 cell, 1/180 rad) scored with every beam with a return, not only "
        "the critical rays: it picks between the near-equal fits a few rays leave (0 = the original)",
    )
    unknown_rays: str = param(
        "drop", choices=("score", "drop"),
        help="drop: rays that land on unknown space at the predicted pose (no known cell within known_margin) are "
        "left out of this scan's fitness, so new walls neither pull the fit back onto mapped ones nor push it; "
        "score: every ray counts, one on an unknown cell as a miss (the original)",
    )
    known_margin: int = param(2, unit="cells", low=0, high=50, help="see unknown_rays",
                              advanced=True, group="unknown rays")
    turn_sigma: float = param(
        0.035, unit="rad", low=0.0, high=10.0,
        help="scatter of the turn per scan about the prediction (turn_null): a match whose turn differs from the "
        "prediction's fit is kept only if the paired z of every beam's fitness gain over that fit reaches "
        "|its extra turn| / turn_sigma (a likelihood ratio against a Gaussian turn prior; sparse scans need a "
        "larger gain); otherwise the prediction's fit is taken. 0 = off (the original)",
    )
    turn_null: str = param(
        "scan_to_scan", choices=("scan_to_scan", "still", "last_motion", "velocity"),
        help="the prediction turn_sigma tests a match against: the last pose (still), the last pose plus the "
        "last matched motion (last_motion), or plus this scan's interval times the mean velocity of the last "
        "velocity_scans motions from the scan timestamps (velocity), or plus the motion that registers this scan "
        "on the previous one alone (scan_to_scan, no map); each settled by the every-beam climb",
        advanced=True, group="turn test",
    )
    turn_starts: str = param(
        "prediction", choices=("prediction", "translations"),
        help="where the every-beam climb for the turn test's alternative starts: the prediction only, or also at the "
        "match's position and at the last pose plus the mean recent translation, each at the prediction's heading",
        advanced=True, group="turn test",
    )
    velocity_scans: int = param(
        3, low=1, high=100,
        help="motions averaged for the velocity of turn_null=velocity and turn_starts=translations",
        advanced=True, group="turn test",
    )
    max_extent: float = param(
        2000.0, unit="m", low=1.0, help="largest width or height the map may grow to (beyond: corrupt data)",
        advanced=True, group="map growth",
    )


def ray_points(scan, d: NDArray[np.float64], selected: NDArray[np.int64], resolution: float) -> NDArray[np.float64]:
    """Robot-frame endpoints of the selected rays, truncated to whole cells in the laser frame as the original does.

    The map update marks a beam's wall ``int(range / cell)`` cells out, up
    to a cell short of the true endpoint; truncating the matched endpoints
    towards the laser the same way keeps them on the marked cells.
    """
    a = scan.angles[selected]
    r = d[selected] / resolution
    cells = np.stack([np.trunc(r * np.cos(a)), np.trunc(r * np.sin(a))], axis=-1) * resolution
    return se2.transform_points(scan.mount, cells)


@register
class Crsm(SlamMethod):
    name = "crsm"
    Params = CrsmParams
    summary = "CRSM SLAM: critical rays + random-restart hill climbing on an 8-bit map, no odometry"
    uses_odometry = False
    stochastic = True
    DIAGNOSTICS = {
        "score": "fitness of the chosen transformation, 0 = rays on free or unknown cells, 1 = on walls [-]",
        "iterations": "candidate transformations scored [-]",
        "restarts": "random restarts of the climb [-]",
        "improvements": "candidates that improved the best [-]",
        "refine_steps": "rounds of the final neighbour climb (dense_refine_rounds) that moved the pose [-]",
        "rays": "critical rays picked [-]",
        "rays_on_unknown": "critical rays left out because they land on unknown space (unknown_rays=drop) [-]",
        "mean_density": "the scan's mean range jump between neighbouring beams, before clamping [m]",
        "cells_updated": "cells walked by the map update [cells]",
        "turn_z": "paired z of the match's every-beam fitness gain over the prediction's fit when their headings "
                  "differ (turn_sigma) [-]",
        "consecutive_turn": "the turn registering the scan on the previous one gives (turn_null=scan_to_scan) [rad]",
        "turn_rejected": "1 when the match's turn lacked the evidence and the prediction's fit was taken [-]",
    }

    def __init__(self, params: CrsmParams | None = None, **kwargs) -> None:
        super().__init__(params, **kwargs)
        p = self.params
        self._map = CrsmMap(p.resolution, grow_margin=100, max_extent=p.max_extent)
        half = 0.5 * p.slam_container_size * p.resolution
        self._map.ensure_contains(-half, -half, half, half, margin=0)
        self._map.draw_patch(np.zeros(3), p.robot_length, p.robot_width)
        self._pose = np.zeros(3)
        self._step = np.zeros(3)  # the last matched motion, robot frame
        self._recent: list[tuple[NDArray[np.float64], float]] = []  # the last matched motions and their intervals
        self._last_time = math.nan
        self._dt = 0.0
        self._previous_points: NDArray[np.float64] | None = None  # the last scan's endpoints, robot frame
        self._consecutive = np.zeros(3)  # this scan's pose in the last scan's frame, from the two scans alone
        self._parameter = 100.0  # the density walk's threshold factor, adapted scan by scan
        self._warm = True
        self._moves_seen = 0  # consecutive warm-up scans whose match moved the robot
        self._scans = 0
        self._random = new_state(self.rng)
        self._directions = None  # (layout key, cos, sin, angles) of the beams: see _beam_directions

    def _relocate(self, pose: NDArray[np.float64]) -> None:
        self._pose, self._step, self._consecutive = pose.copy(), np.zeros(3), np.zeros(3)
        self._recent, self._previous_points, self._last_time = [], None, math.nan

    def update(self, frame: Frame) -> Mapping[str, float] | None:
        p = self.params
        scan = frame.scan
        dt = frame.timestamp - self._last_time
        self._dt = dt if math.isfinite(dt) and dt > 0.0 else 0.0
        laser_max = scan.range_max if math.isfinite(scan.range_max) else float(np.nanmax(scan.ranges, initial=0.0))
        d = np.nan_to_num(scan.ranges, nan=0.0)
        # error codes as no return: as "returns" at the laser they are critical rays (every one a jump) that
        # all land on one cell, and pull the matched pose onto any wall the robot is near
        short = (d > 0) & (d < max(p.min_range, scan.range_min))
        if short.any():
            self.diagnostics.count("short_readings", int(short.sum()))
            d[short] = 0.0
        values: dict[str, float] = {}
        if not (d > 0).any():
            self.diagnostics.count("scans_without_returns")
            self._scans += 1
            return {"rays": 0.0}
        cos_a, sin_a, angles = self._beam_directions(scan)
        # every beam's endpoint, robot frame, cells as the map marks them: once per scan for all the uses below
        bx, by = marked_endpoints(d, cos_a, sin_a, p.resolution, *self._mount_frame(scan))
        ex = ey = None  # every beam with a return short of the maximum range, for the dense climb and the turn test
        if p.dense_refine_rounds > 0 or p.turn_sigma > 0:
            with_return = (d > 0) & (d < laser_max)
            ex, ey = bx[with_return], by[with_return]
        if p.turn_null == "scan_to_scan" and p.turn_sigma > 0:
            # registered on the previous scan alone; the turn test's prediction (kept: the last scan's points)
            everywhere = np.stack([ex, ey], axis=-1)
            if self._previous_points is not None:
                self._consecutive = consecutive_motion(self._previous_points, everywhere, self._consecutive)
                values["consecutive_turn"] = float(self._consecutive[2])
            self._previous_points = everywhere
        selected, self._parameter, mean_density, _ = critical_rays(
            d, laser_max, self._parameter, p.scan_density_lower_boundary, p.desired_number_of_picked_rays,
        )
        values.update(rays=float(selected.shape[0]), mean_density=float(mean_density))
        if self._scans == 0:
            moved = self._pose  # nothing to match against yet: the first scan starts the map at the origin
        elif selected.shape[0] >= _MIN_RAYS:
            qx, qy = bx[selected], by[selected]
            centre = self._pose
            ox, oy = self._map.origin
            if p.unknown_rays == "drop":
                ahead = se2.compose(self._pose, self._step)
                keep = near_known(self._map.values, ox, oy, p.resolution, qx, qy, *ahead, p.known_margin)
                kept = int(np.count_nonzero(keep))
                values["rays_on_unknown"] = float(keep.shape[0] - kept)
                if kept >= _MIN_RAYS:
                    qx, qy = qx[keep], qy[keep]
            dx, dy, dk, fit, n, restarts, better = rrhc_search(
                self._map.values, ox, oy, p.resolution, qx, qy,
                float(centre[0]), float(centre[1]), float(centre[2]),
                p.hill_climbing_disparity, p.max_hill_climbing_iterations, self._random,
            )
            refined = 0
            dqx = dqy = None  # the dense points, contiguous
            if ex is not None:
                dqx, dqy = ex, ey
                if p.unknown_rays == "drop":
                    keep = near_known(self._map.values, ox, oy, p.resolution, ex, ey, *ahead, p.known_margin)
                    if np.count_nonzero(keep) >= _MIN_RAYS:
                        dqx, dqy = ex[keep], ey[keep]
            if p.dense_refine_rounds > 0:
                dx, dy, dk, _, moved_rounds = refine_offset(
                    self._map.values, ox, oy, p.resolution, dqx, dqy, float(centre[0]), float(centre[1]),
                    float(centre[2]), dx, dy, dk, p.dense_refine_rounds,
                )
                refined += moved_rounds
            values.update(score=fit, iterations=n, restarts=restarts, improvements=better, refine_steps=refined)
            moved = np.array([
                centre[0] + dx * p.resolution,
                centre[1] + dy * p.resolution,
                math.remainder(centre[2] + dk * HEADING_STEP, 2 * math.pi),
            ])
            if p.turn_sigma > 0 and dqx is not None:
                moved = self._check_turn(moved, dqx, dqy, values)
        else:
            self.diagnostics.count("scans_too_few_rays")
            moved = self._pose
        if self._warm and self._scans < p.warmup_scans:
            if math.hypot(moved[0], moved[1]) > p.warmup_end_translation or abs(moved[2]) > p.warmup_end_rotation:
                self._moves_seen += 1
            else:
                self._moves_seen = 0
            if self._moves_seen >= p.warmup_end_confirm:
                self._warm = False
                self.diagnostics.summary["warmup_ended_at_scan"] = self._scans
            else:
                moved = np.zeros(3)  # held at the start while the first map builds
            step = np.zeros(3)  # held, or the jump out of the hold: no velocity to keep
        else:
            step = se2.relative(self._pose, moved)
        self._step = step
        self._pose = moved
        self._last_time = frame.timestamp
        if self._dt > 0.0:
            self._recent.append((step, self._dt))
            del self._recent[:-p.velocity_scans]
        else:
            self._recent.clear()  # no interval (first scan, repeated or backward stamp): no velocity to keep
        if self._scans < p.warmup_density_scans:
            mean_density = _WARMUP_DENSITY
        gain = min(max(mean_density, _DENSITY_RANGE[0]), _DENSITY_RANGE[1])
        values["cells_updated"] = self._integrate(scan, d, angles, cos_a, sin_a, gain)
        self._scans += 1
        return values

    def _check_turn(self, moved: NDArray[np.float64], qx: NDArray[np.float64], qy: NDArray[np.float64],
                    values: dict[str, float]) -> NDArray[np.float64]:
        """The match, or the prediction's fit if the match's extra turn is not borne out by every beam.

        Sparse scans leave near-equal maxima degrees apart, and a wrong one
        turns the rest of the map. The alternative is the prediction
        (``turn_null``) settled by the every-beam neighbour climb. With a
        Gaussian prior of scatter ``turn_sigma`` on the turn about the
        prediction, the match wins if its log-likelihood gain, z^2 / 2 for the
        paired z over the beams (:func:`~slam2d.matching.rrhc.paired_gain`),
        exceeds the prior's penalty for its larger turn: z^2 >= (e_m^2 - e_a^2)
        / turn_sigma^2 (e = each pose's turn away from the prediction). A
        small extra turn needs little evidence, a large one in a sparse scan
        much.
        """
        p = self.params
        ox, oy = self._map.origin
        if p.turn_null == "last_motion":
            pred = se2.compose(self._pose, self._step)
        elif p.turn_null == "velocity":
            pred = se2.compose(self._pose, self._velocity_step())
        elif p.turn_null == "scan_to_scan":
            pred = se2.compose(self._pose, self._consecutive)
        else:
            pred = self._pose
        # where the every-beam climb for the prediction's fit starts: the prediction, and (turn_starts=translations)
        # also the match's position and the last pose plus the recent mean translation, at the prediction's heading.
        # Why: the climb moves a cell per round, so from the last pose alone it cannot follow a robot that moved
        # 15-20 cm, ends on a poor local fit, and a wrong turn then beats it (mines-exp1 scans 702, 711).
        starts = [pred]
        if p.turn_starts == "translations":
            glide = se2.compose(self._pose, self._velocity_step(turn=False))
            starts += [np.array([moved[0], moved[1], pred[2]]), np.array([glide[0], glide[1], pred[2]])]
        alt, best = pred, -math.inf
        for pred in starts:
            ax, ay, ak, fit, _ = refine_offset(self._map.values, ox, oy, p.resolution, qx, qy, float(pred[0]),
                                               float(pred[1]), float(pred[2]), 0, 0, 0, max(p.dense_refine_rounds, 1))
            if fit > best:
                best = fit
                alt = np.array([pred[0] + ax * p.resolution, pred[1] + ay * p.resolution,
                                math.remainder(pred[2] + ak * HEADING_STEP, 2 * math.pi)])
        e_m = math.remainder(moved[2] - pred[2], 2 * math.pi)
        e_a = math.remainder(alt[2] - pred[2], 2 * math.pi)
        needed = (e_m * e_m - e_a * e_a) / (p.turn_sigma * p.turn_sigma)
        if needed <= 0.0:
            return moved  # the match turns no further from the prediction than its fit does
        _, z, _ = paired_gain(self._map.values, ox, oy, p.resolution, qx, qy, float(moved[0]), float(moved[1]),
                              float(moved[2]), float(alt[0]), float(alt[1]), float(alt[2]))
        values["turn_z"] = float(min(z, 1e6))
        if z > 0.0 and z * z >= needed:
            values["turn_rejected"] = 0.0
            return moved
        values["turn_rejected"] = 1.0
        self.diagnostics.count("turns_rejected")
        return alt

    def _velocity_step(self, turn: bool = True) -> NDArray[np.float64]:
        """The motion over this scan's interval at the mean velocity of the last ``velocity_scans`` matched motions."""
        if not self._recent:
            return np.zeros(3)
        span = sum(dt for _, dt in self._recent)
        mean = sum(step for step, _ in self._recent) / span
        out = mean * self._dt
        if not turn:
            out[2] = 0.0
        return out

    def _beam_directions(self, scan) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """``(cos, sin, angle)`` of every beam, laser frame; kept while the scans' layout stays the same."""
        key = (scan.num_beams, scan.angle_min, scan.angle_increment)
        if self._directions is None or self._directions[0] != key:
            angles = scan.angles
            self._directions = (key, np.cos(angles), np.sin(angles), angles)
        return self._directions[1:]

    @staticmethod
    def _mount_frame(scan) -> tuple[float, float, float, float]:
        """The laser's mount as ``(x, y, cos, sin)``, as :func:`slam2d.core.se2.transform_points` applies it."""
        m = scan.mount
        return float(m[0]), float(m[1]), float(np.cos(m[2])), float(np.sin(m[2]))

    def _integrate(self, scan, d: NDArray[np.float64], angles: NDArray[np.float64], cos_a: NDArray[np.float64],
                   sin_a: NDArray[np.float64], gain: float) -> float:
        p = self.params
        laser = se2.compose(self._pose, scan.mount)
        # the original walks a beam once per laser-frame endpoint cell
        use = first_beam_per_cell(d, cos_a, sin_a, p.resolution)
        return float(self._map.update(
            laser, d, angles, use, mean_density=gain, density=p.map_update_density,
            obstacle_density=p.map_update_obstacle_density,
        ))

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
