"""``gmapping``: a Rao-Blackwellised particle filter with a scan-matched proposal (GMapping).

Every scan each particle is moved by the odometry increment plus GMapping's
motion noise. When the robot has travelled ``linearUpdate`` or turned
``angularUpdate`` since the last update (or ``temporalUpdate`` seconds passed),
the filter updates: every particle hill-climbs its pose on its own map
(:mod:`slam2d.matching.hill_climb`), optionally draws it from the Gaussian
fitted around the optimum (Grisetti et al. 2007), adds the scan's
log-likelihood to its weight, the set is resampled when Neff falls below
``resampleThreshold * N``, and the scan is added to every map. Maps share
tiles copy-on-write (:mod:`slam2d.grids.tiled`). The output is the best
particle's (largest accumulated log-likelihood) path and the map rebuilt
along it, as the ROS node publishes it. See docs/methods/gmapping.md.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from types import SimpleNamespace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slam2d.core import se2
from slam2d.core.frames import Frame
from slam2d.core.memory import check_allocation
from slam2d.filters import (
    backtrack,
    effective_sample_size,
    normalized_weights,
    published_entropy,
    systematic_resample,
    weight_entropy,
)
from slam2d.graph.wall_end_landmarks import WallEndParams
from slam2d.graph.loop_correction import LoopCorrectionParams, correct_path, spread_node_corrections
from slam2d.graph.wall_refinement import WallRefinementParams, refine_path
from slam2d.grids.occupancy import OccupancyGrid
from slam2d.grids.tiled import TiledMaps
from slam2d.matching.odometry_gaps import OdometryGapParams
from slam2d.matching.hill_climb import (
    BeamSet,
    gaussian_proposal,
    hold_flat_direction,
    match_one,
    match_particles,
    wall_ends,
)
from slam2d.methods.base import SlamMethod
from slam2d.methods.registry import register
from slam2d.params import is_auto, param
from slam2d.sensors.beam_model import beam_sigmas
from slam2d.sensors.motion_noise import draw_from_motion, gmapping_motion_std

__all__ = ["GMappingParams", "GMapping", "island_seed"]


def island_seed(seed: int, k: int) -> int:
    """The seed of island ``k`` of a run seeded ``seed``: the run's own for the first, else drawn from both."""
    return int(seed) if k == 0 else int(np.random.SeedSequence([int(seed), int(k)]).generate_state(1)[0])


# maxRange when the laser reports no finite range_max (the ROS wiki's maxUrange default)
_FALLBACK_MAX_RANGE = 80.0
_PRIOR_FLOOR = np.array([0.01, 0.01, 0.01])  # m, m, rad: the prior's smallest standard deviations
_STEP_FLOOR = np.array([0.01, 0.01, 0.005])  # m, m, rad: loop_correction's smallest step standard deviations


# auto defaults (GMappingParams.srt, stt, between_updates; resolved in GMapping.auto_values)
_GUIDED_SCANS_PER_UPDATE = 3.0  # scans per filter update from which the scan-matched increments drive the motion
_GUIDED_MIN_REACH = 8.0  # m: and only for a laser that reaches this far (99th percentile of its returns)
_NOISE_FLOOR = 0.05  # rad/m and rad/rad: the least odometry noise auto resolves to
_NOISE_CAP = 0.2  # and the most (GMapping's defaults)
_AUTO_SRT = ("the odometry's heading error per unit of an update's motion (linearUpdate m + angularUpdate rad), "
             f"measured against scan matching, within [{_NOISE_FLOOR}, {_NOISE_CAP}]")
_AUTO_STT = "the same value as srt"
_AUTO_BETWEEN = (f"the scans per filter update and the laser's reach: guided at {_GUIDED_SCANS_PER_UPDATE:g} or more "
                 f"scans per update with returns reaching {_GUIDED_MIN_REACH:g} m, else matched")


@dataclass
class GMappingParams(LoopCorrectionParams, WallRefinementParams, OdometryGapParams):
    """GMapping's parameters, with the names and defaults of slam_gmapping (and, not in GMapping, the loop
    correction of the finished best path by a pose graph, ``loop_correction``, and its wall refinement,
    ``wall_refinement``, over the odometry between frames: advanced parameters, listed after GMapping's)."""

    particles: int = param(30, low=1, high=10000, help="number of particles")
    islands: int = param(
        1, unit="filters", low=1, high=64,
        help="not in GMapping: run this many independent filters of `particles` each (the first with the run's "
        "seed, the others with seeds drawn from it) and report the one whose best particle has the largest "
        "accumulated log-likelihood per update (GMapping's weightSum, its own choice of the best particle); "
        "1 = GMapping. A filter that lost the right map early scores far lower (docs/methods/what-was-tried.md, "
        "gmapping, islands); costs islands x the CPU and the memory", advanced=True, group="islands")
    maxUrange: float | None = param(
        None, unit="m", low=0.0, help="usable range: beams are cut here for mapping and ignored beyond it "
        "for matching; unset: maxRange")
    maxRange: float | None = param(
        None, unit="m", low=0.0, help="beams longer than this are dropped; unset: the first scan's range_max - 0.01")
    match_range: float | None = param(
        None, unit="m", low=0.0, help="not in GMapping: beams longer than this are not used for matching and the "
        "likelihood (they are still mapped up to maxUrange). Set it a linearUpdate below the laser's reach and every "
        "matched beam ends where the previous updates' scans have mapped, so moving the pose back does not gain map "
        "points at the edge of the mapped area (a short laser's corridors otherwise shrink); unset: maxUrange",
        advanced=True, group="scan matching")
    sigma: float = param(
        0.05, unit="m^2", low=1e-9, help="scan-matcher score divisor: a beam scores exp(-d^2/sigma) "
        "(= 2 s^2 for a standard deviation s; 0.05 is s = 0.158 m)")
    kernelSize: int = param(1, unit="cells", low=0, high=10, help="search radius around a beam end for its map point")
    lstep: float = param(0.05, unit="m", low=1e-6, help="first translation step of the hill climb")
    astep: float = param(0.05, unit="rad", low=1e-6, help="first rotation step of the hill climb")
    iterations: int = param(5, low=0, high=30, help="step halvings before the hill climb stops")
    linearOdometryReliability: float = param(
        0.0, unit="1/m^2", low=0.0, help="GMapping core (not in the ROS node): the hill climb multiplies a pose's "
        "score by exp(-this * d^2), d its distance from where the climb started; 0: off",
        advanced=True, group="scan matching")
    angularOdometryReliability: float = param(
        0.0, unit="1/rad^2", low=0.0, help="GMapping core: the same for the heading change",
        advanced=True, group="scan matching")
    odometry_prior: float = param(
        0.0, low=0.0, help="not in GMapping: the particles' climb maximises score - this * half the squared "
        "Mahalanobis distance from the particle's predicted pose, with the motion model's (srr...stt) covariance of "
        "the odometry increment since the last update (the mode of likelihood x motion prior); 0: the original's climb",
        advanced=True, group="scan matching")
    tracking_prior: float = param(
        0.0, low=0.0, help="not in GMapping: the same odometry prior for the climbs of the scans between updates "
        "(between_updates=matched or guided), with the covariance of the odometry increment since the last matched "
        "scan; 0: off", advanced=True, group="scan matching")
    flat_ratio: float = param(
        0.0, low=0.0, high=1.0, help="not in GMapping: after every climb (the particles' and the tracked scans') "
        "the score's translation curvature at the optimum is taken by central differences of one cell; when its "
        "smaller eigenvalue is below this times the larger (a corridor longer than the laser's reach) the climb's "
        "move along that direction is undone, the odometry's kept (counted as degenerate_matches); 0: off",
        advanced=True, group="flat directions")
    flat_sigma: float = param(
        0.0, unit="m", low=0.0, help="not in GMapping: with flat_ratio, a held climb is not left at the odometry's "
        "position along its flat direction but moved to where the scan's wall ends (a straight wall's last hit "
        "next to a beam that passes it) meet the same walls' ends in the particle's map, each a Gaussian of this "
        "standard deviation, against the motion model's prior: the few beams that say where along a corridor the "
        "robot is, which the whole score's curvature cannot tell from the walls' ripple; 0: off, held at the "
        "odometry's", advanced=True, group="flat directions")
    lsigma: float = param(
        0.075, unit="m^2", low=1e-9, help="likelihood divisor: a matched beam adds -d^2/lsigma to the "
        "log-likelihood, an unmatched one -0.5/lsigma")
    coarse_kernel: int = param(
        0, unit="cells", low=0, high=10, help="not in GMapping: each particle also climbs from a second start, found "
        "by a climb at the first steps (lstep, astep) whose beams search this many cells around their ends, and "
        "keeps whichever of the two climbs scores higher; reaches walls a few cells beyond kernelSize's window "
        "(a loop coming back to old map); 0: off, the original's one climb", advanced=True, group="scan matching")
    ogain: float = param(3.0, low=1e-6, help="weight smoothing: weights are exp(loglik / (ogain N))")
    lskip: int = param(0, low=0, help="use every (lskip+1)-th beam for matching and likelihood")
    minimumScore: float = param(
        0.0, low=0.0, help="a match scoring at most this fails and the particle keeps its odometry pose")
    srr: float = param(0.1, unit="m/m", low=0.0, help="odometry translation noise from translation")
    srt: float = param(0.2, unit="rad/m", low=0.0, help="odometry rotation noise from translation (as GMapping's code)",
                       auto=_AUTO_SRT)
    str: float = param(0.1, unit="m/rad", low=0.0, help="odometry translation noise from rotation (as GMapping's code)")
    stt: float = param(0.2, unit="rad/rad", low=0.0, help="odometry rotation noise from rotation", auto=_AUTO_STT)
    linearUpdate: float = param(1.0, unit="m", low=0.0, help="update the filter after this much travel")
    angularUpdate: float = param(0.5, unit="rad", low=0.0, help="update the filter after this much rotation")
    temporalUpdate: float = param(
        -1.0, unit="s", help="also update after this long without one; negative: never")
    resampleThreshold: float = param(
        0.5, low=0.0, high=1.0, help="resample when Neff < resampleThreshold * particles")
    xmin: float = param(-100.0, unit="m", help="initial map extent, relative to the first pose (the map grows)")
    ymin: float = param(-100.0, unit="m", help="initial map extent, relative to the first pose")
    xmax: float = param(100.0, unit="m", help="initial map extent, relative to the first pose")
    ymax: float = param(100.0, unit="m", help="initial map extent, relative to the first pose")
    delta: float = param(0.05, unit="m", low=0.001, high=10.0, help="map resolution (cell size)")
    llsamplerange: float = param(0.01, unit="m", low=0.0, help="improved proposal: translation sampling range")
    llsamplestep: float = param(0.01, unit="m", low=1e-6, help="improved proposal: translation sampling step")
    lasamplerange: float = param(0.005, unit="rad", low=0.0, help="improved proposal: rotation sampling range")
    lasamplestep: float = param(0.005, unit="rad", low=1e-6, help="improved proposal: rotation sampling step")
    occ_thresh: float = param(0.25, low=0.0, high=1.0, help="output map: a cell with hits/visits above it is occupied")
    proposal: str = param(
        "hill-climb", choices=("hill-climb", "gaussian"),
        help="hill-climb: the original (particles take the optimum); gaussian: sample from the Gaussian "
        "fitted to likelihood x odometry prior on a grid around it and weight by its normaliser (Grisetti et al. "
        "2007's improved proposal; uses ll/la sample range/step)", advanced=True, group="proposal")
    generateMap: bool = param(
        False, help="particle maps also record free space (slam_gmapping: off, only hit cells)",
        advanced=True, group="maps")
    map_output: str = param(
        "rebuilt", choices=("rebuilt", "best-particle"),
        help="rebuilt: the map re-drawn along the best particle's whole path with free space (as the ROS "
        "node publishes); best-particle: that particle's own map", advanced=True, group="maps")
    between_updates: str = param(
        "matched", choices=("matched", "odometry", "guided"), auto=_AUTO_BETWEEN,
        help="not in GMapping: the pose reported for a scan between filter updates. matched: the best "
        "particle's last pose moved on by the odometry, then hill-climbed on that particle's map (one particle; "
        "the filter and the maps are unchanged); odometry: not climbed (the ROS node's map->odom); guided: "
        "every scan is climbed so, and the climbed increment replaces the odometry's in the motion model and "
        "the update gating (scan-matched odometry)")
    jump_warning: float = param(
        2.0, unit="m", low=0.0, help="an odometry step longer than this between two scans is warned and counted",
        advanced=True, group="odometry checks")


@register
class GMapping(SlamMethod):
    name = "gmapping"
    Params = GMappingParams
    summary = "Rao-Blackwellised particle filter with scan-matched proposal (GMapping)"
    stochastic = True
    DIAGNOSTICS = {
        "updated": "1 when the filter updated on this scan, else 0",
        "neff": "effective number of particles before resampling [particles]",
        "entropy": "entropy slam_gmapping publishes (raw weights; NaN when it publishes none) [nats]",
        "weight_entropy": "entropy of the normalised importance weights, max ln N [nats]",
        "resampled": "1 when the particles were resampled",
        "match_failures": "particles whose scan match failed (odometry used) [particles]",
        "degenerate_matches": "flat_ratio: particles whose climb was undone along an unconstrained direction "
        "[particles]",
        "best_score": "scan-matching score of the best particle [beams]",
        "tiles": "map tiles in use over all particles [tiles]",
        "island": "islands > 1: the island reported after this scan (0 = the run's own seed)",
    }

    def __init__(self, params: GMappingParams | None = None, **kwargs) -> None:
        super().__init__(params, **kwargs)
        self._n = int(self.params.particles)
        self._maps: TiledMaps | None = None
        self._state = np.zeros((self._n, 3))
        self._weight = np.zeros(self._n)  # log-likelihood since the last resampling (GMapping weight)
        self._weight_sum = np.zeros(self._n)  # accumulated over the whole run, inherited (weightSum)
        self._odom: NDArray[np.float64] | None = None
        self._update_odom: NDArray[np.float64] | None = None  # odometry at the last update
        self._update_poses = np.zeros((self._n, 3))  # particle poses at the last update
        self._linear = self._angular = 0.0
        self._put_at: NDArray[np.float64] | None = None  # a relocation waiting for the next frame's odometry
        self._last_update_time = -math.inf
        # the trajectory tree: every particle's pose at each update (a node) and its parent there
        self._node_poses = np.zeros((256, self._n, 3))
        self._node_parents = np.zeros((256, self._n), dtype=np.int32)
        self._node_odom = np.zeros((256, 3))
        self._nodes = 0
        self._scans: list[tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]] = []
        # every frame since the first: time, odometry, and the node it follows
        self._frame_times: list[float] = []
        self._frame_odom: list[NDArray[np.float64]] = []
        # frames the odometry does not join to the one before (a relocation: another recording's odometry)
        self._frame_breaks: list[int] = []
        self._frame_node: list[int] = []
        self._frame_rel: list[NDArray[np.float64] | None] = []  # matched pose relative to its node (between_updates)
        self._frame_scans: list = []  # every frame's scan, kept only for wall_refinement
        self._node_scans: list = []  # every update's scan, kept only for loop_correction
        self._refined: NDArray[np.float64] | None = None  # every frame's pose after wall_refinement
        self._track_pose: NDArray[np.float64] | None = None  # last matched pose of the best particle, and its odometry
        self._track_odom: NDArray[np.float64] | None = None
        self._map_cache: tuple[tuple[int, int], OccupancyGrid] | None = None
        # islands > 1: independent filters fed the same frames; this one only picks among them.
        self._islands: list[GMapping] = []
        p = self.params
        # before any work: the particles' maps of every island, at the first map's size (they grow from there)
        check_allocation(p.islands * TiledMaps.estimate_bytes(p.particles, p.delta, (p.xmin, p.ymin, p.xmax, p.ymax)),
                         f"{p.islands} filter(s) of {p.particles} particle maps in {p.delta:g} m cells",
                         "islands, particles, delta")
        if self.params.islands > 1:
            one = replace(self.params, islands=1)
            self._islands = [GMapping(one, seed=island_seed(self.seed, k), sensor_model=self.sensor_model)
                             for k in range(self.params.islands)]

    @classmethod
    def auto_values(cls, params: GMappingParams, profile: Any) -> dict[str, tuple[Any, str]]:
        out: dict[str, tuple[Any, str]] = {}
        mode = params.between_updates
        per_update = profile.scans_per_travel(float(params.linearUpdate), float(params.angularUpdate))
        if per_update is not None and is_auto(mode):
            reach = profile.longest_return
            dense = per_update >= _GUIDED_SCANS_PER_UPDATE
            # a short-range laser's scan-to-map climb slides along corridors longer than its reach, and guided
            # makes every particle follow the slide (simulated office, URG-04LX: 6.5 m against 0.34 m matched)
            mode = "guided" if dense and reach >= _GUIDED_MIN_REACH else "matched"
            out["between_updates"] = (mode, f"{per_update:.1f} scans per filter update (median odometry step "
                                            f"{profile.step_m:.3f} m, {profile.step_rad:.3f} rad), laser reach "
                                            f"{reach:.1f} m (99th percentile of returns)")
        srt, stt = profile.odometry_heading_per_m, profile.odometry_heading_per_rad
        if srt is not None and stt is not None:
            # one number for both: the heading error over a filter update's motion (linearUpdate metres and
            # angularUpdate radians) per unit of that motion; the split between the two terms is poorly
            # determined by pairs that mostly travel or mostly turn
            lin, ang = float(params.linearUpdate), float(params.angularUpdate)
            per_unit = (srt * lin + stt * ang) / (lin + ang) if lin + ang > 0 else max(srt, stt)
            value = round(min(max(per_unit, _NOISE_FLOOR), _NOISE_CAP), 4)
            why = (f"the odometry's heading error measured on {profile.pairs} scan pairs ({srt:.4f} rad/m, "
                   f"{stt:.4f} rad/rad), {per_unit:.4f} per unit of an update's motion, within "
                   f"[{_NOISE_FLOOR}, {_NOISE_CAP}]")
            out["srt"] = (value, why)
            out["stt"] = (value, why)
        return out

    # ----------------------------------------------------------------- islands

    def island_scores(self) -> NDArray[np.float64]:
        """Per island, its best particle's accumulated log-likelihood per filter update (-inf before its first)."""
        return np.array([isl._weight_sum.max() / isl._nodes if isl._nodes else -math.inf for isl in self._islands])

    def best_island(self) -> GMapping:
        """The island reported (the first on a tie); this filter itself when it runs no islands."""
        return self._islands[int(np.argmax(self.island_scores()))] if self._islands else self

    # ----------------------------------------------------------------- the filter

    def _relocate(self, pose: NDArray[np.float64]) -> None:
        for island in self._islands:
            island._relocate(pose)
        self._put_at = pose.copy()

    def _put_down(self, odom: NDArray[np.float64]) -> None:
        """A relocation, now that the frame's odometry is known: every particle at the pose, no motion read in."""
        pose, self._put_at = self._put_at, None
        self._state[:] = pose
        self._update_poses[:] = pose
        self._odom = self._update_odom = odom
        self._track_pose, self._track_odom = pose.copy(), odom
        self._linear = self._angular = 0.0
        self.diagnostics.count("relocations")
        if self._frame_times:
            self._frame_breaks.append(len(self._frame_times))

    def update(self, frame: Frame) -> Mapping[str, float] | None:
        if self._islands:
            values = [isl.update(frame) for isl in self._islands]
            k = int(np.argmax(self.island_scores()))
            return None if values[k] is None else {**values[k], "island": float(k)}
        odom = frame.odometry
        if odom is None:
            self.diagnostics.count("frames_without_odometry")
            if self._maps is None:
                return None
            odom = self._odom  # no odometry: the particles stay where they are
        odom = np.asarray(odom, dtype=np.float64)
        if self._maps is None:
            return self._initialise(frame, odom)
        if self._put_at is not None:
            self._put_down(odom)
        # a jump is warned and counted, and the particles follow it (as GMapping does)
        delta, step, _ = self.odometry_step(self._odom, odom, self.params.jump_warning, frame.timestamp)
        if step == 0.0 and delta[2] == 0.0:
            self.diagnostics.count("stationary_frames")
        p = self.params
        self._odom = odom
        tracked = None
        guided = p.between_updates == "guided"
        # the beams are built once per scan, and only when something matches this scan
        beams = self._beams(frame.scan) if guided else None
        if guided:
            # the scan-matched increment replaces the odometry's in the motion model and the update gating
            before = self._track_start()[0]
            tracked = self._track(frame, beams)
            if tracked is not None:
                delta = se2.relative(before, tracked)
                step = math.hypot(delta[0], delta[1])
        draw_from_motion(self._state, delta, self.rng.standard_normal((self._n, 3)), p.srr, p.srt, p.str, p.stt)
        self._linear += step
        self._angular += abs(float(delta[2]))
        due = (self._linear >= p.linearUpdate or self._angular >= p.angularUpdate
               or (p.temporalUpdate >= 0.0 and frame.timestamp - self._last_update_time > p.temporalUpdate))
        values: dict[str, float] = {"updated": 0.0}
        if not guided and (due or p.between_updates == "matched"):
            beams = self._beams(frame.scan)
        if not due and p.between_updates == "matched":
            tracked = self._track(frame, beams)
        if beams is None and (due or p.between_updates != "odometry"):
            self.diagnostics.count("scans_without_valid_beam")
        rel = None
        if not due and tracked is not None:
            rel = se2.relative(self._node_poses[self._nodes - 1, self.best_particle()], tracked)
        if due:
            values = self._filter_update(frame, beams)
        self._store_frame(frame.timestamp, rel, frame.scan)
        return values

    def _initialise(self, frame: Frame, odom: NDArray[np.float64]) -> Mapping[str, float]:
        p = self.params
        scan = frame.scan
        self._max_range = p.maxRange if p.maxRange is not None else (
            scan.range_max - 0.01 if math.isfinite(scan.range_max) else _FALLBACK_MAX_RANGE)
        self._usable = p.maxUrange if p.maxUrange is not None else self._max_range
        self._state[:] = odom
        self._update_poses[:] = odom
        self._odom = self._update_odom = odom
        self._maps = TiledMaps(self._n, p.delta, (odom[0] + p.xmin, odom[1] + p.ymin, odom[0] + p.xmax,
                                                   odom[1] + p.ymax))
        # the first scan goes into one map that every particle then shares
        self._register(np.zeros(1, dtype=np.int64), scan)
        self._maps.resample(np.zeros(self._n, dtype=np.int64))
        self._last_update_time = frame.timestamp
        self._store_node(None, scan)
        self._store_frame(frame.timestamp, scan=scan)
        return {"updated": 1.0, "neff": float(self._n), "resampled": 0.0, "match_failures": 0.0,
                "tiles": float(self._maps.tiles_in_use)}

    def _register(self, which: NDArray[np.int64], scan) -> None:
        laser = se2.compose(self._state[which], scan.mount)
        ranges = np.broadcast_to(scan.ranges, (which.shape[0], scan.num_beams))
        self._maps.register(which, laser, ranges, scan.angles, max_range=self._max_range,
                            usable_range=self._usable, generate_map=self.params.generateMap)

    def _beams(self, scan) -> BeamSet | None:
        """The beams matching uses (GMapping's range limits and lskip) with their divisors; None if none is valid."""
        p = self.params
        r = scan.ranges
        with np.errstate(invalid="ignore"):
            use = (r > 0.0) & (r <= self._max_range) & (r <= self._usable)
            if p.match_range is not None:
                use &= r <= p.match_range
        use &= (np.arange(r.shape[0]) % (p.lskip + 1)) == p.lskip
        if not use.any():
            return None
        s = beam_sigmas(scan, self.sensor_model, 0.0)  # extra per-beam range noise, m (0 without a model)
        s2 = np.nan_to_num(2.0 * s * s)
        ends = None
        if p.flat_sigma > 0.0 and p.flat_ratio > 0.0:
            limit = min(self._max_range, self._usable, math.inf if p.match_range is None else p.match_range)
            ends = wall_ends(r, scan.angles, use, limit)
        return BeamSet(r, scan.angles, use, p.sigma + s2, p.lsigma + s2, np.nan_to_num(s * s), ends)

    def _track_start(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The last tracked pose of the best particle and the odometry there (its node after an update)."""
        if self._track_pose is None:
            return self._node_poses[self._nodes - 1, self.best_particle()], self._node_odom[self._nodes - 1]
        return self._track_pose, self._track_odom

    def _track(self, frame: Frame, beams: BeamSet | None) -> NDArray[np.float64] | None:
        """``between_updates``: the best particle's pose for this scan, hill-climbed on its own map.

        The climb starts from the last tracked pose moved on by the odometry since. None (odometry
        is used) when the scan has no valid beam (``beams`` None) or the match fails.
        """
        p = self.params
        if beams is None:
            return None
        best = self.best_particle()
        last, last_odom = self._track_start()
        start = se2.compose(last, se2.relative(last_odom, self._odom))
        maps = self._maps
        x, y, th, _, ok = match_one(maps.pool, maps.occ, maps.table, best, maps.origin[0], maps.origin[1],
                                    maps.resolution, p.kernelSize, start,
                                    np.asarray(frame.scan.mount, dtype=np.float64), beams.ex, beams.ey,
                                    beams.div_score, beams.div_like, p.lstep, p.astep, p.iterations,
                                    p.linearOdometryReliability,
                                    p.angularOdometryReliability, self._prior_info(p.tracking_prior, last_odom)[0],
                                    p.minimumScore)
        if not ok:
            self.diagnostics.count("tracking_failures")
            self._track_pose, self._track_odom = start, self._odom  # carry on from the odometry's pose
            return None
        pose = np.array([[x, y, th]])
        if self.params.flat_ratio > 0.0:  # skip building the arguments when it is off (every tracked scan)
            self._hold_flat(np.asarray(frame.scan.mount, dtype=np.float64), beams, np.array([best], dtype=np.int64),
                            start[None], pose, np.ones(1, dtype=np.bool_), np.zeros(1), count="degenerate_tracking",
                            since=last_odom)
        self._track_pose, self._track_odom = pose[0], self._odom
        return self._track_pose

    def _hold_flat(self, mount, beams: BeamSet, which, starts, poses, ok, like,
                   count: str = "degenerate_matches", since: NDArray[np.float64] | None = None) -> int:
        """``flat_ratio``: undo the climbs' moves along directions their score does not constrain; count them.

        ``flat_sigma``: the wall ends' pull along those directions, against the motion model's prior
        for the odometry increment since the last update (``since``: since the last tracked scan).
        """
        p = self.params
        if p.flat_ratio <= 0.0:
            return 0
        maps = self._maps
        flat = np.zeros(poses.shape[0], dtype=np.int64)
        reach = np.zeros((poses.shape[0], 3))
        end_info = 0.0
        if p.flat_sigma > 0.0:
            end_w = np.zeros(0)  # the wall ends' explicit term (two-sided), not the end points' distances
            end_info = 1.0 / p.flat_sigma ** 2
            prior = self._prior_info(1.0, since)[: poses.shape[0]]
            # where the map ends: the reach of the last update's scan from the laser of each map's pose there
            at_update = self._update_poses[which] if since is None else self._node_poses[self._nodes - 1, which]
            reach[:, :2] = se2.compose(at_update, mount)[:, :2]
            reach[:, 2] = self._usable - (2 * p.kernelSize + 1) * maps.resolution
        else:
            end_w, prior = np.zeros(0), np.zeros((poses.shape[0], 3))
        hold_flat_direction(maps.pool, maps.occ, maps.table, maps.origin[0], maps.origin[1], maps.resolution,
                            p.kernelSize, which, starts, poses, ok, mount, beams.ex, beams.ey,
                            beams.div_score, beams.div_like, maps.resolution, p.flat_ratio,
                            end_w, beams.ends, end_info, reach, prior, like, flat)
        held = int((flat > 0).sum())
        if held:
            self.diagnostics.count(count, held)
        return held

    def _filter_update(self, frame: Frame, beams: BeamSet | None) -> dict[str, float]:
        p = self.params
        scan = frame.scan
        maps = self._maps
        if beams is None:  # counted by update()
            return {"updated": 0.0}
        n = self._n
        out_poses = np.empty((n, 3))
        score, like, ok = np.empty(n), np.empty(n), np.empty(n, dtype=np.bool_)
        mount = np.asarray(scan.mount, dtype=np.float64)
        common = (maps.pool, maps.occ, maps.table, maps.origin[0], maps.origin[1], maps.resolution, p.kernelSize)
        climb = (mount, beams.ex, beams.ey, beams.div_score, beams.div_like, p.lstep, p.astep,
                 p.iterations, p.linearOdometryReliability,
                 p.angularOdometryReliability, self._prior_info(p.odometry_prior), p.minimumScore)
        match_particles(*common, self._state, *climb, out_poses, score, like, ok)
        if p.coarse_kernel > 0:
            # the same climb again from the coarse climb's pose; each particle keeps the higher score
            poses2, score2, like2, ok2 = np.empty((n, 3)), np.empty(n), np.empty(n), np.empty(n, dtype=np.bool_)
            match_particles(*common, self._coarse_climb(mount, beams), *climb, poses2, score2, like2, ok2)
            take = ok2 & (~ok | (score2 > score))
            out_poses[take], score[take], like[take] = poses2[take], score2[take], like2[take]
            ok |= ok2
        degenerate = self._hold_flat(mount, beams, np.arange(n, dtype=np.int64), self._state, out_poses, ok, like)
        failures = int(n - ok.sum())
        if failures:
            self.diagnostics.count("match_failures", failures)
        if p.proposal != "hill-climb" and ok.any():
            out_poses, like = self._gaussian(common, out_poses, like, ok, mount, beams)
        self._state = out_poses
        self._weight += like
        self._weight_sum += like
        w = normalized_weights(self._weight, 1.0 / (p.ogain * n))
        neff = effective_sample_size(w)
        h_w = weight_entropy(w)
        best_score = float(score[int(np.argmax(self._weight_sum))])
        resampled = neff < p.resampleThreshold * n
        parents = None
        if resampled:
            parents = systematic_resample(w, float(self.rng.random()))
            self._state = self._state[parents]
            self._weight_sum = self._weight_sum[parents]
            self._weight = np.zeros(n)
            maps.resample(parents)
            self.diagnostics.count("resamples")
        self._register(np.arange(n, dtype=np.int64), scan)
        self._linear = self._angular = 0.0
        self._last_update_time = frame.timestamp
        self._update_odom = self._odom
        self._update_poses = self._state.copy()
        self._track_pose = self._track_odom = None
        self._store_node(parents, scan)
        return {
            "updated": 1.0, "neff": neff, "entropy": published_entropy(self._weight), "weight_entropy": h_w,
            "resampled": float(resampled), "match_failures": float(failures), "degenerate_matches": float(degenerate),
            "best_score": best_score,
            "tiles": float(maps.tiles_in_use),
        }

    def _coarse_climb(self, mount, beams: BeamSet) -> NDArray[np.float64]:
        """``coarse_kernel``: every particle's second start for GMapping's climb, climbed on a wider score.

        The same climb at its first steps (``lstep``, ``astep``, no halving), but each beam looks for a
        map point within ``coarse_kernel`` cells: a particle whose walls lie beyond the ``kernelSize``
        window (a loop coming back to old map, a particle the motion noise put a few cells off) is
        moved into the basin the original climb then refines. A particle whose coarse climb fails
        starts from its own pose. The wider window alone also matches beams to the wrong wall in
        cluttered rooms, hence the second climb is only kept where it scores higher on the
        original's own score.
        """
        p = self.params
        maps = self._maps
        n = self._n
        out, score, like, ok = np.empty((n, 3)), np.empty(n), np.empty(n), np.empty(n, dtype=np.bool_)
        match_particles(maps.pool, maps.occ, maps.table, maps.origin[0], maps.origin[1], maps.resolution,
                        p.coarse_kernel, self._state, mount, beams.ex, beams.ey,
                        beams.div_score, beams.div_like, p.lstep, p.astep, 0, 0.0, 0.0,
                        self._prior_info(p.odometry_prior), 0.0, out, score, like, ok)
        return np.where(ok[:, None], out, self._state)

    def _prior_info(self, weight: float, since: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
        """Per particle, ``weight`` times the information of the odometry prior a climb weighs (zeros: off).

        The motion model's standard deviations for the whole odometry increment since the last
        update (``since``: the odometry where the climb's start was last matched, for the scans
        between updates), as one draw of ``drawFromMotion`` would have them, floored at 1 cm and 0.01 rad
        (standing still gives a finite prior, not a pose pinned to its start).
        """
        p = self.params
        info = np.zeros((self._n, 3))
        if weight > 0.0:
            origin = self._update_odom if since is None else since
            std = gmapping_motion_std(se2.relative(origin, self._odom), p.srr, p.srt, p.str, p.stt)
            info[:] = weight / np.maximum(std, _PRIOR_FLOOR) ** 2
        return info

    def _gaussian(self, common, optima, like, ok, mount, beams):
        """Improved proposal for the particles whose match succeeded: draw from tau's fitted Gaussian, weight by eta."""
        p = self.params
        delta = se2.relative(self._update_odom, self._odom)
        predicted = se2.compose(self._update_poses, delta)
        std = np.maximum(gmapping_motion_std(delta, p.srr, p.srt, p.str, p.stt), 1e-3)
        normals = self.rng.standard_normal((self._n, 3))
        sampled = np.empty_like(optima)
        logeta = np.empty(self._n)
        # the original's grid (+-1 cm, +-0.005 rad)
        fwd = left = np.arange(-p.llsamplerange, p.llsamplerange + 1e-12, p.llsamplestep)
        ang = np.arange(-p.lasamplerange, p.lasamplerange + 1e-12, p.lasamplestep)
        offsets = np.stack(np.meshgrid(fwd, left, ang, indexing="ij"), axis=-1).reshape(-1, 3)
        gaussian_proposal(*common, optima, predicted, std, offsets, mount, beams.ex, beams.ey,
                          beams.div_score, beams.div_like, normals, sampled, logeta)
        return np.where(ok[:, None], sampled, optima), np.where(ok, logeta, like)

    def _store_node(self, parents, scan) -> None:
        """Keep every particle's pose at this update, who descends from whom, and the scan."""
        k = self._nodes
        if k >= self._node_poses.shape[0]:
            self._node_poses = np.concatenate([self._node_poses, np.zeros_like(self._node_poses)])
            self._node_parents = np.concatenate([self._node_parents, np.zeros_like(self._node_parents)])
            self._node_odom = np.concatenate([self._node_odom, np.zeros_like(self._node_odom)])
        self._node_poses[k] = self._state
        self._node_parents[k] = np.arange(self._n) if parents is None else parents
        self._node_odom[k] = self._odom
        self._scans.append((scan.ranges, scan.angles, scan.mount))
        if self.params.loop_correction:
            self._node_scans.append(scan)
        self._nodes += 1

    def _store_frame(self, timestamp: float, rel: NDArray[np.float64] | None = None, scan=None) -> None:
        if self.params.wall_refinement:
            self._frame_scans.append(scan)
        self._frame_times.append(timestamp)
        self._frame_odom.append(self._odom)
        self._frame_node.append(self._nodes - 1)
        self._frame_rel.append(rel)

    # ----------------------------------------------------------------- outputs

    def best_particle(self) -> int:
        """Index of the particle with the largest accumulated log-likelihood (GMapping's best)."""
        return int(np.argmax(self._weight_sum))

    def current_pose(self) -> NDArray[np.float64] | None:
        """The best particle's pose at the last update, moved on by the odometry since (the ROS node's tf)."""
        if self._islands:
            return self.best_island().current_pose()
        if self._maps is None:
            return None
        node = self._node_poses[self._nodes - 1, self.best_particle()]
        if self._frame_rel and self._frame_rel[-1] is not None:
            return se2.compose(node, self._frame_rel[-1])
        return se2.compose(node, se2.relative(self._node_odom[self._nodes - 1], self._odom))

    def best_nodes(self) -> NDArray[np.float64]:
        """The best particle's pose at every update, through its ancestors (its trajectory tree path)."""
        if self._nodes == 0:
            return np.zeros((0, 3))
        return backtrack(self._node_poses[: self._nodes], self._node_parents[: self._nodes], self.best_particle())

    def trajectory(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The best particle's path: its tree nodes, and odometry composed onto the last node in between
        (after ``wall_refinement``, the refined path)."""
        if self._islands:
            return self.best_island().trajectory()
        if not self._frame_times:
            return np.zeros(0), np.zeros((0, 3))
        if self._refined is not None:
            return np.array(self._frame_times), self._refined.copy()
        nodes = self.best_nodes()
        k = np.asarray(self._frame_node)
        odom = np.stack(self._frame_odom)
        rel = se2.relative(self._node_odom[k], odom)
        matched = np.array([r is not None for r in self._frame_rel])
        if matched.any():  # between_updates=matched
            rel[matched] = np.stack([r for r in self._frame_rel if r is not None])
        return np.array(self._frame_times), se2.compose(nodes[k], rel)

    def map(self) -> OccupancyGrid:
        if self._islands:
            return self.best_island().map()
        key = (self._nodes, self.best_particle(), self._refined is not None)
        if self._map_cache is not None and self._map_cache[0] == key:
            return self._map_cache[1]
        grid = self._build_map()
        self._map_cache = (key, grid)
        return grid

    def _build_map(self) -> OccupancyGrid:
        p = self.params
        if self._maps is None:
            return OccupancyGrid(None)
        if p.map_output == "best-particle" and self._refined is None:
            hits, visits, origin = self._maps.dense(self.best_particle())
        else:
            path = self.best_nodes() if self._refined is None else self._refined[self._node_frames()]
            bounds = (path[0, 0] + p.xmin, path[0, 1] + p.ymin, path[0, 0] + p.xmax, path[0, 1] + p.ymax)
            rebuilt = TiledMaps(1, p.delta, bounds)
            groups: dict[tuple, list[int]] = {}
            for i, (ranges, angles, mount) in enumerate(self._scans):
                groups.setdefault((ranges.shape[0], angles[0], angles[-1], *mount), []).append(i)
            for members in groups.values():  # one compiled call per laser geometry
                laser = se2.compose(path[members], self._scans[members[0]][2])
                ranges = np.stack([self._scans[i][0] for i in members])
                rebuilt.register(np.zeros(len(members), dtype=np.int64), laser, ranges, self._scans[members[0]][1],
                                 max_range=self._max_range, usable_range=self._usable, generate_map=True)
            hits, visits, origin = rebuilt.dense(0)
        occ = np.full(hits.shape, -1, dtype=np.int16)
        seen = visits > 0
        occ[seen] = np.where(hits[seen] > p.occ_thresh * visits[seen], 100, 0)
        return OccupancyGrid.from_occupancy(occ, p.delta, origin)

    def _node_frames(self) -> NDArray[np.int64]:
        """The frame of every update (the first frame that follows its node)."""
        k = np.asarray(self._frame_node)
        return np.flatnonzero(np.r_[True, k[1:] != k[:-1]])

    def refine_walls(self) -> dict[str, float]:
        """``wall_refinement``: the best path over every frame refined jointly with straight walls fitted to
        the scans and the wall ends seen from several frames, tied by the odometry between frames
        (:mod:`slam2d.graph.wall_refinement`); the trajectory and map follow."""
        import time

        cpu = time.process_time()
        p = self.params
        _, poses = self.trajectory()
        # The wall-end detector's other settings are karto's defaults (gmapping has no wall_end_* parameters).
        detector = SimpleNamespace(**{**vars(WallEndParams()), **vars(p)})
        res, segs = refine_path(self._frame_scans, poses, p, odometry=np.stack(self._frame_odom),
                                odometry_breaks=np.asarray(self._frame_breaks, dtype=np.int64),
                                sensor_model=self.sensor_model, range_limit=self._usable, detector=detector)
        if np.all(np.isfinite(res.poses)):
            self._refined = res.poses
            self._map_cache = None
        else:
            self.diagnostics.count("optimizer_failures")
        return res.summary(segs.seg_node.size, time.process_time() - cpu)

    def step_information(self, steps: NDArray[np.float64]) -> NDArray[np.float64]:
        """``loop_correction``: the information of each step of the best path (in its first node's frame): the
        inverse of the motion model's (``srr``...``stt``) variances for that step, the spread the filter drew its
        particles with, times ``loop_correction_step_scale`` and floored at 1 cm and 0.005 rad."""
        p = self.params
        std = gmapping_motion_std(steps.reshape(-1, 3), p.srr, p.srt, p.str, p.stt) * p.loop_correction_step_scale
        std = np.maximum(std, _STEP_FLOOR)
        info = np.zeros((steps.shape[0], 3, 3))
        info[:, [0, 1, 2], [0, 1, 2]] = 1.0 / std**2
        return info

    def correct_loops(self) -> dict:
        """``loop_correction``: the best particle's path as a pose graph (a node per update, the path's own steps
        with the motion model's covariance), closed by karto's loop search and solved by SPA
        (:mod:`slam2d.graph.loop_correction`); the frames between updates get their nodes' corrections spread
        over them, and the trajectory and map follow."""
        p = self.params
        times, poses = self.trajectory()
        nodes = self.best_nodes()
        steps = se2.relative(nodes[:-1], nodes[1:])
        frames = self._node_frames()
        res = correct_path(self._node_scans, nodes, self._node_odom[: self._nodes], times[frames],
                           self.step_information(steps), p, sensor_model=self.sensor_model)
        summary = res.summary(nodes)
        if not np.all(np.isfinite(res.poses)):
            self.diagnostics.count("optimizer_failures")
        elif res.closures:
            anchor = np.asarray(self._frame_node)
            offset = se2.relative(nodes[anchor], poses)
            self._refined = spread_node_corrections(res.poses, steps, anchor, offset)
            self._map_cache = None
        return summary

    def finish(self) -> None:
        if self._islands:
            # Only the island reported is finished (its loop correction, wall refinement); its counters and
            # summary become this filter's, with every island's score.
            scores = self.island_scores()
            best = self.best_island()
            best.finish()
            self.diagnostics.counters.update(best.diagnostics.counters)
            self.diagnostics.summary.update(best.diagnostics.summary)
            self.diagnostics.summary["islands"] = {
                "reported": int(np.argmax(scores)), "seeds": [isl.seed for isl in self._islands],
                "scores": [float(v) for v in scores],
            }
            return
        if self.params.loop_correction and self._maps is not None and self._nodes > 1:
            self.diagnostics.summary["loop_correction"] = self.correct_loops()
        if self.params.wall_refinement and self._maps is not None and len(self._frame_times) > 1:
            self.diagnostics.summary["wall_refinement"] = self.refine_walls()
        if self._maps is not None:
            self.diagnostics.summary["map_tiles_peak"] = self._maps.peak_tiles
            self.diagnostics.summary["map_tile_references"] = self._maps.tile_references
            self.diagnostics.summary["map_pool_mb"] = self._maps.nbytes / 1e6
