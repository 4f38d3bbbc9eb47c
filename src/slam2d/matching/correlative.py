"""Correlative scan matching (Olson 2009; Karto's matcher): exhaustive search over x, y, angle.

The reference points (the scans being matched against, in the world frame)
are drawn into a *correlation grid*: every point is smeared by a Gaussian
``exp(-0.5 (d / sigma)^2)`` of its own sigma, cells keeping the largest value
(0..255 in a ``uint8`` grid, Karto keeps 0..100). A candidate pose of the
query scan scores the mean grid value under its points, the *response* in
[0, 1]: 1 means every point lies on a reference point.

The search is Karto's: per angle, the query points are rotated once and turned
into integer cells (the lookup table), then every x, y offset is an integer
shift. A *coarse* search covers the whole window at two cells per step and
the coarse angle step; a *fine* search covers one coarse step around the
coarse best at one cell per step and the fine angle step. With a penalty the
response is multiplied by ``max(1 - 0.2 d^2 / distance_variance_penalty,
minimum_distance_penalty) * max(1 - 0.2 dtheta^2 / angle_variance_penalty,
minimum_angle_penalty)`` (Karto's gains of 0.2), measured from the prior
pose. Equal best responses are averaged, so a corridor's flat response lands
in its middle rather than at a window edge.

Covariance, from the response surface as Karto computes it: x, y from the
coarse surface (for each x, y the best response over angles), the
response-weighted spread of every x, y within 0.1 of the best, floored at
0.1 coarse-step^2 and divided by the best response; theta from the spread of
the fine angles at the best x, y (floored at one fine step^2). The result also carries the
*coarse heading variance*, the same spread over the coarse angles (best response per angle): the
fine one cannot see an alternative heading beyond its +-1 deg window.

Wide windows (loop closure: 8 m at 5 cm is 81 x 81 x 21 poses) are searched
by *branch and bound* over blocks of translations: a max-pooled copy of the
grid gives, per block and angle, an upper bound of the response of every
translation in the block; blocks are scored exactly in decreasing bound order
until the bound falls more than 0.1 below the best found. Every pose whose
response can be within 0.1 of the best is thus scored exactly, so the result
and its covariance equal the exhaustive search's (a test checks it), at a
fraction of the lookups.

A match's own coarse search (narrow windows, searched exhaustively) skips angles the same
way: angles are scored from the prior's heading outwards, points in chunks, and an angle whose
sums so far plus a full cell for every point still to come (times its largest penalty) cannot
come within 0.1 of the best response scored so far is left unscored. Only the surface within
that band shapes the result, so the match is the exhaustive one bit for bit, with about two
thirds of the lookups on real scans.

This module holds the matcher (:class:`CorrelativeMatcher`); its compiled search kernels are in
:mod:`slam2d.matching.correlative_search`, the grid drawing (the smear, row bands on threads) in
:mod:`slam2d.matching.correlative_grid`, and the grids kept between matches in
:mod:`slam2d.matching.grid_cache`, which :class:`~slam2d.matching.scan_matcher.ScanMatcher` (a
matcher with its grids, what the graph front end calls) keeps to itself.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from slam2d.matching.correlative_grid import (_inside, _PIECES_PER_THREAD, _SCALE, _smear, _smear_sigmas, smear_points,
    _split, _THREADS)
from slam2d.matching.correlative_search import (_along_extent, _band_on_part_edge, _BLOCK, _block_bounds,
    _BNB_MIN_STEPS, _BOUND_BLOCK, _bound_levels, _bound_over, _BOUND_SPLITS, _bound_table, _COVARIANCE_BAND,
    _fine_stage, _finish_search, _heading_spread, _interleaved, _max_pool, MAX_VARIANCE, _PARALLEL_BOUND, _peaks,
    _plane_max, _max_argmax0, _point_columns,
    _PARALLEL_LOOKUPS, _PENALTY_GAIN, _pooled_smear, _PRUNE_CHUNK, _query_cells, _range_max_levels, _ranges,
    _rotated_extent, _score_blocks_stride, _score_poses, _score_poses_pruned, _search_window, _serial_blocks,
    _spaced, _spread_sums)


__all__ = ["CorrelativeMatcher", "MatchResult", "smear_points"]


# Angle offsets that depend only on a matcher's settings, computed once (see _coarse_angles); never written to.
_ANGLES: dict = {}


# Poses responding within this of the best count towards a match's covariance (Karto's 0.1).
COVARIANCE_BAND = _COVARIANCE_BAND


@dataclass
class MatchResult:
    """The best pose of a query scan, with its response and covariance."""

    pose: NDArray[np.float64]  # [x, y, theta] of the query robot pose, world frame
    covariance: NDArray[np.float64]  # 3x3, world-frame x, y, theta
    response: float  # in [0, 1], penalised when the match was
    raw_response: float  # the same pose without the penalty
    evaluated: int  # point lookups done (for diagnostics)
    # Spread of the coarse angles whose best response is within 0.1 of the best (rad^2): wide
    # when the scan fits about as well at headings many coarse steps apart.
    heading_variance_coarse: float = 0.0
    # How far the best coarse response at the prior's own heading (over the x, y window) lies below
    # the best coarse response: whether the scan fits the prior's heading about as well (NaN: not searched).
    prior_heading_drop: float = math.nan


class CorrelativeMatcher:
    """A correlative scan matcher with Karto's search: coarse window, then a fine step.

    Parameters (Karto's names in brackets):
        search_size: full side of the x, y window, m [CorrelationSearchSpaceDimension].
        resolution: correlation grid cell, m [CorrelationSearchSpaceResolution].
        smear_deviation: Gaussian sigma of a reference point, m [CorrelationSearchSpaceSmearDeviation];
            per-point sigmas given to :meth:`match` replace it.
        coarse_angle_offset: half-width of the angle window, rad [CoarseSearchAngleOffset].
        coarse_angle_resolution: coarse angle step, rad [CoarseAngleResolution].
        fine_angle_step: fine angle step, rad [FineSearchAngleOffset, which Karto uses as a step].
        distance_variance_penalty: m^2, already squared [DistanceVariancePenalty].
        angle_variance_penalty: rad^2, already squared [AngleVariancePenalty].
        minimum_distance_penalty, minimum_angle_penalty: floors of the penalty factors.
        response_expansion: widen the angle window by 20 deg up to 3 times when nothing matched.
    """

    def __init__(
        self,
        *,
        search_size: float = 0.3,
        resolution: float = 0.01,
        smear_deviation: float = 0.03,
        coarse_angle_offset: float = math.radians(20.0),
        coarse_angle_resolution: float = math.radians(2.0),
        fine_angle_step: float = math.radians(0.2),
        distance_variance_penalty: float = 0.3**2,
        angle_variance_penalty: float = math.radians(20.0) ** 2,
        minimum_distance_penalty: float = 0.5,
        minimum_angle_penalty: float = 0.9,
        response_expansion: bool = False,
    ) -> None:
        if not resolution > 0 or not search_size > 0:
            raise ValueError("resolution and search_size must be positive")
        if not coarse_angle_resolution > 0 or not fine_angle_step > 0:
            raise ValueError("angle steps must be positive")
        self.search_size = float(search_size)
        self.resolution = float(resolution)
        self.smear_deviation = float(smear_deviation)
        self.coarse_angle_offset = float(coarse_angle_offset)
        self.coarse_angle_resolution = float(coarse_angle_resolution)
        self.fine_angle_step = float(fine_angle_step)
        self.distance_variance_penalty = float(distance_variance_penalty)
        self.angle_variance_penalty = float(angle_variance_penalty)
        self.minimum_distance_penalty = float(minimum_distance_penalty)
        self.minimum_angle_penalty = float(minimum_angle_penalty)
        self.response_expansion = bool(response_expansion)
        # Coarse translations: two cells per step, covering half the window each way.
        self._coarse_half = max(1, int(round(0.5 * self.search_size / (2.0 * self.resolution))))
        self.branch_and_bound = True
        # Extra fine searches re-centred on a best pose that lies on the fine window's edge.
        self.fine_recentre = 0
        # The coarse search scores only the query points at least this far (m) from the last one kept
        # in scan order (0: every point); the fine stage scores them all (see :meth:`coarse_points`).
        self.coarse_point_spacing = 0.0

    def with_window(self, search_size: float) -> "CorrelativeMatcher":
        """The same matcher over a smaller (or larger) x, y window; its grids are interchangeable."""
        out = copy.copy(self)
        out.search_size = float(search_size)
        out._coarse_half = max(1, int(round(0.5 * out.search_size / (2.0 * out.resolution))))
        return out

    def coarse_points(self, q: NDArray[np.float64]) -> NDArray[np.float64]:
        """The query points the coarse search scores: with ``coarse_point_spacing`` only those at least
        that far from the last one kept (dense clutter near the robot is hit by dozens of beams a
        few millimetres apart, which a 2 cm lattice cannot tell apart), else all of them."""
        if self.coarse_point_spacing > 0 and q.shape[0] > 1:
            return _spaced(np.ascontiguousarray(q, dtype=np.float64), float(self.coarse_point_spacing))
        return q

    # ----------------------------------------------------------------- pieces

    def sigmas_for(self, beam_sigma: NDArray[np.float64] | None, n: int) -> NDArray[np.float64]:
        """Smear sigma per reference point: the smear combined with the beam's own range sigma (None: none).

        Clamped to Karto's allowed [0.5, 10] cells so the kernel stays resolvable.
        """
        # (Without a range sigma: sqrt(smear^2 + 0) is the smear itself, exactly.)
        sig = np.zeros(n) if beam_sigma is None else np.asarray(beam_sigma, dtype=np.float64)
        return self.reference_sigmas(sig, np.ones(n, dtype=np.bool_), sig, 0.0, 0.0)

    def reference_sigmas(self, beam_sigma: NDArray[np.float64], use: NDArray[np.bool_], ranges: NDArray[np.float64],
                         gap_share: float, increment: float) -> NDArray[np.float64]:
        """Smear sigma of a scan's reference points, one per beam in ``use``: :meth:`sigmas_for` of their range
        sigmas, then with ``gap_share`` > 0 widened in quadrature by that share of the beam gap (range times
        ``increment``), at most 10 cells: a point stands for the stretch of wall between it and its
        neighbours' beams. In one compiled pass (:func:`_smear_sigmas`)."""
        lo, hi = self.sigma_limits
        return _smear_sigmas(self.smear_deviation, np.ascontiguousarray(beam_sigma, dtype=np.float64),
                             np.asarray(use, dtype=np.bool_), np.ascontiguousarray(ranges, dtype=np.float64),
                             float(gap_share), abs(float(increment)), lo, hi)

    @property
    def sigma_limits(self) -> tuple[float, float]:
        """The least and the largest smear sigma (m) :meth:`sigmas_for` gives: Karto's [0.5, 10] cells."""
        return 0.5 * self.resolution, 10.0 * self.resolution

    def query_box(
        self, query_points: NDArray[np.float64], prior: NDArray[np.float64], angle_offset: float
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """World box (lo, hi) every query point can reach in the search window around ``prior``."""
        q = np.asarray(query_points, dtype=np.float64).reshape(-1, 2)
        key = ("box", angle_offset)
        lin = _ANGLES.get(key)
        if lin is None:
            n = max(2, int(math.ceil(angle_offset / math.radians(10.0))))
            lin = _ANGLES[key] = np.linspace(-angle_offset, angle_offset, 2 * n + 1)
        angles = prior[2] + lin
        x_lo, y_lo, x_hi, y_hi, reach = _rotated_extent(np.cos(angles), np.sin(angles), np.ascontiguousarray(q))
        # Between the sampled angles an arc bulges by at most r (1 - cos(step / 2)).
        pad = 0.5 * self.search_size + reach * (1.0 - math.cos(0.5 * (angles[1] - angles[0]))) + self.resolution
        # Element by element what np.array([x_lo, y_lo]) + prior[:2] - pad gives (and hi so).
        p0, p1 = float(prior[0]), float(prior[1])
        return np.array([x_lo + p0 - pad, y_lo + p1 - pad]), np.array([x_hi + p0 + pad, y_hi + p1 + pad])

    def search_box(self, query_points: NDArray[np.float64], prior: NDArray[np.float64]):
        """The world box the query can reach in this matcher's full window (with response expansion)."""
        widest = self.coarse_angle_offset + (math.radians(60.0) if self.response_expansion else 0.0)
        return self.query_box(query_points, np.asarray(prior, dtype=np.float64), widest)

    def _sig(self, ref, ref_sigmas):
        if ref_sigmas is None:
            return self.sigmas_for(None, ref.shape[0])
        return np.asarray(ref_sigmas, dtype=np.float64)

    def correlation_grid(
        self,
        ref_points: NDArray[np.float64],
        ref_sigmas: NDArray[np.float64],
        lo: NDArray[np.float64],
        hi: NDArray[np.float64],
        *,
        clip: bool = True,
    ) -> tuple[NDArray[np.uint8], float, float]:
        """The smeared grid of the reference points inside the world box (lo, hi): (grid, origin_x, origin_y).

        ``clip`` shrinks the box to the reference points' own extent (smaller
        grid); a grid that will be extended later (:class:`~slam2d.matching.grid_cache.GridCache`) keeps it.
        """
        res = self.resolution
        margin = self.smear_reach(float(ref_sigmas.max(initial=self.smear_deviation)))
        lo = np.asarray(lo, dtype=np.float64).copy()
        hi = np.asarray(hi, dtype=np.float64).copy()
        if ref_points.shape[0]:
            px = np.ascontiguousarray(ref_points[:, 0])
            py = np.ascontiguousarray(ref_points[:, 1])
            keep = _inside(px, py, lo[0] - margin, lo[1] - margin, hi[0] + margin, hi[1] + margin)
            if keep.size < px.size:
                px, py, ref_sigmas = px[keep], py[keep], ref_sigmas[keep]
        else:
            px = py = np.zeros(0)
        if px.size and clip:
            lo = np.maximum(lo, np.array([px.min(), py.min()]) - margin)
            hi = np.minimum(hi, np.array([px.max(), py.max()]) + margin)
        ox, oy, rows, cols = self._geometry(lo, hi)
        grid = np.zeros((rows, cols), dtype=np.uint8)
        origin = (ox, oy)
        if px.size:
            _smear(grid, float(origin[0]), float(origin[1]), res, px, py,
                               np.ascontiguousarray(ref_sigmas, dtype=np.float64), _uniform(ref_sigmas) is not None)
        return grid, float(origin[0]), float(origin[1])

    def smear_reach(self, sigma: float) -> float:
        """How far (m) from a reference point its smear of ``sigma`` can reach a grid cell: the kernel's
        half-width (2 sigma) and two cells for the rounding of the point and the kernel to cells."""
        return 2.0 * sigma + 2.0 * self.resolution

    def _geometry(self, lo, hi) -> tuple[float, float, int, int]:
        res = self.resolution
        hi = np.maximum(hi, lo + res)
        origin = np.floor(lo / res) * res
        shape = np.ceil((hi - origin) / res).astype(np.int64) + 1
        return float(origin[0]), float(origin[1]), int(shape[1]), int(shape[0])

    def grid_geometry(self, ref_sigmas, lo, hi) -> tuple[float, float, int, int]:
        """(origin x, origin y, rows, cols) of ``correlation_grid(..., lo, hi, clip=False)``, without drawing it."""
        return self._geometry(np.asarray(lo, dtype=np.float64).copy(), np.asarray(hi, dtype=np.float64).copy())

    def response_bound(self, ref_points, ref_sigmas, query_points, prior, *, stop: float = 2.0) -> float:
        """An upper bound of :meth:`match`'s response on any grid drawn from at most these reference points.

        Exact (never below the response), with or without penalty and refinement: it covers
        every translation the coarse and fine searches can try (the window plus one fine
        step) and every heading within the larger of half a coarse step and the fine window
        of a coarse angle, on a grid max-pooled over ``_BOUND_BLOCK`` cells a side
        (:func:`_pooled_smear`, drawn without drawing the correlation grid). A caller that only
        needs to know that a match cannot reach a threshold (a near chain out of view) can skip
        the grid and the search. ``stop``: return as soon as the bound is known to reach it
        (some value >= ``stop``). With response expansion (angles beyond the window) it returns 1.
        """
        ref = np.asarray(ref_points, dtype=np.float64).reshape(-1, 2)
        prior = np.asarray(prior, dtype=np.float64).reshape(3)
        if self.response_expansion:
            return 1.0
        if np.asarray(query_points).size == 0 or ref.shape[0] == 0 or not np.all(np.isfinite(prior)):
            return 0.0
        lo, hi = self.query_box(query_points, prior, self.coarse_angle_offset + self._bound_angles()[1])
        reach = sum(self._bound_window())
        ox, oy, rows, cols = self._geometry(lo - reach - 1.0, hi + reach + 1.0)
        pooled = self.pooled_grid(ref, self._sig(ref, ref_sigmas), ox, oy, rows, cols)
        return self.pooled_bound(pooled, ox, oy, query_points, prior, stop=stop)

    def pooled_grid(self, ref_points, ref_sigmas, origin_x, origin_y, rows, cols, out=None):
        """The bound grid of :meth:`pooled_bound` for the correlation grid (origin, rows x cols) of these points.

        ``out`` (a bound grid of the same geometry) is extended instead of a new one drawn.
        """
        b = _BOUND_BLOCK
        if out is None:
            out = np.zeros((rows // b + 1, cols // b + 1), np.uint8)
        ref = np.asarray(ref_points, dtype=np.float64).reshape(-1, 2)
        if ref.shape[0]:
            _pooled_smear(out, np.ascontiguousarray(ref[:, 0]), np.ascontiguousarray(ref[:, 1]),
                          float(np.max(ref_sigmas)), origin_x, origin_y, self.resolution, b, 0, 0)
        return out

    def _bound_angles(self):
        """The coarse angles and the largest heading any search tries away from the nearest one."""
        n_half = int(round(self.coarse_angle_offset / self.coarse_angle_resolution))
        angles = np.arange(-n_half, n_half + 1) * self.coarse_angle_resolution
        n_fine = int(round(0.5 * self.coarse_angle_resolution / self.fine_angle_step))
        return angles, max(0.5 * self.coarse_angle_resolution, n_fine * self.fine_angle_step) + 1e-9

    def _bound_window(self) -> tuple[float, float]:
        """(translations a search tries each way: the coarse window plus one fine step; slack for
        the cell rounding of the lookup table, its centre possibly a mean of offsets, and of a grid
        whose origin is another multiple of the cell), m."""
        return (2 * self._coarse_half + 1) * self.resolution, 4 * self.resolution

    def pooled_bound(self, pooled, origin_x, origin_y, query_points, prior, *, stop: float = 2.0,
                     tables: dict | None = None, mark: float | None = None) -> float:
        """:meth:`response_bound` on a bound grid from :meth:`pooled_grid` (origin: its correlation grid's).

        ``tables``: where the bound grid's sparse table is kept between calls (the caller empties
        it when the bound grid changes); without it the table is built for this call.
        ``mark`` (at most ``stop``): the caller only asks whether the bound is below ``mark``, in
        [mark, stop) or at least ``stop``; the value returned answers that as the bound itself
        would (compared as ``bound < mark``, ``bound < stop``) but may be lower, which lets most
        squares of the bound be summed in part.
        """
        q = np.asarray(query_points, dtype=np.float64).reshape(-1, 2)
        prior = np.asarray(prior, dtype=np.float64).reshape(3)
        if self.response_expansion:
            return 1.0
        if q.shape[0] == 0 or not all(map(math.isfinite, prior.tolist())):
            return 0.0
        key = ("bound", self.coarse_angle_offset, self.coarse_angle_resolution, self.fine_angle_step)
        got = _ANGLES.get(key)
        if got is None:
            angles, delta = self._bound_angles()
            # The prior's heading first, then outwards: a bound that reaches ``stop`` mostly reaches it
            # near there, and returns at once (below ``stop`` every heading is bounded, in any order).
            got = _ANGLES[key] = (angles[np.argsort(np.abs(angles), kind="stable")], delta)
        angles, delta = got
        n = q.shape[0] * _SCALE
        trans, slack = self._bound_window()
        cut = int(math.ceil(stop * n))
        if tables is None:
            qx, qy = np.ascontiguousarray(q[:, 0]), np.ascontiguousarray(q[:, 1])
            rng, table = _bound_table(pooled, _BOUND_BLOCK, self.resolution, qx, qy, trans, slack, delta)
        else:
            qx, qy, rng = _point_columns(q)  # the two columns (contiguous) and _ranges of them, in one pass
            levels = _bound_levels(rng, _BOUND_BLOCK, self.resolution, trans, slack, delta)
            table = tables.get("table")
            if table is None or table.shape[0] < levels:
                table = tables["table"] = _range_max_levels(pooled, levels)
        reached = np.zeros(1, np.int64)
        parts = {}
        # The least sums the caller's comparisons (sum / n against mark and stop) put at or above them.
        low, top = (-1, cut) if mark is None else (_least_total(min(mark, stop), n), _least_total(stop, n))

        def over(a0, a1):
            parts[a0] = _bound_over(table, _BOUND_BLOCK, origin_x, origin_y, self.resolution, qx, qy, rng,
                                    float(prior[0]), float(prior[1]), float(prior[2]), angles, a0, a1, trans, slack,
                                    delta, cut, _BOUND_SPLITS, reached, low, top)

        # Among threads when it pays: a part that reaches ``stop`` stops the others, and the
        # result (``stop``, or the best over every heading) does not depend on which did.
        if q.shape[0] * angles.shape[0] >= _PARALLEL_BOUND:
            _split(over, angles.shape[0], pieces=_THREADS * _PIECES_PER_THREAD)
        else:
            over(0, angles.shape[0])
        return float(max(parts.values())) / n

    def _penalty(self, dx, dy, dth):
        d2 = dx * dx + dy * dy
        pd = np.maximum(1.0 - _PENALTY_GAIN * d2 / self.distance_variance_penalty, self.minimum_distance_penalty)
        pa = np.maximum(1.0 - _PENALTY_GAIN * dth * dth / self.angle_variance_penalty, self.minimum_angle_penalty)
        return pd * pa

    def _search(self, grid, origin, q, center, prior, angles, half, step, penalize, allow_bnb, floor=-1.0,
                prune=False, angle_order=None):
        """One search phase around ``center``: (best pose, best response, raw, surface, lookups).

        ``prune``: the surface is needed only within the covariance band of the best (a match's
        coarse search, not :meth:`places`): angles that cannot come within it are left unscored.
        ``angle_order``: ``np.argsort(np.abs(angles), kind="stable")`` when the caller has it.
        """
        res = self.resolution
        n_steps = 2 * half + 1
        n_points = q.shape[0]
        offs = _offsets(n_steps, half, step * res)
        # The bound is on the raw response, so it prunes exactly only without a penalty.
        exhaustive = penalize or not (allow_bnb and self.branch_and_bound and n_steps >= _BNB_MIN_STEPS)
        if exhaustive and prune:
            q = np.ascontiguousarray(q, dtype=np.float64)
            sums = np.empty((angles.shape[0], n_steps, n_steps))
            cx, cy, ct = float(center[0]), float(center[1]), float(center[2])
            args = (float(prior[0]), float(prior[1]), float(prior[2]), penalize, self.distance_variance_penalty,
                    self.angle_variance_penalty, self.minimum_distance_penalty, self.minimum_angle_penalty)
            if angle_order is None:
                angle_order = np.argsort(np.abs(angles), kind="stable")
            lookups = _score_poses_pruned(grid, origin[0], origin[1], res, _interleaved(q), cx, cy, ct, angles,
                                          angle_order, half, step, 0, 0, n_steps,
                                          *args[:8], -1.0, _PRUNE_CHUNK, sums)
            pose, best, raw_best, resp = _finish_search(sums, n_points, offs, angles, cx, cy, ct, *args)
            return pose, best, float(raw_best), resp, offs, int(lookups)
        if exhaustive:
            q = np.ascontiguousarray(q, dtype=np.float64)
            lookups = angles.shape[0] * n_steps * n_steps * n_points
            # Threads pay only on searches big enough to outweigh waking them (the coarse one).
            if _THREADS > 1 and lookups >= _PARALLEL_LOOKUPS:
                sums = np.empty((angles.shape[0], n_steps, n_steps))
                cx, cy, ct = float(center[0]), float(center[1]), float(center[2])
                _split(lambda a0, a1: _score_poses(grid, origin[0], origin[1], res, q, cx, cy, ct, angles, half, step,
                                                   a0, a1, sums), angles.shape[0],
                       pieces=_THREADS * _PIECES_PER_THREAD)
                pose, best, raw_best, resp = _finish_search(
                    sums, n_points, offs, angles, cx, cy, ct, float(prior[0]), float(prior[1]), float(prior[2]),
                    penalize, self.distance_variance_penalty, self.angle_variance_penalty,
                    self.minimum_distance_penalty, self.minimum_angle_penalty)
            else:
                pose, best, raw_best, resp, offs = _search_window(
                    grid, origin[0], origin[1], res, q, float(center[0]), float(center[1]), float(center[2]),
                    float(prior[0]), float(prior[1]), float(prior[2]), angles, half, step, penalize,
                    self.distance_variance_penalty, self.angle_variance_penalty, self.minimum_distance_penalty,
                    self.minimum_angle_penalty)
            return pose, best, float(raw_best), resp, offs, lookups
        rows, cols = _query_cells(
            q[:, 0], q[:, 1], angles, center[0], center[1], center[2],
            origin[0], origin[1], res, -half * step,
        )
        block = _BLOCK
        n_blocks = (n_steps + block - 1) // block
        width = (block - 1) * step + 1
        pooled = _max_pool(grid, width)
        bounds = _block_bounds(pooled, rows, cols, n_blocks, block * step, width)
        flat = bounds.reshape(-1)
        order = np.argsort(-flat, kind="stable")
        band = _COVARIANCE_BAND + 1e-9
        # Blocks scored in strides, one per thread; then exactly the serial search's blocks are kept.
        sums = np.full((angles.shape[0], n_steps, n_steps), -1.0)
        norm, least, strides = float(n_points) * _SCALE, float(floor), _THREADS

        def score_strides(s0: int, s1: int) -> None:
            for s in range(s0, s1):
                _score_blocks_stride(grid, rows, cols, order, flat, n_blocks, block, n_steps, step, band, norm, least,
                                     s, strides, sums)

        _split(score_strides, strides)
        lookups = _serial_blocks(sums, rows.shape[1], order, flat, n_blocks, block, n_steps, band, norm, least)
        lookups += flat.size * n_points
        pose, best, raw_best, resp = _finish_search(
            sums, n_points, offs, angles, float(center[0]), float(center[1]), float(center[2]),
            float(prior[0]), float(prior[1]), float(prior[2]), penalize, self.distance_variance_penalty,
            self.angle_variance_penalty, self.minimum_distance_penalty, self.minimum_angle_penalty)
        return pose, best, float(raw_best), resp, offs, lookups

    def _positional_covariance(self, resp, offs, center, pose, best, step_m, own=0.0):
        """Karto's x, y covariance of the surface about ``pose`` (see the module docstring).

        ``own`` is the weight of ``pose`` itself as one more sample (a refined place that the
        lattice ``resp`` sampled low; 0 for the lattice's own best). The usual case (the lattice's
        own best, no good response on the window's edge) runs in one compiled pass whose sums are
        numpy's, bit for bit (:func:`_spread_sums`); the others in numpy below.
        """
        if own == 0.0 and resp.ndim == 3:
            norm, sxx, syy, sxy, edge = _spread_sums(resp, offs, float(center[0]), float(center[1]),
                                                     float(pose[0]), float(pose[1]), best - _COVARIANCE_BAND)
            if norm <= 1e-12 or best <= 0:
                return np.diag([MAX_VARIANCE, MAX_VARIANCE])
            floor = 0.1 * step_m * step_m
            # Each entry divided by ``best`` as ``cov /= best`` would (one array, no in-place passes).
            sxy = sxy / norm / best
            cov = np.array([[max(sxx / norm, floor) / best, sxy], [sxy, max(syy / norm, floor) / best]])
            if edge:
                # As in the general case below, with the same sums (the mask's extent along the
                # main axis compiled too).
                vals, vecs = np.linalg.eigh(cov)
                lo, hi = _along_extent(resp, offs, float(center[0]), float(center[1]), float(pose[0]),
                                       float(pose[1]), best - _COVARIANCE_BAND, float(vecs[0, -1]), float(vecs[1, -1]))
                if hi - lo >= 0.5 * self.search_size:
                    vals[-1] = max(vals[-1], self.search_size**2)
                    cov = (vecs * vals) @ vecs.T
            return cov
        return self._positional_covariance_general(resp, offs, center, pose, best, step_m, own)

    def _positional_covariance_general(self, resp, offs, center, pose, best, step_m, own=0.0):
        surface = resp.max(axis=0) if resp.ndim == 3 else resp  # best response over angles, per (y, x)
        mask = surface >= best - _COVARIANCE_BAND
        w = np.where(mask, surface, 0.0)
        norm = w.sum() + own
        cov = np.zeros((2, 2))
        floor = 0.1 * step_m * step_m
        if norm <= 1e-12 or best <= 0:
            return np.diag([MAX_VARIANCE, MAX_VARIANCE])
        dx = (center[0] + offs)[None, :] - pose[0]
        dy = (center[1] + offs)[:, None] - pose[1]
        cov[0, 0] = max((w * dx * dx).sum() / norm, floor)
        cov[1, 1] = max((w * dy * dy).sum() / norm, floor)
        cov[0, 1] = cov[1, 0] = (w * dx * dy).sum() / norm
        cov /= best
        if mask[0, :].any() or mask[-1, :].any() or mask[:, 0].any() or mask[:, -1].any():
            # The good responses run along the spread's main axis through at least half the
            # window and into its edge (a corridor): the spread seen inside the window
            # understates the uncertainty, so along that axis it is taken as at least the whole
            # window (Karto keeps the truncated spread). A peak that merely sits near the edge
            # is left alone.
            vals, vecs = np.linalg.eigh(cov)
            along = (dx * vecs[0, -1] + dy * vecs[1, -1])[mask]
            if along.max() - along.min() >= 0.5 * self.search_size:
                vals[-1] = max(vals[-1], self.search_size**2)
                cov = (vecs * vals) @ vecs.T
        return cov

    # ----------------------------------------------------------------- the match

    def match(
        self,
        ref_points: NDArray[np.float64] | None,
        ref_sigmas: NDArray[np.float64] | None,
        query_points: NDArray[np.float64],
        prior: NDArray[np.float64],
        *,
        penalize: bool = True,
        refine: bool = True,
        grid: tuple[NDArray[np.uint8], float, float] | None = None,
        min_response: float = -1.0,
    ) -> MatchResult:
        """Best pose of the query scan (points ``(N, 2)`` in its robot frame) against world points.

        ``prior`` is the predicted robot pose: the window's centre and the
        penalty's zero. ``ref_sigmas`` (one per reference point, m) replace the
        smear deviation; None uses it for all. A prebuilt ``grid`` (from
        :meth:`correlation_grid`) skips building one. ``min_response`` is the least
        response the caller accepts: a branch-and-bound search skips every pose that
        cannot come within the covariance band of it, so a match that reaches it is the
        exhaustive one (pose, response, covariance) and one that cannot returns some
        response below it, early.
        """
        prior = np.asarray(prior, dtype=np.float64).reshape(3)
        q = np.asarray(query_points, dtype=np.float64).reshape(-1, 2)
        ref = np.zeros((0, 2)) if ref_points is None else np.asarray(ref_points, dtype=np.float64).reshape(-1, 2)
        empty = grid is None and ref.shape[0] == 0
        if q.shape[0] == 0 or empty or not all(map(math.isfinite, prior.tolist())):
            return MatchResult(prior.copy(), np.diag([MAX_VARIANCE, MAX_VARIANCE, MAX_VARIANCE]), 0.0, 0.0, 0)
        if grid is None:
            grid = self.correlation_grid(ref, self._sig(ref, ref_sigmas), *self.search_box(q, prior))
        g, ox, oy = grid
        origin = (ox, oy)
        res = self.resolution
        offset = self.coarse_angle_offset
        lookups = 0
        qc = self.coarse_points(q)
        for _ in range(4 if self.response_expansion else 1):
            n_half = int(round(offset / self.coarse_angle_resolution))
            angles, angle_order = _coarse_angles(offset, self.coarse_angle_resolution)
            pose, best, raw, resp, offs, n = self._search(
                g, origin, qc, prior, prior, angles, self._coarse_half, 2, penalize, True, min_response, prune=True,
                angle_order=angle_order,
            )
            lookups += n
            if best > 0.0:
                break
            offset += math.radians(20.0)
        cov = np.zeros((3, 3))
        cov[:2, :2] = self._positional_covariance(resp, offs, prior, pose, best, 2.0 * res)
        heading_var = _heading_spread(resp, angles, best, self.coarse_angle_resolution**2 / 12.0)
        # The coarse angles are offsets from the prior's heading, which the pruned search scores
        # first and in full; an angle it leaves unscored (only with min_response) is over the band below.
        prior_drop = float(best - max(_plane_max(resp, n_half), 0.0))
        return self._finish_match(g, ox, oy, q, prior, pose, best, raw, cov, heading_var, prior_drop, penalize,
                                  refine, lookups)

    def _finish_match(self, g, ox, oy, q, prior, pose, best, raw, cov, heading_var, prior_drop, penalize, refine,
                      lookups) -> MatchResult:
        """The fine stage after a coarse search (``cov`` holds its x, y covariance) and the result."""
        cov[2, 2] = 1.0  # Karto's placeholder when there is no fine angular search
        if refine and best > 0.0:
            angles, _ = _fine_angles(self.coarse_angle_resolution, self.fine_angle_step)
            # One coarse step of the fine search around the coarse best, in one compiled call: while
            # its best lies on its window's edge and responds better it is re-centred there (up to
            # fine_recentre times): the coarse pose is 1-2 cells and up to half a coarse angle step
            # off; at the wrong angle the best x, y is off too (far points move r * dtheta), and the
            # fine step cannot leave its +-1 cell. The heading variance is the spread of the fine
            # angles at the best x, y.
            pose, best, raw, cov[2, 2], runs = _fine_stage(
                g, float(ox), float(oy), self.resolution, np.ascontiguousarray(q), pose, float(prior[0]),
                float(prior[1]), float(prior[2]), angles, penalize, self.distance_variance_penalty,
                self.angle_variance_penalty, self.minimum_distance_penalty, self.minimum_angle_penalty,
                int(self.fine_recentre), self.fine_angle_step**2, 1000.0 * self.fine_angle_step**2)
            lookups += runs * angles.shape[0] * 9 * q.shape[0]
        elif best <= 0.0:
            cov = np.diag([MAX_VARIANCE, MAX_VARIANCE, MAX_VARIANCE])
        pose[2] = (float(pose[2]) + math.pi) % (2 * math.pi) - math.pi  # numpy's wrap, in Python floats (same %)
        return MatchResult(pose, cov, max(best, 0.0), max(raw, 0.0), int(lookups), heading_var, prior_drop)

    def match_near(
        self,
        query_points: NDArray[np.float64],
        prior: NDArray[np.float64],
        seed: NDArray[np.float64],
        grid: tuple[NDArray[np.uint8], float, float],
        *,
        half_steps: int,
        angle_steps: int,
        penalize: bool = True,
    ) -> MatchResult | None:
        """:meth:`match` (refined) with its coarse search cut to the part of its window nearest ``seed``;
        None when that part cannot stand for the whole window.

        The part is +-``half_steps`` coarse x, y steps and +-``angle_steps`` coarse angles of the
        full search's own lattice (centred on ``prior``, the penalty's zero) around the lattice
        pose nearest ``seed``, scored with the full search's arithmetic; the rest of the window
        counts as unscored. When the full surface's best and every pose within the covariance
        band of it lie in the part, the result is :meth:`match`'s bit for bit. The part cannot
        see a better pose outside it, so it gives up (None: search the whole window) when a pose
        within the band of its best lies on an edge of the part inside the window (a peak
        running out of it, a corridor) or nothing responds; the caller also rejects a weak best.
        """
        prior = np.asarray(prior, dtype=np.float64).reshape(3)
        seed = np.asarray(seed, dtype=np.float64).reshape(3)
        q = np.ascontiguousarray(np.asarray(query_points, dtype=np.float64).reshape(-1, 2))
        p0, p1, p2 = prior.tolist()
        s0, s1, s2 = seed.tolist()
        if q.shape[0] == 0 or not all(map(math.isfinite, (p0, p1, p2, s0, s1, s2))):
            return None
        g, ox, oy = grid
        res = self.resolution
        step_m = 2.0 * res
        big = self._coarse_half
        n_half = int(round(self.coarse_angle_offset / self.coarse_angle_resolution))
        h, k = min(int(half_steps), big), min(int(angle_steps), n_half)
        # The part's lowest lattice indices (x, y, angle), kept inside the window.
        j_lo = min(max(int(round((s0 - p0) / step_m)), h - big), big - h) + big - h
        i_lo = min(max(int(round((s1 - p1) / step_m)), h - big), big - h) + big - h
        d_theta = math.remainder(s2 - p2, 2.0 * math.pi)
        a_seed = min(max(int(round(d_theta / self.coarse_angle_resolution)), -n_half), n_half) + n_half
        a_lo = min(max(a_seed - n_half, k - n_half), n_half - k) + n_half - k
        angles, _ = _coarse_angles(self.coarse_angle_offset, self.coarse_angle_resolution)
        n_steps = 2 * big + 1
        sums = np.full((angles.shape[0], n_steps, n_steps), -1.0)
        # The part's angles nearest the seed's first: the best found early prunes the others (kept per part).
        key = ("part", a_lo, k, a_seed, big, step_m)
        got = _ANGLES.get(key)
        if got is None:
            part = np.arange(a_lo, a_lo + 2 * k + 1)
            got = _ANGLES[key] = (part[np.argsort(np.abs(part - a_seed), kind="stable")],
                                  (np.arange(n_steps) - big) * step_m)
        order, offs = got
        qc = self.coarse_points(q)
        lookups = _score_poses_pruned(g, ox, oy, res, _interleaved(qc), p0, p1, p2, angles,
                                      order, big, 2, i_lo, j_lo, 2 * h + 1, p0, p1,
                                      p2, penalize, self.distance_variance_penalty,
                                      self.angle_variance_penalty, self.minimum_distance_penalty,
                                      self.minimum_angle_penalty, -1.0, _PRUNE_CHUNK, sums)
        pose, best, raw, resp = _finish_search(
            sums, qc.shape[0], offs, angles, p0, p1, p2, p0, p1, p2, penalize, self.distance_variance_penalty,
            self.angle_variance_penalty, self.minimum_distance_penalty, self.minimum_angle_penalty)
        if not best > 0.0:
            return None
        # Edges of the part that are the window's own edges hide nothing.
        if _band_on_part_edge(resp, best - _COVARIANCE_BAND, a_lo, 2 * k + 1, i_lo, j_lo, 2 * h + 1):
            return None
        cov = np.zeros((3, 3))
        cov[:2, :2] = self._positional_covariance(resp, offs, prior, pose, best, step_m)
        heading_var = _heading_spread(resp, angles, best, self.coarse_angle_resolution**2 / 12.0)
        # The prior's heading over the whole window is not known: over any drop unless its best is in the band.
        at_prior = _plane_max(resp, n_half)
        prior_drop = float(best - at_prior) if at_prior >= best - _COVARIANCE_BAND else math.inf
        return self._finish_match(g, ox, oy, q, prior, pose, best, raw, cov, heading_var, prior_drop, penalize,
                                  True, lookups)

    def places(
        self,
        query_points: NDArray[np.float64],
        prior: NDArray[np.float64],
        grid: tuple[NDArray[np.uint8], float, float],
        *,
        floor: float,
        count: int = 16,
        about: bool = False,
    ):
        """The distinct places the query fits in this matcher's window, each refined: [(pose, response)], best first.

        The unpenalised coarse search over the whole window (exhaustive: every pose is
        scored) is reduced to the best response over headings per x, y; a place is an x, y
        whose response is at least each of its 8 neighbours' and at least ``floor`` (at most
        ``count`` of them, best first). Each is then searched one coarse step each way in
        x, y at one cell and in heading at the fine step, so that a peak lying between
        lattice poses is found wherever it is in the lattice's cell: on a 5 cm grid with a
        3 cm smear a wall seen across a corridor gives a peak one cell wide in x and a
        degree in heading, which the 2-cell, 2 deg lattice can sample 0.3 below its value
        while a look-alike place happens to sit on a lattice pose.

        With ``about`` it returns ``(places, covariance)``, where ``covariance(pose, response)``
        is Karto's positional covariance of this coarse surface taken about a refined place:
        the lattice poses responding within the covariance band (0.1) of that place's
        response, and the place itself, response-weighted, divided by its response. Where the
        lattice sampled the place's peak low only the place itself counts; where the lattice
        holds poses about as good (a corridor's ridge) they spread it as Karto's test would.
        """
        prior = np.asarray(prior, dtype=np.float64).reshape(3)
        q = np.asarray(query_points, dtype=np.float64).reshape(-1, 2)
        if q.shape[0] == 0 or not np.all(np.isfinite(prior)):
            return ([], lambda pose, response: np.diag([MAX_VARIANCE, MAX_VARIANCE])) if about else []
        g, ox, oy = grid
        n_half = int(round(self.coarse_angle_offset / self.coarse_angle_resolution))
        angles = np.arange(-n_half, n_half + 1) * self.coarse_angle_resolution
        _, _, _, resp, offs, _ = self._search(g, (ox, oy), q, prior, prior, angles, self._coarse_half, 2, False, False)
        surface, heading = _max_argmax0(resp)  # (y, x): resp.max(axis=0), resp.argmax(axis=0)
        # At least ``floor`` and each of its 8 neighbours (-inf beyond the edge), in one compiled pass.
        iy, ix = np.nonzero(_peaks(surface, float(floor)))
        order = np.argsort(-surface[iy, ix], kind="stable")[:count]
        n_fine = int(round(self.coarse_angle_resolution / self.fine_angle_step))
        fine = np.arange(-n_fine, n_fine + 1) * self.fine_angle_step
        out = []
        for k in order:
            y, x = int(iy[k]), int(ix[k])
            center = np.array([prior[0] + offs[x], prior[1] + offs[y], prior[2] + angles[heading[y, x]]])
            pose, best, _, _, _, _ = self._search(g, (ox, oy), q, center, center, fine, 2, 1, False, False)
            pose[2] = (pose[2] + np.pi) % (2 * np.pi) - np.pi
            out.append((pose, float(best)))
        out.sort(key=lambda t: -t[1])
        if not about:
            return out
        step_m = 2.0 * self.resolution

        def covariance(pose, response):
            return self._positional_covariance(surface, offs, prior, pose, response, step_m, own=response)

        return out, covariance


def _coarse_angles(offset: float, step: float):
    """The coarse search's angle offsets (``np.arange(-n, n + 1) * step``) and the order that scores the
    prior's heading first and then outwards; kept per (offset, step), never written to."""
    key = ("coarse", offset, step)
    got = _ANGLES.get(key)
    if got is None:
        n_half = int(round(offset / step))
        angles = np.arange(-n_half, n_half + 1) * step
        got = _ANGLES[key] = (angles, np.argsort(np.abs(angles), kind="stable"))
    return got


def _offsets(n_steps: int, half: int, step_m: float):
    """A search's x, y offsets ``(np.arange(n_steps) - half) * step_m``, kept per (n_steps, half, step_m);
    never written to."""
    key = ("offsets", n_steps, half, step_m)
    got = _ANGLES.get(key)
    if got is None:
        got = _ANGLES[key] = (np.arange(n_steps) - half) * step_m
    return got


def _fine_angles(coarse_step: float, fine_step: float):
    """The fine stage's angle offsets (one coarse step of fine steps), as :func:`_coarse_angles`."""
    return _coarse_angles(0.5 * coarse_step, fine_step)


def _least_total(x: float, n: float) -> int:
    """The least integer t >= 0 with ``t / n >= x`` in floating point (the division is monotone in t)."""
    t = max(int(math.ceil(x * n)), 0)
    while t > 0 and (t - 1) / n >= x:
        t -= 1
    while t / n < x:
        t += 1
    return t


def _uniform(sigmas: NDArray[np.float64]) -> float | None:
    """The one sigma every point has, or None when they differ (or there are none)."""
    if sigmas.size == 0 or sigmas.min() != sigmas.max():
        return None
    return float(sigmas[0])
