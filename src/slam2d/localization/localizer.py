"""Localization in a fixed map: a Monte Carlo localizer (AMCL-like) and scan-to-map tracking.

``mcl``: a particle filter on the map's likelihood field. Particles move with GMapping's odometry
noise model, are weighed by the likelihood-field beam model (tempered: the beams of one scan are not
independent), resampled when their effective number falls under half, and their number adapts to
their spread (KLD sampling, Fox 2003: 100 when they agree, up to ``max_particles`` while they search).
While searching, random particles are mixed in when the scans fit the particles much worse than
they used to (the short-term average likelihood under the long-term one, Thrun et al.'s augmented
MCL). The reported pose is tracked by matching the scan to the map; where the particles gather
elsewhere, their place takes over only when the scans' likelihood there leads clearly, update after
update.

``match``: the pose of the last scan moved by the odometry, refined by matching the scan to the map
(Gauss-Newton on the distance field, from a few starting offsets when the fit is poor), as
slam_toolbox's localization mode tracks.

Without an initial pose the particles spread over the map's free space, and every place they gather
becomes a hypothesis, tracked by matching and scored by the likelihood of the scans there (a place found
late also on the earlier scans, along its path traced back through the odometry) and of the odometry given how far
the matching moved it from the odometry's prediction; every few updates,
and before one wins, the scan is scored over the whole free space for places the particles missed. One
wins when it leads every other clearly (a symmetric building keeps two alive until the scans tell them
apart). Either way a scan whose endpoints miss the map's walls (``lost_fit``) for ``lost_after`` scans in a
row means the robot is lost: the localizer says so and searches again, near where the odometry took it (it
drifted off the map's walls). Three scans in a row that miss them by far mean it was carried off: the particles
spread over the map's free space. A robot carried to where its scans fit the map as well (a twin of its corridor)
is noticed when they stop fitting well: the whole map is checked for places whose paths fit the last updates' scans
clearly better; any there and it is lost, searched for among them. Where a localized robot's scans end mostly
outside the map's known area (``_MIN_KNOWN``) it is off the map: its pose follows the odometry (state
``off_map``, reported with that state) until the scans reach the map again and matching takes over, or a place near
where the odometry took it fits the last updates' scans clearly better than any other (the odometry drifted it off
the map meanwhile). Matching never moves the tracked pose further from the odometry's prediction than the motion
model allows (``_REACH``). Poses are reported only while localized or off the map.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slam2d.core import se2
from slam2d.errors import InputError
from slam2d.grids.likelihood_field import LikelihoodField, likelihood_field
from slam2d.localization.kernels import (fit_fraction, particle_log_likelihoods, refine_on_field,
                                         scan_log_likelihood_grid, slide_cost, traced_path_log_likelihood)
from slam2d.params import param
from slam2d.sensors.motion_noise import draw_from_motion, gmapping_motion_std

__all__ = ["LocalizationParams", "Localizer", "ScanResult", "STATES"]

STATES = ("searching", "localized", "off_map", "lost")

# GMapping's odometry noise (srr, srt, str, stt): the same motion model the particle filters share
_MOTION_NOISE = (0.1, 0.2, 0.1, 0.2)
# Each scan's mean log-likelihood per beam counts as this many independent beams (tempering: the
# beams of one scan share the map's errors; the product of all of them makes the filter overconfident)
_INDEPENDENT_BEAMS = 1.0
_Z_HIT, _Z_RAND = 0.95, 0.05
# augmented MCL: long- and short-term averages of the scans' likelihood (AMCL's recovery_alpha_*)
_ALPHA_SLOW, _ALPHA_FAST = 0.001, 0.1
# KLD sampling: histogram bins (m, m, rad), error bound and its 99 % quantile (AMCL's kld_err, kld_z)
_KLD_BIN = (0.5, 0.5, math.radians(10.0))
_KLD_ERROR, _KLD_Z = 0.01, 2.326
# the pull of the predicted pose in matching, against the endpoints' unit weights (m^2 per m^2, m^2 per rad^2):
# (0.05 m of endpoint noise / 0.1 m of prediction error)^2, (0.05 m / 0.05 rad)^2
_PRIOR_XY, _PRIOR_TH = 0.25, 1.0
# the tracked pose's pull where its prediction fits less than _EDGE_FIT of the scan (a map's edge). Off: 0.6 and 4.0
# (`benchmarks/localization.py --set _EDGE_FIT=0.6 --set _EDGE_PRIOR_XY=4.0`) brought fr079 in gmapping's map to
# 0.099 m but aces in karto's to 0.31-0.34 m (0.288) and intel's mcl in gmapping's to 0.126 m (0.107)
_EDGE_FIT, _EDGE_PRIOR_XY = 0.0, 4.0
# ... and whether the tracked pose is matched with only the endpoints in the map's known area (those beyond it are
# pulled to the nearest known wall). Off: on (--set _KNOWN_ENDS_ONLY=1), fr079 in gmapping's map 0.811 / 0.108 m
# (mcl / match) -> 0.105 / 0.106 m, but karto's short-range map of the office 0.046 -> 0.050 m, fr079 in karto's
# map 0.119 -> 0.125 m, the corridor loop's continued karto map 0.093 -> 0.114 m
_KNOWN_ENDS_ONLY = 0
# ... and of a search's hypotheses and the paths traced back for them: as loose. The simulated odometry errs by 0.031 m
# and 0.055 rad (RMS) over one scan's step of 0.08 m (GMapping's noise defaults; office's drive 2 of
# benchmarks/localization.py), and the true place's path must follow it. Tighter (10, 40: 0.016 m, 0.008 rad) held the twins' paths too: corridor-loop's search in
# karto's map of drive 1 ended at scan 130 of 637, not 266, and its kidnapping was found again after 86 scans, not 162,
# but office's half-turn twin won one search in nine (localization.py / localization_search.py, NAME=VALUE); the
# position alone (10, 1.0): scan 130 and 141 scans, and the same one search in nine
_SEARCH_PRIOR_XY, _SEARCH_PRIOR_TH = _PRIOR_XY, _PRIOR_TH
# ... but a path pays for each step matching moved it from the odometry's prediction (m, and m per m of travel: the
# std of a Gaussian on each axis). Matched at every step, a twin of the true place fits the scans nearly as well by
# sliding along its corridors: over 10 filter updates the true path slid 0.11-0.17 m (RMS) from the odometry, its
# twins 0.3-1.5 m (corridor-loop and office, karto's maps of drive 1). Without it corridor-loop's search in karto's
# map ended at scan 266 of 637, with it at 44; office's at 94 and 78 of 680 (true map: 94 and 41); corridor-loop's
# kidnapping was found again after 162 scans, now 87-93; aces's second half was never localized, now at 43 %.
# Looser (0.1, 1.0): office's true map at 12 %, the kidnapping after 115-133 scans (benchmarks/localization.py)
# (one odometry reading a step: not tempered as the scans are; _INDEPENDENT_BEAMS, which also scales the traced
# paths' sums, is 1)
_SLIDE_STD = (0.05, 0.5)
# how far matching may move the tracked pose from the odometry's prediction, beyond three times the motion model's
# spread over the step (m, rad): at a map's edge, where few beams reach its walls, the best of the matcher's starts
# turned intel's second half 30-85 degrees a scan against the odometry while it turned in place, and it left the map
# facing backwards. A match beyond it in position is taken where nothing within fits (_FOUND_FIT) and it does: held
# by the prior along corridor-loop's corridor in karto's map, the pose slid 0.3 m from the walls' ends, and at the
# next junction the walls put it 0.44 m on; refused, it turned away and was lost. A wider reach (0.5 m) instead:
# fr079's ATE 0.148 m, not 0.119, intel's 0.34 m, not 0.29
_REACH = (0.2, 0.15)
# ... and it must fit clearly better than the best within reach: where it led by less, it was a turn at a map's
# edge fitting alike 0.5 m away (fr079's second half in gmapping's map, 0.77 against 0.81: 9 scans 0.5 m off)
_BEYOND_LEAD = 0.1
# filter updates in a row (each after some travel) the particles must agree before a search ends: one scan
# of a symmetric building fits in several places, motion tells them apart. Back on the map after a drive off it
# (metres of spread), they must gather on one place at as many updates in a row: once was enough for fr079's second
# half in gmapping's map of its first to take a place 6 m off (15 scans there, ATE 0.811 -> 0.094 m); intel's in
# gmapping's map 2.02 -> 0.107 m (`match`)
_CONFIRM_UPDATES = 5
# scans in a row under half the lost floor that make the robot lost at once (carried off)
_FAR_MISFITS = 3
_DRIFTED_STD = (2.0, 2.0, 0.5)  # m, m, rad: where a robot that drifted off the map's walls is looked for first
# ... and the place found must lie within 3 m plus 20 % of the odometry's travel since of where the odometry says
# it went: off the map (fr079's second half in the map of its first) a room alike another 20 m away fits as well
_DRIFT_RADIUS = (3.0, 0.2)
# the fraction of a scan on the map's walls a found place needs, at each of those updates (a right place fits
# 0.9-1.0 in the simulated worlds and in fr079's mapped parts; wrong places that passed a 0.5 fit 0.45-0.75)
_FOUND_FIT = 0.8
# a localized scan fitting at least this much of the map holds a resumed mapping method there (map_anchor)
_ANCHOR_FIT = 0.8
# from a given initial pose: found when this share of the weight gathers within 1 m
_FOUND_SHARE = 0.5
# while searching, resampled only when the particles' effective number falls under this share: resampling
# more often lost a place's symmetric twin before the scans told them apart (benchmarks/localization_search.py:
# 2 of 9 drives settled in the wrong place at 0.5, 1 of 9 at 0.1)
_SEARCH_NEFF = 0.1
# a global search's hypotheses: at most this many; one wins when it leads every other by _HYPOTHESIS_MARGIN in
# summed log-likelihood (a factor e^3 = 20); one trailing the best by _HYPOTHESIS_DROP is dropped
_MAX_HYPOTHESES = 12
_HYPOTHESIS_MARGIN = 3.0
_HYPOTHESIS_DROP = 8.0
# a hypothesis found during a search is scored on the scans before it too, along its path traced back through the
# odometry and matched to the map at each step: at most this many filter updates back. Starting newcomers level with the best instead kept
# corridor-loop's search open until 44 % of its scans, though the scans had ruled out every twin by 14 %
# (benchmarks/localization_bound.py)
_SEARCH_HISTORY = 400
# a place whose path traced back through the odometry (matched to the map at each step, as the search scores it) puts
# over _THROUGH_WALLS of its poses within _WALL_CLEARANCE (m) of the map's walls is refused: the robot did not drive
# through them. In the Mines logs' first-half maps (rooms of rough rock walls alike) the second half, which drives a
# room the first never saw, was placed 13 m off, the scans fitting 81-86 %: 12 and 28 % of its traced poses lay on
# walls. The places found in the simulated worlds and on fr079, intel, aces, csail and fr101: none (at most 3 % within
# 0.2 m)
_WALL_CLEARANCE = 0.1
_THROUGH_WALLS = 0.05
# ... so a search that has met its margin has compared the winner only with the places its particles found. Before it
# ends, the scan is scored over the whole free space (every _RIVAL_STEP m, every _RIVAL_TURN rad) and the best
# _RIVALS places elsewhere are traced back as hypotheses are: one within the margin keeps the search open
_RIVAL_STEP = 0.25
_RIVAL_TURN = math.radians(2.5)
_RIVALS = 24
# ... and every _RIVAL_EVERY filter updates of a search, places the particles have not found are looked for so
_RIVAL_EVERY = 10
# while localized, the localizer doubts the tracked pose when it fitted a stretch of the last _DOUBT_HISTORY filter
# updates' scans (the last _DOUBT_MIN, ... of them) under the search's margin in summed log-likelihood, and checks, at
# most every _RIVAL_EVERY updates: the whole map is scored (as before a search ends) for places whose paths, traced
# back over such a stretch, fit it better than the tracked pose's by the margin, and nearly perfectly (a summed
# log-likelihood over _DOUBT_FLOOR; every beam on a wall scores 0). Any there and the robot is lost: a global search
# goes on with the longest such stretch, the tracked pose and those places as its hypotheses. A robot carried into a
# twin of its corridor (corridor-loop) fits the map where it is believed for 50 scans and more, until the twin's walls
# end; the lost test (fits under half the usual, 10 scans in a row) never fired there. Stretches, not the whole
# history: the scans before the robot was carried off fit the tracked pose, not the place it was carried to.
# The tracked pose of the simulated worlds' drives scores -0.2 and over in any 30 updates in their true maps, -1.5
# and over in karto's maps of them: never doubted. In fr079's half-mapped rooms it is, and places 11-19 m off led it
# by the margin at -1 to -1.8 over 12-13 updates and at -2.3 to -10 over 20-30. So a kidnapping is noticed in a map
# that fits the right place nearly perfectly (a simulated world's true map, benchmarks/studies/localization_kidnap.py),
# not in one that fits it as loosely as karto's
_DOUBT_HISTORY = 30
_DOUBT_MIN = 20
_DOUBT_FLOOR = -1.0
# the share of a scan's beams that must end in the map's known area (each end pulled back _KNOWN_PULL towards the
# laser: an end on a wall lies half in the unknown behind it) for matching to place the robot. Under it the robot
# is off the map and its pose follows the odometry: matching the few beams that reach the map slid fr079's second
# half 1-3 m into a mapped room while it drove through a hall its first half never saw (share there 0.05-0.17 at
# the reference poses; 0.22-0.47 in the 10 % worst scans of the parts that were mapped)
_MIN_KNOWN = 0.2
_KNOWN_PULL = 0.3
# ... and the share that brings it back: matching from a dead-reckoned pose on a fifth of a scan slid as well
_BACK_KNOWN = 0.4
# back on the map after more odometry than this (m) off it, the robot is searched for around where the odometry
# took it, as from a given initial pose spread by a tenth of that travel (a match from there settled 4-12 m off
# in fr079 after 50 m off the map)
_OFF_MAP_TRUST = 1.0
# the particles put around a found place (mcl goes on from there)
_FOUND_STD = (0.1, 0.1, 0.05)
# the spread (std) of the particles put around a given initial pose (AMCL's initial_cov: 0.5 m, pi/12)
_INITIAL_STD = (0.5, 0.5, math.pi / 12.0)


@dataclass
class LocalizationParams:
    """How ``slam2d localize`` finds and tracks the robot in a fixed map."""

    method: str = param("mcl", choices=("mcl", "match"),
                        help="mcl: particle filter (AMCL-like); match: scan-to-map matching (slam_toolbox-like)")
    min_particles: int = param(100, low=1, help="particles kept once they agree (mcl; AMCL's min_particles)")
    max_particles: int = param(5000, low=10, help="particles while searching (AMCL's max_particles)")
    beams: int = param(60, low=3, help="beams per scan the particle filter weighs (AMCL's laser_max_beams)")
    match_beams: int = param(180, low=3, help="beams per scan matched to the map")
    hit_sigma: float = param(0.2, unit="m", low=0.001, help="spread of a beam's endpoint around a wall (AMCL's laser_sigma_hit)")
    update_distance: float = param(0.1, unit="m", low=0.0, help="travel between particle filter updates")
    update_angle: float = param(0.15, unit="rad", low=0.0, help="turn between particle filter updates")
    lost_fit: float = param(0.3, low=0.0, high=1.0,
                            help="fraction of endpoints within 2 cells of a wall under which a scan does not fit "
                            "(or half the last 100 scans' median fit, when higher)")
    lost_after: int = param(10, low=1, help="scans in a row that do not fit before the robot counts as lost "
                            "(3 in a row that fit under half of that are enough: a robot carried off)")


    def is_update(self, delta: NDArray[np.float64]) -> bool:
        """Whether the odometry increment ``delta`` since the last filter update calls for the next one."""
        return math.hypot(delta[0], delta[1]) >= self.update_distance or abs(delta[2]) >= self.update_angle

@dataclass
class ScanResult:
    """What the localizer says about one scan."""

    timestamp: float
    state: str  # one of STATES
    pose: NDArray[np.float64] | None  # in the map frame; None unless localized
    fit: float  # fraction of endpoints on the map's walls at the reported (or best) pose
    spread: float  # particles' position spread (m); NaN when the filter is not running
    particles: int  # 0 when the filter is not running


class Localizer:
    """Feed frames (scan + odometry) in time order; each gets a :class:`ScanResult`."""

    def __init__(self, grid: Any, params: LocalizationParams | None = None, *, seed: int = 0,
                 initial_pose: NDArray[np.float64] | None = None) -> None:
        self.p = p = params if params is not None else LocalizationParams()
        if p.min_particles > p.max_particles:
            raise InputError(f"min_particles {p.min_particles} is above max_particles {p.max_particles}",
                             field="min_particles")
        self.rng = np.random.default_rng(seed)
        self.resolution = float(grid.resolution)
        self.near = 2.0 * self.resolution + 0.02  # "on a wall": within two cells (and 2 cm)
        self.field: LikelihoodField = likelihood_field(grid, max_distance=max(1.0, 5.0 * p.hit_sigma))
        self.inv_two_sigma2 = 1.0 / (2.0 * p.hit_sigma ** 2)  # the beam model's exponent scale
        self.known = np.ascontiguousarray(grid.observed)
        free = np.argwhere(grid.observed & ~grid.occupied(0.5) & (grid.occupancy() <= 25))
        if len(free) == 0:
            raise InputError("the map has no free cell to place the robot in", field="map")
        ox, oy = self.known_origin = grid.origin
        self.free_xy = np.column_stack([ox + (free[:, 1] + 0.5) * self.resolution,
                                        oy + (free[:, 0] + 0.5) * self.resolution])
        every = max(1, int(round(_RIVAL_STEP / self.resolution)))
        self.rival_xy = np.ascontiguousarray(self.free_xy[(free[:, 0] % every == 0) & (free[:, 1] % every == 0)])
        self.rival_headings = np.arange(-math.pi, math.pi, _RIVAL_TURN)
        self.rival_table: NDArray[np.float64] | None = None  # each cell's beam log-likelihood, drawn at the first check
        self.particles = np.zeros((0, 3))
        self.log_w = np.zeros(0)
        self.w_slow = self.w_fast = 0.0
        self.filter_odom: NDArray[np.float64] | None = None  # odometry at the last filter update
        self.last_odom: NDArray[np.float64] | None = None
        self.pose: NDArray[np.float64] | None = None  # the last reported pose (map frame)
        self.state = "searching"
        self.misfits = 0
        self.far_misfits = 0  # scans in a row under half the lost floor (a robot carried off)
        self.events: list[dict[str, Any]] = []  # when it was localized, lost, found again
        self.hypotheses: list[dict[str, Any]] = []  # a global search's candidate places (see _track_hypotheses)
        # the search's scans: (odometry, matched endpoints x, y), to score a newcomer's path before it was found
        self.search_scans: deque[tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]] = deque(
            maxlen=_SEARCH_HISTORY)
        self.recent_fits: deque[float] = deque(maxlen=100)  # the fits of the last scans while localized
        # while localized: the last filter updates' scans (as search_scans), to check a doubtful pose (_doubt)
        self.track_scans: deque[tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]] = deque(
            maxlen=_DOUBT_HISTORY)
        self.track_ll: deque[float] = deque(maxlen=_DOUBT_HISTORY)  # ... and the tracked pose's log-likelihood there
        self.doubt_wait = 0  # updates until the next check
        self.challenger: dict[str, Any] | None = None  # while localized (mcl): where the particles say instead
        # a robot that drifted off the map's walls: where the odometry has taken it since, and how far it went
        self.drifted: tuple[NDArray[np.float64], float] | None = None
        self.off_travel = 0.0  # odometry travel (m) since the robot went off the map
        self.restart(initial_pose, said=False)

    def restart(self, initial_pose: NDArray[np.float64] | None = None, *, t: float | None = None,
                said: bool = True) -> None:
        """Search again: around ``initial_pose`` (as RViz's "2D Pose Estimate" sends it), or over the whole map."""
        self.state, self.pose, self.misfits, self.far_misfits = "searching", None, 0, 0
        self.drifted = None
        self.gathered = None
        self.hypotheses, self.challenger, self.filter_odom = [], None, None
        self.search_scans.clear()
        self.search_updates = 0
        self.recent_fits.clear()
        self._forget_track()
        self.w_slow = self.w_fast = 0.0
        self.confirm = 1 if initial_pose is not None else _CONFIRM_UPDATES
        if initial_pose is not None:
            self._spread_around(np.asarray(initial_pose, dtype=np.float64))
        else:
            self._spread_globally()
        if said:
            where = "the whole map" if initial_pose is None else "({:.2f}, {:.2f}, {:.2f})".format(*initial_pose)
            self.events.append({"time": t, "state": "searching", "why": f"restarted around {where}"})

    # -- particles ------------------------------------------------------------------------------

    def _spread_globally(self) -> None:
        n = self.p.max_particles
        cells = self.rng.integers(0, len(self.free_xy), n)
        jitter = self.rng.uniform(-0.5, 0.5, (n, 2)) * self.resolution
        self.particles = np.column_stack([self.free_xy[cells] + jitter, self.rng.uniform(-np.pi, np.pi, n)])
        self.log_w = np.zeros(n)

    def _spread_around(self, pose: NDArray[np.float64], std: tuple[float, float, float] = _INITIAL_STD,
                       count: int = 500) -> None:
        n = max(self.p.min_particles, min(self.p.max_particles, count))
        self.particles = pose + self.rng.standard_normal((n, 3)) * np.asarray(std)
        self.particles[:, 2] = se2.wrap_angle(self.particles[:, 2])
        self.log_w = np.zeros(n)

    def _weights(self) -> NDArray[np.float64]:
        w = np.exp(self.log_w - self.log_w.max())
        return w / w.sum()

    def _kld_count(self, poses: NDArray[np.float64]) -> int:
        """How many particles the spread of ``poses`` needs (KLD sampling), within the configured bounds."""
        keys = np.floor(poses / np.asarray(_KLD_BIN)).astype(np.int64)
        k = len(np.unique(keys[:, 0] * 1_000_003 * 1_009 + keys[:, 1] * 1_009 + keys[:, 2], axis=0))
        if k <= 1:
            n = self.p.min_particles
        else:
            a = 2.0 / (9.0 * (k - 1))
            n = int(math.ceil((k - 1) / (2.0 * _KLD_ERROR) * (1.0 - a + math.sqrt(a) * _KLD_Z) ** 3))
        return int(min(self.p.max_particles, max(self.p.min_particles, n)))

    def _resample(self) -> None:
        w = self._weights()
        # systematic resampling of a first draw, then as many as its spread needs (KLD)
        n = self._kld_count(self.particles)
        picked = self.particles[np.minimum(np.searchsorted(np.cumsum(w), (self.rng.random() + np.arange(n)) / n),
                                           len(w) - 1)]
        # augmented MCL: random particles in proportion to how much worse the scans fit lately
        # (only while searching: once localized, random particles gathered on wrong places that fit a scan at
        # the map's edge better than the right one, fr079; a carried-off robot is found by the lost rule)
        inject = max(0.0, 1.0 - self.w_fast / self.w_slow) if self.w_slow > 0 and self.state != "localized" else 0.0
        randoms = int(self.rng.binomial(n, inject)) if inject > 0 else 0
        if randoms:
            cells = self.rng.integers(0, len(self.free_xy), randoms)
            picked[:randoms] = np.column_stack([self.free_xy[cells], self.rng.uniform(-np.pi, np.pi, randoms)])
            self.w_fast = self.w_slow  # AMCL resets the short-term average after injecting
        self.particles = picked
        self.log_w = np.zeros(n)

    def _filter_update(self, delta: NDArray[np.float64], bx: NDArray[np.float64], by: NDArray[np.float64]) -> None:
        draw_from_motion(self.particles, delta, self.rng.standard_normal(self.particles.shape), *_MOTION_NOISE)
        tempered = _INDEPENDENT_BEAMS * self._log_likelihoods(self.particles, bx, by)
        self.log_w = self.log_w + tempered
        w_avg = float(np.mean(np.exp(tempered)))
        self.w_slow = w_avg if self.w_slow == 0 else self.w_slow + _ALPHA_SLOW * (w_avg - self.w_slow)
        self.w_fast = w_avg if self.w_fast == 0 else self.w_fast + _ALPHA_FAST * (w_avg - self.w_fast)
        w = self._weights()
        # while searching, resampled only when few particles carry the weight: a place and its symmetric twin
        # keep their particles until the scans tell them apart
        if 1.0 / float(np.sum(w * w)) < (_SEARCH_NEFF if self.state != "localized" else 0.5) * len(w):
            self._resample()

    def _log_likelihoods(self, poses: NDArray[np.float64], bx, by) -> NDArray[np.float64]:
        """The mean log-likelihood per beam of the scan (endpoints ``bx, by``) at each of ``poses``."""
        f = self.field
        ll = np.empty(len(poses))
        particle_log_likelihoods(f.distance, f.origin[0], f.origin[1], f.resolution, f.max_distance, poses,
                                 bx, by, self.inv_two_sigma2, _Z_HIT, _Z_RAND, ll)
        return ll

    def _mean_pose(self, sel: NDArray[np.bool_], w: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray]:
        """The weighted mean pose of the selected particles (circular mean heading) and their weights."""
        ws = w[sel] + 1e-300
        xy = np.average(self.particles[sel, :2], axis=0, weights=ws)
        th = math.atan2(float(np.sum(ws * np.sin(self.particles[sel, 2]))),
                        float(np.sum(ws * np.cos(self.particles[sel, 2]))))
        return np.array([xy[0], xy[1], th]), ws

    def _cluster(self) -> tuple[NDArray[np.float64], float, float]:
        """The heaviest cluster's mean pose, its share of the weight and its position spread (std, m)."""
        w = self._weights()
        keys = np.floor(self.particles[:, :2] / 1.0).astype(np.int64)  # 1 m bins
        _, inverse = np.unique(keys, axis=0, return_inverse=True)
        inverse = inverse.reshape(-1)
        heaviest = int(np.argmax(np.bincount(inverse, weights=w)))
        seed_xy = np.average(self.particles[inverse == heaviest, :2], axis=0, weights=w[inverse == heaviest] + 1e-300)
        near = np.hypot(*(self.particles[:, :2] - seed_xy).T) < 1.0
        mean, wn = self._mean_pose(near, w)
        spread = math.sqrt(float(np.average(np.sum((self.particles[near, :2] - mean[:2]) ** 2, axis=1), weights=wn)))
        return mean, float(w[near].sum()), spread

    # -- matching ----------------------------------------------------------------------------------

    def _fit(self, pose: NDArray[np.float64], bx, by) -> float:
        f = self.field
        return float(fit_fraction(f.distance, f.origin[0], f.origin[1], f.resolution, f.max_distance,
                                  float(pose[0]), float(pose[1]), float(pose[2]), bx, by, self.near))

    def _known_share(self, pose: NDArray[np.float64], bx, by) -> float:
        """The share of the endpoints (each pulled back ``_KNOWN_PULL`` towards the laser) in the map's known cells."""
        return float(np.count_nonzero(self._known_ends(pose, bx, by))) / max(len(bx), 1)

    def _known_ends(self, pose: NDArray[np.float64], bx, by) -> NDArray[np.bool_]:
        """Per endpoint, whether it (pulled back ``_KNOWN_PULL`` towards the laser) lies in the map's known cells."""
        rng = np.hypot(bx, by)
        pull = np.maximum(rng - _KNOWN_PULL, 0.0) / np.maximum(rng, 1e-9)
        ends = se2.transform_points(pose, np.column_stack([bx * pull, by * pull]))
        col = np.floor((ends[:, 0] - self.known_origin[0]) / self.resolution).astype(np.int64)
        row = np.floor((ends[:, 1] - self.known_origin[1]) / self.resolution).astype(np.int64)
        inside = (row >= 0) & (col >= 0) & (row < self.known.shape[0]) & (col < self.known.shape[1])
        known = np.zeros(len(bx), dtype=bool)
        known[inside] = self.known[row[inside], col[inside]]
        return known

    def _refine(self, pose: NDArray[np.float64], bx, by, *, wide: bool, prior: tuple[float, float] | None = None,
                reach: tuple[float, float] | None = None, edge: bool = False) -> tuple[NDArray[np.float64], float]:
        """The matched pose near ``pose`` and its fit; from several starts when ``wide`` or the first fits poorly.
        ``prior``: the pull of ``pose`` (m^2 per m^2, m^2 per rad^2; the tracked pose's when None). ``reach`` (m, rad):
        a matched pose further from ``pose`` is not taken. ``edge``: the tracked pose's match (_EDGE_FIT)."""
        prior = (_PRIOR_XY, _PRIOR_TH) if prior is None else prior
        f = self.field
        best, best_fit = pose, self._fit(pose, bx, by)
        if edge and best_fit < _EDGE_FIT:
            prior = (_EDGE_PRIOR_XY, prior[1])
        starts = [(0.0, 0.0, 0.0)]
        if wide or best_fit < 0.8:
            starts += [(dx, dy, dt) for dx in (-0.2, 0.0, 0.2) for dy in (-0.2, 0.0, 0.2) for dt in (-0.15, 0.0, 0.15)
                       if (dx, dy, dt) != (0.0, 0.0, 0.0)]
        beyond, beyond_fit = pose, 0.0  # the best match out of reach
        rx, ry = bx, by
        if edge and _KNOWN_ENDS_ONLY:
            known = self._known_ends(pose, bx, by)
            if np.count_nonzero(known) >= 10:
                rx, ry = np.ascontiguousarray(bx[known]), np.ascontiguousarray(by[known])
        for dx, dy, dt in starts:
            x, y, th, used = refine_on_field(f.distance, f.origin[0], f.origin[1], f.resolution, f.max_distance,
                                             float(pose[0] + dx), float(pose[1] + dy), float(pose[2] + dt),
                                             rx, ry, 20, 0.1, pose, *prior)
            if used < 10:
                continue
            cand = np.array([x, y, th])
            fit = self._fit(cand, bx, by)
            if reach is not None and not _near(cand, pose, *reach):
                if fit > beyond_fit and _near(cand, pose, math.inf, reach[1]):
                    beyond, beyond_fit = cand, fit
                continue
            # the first start's match is taken when it fits no worse: the share of endpoints on walls saturates
            # (every one within two cells), the squared distances the match minimised do not (kept only when it
            # fitted better, the tracked pose followed the odometry within the cells: karto's short-range maps of
            # corridor-loop and office 0.042 and 0.046 m, now 0.036 and 0.044). Another start must fit clearly
            # better: in a corridor many fit alike, and picking the best of them scan after scan walks the pose along it
            if fit >= best_fit if (dx, dy, dt) == (0.0, 0.0, 0.0) else fit > best_fit + 0.05:
                best, best_fit = cand, fit
        # ... but where nothing in reach fits and a match beyond it (in position, not heading) does, the pose had slid
        # where the walls said nothing (along a corridor, held by the prior) and the walls now say where it is
        if best_fit < _FOUND_FIT <= beyond_fit and beyond_fit >= best_fit + _BEYOND_LEAD:
            return beyond, beyond_fit
        return best, best_fit

    def match(self, scan: Any, pose: NDArray[np.float64]) -> tuple[NDArray[np.float64], float]:
        """The pose near ``pose`` where ``scan`` (a LaserScan) fits the map, matched as the tracked pose is (from
        ``pose`` alone, held by the same prior), and the share of its endpoints on the map's walls there."""
        mx, my = self._beams(scan.points_in_base(), self.p.match_beams)
        if len(mx) < 10:
            return np.asarray(pose, dtype=np.float64).copy(), float("nan")
        return self._refine(np.asarray(pose, dtype=np.float64), mx, my, wide=False)

    def _through_walls(self, pose: NDArray[np.float64], scans: Sequence) -> float:
        """The share of the path traced back from ``pose`` over ``scans`` (odometry, matched endpoints), as a search
        traces a place back, whose poses lie on the map's walls (within _WALL_CLEARANCE of an occupied cell)."""
        scans = list(scans)
        if len(scans) < 2:
            return 0.0
        poses = self._trace(pose, scans)
        return float(np.mean(self.field.lookup(poses[:, :2]) < _WALL_CLEARANCE))

    def _trace(self, pose: NDArray[np.float64], scans: Sequence) -> NDArray[np.float64]:
        """The poses of ``scans`` (odometry, matched endpoints x, y) when the last is at ``pose`` (:meth:`traced_back`)."""
        poses = np.empty((len(scans), 3))
        poses[-1] = pose
        for k in range(len(scans) - 2, -1, -1):
            step = se2.relative(scans[k + 1][0], scans[k][0]).reshape(3)
            predicted = se2.compose(poses[k + 1], step).reshape(3)
            mx, my = scans[k][1], scans[k][2]
            if len(mx) >= 10 and self._known_share(predicted, mx, my) >= _MIN_KNOWN:
                predicted = self._refine(predicted, mx, my, wide=False)[0]
            poses[k] = predicted
        return poses

    def traced_back(self, frames: Sequence[Any], pose: NDArray[np.float64]) -> NDArray[np.float64] | None:
        """The poses of ``frames`` when the last one is at ``pose``: each earlier pose is the later one moved by the
        odometry between them and matched to the map from there (where its scan ends mostly in the map's known area;
        elsewhere the odometry alone), as the search traces a place back. None when a frame has no odometry."""
        if any(f.odometry is None for f in frames):
            return None
        return self._trace(pose, [(np.asarray(f.odometry, dtype=np.float64),
                                   *self._beams(f.scan.points_in_base(), self.p.match_beams)) for f in frames])

    # -- the per-scan step -----------------------------------------------------------------------------

    @staticmethod
    def _beams(pts: NDArray[np.float64], count: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """At most ``count`` of the scan's endpoints ``pts`` (base frame), evenly spread: their x and y."""
        if len(pts) > count:
            pts = pts[np.linspace(0, len(pts) - 1, count).astype(np.int64)]
        return np.ascontiguousarray(pts[:, 0]), np.ascontiguousarray(pts[:, 1])

    def feed(self, frame: Any) -> ScanResult:
        odom = np.asarray(frame.odometry, dtype=np.float64) if frame.odometry is not None else None
        t = frame.timestamp
        step = np.zeros(3)
        if odom is not None and self.last_odom is not None:
            step = se2.relative(self.last_odom, odom).reshape(3)
        self.last_odom = odom if odom is not None else self.last_odom
        points = frame.scan.points_in_base()
        fx, fy = self._beams(points, self.p.beams)
        mx, my = self._beams(points, self.p.match_beams)
        if len(mx) < 10:  # too few returns to say anything: the pose moves with the odometry
            if self.pose is not None:
                self.pose = se2.compose(self.pose, step).reshape(3)
            return ScanResult(t, self.state, self.pose if self.state == "localized" else None, float("nan"),
                              float("nan"), len(self.particles))
        tracking = self.state in ("localized", "off_map")
        # off the map the particles would be weighed on the few beams that reach it: they wait, and start again
        # around the matched place when the robot is back
        filtering = (self.p.method == "mcl" and self.state != "off_map") or not tracking
        spread, moved = float("nan"), False
        if filtering:
            if self.filter_odom is None or odom is None:
                delta = step if odom is None else np.zeros(3)
                moved = self.filter_odom is None or odom is None
            else:
                delta = se2.relative(self.filter_odom, odom).reshape(3)
                moved = self.p.is_update(delta)
            if moved:
                self._filter_update(delta, fx, fy)
                self.filter_odom = odom
            estimate, share, spread = self._cluster()
            if self.filter_odom is not None and odom is not None:  # the odometry since the update
                estimate = se2.compose(estimate, se2.relative(self.filter_odom, odom)).reshape(3)
        if tracking:
            predicted = se2.compose(self.pose, step).reshape(3)
            known = self._known_share(predicted, mx, my)
            if known < (_BACK_KNOWN if self.state == "off_map" else _MIN_KNOWN):
                # off the map: the odometry carries the pose until the scans reach the map again
                travel = self.off_travel if self.state == "off_map" else 0.0
                return self._off_map(t, predicted, travel + math.hypot(step[0], step[1]), mx, my, spread,
                                     f"{known:.0%} of the scan ends in the map's known area: following the odometry",
                                     (odom, fx, fy))
            back = self.state == "off_map"
            if back and self.off_travel > _OFF_MAP_TRUST:
                self._set_state("searching", t, f"back on the map after {self.off_travel:.1f} m off it: searching "
                                "near where the odometry took it")
                std = max(_DRIFTED_STD[0], 0.1 * self.off_travel)
                self._spread_around(predicted, (std, std, _DRIFTED_STD[2]), self.p.max_particles)
                self.drifted = (predicted.copy(), self.off_travel)
                self.gathered = None
                self.filter_odom, self.confirm = odom, 1
                self._forget_track()
                return ScanResult(t, "searching", None, self._fit(predicted, mx, my), spread, len(self.particles))
            pose, fit = self._refine(predicted, mx, my, wide=back, reach=None if back else _reach(step), edge=not back)
            if back:  # the odometry drifted while off the map: the filter goes on from the matched place
                self._set_state("localized", t, f"back on the map ({known:.0%} of the scan in its known area, "
                                f"{fit:.0%} on walls)")
                if self.p.method == "mcl":
                    self._spread_around(pose, _FOUND_STD)
                self.filter_odom = odom
                self._forget_track()  # (the scans off the map)
            elif self.p.method == "mcl":
                pose, fit = self._challenge(pose, fit, estimate, step, mx, my, moved, t)
            self.pose = pose
            # lost: the scans fit under lost_fit, or under half of what they fitted lately (a map whose walls
            # fit 0.95 of a scan does not fit 0.4 of it at the right place)
            floor = max(self.p.lost_fit, 0.5 * float(np.median(self.recent_fits))) if self.recent_fits else self.p.lost_fit
            self.recent_fits.append(fit)
            self.misfits = self.misfits + 1 if fit < floor else 0
            self.far_misfits = self.far_misfits + 1 if fit < 0.5 * floor else 0
            # a scan that fits under half the floor is not a wall the map lacks or a passer-by: a few in a row
            # and the robot is elsewhere (carried off); waiting lost_after scans lets the match slide to a twin
            carried_off = self.far_misfits >= _FAR_MISFITS
            if carried_off or self.misfits >= self.p.lost_after:
                self._set_state("lost", t, f"{self.far_misfits} scans in a row fit the map under half of {floor:.0%}"
                                if carried_off else f"{self.misfits} scans in a row fit the map under {floor:.0%}")
                self.recent_fits.clear()
                if carried_off:
                    self._spread_globally()  # anywhere
                else:  # drifted off the map's walls: near where it was lost first
                    self._spread_around(self.pose, _DRIFTED_STD, self.p.max_particles)
                    self.drifted = (self.pose.copy(), 0.0)
                self.filter_odom, self.misfits, self.far_misfits, self.confirm = odom, 0, 0, _CONFIRM_UPDATES
                self._forget_track()
                return ScanResult(t, "lost", None, fit, spread, len(self.particles))
            if self._doubt(odom, fx, fy, mx, my, t):
                return ScanResult(t, "lost", None, fit, spread, len(self.particles))
            return ScanResult(t, "localized", self.pose.copy(), fit, spread,
                              len(self.particles) if self.p.method == "mcl" else 0)
        # searching (or lost)
        if self.drifted is not None:
            where, travelled = self.drifted
            self.drifted = (se2.compose(where, step).reshape(3), travelled + math.hypot(step[0], step[1]))
            if self._known_share(self.drifted[0], mx, my) < _MIN_KNOWN:
                # where the odometry says it is, the scans miss the map: off it again rather than searching it
                return self._off_map(t, *self.drifted, mx, my, spread, "the scans end outside the map's known "
                                     "area where the odometry took it: following the odometry")
        if self.confirm == 1:  # around a given initial pose or where the odometry took a robot back on the map
            pose, fit = self._refine(estimate, mx, my, wide=True)
            if self.gathered is not None:
                self.gathered = (self.gathered[0], se2.compose(self.gathered[1], step).reshape(3))
            if moved:
                ok = share > _FOUND_SHARE and spread < 0.5 and fit >= _FOUND_FIT and self._within_drift(pose)
                same = self.gathered is not None and _near(pose, self.gathered[1], 0.5, 0.3)
                self.gathered = ((self.gathered[0] + 1 if same else 1), pose) if ok else None
                need = _CONFIRM_UPDATES if self.drifted is not None else 1  # given by the user: once
                if self.gathered is not None and self.gathered[0] >= need:
                    self.gathered = None
                    return self._found(t, pose, fit, f"{share:.0%} of the weight within {spread:.2f} m, "
                                       f"{fit:.0%} of the scan on walls", spread)
            return ScanResult(t, self.state, None, fit, spread, len(self.particles))
        # a global search: every place the particles gather becomes a hypothesis, tracked by matching and
        # scored scan after scan; one wins only when every other fits clearly worse (a symmetric building
        # keeps two alive until a door or a pillar tells them apart)
        best = self._track_hypotheses(odom, step, fx, fy, mx, my, moved)
        if best is None:
            return ScanResult(t, self.state, None, float("nan"), spread, len(self.particles))
        h, lead = best
        if (h["updates"] >= _CONFIRM_UPDATES and h["fit"] >= _FOUND_FIT and lead >= _HYPOTHESIS_MARGIN
                and self._within_drift(h["pose"])):
            through = self._through_walls(h["pose"], self.search_scans)
            if through > _THROUGH_WALLS:  # the robot could not have come that way: not there
                self.hypotheses.remove(h)
                self.events.append({"time": t, "state": self.state, "why": f"a place fitting {h['fit']:.0%} of the "
                                    f"scan refused: its path traced back runs through the map's walls ({through:.0%} "
                                    "of its poses on them)"})
                return ScanResult(t, self.state, None, h["fit"], spread, len(self.particles))
            rivals = self._unseen_rivals(h["score"] - _HYPOTHESIS_MARGIN, fx, fy, mx, my)
            if rivals:  # places the particles missed fit the scans as well: the search goes on with them
                self.hypotheses = sorted(self.hypotheses + rivals, key=lambda r: -r["score"])[:_MAX_HYPOTHESES]
                return ScanResult(t, self.state, None, h["fit"], spread, len(self.particles))
            others = len(self.hypotheses) - 1
            return self._found(t, h["pose"], h["fit"], f"{h['fit']:.0%} of the scan on walls; "
                               + (f"{others} other places fit worse (by {lead:.1f} in log-likelihood)" if others
                                  else "no other place fits"), spread)
        return ScanResult(t, self.state, None, h["fit"], spread, len(self.particles))

    def _within_drift(self, pose: NDArray[np.float64]) -> bool:
        """Whether a place found while searching near where the odometry took a robot that drifted off the map's walls
        (or came back to the map) lies within _DRIFT_RADIUS of there; any place when the search is not such a one.
        Back on fr079's first-half map made by gmapping, the particles gathered 4.4 m off where the scans fitted the
        map's edge better than the true place (0.5 m from the odometry's): localized there for 171 scans."""
        if self.drifted is None:
            return True
        where, travelled = self.drifted
        return _near(pose, where, _drift_radius(travelled), math.tau)

    def _off_map(self, t: float, pose: NDArray[np.float64], travel: float, mx, my, spread: float,
                 why: str, scan: tuple | None = None) -> ScanResult:
        """The robot at ``pose``, ``travel`` m of odometry since it left the map: said when it just left. With
        ``scan`` (odometry, filter beams x, y), checked for a place it rejoined the map (:meth:`_rejoin`)."""
        if self.state != "off_map":
            self._set_state("off_map", t, why)
            self._forget_track()
        self.pose, self.off_travel = pose, travel
        self.challenger, self.drifted, self.misfits, self.far_misfits = None, None, 0, 0
        if scan is not None and scan[0] is not None:
            found = self._rejoin(t, *scan, mx, my, spread)
            if found is not None:
                return found
        return ScanResult(t, "off_map", pose.copy(), self._fit(pose, mx, my), spread,
                          len(self.particles) if self.p.method == "mcl" else 0)

    def _rejoin(self, t: float, odom, fx, fy, mx, my, spread: float) -> ScanResult | None:
        """Off the map: found again where a place near where the odometry took the robot (within _DRIFT_RADIUS) fits
        the last updates' scans better than any other place by the search's margin, checked every _RIVAL_EVERY updates.
        The odometry's pose alone comes back to the map only if it did not drift off it meanwhile: intel's second half
        in the map of its first left it 1 m off at the map's edge and drifted 8 m off within 4 scans, then followed the
        odometry for its last 373 scans, most of them in the map."""
        if not self._tracked_update(odom, mx, my) or self.doubt_wait > 0 or len(self.track_scans) < _DOUBT_MIN:
            return None
        self.doubt_wait = _RIVAL_EVERY
        places = sorted(self._unseen_rivals(-math.inf, fx, fy, mx, my, self.track_scans, []), key=lambda h: -h["score"])
        if not places:
            return None
        best = places[0]
        lead = best["score"] - places[1]["score"] if len(places) > 1 else math.inf
        if (lead < _HYPOTHESIS_MARGIN or not _near(best["pose"], self.pose, _drift_radius(self.off_travel), math.tau)
                or self._known_share(best["pose"], mx, my) < _BACK_KNOWN
                or self._through_walls(best["pose"], self.track_scans) > _THROUGH_WALLS):
            return None
        self.filter_odom = odom  # the filter goes on from there (it waited off the map)
        off = math.hypot(*(best["pose"][:2] - self.pose[:2]))
        return self._found(t, best["pose"], best["fit"], f"back on the map {off:.1f} m from where the odometry took it: "
                           f"{best['fit']:.0%} of the scan on walls, other places fit the last {len(self.track_scans)} "
                           f"updates worse (by {lead:.1f} in log-likelihood)", spread)

    def _tracked_update(self, odom, mx, my) -> bool:
        """Keep the scan (odometry, matched endpoints) in the tracked history when the odometry moved a filter update's
        worth since the last one kept: whether it did (:meth:`_doubt` and :meth:`_rejoin` check every _RIVAL_EVERY)."""
        if self.track_scans and not self.p.is_update(se2.relative(self.track_scans[-1][0], odom).reshape(3)):
            return False
        self.track_scans.append((odom, mx, my))
        self.doubt_wait -= 1
        return True

    def _forget_track(self) -> None:
        """Drop the tracked pose's recent scans and scores (:meth:`_doubt`): it was lost, moved or found again."""
        self.track_scans.clear()
        self.track_ll.clear()

    def _doubt(self, odom, fx, fy, mx, my, t: float) -> bool:
        """Whether places elsewhere fit the last updates' scans clearly better than the tracked pose does (checked
        when the tracked pose fitted some of them poorly): then the robot is lost, and searched for among them."""
        if odom is None:
            self._forget_track()
            return False
        if not self._tracked_update(odom, mx, my):
            return False
        self.track_ll.append(_INDEPENDENT_BEAMS * float(self._log_likelihoods(self.pose[None], mx, my)[0]))
        n = len(self.track_scans)
        # the tracked pose's summed log-likelihood over the last 1, 2, ... n updates: a stretch of them under the
        # margin, and places elsewhere might fit them better
        if self.doubt_wait > 0 or n < _DOUBT_MIN or float(
                np.min(np.cumsum(np.array(self.track_ll)[::-1])[_DOUBT_MIN - 1:])) >= -_HYPOTHESIS_MARGIN:
            return False
        self.doubt_wait = _RIVAL_EVERY
        own_terms = np.zeros(n)
        own = {"pose": self.pose.copy(), "fit": self._fit(self.pose, mx, my),
               "score": self._path_score(self.pose, self.track_scans, own_terms, loose=True), "updates": 0}
        # (matched as the tracked pose is: _DOUBT_FLOOR asks for a nearly perfect fit)
        places = self._unseen_rivals(-math.inf, fx, fy, mx, my, self.track_scans, [own], loose=True)
        if not places:
            return False
        # over the last L updates (L from _DOUBT_MIN to n: the robot may have been carried off in between), a place
        # must lead the tracked pose by the search's margin and fit the scans nearly perfectly: over _DOUBT_FLOOR
        # (every beam on a wall scores 0)
        own_sums = np.cumsum(own_terms[::-1])[_DOUBT_MIN - 1:]
        sums = np.array([np.cumsum(h["terms"][::-1])[_DOUBT_MIN - 1:] for h in places])
        wins = (sums > own_sums + _HYPOTHESIS_MARGIN) & (sums > _DOUBT_FLOOR)
        if not wins.any():
            return False
        back = int(np.flatnonzero(wins.any(axis=0)).max())  # the longest such stretch
        length = back + _DOUBT_MIN
        rivals = [h for h, won in zip(places, wins[:, back]) if won]
        scans = list(self.track_scans)[-length:]
        for h in rivals + [own]:  # scored over the stretch as the search scores its hypotheses
            h["score"] = self._path_score(h["pose"], scans)
        self.restart(None, said=False)
        self.search_scans.extend(scans)  # the search goes on with them, and from the tracked pose and those places
        self.hypotheses = sorted(rivals + [own], key=lambda h: -h["score"])[:_MAX_HYPOTHESES]
        self.filter_odom = odom
        self._set_state("lost", t, f"{own['fit']:.0%} of the scan on walls; {len(rivals)} place(s) elsewhere fit the "
                        f"last {length} updates better (the best by {self.hypotheses[0]['score'] - own['score']:.1f} "
                        "in log-likelihood): searching the whole map")
        return True

    def _challenge(self, pose, fit, estimate, step, mx, my, moved: bool, t: float):
        """The tracked pose against the particles' place when they disagree: theirs takes over only when
        the scans' likelihood there leads by the search's margin over five updates (the random particles of
        a recovery can gather on a wrong place that fits a scan as well as the right one at a map's edge)."""
        c = self.challenger
        if c is not None:
            c["pose"], c["fit"] = self._refine(se2.compose(c["pose"], step).reshape(3), mx, my, wide=False)
        elif moved and not _near(pose, estimate, 0.5, 0.3):
            c_pose, c_fit = self._refine(estimate, mx, my, wide=False)
            if not _near(pose, c_pose, 0.5, 0.3):
                c = self.challenger = {"pose": c_pose, "fit": c_fit, "lead": 0.0, "updates": 0}
        if c is None:
            return pose, fit
        ll = self._log_likelihoods(np.array([pose, c["pose"]]), mx, my)
        c["lead"] += _INDEPENDENT_BEAMS * float(ll[1] - ll[0])
        c["updates"] += int(moved)
        if c["lead"] < -_HYPOTHESIS_DROP or _near(pose, c["pose"], 0.3, 0.2):
            self.challenger = None
        elif c["updates"] >= _CONFIRM_UPDATES and c["lead"] >= _HYPOTHESIS_MARGIN:
            self.challenger = None
            self.events.append({"time": t, "state": "localized", "why": f"moved to where the particles are: the scans "
                                f"fit there better (by {c['lead']:.1f} in log-likelihood)"})
            return c["pose"], c["fit"]
        return pose, fit

    def _found(self, t: float, pose: NDArray[np.float64], fit: float, why: str, spread: float) -> ScanResult:
        self.pose = pose
        self.misfits = self.far_misfits = 0
        self.hypotheses, self.challenger, self.drifted = [], None, None
        self.search_scans.clear()
        self.search_updates = 0
        self._forget_track()
        self._set_state("localized", t, why)
        if self.p.method == "mcl":  # the filter goes on from where the scan says the robot is
            self._spread_around(pose, _FOUND_STD)
        return ScanResult(t, "localized", self.pose.copy(), fit, spread, len(self.particles))

    def _modes(self) -> list[NDArray[np.float64]]:
        """The places the particles gather: the weighted means of the heaviest (1 m, 1 m, 45 deg) bins."""
        w = self._weights()
        keys = np.floor(self.particles / np.array([1.0, 1.0, np.pi / 4])).astype(np.int64)
        _, inverse = np.unique(keys, axis=0, return_inverse=True)
        inverse = inverse.reshape(-1)
        mass = np.bincount(inverse, weights=w)
        modes = []
        for b in np.argsort(mass)[::-1][:_MAX_HYPOTHESES]:
            if mass[b] < 0.01:
                break
            modes.append(self._mean_pose(inverse == b, w)[0])
        return modes

    def _path_score(self, pose: NDArray[np.float64], scans: Sequence | None = None,
                    per_scan: NDArray[np.float64] | None = None, loose: bool = False) -> float:
        """The summed log-likelihood of the search's scans (or ``scans``) along the path traced back from ``pose``
        (now, at the last of them); each scan's term in ``per_scan`` when given."""
        scans = self.search_scans if scans is None else scans
        odoms = np.array([s[0] for s in scans])
        steps = np.ascontiguousarray(se2.relative(odoms[1:], odoms[:-1]).reshape(-1, 3))
        bx = np.concatenate([s[1] for s in scans])
        by = np.concatenate([s[2] for s in scans])
        starts = np.zeros(len(odoms) + 1, dtype=np.int64)
        np.cumsum([len(s[1]) for s in scans], out=starts[1:])
        f = self.field
        prior = (_PRIOR_XY, _PRIOR_TH) if loose else (_SEARCH_PRIOR_XY, _SEARCH_PRIOR_TH)
        slide = (0.0, 0.0) if loose else _SLIDE_STD
        return _INDEPENDENT_BEAMS * float(traced_path_log_likelihood(
            f.distance, f.origin[0], f.origin[1], f.resolution, f.max_distance, float(pose[0]), float(pose[1]),
            float(pose[2]), steps, bx, by, starts, 20, 0.1, *prior, self.inv_two_sigma2, _Z_HIT, _Z_RAND, *slide,
            per_scan if per_scan is not None else np.empty(0)))

    def _unseen_rivals(self, floor: float, fx, fy, mx, my, scans: Sequence | None = None,
                       known: list[dict] | None = None, loose: bool = False) -> list[dict]:
        """New hypotheses: places the scan fits well whose paths score over ``floor`` on the search's scans (or
        ``scans``), other than the search's hypotheses (or ``known``); each with its path's per-scan terms."""
        scans = self.search_scans if scans is None else scans
        known = self.hypotheses if known is None else known
        if not scans or len(self.rival_xy) == 0:
            return []
        f = self.field
        inv = self.inv_two_sigma2
        if self.rival_table is None:  # the beam model of particle_log_likelihoods, per cell
            self.rival_table = np.log(_Z_HIT * np.exp(-f.distance ** 2 * inv) + _Z_RAND)
        grid = np.empty((len(self.rival_xy), len(self.rival_headings)))
        scan_log_likelihood_grid(self.rival_table, f.origin[0], f.origin[1], f.resolution,
                                 math.log(_Z_HIT * math.exp(-f.max_distance ** 2 * inv) + _Z_RAND), self.rival_xy,
                                 self.rival_headings, fx, fy, grid)
        turn = np.argmax(grid, axis=1)
        best = grid[np.arange(len(grid)), turn]
        rivals: list[dict] = []
        picked: list[NDArray[np.float64]] = []
        for i in np.argsort(best)[::-1]:  # the best places first, one per metre and turn
            start = np.array([self.rival_xy[i, 0], self.rival_xy[i, 1], self.rival_headings[turn[i]]])
            if any(_near(start, q, 1.0, 0.3) for q in picked):
                continue
            picked.append(start)
            if len(picked) > _RIVALS:
                break
            pose, fit = self._refine(start, mx, my, wide=True)
            if fit < _FOUND_FIT or any(_near(pose, q["pose"], 1.0, 0.3) for q in known + rivals):
                continue
            terms = np.zeros(len(scans))
            score = self._path_score(pose, scans, terms, loose)
            if score > floor:
                rivals.append({"pose": pose, "fit": fit, "score": score, "updates": 0, "terms": terms})
        return rivals

    def _track_hypotheses(self, odom, step, fx, fy, mx, my, moved: bool) -> tuple[dict, float] | None:
        """Move and match every hypothesis, score it, add the particles' new places, drop the hopeless."""
        for h in self.hypotheses:
            h["pose"], h["fit"] = self._refine(se2.compose(h["pose"], step).reshape(3), mx, my, wide=False,
                                               prior=(_SEARCH_PRIOR_XY, _SEARCH_PRIOR_TH))
        if moved:  # scored at the filter's updates only: a robot standing still sees the same scan again
            if odom is not None:
                self.search_scans.append((odom, mx, my))
                self.search_updates += 1
            else:  # without odometry a path cannot be traced back
                self.search_scans.clear()
            if self.hypotheses:
                ll = self._log_likelihoods(np.array([h["pose"] for h in self.hypotheses]), mx, my)
                for h, v in zip(self.hypotheses, ll):
                    h["score"] += _INDEPENDENT_BEAMS * float(v) - _slide_cost(h, odom)
                    h["updates"] += 1
            top = max((h["score"] for h in self.hypotheses), default=0.0)
            for mode in self._modes():
                if any(_near(mode, h["pose"], 0.5, 0.3) for h in self.hypotheses):
                    continue
                pose, fit = self._refine(mode, mx, my, wide=True)
                if fit >= _FOUND_FIT and not any(_near(pose, h["pose"], 0.2, 0.1) for h in self.hypotheses):
                    # a newcomer is scored on the search's scans along its path so far (the incumbents' scores
                    # began the same way); without them it starts level with the best
                    score = self._path_score(pose) if self.search_scans else top
                    self.hypotheses.append({"pose": pose, "fit": fit, "score": score, "updates": 0})
            if self.search_scans and self.search_updates % _RIVAL_EVERY == 0:
                floor = max((h["score"] for h in self.hypotheses), default=-math.inf) - _HYPOTHESIS_DROP
                self.hypotheses += self._unseen_rivals(floor, fx, fy, mx, my)
        if not self.hypotheses:
            return None
        self.hypotheses.sort(key=lambda h: -h["score"])
        kept: list[dict] = []
        for h in self.hypotheses:  # one per place (two that matched onto the same place are one), the hopeless out
            if h["score"] >= self.hypotheses[0]["score"] - _HYPOTHESIS_DROP and h["fit"] >= self.p.lost_fit and not any(
                    _near(h["pose"], k["pose"], 0.2, 0.1) for k in kept):
                kept.append(h)
        self.hypotheses = kept[:_MAX_HYPOTHESES]
        if not self.hypotheses:
            return None
        lead = self.hypotheses[0]["score"] - self.hypotheses[1]["score"] if len(self.hypotheses) > 1 else math.inf
        return self.hypotheses[0], lead

    def _set_state(self, state: str, t: float, why: str) -> None:
        self.events.append({"time": t, "state": state, "why": why})
        self.state = state


def _slide_cost(h: dict[str, Any], odom: NDArray[np.float64] | None) -> float:
    """What hypothesis ``h`` pays for how far matching moved it from where the odometry since its last filter update
    took it (as :func:`~slam2d.localization.kernels.traced_path_log_likelihood` charges a path traced back)."""
    anchor = h.get("anchor")
    h["anchor"] = None if odom is None else (h["pose"].copy(), odom)
    if anchor is None or odom is None:
        return 0.0
    step = se2.relative(anchor[1], odom).reshape(3)
    predicted = se2.compose(anchor[0], step).reshape(3)
    return float(slide_cost(float(h["pose"][0] - predicted[0]), float(h["pose"][1] - predicted[1]),
                            math.hypot(step[0], step[1]), *_SLIDE_STD))


def _drift_radius(travelled: float) -> float:
    """How far (m) from where the odometry took a robot off the map's walls a place found for it may lie, after
    ``travelled`` metres of odometry (_DRIFT_RADIUS)."""
    return _DRIFT_RADIUS[0] + _DRIFT_RADIUS[1] * travelled


def map_anchor(result: ScanResult) -> NDArray[np.float64] | None:
    """The pose to hold a mapping method to (``SlamMethod.anchor_to_map``) from a scan's localization: a localized
    pose whose scan fits the map's walls at least _ANCHOR_FIT, else None."""
    return result.pose if result.pose is not None and result.fit >= _ANCHOR_FIT else None


def _reach(step: NDArray[np.float64]) -> tuple[float, float]:
    """How far (m, rad) matching may move the tracked pose from where the odometry ``step`` took it: _REACH plus three
    times the motion model's spread over the step (_MOTION_NOISE, as the particles move; the larger of its two axes)."""
    sx, sy, sth = gmapping_motion_std(step, *_MOTION_NOISE)
    return (_REACH[0] + 3.0 * max(sx, sy), _REACH[1] + 3.0 * sth)


def _near(a: NDArray[np.float64], b: NDArray[np.float64], distance: float, angle: float) -> bool:
    return math.hypot(a[0] - b[0], a[1] - b[1]) < distance and abs(math.remainder(a[2] - b[2], math.tau)) < angle
