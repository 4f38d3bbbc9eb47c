"""The graph front end's parameters (:class:`GraphSlamParams`): Karto's mapper settings and the additions."""

from __future__ import annotations

import math
from dataclasses import dataclass

from slam2d.grids.occupancy import GridParams
from slam2d.matching.odometry_gaps import OdometryGapParams
from slam2d.params import param
from slam2d.graph.wall_end_landmarks import WallEndParams
from slam2d.graph.dense_refinement import DenseRefinementParams
from slam2d.graph.wall_refinement import WallRefinementParams

__all__ = ["GraphSlamParams"]

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
    revisit_without_nodes: bool = param(
        True,
        help="a kept scan that retraces older passes adds no node (not in Karto, which adds one for every kept scan, "
        "so driving an area again and again grows the graph, the stored scans and the near chains matched per scan "
        "with the scans, not with the area): when it links to two near chains (or the last kept scan was such a "
        "revisit frame), lies less than minimum_travel_distance and minimum_travel_heading from one of their nodes "
        "and leaves no loop candidate to try, its pose (the matches' mean) hangs from that old node, which joins "
        "the running scans, and the next scans are predicted from it; entering the covered place its matches become "
        "edges from the last node. Intel driven 8 times (benchmarks/memory.py): peak 418 MB instead of 507 MB "
        "(346 MB once), 133 s of CPU instead of 463 s, when added (389 MB with the odometry guard's reversing "
        "check since, BENCHMARKS.md); the real logs' and simulated worlds' ATE as before (docs)",
        advanced=True, group="revisits",
    )
    scan_buffer_size: int = param(70, low=1, help="running scans the sequential matcher matches against [ScanBufferSize]")
    scan_buffer_maximum_scan_distance: float = param(
        20.0, unit="m", low=0.0,
        help="drop running scans farther than this from the newest one [ScanBufferMaximumScanDistance]",
    )
    link_match_minimum_response_fine: float = param(
        0.8, low=0.0, high=1.0, help="least response that links a near chain [LinkMatchMinimumResponseFine]"
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
        "graph was optimised since (0: bounded at every kept scan; a speed setting, see docs/methods/what-was-tried.md#karto-speed)",
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
