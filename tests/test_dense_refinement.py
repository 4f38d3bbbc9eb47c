"""The dense alignment after the wall refinement (`dense_refinement`): normals, the joint solve, the wiring."""

from __future__ import annotations

import math

import numpy as np

from slam2d.backends import PoseGraph
from slam2d.core import make_scan, se2
from slam2d.graph.dense_refinement import DenseTerm, scan_normals
from slam2d.graph.params import GraphSlamParams
from slam2d.graph.wall_refinement import refine_path, refine_walls, scan_segments

# A corridor 2 m wide (walls y = +-1), longer than the laser's reach, with round posts along its walls:
# the walls hold the heading and the distance to them, only the posts hold the position along it.
POSTS = np.array([[1.5, 0.7], [3.5, -0.7], [5.0, 0.75], [7.0, -0.7], [8.5, 0.7]])
POST_RADIUS = 0.15


def _corridor_scan(pose, rng, n=361, fov=math.radians(240), max_range=5.6):
    a = -fov / 2 + fov * np.arange(n) / (n - 1)
    d = pose[2] + a
    dx, dy = np.cos(d), np.sin(d)
    with np.errstate(divide="ignore"):
        t = np.where(dy > 0, (1.0 - pose[1]) / dy, np.where(dy < 0, (-1.0 - pose[1]) / dy, np.inf))
    for c in POSTS:
        ox, oy = pose[0] - c[0], pose[1] - c[1]
        b = ox * dx + oy * dy
        disc = b * b - (ox * ox + oy * oy - POST_RADIUS**2)
        hit = np.where(disc > 0, -b - np.sqrt(np.maximum(disc, 0.0)), np.inf)
        t = np.fmin(t, np.where(hit > 0, hit, np.inf))
    t = t + rng.normal(0.0, 0.005, t.shape)
    return make_scan(0.0, np.where(t < max_range, t, np.nan), -fov / 2, fov / (n - 1), 0.02, max_range)


def _corridor_problem(nodes=40):
    """True poses down the corridor, their scans, and a graph of odometry 5 % long (the start: its integral)."""
    rng = np.random.default_rng(0)
    s = np.linspace(0.0, 1.0, nodes)
    truth = np.stack([9.0 * s, 0.1 * np.sin(3.0 * s), 0.05 * np.cos(5.0 * s)], -1)
    scans = [_corridor_scan(p, rng) for p in truth]
    inc = se2.relative(truth[:-1], truth[1:])
    inc[:, 0] *= 1.05
    start = np.zeros_like(truth)
    start[0] = truth[0]
    for i in range(nodes - 1):
        start[i + 1] = se2.compose(start[i], inc[i])
    graph = PoseGraph()
    graph.add_nodes(start)
    sig = np.array([0.05, 0.05, math.radians(1.0)])
    graph.add_edges(np.arange(nodes - 1), np.arange(1, nodes), inc, np.diag(1.0 / sig**2))
    return truth, scans, graph


def _params(**kw):
    base = dict(wall_refinement=True, dense_refinement=True, dense_refinement_frame_gap=1,
                dense_refinement_max_distance=0.3, wall_refinement_ends=False)
    return GraphSlamParams(**{**base, **kw})


def _error(poses, truth):
    return np.hypot(poses[:, 0] - truth[:, 0], poses[:, 1] - truth[:, 1])


def test_normals_of_a_circle_point_at_its_centre_and_a_corner_fits_badly():
    a = np.linspace(-1.0, 1.0, 81)
    pts = np.stack([2.0 + 0.5 * np.cos(a), 0.5 * np.sin(a)], -1)
    n, rms = scan_normals(pts, 4, 0.2)
    radial = np.stack([np.cos(a), np.sin(a)], -1)
    cos = np.abs((n * radial).sum(1))
    assert np.all(cos[4:-4] > math.cos(math.radians(0.1)))  # a full window: the chord's normal, radial
    assert np.all(cos > math.cos(math.radians(5.0)))  # at the arc's ends the window is one-sided
    assert np.all(rms < 0.005)
    corner = np.concatenate([np.stack([np.linspace(0, 1, 21), np.zeros(21)], -1),
                             np.stack([np.ones(20), np.linspace(0.05, 1, 20)], -1)])
    _, rms = scan_normals(corner, 4, 0.2)
    assert rms[20] > 0.02 and rms[5] < 1e-9  # at the corner the line fits badly, along a wall exactly
    far = np.array([[0.0, 0.0], [0.01, 0.0], [0.02, 0.0], [5.0, 0.0], [5.01, 0.0]])
    _, rms = scan_normals(far, 4, 0.2)
    assert np.isinf(rms[3]) and np.isinf(rms[4])  # a run of two: no line


def test_round_posts_fix_the_position_along_a_corridor():
    truth, scans, graph = _corridor_problem()
    p = _params()
    segs = scan_segments(scans, [None] * len(scans), p)
    walls = refine_walls(graph, segs, p)
    start, alone = _error(graph.poses, truth).max(), _error(walls.poses, truth).max()
    assert start > 0.3 and alone > 0.2, (start, alone)  # the walls cannot tell where along the corridor
    term = DenseTerm(scans, [None] * len(scans), p)
    dense = refine_walls(graph, segs, p, extra=term, iterations=8)
    err = _error(dense.poses, truth)
    assert err.max() < 0.04 and err.mean() < 0.015, (err.max(), err.mean())
    assert np.abs(se2.wrap_angle(dense.poses[:, 2] - truth[:, 2])).max() < math.radians(0.5)
    np.testing.assert_array_equal(dense.poses[0], graph.poses[0])  # the gauge stays
    assert dense.rounds[-1]["pairs"] > 0.5 * term.frame.size


def test_pairs_respect_the_frame_gap_and_the_distance():
    truth, scans, _ = _corridor_problem(nodes=12)
    p = _params(dense_refinement_frame_gap=3, dense_refinement_max_distance=0.05)
    term = DenseTerm(scans, [None] * len(scans), p)
    assert term.associate(truth) > 0
    fa, fb = term.frame[term.a], term.frame[term.b]
    assert np.all(np.abs(fa - fb) >= 3) and np.all(term.usable[term.b])
    wa = se2.transform_points(truth[fa], term.q[term.a][:, None, :])[:, 0, :]
    wb = se2.transform_points(truth[fb], term.q[term.b][:, None, :])[:, 0, :]
    assert np.all(np.hypot(*(wa - wb).T) <= 0.05)


def test_refine_path_runs_the_dense_stage_only_when_asked():
    truth, scans, graph = _corridor_problem(nodes=25)
    odom = graph.poses.copy()
    p = _params()
    plain, _ = refine_path(scans, graph.poses, p, odometry=odom)
    again, _ = refine_path(scans, graph.poses, p, odometry=odom, dense=None)
    np.testing.assert_array_equal(plain.poses, again.poses)
    assert plain.dense_pairs == -1 and "dense_pairs" not in plain.summary(0, 0.0)
    dense, _ = refine_path(scans, graph.poses, p, odometry=odom, dense=p)
    assert dense.dense_pairs > 0 and dense.summary(0, 0.0)["dense_pairs"] == dense.dense_pairs
    assert _error(dense.poses, truth).mean() < 0.5 * _error(plain.poses, truth).mean()
