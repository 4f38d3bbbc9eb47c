"""Karto's graph SLAM front end: scans become pose-graph nodes linked by correlative matches.

For every scan (:meth:`GraphFrontend.process`):

1. *Predict*: the last node's pose plus the odometry moved since it.
2. *Gate* (Karto's ``HasMovedEnough``): keep the scan only if it moved at
   least ``minimum_travel_distance`` or turned ``minimum_travel_heading``
   since the last kept scan, or ``minimum_time_interval`` passed. Other
   scans get the predicted pose and no node.
3. *Sequential match* against the *running scans* (the last
   ``scan_buffer_size`` kept scans within ``scan_buffer_maximum_scan_distance``),
   with the distance and angle penalty. A match stuck on its window's edge or
   responding poorly is searched again over ``sequential_recovery_window``
   (the odometry may be wrong by more than the window).
4. *Add the node*; link it to the previous node and to the closest running
   scan (``LinkChainToScan``); match it against each *near chain* (older
   passes within ``link_scan_maximum_distance`` already connected to it in
   the graph, not penalised) and link those that respond above
   ``link_match_minimum_response_fine``. The node's pose is the
   information-weighted mean of these matches. With ``odometry_fusion``, a
   sequential match whose coarse heading spread exceeds the odometry's is
   first fused with the odometry prediction.
5. *Loop closure* (``TryCloseLoop``): candidate chains are runs of
   consecutive older scans within ``loop_search_maximum_distance`` that are
   *not* reachable in the graph through scans within that distance, at least
   ``loop_match_minimum_chain_size`` long. Each is matched over the wide
   loop window (no penalty; coarse, then refined on the same grid when
   ``loop_coarse_refine``) and accepted if the response
   exceeds ``loop_match_minimum_response_coarse`` and the x and y variances
   are below ``loop_match_maximum_variance_coarse``; then refined with the
   sequential matcher (no penalty) and accepted if the response reaches
   ``loop_match_minimum_response_fine``. With ``loop_check_peaks`` every
   distinct peak of the coarse surface is refined in between: the best place
   is the match, and one with a rival place about as good far away is
   ambiguous and waits for an unambiguous match from another scan. Every
   accepted closure links the chain and runs the back end over the whole graph.

Distances between scans use each scan's barycentre (Karto's
``UseScanBarycenter``). Edge covariances from the matcher are in the world
frame and are rotated into the first node's frame, as Karto's ``LinkInfo``
does, before they become information matrices.

All poses are robot base poses; the scan points are stored in the base frame
(``scan.points_in_base()``), so a laser mounted off-centre needs nothing
special.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from numba import njit

from slam2d.backends import PoseGraph, get_backend
from slam2d.core import se2
from slam2d.core.arrays import grown
from slam2d.core.frames import Frame
from slam2d.grids.occupancy import GridParams, OccupancyGrid
from slam2d.matching.odometry_gaps import OdometryGapParams
from slam2d.matching.correlative import COVARIANCE_BAND, CorrelativeMatcher
from slam2d.matching.grid_cache import GridCache
from slam2d.params import param
from slam2d.sensors.beam_model import beam_sigmas
from slam2d.graph.wall_end_landmarks import WallEndLandmarks, WallEndParams
from slam2d.graph.dense_refinement import DenseRefinementParams
from slam2d.graph.wall_refinement import WallRefinementParams, refine_path

__all__ = ["GraphSlamParams", "GraphFrontend", "LoopClosure"]

_DEG = math.pi / 180.0


@dataclass
class GraphSlamParams(GridParams, WallEndParams, WallRefinementParams, DenseRefinementParams, OdometryGapParams):
    """Karto's mapper parameters (open_karto names in snake case, its defaults), plus the back end.

    Squared quantities are given squared (m^2, rad^2) and angles in radians:
    open_karto's defaults are stored that way, while slam_karto's ROS
    parameters are the square roots (0.3 m, 0.349 rad, 0.4 m) that its
    setters square. ``--set angle=10deg`` converts degrees.
    """

    backend: str = param("spa", choices=("spa", "lago", "gtsam"), help="pose-graph optimiser run after each loop closure")
    use_scan_matching: bool = param(True, help="match scans (off: nodes at the odometry pose) [UseScanMatching]")
    minimum_match_response: float = param(
        0.0, low=0.0, high=1.0,
        help="a sequential match responding below this is not used: the odometry step is kept instead "
        "(not in Karto, which uses any match; 0 = off, since on intel's poor odometry any threshold hurts)",
        advanced=True, group="sequential matching",
    )
    match_between_nodes: bool = param(
        True,
        help="match every scan that adds no node against the running scans too, for its pose in the "
        "trajectory (not in Karto, whose poses between nodes are the odometry's: with noisy odometry "
        "they are degrees off); costs one sequential match per scan",
    )
    between_nodes_search_dimension: float = param(
        0.3, unit="m", low=0.001,
        help="side of the x, y window of the matches of scans that add no node (match_between_nodes; not in Karto): "
        "their prediction is at most one node's travel from a matched node, so a window smaller than "
        "correlation_search_space_dimension can do, at a fraction of the cost",
        advanced=True, group="between nodes",
    )
    between_nodes_angle_offset: float = param(
        20.0 * _DEG, unit="rad", low=0.0,
        help="half-width of the coarse angle window of the matches of scans that add no node (not in Karto; "
        "see between_nodes_search_dimension)",
        advanced=True, group="between nodes",
    )
    between_nodes_skip_travel: float = param(
        0.0, unit="m", low=0.0,
        help="a scan that adds no node is not matched while the odometry since the last matched scan has moved "
        "less than this and turned less than between_nodes_skip_turn: its pose is that scan's plus the odometry "
        "since it (not in Karto; a speed setting, 0 = every such scan matched, see docs/methods/karto-measured.md)",
        advanced=True, group="between nodes",
    )
    between_nodes_skip_turn: float = param(
        2.0 * _DEG, unit="rad", low=0.0,
        help="with between_nodes_skip_travel, a scan that adds no node is matched anyway once the odometry "
        "since the last matched scan has turned this far (not in Karto)",
        advanced=True, group="between nodes",
    )
    seeded_search_window: float = param(
        0.2, unit="m", low=0.0,
        help="with match_between_nodes, a sequential match (of a scan that adds no node, or of a node right after "
        "one) first searches only this side of its coarse x, y lattice (and seeded_search_angle) around the last "
        "scan's matched pose plus the odometry since it; it searches its "
        "whole window when a pose responding within 0.1 of that part's best lies on the part's edge, when the "
        "part's best responds more than seeded_search_drop below the last scan, or when its coarse headings are "
        "ambiguous (odometry_fusion); 0 always searches the whole window (not in Karto; a speed-up: where the "
        "part holds the whole search's best and its covariance band, the match is the whole search's bit for bit)",
        advanced=True, group="between nodes",
    )
    seeded_search_angle: float = param(
        6.0 * _DEG, unit="rad", low=0.0,
        help="half-width of the coarse angles of the seeded search of seeded_search_window (not in Karto)",
        advanced=True, group="between nodes",
    )
    seeded_search_drop: float = param(
        0.05, low=0.0, high=1.0,
        help="the seeded search of seeded_search_window is kept only when its unpenalised response is at most "
        "this below the last matched scan's (not in Karto; consecutive scans overlap almost wholly)",
        advanced=True, group="between nodes",
    )
    predict_from_last_scan: bool = param(
        True,
        help="when the last scan's matched pose plus the odometry since it gives a heading more than half "
        "coarse_search_angle_offset from the last node's plus the odometry, predict from the last scan (its "
        "heading only, after a match flat along a corridor); needs match_between_nodes; not in Karto: a turn "
        "whose odometry heading goes 20 deg or more wrong between two nodes is then recovered scan by scan",
        advanced=True, group="sequential matching",
    )
    odometry_fusion: bool = param(
        True,
        help="when the coarse angles responding within 0.1 of the best spread wider than the odometry's 3 deg, "
        "fuse the odometry prediction (0.1 m, 3 deg per kept scan) into the sequential match, taking that spread "
        "as the match's heading variance (not in Karto): a scan that fits about as well 20 deg off (clutter, "
        "people) keeps the odometry heading",
        advanced=True, group="odometry fusion",
    )
    odometry_fusion_maximum_drop: float = param(
        0.1, low=0.0, high=1.0,
        help="odometry_fusion fuses the odometry only when the sequential match's best coarse response at the "
        "odometry's own heading is at most this below its best (the odometry's heading is one of those the scan "
        "fits about as well; 0.1 is the covariance band) (not in Karto): aces, smear 0.032, node 216: the match "
        "1.3 deg off, the odometry 7.9 deg off and 0.15 below, fused 3.8 deg off; 1 fuses whenever the spread "
        "is wide, as before",
        advanced=True, group="odometry fusion",
    )
    reference_range_margin: float = param(
        0.0, unit="m", low=0.0,
        help="a scan used as a matching reference keeps returns up to range_threshold plus this (not in Karto): "
        "the query's far points then land inside the reference's reach, instead of past its edge where they "
        "score nothing unless the match steps back (which shortens steps along corridors); 0 = off (Karto), as "
        "8 m helped aces and intel but not fr101 (docs)",
        advanced=True, group="sequential matching",
    )
    reference_gap_fill: float = param(
        0.0, unit="m", low=0.0,
        help="in a scan used as a matching reference, neighbouring points (in beam order) closer than this are "
        "joined by points every two correlation cells (not in Karto): a wall seen at a glancing angle is then a "
        "line, not dots ever further apart, whose density pulls a match toward where the reference is dense "
        "(steps along a corridor came out 1-2 cm short in simulation); 0 = off (Karto): in the whole front end "
        "it lengthened the steps past the truth (docs)",
        advanced=True, group="sequential matching",
    )
    point_spacing: float = param(
        0.0, unit="m", low=0.0,
        help="keep one scan point per square of this side before matching (not in Karto): near clutter "
        "hit by dozens of beams weighs less and matching is cheaper; 0 keeps every point, as Karto does",
        advanced=True, group="sequential matching",
    )
    near_chain_angle_offset: float = param(
        6.0 * _DEG, unit="rad", low=0.0,
        help="half-width of the coarse angle window of the near-chain matches and their response bound (not in "
        "Karto, which uses coarse_search_angle_offset, 20 deg): a near chain is already connected to the new scan "
        "in the graph, and the links it makes correct the heading by at most 2.6 deg on the four logs (99 % "
        "within 0.84 deg), so 6 deg spares two thirds of their lookups and headings bounded, with the same "
        "results on intel, aces, fr101 and the simulated rows (docs); 0 uses coarse_search_angle_offset",
        advanced=True, group="near chains",
    )
    coarse_point_spacing: float = param(
        0.0, unit="m", low=0.0,
        help="the coarse search of every 1 cm match (sequential, between nodes, near chains, loop refinement) scores "
        "only the query points at least this far from the last one kept, in scan order; the fine search scores every "
        "point (not in Karto: near walls and clutter are hit by beams millimetres apart, which a 2 cm, 2 deg "
        "lattice cannot tell apart, and the coarse lookups are points x poses); 0 scores every point, as Karto",
        advanced=True, group="sequential matching",
    )
    sequential_recovery_window: float = param(
        1.6, unit="m", low=0.0,
        help="when the sequential match's best pose lies within a coarse step of its window's edge, or its "
        "unpenalised response is below sequential_recovery_response, search again without the penalty over "
        "this x, y window (on the loop grid's 5 cm cells, then the 1 cm match there) and keep that match if it "
        "removes sequential_recovery_margin of the first match's misfit (not in Karto: fr079's odometry logs reversing as "
        "forward); 0 turns it off",
        advanced=True, group="sequential recovery",
    )
    sequential_recovery_response: float = param(
        0.5, low=0.0, high=1.0,
        help="a sequential match whose unpenalised response is below this is searched again over "
        "sequential_recovery_window, and a recovery must respond at least this (not in Karto)",
        advanced=True, group="sequential recovery",
    )
    sequential_recovery_drop: float = param(
        0.2, low=0.0, high=1.0,
        help="a sequential match whose unpenalised response is this much below the last matched scan's is "
        "searched again over sequential_recovery_window too (not in Karto): consecutive scans overlap almost "
        "wholly, so a sudden drop means the odometry prediction is off by more than the window (wheel slip); "
        "smear_beam_spacing compresses responses, so with it this rarely fires; 1 turns it off",
        advanced=True, group="sequential recovery",
    )
    sequential_recovery_margin: float = param(
        0.3, low=0.0, high=1.0,
        help="the share of the first match's misfit (1 - its unpenalised response) the recovery must remove "
        "to replace it (not in Karto): a point d off a wall of smear sigma scores about 1 - d^2 / 2 sigma^2, "
        "so misfits scale with the smear and their ratio does not",
        advanced=True, group="sequential recovery",
    )
    sequential_recovery_angle: float = param(
        45.0 * _DEG, unit="rad", low=0.0,
        help="half-width of the recovery search's angle window (at least coarse_search_angle_offset; "
        "not in Karto)",
        advanced=True, group="sequential recovery",
    )
    sequential_recovery_maximum_variance: float = param(
        0.01, unit="m^2", low=0.0,
        help="a recovery whose x, y covariance (the 1 cm match's) exceeds this in some direction (a corridor) "
        "has the odometry prediction's position fused in (0.1 m; its heading is not), so the odometry decides "
        "along the corridor and the scan across it and the heading (not in Karto); inf takes every recovery as it is",
        advanced=True, group="sequential recovery",
    )
    use_scan_barycenter: bool = param(
        True, help="measure distances between scans from the centroid of their points, not the robot [UseScanBarycenter]"
    )
    minimum_time_interval: float = param(
        3600.0, unit="s", low=0.0, help="keep a scan when this long has passed since the last kept one [MinimumTimeInterval]"
    )
    minimum_travel_distance: float = param(
        0.2, unit="m", low=0.0, help="keep a scan when the robot moved this far since the last kept one [MinimumTravelDistance]"
    )
    minimum_travel_heading: float = param(
        10.0 * _DEG, unit="rad", low=0.0,
        help="keep a scan when the robot turned this much since the last kept one (Karto's 10 deg) [MinimumTravelHeading]",
    )
    scan_buffer_size: int = param(70, low=1, help="running scans the sequential matcher matches against [ScanBufferSize]")
    scan_buffer_maximum_scan_distance: float = param(
        20.0, unit="m", low=0.0,
        help="drop running scans farther than this from the newest one [ScanBufferMaximumScanDistance]",
    )
    link_match_minimum_response_fine: float = param(
        0.8, low=0.0, high=1.0, help="least response that links a near chain [LinkMatchMinimumResponseFine]"
    )
    link_flat_variance: float = param(
        0.0, unit="m^2", low=0.0,
        help="a near-chain link whose match is flat along a corridor (its x, y spread fills the window) gets "
        "this variance along the corridor (not in Karto): unpenalised, such a match only repeats where the "
        "graph already puts the scan, and dozens of them along one corridor hold the graph there against a "
        "loop closure; 0 (default) keeps the window's variance, since 1-100 helped the simulated worlds but "
        "not intel, aces or fr101",
        advanced=True, group="near chains",
    )
    match_covariance_scale: float = param(
        1.0, unit="factor", low=1e-6,
        help="factor on the covariance of every scan-match edge the graph gets (sequential, running and "
        "near-chain links, loop closures; the edge information is divided by it); 1 (default) keeps the "
        "matcher's response-surface covariance, some 10 (URG-04LX) to 25 (RPLidar) times too wide at the "
        "true poses of the simulated runs; matters only against the wall-end landmarks' sightings (with "
        "the pose edges alone a common factor does not move the optimum)",
        advanced=True, group="graph edges",
    )
    running_link_chain_covariance: bool = param(
        True,
        help="the edge from the closest running scan to a new node (Karto's LinkChainToScan over the running "
        "scans), when that scan is not the previous node, gets the match's covariance plus the uncertainty of "
        "the sequential edges between the two (not in Karto, which gives it the match's alone): the match "
        "placed the scan in a map of scans drawn at their current poses, so the relative pose to an older "
        "scan carries whatever the steps since it got wrong (aces: a 4 deg turn fused with the odometry, "
        "claimed 2.2 deg, was frozen by such an edge claiming 0.5 deg)",
        advanced=True, group="graph edges",
    )
    grid_keep_tolerance: float = param(
        0.0, unit="m", low=0.0,
        help="after an optimisation a cached sequential or near-chain correlation grid is kept when none "
        "of its scans' points moved more than this (translation plus rotation times the scan's reach); "
        "0 (Karto) draws every grid again; half the sequential cell (0.005) keeps each point within "
        "its cell's rounding (not in Karto)",
        advanced=True, group="grid cache",
    )
    grid_cache_entries: int = param(
        32, unit="grids", low=1,
        help="1 cm correlation grids (running scans, near chains) kept for reuse, the least recently used "
        "dropped first (not in Karto, which draws every grid anew); 32 (8 before) lets a near chain find "
        "its pass's grid again after the other chains' requests: on fr079 26 % fewer points smeared, "
        "about 7 % less CPU, 80 MB more peak memory",
        advanced=True, group="grid cache",
    )
    near_chain_grid_extra: int = param(
        10, unit="scans", low=0,
        help="a near chain is matched on a cached grid holding at most this many scans besides its own "
        "(neighbours of the same pass), extended by the chain's missing scans, instead of a new grid "
        "(Karto draws the chain alone; 10 is the sequential matcher's own allowance)",
        advanced=True, group="near chains",
    )
    link_scan_maximum_distance: float = param(
        10.0, unit="m", low=0.0, help="near chains are looked for within this distance [LinkScanMaximumDistance]"
    )
    do_loop_closing: bool = param(True, help="look for loop closures [DoLoopClosing]")
    loop_search_maximum_distance: float = param(
        4.0, unit="m", low=0.0, help="loop candidates lie within this distance of the new scan [LoopSearchMaximumDistance]"
    )
    loop_match_minimum_chain_size: int = param(
        10, low=1, help="fewest consecutive scans a loop or near chain needs [LoopMatchMinimumChainSize]"
    )
    loop_match_maximum_variance_coarse: float = param(
        0.4**2, unit="m^2", low=0.0,
        help="largest x and y variance of the coarse loop match; a variance, already squared "
        "(slam_karto's YAML gives 0.4 and squares it) [LoopMatchMaximumVarianceCoarse]",
    )
    loop_match_minimum_response_coarse: float = param(
        0.8, low=0.0, high=1.0, help="least response of the coarse loop match [LoopMatchMinimumResponseCoarse]"
    )
    loop_coarse_relative: bool = param(
        False,
        help="the coarse loop threshold is relative to the best coarse response the new scan can reach against "
        "itself when the truth lies half a coarse step (cell and angle) from every sampled pose (not in Karto): "
        "the coarse grid's sampling alone costs long-range scans a tenth to a third of their response",
        advanced=True, group="loop closure",
    )
    loop_coarse_refine: bool = param(
        True,
        help="score the coarse loop match after a fine angle and one-cell step on the loop grid (Karto's "
        "refine step, which its loop closure skips): the 2 deg coarse angle sampling alone costs a long-range "
        "scan much of its response, so a true closure can miss the coarse threshold (not in Karto)",
        advanced=True, group="loop closure",
    )
    loop_match_minimum_response_fine: float = param(
        0.8, low=0.0, high=1.0, help="least response of the fine loop match [LoopMatchMinimumResponseFine]"
    )
    loop_match_minimum_response_confirmed: float = param(
        0.55, low=0.0, high=1.0,
        help="a loop match whose coarse and fine responses reach this but not Karto's thresholds (and whose "
        "coarse variances pass) is kept as a hypothesis, and accepted with another such hypothesis (or a "
        "closure) from a different scan nearby when the two agree on where the new scans lie in the old map "
        "(loop_confirm_distance, loop_confirm_angle) (not in Karto: on logs thinned to ~1 m between scans "
        "true closures respond 0.55-0.8); 1 turns it off",
        advanced=True, group="loop closure",
    )
    loop_confirm_distance: float = param(
        0.1, unit="m", low=0.0,
        help="two loop hypotheses confirm each other when the cycle through both (chain to scan, scan to scan "
        "along the graph, scan to chain, back along the old chain) closes within this distance (not in Karto)",
        advanced=True, group="loop closure",
    )
    loop_confirm_angle: float = param(
        1.5 * _DEG, unit="rad", low=0.0, help="and within this angle (not in Karto)",
        advanced=True, group="loop closure",
    )
    loop_confirm_path: float = param(
        5.0, unit="m", low=0.0,
        help="a loop hypothesis waits for confirmation until the robot has travelled this far past it, and "
        "the two old scans of a confirming pair lie at most this far apart along their pass (not in Karto)",
        advanced=True, group="loop closure",
    )
    loop_match_maximum_correction: float = param(
        0.5, unit="m", low=0.0,
        help="a loop closure may move the new scan at most this far plus loop_match_maximum_drift times "
        "the path travelled since the chain (not in Karto: rejects look-alike places far from the estimate)",
        advanced=True, group="loop closure",
    )
    loop_match_maximum_drift: float = param(
        0.02, unit="m/m", low=0.0,
        help="the odometry-plus-matching drift a loop closure may correct, per metre travelled since the chain "
        "(not in Karto); inf turns the gate off",
        advanced=True, group="loop closure",
    )
    loop_check_peaks: bool = param(
        True,
        help="refine every distinct peak of a loop match's coarse surface that could come within 0.1 of the best "
        "and take the best refined one; when the refined peaks within 0.1 of it spread wider than "
        "loop_match_maximum_variance_coarse (Karto's variance test over places, not only around the best lattice "
        "pose) the match is ambiguous and is accepted only with a consistent match from another scan that is not "
        "(not in Karto): the coarse lattice can sample a sharp true peak below a look-alike",
        advanced=True, group="loop closure",
    )
    loop_refine_coarse: bool = param(
        True,
        help="a loop match that fails Karto's coarse tests but whose coarse response is within the refine step's "
        "reach (0.2) of the hypothesis threshold has every distinct peak of its coarse surface refined as "
        "loop_check_peaks does, and Karto's tests are applied to the best refined place: its response, and the "
        "coarse surface's variance about it (the lattice poses within 0.1 of its response, and itself); the "
        "peak check's ambiguity test follows (not in Karto): with a narrow smear a true place can fall between "
        "the coarse lattice's poses and score 0.3 below its refined value",
        advanced=True, group="loop closure",
    )
    loop_retry_distance: float = param(
        0.3, unit="m", low=0.0,
        help="a chain a loop match was tried against (or a near chain that failed to link) is tried again only "
        "once the robot is this far from where it was tried or the graph was optimised since (not in Karto, "
        "which retries at every kept scan; 0 retries always)",
        advanced=True, group="loop closure",
    )
    near_bound_retry_distance: float = param(
        0.0, unit="m", low=0.0,
        help="a near chain whose response bound lies between the failure mark and the link threshold (it cannot "
        "link from there) is bounded again only once the robot is this far from where it was bounded or the "
        "graph was optimised since (0: bounded at every kept scan; a speed setting, see docs/methods/karto-measured.md)",
        advanced=True, group="near chains",
    )
    near_link_skip_distance: float = param(
        0.0, unit="m", low=0.0,
        help="a near chain that linked is not matched again (no link) until the robot is this far from where "
        "it linked or the graph was optimised since (not in Karto, which links it from every node; 0: matched "
        "at every kept scan; a speed setting, see docs/methods/karto-measured.md)",
        advanced=True, group="near chains",
    )
    correlation_search_space_dimension: float = param(
        0.3, unit="m", low=0.001, help="side of the sequential matcher's x, y window [CorrelationSearchSpaceDimension]"
    )
    correlation_search_space_resolution: float = param(
        0.01, unit="m", low=0.001, help="cell of the sequential correlation grid [CorrelationSearchSpaceResolution]"
    )
    correlation_search_space_smear_deviation: float = param(
        0.03, unit="m", low=0.0,
        help="Gaussian sigma a reference point is smeared with; a sensor model's per-beam sigma adds "
        "in quadrature [CorrelationSearchSpaceSmearDeviation]",
    )
    loop_search_space_dimension: float = param(
        8.0, unit="m", low=0.001, help="side of the loop matcher's x, y window [LoopSearchSpaceDimension]"
    )
    loop_search_space_resolution: float = param(
        0.05, unit="m", low=0.001, help="cell of the loop correlation grid [LoopSearchSpaceResolution]"
    )
    loop_search_space_smear_deviation: float = param(
        0.03, unit="m", low=0.0, help="smear sigma of the loop grid [LoopSearchSpaceSmearDeviation]"
    )
    smear_beam_spacing: float = param(
        0.5, low=0.0,
        help="widen each reference point's smear, in quadrature, by this share of the gap between its beam "
        "and the next at its range (range x angle increment), up to 10 cells (a wall point between two beam ends "
        "is at most half the gap from the nearer); 0.5 meets more of the targets than 1.0 (the simulated RPLidar, "
        "aces at most smears) though fr079 and fr101 are better with 1.0 (docs) (not in Karto, whose smear is "
        "the same for every point: far points of a 1 deg laser 1 m apart then match as isolated dots); 0 = off",
        advanced=True, group="sequential matching",
    )
    distance_variance_penalty: float = param(
        0.3**2, unit="m^2", low=1e-9,
        help="sequential match penalty 1 - 0.2 d^2 / this; a variance, already squared (slam_karto "
        "squares its 0.3) [DistanceVariancePenalty]",
    )
    angle_variance_penalty: float = param(
        (20.0 * _DEG) ** 2, unit="rad^2", low=1e-12,
        help="sequential match penalty 1 - 0.2 dtheta^2 / this; already squared, radians despite "
        "slam_karto's 'degrees' comment [AngleVariancePenalty]",
    )
    fine_search_angle_offset: float = param(
        0.2 * _DEG, unit="rad", low=1e-6,
        help="the fine search's angle STEP (Karto's name; Karto uses it as the step, the fine "
        "window is half a coarse step each way) [FineSearchAngleOffset]",
    )
    fine_search_recentre: int = param(
        3, low=0, unit="searches",
        help="while the 1 cm matcher's fine search (sequential matches, near chains, loop refinement) finds "
        "its best pose on the edge of its +-1 cell, +-half a coarse step window, responding better, search "
        "again around it, at most this many times (not "
        "in Karto: at a coarse angle up to 1 deg off, the coarse x, y of a long-range scan is off by "
        "more than the fine step can reach); 0 = Karto's single fine search",
        advanced=True, group="sequential matching",
    )
    coarse_search_angle_offset: float = param(
        20.0 * _DEG, unit="rad", low=0.0, help="half-width of the coarse angle window [CoarseSearchAngleOffset]"
    )
    coarse_angle_resolution: float = param(
        2.0 * _DEG, unit="rad", low=1e-6, help="coarse angle step [CoarseAngleResolution]"
    )
    minimum_angle_penalty: float = param(0.9, low=0.0, high=1.0, help="floor of the angle penalty [MinimumAnglePenalty]")
    minimum_distance_penalty: float = param(
        0.5, low=0.0, high=1.0, help="floor of the distance penalty [MinimumDistancePenalty]"
    )
    use_response_expansion: bool = param(
        False, help="widen the angle window by 20 deg (up to 3 times) when a match finds nothing [UseResponseExpansion]"
    )
    range_threshold: float = param(
        12.0, unit="m", low=0.0, help="returns beyond this are not matched (they still map) [RangeThreshold]"
    )


@dataclass
class LoopClosure:
    """One accepted loop closure: node ``to`` (the new scan) seen from node ``frm``."""

    frm: int
    to: int
    time_from: float
    time_to: float
    measurement: list[float]  # relative pose of `to` in `frm`'s frame, as the edge holds it
    response_coarse: float
    response_fine: float
    cost_before: float
    cost_after: float
    chain_size: int
    confirmed_by: int = -1  # node of the hypothesis that confirmed a weak closure (-1: passed Karto's thresholds)

    def as_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


def _runs(mask: NDArray[np.bool_]) -> list[tuple[int, int]]:
    """Half-open index ranges ``[a, b)`` of the runs of True in ``mask``."""
    if mask.size == 0:
        return []
    return _run_bounds(np.ascontiguousarray(mask, dtype=np.bool_)).tolist()


def _runs_counted(mask: NDArray[np.bool_], flags: NDArray[np.bool_]) -> list[list[int]]:
    """:func:`_runs` of ``mask``, each with how many of ``flags[a:b]`` are True: ``[a, b, count]``."""
    if mask.size == 0:
        return []
    return _run_counts(np.ascontiguousarray(mask, dtype=np.bool_), np.ascontiguousarray(flags, dtype=np.bool_)).tolist()


@njit(cache=True)
def _run_counts(mask, flags):
    """(runs, 3): start, end (half-open) and the number of True ``flags`` of each run of True in ``mask``."""
    runs = _run_bounds(mask)
    out = np.empty((runs.shape[0], 3), np.int64)
    for k in range(runs.shape[0]):
        c = 0
        for i in range(runs[k, 0], runs[k, 1]):
            if flags[i]:
                c += 1
        out[k, 0] = runs[k, 0]
        out[k, 1] = runs[k, 1]
        out[k, 2] = c
    return out


@njit(cache=True)
def _run_bounds(mask):
    """(runs, 2): start and end (half-open) of each run of True in ``mask``, in order."""
    n = mask.shape[0]
    out = np.empty((n // 2 + 1, 2), np.int64)
    m = 0
    k = 0
    while k < n:
        if mask[k]:
            a = k
            while k < n and mask[k]:
                k += 1
            out[m, 0] = a
            out[m, 1] = k
            m += 1
        else:
            k += 1
    return out[:m]


@njit(cache=True)
def _within(ref_xy, node, limit2):
    """Per node, whether its squared distance to ``node``'s (numpy's ``((d) ** 2).sum(axis=1)``) is below ``limit2``."""
    n = ref_xy.shape[0]
    out = np.empty(n, np.bool_)
    x0 = ref_xy[node, 0]
    y0 = ref_xy[node, 1]
    for i in range(n):
        dx = ref_xy[i, 0] - x0
        dy = ref_xy[i, 1] - y0
        out[i] = dx * dx + dy * dy < limit2
    return out


class GraphFrontend:
    """The Karto-class front end over a :class:`~slam2d.backends.PoseGraph`.

    ``sensor_model`` (optional) gives per-beam range sigmas through
    :func:`~slam2d.sensors.beam_model.beam_sigmas`; they widen the smear of
    each reference point in quadrature.
    """

    def __init__(self, params: GraphSlamParams, *, sensor_model: Any = None, diagnostics: Any = None) -> None:
        p = params
        self.params = p
        self.sensor_model = sensor_model
        self.diagnostics = diagnostics
        common = dict(
            coarse_angle_offset=p.coarse_search_angle_offset,
            coarse_angle_resolution=p.coarse_angle_resolution,
            fine_angle_step=p.fine_search_angle_offset,
            distance_variance_penalty=p.distance_variance_penalty,
            angle_variance_penalty=p.angle_variance_penalty,
            minimum_distance_penalty=p.minimum_distance_penalty,
            minimum_angle_penalty=p.minimum_angle_penalty,
            response_expansion=p.use_response_expansion,
        )
        self.sequential = CorrelativeMatcher(
            search_size=p.correlation_search_space_dimension,
            resolution=p.correlation_search_space_resolution,
            smear_deviation=p.correlation_search_space_smear_deviation,
            **common,
        )
        self.loop = CorrelativeMatcher(
            search_size=p.loop_search_space_dimension,
            resolution=p.loop_search_space_resolution,
            smear_deviation=p.loop_search_space_smear_deviation,
            **common,
        )
        self.sequential.fine_recentre = p.fine_search_recentre
        self.sequential.coarse_point_spacing = p.coarse_point_spacing
        # Scans that add no node are matched over their own (smaller) window; its grids are the sequential ones.
        self.between = self.sequential.with_window(p.between_nodes_search_dimension)
        self.between.coarse_angle_offset = p.between_nodes_angle_offset
        # Near chains: the sequential matcher (and grids) over their own angle window.
        self.near = self.sequential.with_window(p.correlation_search_space_dimension)
        if p.near_chain_angle_offset > 0:
            self.near.coarse_angle_offset = p.near_chain_angle_offset
        self.backend = get_backend(p.backend)
        self._seq_cache = GridCache(self.sequential, self._node_reference, max_entries=p.grid_cache_entries)
        self._loop_cache = GridCache(self.loop, self._node_reference)
        self.graph = PoseGraph()
        # Per node: points (base frame), their range sigmas, odometry, time, base-frame barycentre.
        self._points: list[NDArray[np.float64]] = []
        self._sigmas: list[NDArray[np.float64]] = []
        self._ref: list[tuple[NDArray[np.float64], NDArray[np.float64]]] = []  # as a reference (gaps filled)
        self._reach = np.zeros(0)  # per node: its farthest reference point from the robot (see _moved_nodes)
        self._world: list[NDArray[np.float64] | None] = []
        self._odom: list[NDArray[np.float64]] = []
        self._times: list[float] = []
        self._bary_base = np.zeros((0, 2))
        self._bary_store = self._bary_base  # _bary_base's rows, with room to grow (see _append_node)
        self._scans: list[Any] = []  # the kept scans, for the map
        self._running: list[int] = []
        self._put_at: NDArray[np.float64] | None = None  # a relocation waiting for the next frame
        self._directions: dict = {}  # beam layout -> cos, sin of its beam angles
        self.loop_closures: list[LoopClosure] = []
        self.loop_attempts: list[dict[str, Any]] = []
        self.optimizations: list[dict[str, float]] = []
        # Loop attempts since the last optimisation: (chain start, chain end, robot x, y).
        self._tried: list[tuple[int, int, float, float]] = []
        self._self_response: dict[int, float] = {}
        # Weak loop matches waiting for a consistent partner: see _confirm_hypothesis.
        self._hypotheses: list[_Hypothesis] = []
        # Near chains that failed to link since the last optimisation, the same way.
        self._near_failed: list[tuple[int, int, float, float]] = []
        self._near_between: list[tuple[int, int, float, float]] = []
        self._near_linked_at: list[tuple[int, int, float, float]] = []  # near chains linked (near_link_skip_distance)
        # Near chains (start, end) that responded at least _NEAR_HOT of the link threshold from the last node.
        self._near_hot: list[tuple[int, int]] = []
        self._last_odom: NDArray[np.float64] | None = None
        self._ref_cache: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None
        self._frame_pose: NDArray[np.float64] | None = None  # the last frame's pose (world)
        self._after_between = False  # whether the last frame was matched between nodes
        self._frame_degenerate = False  # whether its match was flat along a corridor
        self._frame_response = math.nan  # the last matched scan's unpenalised response
        self._matched_odom: NDArray[np.float64] | None = None  # odometry at the last matched scan
        self._steps: list[NDArray[np.float64]] = []  # per node after the first: see between_node_steps
        # Per node after the first: its sequential edge's measurement and covariance (previous node's frame).
        self._seq_steps: list[tuple[NDArray[np.float64], NDArray[np.float64]]] = []
        self.anchor = -1  # node the last frame's pose hangs from (-1: none yet)
        self.offset = np.zeros(3)
        self.wall_ends = WallEndLandmarks(p, diagnostics) if p.wall_end_landmarks else None

    # ----------------------------------------------------------------- small helpers

    def _count(self, name: str, n: int = 1) -> None:
        if self.diagnostics is not None:
            self.diagnostics.count(name, n)

    @property
    def num_nodes(self) -> int:
        return self.graph.num_nodes

    @property
    def kept_scans(self) -> list[Any]:
        return self._scans

    def odometry_at_nodes(self) -> NDArray[np.float64]:
        """The odometry pose of every node's scan, (N, 3)."""
        return np.asarray(self._odom, dtype=np.float64).reshape(-1, 3)

    def between_node_steps(self) -> NDArray[np.float64]:
        """(N-1, 3): per node k, the pose of node k+1 relative to node k along which the frames between them were placed.

        Matched frames (``match_between_nodes``) hang from node k by their match, so they end at
        node k+1 as it was placed; frames placed by odometry end at the odometry step. Whatever
        an optimisation changes later is the correction to spread over them.
        """
        return np.asarray(self._steps, dtype=np.float64).reshape(-1, 3)

    def node_times(self) -> NDArray[np.float64]:
        return np.asarray(self._times, dtype=np.float64)

    def node_points(self, i: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Node i's matched scan points (base frame, (N, 2)) and their smear sigmas (m)."""
        return self._points[i], self._sigmas[i]

    def _scan_points(self, scan, sig, use) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The scan's points (base frame) of the beams in ``use`` and their smear sigmas.

        ``sig`` None: the points only (a scan matched as a query, never drawn), sigmas None.
        """
        p = self.params
        cos, sin = self._beam_directions(scan)
        # Scan.points()' arithmetic, with the beam directions' cos and sin computed once per layout.
        mount = se2._one(scan.mount)
        if mount is not None:
            # In one compiled pass: the same products and sums in the same order as transform_points'.
            points = _beam_points(mount[0], mount[1], math.cos(mount[2]), math.sin(mount[2]), scan.ranges, cos, sin, use)
        else:
            r = scan.ranges[use]
            points = se2.transform_points(scan.mount, np.stack([r * cos[use], r * sin[use]], axis=-1))
        if sig is None:
            return (points[_thin_keep(points, p.point_spacing)] if p.point_spacing > 0 else points), None
        m = self.sequential
        if type(m).sigmas_for is CorrelativeMatcher.sigmas_for and sig.dtype == scan.ranges.dtype == np.float64:
            # sigmas_for and the beam-gap share below in one compiled pass (the same arithmetic).
            sigmas = _smear_sigmas(float(m.smear_deviation), sig, use, scan.ranges, float(p.smear_beam_spacing),
                                   abs(float(scan.angle_increment)), 0.5 * m.resolution, 10.0 * m.resolution)
            if p.point_spacing > 0:
                points, sigmas = _thin(points, sigmas, p.point_spacing)
            return points, sigmas
        sigmas = self.sequential.sigmas_for(sig[use], int(use.sum()))
        if p.smear_beam_spacing > 0:
            # A reference point stands for the stretch of wall between it and its neighbours'
            # beams: smear it by a share of that gap (range times the beam spacing), in quadrature.
            gap = p.smear_beam_spacing * scan.ranges[use] * abs(float(scan.angle_increment))
            sigmas = np.minimum(np.sqrt(sigmas * sigmas + gap * gap), 10.0 * self.sequential.resolution)
        if p.point_spacing > 0:
            points, sigmas = _thin(points, sigmas, p.point_spacing)
        return points, sigmas

    def _beam_directions(self, scan) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        key = (scan.angle_min, scan.angle_increment, scan.num_beams)
        got = self._directions.get(key)
        if got is None:
            a = scan.angles
            got = self._directions[key] = (np.cos(a), np.sin(a))
        return got

    def _world_points(self, i: int) -> NDArray[np.float64]:
        w = self._world[i]
        if w is None:
            x0, y0, t = self.graph.poses[i].tolist()
            # transform_points' arithmetic in one compiled pass (no numpy temporaries per node).
            w = _transform_xy(x0, y0, math.cos(t), math.sin(t), self._ref[i][0])
            self._world[i] = w
        return w

    def _node_reference(self, i: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Node i as a matching reference: its points with the gaps filled (world frame) and their sigmas."""
        w = self._world[i]  # (asked for every node of every new grid: the cached points without a second call)
        return (self._world_points(i) if w is None else w), self._ref[i][1]

    def _match(self, matcher: CorrelativeMatcher, cache: GridCache, nodes, points, prior, *, penalize, refine,
               min_response=-1.0):
        """Match the query points at ``prior`` against the nodes' scans, through the grid cache."""
        grid = cache.get(nodes, *matcher.search_box(points, prior))
        return matcher.match(None, None, points, prior, penalize=penalize, refine=refine, grid=grid,
                             min_response=min_response)

    def reference_positions(self, poses: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
        """Where each node is for distance tests: barycentre of its points, or the robot position."""
        if poses is None and self.params.use_scan_barycenter:
            # Asked several times per kept scan while the poses rarely change: the last answer is
            # reused while the poses are the same (compared by value, so in-place edits count).
            cached = self._ref_cache
            poses = self.graph.poses
            n = poses.shape[0]
            if cached is not None:
                old, out = cached
                k = old.shape[0]
                # The rows old and poses share from the start, compared as np.array_equal does (==).
                same = _equal_rows(old, poses) if old.ndim == poses.ndim == 2 and old.shape[1] == poses.shape[1] == 3 else -1
                if k == n and same == n:
                    return out
                # A kept scan appends a node, then may move it (the near links' mean): only the new or
                # last rows are transformed again (elementwise, so each row is what the whole would give).
                if 0 < k <= n and same >= k - 1:
                    first = k - 1 if same == k - 1 else k
                    ref = np.empty((n, 2))
                    ref[:first] = out[:first]
                    # se2.transform_points(poses[first:], bary[first:n, None, :]) row by row, its arithmetic.
                    _transform_rows(poses, self._bary_base, np.cos(poses[first:, 2]), np.sin(poses[first:, 2]),
                                    first, ref)
                    ref.flags.writeable = False
                    self._ref_cache = (poses.copy(), ref)
                    return ref
            out = se2.transform_points(poses, self._bary_base[:, None, :])[:, 0, :]
            out.flags.writeable = False
            self._ref_cache = (poses.copy(), out)
            return out
        poses = self.graph.poses if poses is None else poses
        if not self.params.use_scan_barycenter:
            return poses[:, :2].copy()
        return se2.transform_points(poses, self._bary_base[:, None, :])[:, 0, :]

    def _near_and_linked(self, node: int, ref_xy: NDArray[np.float64], max_distance: float):
        """(nodes within ``max_distance`` of ``node``'s reference position, Karto's FindNearLinkedScans: the
        nodes reachable from ``node`` through nodes within that distance)."""
        n = self.graph.num_nodes
        near = _within(np.ascontiguousarray(ref_xy, dtype=np.float64), node, max_distance**2 + 1e-9)
        return near, _reachable(node, near, np.asarray(self.graph.edge_i, dtype=np.int64),
                                np.asarray(self.graph.edge_j, dtype=np.int64), n)

    def _moved_enough(self, odom: NDArray[np.float64], t: float) -> bool:
        if not self._odom:
            return True
        p = self.params
        last = self._odom[-1]
        if t - self._times[-1] >= p.minimum_time_interval:
            return True
        if math.hypot(odom[0] - last[0], odom[1] - last[1]) >= p.minimum_travel_distance:
            return True
        return abs(se2.wrap_scalar(float(odom[2] - last[2]))) >= p.minimum_travel_heading  # wrap_angle's arithmetic on a float

    def _match_information(self, covariance: NDArray[np.float64]) -> NDArray[np.float64]:
        """The information a scan-match edge gets from its covariance (scaled by match_covariance_scale)."""
        return np.linalg.inv(covariance) / self.params.match_covariance_scale

    def _add_edge(self, i: int, j: int, pose_j: NDArray[np.float64], covariance: NDArray[np.float64]) -> None:
        """Edge i -> j measuring ``pose_j`` seen from node i's current pose; world covariance rotated into i."""
        z = se2.relative(self.graph.poses[i], pose_j)
        self.graph.add_edge(i, j, z, self._match_information(self._local_covariance(i, covariance)))

    def _closest_to_node(self, chain: list[int], node: int, pose: NDArray[np.float64]) -> int:
        """The chain's scan whose reference position is closest to the node's (``pose`` before it has one)."""
        ref = self.reference_positions()
        return self._closest_to(chain, ref[node] if node < len(ref) else pose[:2])

    def _link_chain_to_scan(self, chain: list[int], node: int, pose: NDArray[np.float64], cov: NDArray[np.float64]) -> int:
        """Karto's LinkChainToScan: an edge from the chain's scan closest to ``pose``; returns that scan."""
        closest = self._closest_to_node(chain, node, pose)
        if not self._has_edge(closest, node):
            self._add_edge(closest, node, pose, cov)
        return closest

    def _link_running_scan(self, last: int, node: int, pose: NDArray[np.float64], cov: NDArray[np.float64]) -> None:
        """LinkChainToScan over the running scans; with running_link_chain_covariance the edge from an older
        scan than ``last`` carries the sequential steps' uncertainty between the two (see _chain_covariance)."""
        if not self.params.running_link_chain_covariance:
            self._link_chain_to_scan(self._running, node, pose, cov)
            return
        closest = self._closest_to_node(self._running, node, pose)
        if closest == last or self._has_edge(closest, node):
            return  # Karto's edge from the previous node is the sequential one, already added
        z = se2.relative(self.graph.poses[closest], pose)
        local = self._chain_covariance(closest, last, se2.relative(self.graph.poses[last], pose),
                                       self._local_covariance(last, cov))
        self._count("running_links_chained")
        self.graph.add_edge(closest, node, z, self._match_information(local))

    def _chain_covariance(self, i: int, last: int, step: NDArray[np.float64], step_cov: NDArray[np.float64]):
        """Covariance, in node i's frame, of node i's sequential edges up to ``last`` followed by ``step``.

        First-order propagation of ``a + b`` (the relative pose so far composed with the next
        step): Ja covers how the heading error so far swings the step's translation, Jb rotates
        the step's own covariance. The chain is at most the running buffer long.
        """
        heading = 0.0  # of the relative pose so far (se2.compose's heading: its x, y are not needed)
        acc = np.zeros((3, 3))
        seq = self._seq_steps
        for k in range(i, last + 1):  # a few dozen 3x3 products per linked scan, not a per-beam loop
            z, c = seq[k] if k < last else (step, step_cov)
            z0, z1, z2 = float(z[0]), float(z[1]), float(z[2])
            ct, st = math.cos(heading), math.sin(heading)
            ja = np.array([[1.0, 0.0, -st * z0 - ct * z1], [0.0, 1.0, ct * z0 - st * z1], [0.0, 0.0, 1.0]])
            jb = np.array([[ct, -st, 0.0], [st, ct, 0.0], [0.0, 0.0, 1.0]])
            acc = ja @ acc @ ja.T + jb @ c @ jb.T
            heading = se2.wrap_scalar(heading + z2)
        return 0.5 * (acc + acc.T) + _TINY_EYE

    def _has_edge(self, i: int, j: int) -> bool:
        # np.any(((ei == i) & (ej == j)) | ((ei == j) & (ej == i))) in one compiled pass (stops at the first).
        return bool(_edge_between(self.graph.edge_i, self.graph.edge_j, int(i), int(j)))

    def _matches_between_nodes(self, last: int) -> bool:
        p = self.params
        return last >= 0 and p.use_scan_matching and p.match_between_nodes

    def _degenerate(self, cov: NDArray[np.float64], matcher: CorrelativeMatcher | None = None) -> bool:
        """Whether a sequential match's x, y covariance was widened to the window (flat along a corridor)."""
        size = (matcher or self.sequential).search_size
        limit = 0.99 * size**2
        # The largest eigenvalue lies between the larger diagonal entry and that plus the off-diagonal
        # one (Gershgorin): only a covariance near the limit needs the eigenvalue (most are far below).
        a, b, d = float(cov[0, 0]), abs(float(cov[1, 0])), float(cov[1, 1])  # eigvalsh reads the lower triangle
        if max(a, d) + b < limit * (1.0 - 1e-9):
            return False
        return bool(np.linalg.eigvalsh(cov[:2, :2])[-1] >= limit)

    def _sequential_estimate(self, points: NDArray[np.float64], predicted: NDArray[np.float64],
                             values: dict[str, float] | None = None, last_response: float = math.nan,
                             matcher: CorrelativeMatcher | None = None, seed: NDArray[np.float64] | None = None):
        """The sequential match of ``points`` against the running scans from ``predicted``: (pose, covariance, result).

        With ``values`` (a new node's log) a stuck or weak match is searched again over the
        recovery window first. With ``odometry_fusion`` a match whose coarse heading is
        ambiguous is fused with the prediction, unless it is a recovery (which has just shown
        the odometry wrong); a match below ``minimum_match_response`` is replaced by the prediction.
        With ``seed`` the match searches near it first (:meth:`_seeded_match`).
        """
        p = self.params
        matcher = matcher or self.sequential
        if seed is not None and p.seeded_search_window > 0:
            result = self._seeded_match(matcher, points, predicted, seed, last_response)
        else:
            result = self._match(matcher, self._seq_cache, self._running, points, predicted, penalize=True,
                                 refine=True)
        recovered = False
        if values is not None:
            result, recovered = self._recover_sequential(result, points, predicted, values, last_response)
        pose, cov = result.pose, result.covariance
        fuse = p.odometry_fusion and not recovered and result.heading_variance_coarse > ODOMETRY_SIGMA_THETA**2
        if fuse and result.prior_heading_drop > p.odometry_fusion_maximum_drop:
            # The scan fits the odometry's heading clearly worse than its best: the headings it cannot
            # tell apart do not include the odometry's, which is then no evidence to average in.
            self._count("odometry_fusion_refused")
            fuse = False
        if fuse:
            c = cov.copy()
            c[2, 2] = max(c[2, 2], result.heading_variance_coarse)
            pose, cov = _fuse(pose, c, predicted, _odometry_covariance())
        self._frame_response = result.raw_response
        if result.response < p.minimum_match_response:
            # The scan does not fit the running scans (clutter, people, a new room seen from
            # its door): trust the odometry for this step, with an odometry-like uncertainty.
            self._count("match_failures")
            pose = predicted
            cov = _odometry_covariance()
        return pose, cov, result

    def _seeded_match(self, matcher: CorrelativeMatcher, points, predicted, seed, last_response: float):
        """The sequential match of ``points`` from ``predicted``, searched near ``seed`` first.

        The grid is the one the whole search asks for, so the cache evolves the same either way.
        The seeded part stands for the whole window unless its band reaches its edge, its
        response drops from the last scan's (NaN: no reference, so never kept), or its coarse
        headings are ambiguous enough for odometry_fusion to weigh them (decided on the whole
        surface).
        """
        p = self.params
        grid = self._seq_cache.get(self._running, *matcher.search_box(points, predicted))
        half = int(round(0.5 * p.seeded_search_window / (2.0 * matcher.resolution)))
        steps = int(round(p.seeded_search_angle / matcher.coarse_angle_resolution))
        near = matcher.match_near(points, predicted, seed, grid, half_steps=half, angle_steps=steps)
        if (near is not None and near.raw_response >= last_response - p.seeded_search_drop
                and not (p.odometry_fusion and near.heading_variance_coarse > ODOMETRY_SIGMA_THETA**2)):
            self._count("seeded_matches")
            return near
        self._count("seeded_matches_searched_whole")
        return matcher.match(None, None, points, predicted, penalize=True, refine=True, grid=grid)

    def _append_node(self, scan, sig, points, sigmas, pose, odom, timestamp: float) -> int:
        """Add a node at ``pose`` with the scan's points, reference, odometry and time; returns its index."""
        p = self.params
        node = self.graph.add_node(pose)
        self._points.append(points)
        self._sigmas.append(sigmas)
        if p.reference_range_margin > 0:
            wide, _ = _in_range(scan, p.range_threshold + p.reference_range_margin)
            ref = self._scan_points(scan, sig, wide)
        else:
            ref = (points, sigmas)
        self._ref.append(_fill_gaps(*ref, p.reference_gap_fill, 2.0 * self.sequential.resolution))
        self._world.append(None)
        self._odom.append(odom)
        self._times.append(timestamp)
        if not points.shape[0]:
            bary = np.zeros(2)  # no point: the robot's position
        elif points.dtype == np.float64 and points.ndim == 2 and points.shape[1] == 2 and points.flags.c_contiguous:
            bary = _column_means(points)  # points.mean(axis=0): its row-by-row sums and division, compiled
        else:
            bary = points.mean(axis=0)
        # Appended to a growing store (``_bary_base`` is its first rows) instead of a vstack per node.
        base, store = self._bary_base, self._bary_store
        n = base.shape[0]
        if base.base is not store or n > store.shape[0]:
            store = base.copy()  # set from outside: start a store from it
        store = grown(store, n + 1)
        store[n] = bary
        self._bary_store = store
        self._bary_base = store[: n + 1]
        self._scans.append(scan)
        return node

    def add_placed_node(self, scan, odom: NDArray[np.float64], timestamp: float,
                        step: NDArray[np.float64] | None = None,
                        information: NDArray[np.float64] | None = None) -> int:
        """A node the caller placed (no sequential match, no near chains), then the loop closure search.

        The node lies at the previous node's current pose composed with ``step`` (the first node at
        ``odom``), with an edge from the previous node holding ``step`` and ``information``; then
        :meth:`_try_close_loop` runs as in :meth:`process` (candidate chains, coarse then fine
        match, thresholds, hypotheses, the back end after each accepted closure). For a path
        estimated elsewhere (gmapping's ``loop_correction``). Returns the closures accepted.
        """
        p = self.params
        odom = np.asarray(odom, dtype=np.float64)
        use, _ = _in_range(scan, p.range_threshold)
        sig = beam_sigmas(scan, self.sensor_model, 0.0)
        points, sigmas = self._scan_points(scan, sig, use)
        last = self.graph.num_nodes - 1
        if last < 0:
            pose = odom.copy()
        else:
            step = np.asarray(step, dtype=np.float64)
            pose = se2.compose(self.graph.poses[last], step)
        node = self._append_node(scan, sig, points, sigmas, pose, odom, timestamp)
        if last >= 0:
            self.graph.add_edge(last, node, step, information)
            self._seq_steps.append((step.copy(), np.linalg.inv(information)))
            self._steps.append(step.copy())
        self._running.append(node)
        self._trim_running()
        if not (p.do_loop_closing and node > 0 and points.shape[0]):
            return 0
        return self._try_close_loop(node, points)

    # ----------------------------------------------------------------- the main step

    def relocate(self, pose: NDArray[np.float64]) -> None:
        """The next frame is taken at ``pose`` (map frame): see :meth:`process`."""
        self._put_at = np.asarray(pose, dtype=np.float64).reshape(3)

    def process(self, frame: Frame) -> dict[str, float] | None:
        """Handle one frame; returns the values to log, or None when the scan added no node.

        The caller reads :attr:`anchor` (the node the frame's pose hangs from)
        and :attr:`offset` (its pose relative to that node).
        """
        p = self.params
        odom = frame.odometry
        if odom is None:
            self._count("frames_without_odometry")
            odom = self._last_odom if self._last_odom is not None else np.zeros(3)
        odom = np.asarray(odom, dtype=np.float64)
        previous_odom = self._last_odom
        self._last_odom = odom
        relocating = self._put_at is not None and self.graph.num_nodes > 0
        if relocating:
            # A resumed session's new recording: the next node is predicted at the given pose (the last
            # node's odometry re-expressed so that the odometry since it is the step to there), matched
            # against the old scans near it (near chains, loop closure), not against the last ones.
            last = self.graph.num_nodes - 1
            self._odom[last] = se2.compose(odom, se2.inverse(se2.relative(self.graph.poses[last], self._put_at)))
            previous_odom, self._frame_pose, self._running = None, None, []
            self._put_at = None
            self._count("relocations")
        # The last frame's response is a reference only for a scan taken close to it (less than
        # the gate's travel by odometry): on logs thinned to a metre between scans it varies too much.
        last_response, self._frame_response = self._frame_response, math.nan
        if previous_odom is None or math.hypot(float(odom[0]) - float(previous_odom[0]),
                                               float(odom[1]) - float(previous_odom[1])) >= p.minimum_travel_distance:
            last_response = math.nan
        if self.graph.num_nodes:
            last = self.graph.num_nodes - 1
            offset = se2.relative(self._odom[last], odom)
            predicted = se2.compose(self.graph.poses[last], offset)
        else:
            last, offset, predicted = -1, np.zeros(3), odom.copy()
        # The last frame's pose plus the odometry since it (None before the first frame).
        chained = (None if self._frame_pose is None or previous_odom is None
                   else se2.compose(self._frame_pose, se2.relative(previous_odom, odom)))
        if p.predict_from_last_scan and self._matches_between_nodes(last) and chained is not None:
            # The last scan was matched too. Where its pose plus the odometry since it puts the
            # heading more than half the angle window from the node-based prediction, the odometry
            # turned wrong since the node, and the match could miss it: predict from that scan. Its
            # position is taken only if its match was not flat along a corridor (chaining those
            # drifts more than the odometry).
            if abs(se2.wrap_scalar(float(chained[2] - predicted[2]))) > 0.5 * p.coarse_search_angle_offset:
                self._count("predicted_from_last_scan")
                if self._frame_degenerate:
                    predicted = np.array([predicted[0], predicted[1], chained[2]])
                else:
                    predicted = chained
        # Where the seeded search looks first: the last scan's matched pose plus the odometry since it,
        # when that scan was matched between nodes (a few cm back). A node right after a node is
        # searched whole: its prediction can be decimetres off, where a second peak outside the
        # part can hold poses within the covariance band (intel: once in 905 nodes).
        seed = chained if self._matches_between_nodes(last) and chained is not None else None
        after_between, self._after_between = self._after_between, False
        moved = self._moved_enough(odom, frame.timestamp)
        if not moved and not self._matches_between_nodes(last):
            self.anchor, self.offset = last, offset
            return None
        scan = frame.scan
        use, any_use = _in_range(scan, p.range_threshold)
        if not any_use:
            self._count("empty_scans")
            self.anchor, self.offset = last, offset
            if not moved and chained is not None:
                # Between nodes: the last frame's pose plus the odometry since it.
                self.offset = se2.relative(self.graph.poses[last], chained)
                self._frame_pose = chained
            return None
        if not moved and p.between_nodes_skip_travel > 0 and chained is not None and self._matched_odom is not None:
            # Between nodes the odometry over a few cm is good to well under the matcher's cell:
            # chain the last scan's pose instead of matching, until it has moved or turned enough.
            since = se2.relative(self._matched_odom, odom)
            if (math.hypot(since[0], since[1]) < p.between_nodes_skip_travel
                    and abs(float(since[2])) < p.between_nodes_skip_turn):
                self._count("frames_chained_between_nodes")
                self.anchor, self.offset = last, se2.relative(self.graph.poses[last], chained)
                self._frame_pose = chained
                self._frame_response = last_response
                self._after_between = True
                return None
        if not moved:
            # A scan that adds no node is still matched against the running scans, for its own
            # pose in the trajectory: between nodes the odometry alone can be degrees off. It is
            # never drawn as a reference, so it needs no sigmas.
            points, _ = self._scan_points(scan, None, use)
            pose, fcov, _ = self._sequential_estimate(points, predicted, matcher=self.between,
                                                      last_response=last_response, seed=seed)
            self._frame_degenerate = self._degenerate(fcov, self.between)
            self._count("frames_matched_between_nodes")
            self.anchor, self.offset = last, se2.relative(self.graph.poses[last], pose)
            self._frame_pose = pose
            self._matched_odom = odom
            self._after_between = True
            return None
        sig = beam_sigmas(scan, self.sensor_model, 0.0)
        points, sigmas = self._scan_points(scan, sig, use)
        values: dict[str, float] = {}
        pose = predicted
        if relocating:
            cov = np.diag([RELOCATION_SIGMA_XY**2, RELOCATION_SIGMA_XY**2, RELOCATION_SIGMA_THETA**2])
        elif last >= 0 and p.use_scan_matching:
            pose, cov, result = self._sequential_estimate(points, predicted, values, last_response,
                                                          seed=seed if after_between else None)
            values["response"] = result.response
            # np.hypot of the two differences, taken in Python floats (the same subtractions).
            values["correction_m"] = float(np.hypot(float(result.pose[0]) - float(predicted[0]),
                                                    float(result.pose[1]) - float(predicted[1])))
        elif last >= 0:
            cov = _odometry_covariance()
        else:
            cov = np.diag([MAX_COV, MAX_COV, MAX_COV])
        node = self._append_node(scan, sig, points, sigmas, pose, odom, frame.timestamp)
        if last >= 0:
            means = [pose]
            covs = [cov]
            self._add_edge(last, node, pose, cov)
            self._seq_steps.append((self.graph.measurements[-1].copy(), self._local_covariance(last, cov)))
            if self._running:  # (none right after a relocation)
                self._link_running_scan(last, node, pose, cov)
            linked = self._link_near_chains(node, points, pose, means, covs)
            values["near_links"] = float(linked)
            if len(means) > 1:
                pose = _weighted_mean(means, covs)
                self.graph.poses[node] = pose
                self._world[node] = None
            # The step from the last node that the frames in between were placed along: their
            # matched poses end at this node as placed now, their odometry at the odometry step.
            if self._matches_between_nodes(last):
                self._steps.append(se2.relative(self.graph.poses[last], self.graph.poses[node]))
            else:
                self._steps.append(se2.relative(self._odom[last], odom))
        self._running.append(node)
        self._trim_running()
        if self.wall_ends is None and node == 0 and 0.0 < scan.range_max < p.wall_end_auto_range:
            # A short-range laser (wall_end_auto_range): the wall ends go on from the first scan.
            self.wall_ends = WallEndLandmarks(p, self.diagnostics)
            self._count("wall_end_landmarks_auto")
        if self.wall_ends is not None:
            self.wall_ends.observe(self, node, scan, sig)
        closed = 0
        if p.do_loop_closing and node > 0:
            closed = self._try_close_loop(node, points)
        values["loop_closures"] = float(closed)
        self.anchor, self.offset = node, np.zeros(3)
        self._frame_pose = self.graph.poses[node].copy()
        self._frame_degenerate = self._degenerate(cov)
        self._matched_odom = odom
        return values

    def _recover_sequential(self, result, points, predicted, values, last_response=math.nan):
        """Search a sequential match again over the wide recovery window when it is stuck or weak.

        Karto trusts the odometry to within its +-0.15 m window. On fr079 the odometry logs
        reversing as driving forward (0.6 m wrong per kept scan) and slips 0.2-0.4 m in
        turns: the match then sits on the window's edge or responds poorly, and the error
        stays in the graph. The wide search is not penalised (any place in the window is as
        likely); it replaces the first match only when it fits clearly better. Returns the
        match to use and whether it is a recovery.
        """
        p = self.params
        m = self.sequential
        if p.sequential_recovery_window <= m.search_size:
            return result, False
        # np.abs(result.pose[:2] - predicted[:2]).max() on floats (NaN if either is, as numpy's max).
        d0 = abs(float(result.pose[0]) - float(predicted[0]))
        d1 = abs(float(result.pose[1]) - float(predicted[1]))
        shift = math.nan if d0 != d0 or d1 != d1 else max(d0, d1)
        edge = shift >= 0.5 * m.search_size - 2.5 * m.resolution  # within a coarse step of the edge
        # A drop from the last matched scan's response (NaN: none) counts as weak as well.
        drop = result.raw_response < last_response - p.sequential_recovery_drop
        if not edge and not drop and result.raw_response >= p.sequential_recovery_response:
            return result, False
        self._count("sequential_edge_hits" if edge else
                    "sequential_weak_matches" if result.raw_response < p.sequential_recovery_response
                    else "sequential_response_drops")
        # Coarse over the wide window on a fresh grid at the loop matcher's cell (5 cm: cheap to
        # build, and the cached 1 cm grids stay as they were), then the usual 1 cm match there.
        wide = self.loop.with_window(p.sequential_recovery_window)
        wide.coarse_angle_offset = max(wide.coarse_angle_offset, p.sequential_recovery_angle)
        parts = [self._node_reference(n) for n in self._running]
        ref, sig = np.concatenate([q[0] for q in parts]), np.concatenate([q[1] for q in parts])
        grid = wide.correlation_grid(ref, sig, *wide.search_box(points, predicted))
        coarse = wide.match(None, None, points, predicted, penalize=False, refine=True, grid=grid)
        alt = self._match(m, self._seq_cache, self._running, points, coarse.pose, penalize=False, refine=True)
        # It must fit clearly better, and not be a weak match itself (a 0.4 match 1 m away
        # on intel was a wrong one). "Better" is a share of the first match's misfit: a wider
        # smear (smear_beam_spacing) lifts every response towards 1 and shrinks differences in
        # response, not their ratio (corridor loop, RPLidar: 0.91 -> 0.95 found a 0.25 m slip).
        misfit = (1.0 - result.raw_response) * (1.0 - p.sequential_recovery_margin)
        floor = max(1.0 - misfit, p.sequential_recovery_response)
        values["recovery_response"] = alt.response
        if alt.response < floor:
            return result, False
        values["recovery_m"] = float(np.hypot(*(alt.pose[:2] - result.pose[:2])))
        if float(np.linalg.eigvalsh(alt.covariance[:2, :2]).max()) > p.sequential_recovery_maximum_variance:
            # Along a corridor the better fit holds the heading and the position across it, not
            # where along it the scan is (in the simulated office one such fit, response 1.0, lay
            # 0.63 m along the corridor from the truth): the odometry prediction is fused in, so
            # along the corridor it decides.
            self._count("sequential_recoveries_fused")
            odo = _odometry_covariance()
            odo[2, 2] = MAX_COV  # the odometry's heading is what went wrong
            pose, cov = _fuse(alt.pose, alt.covariance, predicted, odo)
            alt = dataclasses.replace(alt, pose=pose, covariance=cov)
            values["recovery_m"] = float(np.hypot(*(pose[:2] - result.pose[:2])))
        else:
            self._count("sequential_recoveries")
        return alt, True

    def _path_length(self, i: int, j: int) -> float:
        """Distance the robot travelled from node i to node j along the graph's current poses."""
        xy = self.graph.poses[i : j + 1, :2]
        return float(np.hypot(*np.diff(xy, axis=0).T).sum()) if j > i else 0.0

    def _trim_running(self) -> None:
        p = self.params
        while len(self._running) > p.scan_buffer_size:
            self._running.pop(0)
        if len(self._running) > 1:
            ref = self.reference_positions()
            nx, ny = ref[self._running[-1]].tolist()
            while len(self._running) > 1:
                ox, oy = ref[self._running[0]].tolist()
                d = float(np.hypot(ox - nx, oy - ny))  # np.hypot of the same differences, on floats
                if d <= p.scan_buffer_maximum_scan_distance:
                    break
                self._running.pop(0)

    def _link_near_chains(self, node: int, points, pose, means: list, covs: list) -> int:
        """Karto's LinkNearChains: match older passes already connected in the graph; link the good ones."""
        p = self.params
        ref_xy = self.reference_positions()
        near, linked = self._near_and_linked(node, ref_xy, p.link_scan_maximum_distance)
        linked[node] = False
        hot, self._near_hot = self._near_hot, []
        if not linked.any():
            return 0
        link = p.link_match_minimum_response_fine
        lo, hi = self.sequential.search_box(points, pose)  # the same query box for every chain
        count = 0
        for a, b, n_linked in _runs_counted(near, linked):
            if a <= node < b or not n_linked or b - a < p.loop_match_minimum_chain_size:
                continue
            if self._tried_nearby(a, b, pose, p.loop_retry_distance, self._near_failed):
                self._count("near_skipped_retry")
                continue
            if self._tried_nearby(a, b, pose, p.near_link_skip_distance, self._near_linked_at):
                self._count("near_skipped_linked")
                continue
            chain = range(a, b)  # a list only where it links (reserve reads a range's ends directly)
            # The cache's book-keeping is done whatever happens, so later matches read the grids
            # they would have (see GridCache.reserve).
            entry = self._seq_cache.reserve(chain, lo, hi, max_extra=p.near_chain_grid_extra)
            # Hot: like a chain that responded well from the last node, its grid already drawn (a first
            # draw costs more than the bound it would spare).
            warm = entry["grid"] is not None and any(ha < b and a < hb for ha, hb in hot)
            if not warm and self._tried_nearby(a, b, pose, p.near_bound_retry_distance, self._near_between):
                self._count("near_skipped_between_retry")
                continue
            outcome = self._near_outcome(entry, points, pose, lo, hi, warm)
            if outcome is None:
                if p.near_bound_retry_distance > 0:
                    self._near_between.append((a, b, float(pose[0]), float(pose[1])))
                    del self._near_between[:-100]
                continue
            if outcome == "failed":
                # Only a chain far from linking (out of view, behind a wall) is skipped next
                # time: one that nearly linked may link from the next pose.
                self._near_failed.append((a, b, float(pose[0]), float(pose[1])))
                del self._near_failed[:-100]
                continue
            result = outcome
            if result.response >= _NEAR_HOT * link:
                self._near_hot.append((a, b))
            if result.response > link:
                cov = result.covariance
                if p.link_flat_variance > 0 and self._degenerate(cov):
                    w, v = np.linalg.eigh(cov[:2, :2])
                    cov = cov.copy()
                    cov[:2, :2] += max(p.link_flat_variance - w[-1], 0.0) * np.outer(v[:, -1], v[:, -1])
                    self._count("near_links_flat")
                means.append(result.pose)
                covs.append(cov)
                self._link_chain_to_scan(list(chain), node, result.pose, cov)
                count += 1
                if p.near_link_skip_distance > 0:
                    self._near_linked_at.append((a, b, float(pose[0]), float(pose[1])))
                    del self._near_linked_at[:-100]
        return count

    def _near_outcome(self, entry: dict, points, pose, lo, hi, hot: bool):
        """A near chain's match (a MatchResult), "failed" (record it), or None (not linked, not failed).

        The response bound (no 1 cm grid needed) tells most chains that cannot link apart
        without drawing or searching: below the failure mark (half the link threshold) the
        chain is failed, below the threshold it is skipped. A ``hot`` chain (one like it
        responded well from the last node) most likely links again: it is
        matched first and bounded only when its response falls below the mark, so the outcome
        is the one the bound-first order gives (response <= bound: a response at or above the
        mark means a bound at or above it too).
        """
        link = self.params.link_match_minimum_response_fine
        fail = 0.5 * link
        bound = None
        if not hot:
            bound = self._seq_cache.bound(entry, points, pose, stop=link, mark=fail, matcher=self.near)
            if bound < fail:
                self._count("near_skipped_bound")
                return "failed"
            if bound < link:
                # It cannot link from here either, but it may respond well enough not to count as
                # failed: it is tried again from the next pose, as a match that nearly linked is.
                self._count("near_skipped_bound_link")
                return None
        smeared = self._seq_cache.smeared
        grid = self._seq_cache.materialize(entry, lo, hi)
        self._count("near_points_smeared", self._seq_cache.smeared - smeared)
        result = self.near.match(None, None, points, pose, penalize=False, refine=True, grid=grid)
        if result.response >= fail:
            return result
        if bound is None:
            # Bound-first would not have matched a chain bounded in [fail, link), nor failed it.
            self._count("near_matched_before_bound")
            bound = self._seq_cache.bound(entry, points, pose, stop=link, mark=fail, matcher=self.near)
            if fail <= bound < link:
                self._count("near_skipped_bound_link")
                return None
            if bound < fail:
                self._count("near_skipped_bound")
        return "failed"

    def _try_close_loop(self, node: int, points: NDArray[np.float64]) -> int:
        p = self.params
        closed = 0
        start = 0
        candidate = None
        while True:
            if candidate is None:  # the graph changes only when a closure is accepted
                ref_xy = self.reference_positions()
                near, linked = self._near_and_linked(node, ref_xy, p.loop_search_maximum_distance)
                candidate = near & ~linked
            chains = [(a, b) for a, b in _runs(candidate) if b - a >= p.loop_match_minimum_chain_size and a >= start]
            if not chains:
                return closed
            a, b = chains[0]
            start = b
            chain = list(range(a, b))
            pose = self.graph.poses[node].copy()
            if self._tried_nearby(a, b, pose, p.loop_retry_distance):
                self._count("loop_skipped_retry")
                continue
            self._tried.append((a, b, float(pose[0]), float(pose[1])))
            del self._tried[:-100]  # only recent attempts can be near the robot
            # Poses that cannot reach the acceptance threshold are not searched (exact for every
            # accepted closure; a rejected one may report a lower response than the best).
            coarse_threshold = p.loop_match_minimum_response_coarse
            if p.loop_coarse_relative:
                coarse_threshold *= self._coarse_self_response(node, points)
            # The drift gate bounds the correction a closure may make, so the window need not
            # reach farther (a look-alike beyond it would be rejected anyway).
            path = self._path_length(b - 1, node)
            allowed = p.loop_match_maximum_correction + p.loop_match_maximum_drift * path
            matcher = self.loop
            if 2.0 * allowed < self.loop.search_size:
                matcher = self.loop.with_window(max(2.0 * allowed, self.sequential.search_size))
            # The refine step can lift a coarse pose by about the angle sampling's loss, so the
            # branch and bound must keep scoring poses that far below the threshold.
            floor = min(coarse_threshold, p.loop_match_minimum_response_confirmed)
            floor -= _REFINE_GAIN if p.loop_coarse_refine else 0.0
            coarse = self._match(matcher, self._loop_cache, chain, points, pose, penalize=False,
                                 refine=p.loop_coarse_refine, min_response=floor)
            self._count("loop_attempts")
            correction = float(np.hypot(*(coarse.pose[:2] - pose[:2])))
            attempt = {"to": node, "chain": [a, b], "response_coarse": coarse.response,
                       "var_x": float(coarse.covariance[0, 0]), "var_y": float(coarse.covariance[1, 1]),
                       "correction_m": correction, "path_m": path, "threshold_coarse": coarse_threshold,
                       "pose": [float(v) for v in coarse.pose]}
            self.loop_attempts.append(attempt)
            if correction > p.loop_match_maximum_correction + p.loop_match_maximum_drift * path:
                self._count("loop_rejected_drift")
                continue
            variance_ok = (coarse.covariance[0, 0] < p.loop_match_maximum_variance_coarse
                           and coarse.covariance[1, 1] < p.loop_match_maximum_variance_coarse)
            strong = coarse.response > coarse_threshold
            rescued = False
            # Every peak that could refine to the hypothesis threshold is refined (the reach the branch and
            # bound searched), not only those near the lattice's best: the lattice can sample the true place
            # lowest of all (a sharp peak half a step from every lattice pose).
            reach_floor = min(coarse_threshold, p.loop_match_minimum_response_confirmed) - _REFINE_GAIN
            if not (variance_ok and (strong or coarse.response >= p.loop_match_minimum_response_confirmed)):
                # The lattice may have sampled a sharp true place far below its value: a match within
                # the refine step's reach of the hypothesis threshold is judged on its refined places.
                if not (p.loop_refine_coarse and coarse.response > 0.0 and coarse.response >= reach_floor):
                    self._count("loop_rejected_coarse")
                    continue
                self._count("loop_refined_coarse")
                attempt["refined"] = True
                coarse, spread, surface_cov = self._best_place(matcher, chain, points, pose, coarse, allowed, attempt,
                                                               keep_near=False, floor=reach_floor)
                # Karto's tests on the best refined place: its response, and the coarse surface's
                # spread about it (lattice poses within the band of its response, and itself).
                cov = surface_cov(coarse.pose, coarse.response)
                attempt["var_x_refined"], attempt["var_y_refined"] = float(cov[0, 0]), float(cov[1, 1])
                strong = coarse.response > coarse_threshold
                if not (cov[0, 0] < p.loop_match_maximum_variance_coarse and cov[1, 1] < p.loop_match_maximum_variance_coarse
                        and (strong or coarse.response >= p.loop_match_minimum_response_confirmed)):
                    self._count("loop_rejected_coarse")
                    continue
                self._count("loop_rescued")
                attempt["rescued"] = True
                rescued = True
            ambiguous = False
            if p.loop_check_peaks or rescued:
                if not rescued:
                    coarse, spread, _ = self._best_place(matcher, chain, points, pose, coarse, allowed, attempt,
                                                         floor=reach_floor if p.loop_refine_coarse else None)
                # Places about equally good far apart: whichever this scan's match picked, it is not
                # evidence alone. It waits, as a weak match does, for a match from another scan that
                # is not ambiguous and puts the new scans in the same place of the old map.
                ambiguous = spread > p.loop_match_maximum_variance_coarse
                strong = coarse.response > coarse_threshold and not ambiguous
                if ambiguous:
                    self._count("loop_ambiguous")
                    attempt["ambiguous"] = True
            fine = self._match(self.sequential, self._seq_cache, chain, points, coarse.pose, penalize=False, refine=True)
            attempt["response_fine"] = fine.response
            strong = strong and fine.response >= p.loop_match_minimum_response_fine
            if not strong and fine.response < p.loop_match_minimum_response_confirmed:
                self._count("loop_rejected_fine")
                continue
            frm = self._closest_in_chain(chain, fine.pose)
            hyp = _Hypothesis(node=node, frm=frm, z=se2.relative(self.graph.poses[frm], fine.pose),
                              covariance=self._local_covariance(frm, fine.covariance),
                              response_coarse=coarse.response, response_fine=fine.response, chain_size=b - a,
                              ambiguous=ambiguous)
            partner = None
            if not strong:
                # Below Karto's thresholds a match alone is not trusted; a second one from another
                # scan that puts the new scans in the same place of the old map is the evidence.
                partner = self._confirming_hypothesis(hyp)
                if partner is None:
                    self._hypotheses.append(hyp)
                    self._count("loop_hypotheses")
                    attempt["hypothesis"] = True
                    continue
                self._hypotheses.remove(partner)
                self._count("loop_confirmed")
            attempt["accepted"] = True
            for h in (partner, hyp):
                if h is None:
                    continue
                if h.node == node:
                    self.graph.poses[node] = fine.pose
                    self._world[node] = None
                if not self._has_edge(h.frm, h.node):
                    self.graph.add_edge(h.frm, h.node, h.z, self._match_information(h.covariance))
            before, after = self.optimize()
            for h in (partner, hyp):
                if h is None:
                    continue
                self.loop_closures.append(
                    LoopClosure(
                        frm=h.frm, to=h.node, time_from=self._times[h.frm], time_to=self._times[h.node],
                        measurement=[float(v) for v in h.z], response_coarse=h.response_coarse,
                        response_fine=h.response_fine, cost_before=before, cost_after=after, chain_size=h.chain_size,
                        confirmed_by=-1 if partner is None else (partner.node if h is hyp else hyp.node),
                    )
                )
                self._count("loop_closures")
                closed += 1
            candidate = None

    def _best_place(self, matcher, chain, points, pose, coarse, allowed, attempt, keep_near=True, floor=None):
        """The loop match's best place among every distinct peak of its coarse surface, and their spread.

        The coarse search samples x, y every two cells and the heading every 2 deg; a wall
        seen across a corridor gives a peak a few centimetres wide, which the lattice can
        sample 0.15-0.3 below its value while a look-alike place happens to sit on a lattice
        point (simulated corridor loop: true place 1.0 refined, 0.67 on the lattice; a place
        1.5 m along the corridor 0.83). So every local maximum of the coarse surface that
        the refine step could lift to within the covariance band of the best (down to
        _REFINE_GAIN plus that band below it) and that the drift gate allows is refined as
        the best one was, and the best refined place is the match. Karto's variance test is
        then repeated over the refined places: their response-weighted spread about the best
        (divided by the best response, as Karto's covariance is), counting those within the
        covariance band of it, in the worst direction. Two places that fit about equally
        well far apart are a look-alike, whichever is right: the caller treats the match as
        ambiguous when the spread exceeds Karto's limit. With ``keep_near`` false (a match that
        failed the coarse tests, loop_refine_coarse) the best refined place is the match even
        near the first one. Returns (match, spread in m^2, the coarse surface's covariance
        about a pose: ``places(about=True)``).
        """
        grid = self._loop_cache.get(chain, *matcher.search_box(points, pose))
        band = COVARIANCE_BAND
        places = [(coarse.pose, coarse.response)]
        if floor is None:
            floor = coarse.response - band - _REFINE_GAIN
        found, surface_cov = matcher.places(points, pose, grid, floor=floor, about=True)
        for q_pose, q_resp in found:
            if float(np.hypot(*(q_pose[:2] - pose[:2]))) <= allowed:
                places.append((q_pose, q_resp))
        # Places within the reach of the best's own refine (one coarse step and a cell) are that
        # place: the match stays as it was unless a place beyond that fits better.
        reach = 3.0 * matcher.resolution
        best = max(range(len(places)), key=lambda k: places[k][1])
        if keep_near and float(np.hypot(*(places[best][0][:2] - coarse.pose[:2]))) <= reach:
            best = 0
        b_pose, b_resp = places[best]
        spread = np.zeros((2, 2))
        weight = b_resp
        rivals = 0
        for k, (q_pose, q_resp) in enumerate(places):
            d = q_pose[:2] - b_pose[:2]
            if k == best or q_resp < b_resp - band or float(np.hypot(*d)) <= reach:
                continue
            spread += q_resp * np.outer(d, d)
            weight += q_resp
            rivals += 1
        worst = float(np.linalg.eigvalsh(spread / (weight * max(b_resp, 1e-9)))[-1]) if rivals else 0.0
        attempt["peaks"] = len(places) - 1
        attempt["rivals"] = rivals
        attempt["spread"] = worst
        if best != 0:
            self._count("loop_better_peaks")
            attempt["moved_m"] = float(np.hypot(*(b_pose[:2] - coarse.pose[:2])))
            attempt["response_coarse"] = b_resp
            coarse = dataclasses.replace(coarse, pose=b_pose.copy(), response=b_resp)
        return coarse, worst, surface_cov

    def _closest_in_chain(self, chain: list[int], pose: NDArray[np.float64]) -> int:
        """The chain's scan whose reference position is closest to the new scan at ``pose`` (LinkChainToScan's choice)."""
        node = self.graph.num_nodes - 1
        target = se2.transform_points(pose, self._bary_base[node][None, :])[0] if self.params.use_scan_barycenter else pose[:2]
        return self._closest_to(chain, target)

    def _closest_to(self, chain: list[int], target: NDArray[np.float64]) -> int:
        """The chain's scan whose reference position is closest to ``target`` (the first on a tie)."""
        ref = self.reference_positions()
        # np.argmin(((ref[chain] - target) ** 2).sum(axis=1)) in one compiled pass (the same sums).
        return int(chain[_closest_row(ref, np.asarray(chain, dtype=np.int64), float(target[0]), float(target[1]))])

    def _local_covariance(self, i: int, covariance: NDArray[np.float64]) -> NDArray[np.float64]:
        """A world-frame match covariance rotated into node i's frame, as an edge from i holds it."""
        c, s = math.cos(self.graph.poses[i][2]), math.sin(self.graph.poses[i][2])
        rot = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
        cov = rot @ covariance @ rot.T
        return 0.5 * (cov + cov.T) + _TINY_EYE

    def _confirming_hypothesis(self, hyp: _Hypothesis) -> _Hypothesis | None:
        """A waiting hypothesis from another recent scan that agrees with ``hyp`` (pairwise consistency).

        Each hypothesis says where its scan lies relative to an old scan. Going round the cycle
        old scan 1 -> new scan 1 (hypothesis 1) -> new scan 2 (the graph, a few metres of recent
        matching) -> old scan 2 (hypothesis 2, inverted) -> old scan 1 (the graph along the old
        pass) must bring us back where we started if both are right; two wrong matches (or one
        right, one wrong) rarely agree. Expired hypotheses are dropped here.
        """
        p = self.params
        poses = self.graph.poses
        keep = []
        best, best_err = None, math.inf
        for h in self._hypotheses:
            if self._path_length(h.node, hyp.node) > p.loop_confirm_path:
                continue
            keep.append(h)
            # Both legs of the cycle through the graph must be short: a long one carries the
            # drift a closure is there to correct, and a wrong match can agree with it.
            # Two ambiguous matches can agree on the same wrong place (a repeated stretch of corridor
            # seen from two poses): one of the pair must have seen the place unambiguously.
            if (h.ambiguous and hyp.ambiguous) or h.node == hyp.node or self._path_length(min(h.frm, hyp.frm), max(h.frm, hyp.frm)) > p.loop_confirm_path:
                continue
            via_h = se2.compose(se2.compose(poses[h.frm], h.z), se2.relative(poses[h.node], poses[hyp.node]))
            err = se2.relative(se2.compose(poses[hyp.frm], hyp.z), via_h)
            dist, ang = float(np.hypot(err[0], err[1])), abs(float(se2.wrap_angle(err[2])))
            if dist <= p.loop_confirm_distance and ang <= p.loop_confirm_angle:
                score = dist / max(p.loop_confirm_distance, 1e-9) + ang / max(p.loop_confirm_angle, 1e-9)
                if score < best_err:
                    best, best_err = h, score
        self._hypotheses = keep
        return best

    def _coarse_self_response(self, node: int, points: NDArray[np.float64]) -> float:
        """Coarse loop response of the scan against itself, the truth half a coarse step off every sample.

        This is what a perfect loop match is sure to reach on the loop grid: points
        far from the robot leave their cell when the angle is off by a degree, so a
        long-range scan scores well below 1 even at the right place.
        """
        got = self._self_response.get(node)
        if got is None:
            m = self.loop
            sig = self._sigmas[node]
            lo, hi = points.min(axis=0) - 1.0, points.max(axis=0) + 1.0
            grid = m.correlation_grid(points, sig, lo, hi)
            off = np.array([0.5 * m.resolution, 0.5 * m.resolution, 0.25 * m.coarse_angle_resolution])
            small = m.with_window(8.0 * m.resolution)
            r = small.match(None, None, points, off, penalize=False, refine=False, grid=grid)
            got = float(min(max(r.response, 0.5), 1.0))
            self._self_response[node] = got
        return got

    def _tried_nearby(self, a: int, b: int, pose: NDArray[np.float64], distance: float, tried=None) -> bool:
        """Whether a chain overlapping [a, b) was tried from within ``distance`` of ``pose`` since the last optimisation."""
        if distance <= 0:
            return False
        px, py = float(pose[0]), float(pose[1])  # read once (the same differences as pose[0] - x)
        for ta, tb, x, y in reversed(self._tried if tried is None else tried):
            if ta < b and a < tb and math.hypot(px - x, py - y) < distance:
                return True
        return False

    def _moved_nodes(self, before: NDArray[np.float64], after: NDArray[np.float64]) -> NDArray[np.bool_] | None:
        """Per node, whether one of its reference points moved more than ``grid_keep_tolerance`` (None: all).

        A point x (base frame) moves by at most |dt| + 2 |sin(dtheta / 2)| |x|.
        """
        tol = self.params.grid_keep_tolerance
        if tol <= 0 or before.shape != after.shape:
            return None
        n = len(self._ref)
        if self._reach.size < n:  # each node's farthest reference point, computed once
            new = [float(np.sqrt((r[0] ** 2).sum(axis=1)).max()) if len(r[0]) else 0.0 for r in self._ref[self._reach.size:]]
            self._reach = np.concatenate([self._reach, np.asarray(new, dtype=np.float64)])
        d = after[:n] - before[:n]
        shift = np.hypot(d[:, 0], d[:, 1]) + 2.0 * np.abs(np.sin(0.5 * d[:, 2])) * self._reach[:n]
        return shift > tol

    def optimize(self) -> tuple[float, float]:
        """Run the back end over the whole graph and keep its poses: (cost before, cost after)."""
        if self.graph.num_edges == 0:
            return 0.0, 0.0
        res = (self.backend.optimize(self.graph) if self.wall_ends is None
               else self.wall_ends.optimize(self.backend, self.graph))
        before = self.graph.poses.copy()  # the setter below writes into the array `poses` returns
        if np.all(np.isfinite(res.poses)):
            self.graph.poses = res.poses
        else:
            self._count("optimizer_failures")
        self._world = [None] * len(self._world)
        self._seq_cache.invalidate(self._moved_nodes(before, self.graph.poses))
        self._loop_cache.invalidate()
        self._tried.clear()
        self._near_failed.clear()
        self._near_between.clear()
        self._near_linked_at.clear()
        self.optimizations.append(
            {"nodes": self.graph.num_nodes, "edges": self.graph.num_edges, "cost_before": res.cost_before,
             "cost_after": res.cost_after, "iterations": res.iterations, "cpu_s": res.cpu_s}
        )
        return float(res.cost_before), float(res.cost_after)

    def refine_walls(self, frames: tuple | None = None) -> tuple[dict[str, float], NDArray[np.float64] | None]:
        """The wall bundle adjustment (``wall_refinement``) of the finished graph: the node poses replaced.

        ``frames`` (optional): ``(scans, odometry (F, 3), poses (F, 3), node_frame (N,))``, every placed
        frame with its scan, odometry and current pose, and the frame of each node: the refinement then
        runs over all frames (odometry between consecutive frames), and the refined frame poses are
        returned too. Returns (a summary: walls, beams on them, objective before and after, CPU
        seconds; the refined frame poses or None).
        """
        import time

        cpu = time.process_time()
        p = self.params
        if frames is None:
            scans, odom, poses, node_frame = self._scans, self.odometry_at_nodes(), self.graph.poses, None
        else:
            scans, odom, poses, node_frame = frames
        we = self.wall_ends
        obs = we.observations() if we is not None else None
        if obs is not None and node_frame is not None:
            obs = type(obs)(node_frame[obs.pose], obs.landmark, obs.z, obs.information)
        where = (lambda k: k) if node_frame is None else (lambda k: node_frame[k])
        graph, extra = None, None
        if p.wall_refinement_edges == "graph" and node_frame is None:
            graph = self.graph
        else:
            ei, ej = self.graph.edge_i, self.graph.edge_j
            if p.wall_refinement_edges == "graph":
                sel = np.ones(ei.shape[0], dtype=bool)
            elif p.wall_refinement_edges == "odometry+loops" and self.loop_closures:
                loops = {(c.frm, c.to) for c in self.loop_closures}
                sel = np.array([(int(a), int(b)) in loops for a, b in zip(ei, ej)], dtype=bool)
            else:
                sel = np.zeros(ei.shape[0], dtype=bool)
            extra = (where(ei[sel]), where(ej[sel]), self.graph.measurements[sel], self.graph.information[sel])
        res, segs = refine_path(scans, poses, p, graph=graph, odometry=odom, fixed=int(where(self.graph.fixed)),
                                extra_edges=extra, sensor_model=self.sensor_model, range_limit=p.range_threshold,
                                points=obs, point_count=we.num_landmarks if we is not None else 0,
                                dense=p if p.dense_refinement else None)
        refined = None
        if np.all(np.isfinite(res.poses)):
            self.graph.poses = res.poses if node_frame is None else res.poses[node_frame]
            refined = res.poses if node_frame is not None else None
        else:
            self._count("optimizer_failures")
        self._world = [None] * len(self._world)
        cpu = time.process_time() - cpu
        self.optimizations.append(
            {"nodes": self.graph.num_nodes, "edges": self.graph.num_edges, "cost_before": res.cost_before,
             "cost_after": res.cost_after, "iterations": len(res.rounds), "cpu_s": cpu, "wall_refinement": 1.0}
        )
        return res.summary(segs.seg_node.size, cpu), refined

    # ----------------------------------------------------------------- outputs

    def build_map(self, grid_params: GridParams) -> OccupancyGrid:
        """The occupancy grid of every kept scan at its optimised pose."""
        grid = OccupancyGrid(grid_params)
        poses = self.graph.poses
        if len(poses):
            margin = grid_params.max_range if grid_params.max_range is not None else 10.0
            lo = poses[:, :2].min(axis=0) - margin
            hi = poses[:, :2].max(axis=0) + margin
            grid.ensure_contains(lo[0], lo[1], hi[0], hi[1])
        for scan, pose in zip(self._scans, poses, strict=True):
            grid.integrate(scan, pose)
        return grid

    def release_caches(self) -> None:
        """Drop the correlation grids kept between matches (the run is over; they are rebuilt if it goes on)."""
        self._seq_cache.release()
        self._loop_cache.release()

    def summary(self) -> Mapping[str, Any]:
        return {
            "nodes": self.graph.num_nodes,
            "edges": self.graph.num_edges,
            "loop_closures": [c.as_dict() for c in self.loop_closures],
            "loop_attempts": list(self.loop_attempts),
            "optimizations": list(self.optimizations),
            "grid_builds": {"sequential": self._seq_cache.builds, "loop": self._loop_cache.builds},
            "grid_extensions": {"sequential": self._seq_cache.extensions, "loop": self._loop_cache.extensions},
            # Grids actually drawn (a build whose near chain the response bound skipped may never be).
            "grid_draws": {"sequential": self._seq_cache.draws, "loop": self._loop_cache.draws},
            "grid_points_smeared": {"sequential": self._seq_cache.smeared, "loop": self._loop_cache.smeared},
            "grid_kept": self._seq_cache.kept,
        }


@dataclass
class _Hypothesis:
    """A loop match below Karto's thresholds, waiting for a consistent second one."""

    node: int  # the new scan
    frm: int  # the old scan the edge would hang from
    z: NDArray[np.float64]  # the new scan's pose in frm's frame
    covariance: NDArray[np.float64]  # in frm's frame
    response_coarse: float
    response_fine: float
    chain_size: int
    ambiguous: bool = False  # its scan fits other places about as well (loop_check_peaks)


MAX_COV = 500.0
# A near chain that responded at least this share of the link threshold from the last node is matched
# before it is bounded (see _near_outcome): on fr079 about 93 % of those link or nearly link again.
_NEAR_HOT = 0.75
# How far below the coarse loop threshold a pose is still searched when the coarse match is refined.
_REFINE_GAIN = 0.2
# Uncertainty of an edge that holds the odometry step (scan matching off or failed).
ODOMETRY_SIGMA_XY = 0.1  # m
# a relocation's edge (a resumed session's first new node from the last old one): the localization's uncertainty,
# loose enough that the matches against the old scans near it decide
RELOCATION_SIGMA_XY, RELOCATION_SIGMA_THETA = 0.3, 0.1  # m, rad
ODOMETRY_SIGMA_THETA = 3.0 * _DEG  # rad


def _fill_gaps(points: NDArray[np.float64], sigmas: NDArray[np.float64], max_gap: float, step: float):
    """The points plus, between neighbours less than ``max_gap`` apart, points every ``step`` (and their sigmas).

    Each added point takes the smaller sigma of its pair. Neighbours are taken in scan order.
    """
    if max_gap <= 0 or points.shape[0] < 2:
        return points, sigmas
    d = np.diff(points, axis=0)
    gap = np.hypot(d[:, 0], d[:, 1])
    pair = np.flatnonzero((gap < max_gap) & (gap > step))
    if pair.size == 0:
        return points, sigmas
    n = np.floor(gap[pair] / step).astype(np.int64)  # segments; n - 1 inner points
    k = np.repeat(pair, n - 1)
    inner = np.arange(k.size) - np.repeat(np.cumsum(n - 1) - (n - 1), n - 1) + 1
    f = (inner / np.repeat(n, n - 1))[:, None]
    added = points[k] + f * d[k]
    sig = np.minimum(sigmas[k], sigmas[k + 1])
    return np.concatenate([points, added]), np.concatenate([sigmas, sig])


def _thin_keep(points: NDArray[np.float64], spacing: float) -> NDArray[np.int64]:
    """Indices of the first point (in scan order) of every ``spacing``-sided square."""
    cells = np.floor(points / spacing).astype(np.int64)
    _, first = np.unique(cells, axis=0, return_index=True)
    return np.sort(first)


def _thin(points: NDArray[np.float64], sigmas: NDArray[np.float64], spacing: float):
    """The first point (in scan order) of every ``spacing``-sided square, and its sigma."""
    keep = _thin_keep(points, spacing)
    return points[keep], sigmas[keep]


@njit(cache=True)
def _smear_sigmas(smear, sig, use, ranges, spacing, increment, lo, hi):
    """CorrelativeMatcher.sigmas_for(sig[use]) then, with ``spacing`` > 0, the beam-gap share of
    GraphFrontend._scan_points, per beam in ``use``: the same operations in the same order."""
    n = 0
    for k in range(use.shape[0]):
        if use[k]:
            n += 1
    out = np.empty(n)
    m = 0
    big = 1.7976931348623157e308  # np.nan_to_num's stand-in for an infinite sigma
    for k in range(use.shape[0]):
        if not use[k]:
            continue
        b = sig[k]
        if np.isnan(b):
            b = 0.0
        elif b == np.inf:
            b = big
        elif b == -np.inf:
            b = -big
        v = math.sqrt(smear * smear + b * b)
        v = min(max(v, lo), hi)
        if spacing > 0:
            gap = spacing * ranges[k] * increment
            v = min(math.sqrt(v * v + gap * gap), hi)
        out[m] = v
        m += 1
    return out


@njit(cache=True)
def _column_means(p):
    """``p.mean(axis=0)`` of a C-contiguous (n >= 1, 2) array as numpy reduces it: the first row, then each
    next row added in order, divided by n."""
    n = p.shape[0]
    sx = p[0, 0]
    sy = p[0, 1]
    for k in range(1, n):
        sx += p[k, 0]
        sy += p[k, 1]
    out = np.empty(2)
    out[0] = sx / n
    out[1] = sy / n
    return out


@njit(cache=True)
def _edge_between(ei, ej, i, j):
    """Whether some edge k joins i and j either way (``ei[k], ej[k]`` is ``i, j`` or ``j, i``)."""
    for k in range(ei.shape[0]):
        if (ei[k] == i and ej[k] == j) or (ei[k] == j and ej[k] == i):
            return True
    return False


@njit(cache=True)
def _equal_rows(a, b):
    """How many leading rows of ``a`` and ``b`` (both (n, 3)) are equal element by element (``==``: NaN never is)."""
    n = min(a.shape[0], b.shape[0])
    for i in range(n):
        if not (a[i, 0] == b[i, 0] and a[i, 1] == b[i, 1] and a[i, 2] == b[i, 2]):
            return i
    return n


@njit(cache=True)
def _transform_rows(poses, base, cos, sin, first, out):
    """Rows ``first:`` of ``out``: ``base[i]`` mapped by ``poses[i]`` (heading's cos and sin from ``first``),
    with se2.transform_points' products and sums in its order."""
    for i in range(first, poses.shape[0]):
        c = cos[i - first]
        s = sin[i - first]
        px = base[i, 0]
        py = base[i, 1]
        out[i, 0] = poses[i, 0] + c * px - s * py
        out[i, 1] = poses[i, 1] + s * px + c * py


# np.eye(3) * 1e-12, added to a covariance to keep it invertible; never written to.
_TINY_EYE = np.eye(3) * 1e-12
_TINY_EYE.flags.writeable = False


@njit(cache=True)
def _closest_row(ref, idx, tx, ty):
    """``np.argmin(((ref[idx] - (tx, ty)) ** 2).sum(axis=1))``: the first smallest (the first NaN if any)."""
    best = np.inf
    at = 0
    for k in range(idx.shape[0]):
        dx = ref[idx[k], 0] - tx
        dy = ref[idx[k], 1] - ty
        d = dx * dx + dy * dy
        if np.isnan(d):
            return k
        if d < best:
            best = d
            at = k
    return at


def _in_range(scan, threshold: float) -> tuple[NDArray[np.bool_], bool]:
    """(``scan.valid & (scan.ranges <= threshold)``, whether any beam is in it): one compiled pass for
    float64 ranges, numpy otherwise."""
    r = scan.ranges
    if type(r) is np.ndarray and r.dtype == np.float64 and r.ndim == 1:
        use, count = _valid_within(r, float(threshold))
        return use, count > 0
    with np.errstate(invalid="ignore"):
        use = scan.valid & (r <= threshold)
    return use, bool(use.any())


@njit(cache=True)
def _valid_within(ranges, threshold):
    """``~np.isnan(ranges) & (ranges <= threshold)`` and how many beams it holds."""
    out = np.empty(ranges.shape[0], np.bool_)
    count = 0
    for k in range(ranges.shape[0]):
        r = ranges[k]
        ok = not np.isnan(r) and r <= threshold
        out[k] = ok
        count += ok
    return out, count


@njit(cache=True)
def _transform_xy(x0, y0, c, s, pts):
    """se2.transform_points of (N, 2) points by the pose (x0, y0) with heading cos c, sin s (same arithmetic)."""
    out = np.empty((pts.shape[0], 2))
    for k in range(pts.shape[0]):
        px = pts[k, 0]
        py = pts[k, 1]
        out[k, 0] = x0 + c * px - s * py
        out[k, 1] = y0 + s * px + c * py
    return out


@njit(cache=True)
def _beam_points(x0, y0, c, s, ranges, cos, sin, use):
    """The points (mount pose x0, y0, cos c, sin s) of the beams in ``use``: Scan.points()' arithmetic."""
    n = 0
    for k in range(use.shape[0]):
        if use[k]:
            n += 1
    out = np.empty((n, 2))
    m = 0
    for k in range(use.shape[0]):
        if use[k]:
            px = ranges[k] * cos[k]
            py = ranges[k] * sin[k]
            out[m, 0] = x0 + c * px - s * py
            out[m, 1] = y0 + s * px + c * py
            m += 1
    return out


@njit(cache=True)
def _reachable(start, near, ei, ej, n):
    """Nodes reachable from ``start`` over edges whose both ends are ``near`` (breadth first)."""
    deg = np.zeros(n + 1, np.int64)
    for k in range(ei.shape[0]):
        if near[ei[k]] and near[ej[k]]:
            deg[ei[k] + 1] += 1
            deg[ej[k] + 1] += 1
    for i in range(n):
        deg[i + 1] += deg[i]
    adj = np.empty(deg[n], np.int64)
    fill = deg[:n].copy()
    for k in range(ei.shape[0]):
        if near[ei[k]] and near[ej[k]]:
            adj[fill[ei[k]]] = ej[k]
            fill[ei[k]] += 1
            adj[fill[ej[k]]] = ei[k]
            fill[ej[k]] += 1
    out = np.zeros(n, np.bool_)
    queue = np.empty(n, np.int64)
    out[start] = True
    queue[0] = start
    head, tail = 0, 1
    while head < tail:
        v = queue[head]
        head += 1
        for k in range(deg[v], deg[v + 1]):
            w = adj[k]
            if not out[w]:
                out[w] = True
                queue[tail] = w
                tail += 1
    return out


def _odometry_covariance() -> NDArray[np.float64]:
    """A fresh odometry-step covariance (what a step the scan cannot place is given)."""
    return np.diag([ODOMETRY_SIGMA_XY**2, ODOMETRY_SIGMA_XY**2, ODOMETRY_SIGMA_THETA**2])


def _fuse(pose: NDArray[np.float64], cov: NDArray[np.float64], predicted: NDArray[np.float64],
          odo: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """A match fused with the odometry prediction by information weighting: (pose, covariance)."""
    return _weighted_mean([pose, predicted], [cov, odo]), np.linalg.inv(np.linalg.inv(cov) + np.linalg.inv(odo))


def _weighted_mean(means: list[NDArray[np.float64]], covs: list[NDArray[np.float64]]) -> NDArray[np.float64]:
    """Information-weighted mean of poses (angles unwrapped about the first)."""
    ref = means[0]
    info_sum = np.zeros((3, 3))
    acc = np.zeros(3)
    for m, c in zip(means, covs, strict=True):
        info = np.linalg.inv(c + _TINY_EYE)
        v = np.array([m[0], m[1], ref[2] + se2.wrap_scalar(float(m[2] - ref[2]))])
        info_sum += info
        acc += info @ v
    out = np.linalg.solve(info_sum, acc)
    out[2] = se2.wrap_scalar(float(out[2]))
    return out
