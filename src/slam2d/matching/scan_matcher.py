"""A scan matcher with its grids inside (:class:`ScanMatcher`): match a scan against these nodes' scans, in this window.

The graph front end matches every scan against sets of earlier scans (the running scans, near
chains, loop chains). Drawing their correlation grids costs as much as the search, so the grids
are kept between matches (:class:`~slam2d.matching.grid_cache.GridCache`); that cache is this
class's business alone, so that the caching can change without touching its callers.
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np
from numpy.typing import NDArray

from slam2d.matching.correlative import CorrelativeMatcher, MatchResult
from slam2d.matching.grid_cache import GridCache

__all__ = ["ChainGrid", "ScanMatcher"]


class ScanMatcher:
    """A :class:`CorrelativeMatcher` and the correlation grids it keeps, one for each set of nodes asked for.

    ``points_of(node)`` gives a node's reference: its world points (N, 2) and their smear sigmas (N,).
    Every method takes the ``window`` to search (the matcher's own by default): another window
    or angle offset of the same matcher (:meth:`CorrelativeMatcher.with_window`), at the same
    cell and smear, reads the same grids. ``max_entries``: the grids kept, at most.
    """

    def __init__(self, matcher: CorrelativeMatcher, points_of: Callable[[int], tuple], *,
                 max_entries: int = 8) -> None:
        self.matcher = matcher
        self._points_of = points_of
        self._cache = GridCache(matcher, points_of, max_entries=max_entries)

    def match(self, nodes, points: NDArray[np.float64], prior: NDArray[np.float64], *,
              window: CorrelativeMatcher | None = None, penalize: bool, refine: bool,
              min_response: float = -1.0) -> MatchResult:
        """The query ``points`` (robot frame) matched from ``prior`` against the nodes' scans (:meth:`CorrelativeMatcher.match`)."""
        window = window or self.matcher
        grid = self._cache.get(nodes, *window.search_box(points, prior))
        return window.match(None, None, points, prior, penalize=penalize, refine=refine, grid=grid,
                            min_response=min_response)

    def match_uncached(self, nodes, points: NDArray[np.float64], prior: NDArray[np.float64], *,
                       window: CorrelativeMatcher | None = None, penalize: bool, refine: bool) -> MatchResult:
        """:meth:`match` on a grid drawn for this match alone and not kept (a one-off window, whose grid would
        only push the kept ones out)."""
        window = window or self.matcher
        parts = [self._points_of(n) for n in nodes]
        ref, sig = np.concatenate([q[0] for q in parts]), np.concatenate([q[1] for q in parts])
        grid = window.correlation_grid(ref, sig, *window.search_box(points, prior))
        return window.match(None, None, points, prior, penalize=penalize, refine=refine, grid=grid)

    def match_near(self, nodes, points: NDArray[np.float64], prior: NDArray[np.float64], seed: NDArray[np.float64],
                   *, window: CorrelativeMatcher | None = None, half_steps: int, angle_steps: int) -> MatchResult | None:
        """:meth:`CorrelativeMatcher.match_near` against the nodes' scans: the search near ``seed`` first, or None.

        The grid is the one :meth:`match` asks for, so the cache evolves the same whether or not
        the caller then searches the whole window.
        """
        window = window or self.matcher
        grid = self._cache.get(nodes, *window.search_box(points, prior))
        return window.match_near(points, prior, seed, grid, half_steps=half_steps, angle_steps=angle_steps)

    def places(self, nodes, points: NDArray[np.float64], prior: NDArray[np.float64], *,
               window: CorrelativeMatcher | None = None, floor: float):
        """:meth:`CorrelativeMatcher.places` (``about=True``) against the nodes' scans: (places, covariance)."""
        window = window or self.matcher
        grid = self._cache.get(nodes, *window.search_box(points, prior))
        return window.places(points, prior, grid, floor=floor, about=True)

    def reserve(self, nodes, lo: NDArray[np.float64], hi: NDArray[np.float64], *,
                max_extra: int | None = None) -> "ChainGrid":
        """The grid of the nodes for queries inside the world box (lo, hi), its drawing deferred.

        The cache's book-keeping is done now whatever the caller then does, so later matches
        read the grids they would have had this one been matched (see :meth:`GridCache.reserve`).
        ``max_extra``: how many nodes not asked for the grid may hold (a looser superset than
        the cache's own).
        """
        return ChainGrid(self, self._cache.reserve(nodes, lo, hi, max_extra=max_extra), lo, hi)

    def invalidate(self, moved: NDArray[np.bool_] | None = None) -> None:
        """Forget the grids of scans that moved (an optimisation): all, or those holding a ``moved`` node."""
        self._cache.invalidate(moved)

    def release(self) -> None:
        """Forget every grid and give the memory back (the run is over; they are drawn again if it goes on)."""
        self._cache.release()

    @property
    def points_smeared(self) -> int:
        """Points drawn into grids so far."""
        return self._cache.smeared

    def stats(self) -> dict[str, Any]:
        """The grid counters for the diagnostics: grids set up (``builds``), extended by new scans, actually
        drawn (a reserved grid that was never matched is not), points smeared, and grids kept across an
        optimisation."""
        c = self._cache
        return {"builds": c.builds, "extensions": c.extensions, "draws": c.draws, "smeared": c.smeared,
                "kept": c.kept}


class ChainGrid:
    """A set of nodes' grid reserved by :meth:`ScanMatcher.reserve`, drawn only if it is matched.

    For a near chain: its response bound (no grid drawn) tells most chains that cannot link apart
    before the 1 cm grid is drawn.
    """

    def __init__(self, owner: ScanMatcher, entry: dict, lo: NDArray[np.float64], hi: NDArray[np.float64]) -> None:
        self._owner = owner
        self._entry = entry
        self._box = (lo, hi)

    @property
    def drawn(self) -> bool:
        """Whether the grid is drawn already (by this request or an earlier one)."""
        return GridCache.has_grid(self._entry)

    def bound(self, points: NDArray[np.float64], prior: NDArray[np.float64], *, window: CorrelativeMatcher | None = None,
              stop: float = 2.0, mark: float | None = None) -> float:
        """An upper bound of the match's response, without drawing the grid (:meth:`GridCache.bound`)."""
        return self._owner._cache.bound(self._entry, points, prior, stop=stop, mark=mark, matcher=window)

    def match(self, points: NDArray[np.float64], prior: NDArray[np.float64], *, window: CorrelativeMatcher | None = None,
              penalize: bool, refine: bool) -> MatchResult:
        """The match on this grid (drawn where the reserved box needs it)."""
        window = window or self._owner.matcher
        grid = self._owner._cache.materialize(self._entry, *self._box)
        return window.match(None, None, points, prior, penalize=penalize, refine=refine, grid=grid)
