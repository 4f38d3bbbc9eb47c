"""The graph front end's sequential step: each frame matched against the running scans.

The prediction from the last node (or the last matched frame) plus the odometry, Karto's gate
(``HasMovedEnough``), the frames placed between nodes, the sequential match itself (seeded,
recovered over a wide window when stuck or weak, fused with the odometry when its heading is
ambiguous), and the edges from the running scans to a new node.

:class:`SequentialMatching` is a part of :class:`~slam2d.graph.frontend.GraphFrontend`, which
holds the state it reads and writes.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numpy.typing import NDArray

from slam2d.core import se2
from slam2d.matching.correlative import CorrelativeMatcher
from slam2d.graph.nodes import _TINY_EYE
from slam2d.graph.params import _DEG

__all__ = ["SequentialMatching"]

# A variance that stands for "unknown": the first node's, a wrong odometry heading's (see _recover_sequential).
MAX_COV = 500.0
# Uncertainty of an edge that holds the odometry step (scan matching off or failed).
ODOMETRY_SIGMA_XY = 0.1  # m
# a relocation's edge (a resumed session's first new node from the last old one): the localization's uncertainty,
# loose enough that the matches against the old scans near it decide
RELOCATION_SIGMA_XY, RELOCATION_SIGMA_THETA = 0.3, 0.1  # m, rad
# A map anchor (a resumed session's new node where localization in the saved map places it, an edge from the
# gauge node; only scans that fit the map well, localization.map_anchor): its uncertainty, and how far from the
# node's own matched estimate one is still believed. A wrong place, or a map stretched along a corridor, would
# otherwise pull the graph along (a 1 m gate failed tests/test_session.py's resumed corridor drive). 0.05 m
# instead of 0.2 m: intel 0.094 m (0.087), fr079 0.117 m (0.112); the simulated rows alike
# (benchmarks/localization.py, continue rows).
MAP_ANCHOR_SIGMA_XY, MAP_ANCHOR_SIGMA_THETA, MAP_ANCHOR_GATE = 0.2, 0.05, 0.3  # m, rad, m
ODOMETRY_SIGMA_THETA = 3.0 * _DEG  # rad


class SequentialMatching:
    """Prediction, gating and the sequential match of every frame (a part of GraphFrontend)."""

    # ----------------------------------------------------------------- prediction and gating

    def _predict(self, odom: NDArray[np.float64], previous_odom: NDArray[np.float64] | None):
        """The frame's prediction: (last node (-1: none), odometry since it, predicted pose, the last
        frame's pose plus the odometry since it (or None), where the seeded search looks first (or None))."""
        p = self.params
        if self.graph.num_nodes and self._base is not None:
            # After a revisit frame: from the old node it hung from, plus the odometry since that frame.
            last, at, base_odom = self._base
            offset = se2.compose(at, se2.relative(base_odom, odom))
            predicted = se2.compose(self.graph.poses[last], offset)
        elif self.graph.num_nodes:
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
        return last, offset, predicted, chained, seed

    def _moved_enough(self, odom: NDArray[np.float64], t: float) -> bool:
        if not self._odom:
            return True
        p = self.params
        last, t_last = (self._odom[-1], self._times[-1]) if self._gate is None else self._gate
        if t - t_last >= p.minimum_time_interval:
            return True
        if math.hypot(odom[0] - last[0], odom[1] - last[1]) >= p.minimum_travel_distance:
            return True
        return abs(se2.wrap_scalar(float(odom[2] - last[2]))) >= p.minimum_travel_heading  # wrap_angle's arithmetic on a float

    def _matches_between_nodes(self, last: int) -> bool:
        p = self.params
        return last >= 0 and p.use_scan_matching and p.match_between_nodes

    def _place_between_nodes(self, scan, use, last: int, predicted, seed, last_response: float) -> None:
        """Place a frame that adds no node: its pose hangs from node ``last`` (:attr:`anchor`, :attr:`offset`)."""
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
        self._after_between = True

    # ----------------------------------------------------------------- the sequential match

    def _node_estimate(self, points, predicted, last: int, relocating: bool, values: dict[str, float],
                       last_response: float, seed):
        """A new node's pose and covariance before the near chains: (pose, covariance); logs to ``values``."""
        p = self.params
        pose = predicted
        if relocating:
            cov = np.diag([RELOCATION_SIGMA_XY**2, RELOCATION_SIGMA_XY**2, RELOCATION_SIGMA_THETA**2])
        elif last >= 0 and p.use_scan_matching:
            pose, cov, result = self._sequential_estimate(points, predicted, values, last_response, seed=seed)
            values["response"] = result.response
            # np.hypot of the two differences, taken in Python floats (the same subtractions).
            values["correction_m"] = float(np.hypot(float(result.pose[0]) - float(predicted[0]),
                                                    float(result.pose[1]) - float(predicted[1])))
        elif last >= 0:
            cov = _odometry_covariance()
        else:
            cov = np.diag([MAX_COV, MAX_COV, MAX_COV])
        return pose, cov

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
        the odometry wrong).
        With ``seed`` the match searches near it first (:meth:`_seeded_match`).
        """
        p = self.params
        matcher = matcher or self.sequential
        if seed is not None and p.seeded_search_window > 0:
            result = self._seeded_match(matcher, points, predicted, seed, last_response)
        else:
            result = self.seq_matcher.match(self._running, points, predicted, window=matcher, penalize=True,
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
        half = int(round(0.5 * p.seeded_search_window / (2.0 * matcher.resolution)))
        steps = int(round(p.seeded_search_angle / matcher.coarse_angle_resolution))
        near = self.seq_matcher.match_near(self._running, points, predicted, seed, window=matcher, half_steps=half,
                                           angle_steps=steps)
        if (near is not None and near.raw_response >= last_response - p.seeded_search_drop
                and not (p.odometry_fusion and near.heading_variance_coarse > ODOMETRY_SIGMA_THETA**2)):
            self._count("seeded_matches")
            return near
        self._count("seeded_matches_searched_whole")
        return self.seq_matcher.match(self._running, points, predicted, window=matcher, penalize=True, refine=True)

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
        coarse = self.loop_matcher.match_uncached(self._running, points, predicted, window=wide, penalize=False,
                                                  refine=True)
        alt = self.seq_matcher.match(self._running, points, coarse.pose, penalize=False, refine=True)
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

    # ----------------------------------------------------------------- the running scans

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
        if local is None:
            # An old pass's scan (revisit frames): no sequential edges lead from it to ``last``; Karto's edge.
            self._add_edge(closest, node, pose, cov)
            return
        self._count("running_links_chained")
        self.graph.add_edge(closest, node, z, self._match_information(local))

    def _chain_covariance(self, i: int, last: int, step: NDArray[np.float64], step_cov: NDArray[np.float64]):
        """Covariance, in node i's frame, of node i's sequential edges up to ``last`` followed by ``step``.

        First-order propagation of ``a + b`` (the relative pose so far composed with the next
        step): Ja covers how the heading error so far swings the step's translation, Jb rotates
        the step's own covariance. The chain is at most the running buffer long.
        """
        # The sequential edges back from ``last`` (each node's from the one before it, but after revisit
        # frames from the old node the robot hung from): None when they pass i by or take more steps than
        # the running buffer holds scans.
        path = [last]
        pred = self._pred
        k = last
        while k > i and len(path) <= self.params.scan_buffer_size:
            # (a node's predecessor is always an older node; one put in the graph directly, not through
            # _append_node, has none recorded and follows the one before it)
            k = pred[k] if k < len(pred) else k - 1
            path.append(k)
        if k != i:
            return None
        path.reverse()
        heading = 0.0  # of the relative pose so far (se2.compose's heading: its x, y are not needed)
        acc = np.zeros((3, 3))
        seq = self._seq_steps
        for m, k in enumerate(path):  # a few dozen 3x3 products per linked scan, not a per-beam loop
            z, c = seq[path[m + 1] - 1] if k != last else (step, step_cov)
            z0, z1, z2 = float(z[0]), float(z[1]), float(z[2])
            ct, st = math.cos(heading), math.sin(heading)
            ja = np.array([[1.0, 0.0, -st * z0 - ct * z1], [0.0, 1.0, ct * z0 - st * z1], [0.0, 0.0, 1.0]])
            jb = np.array([[ct, -st, 0.0], [st, ct, 0.0], [0.0, 0.0, 1.0]])
            acc = ja @ acc @ ja.T + jb @ c @ jb.T
            heading = se2.wrap_scalar(heading + z2)
        return 0.5 * (acc + acc.T) + _TINY_EYE

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
