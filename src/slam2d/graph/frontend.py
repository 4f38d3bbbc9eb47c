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
   With ``revisit_without_nodes`` a scan that retraces older passes adds no node (a *revisit
   frame*, :meth:`GraphFrontend._covering_node`): once it links to two near chains (or the robot is
   retracing already) and lies within the travel gate of one of their nodes, with no loop candidate
   left to try, the node is taken back; the frame hangs from that old node, which joins the running
   scans, and the next scans are predicted from it. Entering the covered place, the frame's sequential
   and near-chain matches become edges from the last node to the chains' scans. Driving an area again
   and again then grows the graph with the area, not with the scans.
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

This module is the front end's frame loop and its graph; the steps live in their own modules, as
parts of :class:`GraphFrontend`: :mod:`~slam2d.graph.sequential` (1-3, and the edges from the
running scans), :mod:`~slam2d.graph.near_chains` (the near chains of 4),
:mod:`~slam2d.graph.loop_closing` (5), :mod:`~slam2d.graph.nodes` (the nodes' points, positions
and edges) and :mod:`~slam2d.graph.kernels` (their compiled helpers). The parameters are
:class:`~slam2d.graph.params.GraphSlamParams`. Every match against the nodes' scans goes through a
:class:`~slam2d.matching.scan_matcher.ScanMatcher`, which keeps the correlation grids.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slam2d.backends import PoseGraph, get_backend
from slam2d.core import se2
from slam2d.core.arrays import grown
from slam2d.core.frames import Frame
from slam2d.grids.occupancy import GridParams, OccupancyGrid
from slam2d.matching.correlative import CorrelativeMatcher
from slam2d.matching.scan_matcher import ScanMatcher
from slam2d.sensors.beam_model import beam_sigmas
from slam2d.graph.wall_end_landmarks import WallEndLandmarks
from slam2d.graph.wall_refinement import refine_path
from slam2d.graph.kernels import _column_means, _in_range
from slam2d.graph.loop_closing import LoopClosing, LoopClosure, _Hypothesis
from slam2d.graph.near_chains import NearChainLinking
from slam2d.graph.nodes import NodeStore
from slam2d.graph.params import GraphSlamParams
from slam2d.graph.sequential import (MAP_ANCHOR_GATE, MAP_ANCHOR_SIGMA_THETA, MAP_ANCHOR_SIGMA_XY, SequentialMatching,
                                     _weighted_mean)

__all__ = ["GraphFrontend"]


class GraphFrontend(NodeStore, SequentialMatching, NearChainLinking, LoopClosing):
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
        # The matches against the nodes' scans, each with the grids it keeps: the 1 cm grids serve
        # the sequential matches, the near chains and the loop closures' fine step; the loop's coarse
        # window has grids of its own.
        self.seq_matcher = ScanMatcher(self.sequential, self._node_reference, max_entries=p.grid_cache_entries)
        self.loop_matcher = ScanMatcher(self.loop, self._node_reference)
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
        # Per node: the node its sequential edge comes from (-1: none); the previous node but after a revisit.
        self._pred: list[int] = []
        # Where the robot hangs from after a revisit frame (revisit_without_nodes): (old node, the frame's pose
        # relative to it, the frame's odometry); None: from the last node, at its odometry.
        self._base: tuple[int, NDArray[np.float64], NDArray[np.float64]] | None = None
        # The odometry and time the travel gate measures from when that is not the last node's: a revisit frame's.
        self._gate: tuple[NDArray[np.float64], float] | None = None
        # The near chains the last kept scan linked to: (start, end, the scan linked, the match's pose, covariance).
        self._near_linked: list[tuple] = []
        # Edges revisit frames added (see _link_through): (from, to) -> edge index.
        self._revisit_edges: dict[tuple[int, int], int] = {}
        # The first node added since the last revisit frame (the running scans before it are an old pass's).
        self._streak_start = 0
        self._put_at: NDArray[np.float64] | None = None  # a relocation waiting for the next frame
        self._map_anchor: NDArray[np.float64] | None = None  # the next frame's pose in the saved map (anchor_to_map)
        self._directions: dict = {}  # beam layout -> cos, sin of its beam angles
        self.loop_closures: list[LoopClosure] = []
        self.loop_attempts: list[dict[str, Any]] = []
        self.optimizations: list[dict[str, float]] = []
        # Loop attempts since the last optimisation: (chain start, chain end, robot x, y).
        self._tried: list[tuple[int, int, float, float]] = []
        # Weak loop matches waiting for a consistent partner: see _confirm_hypothesis.
        self._hypotheses: list[_Hypothesis] = []
        # Near chains that failed to link since the last optimisation, the same way.
        self._near_failed: list[tuple[int, int, float, float]] = []
        self._near_between: list[tuple[int, int, float, float]] = []
        # Near chains (start, end) that responded at least _NEAR_HOT of the link threshold from the last node.
        self._near_hot: list[tuple[int, int]] = []
        self._last_odom: NDArray[np.float64] | None = None
        self._ref_cache: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None
        self._frame_pose: NDArray[np.float64] | None = None  # the last frame's pose (world)
        self._after_between = False  # whether the last frame was matched between nodes
        self._frame_degenerate = False  # whether its match was flat along a corridor
        self._frame_response = math.nan  # the last matched scan's unpenalised response
        self._steps: list[NDArray[np.float64]] = []  # per node after the first: see between_node_steps
        # Per node after the first: its sequential edge's measurement and covariance (previous node's frame).
        self._seq_steps: list[tuple[NDArray[np.float64], NDArray[np.float64]]] = []
        self.anchor = -1  # node the last frame's pose hangs from (-1: none yet)
        self.revisit_anchor = False  # whether that is an old node a revisit frame hung from (see revisit_without_nodes)
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

    def _append_node(self, scan, points, sigmas, pose, odom, timestamp: float) -> int:
        """Add a node at ``pose`` with the scan's points, reference, odometry and time; returns its index."""
        node = self.graph.add_node(pose)
        self._pred.append(node - 1)
        self._points.append(points)
        self._sigmas.append(sigmas)
        self._ref.append((points, sigmas))
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
        node = self._append_node(scan, points, sigmas, pose, odom, timestamp)
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

    def anchor_to_map(self, pose: NDArray[np.float64]) -> None:
        """The next frame's pose in the saved map, as localization in it finds it: if the frame makes a node
        less than ``MAP_ANCHOR_GATE`` from where the matches put it, the node is tied to it (an edge from the
        gauge node) and its estimate averaged with it. Without these, a resumed run's new nodes slid along
        featureless corridors, beyond the near chains' window (corridor-loop: 0.156 m, with them 0.03 m)."""
        self._map_anchor = np.asarray(pose, dtype=np.float64).reshape(3)

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
        anchor, self._map_anchor = self._map_anchor, None
        relocating = self._put_at is not None and self.graph.num_nodes > 0
        if relocating:
            # A resumed session's new recording: the next node is predicted at the given pose (the last
            # node's odometry re-expressed so that the odometry since it is the step to there), matched
            # against the old scans near it (near chains, loop closure), not against the last ones.
            last = self.graph.num_nodes - 1
            self._odom[last] = se2.compose(odom, se2.inverse(se2.relative(self.graph.poses[last], self._put_at)))
            previous_odom, self._frame_pose, self._running = None, None, []
            self._base, self._gate = None, None
            self._put_at = None
            self._count("relocations")
        # The last frame's response is a reference only for a scan taken close to it (less than
        # the gate's travel by odometry): on logs thinned to a metre between scans it varies too much.
        last_response, self._frame_response = self._frame_response, math.nan
        if previous_odom is None or math.hypot(float(odom[0]) - float(previous_odom[0]),
                                               float(odom[1]) - float(previous_odom[1])) >= p.minimum_travel_distance:
            last_response = math.nan
        last, offset, predicted, chained, seed = self._predict(odom, previous_odom)
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
        if not moved:
            self._place_between_nodes(scan, use, last, predicted, seed, last_response)
            return None
        sig = beam_sigmas(scan, self.sensor_model, 0.0)
        points, sigmas = self._scan_points(scan, sig, use)
        values: dict[str, float] = {}
        pose, cov = self._node_estimate(points, predicted, last, relocating, values, last_response,
                                        seed if after_between else None)
        edges = self.graph.num_edges
        node = self._append_node(scan, points, sigmas, pose, odom, frame.timestamp)
        self._pred[node] = last
        if last >= 0:
            means = [pose]
            covs = [cov]
            self._add_edge(last, node, pose, cov)
            self._seq_steps.append((self.graph.measurements[-1].copy(), self._local_covariance(last, cov)))
            if self._running:  # (none right after a relocation)
                self._link_running_scan(last, node, pose, cov)
            linked = self._link_near_chains(node, points, pose, means, covs)
            values["near_links"] = float(linked)
            if anchor is not None:
                self._anchor_node(node, anchor, pose, means, covs)
            if len(means) > 1:
                pose = _weighted_mean(means, covs)
                self.graph.poses[node] = pose
                self._world[node] = None
            covering = -1 if relocating or not p.revisit_without_nodes else self._covering_node(pose)
            if covering >= 0 and not self._loop_candidates(node, pose):
                # A revisit frame: no node. Entering the covered place from a node, the scan's matches still
                # tie that node to the old passes (a loop constraint); once retracing them they add nothing.
                self._drop_last_node(edges)
                if self._base is None:
                    for _, _, closest, near_pose, near_cov in self._near_linked:
                        self._link_through(last, closest, means[0], covs[0], near_pose, near_cov)
                self._hang_from(covering, pose, odom, frame.timestamp, cov)
                return None
            # The step from the last node that the frames in between were placed along: their
            # matched poses end at this node as placed now, their odometry at the odometry step.
            if last != node - 1:
                # After revisit frames: the frames hung from the previous node were not placed towards this one.
                self._steps.append(np.zeros(3))
            elif self._matches_between_nodes(last):
                self._steps.append(se2.relative(self.graph.poses[last], self.graph.poses[node]))
            else:
                self._steps.append(se2.relative(self._odom[last], odom))
        self._base, self._gate, self.revisit_anchor = None, None, False
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
        return values

    def _anchor_node(self, node: int, at: NDArray[np.float64], pose: NDArray[np.float64], means: list,
                     covs: list) -> None:
        """Tie ``node`` (matched to ``pose``) to ``at``, its pose in the saved map (:meth:`anchor_to_map`)."""
        if math.hypot(float(at[0] - pose[0]), float(at[1] - pose[1])) > MAP_ANCHOR_GATE:
            self._count("map_anchors_refused")
            return
        cov = np.diag([MAP_ANCHOR_SIGMA_XY**2, MAP_ANCHOR_SIGMA_XY**2, MAP_ANCHOR_SIGMA_THETA**2])
        means.append(at)
        covs.append(cov)
        self._add_edge(int(self.graph.fixed), node, at, cov)
        self._count("map_anchors")

    def _covering_node(self, pose: NDArray[np.float64]) -> int:
        """An old node the new scan at ``pose`` adds nothing to (-1: none): see ``revisit_without_nodes``.

        The place must be covered: the scan linked to at least two near chains (two older passes
        connected here), or the robot is retracing an old pass already (the last kept scan was a
        revisit frame). The node must lie less than the travel gate's distance and heading from
        ``pose`` (the robot would not have kept the scan had it stayed there) in a near chain the
        scan has just linked to, or, when retracing, among the old pass's running scans if the
        sequential match responded at least the near-chain link threshold; the closest such node.
        """
        p = self.params
        best, best_d = -1, math.inf
        poses = self.graph.poses
        x, y, t = float(pose[0]), float(pose[1]), float(pose[2])
        groups = [(a, b, None) for a, b, *_ in self._near_linked]
        if len(groups) < 2 and self._base is None:
            return -1
        if self._frame_response >= p.link_match_minimum_response_fine:
            old = [i for i in self._running if i < self._streak_start]
            if old:
                groups.append((0, 0, np.asarray(old, dtype=np.int64)))
        for a, b, idx in groups:
            chain = poses[a:b] if idx is None else poses[idx]
            d = np.hypot(chain[:, 0] - x, chain[:, 1] - y)
            turn = np.abs(se2.wrap_angle(chain[:, 2] - t))
            ok = np.flatnonzero((d < p.minimum_travel_distance) & (turn < p.minimum_travel_heading))
            if ok.size:
                k = int(ok[np.argmin(d[ok])])
                if d[k] < best_d:
                    best, best_d = (a + k if idx is None else int(idx[k])), float(d[k])
        return best

    def _link_through(self, last: int, to: int, seq_pose, seq_cov, near_pose, near_cov) -> None:
        """The edge last -> ``to`` a revisit frame's two matches make (the sequential one from ``last`` at
        ``seq_pose``, the near chain's from ``to`` at ``near_pose``), the frame eliminated; merged into the
        one an earlier revisit frame made between the two (information added).

        The covariance is the two matches' (world frame) summed, with the lever arm by which the
        frame's heading error moves ``to`` (under the travel gate's distance), rotated into ``last``'s frame.
        """
        if to == last:
            return
        at = se2.compose(seq_pose, se2.relative(near_pose, self.graph.poses[to]))  # ``to`` as the matches place it
        lx, ly = float(at[0] - seq_pose[0]), float(at[1] - seq_pose[1])
        jac = np.array([[1.0, 0.0, -ly], [0.0, 1.0, lx], [0.0, 0.0, 1.0]])  # the frame's heading swings ``to``
        cov = jac @ (seq_cov + near_cov) @ jac.T
        z = se2.relative(self.graph.poses[last], at)
        info = self._match_information(self._local_covariance(last, cov))
        k = self._revisit_edges.get((last, to))
        if k is None:
            self._revisit_edges[(last, to)] = self.graph.num_edges
            self.graph.add_edge(last, to, z, info)
            return
        old_z, old_info = self.graph.measurements[k].copy(), self.graph.information[k].copy()
        merged = _weighted_mean([old_z, z], [np.linalg.inv(old_info), np.linalg.inv(info)])
        self.graph.measurements[k] = merged
        self.graph.information[k] = old_info + info

    def _drop_last_node(self, edges: int) -> None:
        """Forget the node just added (and its edges, from edge ``edges`` on): nothing else has seen it yet."""
        node = self.graph.num_nodes - 1
        self.graph.truncate(node, edges)
        for per_node in (self._points, self._sigmas, self._ref, self._world, self._odom, self._times, self._scans,
                         self._pred):
            per_node.pop()
        self._bary_base = self._bary_store[:node]
        if node > 0:
            self._seq_steps.pop()

    def _hang_from(self, node: int, pose: NDArray[np.float64], odom: NDArray[np.float64], timestamp: float,
                   cov: NDArray[np.float64]) -> None:
        """A revisit frame at ``pose``: it hangs from the old ``node`` covering it, and so do the next frames' predictions."""
        self._count("revisit_frames")
        self._streak_start = self.graph.num_nodes
        offset = se2.relative(self.graph.poses[node], pose)
        self._base = (node, offset, odom)
        self._gate = (odom, timestamp)
        # The next scans are matched against the old pass the robot retraces, not the last nodes it left.
        if node in self._running:
            self._running.remove(node)
        self._running.append(node)
        self._trim_running()
        self.anchor, self.offset, self.revisit_anchor = node, offset, True
        self._frame_pose = np.array(pose, dtype=np.float64)
        self._frame_degenerate = self._degenerate(cov)
        self._after_between = True

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
        self.seq_matcher.invalidate(self._moved_nodes(before, self.graph.poses))
        self.loop_matcher.invalidate()
        self._tried.clear()
        self._near_failed.clear()
        self._near_between.clear()
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
            scans, odom, poses, node_frame, breaks = self._scans, self.odometry_at_nodes(), self.graph.poses, None, None
        else:
            scans, odom, poses, node_frame, breaks = frames
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
        res, segs = refine_path(scans, poses, p, graph=graph, odometry=odom, odometry_breaks=breaks,
                                fixed=int(where(self.graph.fixed)),
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
        self.seq_matcher.release()
        self.loop_matcher.release()

    def summary(self) -> Mapping[str, Any]:
        seq, loop = self.seq_matcher.stats(), self.loop_matcher.stats()
        return {
            "nodes": self.graph.num_nodes,
            "edges": self.graph.num_edges,
            "loop_closures": [c.as_dict() for c in self.loop_closures],
            "loop_attempts": list(self.loop_attempts),
            "optimizations": list(self.optimizations),
            "grid_builds": {"sequential": seq["builds"], "loop": loop["builds"]},
            "grid_extensions": {"sequential": seq["extensions"], "loop": loop["extensions"]},
            # Grids actually drawn (a build whose near chain the response bound skipped may never be).
            "grid_draws": {"sequential": seq["draws"], "loop": loop["draws"]},
            "grid_points_smeared": {"sequential": seq["smeared"], "loop": loop["smeared"]},
            "grid_kept": seq["kept"],
        }
