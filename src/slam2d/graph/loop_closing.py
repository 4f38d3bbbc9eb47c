"""The graph front end's loop closing (Karto's ``TryCloseLoop``): a new node matched against older passes.

Candidate chains are runs of older scans near the new node that the graph does not connect to it
through nearby scans. Each is matched over the wide loop window, coarse then fine, and accepted
on Karto's thresholds; with ``loop_check_peaks`` every distinct peak of the coarse surface is
refined (:meth:`LoopClosing._best_place`), and a weak or ambiguous match waits as a hypothesis
for a consistent one from another scan (:meth:`LoopClosing._confirming_hypothesis`). Every
accepted closure runs the back end over the whole graph.

:class:`LoopClosing` is a part of :class:`~slam2d.graph.frontend.GraphFrontend`, which holds the
state it reads and writes.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slam2d.core import se2
from slam2d.matching.correlative import COVARIANCE_BAND
from slam2d.graph.kernels import _runs

__all__ = ["LoopClosure", "LoopClosing"]

# How far below the coarse loop threshold a pose is still searched when the coarse match is refined.
_REFINE_GAIN = 0.2


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


class LoopClosing:
    """Loop closure search from each new node, and its hypotheses (a part of GraphFrontend)."""

    def _try_close_loop(self, node: int, points: NDArray[np.float64]) -> int:
        """Karto's TryCloseLoop from the new ``node`` (its ``points`` in the base frame): the closures accepted."""
        p = self.params
        closed = 0
        start = 0
        candidate = None
        while True:
            if candidate is None:  # the graph changes only when a closure is accepted
                candidate = self._loop_candidate_nodes(node)
            chains = self._loop_chains(candidate, start)
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
            coarse = self.loop_matcher.match(chain, points, pose, window=matcher, penalize=False,
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
            fine = self.seq_matcher.match(chain, points, coarse.pose, penalize=False, refine=True)
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
        band = COVARIANCE_BAND
        places = [(coarse.pose, coarse.response)]
        if floor is None:
            floor = coarse.response - band - _REFINE_GAIN
        found, surface_cov = self.loop_matcher.places(chain, points, pose, window=matcher, floor=floor)
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

    def _loop_candidate_nodes(self, node: int) -> NDArray[np.bool_]:
        """Per node, whether it lies within the loop search distance of ``node`` but the graph does not reach
        ``node`` from it through scans that near (Karto's candidates for a loop closure)."""
        near, linked = self._near_and_linked(node, self.reference_positions(), self.params.loop_search_maximum_distance)
        return near & ~linked

    def _loop_chains(self, candidate: NDArray[np.bool_], start: int = 0) -> list[tuple[int, int]]:
        """The runs of ``candidate`` nodes long enough to be matched as a chain, from node ``start`` on."""
        p = self.params
        return [(a, b) for a, b in _runs(candidate) if b - a >= p.loop_match_minimum_chain_size and a >= start]

    def _loop_candidates(self, node: int, pose: NDArray[np.float64]) -> bool:
        """Whether the loop closure search from ``node`` at ``pose`` would match a chain (one not tried from
        nearby)."""
        p = self.params
        if not p.do_loop_closing:
            return False
        return any(not self._tried_nearby(a, b, pose, p.loop_retry_distance)
                   for a, b in self._loop_chains(self._loop_candidate_nodes(node)))

    def _tried_nearby(self, a: int, b: int, pose: NDArray[np.float64], distance: float, tried=None) -> bool:
        """Whether a chain overlapping [a, b) was tried from within ``distance`` of ``pose`` since the last optimisation."""
        if distance <= 0:
            return False
        px, py = float(pose[0]), float(pose[1])  # read once (the same differences as pose[0] - x)
        for ta, tb, x, y in reversed(self._tried if tried is None else tried):
            if ta < b and a < tb and math.hypot(px - x, py - y) < distance:
                return True
        return False
