"""The per-match speed paths of the correlative matcher change no result.

The coarse search's angle pruning, the compiled fine stage, the compiled coarse heading
spread and the compiled corridor widening of the covariance are checked against the plain
numpy computations they replace, bit for bit.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from slam2d.core import se2
from slam2d.matching.correlative import MAX_VARIANCE, CorrelativeMatcher
from slam2d.matching.correlative_search import _COVARIANCE_BAND, _heading_spread, _tie_mean
from tests.test_matching_bound import _walls


def _corridor(rng, step=0.015):
    """Two long parallel walls: a response flat along them, spread to the window's edge."""
    x = np.arange(-6.0, 6.0, step)
    return np.vstack([np.c_[x, np.full_like(x, -1.0)], np.c_[x, np.full_like(x, 1.0)]])


def _scene(seed):
    rng = np.random.default_rng(seed)
    world = _corridor(rng) if seed % 3 == 0 else _walls(rng, 8)
    truth = np.array([rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3), rng.uniform(-math.pi, math.pi)])
    seen = world[rng.random(world.shape[0]) < 0.5][::3] if seed % 4 != 1 else _walls(rng, 6)
    q = se2.transform_points(se2.inverse(truth), seen) + rng.normal(0.0, 0.005, (seen.shape[0], 2))
    prior = truth + np.array([rng.uniform(-0.1, 0.1), rng.uniform(-0.1, 0.1), rng.uniform(-0.25, 0.25)])
    return world, q, prior


def _grid(m, world, q, prior):
    return m.correlation_grid(world, np.full(world.shape[0], 0.03), *m.search_box(q, prior))


def _coarse_angles(m):
    n_half = int(round(m.coarse_angle_offset / m.coarse_angle_resolution))
    return np.arange(-n_half, n_half + 1) * m.coarse_angle_resolution


@pytest.mark.parametrize("seed", range(12))
@pytest.mark.parametrize("penalize", [True, False])
def test_pruned_coarse_search_is_the_exhaustive_one(seed, penalize):
    world, q, prior = _scene(seed)
    m = CorrelativeMatcher()
    g, ox, oy = _grid(m, world, q, prior)
    angles = _coarse_angles(m)
    full = m._search(g, (ox, oy), q, prior, prior, angles, m._coarse_half, 2, penalize, True)
    pruned = m._search(g, (ox, oy), q, prior, prior, angles, m._coarse_half, 2, penalize, True, prune=True)
    pose, best, raw, resp, offs, lookups = full
    p_pose, p_best, p_raw, p_resp, p_offs, p_lookups = pruned
    assert np.array_equal(pose, p_pose) and best == p_best and raw == p_raw
    assert p_lookups <= lookups
    # Every pose within the covariance band of the best was scored exactly; the rest can only be lower.
    keep = resp >= best - _COVARIANCE_BAND - 1e-9
    assert np.array_equal(resp[keep], p_resp[keep]) and np.all(p_resp <= np.maximum(resp, best - _COVARIANCE_BAND))
    for surface in (resp, p_resp):
        cov = m._positional_covariance(surface, offs, prior, pose, best, 2.0 * m.resolution)
        assert np.array_equal(cov, m._positional_covariance(resp, offs, prior, pose, best, 2.0 * m.resolution))
        floor = m.coarse_angle_resolution**2 / 12.0
        assert _heading_spread(surface, angles, best, floor) == _heading_spread(resp, angles, best, floor)


def _numpy_heading_spread(resp, angles, best, floor):
    a_curve = resp.max(axis=(1, 2))
    w = np.where(a_curve >= best - _COVARIANCE_BAND, np.maximum(a_curve, 0.0), 0.0)
    dth = angles - angles[int(np.argmax(a_curve))]
    var = float((w * dth * dth).sum() / w.sum()) if w.sum() > 1e-12 else MAX_VARIANCE
    return max(var, floor)


@pytest.mark.parametrize("seed", range(6))
def test_compiled_heading_spread_is_numpy(seed):
    rng = np.random.default_rng(seed)
    angles = (np.arange(21) - 10) * math.radians(2.0)
    resp = rng.uniform(0.0, 1.0, (21, 17, 17)) ** (1 + seed)
    resp[rng.random(21) < 0.3] = -1.0  # unscored angles
    best = float(resp.max())
    assert _heading_spread(resp, angles, best, 1e-4) == _numpy_heading_spread(resp, angles, best, 1e-4)
    flat = np.full((21, 3, 3), -1.0)
    assert _heading_spread(flat, angles, 0.5, 1e-4) == MAX_VARIANCE


def test_tie_mean_is_numpy():
    rng = np.random.default_rng(3)
    offs = (np.arange(17) - 8) * 0.02
    angles = (np.arange(21) - 10) * math.radians(2.0)
    resp = rng.integers(0, 4, (21, 17, 17)).astype(np.float64) / 3.0
    best = float(resp.max())
    a, i, j = np.nonzero(resp >= best - 1e-12)
    want = np.array([0.3 + offs[j].mean(), -2.0 + offs[i].mean(), 1.0 + angles[a].mean()])
    assert np.array_equal(_tie_mean(resp, best, offs, angles, 0.3, -2.0, 1.0), want)


def _python_fine_stage(m, g, ox, oy, q, pose, prior, penalize):
    """The fine stage as it was written in numpy around :meth:`CorrelativeMatcher._search`."""
    n_half = int(round(0.5 * m.coarse_angle_resolution / m.fine_angle_step))
    angles = np.arange(-n_half, n_half + 1) * m.fine_angle_step
    pose, best, raw, resp_f, _, _ = m._search(g, (ox, oy), q, pose, prior, angles, 1, 1, penalize, False)
    for _ in range(m.fine_recentre):
        a_b, i_b, j_b = np.unravel_index(int(np.argmax(resp_f)), resp_f.shape)
        if 0 < i_b < 2 and 0 < j_b < 2 and 0 < a_b < angles.size - 1:
            break
        pose2, best2, raw2, resp2, _, _ = m._search(g, (ox, oy), q, pose, prior, angles, 1, 1, penalize, False)
        if best2 <= best + 1e-12:
            break
        pose, best, raw, resp_f = pose2, best2, raw2, resp2
    _, i_b, j_b = np.unravel_index(int(np.argmax(resp_f)), resp_f.shape)
    a_curve = resp_f[:, i_b, j_b]
    w = np.where(a_curve >= float(a_curve.max()) - _COVARIANCE_BAND, a_curve, 0.0)
    dth = angles - angles[int(np.argmax(a_curve))]
    norm = w.sum()
    var = (w * dth * dth).sum() / norm if norm > 1e-12 else 1000.0 * m.fine_angle_step**2
    return pose, best, raw, max(var, m.fine_angle_step**2)


@pytest.mark.parametrize("seed", range(8))
@pytest.mark.parametrize("recentre", [0, 3])
def test_match_is_its_numpy_steps(seed, recentre):
    """A whole match equals the coarse search, covariance and numpy fine stage done step by step."""
    world, q, prior = _scene(seed)
    m = CorrelativeMatcher()
    m.fine_recentre = recentre
    grid = _grid(m, world, q, prior)
    g, ox, oy = grid
    for penalize in (True, False):
        got = m.match(None, None, q, prior, penalize=penalize, refine=True, grid=grid)
        angles = _coarse_angles(m)
        pose, best, raw, resp, offs, _ = m._search(g, (ox, oy), q, prior, prior, angles, m._coarse_half, 2,
                                                   penalize, True)
        cov_xy = m._positional_covariance_general(resp, offs, prior, pose, best, 2.0 * m.resolution)
        heading = _numpy_heading_spread(resp, angles, best, m.coarse_angle_resolution**2 / 12.0)
        assert np.array_equal(got.covariance[:2, :2], cov_xy)
        assert got.heading_variance_coarse == heading
        if best > 0.0:
            pose, best, raw, var = _python_fine_stage(m, g, ox, oy, q, pose, prior, penalize)
            assert got.covariance[2, 2] == var
        pose[2] = (pose[2] + np.pi) % (2 * np.pi) - np.pi
        assert np.array_equal(got.pose, pose) and got.response == max(best, 0.0) and got.raw_response == max(raw, 0.0)


@pytest.mark.parametrize("seed", [0, 3, 6, 9])
def test_corridor_covariance_widening_is_the_general_one(seed):
    world, q, prior = _scene(seed)  # corridors
    m = CorrelativeMatcher()
    g, ox, oy = _grid(m, world, q, prior)
    widened = 0
    for dx in np.linspace(-0.1, 0.1, 5):
        p = prior + np.array([dx, 0.0, 0.0])
        pose, best, _, resp, offs, _ = m._search(g, (ox, oy), q, p, p, _coarse_angles(m), m._coarse_half, 2, True,
                                                 True)
        fast = m._positional_covariance(resp, offs, p, pose, best, 2.0 * m.resolution)
        slow = m._positional_covariance_general(resp, offs, p, pose, best, 2.0 * m.resolution)
        assert np.array_equal(fast, slow)
        widened += bool(np.linalg.eigvalsh(fast)[-1] >= 0.99 * m.search_size**2)
    if seed == 0:
        assert widened > 0  # the corridor did reach the window's edge


@pytest.mark.parametrize("seed", range(6))
def test_one_call_search_is_cells_scores_and_responses(seed):
    """The compiled search phase equals the lookup table, scores and response pass run one by one."""
    from slam2d.matching.correlative_search import _query_cells, _responses, _score_all

    world, q, prior = _scene(seed)
    m = CorrelativeMatcher()
    g, ox, oy = _grid(m, world, q, prior)
    angles = _coarse_angles(m)
    center = prior + np.array([0.013, -0.007, 0.004])
    for penalize in (True, False):
        half, step = m._coarse_half, 2
        pose, best, raw, resp, offs, _ = m._search(g, (ox, oy), q, center, prior, angles, half, step, penalize,
                                                   False)
        rows, cols = _query_cells(q[:, 0], q[:, 1], angles, *center, ox, oy, m.resolution, -half * step)
        sums = _score_all(g, rows, cols, 2 * half + 1, step)
        want_offs = (np.arange(2 * half + 1) - half) * (step * m.resolution)
        w_raw, w_resp, w_best, ties, (a0, y0, x0) = _responses(
            sums, float(q.shape[0] * 255.0), want_offs, angles, *center, *prior, penalize,
            m.distance_variance_penalty, m.angle_variance_penalty, m.minimum_distance_penalty,
            m.minimum_angle_penalty)
        assert np.array_equal(offs, want_offs) and np.array_equal(resp, w_resp) and best == w_best
        assert raw == w_raw[a0, y0, x0]
        if ties == 1:
            assert np.array_equal(pose, center + np.array([want_offs[x0], want_offs[y0], angles[a0]]))
