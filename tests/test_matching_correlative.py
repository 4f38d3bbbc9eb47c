"""The correlative scan matcher: known offsets, response, covariance, branch and bound, grid cache."""

from __future__ import annotations

import math

import numpy as np
import pytest

from slam2d.core import se2
from slam2d.matching.correlative import MAX_VARIANCE, CorrelativeMatcher
from slam2d.matching.grid_cache import GridCache


def _segments(segs, step=0.02):
    pts = []
    for a, b in segs:
        a = np.asarray(a, float)
        b = np.asarray(b, float)
        n = max(2, int(np.linalg.norm(b - a) / step))
        pts.append(a + (b - a) * np.linspace(0.0, 1.0, n)[:, None])
    return np.vstack(pts)


# A room with an L-shaped obstacle: constrains x, y and heading.
ROOM = _segments([
    ((-4, -3), (4, -3)), ((4, -3), (4, 3)), ((4, 3), (-4, 3)), ((-4, 3), (-4, -3)),
    ((1, 0), (2, 0)), ((2, 0), (2, 1.5)),
])
# A straight corridor: no information along x.
CORRIDOR = _segments([((-30, -1), (30, -1)), ((-30, 1), (30, 1))])


def _query(world, truth, rng, noise=0.005, every=3):
    pts = se2.transform_points(se2.inverse(truth), world[::every])
    return pts + rng.normal(0.0, noise, pts.shape)


@pytest.mark.parametrize("offset", [(0.08, -0.05, 0.1), (-0.12, 0.1, -0.2), (0.0, 0.0, 0.0), (0.14, 0.14, 0.3)])
def test_recovers_known_offsets(offset):
    rng = np.random.default_rng(1)
    truth = np.array([0.3, -0.2, 0.15])
    q = _query(ROOM, truth, rng)
    m = CorrelativeMatcher()
    r = m.match(ROOM, None, q, truth + np.array(offset))
    assert np.hypot(*(r.pose[:2] - truth[:2])) <= 0.015
    assert abs(se2.wrap_angle(r.pose[2] - truth[2])) <= math.radians(0.3)
    assert 0.7 < r.response <= 1.0 and r.raw_response >= r.response
    cov = r.covariance
    assert np.allclose(cov, cov.T) and np.all(np.linalg.eigvalsh(cov) > 0)
    # a good match in a structured room is certain to a few centimetres and a fraction of a degree
    assert np.sqrt(cov[0, 0]) < 0.05 and np.sqrt(cov[1, 1]) < 0.05 and np.sqrt(cov[2, 2]) < math.radians(1.0)


def test_response_is_one_on_itself_and_drops_off_the_walls():
    m = CorrelativeMatcher()
    pose = np.array([0.5, 0.5, 0.0])
    q = se2.transform_points(se2.inverse(pose), ROOM)
    assert m.match(ROOM, None, q, pose).response == pytest.approx(1.0)
    # far away from anything: nothing to match
    far = m.match(ROOM, None, q + 50.0, pose)
    assert far.response == 0.0 and far.covariance[0, 0] == MAX_VARIANCE


def test_penalty_prefers_the_prior_and_outside_window_is_not_found():
    rng = np.random.default_rng(2)
    truth = np.array([0.0, 0.0, 0.0])
    q = _query(ROOM, truth, rng)
    m = CorrelativeMatcher()
    # an offset beyond the 0.3 m window cannot be recovered
    r = m.match(ROOM, None, q, truth + np.array([0.5, 0.0, 0.0]))
    assert np.hypot(*(r.pose[:2] - truth[:2])) > 0.3
    pen = m.match(ROOM, None, q, truth + [0.1, 0.0, 0.0], penalize=True)
    raw = m.match(ROOM, None, q, truth + [0.1, 0.0, 0.0], penalize=False)
    assert pen.response < raw.response


def test_corridor_covariance_is_long_along_the_corridor():
    rng = np.random.default_rng(3)
    truth = np.array([0.0, 0.0, 0.0])
    q = _query(CORRIDOR, truth, rng)
    q = q[np.abs(q[:, 0]) < 5.0]  # the laser sees 5 m of it
    r = CorrelativeMatcher().match(CORRIDOR, None, q, truth + [0.05, 0.03, 0.0], penalize=False)
    assert abs(r.pose[1] - truth[1]) < 0.015  # across: pinned
    assert r.covariance[0, 0] > 20 * r.covariance[1, 1]  # along: unknown


def test_branch_and_bound_equals_exhaustive_search():
    rng = np.random.default_rng(4)
    truth = np.array([0.3, -0.2, 0.15])
    q = _query(ROOM, truth, rng)
    for prior in (truth + [1.5, -2.0, 0.3], truth + [3.6, 2.1, -0.2]):  # the second reaches past the grid edge
        wide = CorrelativeMatcher(search_size=8.0, resolution=0.05)
        a = wide.match(ROOM, None, q, prior, penalize=False, refine=False)
        wide.branch_and_bound = False
        b = wide.match(ROOM, None, q, prior, penalize=False, refine=False)
        assert np.array_equal(a.pose, b.pose) and a.response == b.response
        assert np.allclose(a.covariance, b.covariance)
        assert a.evaluated < b.evaluated / 3  # and it does pay


def test_branch_and_bound_threshold_is_exact_when_reached_and_below_it_otherwise():
    rng = np.random.default_rng(5)
    truth = np.array([0.3, -0.2, 0.15])
    q = _query(ROOM, truth, rng)
    prior = truth + [1.5, -2.0, 0.3]
    wide = CorrelativeMatcher(search_size=8.0, resolution=0.05)
    full = wide.match(ROOM, None, q, prior, penalize=False, refine=False)
    reached = wide.match(ROOM, None, q, prior, penalize=False, refine=False, min_response=full.response - 0.05)
    assert np.array_equal(reached.pose, full.pose) and reached.response == full.response
    assert np.allclose(reached.covariance, full.covariance)
    assert reached.evaluated <= full.evaluated
    # A threshold above the best response: the search gives up with something below it, cheaply.
    missed = wide.match(ROOM, None, q, prior, penalize=False, refine=False, min_response=full.response + 0.3)
    assert missed.response < full.response + 0.3
    assert missed.evaluated < 0.8 * full.evaluated


def test_smaller_window_matcher_finds_the_same_pose_inside_it():
    rng = np.random.default_rng(6)
    truth = np.array([0.3, -0.2, 0.15])
    q = _query(ROOM, truth, rng)
    prior = truth + [0.4, -0.3, 0.1]
    wide = CorrelativeMatcher(search_size=8.0, resolution=0.05)
    narrow = wide.with_window(1.2)
    assert narrow.search_size == 1.2 and wide.search_size == 8.0
    a = wide.match(ROOM, None, q, prior, penalize=False, refine=False)
    b = narrow.match(ROOM, None, q, prior, penalize=False, refine=False)
    assert np.allclose(a.pose, b.pose) and a.response == b.response


def test_sensor_sigmas_widen_the_smear():
    m = CorrelativeMatcher()
    s = m.sigmas_for(np.array([0.0, 0.04, np.nan, 1.0]), 4)
    assert s[0] == pytest.approx(0.03) and s[1] == pytest.approx(0.05) and s[2] == pytest.approx(0.03)
    assert s[3] == pytest.approx(0.1)  # clamped to 10 cells


def test_grid_cache_extends_to_the_same_grid_as_a_fresh_build():
    m = CorrelativeMatcher()
    parts = [ROOM[i::4] for i in range(4)]
    sig = [np.full(len(p), 0.03) for p in parts]
    cache = GridCache(m, lambda i: (parts[i], sig[i]))
    lo, hi = np.array([-3.0, -2.0]), np.array([3.0, 2.0])
    cache.get([0, 1], lo, hi)
    g, ox, oy = cache.get([0, 1, 2, 3], lo, hi)  # extends the first grid
    assert cache.builds == 1 and cache.extensions == 1
    rows, cols = g.shape
    box_hi = np.array([ox + (cols - 1) * m.resolution, oy + (rows - 1) * m.resolution])
    fresh, fx, fy = m.correlation_grid(np.vstack(parts), np.concatenate(sig), np.array([ox, oy]), box_hi, clip=False)
    assert np.allclose((ox, oy), (fx, fy)) and np.array_equal(g, fresh)
    # The cached grid covers the reference points, not the query's reach: a match through it
    # equals a match that builds its own grid over the whole reach.
    prior = np.array([0.05, -0.04, 0.03])
    direct = m.match(np.vstack(parts), np.concatenate(sig), ROOM, prior)
    cached = m.match(None, None, ROOM, prior, grid=cache.get([0, 1, 2, 3], *m.search_box(ROOM, prior)))
    assert np.allclose(direct.pose, cached.pose) and direct.response == cached.response
    cache.invalidate()
    cache.get([2, 3], lo, hi)
    assert cache.builds == 2


def test_empty_and_bad_input():
    m = CorrelativeMatcher()
    r = m.match(np.zeros((0, 2)), None, ROOM[:10], np.zeros(3))
    assert r.response == 0.0 and np.all(np.diag(r.covariance) == MAX_VARIANCE)
    r = m.match(ROOM, None, np.zeros((0, 2)), np.zeros(3))
    assert r.response == 0.0
    r = m.match(ROOM, None, ROOM[:10], np.array([np.nan, 0.0, 0.0]))
    assert r.response == 0.0
    with pytest.raises(ValueError):
        CorrelativeMatcher(resolution=0.0)


def test_score_kernel_equals_a_plain_sum_for_every_step_and_at_the_grid_edges():
    from slam2d.matching.correlative_search import _score_all

    rng = np.random.default_rng(3)
    grid = rng.integers(0, 256, (60, 70)).astype(np.uint8)
    # Points inside, partly outside and wholly outside the grid.
    rows = rng.integers(-30, 80, (4, 50)).astype(np.int64)
    cols = rng.integers(-30, 90, (4, 50)).astype(np.int64)
    for step in (1, 2, 3):
        n = 7
        got = _score_all(grid, rows, cols, n, step)
        want = np.zeros((4, n, n))
        for a in range(4):
            for i in range(n):
                for j in range(n):
                    r = rows[a] + i * step
                    c = cols[a] + j * step
                    ok = (r >= 0) & (r < grid.shape[0]) & (c >= 0) & (c < grid.shape[1])
                    want[a, i, j] = grid[r[ok], c[ok]].astype(np.int64).sum()
        assert np.array_equal(got, want), step


def test_smear_skipping_repeated_cells_draws_the_same_grid():
    from slam2d.matching.correlative import smear_points

    rng = np.random.default_rng(4)
    px = rng.uniform(0.0, 1.0, 300)
    py = rng.uniform(0.0, 1.0, 300)
    px = np.concatenate([px, px + 0.001])  # the same 1 cm cells again
    py = np.concatenate([py, py + 0.001])
    sig = np.full(px.size, 0.03)
    full = np.zeros((110, 110), np.uint8)
    skipped = np.zeros((110, 110), np.uint8)
    smear_points(full, -0.05, -0.05, 0.01, px, py, sig, False)
    smear_points(skipped, -0.05, -0.05, 0.01, px, py, sig, True)
    assert np.array_equal(full, skipped)
    centres = {(int(np.floor((y + 0.05) / 0.01)), int(np.floor((x + 0.05) / 0.01))) for x, y in zip(px, py)}
    assert (full == 255).sum() == len(centres) < px.size  # only kernel centres reach the full value


def test_refining_a_loop_grid_match_recovers_what_the_coarse_angle_sampling_loses():
    # A loop-closure matcher (5 cm grid, 2 deg coarse steps); the truth lies one degree
    # from every sampled heading, so far points miss their cells in the coarse search.
    rng = np.random.default_rng(5)
    m = CorrelativeMatcher(search_size=2.0, resolution=0.05)
    truth = np.array([0.3, -0.2, 0.15])
    q = _query(ROOM, truth, rng, noise=0.002, every=2)
    prior = truth + np.array([0.1, 0.05, math.radians(1.0)])
    coarse = m.match(ROOM, None, q, prior, penalize=False, refine=False)
    refined = m.match(ROOM, None, q, prior, penalize=False, refine=True)
    assert refined.response > coarse.response + 0.05
    assert abs(se2.wrap_angle(refined.pose[2] - truth[2])) < abs(se2.wrap_angle(coarse.pose[2] - truth[2]))
    # the positional covariance is the coarse surface's either way (Karto's loop variance test)
    np.testing.assert_allclose(refined.covariance[:2, :2], coarse.covariance[:2, :2])


def test_coarse_heading_variance_is_wide_only_when_the_heading_is_ambiguous():
    rng = np.random.default_rng(6)
    m = CorrelativeMatcher()
    truth = np.array([0.0, 0.0, 0.1])
    sharp = m.match(ROOM, None, _query(ROOM, truth, rng), truth)
    assert sharp.heading_variance_coarse < math.radians(2.0) ** 2
    # A round room looks the same at every heading.
    a = np.linspace(0.0, 2.0 * np.pi, 900, endpoint=False)
    circle = np.stack([3.0 * np.cos(a), 3.0 * np.sin(a)], axis=1)
    flat = m.match(circle, None, _query(circle, truth, rng), truth)
    assert flat.heading_variance_coarse > math.radians(8.0) ** 2


@pytest.mark.parametrize("width", [1, 2, 3, 7, 8, 15, 40])
def test_max_pool_equals_the_windowed_maximum(width):
    from slam2d.matching.correlative_search import _max_pool

    rng = np.random.default_rng(width)
    grid = rng.integers(0, 256, (23, 31)).astype(np.uint8)
    want = np.array([[grid[r:r + width, c:c + width].max() for c in range(31)] for r in range(23)])
    assert np.array_equal(_max_pool(grid, width), want)


def test_a_wider_kernel_covers_a_narrower_one_at_the_same_centre():
    """What merging the points of one cell (keeping the widest sigma) relies on, over Karto's sigma range."""
    from slam2d.matching.correlative import smear_points

    res = 0.01
    sigmas = np.concatenate([np.linspace(0.5, 10.0, 400), [3.0, 3.0000001]]) * res
    half = int(np.ceil(2.0 * sigmas.max() / res))
    previous = None
    for s in np.sort(sigmas):
        grid = np.zeros((2 * half + 1, 2 * half + 1), np.uint8)
        smear_points(grid, 0.0, 0.0, res, np.array([half * res + 0.5 * res]), np.array([half * res + 0.5 * res]),
                     np.array([s]))
        if previous is not None:
            assert np.all(grid >= previous)
        previous = grid


@pytest.mark.parametrize("bands", [1, 3])
def test_points_sharing_a_cell_are_drawn_once_to_the_same_grid(bands):
    """The row sort merges the points of one cell (widest sigma kept); the grid is each point drawn alone, max-combined."""
    from slam2d.matching.correlative import smear_points
    from slam2d.matching.correlative_grid import _row_sort, smear_in_row_bands, smear_in_row_order

    rng = np.random.default_rng(7)
    px = rng.uniform(-0.2, 1.2, 400)  # some beyond the grid, whose kernels still reach it
    py = rng.uniform(-0.2, 1.2, 400)
    # The same cells again, with other sigmas (wider and narrower), in another order.
    perm = rng.permutation(px.size)
    px = np.concatenate([px, px[perm] + 0.003])
    py = np.concatenate([py, py[perm] + 0.002])
    px -= np.mod(px, 0.01) - 0.001  # every point 1 mm into its cell, so the shift stays inside it
    py -= np.mod(py, 0.01) - 0.001
    sig = rng.uniform(0.005, 0.1, px.size)
    one_by_one = np.zeros((100, 120), np.uint8)
    for k in range(px.size):
        smear_points(one_by_one, 0.0, 0.0, 0.01, px[k:k + 1], py[k:k + 1], sig[k:k + 1])
    merged = np.zeros_like(one_by_one)
    if bands == 1:
        smear_in_row_order(merged, 0.0, 0.0, 0.01, px, py, sig)
    else:
        smear_in_row_bands(merged, 0.0, 0.0, 0.01, px, py, sig, False, bands)
    assert np.array_equal(merged, one_by_one)
    sx, sy, ss, start = _row_sort(merged, 0.0, 0.0, 0.01, px, py, sig)
    cu, cv = np.floor(px / 0.01).astype(int), np.floor(py / 0.01).astype(int)
    inside = (cu >= 0) & (cu < 120) & (cv >= 0) & (cv < 100)  # each cell of the grid once
    cells = len(set(zip(cu[inside], cv[inside])))
    outside = len(set(zip(cu[~inside], cv[~inside])))  # beyond it, repeats are merged where found
    assert cells + outside <= sx.size <= cells + (~inside).sum()
    assert sx.size == start[-1] < px.size


def test_grid_cache_keeps_entries_whose_scans_did_not_move():
    """invalidate(moved): an entry holding a moved node is drawn again, the others are reused as drawn."""
    m = CorrelativeMatcher()
    parts = [ROOM[i::4].copy() for i in range(4)]
    sig = [np.full(len(p), 0.03) for p in parts]
    cache = GridCache(m, lambda i: (parts[i], sig[i]))
    lo, hi = np.array([-3.0, -2.0]), np.array([3.0, 2.0])
    g01 = cache.get([0, 1], lo, hi)[0].copy()
    cache.get([2, 3], lo, hi)
    assert cache.builds == 2
    # Nodes 0, 1 moved by 4 mm (within a 5 mm tolerance: not flagged), node 2 by more.
    parts[0] = parts[0] + 0.004
    parts[1] = parts[1] + 0.004
    parts[2] = parts[2] + 0.05
    cache.invalidate(np.array([False, False, True, False]))
    assert cache.kept == 1
    g, ox, oy = cache.get([0, 1], lo, hi)
    assert cache.builds == 2 and np.array_equal(g, g01)  # reused, not redrawn
    # The kept grid differs from a fresh draw of the moved points by at most the kernel's slope
    # times the shift plus a cell's rounding.
    rows, cols = g.shape
    box_hi = np.array([ox + (cols - 1) * m.resolution, oy + (rows - 1) * m.resolution])
    fresh, _, _ = m.correlation_grid(np.vstack(parts[:2]), np.concatenate(sig[:2]), np.array([ox, oy]), box_hi, clip=False)
    assert not np.array_equal(g, fresh)
    slope = 255.0 / (0.03 * math.sqrt(math.e))  # per metre, of a Gaussian of sigma 3 cm scaled to 255
    shift = math.hypot(0.004, 0.004) + math.sqrt(2.0) * m.resolution
    assert np.abs(g.astype(int) - fresh.astype(int)).max() <= slope * shift + 1
    # The entry holding node 2 is gone: asking for it draws a new grid with its new points.
    g2, ox2, oy2 = cache.get([2, 3], lo, hi)
    assert cache.builds == 3
    rows, cols = g2.shape
    box_hi = np.array([ox2 + (cols - 1) * m.resolution, oy2 + (rows - 1) * m.resolution])
    fresh2, _, _ = m.correlation_grid(np.vstack(parts[2:]), np.concatenate(sig[2:]), np.array([ox2, oy2]), box_hi, clip=False)
    assert np.array_equal(g2, fresh2)
    # A node the mask does not cover (added after it) counts as moved.
    cache.invalidate(np.array([False]))
    assert cache.kept == 1
    cache.get([0, 1], lo, hi)
    assert cache.builds == 4


def test_grid_cache_reserve_looser_superset_on_request():
    """reserve(max_extra=k) reuses an entry holding up to k scans not asked for; the default allowance does not."""
    m = CorrelativeMatcher()
    parts = [ROOM[i::16] for i in range(16)]
    sig = [np.full(len(p), 0.03) for p in parts]
    cache = GridCache(m, lambda i: (parts[i], sig[i]), max_extra=10)
    lo, hi = np.array([-3.0, -2.0]), np.array([3.0, 2.0])
    cache.get(list(range(16)), lo, hi)
    e = cache.reserve([0, 1, 2], lo, hi)  # 13 extra: a new entry
    assert cache.builds == 2 and e["nodes"] == {0, 1, 2}
    e = cache.reserve([3, 4], lo, hi, max_extra=14)  # the 16-scan entry, 14 extra
    assert cache.builds == 2 and len(e["nodes"]) == 16
    g, ox, oy = cache.materialize(e, lo, hi)
    rows, cols = g.shape
    box_hi = np.array([ox + (cols - 1) * m.resolution, oy + (rows - 1) * m.resolution])
    fresh, _, _ = m.correlation_grid(np.vstack(parts), np.concatenate(sig), np.array([ox, oy]), box_hi, clip=False)
    # Drawn where a query inside (lo, hi) reads it, the superset grid equals the fresh one there.
    assert g.shape == fresh.shape and np.array_equal(g, fresh)


def test_scan_matcher_matches_as_the_matcher_on_the_nodes_points():
    """ScanMatcher: a match against nodes' scans (through its grids or not, in another window too), a reserved grid's
    match and bound, and its counters, as the matcher and its bound on the nodes' points give them."""
    from slam2d.matching.scan_matcher import ScanMatcher

    m = CorrelativeMatcher()
    parts = [ROOM[i::4] for i in range(4)]
    sig = [np.full(len(p), 0.03) for p in parts]
    box = ScanMatcher(m, lambda i: (parts[i], sig[i]))
    prior = np.array([0.05, -0.04, 0.03])
    for window in (None, m.with_window(0.2)):
        w = window or m
        direct = w.match(np.vstack(parts), np.concatenate(sig), ROOM, prior, penalize=False)
        got = box.match([0, 1, 2, 3], ROOM, prior, window=window, penalize=False, refine=True)
        assert np.array_equal(direct.pose, got.pose) and direct.response == got.response
        got = box.match_uncached([0, 1, 2, 3], ROOM, prior, window=window, penalize=False, refine=True)
        assert np.array_equal(direct.pose, got.pose) and direct.response == got.response
    assert box.stats()["builds"] == 1 and box.stats()["draws"] == 1  # (the uncached grids are not kept)
    grid = box.reserve([0, 1], *m.search_box(ROOM, prior), max_extra=0)  # not the grid of all four
    assert not grid.drawn and box.stats()["builds"] == 2 and box.stats()["draws"] == 1
    bound = grid.bound(ROOM, prior)
    assert not grid.drawn and 0.0 < bound <= 1.0
    smeared = box.points_smeared
    got = grid.match(ROOM, prior, penalize=True, refine=True)
    assert grid.drawn and box.points_smeared > smeared and got.response <= bound
    direct = m.match(np.vstack(parts[:2]), np.concatenate(sig[:2]), ROOM, prior)
    assert np.array_equal(direct.pose, got.pose) and direct.response == got.response
    box.invalidate()
    box.match([0, 1], ROOM, prior, penalize=True, refine=True)
    assert box.stats()["builds"] == 3
    box.release()


def test_coarse_search_point_order_does_not_change_the_match():
    """The coarse search's integer sums do not depend on the points' order (its chunks are interleaved
    for pruning): any order of the query gives the same match bit for bit."""
    from slam2d.matching.correlative_search import _interleaved

    rng = np.random.default_rng(4)
    truth = np.array([0.3, -0.2, 0.15])
    q = _query(ROOM, truth, rng, every=1)[::2]
    assert q.shape[0] > 64
    order = _interleaved(q)
    assert sorted(map(tuple, order)) == sorted(map(tuple, q)) and not np.array_equal(order, q)
    m = CorrelativeMatcher()
    prior = truth + np.array([0.05, -0.04, 0.1])
    grid = m.correlation_grid(ROOM, m.sigmas_for(None, ROOM.shape[0]), *m.search_box(q, prior))
    for penalize in (True, False):
        a = m.match(None, None, q, prior, penalize=penalize, grid=grid)
        b = m.match(None, None, q[rng.permutation(q.shape[0])], prior, penalize=penalize, grid=grid)
        assert np.array_equal(a.pose, b.pose) and np.array_equal(a.covariance, b.covariance)
        assert a.response == b.response and a.heading_variance_coarse == b.heading_variance_coarse


def test_coarse_point_spacing_thins_the_coarse_search_only():
    from slam2d.matching.correlative_search import _spaced

    rng = np.random.default_rng(5)
    truth = np.array([0.3, -0.2, 0.15])
    q = _query(ROOM, truth, rng, every=1)
    kept = _spaced(q, 0.05)
    # In scan order every kept point is at least the spacing from the one kept before it, the first is kept,
    # and every dropped point lies within the spacing of the last one kept before it.
    assert np.array_equal(kept[0], q[0]) and np.all(np.hypot(*np.diff(kept, axis=0).T) >= 0.05)
    assert 0.2 * q.shape[0] < kept.shape[0] < 0.6 * q.shape[0]
    m = CorrelativeMatcher()
    assert m.coarse_points(q) is q
    thin = CorrelativeMatcher()
    thin.coarse_point_spacing = 0.05
    assert np.array_equal(thin.coarse_points(q), kept)
    prior = truth + np.array([0.08, -0.05, 0.1])
    full, r = m.match(ROOM, None, q, prior), thin.match(ROOM, None, q, prior)
    # The fine stage scores every point: the pose is as good, the coarse lookups fewer.
    assert np.hypot(*(r.pose[:2] - truth[:2])) <= 0.015
    assert abs(se2.wrap_angle(r.pose[2] - truth[2])) <= math.radians(0.3)
    assert r.evaluated < 0.7 * full.evaluated
    assert abs(r.response - full.response) < 0.05


def test_smear_kernel_equals_the_per_cell_exponential():
    """The kernel's recurrence gives the values exp() per cell would, rounded to 0..255 (many sigmas)."""
    import math

    from slam2d.matching.correlative import smear_points
    from slam2d.matching.correlative_grid import _SCALE

    res = 0.01
    for s in np.random.default_rng(3).uniform(0.004, 0.1, 400):
        half = int(math.ceil(2.0 * s / res))
        n = 2 * half + 1
        d = (np.arange(n) - half) * (res / s)
        ex = np.exp(-0.5 * d * d) * _SCALE
        expected = np.empty((n, n), np.uint8)
        for i in range(n):  # the formula as Karto writes it: exp() per row and column, then their product
            expected[i] = [int(ex[i] / _SCALE * ex[j] + 0.5) for j in range(n)]
        grid = np.zeros((n, n), np.uint8)
        smear_points(grid, 0.0, 0.0, res, np.array([(half + 0.5) * res]), np.array([(half + 0.5) * res]), np.array([s]))
        np.testing.assert_array_equal(grid, expected, err_msg=f"sigma {s}")
