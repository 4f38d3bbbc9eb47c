"""The matcher's speed paths change no result: the response bound, lazily drawn cache grids, the fused response pass."""

from __future__ import annotations

import math

import numpy as np
import pytest

from slam2d.core import se2
from slam2d.matching.correlative import CorrelativeMatcher, smear_points
from slam2d.matching.correlative_search import _BOUND_BLOCK, _range_max, _range_max_levels, _responses
from slam2d.matching.grid_cache import GridCache


def _walls(rng, n_walls=8, extent=6.0, step=0.015):
    """Random straight walls (a cluttered room) as points ~1.5 cm apart."""
    pts = []
    for _ in range(n_walls):
        a = rng.uniform(-extent, extent, 2)
        b = a + rng.uniform(-4.0, 4.0, 2)
        n = max(2, int(np.linalg.norm(b - a) / step))
        pts.append(a + (b - a) * np.linspace(0.0, 1.0, n)[:, None])
    return np.vstack(pts)


def _scene(seed):
    rng = np.random.default_rng(seed)
    world = _walls(rng)
    truth = np.array([rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), rng.uniform(-math.pi, math.pi)])
    # The query sees part of the world (a subset of walls, or other walls when seed is odd: out of view).
    seen = _walls(rng) if seed % 2 else world[rng.random(world.shape[0]) < 0.6][::3]
    q = se2.transform_points(se2.inverse(truth), seen) + rng.normal(0.0, 0.005, (seen.shape[0], 2))
    prior = truth + np.array([rng.uniform(-0.12, 0.12), rng.uniform(-0.12, 0.12), rng.uniform(-0.3, 0.3)])
    return world, q, prior


@pytest.mark.parametrize("seed", range(12))
def test_bound_is_never_below_the_response(seed):
    world, q, prior = _scene(seed)
    m = CorrelativeMatcher()
    sig = np.full(world.shape[0], 0.03)
    bound = m.response_bound(world, sig, q, prior)
    for penalize in (False, True):
        r = m.match(world, sig, q, prior, penalize=penalize, refine=True)
        assert r.response <= bound + 1e-12, (seed, penalize, r.response, bound)
    # The same through a cache entry (its own lattice), drawn or not.
    cache = GridCache(m, lambda i: (world, sig))
    lo, hi = m.search_box(q, prior)
    e = cache.reserve([0], lo, hi)
    assert cache.bound(e, q, prior) == pytest.approx(bound, abs=0.05)
    assert m.match(None, None, q, prior, penalize=False, grid=cache.materialize(e, lo, hi)).response <= cache.bound(
        e, q, prior) + 1e-12
    # Out-of-view queries (odd seeds) are what it is for: the bound prunes them well below 1.
    if seed % 2:
        assert bound < 0.9


def test_bound_prunes_a_query_from_another_place_and_keeps_a_true_match():
    world, q, prior = _scene(0)
    m = CorrelativeMatcher()
    sig = np.full(world.shape[0], 0.03)
    far = np.array([prior[0] + 40.0, prior[1], prior[2]])
    assert m.response_bound(world, sig, q, far) == 0.0
    r = m.match(world, sig, q, prior, penalize=False)
    assert r.response > 0.5 and m.response_bound(world, sig, q, prior) >= r.response
    # With an early stop the answer only says "at least the stop".
    assert m.response_bound(world, sig, q, prior, stop=0.3) >= 0.3


def test_pooled_grid_equals_max_pooling_the_drawn_grid():
    rng = np.random.default_rng(7)
    world = _walls(rng, extent=2.0)
    m = CorrelativeMatcher()
    sig = np.full(world.shape[0], 0.03)
    lo, hi = world.min(axis=0) - 0.5, world.max(axis=0) + 0.5
    grid, ox, oy = m.correlation_grid(world, sig, lo, hi, clip=False)
    pooled = m.pooled_grid(world, sig, ox, oy, *grid.shape)
    b = _BOUND_BLOCK
    rows, cols = grid.shape
    padded = np.zeros((pooled.shape[0] * b, pooled.shape[1] * b), np.uint8)
    padded[:rows, :cols] = grid
    want = padded.reshape(pooled.shape[0], b, pooled.shape[1], b).max(axis=(1, 3))
    assert np.array_equal(pooled, want)


def test_range_max_equals_a_plain_max():
    rng = np.random.default_rng(8)
    pooled = rng.integers(0, 256, (37, 45)).astype(np.uint8)
    table = _range_max_levels(pooled, 4)
    for _ in range(300):
        r0, c0 = rng.integers(0, 37), rng.integers(0, 45)
        r1, c1 = rng.integers(r0, 37), rng.integers(c0, 45)
        assert _range_max(table, r0, r1, c0, c1) == pooled[r0 : r1 + 1, c0 : c1 + 1].max()


def test_lazily_drawn_cache_grid_equals_the_whole_grid_where_requests_read():
    rng = np.random.default_rng(9)
    parts = [_walls(rng, n_walls=3, extent=8.0) for _ in range(6)]
    sig = [np.full(len(p), 0.03) for p in parts]
    m = CorrelativeMatcher()
    cache = GridCache(m, lambda i: (parts[i], sig[i]))
    q = _walls(rng, n_walls=3, extent=2.0)[::4]
    priors = [np.array([-3.0, -2.0, 0.2]), np.array([-1.0, 0.0, 0.2]), np.array([2.0, 1.5, -0.4])]
    nodes = [[0, 1, 2], [0, 1, 2, 3], [0, 1, 2, 3, 4, 5]]
    for prior, ns in zip(priors, nodes):
        lo, hi = m.search_box(q, prior)
        e = cache.reserve(ns, lo, hi)
        g, ox, oy = cache.materialize(e, lo, hi)
        rows, cols = g.shape
        box_hi = np.array([ox + (cols - 1) * m.resolution, oy + (rows - 1) * m.resolution])
        pts = np.vstack([parts[i] for i in sorted(e["nodes"])])
        whole, wx, wy = m.correlation_grid(pts, np.full(len(pts), 0.03), np.array([ox, oy]), box_hi, clip=False)
        assert (wx, wy) == (ox, oy)
        # Every cell of the request's box (and the margin) equals the grid drawn at once ...
        r0, c0 = (np.floor((lo - cache.draw_margin - [ox, oy]) / m.resolution)).astype(int)
        r1, c1 = (np.floor((hi + cache.draw_margin - [ox, oy]) / m.resolution)).astype(int)
        c0, r0 = max(r0, 0), max(c0, 0)  # (x, y) -> (col, row)
        c1, r1 = min(r1, cols - 1), min(c1, rows - 1)
        assert np.array_equal(g[r0 : r1 + 1, c0 : c1 + 1], whole[r0 : r1 + 1, c0 : c1 + 1])
        # ... so the match is the same.
        a = m.match(None, None, q, prior, grid=(g, ox, oy))
        b = m.match(None, None, q, prior, grid=(whole, wx, wy))
        assert np.array_equal(a.pose, b.pose) and a.response == b.response
        assert np.array_equal(a.covariance, b.covariance)
    assert cache.draws <= cache.builds



def test_lazily_drawn_grid_stays_whole_when_a_wider_scan_joins_before_it_grows():
    """A scan with wider smears joins a drawn entry, then a request grows the drawn box: the old scans'
    points between the old box plus its reach of then and plus the wider reach are drawn too."""
    rng = np.random.default_rng(4)
    narrow = np.column_stack([rng.uniform(-6.0, 6.0, 4000), rng.uniform(-1.0, 1.0, 4000)])
    wide = np.array([[5.0, 0.5], [-5.0, -0.5]])
    parts = [narrow, wide]
    sig = [np.full(len(narrow), 0.01), np.full(len(wide), 0.1)]
    m = CorrelativeMatcher()
    cache = GridCache(m, lambda i: (parts[i], sig[i]))
    cache.draw_margin = 0.0
    requests = [([0], np.array([-2.0, -0.5]), np.array([0.0, 0.5])),
                ([0, 1], np.array([-2.0, -0.5]), np.array([0.0, 0.5])),
                ([0, 1], np.array([-2.0, -0.5]), np.array([0.5, 0.5]))]
    for nodes, lo, hi in requests:
        e = cache.reserve(nodes, lo, hi)
        g, ox, oy = cache.materialize(e, lo, hi)
    whole = np.zeros_like(g)
    pts = np.vstack(parts)
    smear_points(whole, ox, oy, m.resolution, pts[:, 0].copy(), pts[:, 1].copy(), np.concatenate(sig))
    c0, r0 = np.floor((lo - [ox, oy]) / m.resolution).astype(int)
    c1, r1 = np.floor((hi - [ox, oy]) / m.resolution).astype(int)
    assert np.array_equal(g[r0 : r1 + 1, c0 : c1 + 1], whole[r0 : r1 + 1, c0 : c1 + 1])

@pytest.mark.parametrize("penalize", [False, True])
def test_fused_responses_are_the_numpy_values_bit_for_bit(penalize):
    rng = np.random.default_rng(10)
    m = CorrelativeMatcher()
    na, n = 21, 17
    sums = rng.integers(0, 255 * 300, (na, n, n)).astype(np.float64)
    sums[0, 0, :3] = -1.0  # unscored poses (branch and bound)
    norm = 300 * 255.0
    offs = (np.arange(n) - 8) * 0.02
    angles = (np.arange(na) - 10) * math.radians(2.0)
    center = np.array([0.31, -7.2, 3.1])
    prior = np.array([0.27, -7.15, -3.05])  # across the +-pi seam
    raw, resp, best, ties, first = _responses(sums, norm, offs, angles, *center, *prior, penalize,
                                              m.distance_variance_penalty, m.angle_variance_penalty,
                                              m.minimum_distance_penalty, m.minimum_angle_penalty)
    want_raw = sums / norm
    if penalize:
        xs = center[0] + offs[None, None, :]
        ys = center[1] + offs[None, :, None]
        dth = np.asarray(center[2] + angles[:, None, None] - prior[2])
        dth = (dth + np.pi) % (2 * np.pi) - np.pi
        want = np.where(want_raw >= 0, want_raw * m._penalty(xs - prior[0], ys - prior[1], dth), -1.0)
    else:
        want = want_raw
    assert np.array_equal(raw, want_raw) and np.array_equal(resp, want)
    assert best == want.max()
    hits = np.argwhere(want >= want.max() - 1e-12)
    assert ties == len(hits) and tuple(hits[0]) == tuple(first)


def test_karto_skips_only_near_chains_that_cannot_link(monkeypatch):
    """Every near chain the bound keeps from matching responds below the link threshold (matched here to check)."""
    from slam2d.methods import get_method
    from slam2d.sim.simulate import SimulationParams, simulate

    frames = simulate("office", SimulationParams(duration=120.0, seed=1)).frames()
    original = GridCache.bound
    skipped = []

    def checked(self, e, q, prior, stop=2.0, mark=None, matcher=None):
        b = original(self, e, q, prior, stop=stop, mark=mark, matcher=matcher)
        if b < stop:
            lo, hi = self.matcher.search_box(q, prior)
            r = (matcher or self.matcher).match(None, None, q, prior, penalize=False, refine=True,
                                                grid=self.materialize(e, lo, hi))
            skipped.append((b, r.response, mark))
        return b

    monkeypatch.setattr(GridCache, "bound", checked)
    slam = get_method("karto")(seed=0).run(frames)
    link = slam.params.link_match_minimum_response_fine
    counters = slam.diagnostics.counters
    assert counters.get("near_skipped_bound", 0) > 0 and counters.get("near_skipped_bound_link", 0) > 0
    assert len(skipped) == counters["near_skipped_bound"] + counters["near_skipped_bound_link"]
    # With a mark the bound is only as high as its two answers need: below the mark means the response is.
    assert all(r < link and (r <= b + 1e-9 if mark is None else (b >= mark or r < mark)) for b, r, mark in skipped)
    assert any(mark is not None for _, _, mark in skipped)


def test_bound_of_nothing_is_zero():
    m = CorrelativeMatcher()
    world, q, prior = _scene(2)
    sig = np.full(world.shape[0], 0.03)
    assert m.response_bound(world, sig, np.zeros((0, 2)), prior) == 0.0
    assert m.response_bound(np.zeros((0, 2)), np.zeros(0), q, prior) == 0.0
    assert m.response_bound(world, sig, q, np.array([np.nan, 0.0, 0.0])) == 0.0


def test_cached_sparse_table_gives_the_bound_of_a_fresh_one():
    """A cache entry keeps its bound grid's sparse table between bounds (rebuilt when scans are added)."""
    rng = np.random.default_rng(3)
    parts = [_walls(rng, n_walls=3) for _ in range(4)]
    sig = [np.full(p.shape[0], 0.03) for p in parts]
    m = CorrelativeMatcher()
    cache = GridCache(m, lambda i: (parts[i], sig[i]))
    for nodes in ([0], [0], [0, 1], [0, 1, 2], [0, 1, 2], [0, 1, 2, 3]):
        for _ in range(3):
            world = np.vstack([parts[i] for i in nodes])
            prior = np.array([rng.uniform(-2, 2), rng.uniform(-2, 2), rng.uniform(-math.pi, math.pi)])
            q = se2.transform_points(se2.inverse(prior), world[::4])
            # Short and long query ranges need tables of different depths.
            q = q[np.hypot(q[:, 0], q[:, 1]) < rng.uniform(2.0, 12.0)]
            if q.shape[0] < 10:
                continue
            lo, hi = m.search_box(q, prior)
            e = cache.reserve(nodes, lo, hi)
            for stop in (0.4, 2.0):
                got = cache.bound(e, q, prior, stop=stop)
                pooled, row0, col0 = e["pooled"]
                fresh = m.pooled_bound(pooled, col0 * _BOUND_BLOCK * m.resolution, row0 * _BOUND_BLOCK * m.resolution,
                                       q, prior, stop=stop)
                assert got == fresh
    assert cache.extensions >= 2


@pytest.mark.parametrize("seed", range(6))
def test_compiled_positional_covariance_is_the_numpy_one_bit_for_bit(seed):
    """The usual case's compiled sums against the numpy code that still serves the edge case."""
    rng = np.random.default_rng(seed)
    m = CorrelativeMatcher()
    for n_steps in (17, 9, 33):
        half = n_steps // 2
        offs = (np.arange(n_steps) - half) * 0.02
        for _ in range(20):
            resp = rng.uniform(-1.0, 0.6, (21, n_steps, n_steps))
            a, i, j = rng.integers(0, 21), rng.integers(1, n_steps - 1), rng.integers(1, n_steps - 1)
            resp[a, i - 1:i + 2, j - 1:j + 2] = rng.uniform(0.62, 0.9, (3, 3))  # a peak inside the window
            best = float(resp.max())
            center = rng.normal(size=3)
            pose = center + np.array([offs[j], offs[i], 0.0])
            got = m._positional_covariance(resp, offs, center, pose, best, 0.02)
            want = m._positional_covariance_general(resp, offs, center, pose, best, 0.02)
            assert np.array_equal(got, want)


def test_compiled_pairwise_sum_is_numpys():
    from slam2d.matching.correlative_search import _pairwise_sum

    rng = np.random.default_rng(1)
    for n in (1, 5, 8, 9, 17, 128, 129, 289, 441, 1000, 5000, 100000):
        for _ in range(20):
            a = rng.normal(size=n) * 10 ** rng.uniform(-3, 3, n)
            assert 0.0 + _pairwise_sum(a, 0, n) == a.sum()


@pytest.mark.parametrize("uniform", [True, False])
def test_grid_started_from_a_drawn_one_equals_a_fresh_smear(uniform):
    """A new entry's grid copied from a drawn entry (its dropped scans cleared, the rest drawn) is the
    grid drawn afresh wherever requests read, through later scans and growing boxes too."""
    rng = np.random.default_rng(21)
    parts, sig = [], []
    for i in range(40):  # a robot walking along x, each scan seeing walls around it
        p = _walls(rng, n_walls=3, extent=3.0) + [0.25 * i, 0.0]
        parts.append(p)
        sig.append(np.full(len(p), 0.03) if uniform else rng.uniform(0.01, 0.08, len(p)))
    m = CorrelativeMatcher()
    q = _walls(rng, n_walls=2, extent=1.5)[::4]
    priors = [np.array([0.25 * i + rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0), 0.1]) for i in range(40)]
    grids = {}
    for derive in (True, False):
        cache = GridCache(m, lambda i: (parts[i], sig[i]), max_extra=3, margin=0.5)
        cache.derive = derive
        got = []
        for i in range(8, 40):
            nodes = list(range(i - 8, i))
            lo, hi = m.search_box(q, priors[i])
            e = cache.reserve(nodes, lo, hi)
            g, ox, oy = cache.materialize(e, lo, hi)
            rows, cols = g.shape
            pts = np.vstack([parts[n] for n in sorted(e["nodes"])])
            whole = np.zeros_like(g)
            smear_points(whole, ox, oy, m.resolution, pts[:, 0].copy(), pts[:, 1].copy(),
                         np.concatenate([sig[n] for n in sorted(e["nodes"])]))
            c0, r0 = np.maximum(np.floor((lo - [ox, oy]) / m.resolution).astype(int), 0)
            c1, r1 = np.floor((hi - [ox, oy]) / m.resolution).astype(int)
            c1, r1 = min(c1, cols - 1), min(r1, rows - 1)
            assert np.array_equal(g[r0 : r1 + 1, c0 : c1 + 1], whole[r0 : r1 + 1, c0 : c1 + 1])
            got.append((ox, oy, g[r0 : r1 + 1, c0 : c1 + 1].copy()))
        grids[derive] = got
        if derive:
            assert cache.derived > 0
    for (ax, ay, a), (bx, by, b) in zip(grids[True], grids[False]):
        assert (ax, ay) == (bx, by) and np.array_equal(a, b)


def test_bound_with_a_mark_answers_as_the_bound_does():
    """With ``mark`` the bound's squares are summed only as far as the caller's two comparisons need:
    below the mark, between it and ``stop``, or at ``stop``, always the same answer as the bound's."""
    from slam2d.matching.correlative import _least_total

    for x, n in ((0.4, 255.0 * 350), (0.8, 255.0 * 350), (0.8, 255.0 * 7), (0.0, 255.0), (1.3, 510.0)):
        t = _least_total(x, n)
        assert t / n >= x and (t == 0 or (t - 1) / n < x)
    rng = np.random.default_rng(11)
    m = CorrelativeMatcher()
    kinds = set()
    for seed in range(24):
        world, q, prior = _scene(seed)
        sig = np.full(world.shape[0], 0.03)
        cache = GridCache(m, lambda i, w=world, s=sig: (w, s))
        e = cache.reserve([0], *m.search_box(q, prior))
        for _ in range(3):
            # Marks around the bound itself, so that every side of them is met.
            exact = cache.bound(e, q, prior)
            for mark, stop in ((0.4, 0.8), (exact, exact + 0.05), (exact - 0.02, exact + 0.01), (exact - 0.1, exact),
                               (0.5 * exact, exact - 0.01)):
                mark = max(mark, 0.0)
                full = cache.bound(e, q, prior, stop=stop)
                got = cache.bound(e, q, prior, stop=stop, mark=mark)
                assert got <= full + 1e-15
                assert (got < mark) == (full < mark) and (got < stop) == (full < stop), (seed, mark, stop, got, full)
                kinds.add((full < mark, full < stop))
            q = q[rng.random(q.shape[0]) < 0.8]
    assert kinds >= {(True, True), (False, True), (False, False)}


@pytest.mark.parametrize("seed", range(6))
def test_cache_bound_for_a_narrower_angle_window_bounds_its_match(seed):
    """GridCache.bound with another matcher (near chains' narrower heading window, same cells and smear)
    bounds that matcher's response, and is at most the cache matcher's own bound (fewer headings)."""
    world, q, prior = _scene(seed)
    m = CorrelativeMatcher()
    narrow = m.with_window(m.search_size)
    narrow.coarse_angle_offset = math.radians(10.0)
    sig = np.full(world.shape[0], 0.03)
    cache = GridCache(m, lambda i: (world, sig))
    lo, hi = m.search_box(q, prior)
    e = cache.reserve([0], lo, hi)
    wide_bound = cache.bound(e, q, prior)
    bound = cache.bound(e, q, prior, matcher=narrow)
    assert bound <= wide_bound + 1e-12
    r = narrow.match(None, None, q, prior, penalize=False, refine=True, grid=cache.materialize(e, lo, hi))
    assert r.response <= bound + 1e-12, (seed, r.response, bound)


def test_bound_blocks_survive_a_partial_invalidate_as_computed():
    """Each node's bound-grid blocks live in one compacted store: invalidate(moved) keeps the unmoved
    nodes' blocks as they were computed (at their old poses, as their kept grids are) and computes the
    moved ones' again, so a new entry's bound grid is the scatter of exactly those blocks."""
    from slam2d.matching.correlative_search import _node_blocks

    rng = np.random.default_rng(7)
    parts = [_walls(rng, n_walls=2) for _ in range(5)]
    sig = [np.full(p.shape[0], 0.03) for p in parts]
    m = CorrelativeMatcher()
    cache = GridCache(m, lambda i: (parts[i], sig[i]))

    def blocks(p):
        return _node_blocks(np.ascontiguousarray(p[:, 0]), np.ascontiguousarray(p[:, 1]), 0.03, m.resolution,
                            _BOUND_BLOCK)

    def pooled_of(nodes, want):
        q = parts[nodes[0]][::5]
        lo, hi = m.search_box(q, np.zeros(3))
        e = cache.reserve(nodes, lo, hi, max_extra=0)
        cache.bound(e, q, np.zeros(3))
        pooled, row0, col0 = e["pooled"]
        expect = np.zeros_like(pooled)
        for r, c, v in want:
            inside = (r - row0 >= 0) & (r - row0 < pooled.shape[0]) & (c - col0 >= 0) & (c - col0 < pooled.shape[1])
            np.maximum.at(expect, (r[inside] - row0, c[inside] - col0), v[inside])
        return pooled, expect

    before = [blocks(p) for p in parts]
    got, expect = pooled_of([0, 1, 2, 3, 4], before)
    assert np.array_equal(got, expect) and got.any()
    # Nodes 1 and 3 move; the mask covers four nodes, so node 4 counts as moved too.
    moved = [p + np.array([0.7, -0.4]) for p in parts]
    parts[1], parts[3], parts[4] = moved[1], moved[3], moved[4]
    parts[0] = parts[0] + 0.002  # moved within tolerance: its old blocks stay
    cache.invalidate(np.array([False, True, False, True]))
    got, expect = pooled_of([0, 1, 2, 3, 4], [before[0], blocks(moved[1]), before[2], blocks(moved[3]),
                                              blocks(moved[4])])
    assert np.array_equal(got, expect)
    # A full invalidate computes every node's blocks afresh.
    cache.invalidate()
    got, expect = pooled_of([0, 1, 2, 3, 4], [blocks(p) for p in parts])
    assert np.array_equal(got, expect)
