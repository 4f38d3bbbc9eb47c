"""Near chains matched before they are bounded (hot chains) give the outcomes of the bound-first order.

A chain that responded at least half the link threshold from the last node is matched at
once and bounded only when its response falls below that mark; the front end must add the
same edges, record the same failures and end with the same trajectory, bit for bit.
"""

from __future__ import annotations

import numpy as np
import pytest

from slam2d.core import se2
from slam2d.graph.frontend import GraphFrontend
from slam2d.graph.params import GraphSlamParams
from slam2d.matching.correlative import MatchResult
from slam2d.matching.grid_cache import GridCache
from slam2d.matching.scan_matcher import ScanMatcher
from tests.test_matching_bound import _walls


@pytest.fixture(scope="module")
def office_frames():
    from slam2d.sim.simulate import SimulationParams, simulate

    return simulate("office", SimulationParams(duration=120.0, seed=1)).frames()


def _run(frames):
    from slam2d.methods import get_method

    slam = get_method("karto")(seed=0).run(frames)
    return slam


def _effect(outcome, link):
    """What the front end does with an outcome: link (the match), record a failure, or nothing."""
    if isinstance(outcome, MatchResult):
        if outcome.response > link:
            return ("link", tuple(outcome.pose), outcome.response, tuple(outcome.covariance.ravel()))
        return None  # a match that does not link and is not failed: nothing, as a skipped chain
    return outcome


def _same(a, b, link) -> bool:
    return _effect(a, link) == _effect(b, link)


def test_hot_near_chains_get_the_bound_first_outcome(monkeypatch, office_frames):
    original = GraphFrontend._near_outcome
    seen = {"hot": 0, "hot_low": 0}

    def checked(self, grid, points, pose, hot):
        got = original(self, grid, points, pose, hot)
        if hot:
            # The bound-first order on the same grid (counters off: the run's own are checked below).
            diagnostics, self.diagnostics = self.diagnostics, None
            try:
                want = original(self, grid, points, pose, False)
            finally:
                self.diagnostics = diagnostics
            assert _same(got, want, self.params.link_match_minimum_response_fine)
            seen["hot"] += 1
            seen["hot_low"] += not isinstance(got, MatchResult)
        return got

    monkeypatch.setattr(GraphFrontend, "_near_outcome", checked)
    _run(office_frames)
    assert seen["hot"] > 20
    assert seen["hot"] > 10


def test_hot_near_chains_leave_the_trajectory_bit_for_bit(monkeypatch, office_frames):
    fast = _run(office_frames)
    original = GraphFrontend._near_outcome
    monkeypatch.setattr(GraphFrontend, "_near_outcome",
                        lambda self, grid, points, pose, hot: original(self, grid, points, pose, False))
    slow = _run(office_frames)
    t_fast, p_fast = fast.trajectory()
    t_slow, p_slow = slow.trajectory()
    assert np.array_equal(t_fast, t_slow) and np.array_equal(p_fast, p_slow)
    assert fast.diagnostics.summary["edges"] == slow.diagnostics.summary["edges"]
    # The hot chains skipped bounds the bound-first order computed.
    c_fast, c_slow = fast.diagnostics.counters, slow.diagnostics.counters
    bounds_fast = c_fast.get("near_skipped_bound", 0) + c_fast.get("near_skipped_bound_link", 0)
    bounds_slow = c_slow.get("near_skipped_bound", 0) + c_slow.get("near_skipped_bound_link", 0)
    assert bounds_fast <= bounds_slow
    assert c_slow.get("near_matched_before_bound", 0) == 0


def _mixed_scene(seed):
    """A world of walls and a query seeing a share of them (the rest: walls elsewhere), near its true pose."""
    rng = np.random.default_rng(seed)
    world = _walls(rng)
    truth = np.array([rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), rng.uniform(-np.pi, np.pi)])
    share = (seed % 5) / 4.0  # 0: out of view ... 1: all seen
    seen = world[rng.random(world.shape[0]) < share][::3]
    other = _walls(rng, 4)[:: max(1, int(4 * share) + 1)]
    q = se2.transform_points(se2.inverse(truth), np.vstack([seen, other]))
    prior = truth + np.array([rng.uniform(-0.1, 0.1), rng.uniform(-0.1, 0.1), rng.uniform(-0.2, 0.2)])
    return world, q, prior


def test_near_outcome_is_the_same_in_either_order_in_every_branch():
    """Direct checks over scenes and link thresholds that reach every branch, including a hot chain's
    match falling below the failure mark (bounded then: failed, or skipped when the bound is in between)."""
    kinds = set()
    for seed in range(10):
        world, q, prior = _mixed_scene(seed)
        sig = np.full(world.shape[0], 0.03)
        for link in (0.3, 0.6, 0.8, 0.95):
            outcomes = []
            for hot in (False, True):
                fe = GraphFrontend(GraphSlamParams(link_match_minimum_response_fine=link))
                fe.seq_matcher = ScanMatcher(fe.sequential, lambda i: (world, sig))
                lo, hi = fe.sequential.search_box(q, prior)
                grid = fe.seq_matcher.reserve([0], lo, hi)
                outcomes.append(fe._near_outcome(grid, q, prior, hot))
            cold, hot_out = outcomes
            assert _same(cold, hot_out, link), (seed, link)
            effect = _effect(cold, link)
            kinds.add(effect[0] if isinstance(effect, tuple) else str(effect))
            if not isinstance(hot_out, MatchResult):
                # The hot order matched, found the response below the mark and bounded it.
                kinds.add(f"hot-{hot_out}")
    assert kinds == {"link", "failed", "None", "hot-failed", "hot-None"}, kinds


def test_a_request_the_entry_already_holds_keeps_its_extent_and_grid():
    """GridCache.reserve's shortcut for a request with no node to add (a chain that shrank or stayed)."""
    from slam2d.matching.correlative import CorrelativeMatcher

    rng = np.random.default_rng(3)
    parts = [_walls(rng, 3) for _ in range(5)]
    sig = [np.full(len(q), 0.03) for q in parts]
    m = CorrelativeMatcher()
    cache = GridCache(m, lambda i: (parts[i], sig[i]))
    lo, hi = np.array([-4.0, -4.0]), np.array([4.0, 4.0])
    e = cache.reserve([0, 1, 2, 3, 4], lo, hi)
    before = (e["ext_lo"].copy(), e["ext_hi"].copy(), e["reach"])
    xlo, xhi, reach = cache._extent([0, 1, 2, 3, 4])
    assert np.array_equal(before[0], xlo) and np.array_equal(before[1], xhi) and before[2] == reach
    for subset in ([1, 2], [4], [0, 1, 2, 3, 4]):
        assert cache.reserve(subset, lo, hi) is e
        assert np.array_equal(e["ext_lo"], before[0]) and np.array_equal(e["ext_hi"], before[1])
        assert e["reach"] == before[2]
    assert cache.builds == 1 and cache.extensions == 0
    g, ox, oy = cache.materialize(e, lo, hi)
    fresh = GridCache(m, lambda i: (parts[i], sig[i]))
    f, fx, fy = fresh.get([0, 1, 2, 3, 4], lo, hi)
    assert (ox, oy) == (fx, fy) and np.array_equal(g, f)


def test_moved_nodes_bounds_every_point_shift():
    """_moved_nodes flags a node exactly when one of its points moved more than grid_keep_tolerance."""
    from types import SimpleNamespace

    rng = np.random.default_rng(3)
    refs = [(rng.uniform(-8, 8, (50, 2)), np.full(50, 0.03)) for _ in range(6)]
    refs.append((np.zeros((0, 2)), np.zeros(0)))  # a node without points moves with its pose only
    before = rng.uniform(-5, 5, (7, 3))
    after = before.copy()
    after[1, :2] += 0.003  # 3 mm: kept
    after[2, 2] += 0.0001  # 0.1 mrad, up to 1.1 mm at 11 m: kept
    after[3, 2] += 0.002  # 2 mrad: up to 2.3 cm: moved
    after[4, 0] += 0.02  # moved
    after[6, :2] += 0.003  # no points: 4.2 mm, kept
    fake = SimpleNamespace(params=GraphSlamParams(grid_keep_tolerance=0.005), _ref=refs, _reach=np.zeros(0))
    moved = GraphFrontend._moved_nodes(fake, before, after)
    for i, (pts, _) in enumerate(refs):
        shift = np.hypot(*(se2.transform_points(after[i], pts) - se2.transform_points(before[i], pts)).T) if len(pts) else [0.0]
        if not moved[i]:
            assert np.max(shift) <= 0.005  # a kept node's points all moved within the tolerance
    assert moved.tolist() == [False, False, False, True, True, False, False]
    fake.params = GraphSlamParams()  # 0: every grid is drawn again
    assert GraphFrontend._moved_nodes(fake, before, after) is None


def test_optimize_compares_the_poses_before_the_solve(office_frames):
    """optimize hands _moved_nodes the poses before the back end moved them, not the graph's live array.

    (``graph.poses`` is a view the setter writes into; kept as is, before and after were the same
    array and every grid counted as unmoved.)
    """
    from slam2d.backends.base import OptimizationResult

    front = GraphFrontend(GraphSlamParams(grid_keep_tolerance=0.005))
    for frame in office_frames[:60]:
        front.process(frame)
    assert front.graph.num_edges > 0
    shifted = front.graph.poses.copy()
    shifted[1:, 0] += 0.5  # every node but the first moves 0.5 m

    class Shift:
        def optimize(self, graph):
            return OptimizationResult(poses=shifted, cost_before=1.0, cost_after=0.0, iterations=1,
                                      converged=True, wall_s=0.0)

    seen = {}
    real = front._moved_nodes
    front._moved_nodes = lambda before, after: seen.setdefault("moved", real(before, after))
    front.backend = Shift()
    front.optimize()
    assert np.array_equal(front.graph.poses, shifted)
    assert seen["moved"][1:].all() and not seen["moved"][0]


def test_near_chains_over_a_narrower_heading_window(monkeypatch, office_frames):
    """near_chain_angle_offset (6 deg) narrows the near-chain matches and their bound only (the sequential
    matcher keeps its window); the links it finds put the trajectory where the full window (0: Karto's
    20 deg) does, to a centimetre."""
    import math

    from slam2d.methods import get_method

    narrow = math.radians(6.0)
    method = get_method("karto")
    seen = []
    original = GraphFrontend._near_outcome

    def checked(self, grid, points, pose, hot):
        seen.append((self.near.coarse_angle_offset, self.sequential.coarse_angle_offset))
        return original(self, grid, points, pose, hot)

    monkeypatch.setattr(GraphFrontend, "_near_outcome", checked)
    slam = method(method.Params(near_chain_angle_offset=narrow), seed=0).run(office_frames)
    monkeypatch.setattr(GraphFrontend, "_near_outcome", original)
    full = method(method.Params(near_chain_angle_offset=0.0), seed=0).run(office_frames)
    assert seen and all(n == pytest.approx(narrow) and s == pytest.approx(math.radians(20.0)) for n, s in seen)
    links = [float(np.nansum(s.diagnostics.array("near_links"))) for s in (slam, full)]
    assert links[0] > 0 and links[0] >= 0.8 * links[1]
    (t0, p0), (t1, p1) = slam.trajectory(), full.trajectory()
    assert np.array_equal(t0, t1)
    assert float(np.sqrt(np.mean(np.sum((p0[:, :2] - p1[:, :2]) ** 2, axis=1)))) < 0.01
