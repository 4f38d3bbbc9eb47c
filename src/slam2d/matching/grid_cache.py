"""Correlation grids kept between matches (:class:`GridCache`), extended scan by scan instead of rebuilt.

Its user is :class:`~slam2d.matching.scan_matcher.ScanMatcher`, which keeps its entries to itself.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

from slam2d.core.arrays import grown
from slam2d.matching.correlative import CorrelativeMatcher
from slam2d.matching.correlative_grid import _derive_grid, _inside, _inside_not, _smear
from slam2d.matching.correlative_search import (_BOUND_BLOCK, _boxes_extent, _boxes_sigma, _node_blocks_of,
    _node_stats, _scatter_max_nodes, _unknown_nodes)

__all__ = ["GridCache"]

# The drawn grids kept, at most (least recently used dropped first): at 1 cm a near chain's grid of a
# long-range log is 4-10 MB, and 32 of them held 233 MB of karto's 698 MB peak on fr101 (128 MB: the
# same matches on every log; 64-96 MB changed one on csail, 0.149 -> 0.168 m).
_MAX_BYTES = 128 << 20
# The bound-grid blocks kept per node, at most (then only the nodes of the current query keep theirs; the rest
# are computed again when asked): the shared logs use 1.5-9 MB, a log driven four times over 40 MB, growing
# with the scans though the area is the same.
_MAX_BLOCK_BYTES = 16 << 20


class GridCache:
    """Correlation grids kept between matches, extended scan by scan instead of rebuilt.

    The sequential matcher's reference set (the running scans) and a near
    chain change by a scan or two from one kept scan to the next, while
    smearing them costs as much as the search. An entry holds a grid, the
    nodes drawn into it and the bounding box of all their points (``ext``,
    including points that fell outside the grid). A request for a node set
    which differs from the entry only by nodes to add, and by at most
    ``max_extra`` nodes drawn but no longer asked for, smears just the new
    nodes, provided every reference point the query can reach (the part of
    ``ext`` inside the query's box) lies in the grid. Cells outside a grid
    read as empty, exactly as empty cells do, so the grid need only hold the
    reference points the query can reach: it is sized by the points' extent
    plus ``margin`` (clipped to the query's box plus ``query_margin``), not by the query's reach,
    and a robot moving along its reference scans rarely needs a new one.
    The grid is thus a superset of the asked-for scans by at most
    ``max_extra`` neighbouring scans (Karto rebuilds it every time; the
    difference is a slightly longer buffer). ``invalidate()`` (after an
    optimisation moved the nodes) drops everything.
    """

    def __init__(self, matcher: CorrelativeMatcher, points_of, *, margin: float = 3.0,
                 max_extra: int = 10, max_entries: int = 8, query_margin: float = 10.0) -> None:
        self.matcher = matcher
        self.points_of = points_of  # node -> (world points (N, 2), sigmas (N,))
        self.margin = float(margin)
        self.query_margin = float(query_margin)
        self.max_extra = int(max_extra)
        self.max_entries = int(max_entries)
        self.draw_margin = 1.0  # m drawn beyond a request's box (see materialize)
        self._entries: list[dict] = []
        # Per node: bounding box (lo x, lo y, hi x, hi y) of its points, its widest smear's sigma and its one sigma
        # (see _node_stats).
        self._box = np.zeros((0, 6))
        self._known = np.zeros(0, dtype=bool)
        # Each node's share of a bound grid (see bound()), its blocks' rows, columns and values in
        # three growing columns; a node's [start, end) in them, or -1 until computed.
        self._block_store = (np.zeros(0, np.int32), np.zeros(0, np.int32), np.zeros(0, np.uint8))  # int32: half the bytes
        self._block_used = 0
        self._block_span = np.full((0, 2), -1, np.int64)
        self.builds = 0  # entries made (book-keeping; a pruned request may never draw its grid)
        self.extensions = 0
        self.draws = 0  # grids actually drawn
        self.smeared = 0  # points smeared into grids (book-keeping)
        self.kept = 0  # entries kept across an optimisation (see invalidate)
        # A new entry's grid starts as a copy of a drawn entry's holding most of its scans (see
        # materialize); False draws every new grid afresh (the same grids, tested).
        self.derive = True
        self.derived = 0  # new grids started from a drawn one
        self._epoch = 0  # optimisations seen: a grid drawn before one holds scans at old poses

    def release(self) -> None:
        """Forget everything and give the memory back (the run is over: its map and outputs need it)."""
        self.invalidate()
        self._block_store = tuple(np.zeros(0, col.dtype) for col in self._block_store)

    def invalidate(self, moved=None) -> None:
        """Forget grids drawn at poses that have changed: all of them, or those holding a ``moved`` node.

        ``moved`` (bool per node; nodes past its end count as moved) lets the caller keep the
        entries whose scans all moved less than it tolerates: their grids and bounds stay as
        drawn, scans added later are drawn at their new poses.
        """
        self._epoch += 1
        if moved is None:
            self._entries.clear()
            self._known[:] = False
            self._block_span[:] = -1
            self._block_used = 0
            return
        moved = np.asarray(moved, dtype=bool)

        def stale(n: int) -> bool:
            return n >= moved.size or bool(moved[n])

        keep = [e for e in self._entries if not any(stale(n) for n in e["nodes"])]
        self.kept += len(keep)
        self._entries[:] = keep
        k = min(moved.size, self._known.size)
        self._known[:k] &= ~moved[:k]
        self._known[k:] = False
        self._keep_blocks(~moved)

    def _extent(self, nodes) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
        """Bounding box of the nodes' points and their largest smear reach (:meth:`CorrelativeMatcher.smear_reach`)."""
        if len(nodes) == 1 and isinstance(nodes, list):
            # One node (a kept scan joining an entry): its own box, without the reductions below.
            n = int(nodes[0])
            if n < self._known.size and self._known[n]:
                b = self._box[n]
                return b[:2].copy(), b[2:4].copy(), self.matcher.smear_reach(float(b[4]))
        idx = np.asarray(nodes, dtype=np.int64)
        if idx.size == 0:
            return np.full(2, np.inf), np.full(2, -np.inf), self.matcher.smear_reach(0.0)
        top, unknown = _unknown_nodes(self._known, idx)  # idx.max() + 1, and the nodes without a box yet
        if top > self._known.size:
            self._known = grown(self._known, top)
            self._box = grown(self._box, self._known.size)
        # Each node's box is computed once (until the next invalidate), the rest is array work.
        for n in unknown.tolist():
            pts, sig = self.points_of(n)
            _node_stats(pts, sig, self._box[n])
            self._known[n] = True
        # One compiled pass over the nodes' boxes (min and max are exact in any order).
        out = _boxes_extent(self._box, idx)
        return out[0:2], out[2:4], self.matcher.smear_reach(float(out[4]))

    def _sigma_of(self, nodes) -> float | None:
        """The one sigma of every point of these nodes (as :func:`_uniform` of their sigmas; after :meth:`_extent`)."""
        ok, u = _boxes_sigma(self._box, np.asarray(nodes, dtype=np.int64))
        return float(u) if ok else None

    def get(self, nodes, lo: NDArray[np.float64], hi: NDArray[np.float64]) -> tuple[NDArray[np.uint8], float, float]:
        """The grid of (a superset of) ``nodes`` holding every point a query inside (lo, hi) can reach."""
        return self.materialize(self.reserve(nodes, lo, hi), lo, hi)

    def reserve(self, nodes, lo: NDArray[np.float64], hi: NDArray[np.float64], *, max_extra: int | None = None) -> dict:
        """The entry :meth:`get` would return, with its book-keeping done but its smearing deferred.

        Which entry serves a request, and which nodes it then holds, depend only on
        earlier requests, never on whether their grids were drawn: a caller that can
        tell from the entry's points alone that it need not match (:meth:`bound`)
        leaves the cache exactly as :meth:`get` would, so later matches read the same
        grids. :meth:`materialize` draws what is pending (max-combining is
        order-free, so the grid equals the one drawn at once).
        """
        wanted = set(nodes.tolist() if isinstance(nodes, np.ndarray) else nodes)
        extra = self.max_extra if max_extra is None else int(max_extra)  # a caller may accept a looser superset
        if not wanted:
            wmin, wmax = 0, -1
        elif type(nodes) is range and nodes.step == 1:
            wmin, wmax = nodes[0], nodes[-1]  # a range's least and most without a pass over it
        else:
            wmin, wmax = min(wanted), max(wanted)
        lx, ly, hx, hy = float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])
        for k, e in enumerate(self._entries):
            if e["span"][1] < wmin or e["span"][0] > wmax:
                continue  # no node in common (a cheap test first: up to 32 entries per request)
            have = e["nodes"]
            if have.isdisjoint(wanted):
                continue  # nothing in common
            miss = wanted - have
            if len(have) - (len(wanted) - len(miss)) > extra:  # drawn but not asked for: len(have - wanted)
                continue
            missing = sorted(miss)
            if missing:
                xlo, xhi, reach = self._extent(missing)
                xlo = np.minimum(xlo, e["ext_lo"])
                xhi = np.maximum(xhi, e["ext_hi"])
                reach = max(reach, e["reach"])
            else:  # what _extent of nothing (inf, -inf, 2 cells) leaves the entry's at
                xlo, xhi, reach = e["ext_lo"], e["ext_hi"], e["reach"]
            # The reference points (with their smear) the query can reach must lie in the grid
            # (in Python floats: the same comparisons as on the 2-vectors, without numpy's per-call cost).
            nlx, nly = max(lx, float(xlo[0]) - reach), max(ly, float(xlo[1]) - reach)
            nhx, nhy = min(hx, float(xhi[0]) + reach), min(hy, float(xhi[1]) + reach)
            empty = nlx > nhx or nly > nhy
            if not empty and not (nlx >= e["lo"][0] and nly >= e["lo"][1] and nhx <= e["hi"][0] and nhy <= e["hi"][1]):
                continue
            if missing:
                # Repeated cells are skipped only while every point drawn has had one sigma.
                same = e["sigma"] is not None and self._sigma_of(missing) == e["sigma"]
                if not same:
                    e["sigma"] = None
                e["order"].extend(missing)
                have.update(missing)
                e["span"] = (min(e["span"][0], missing[0]), max(e["span"][1], missing[-1]))
                e["ext_lo"], e["ext_hi"], e["reach"] = xlo, xhi, reach
                self.extensions += 1
            self._entries.insert(0, self._entries.pop(k))
            return e
        order_nodes = sorted(wanted)
        donor = self._donor(wanted, wmin, wmax) if self.derive else None
        xlo, xhi, reach = self._extent(order_nodes)
        # Room to grow by ``margin`` around the points (the next scans extend them), but never
        # far beyond the query's reach (a long buffer in open space would make a huge grid).
        blo = np.maximum(lo - self.query_margin, xlo - reach - self.margin)
        bhi = np.minimum(hi + self.query_margin, xhi + reach + self.margin)
        ox, oy, rows, cols = self.matcher.grid_geometry(None, blo, bhi)
        res = self.matcher.resolution
        e = {"grid": None, "box": (blo, bhi), "nodes": wanted, "lo": np.array([ox, oy]),
             "hi": np.array([ox + (cols - 1) * res, oy + (rows - 1) * res]),
             "ext_lo": xlo, "ext_hi": xhi, "reach": reach, "sigma": self._sigma_of(order_nodes),
             "parts": [], "order": list(order_nodes),
             "span": (order_nodes[0], order_nodes[-1]) if order_nodes else (0, -1),  # least and most node
             "epoch": self._epoch, "donor": donor}
        self._entries.insert(0, e)
        self._evict(e)
        self.builds += 1
        return e

    def _evict(self, keep: dict) -> None:
        """Drop the least recently used entries beyond ``max_entries`` or _MAX_BYTES of drawn grids."""
        kept, total = [], 0
        for k, x in enumerate(self._entries):
            size = x["grid"][0].nbytes if x["grid"] is not None else 0
            if x is keep or k == 0 or (len(kept) < self.max_entries and total + size <= _MAX_BYTES):
                kept.append(x)
                total += size
        if len(kept) == len(self._entries):
            return
        self._entries[:] = kept
        # An entry not drawn yet keeps its donor only while the donor is cached (memory).
        live = {id(x) for x in self._entries}
        for x in self._entries:
            if x.get("donor") is not None and id(x["donor"]) not in live:
                x["donor"] = None

    def _donor(self, wanted: set, wmin: int, wmax: int) -> dict | None:
        """A drawn entry of this epoch whose drawn scans are at least half of ``wanted`` (the most shared), or None."""
        best, most = None, (len(wanted) + 1) // 2 - 1
        for e in self._entries:
            if e["grid"] is None or not e["n_drawn"] or e["epoch"] != self._epoch:
                continue
            if e["span"][1] < wmin or e["span"][0] > wmax:
                continue
            common = len(wanted.intersection(e["order"][: e["n_drawn"]]))
            if common > most:
                best, most = e, common
        return best

    def _derive(self, e: dict, new) -> bool:
        """Start the new entry's grid from its donor's (see :func:`_derive_grid`) and draw the rest; False if it cannot."""
        d = e.pop("donor", None)
        if d is None or d["epoch"] != self._epoch or d["epoch"] != e["epoch"] or d["grid"] is None:
            return False
        res = self.matcher.resolution
        g, ox, oy = e["grid"]
        sg, sox, soy = d["grid"]
        oc = int(round((sox - ox) / res))
        orow = int(round((soy - oy) / res))
        m = e["reach"] + 2.0 * res
        # The donor's exact cells (inside its drawn box), clipped to the new grid and its box plus the reach.
        dlo, dhi = d["drawn"]
        c0 = max(int(math.floor((dlo[0] - sox) / res)) + 1, -oc, int(math.floor((new[0][0] - m - sox) / res)))
        r0 = max(int(math.floor((dlo[1] - soy) / res)) + 1, -orow, int(math.floor((new[0][1] - m - soy) / res)))
        c1 = min(int(math.floor((dhi[0] - sox) / res)) - 1, g.shape[1] - 1 - oc, sg.shape[1] - 1,
                 int(math.floor((new[1][0] + m - sox) / res)))
        r1 = min(int(math.floor((dhi[1] - soy) / res)) - 1, g.shape[0] - 1 - orow, sg.shape[0] - 1,
                 int(math.floor((new[1][1] + m - soy) / res)))
        c0, r0 = max(c0, 0), max(r0, 0)
        drawn = set(d["order"][: d["n_drawn"]])
        parts = self._parts(e)
        px, py, sig = self._columns(e, 0, len(parts), like=d)
        kept = np.repeat(np.array([n in drawn for n in e["order"]], dtype=np.bool_), np.diff(e["starts"]))
        # The donor's drawn scans the new entry does not hold, from the donor's columns.
        dx, dy, ds = self._columns(d, 0, d["n_drawn"])
        dst = d["starts"]
        gone = [(dst[k], dst[k + 1]) for k, n in enumerate(d["order"][: d["n_drawn"]]) if n not in e["nodes"]]
        if len(gone) == 1:
            xpx, xpy, xsig = dx[gone[0][0]:gone[0][1]], dy[gone[0][0]:gone[0][1]], ds[gone[0][0]:gone[0][1]]
        elif gone:
            xpx = np.concatenate([dx[a:b] for a, b in gone])
            xpy = np.concatenate([dy[a:b] for a, b in gone])
            xsig = np.concatenate([ds[a:b] for a, b in gone])
        else:
            xpx, xpy, xsig = np.zeros(0), np.zeros(0), np.zeros(0)
        ok, todo = _derive_grid(g, ox, oy, sg, sox, soy, res, oc, orow, r0, r1, c0, c1, px, py, sig, kept,
                                xpx, xpy, xsig, new[0][0] - m, new[0][1] - m, new[1][0] + m, new[1][1] + m)
        if not ok:
            return False
        if todo.size:
            _smear(g, ox, oy, res, *_take3(px, py, sig, todo), False)
            self.smeared += int(todo.size)
        # A full cell (a kernel's centre) no longer means its whole kernel is drawn (the clearing may
        # have cut it), so repeated cells are never skipped in this grid.
        e["sigma"] = None
        self.derived += 1
        return True

    @staticmethod
    def has_grid(e: dict) -> bool:
        """Whether the entry (from :meth:`reserve`) has its grid: :meth:`materialize` drew it once at least."""
        return e["grid"] is not None

    def materialize(self, e: dict, lo: NDArray[np.float64], hi: NDArray[np.float64]) -> tuple[NDArray[np.uint8], float, float]:
        """The entry's grid, drawn where a query inside (lo, hi) can read it.

        A cell holds its final value once every point whose smear reaches it is drawn. The
        entry keeps the box where that holds (``drawn``) and grows it to each request plus
        ``draw_margin`` (which also covers the fine search's degree beyond the coarse angles,
        0.2 m at 12 m), drawing only the points near the part that is new, and new scans only
        inside it: a chain's grid is drawn where its matches look, not over all its scans.
        Max-combining is order-free, so every cell a match reads equals the grid drawn at once.
        """
        res = self.matcher.resolution
        grid = e["grid"]
        if grid is None:
            blo, bhi = e["box"]
            ox, oy, rows, cols = self.matcher.grid_geometry(None, blo, bhi)
            grid = e["grid"] = (np.zeros((rows, cols), np.uint8), ox, oy)
            e["drawn"] = None
            e["n_drawn"] = 0
            self.draws += 1
            if any(x is e for x in self._entries):
                self._evict(e)
        old = e["drawn"]
        parts = self._parts(e)
        # (Python floats: the same comparisons as np.all on the 2-vectors, without its per-call cost.)
        inside = old is not None and (float(lo[0]) >= float(old[0][0]) and float(lo[1]) >= float(old[0][1])
                                      and float(hi[0]) <= float(old[1][0]) and float(hi[1]) <= float(old[1][1]))
        if inside and e["n_drawn"] == len(parts):
            return grid
        new = old if inside else (lo - self.draw_margin, hi + self.draw_margin)
        if old is not None and not inside:
            new = (np.minimum(new[0], old[0]), np.maximum(new[1], old[1]))
        # A point further than its smear's reach (plus a cell's rounding) from a box draws nothing in it.
        m = e["reach"] + 2.0 * res
        same = e["sigma"] is not None  # one sigma for every point: repeated cells can be skipped
        g, ox, oy = grid
        if old is None and e.get("donor") is not None and self._derive(e, new):
            e["drawn"] = (np.asarray(new[0], dtype=np.float64), np.asarray(new[1], dtype=np.float64))
            e["n_drawn"] = len(parts)
            e["drawn_reach"] = m
            return grid
        e.pop("donor", None)  # drawn without it: let its grid go
        if old is not None and not inside and e["n_drawn"]:
            px, py, sig = self._columns(e, 0, e["n_drawn"])
            # The points drawn before are those within the old box plus the reach of then (scans
            # added since can have widened it): the rest of the old scans' points near the new box.
            m_old = e["drawn_reach"]
            keep = _inside_not(px, py, new[0][0] - m, new[0][1] - m, new[1][0] + m, new[1][1] + m,
                               old[0][0] - m_old, old[0][1] - m_old, old[1][0] + m_old, old[1][1] + m_old)
            if keep.size:
                _smear(g, ox, oy, res, *_take3(px, py, sig, keep), same)
                self.smeared += int(keep.size)
        if e["n_drawn"] < len(parts):
            px, py, sig = self._columns(e, e["n_drawn"], len(parts))
            keep = _inside(px, py, new[0][0] - m, new[0][1] - m, new[1][0] + m, new[1][1] + m)
            if keep.size:
                _smear(g, ox, oy, res, *_take3(px, py, sig, keep), same)
                self.smeared += int(keep.size)
        e["drawn"] = (np.asarray(new[0], dtype=np.float64), np.asarray(new[1], dtype=np.float64))
        e["n_drawn"] = len(parts)
        if not inside:
            # Every scan is now drawn to here; a request inside the box draws only new scans, to the
            # reach of then, so the old ones keep the reach they were drawn with (the least counts).
            e["drawn_reach"] = m
        return grid

    def bound(self, e: dict, query_points, prior, *, stop: float = 2.0, mark: float | None = None,
              matcher: CorrelativeMatcher | None = None) -> float:
        """:meth:`CorrelativeMatcher.response_bound` of a match on the entry's grid, drawn or not.

        The entry keeps its bound grid and extends it as scans are added, as it does the
        correlation grid. Each scan's share (its blocks in a lattice of origin 0, a few hundred)
        is computed once per scan until :meth:`invalidate`, so a new entry costs a scatter of
        those, not a smear of every point. The lattice differs from the correlation grid's by at
        most a cell's rounding, which the bound's reach allows for. ``matcher``: the match's own
        (the cache's by default; another window or angle offset at the same resolution and smear).
        """
        m = self.matcher
        searcher = matcher or m
        res = m.resolution
        b = _BOUND_BLOCK
        if e.get("pooled") is None:
            row0 = int(math.floor(float(e["lo"][1]) / res)) // b - 1
            col0 = int(math.floor(float(e["lo"][0]) / res)) // b - 1
            rows = int(math.floor(float(e["hi"][1]) / res)) // b + 2 - row0
            cols = int(math.floor(float(e["hi"][0]) / res)) // b + 2 - col0
            e["pooled"] = (np.zeros((rows, cols), np.uint8), row0, col0)
            e["pooled_nodes"] = 0
        pooled, row0, col0 = e["pooled"]
        order = e["order"]
        if e["pooled_nodes"] < len(order):
            nodes = np.asarray(order[e["pooled_nodes"]:], dtype=np.int64)
            self._ensure_blocks(nodes)
            _scatter_max_nodes(pooled, *self._block_store, self._block_span, nodes, row0, col0)
            e["pooled_nodes"] = len(order)
            e["pooled_tables"] = {}  # the bound grid changed: its sparse table is built again
        return searcher.pooled_bound(pooled, col0 * b * res, row0 * b * res, query_points, prior, stop=stop,
                                     tables=e.setdefault("pooled_tables", {}), mark=mark)

    def _ensure_blocks(self, nodes: NDArray[np.int64]) -> None:
        """Compute the bound-grid blocks of those ``nodes`` that have none yet (once per node until invalidated)."""
        self._block_span = grown(self._block_span, int(nodes.max()) + 1, fill=-1)
        res, default = self.matcher.resolution, float(self.matcher.smear_deviation)
        missing = nodes[self._block_span[nodes, 0] < 0]
        row_bytes = sum(col.itemsize for col in self._block_store)
        if missing.size and self._block_used * row_bytes > _MAX_BLOCK_BYTES:
            keep = np.zeros(self._block_span.shape[0], dtype=np.bool_)
            keep[nodes] = True
            self._keep_blocks(keep)  # a pure cache: the dropped nodes' blocks are the same when computed again
        for n in missing.tolist():
            pts, sig = self.points_of(n)
            # _node_blocks of the point columns at the largest sigma (the default when none), in one compiled call.
            got = _node_blocks_of(np.asarray(pts, dtype=np.float64), np.asarray(sig, dtype=np.float64), default, res,
                                  _BOUND_BLOCK)
            a = self._block_used
            b = a + got[0].shape[0]
            if b > self._block_store[0].shape[0]:
                self._block_store = tuple(grown(col, b) for col in self._block_store)
            for col, part in zip(self._block_store, got):
                col[a:b] = part
            self._block_span[n] = (a, b)
            self._block_used = b

    def _keep_blocks(self, keep: NDArray[np.bool_]) -> None:
        """Keep the bound-grid blocks of the nodes in ``keep`` only (nodes past its end are dropped); compact the store."""
        span = self._block_span
        live = np.flatnonzero(span[: keep.size, 0] >= 0)
        live = live[keep[live]]
        starts, lengths = span[live, 0], span[live, 1] - span[live, 0]
        offsets = np.cumsum(lengths) - lengths
        total = int(lengths.sum())
        idx = np.repeat(starts - offsets, lengths) + np.arange(total)
        self._block_store = tuple(col[idx] for col in self._block_store)
        span[:] = -1
        span[live, 0] = offsets
        span[live, 1] = offsets + lengths
        self._block_used = total

    def _parts(self, e: dict) -> list:
        """Per node of the entry, its (world points, sigmas), fetched when first needed."""
        parts, order = e["parts"], e["order"]
        if len(parts) < len(order):
            parts.extend(map(self.points_of, order[len(parts):]))
        return parts

    def _columns(self, e: dict, k0: int, k1: int, like: dict | None = None):
        """x, y and sigma (contiguous, read-only use) of the points of the entry's nodes ``order[k0:k1]``.

        The entry keeps its nodes' points as the three rows of one growing store (``starts``: where each node's
        begin), filled as :meth:`_parts` fetches them, so a range of nodes is a slice, not a copy.
        """
        parts = e["parts"] if len(e["parts"]) >= k1 else self._parts(e)
        cols = e.get("cols")
        if cols is None:
            cols = e["cols"] = np.empty((3, 0))  # rows x, y, sigma: each row's slice is contiguous
            e["starts"] = [0]
        starts = e["starts"]
        done = len(starts) - 1
        if done < len(parts):
            new = parts[done:]
            a = starts[-1]
            size = a
            for q in new:
                size += q[0].shape[0]
                starts.append(size)
            if size > cols.shape[1]:
                # Doubling, as grown() does along rows; only the filled columns are copied (the rest is never read).
                wider = np.empty((3, max(size, 2 * cols.shape[1])))
                wider[:, :a] = cols[:, :a]
                cols = e["cols"] = wider
            # The new nodes' points written straight into the rows (no concatenated copy first).
            if like is not None and done == 0 and like.get("cols") is not None and len(new) > 1:
                _copy_like(cols, new, like)  # runs of the same node arrays copied from ``like``'s rows
            elif len(new) == 1:
                cols[0:2, a:size] = new[0][0].T
                cols[2, a:size] = new[0][1]
            else:
                np.concatenate([q[0].T for q in new], axis=1, out=cols[0:2, a:size])
                np.concatenate([q[1] for q in new], out=cols[2, a:size])
        a, b = starts[k0], starts[k1]
        return cols[0, a:b], cols[1, a:b], cols[2, a:b]


def _copy_like(cols, parts, like: dict) -> None:
    """Fill ``cols`` (3 rows) with the points of ``parts`` (per node (points, sigmas)), one node after another.

    A run of parts that are the very arrays (the same objects) of consecutive parts of ``like``, another
    entry whose rows already hold them, is copied from ``like``'s rows in one slice; any other part is
    written from its arrays. The values are the ones writing every part from its arrays gives.
    """
    lp, lst, lcols = like["parts"], like["starts"], like["cols"]
    nl = len(lst) - 1  # like's parts held in its rows
    where = {id(q[0]): j for j, q in enumerate(lp[:nl])}
    pos, k, n = 0, 0, len(parts)
    while k < n:
        pts, sig = parts[k]
        j = where.get(id(pts))
        if j is not None and lp[j][0] is pts and lp[j][1] is sig:
            r = 1
            while k + r < n and j + r < nl and lp[j + r][0] is parts[k + r][0] and lp[j + r][1] is parts[k + r][1]:
                r += 1
            s0, s1 = lst[j], lst[j + r]
            cols[:, pos:pos + s1 - s0] = lcols[:, s0:s1]
            pos += s1 - s0
            k += r
        else:
            m = pts.shape[0]
            cols[0:2, pos:pos + m] = pts.T
            cols[2, pos:pos + m] = sig
            pos += m
            k += 1


@njit(cache=True)
def _take3(px, py, sig, idx):
    """``px[idx], py[idx], sig[idx]`` (new contiguous arrays) in one compiled pass."""
    n = idx.shape[0]
    ox = np.empty(n, px.dtype)
    oy = np.empty(n, py.dtype)
    os_ = np.empty(n, sig.dtype)
    for k in range(n):
        i = idx[k]
        ox[k] = px[i]
        oy[k] = py[i]
        os_[k] = sig[i]
    return ox, oy, os_
