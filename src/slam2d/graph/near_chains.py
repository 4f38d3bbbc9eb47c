"""The graph front end's near chains (Karto's ``LinkNearChains``): older passes near a new node linked to it.

A near chain is a run of older scans within ``link_scan_maximum_distance`` of the new node that
the graph already connects to it; each is matched (unpenalised) and linked when it responds
above ``link_match_minimum_response_fine``. The matcher's response bound tells most chains that
cannot link apart before any 1 cm grid is drawn.

:class:`NearChainLinking` is a part of :class:`~slam2d.graph.frontend.GraphFrontend`, which
holds the state it reads and writes.
"""

from __future__ import annotations

from slam2d.matching.scan_matcher import ChainGrid
from slam2d.graph.kernels import _runs_counted

__all__ = ["NearChainLinking"]

# A near chain that responded at least this share of the link threshold from the last node is matched
# before it is bounded (see _near_outcome): on fr079 about 93 % of those link or nearly link again.
_NEAR_HOT = 0.75


class NearChainLinking:
    """Matching and linking the near chains of a new node (a part of GraphFrontend)."""

    def _link_near_chains(self, node: int, points, pose, means: list, covs: list) -> int:
        """Karto's LinkNearChains: match older passes already connected in the graph; link the good ones."""
        p = self.params
        ref_xy = self.reference_positions()
        near, linked = self._near_and_linked(node, ref_xy, p.link_scan_maximum_distance)
        linked[node] = False
        hot, self._near_hot = self._near_hot, []
        self._near_linked = []  # (start, end, the scan linked, the match's pose and covariance) per chain linked
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
            chain = range(a, b)  # a list only where it links (reserve reads a range's ends directly)
            # Reserved whatever happens next, so later matches read the grids they would have
            # (see ScanMatcher.reserve).
            grid = self.seq_matcher.reserve(chain, lo, hi, max_extra=p.near_chain_grid_extra)
            # Hot: like a chain that responded well from the last node, its grid already drawn (a first
            # draw costs more than the bound it would spare).
            warm = grid.drawn and any(ha < b and a < hb for ha, hb in hot)
            if not warm and self._tried_nearby(a, b, pose, p.near_bound_retry_distance, self._near_between):
                self._count("near_skipped_between_retry")
                continue
            outcome = self._near_outcome(grid, points, pose, warm)
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
                means.append(result.pose)
                covs.append(cov)
                closest = self._link_chain_to_scan(list(chain), node, result.pose, cov)
                self._near_linked.append((a, b, closest, result.pose, cov))
                count += 1
        return count

    def _near_outcome(self, grid: ChainGrid, points, pose, hot: bool):
        """A near chain's match on its reserved ``grid`` (a MatchResult), "failed" (record it), or None (not
        linked, not failed).

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
            bound = grid.bound(points, pose, window=self.near, stop=link, mark=fail)
            if bound < fail:
                self._count("near_skipped_bound")
                return "failed"
            if bound < link:
                # It cannot link from here either, but it may respond well enough not to count as
                # failed: it is tried again from the next pose, as a match that nearly linked is.
                self._count("near_skipped_bound_link")
                return None
        smeared = self.seq_matcher.points_smeared
        result = grid.match(points, pose, window=self.near, penalize=False, refine=True)
        self._count("near_points_smeared", self.seq_matcher.points_smeared - smeared)
        if result.response >= fail:
            return result
        if bound is None:
            # Bound-first would not have matched a chain bounded in [fail, link), nor failed it.
            self._count("near_matched_before_bound")
            bound = grid.bound(points, pose, window=self.near, stop=link, mark=fail)
            if fail <= bound < link:
                self._count("near_skipped_bound_link")
                return None
            if bound < fail:
                self._count("near_skipped_bound")
        return "failed"
