"""karto's link from the closest running scan carries the uncertainty of the steps since that scan."""

from __future__ import annotations

import math

import numpy as np
import pytest

from slam2d.core import se2
from slam2d.graph.frontend import GraphFrontend
from slam2d.graph.params import GraphSlamParams


def _chain(steps, covs, **settings):
    """A front end whose graph is a chain of sequential edges with these steps and local covariances."""
    fe = GraphFrontend(GraphSlamParams(**settings))
    pose = np.zeros(3)
    fe.graph.add_node(pose)
    for z, c in zip(steps, covs, strict=True):
        pose = se2.compose(pose, z)
        fe.graph.add_node(pose)
        fe._seq_steps.append((np.asarray(z, dtype=float), np.asarray(c, dtype=float)))
    return fe


def test_chain_covariance_matches_sampling():
    """First-order propagation agrees with sampling the composed steps (small errors)."""
    rng = np.random.default_rng(0)
    steps = [np.array([1.0, 0.1, 0.3]), np.array([0.8, -0.2, -0.5]), np.array([1.2, 0.0, 0.2])]
    covs = [np.diag([0.02**2, 0.01**2, math.radians(2.0) ** 2]),
            np.diag([0.03**2, 0.02**2, math.radians(1.0) ** 2]),
            np.diag([0.01**2, 0.01**2, math.radians(0.5) ** 2])]
    fe = _chain(steps[:2], covs[:2])
    got = fe._chain_covariance(0, 2, steps[2], covs[2])
    n = 200_000
    rel = np.zeros((n, 3))
    for z, c in zip(steps, covs, strict=True):
        rel = se2.compose(rel, z + rng.multivariate_normal(np.zeros(3), c, size=n))
    mean = se2.compose(se2.compose(steps[0], steps[1]), steps[2])
    d = rel - mean
    d[:, 2] = se2.wrap_angle(d[:, 2])
    want = d.T @ d / n
    np.testing.assert_allclose(got, want, rtol=0.05, atol=1e-7)
    # A heading error early in the chain swings the later steps sideways: the lateral
    # variance is far above the sum of the steps' own.
    assert got[1, 1] > 5 * sum(c[1, 1] for c in covs)


def _link(fe, node, pose, cov):
    """Add node ``node`` at ``pose`` with its sequential edge, then the running-scan link, as process() does."""
    last = node - 1
    fe.graph.add_node(pose)
    fe._bary_base = np.zeros((fe.graph.num_nodes, 2))
    fe._world = [None] * fe.graph.num_nodes
    fe._running = list(range(node))  # the new node joins the running scans after linking
    fe._add_edge(last, node, pose, cov)
    fe._seq_steps.append((fe.graph.measurements[-1].copy(), fe._local_covariance(last, cov)))
    fe._link_running_scan(last, node, pose, cov)


def _u_turn(**settings):
    """Out along x for three 1 m steps with an uncertain heading, back along y = 0.3: node 4 lies next to node 0."""
    step_cov = np.diag([0.02**2, 0.02**2, math.radians(2.0) ** 2])
    fe = _chain([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.3, 0.3, math.pi]], [step_cov] * 3,
                use_scan_barycenter=False, **settings)
    match_cov = np.diag([0.01**2, 0.01**2, math.radians(0.5) ** 2])
    _link(fe, 4, np.array([0.1, 0.3, math.pi]), match_cov)
    return fe, match_cov


def test_running_link_from_an_older_scan_carries_the_chain():
    fe, match_cov = _u_turn()
    ei, ej = np.asarray(fe.graph.edge_i), np.asarray(fe.graph.edge_j)
    k = np.nonzero((ei == 0) & (ej == 4))[0]
    assert k.size == 1, "the closest running scan (node 0) is linked to the new node"
    cov = np.linalg.inv(fe.graph.information[k[0]])
    # Heading: the three uncertain steps plus the match; not the match's 0.5 deg alone.
    assert cov[2, 2] > 3 * math.radians(2.0) ** 2
    np.testing.assert_allclose(fe.graph.measurements[k[0]], se2.relative(fe.graph.poses[0], fe.graph.poses[4]), atol=1e-12)


def test_running_link_as_karto_when_off():
    fe, match_cov = _u_turn(running_link_chain_covariance=False)
    ei, ej = np.asarray(fe.graph.edge_i), np.asarray(fe.graph.edge_j)
    k = np.nonzero((ei == 0) & (ej == 4))[0]
    assert k.size == 1
    cov = np.linalg.inv(fe.graph.information[k[0]])
    assert math.isclose(cov[2, 2], match_cov[2, 2], rel_tol=1e-6)


def test_no_second_edge_when_the_closest_running_scan_is_the_previous_node():
    step_cov = np.diag([0.02**2, 0.02**2, math.radians(2.0) ** 2])
    fe = _chain([[1.0, 0.0, 0.0]], [step_cov], use_scan_barycenter=False)
    _link(fe, 2, np.array([2.0, 0.0, 0.0]), step_cov)
    assert fe.graph.num_edges == 1  # the sequential 1 -> 2 only (_chain adds no edges)


def test_prior_heading_drop_says_whether_the_scan_fits_the_prior_heading():
    """The matcher reports how far below its best the prior's own heading responds (coarse search)."""
    from slam2d.matching.correlative import CorrelativeMatcher

    from tests.test_matching_correlative import ROOM, _query

    rng = np.random.default_rng(3)
    truth = np.array([0.3, -0.2, 0.15])
    q = _query(ROOM, truth, rng)
    m = CorrelativeMatcher()
    right = m.match(ROOM, None, q, truth)
    wrong = m.match(ROOM, None, q, truth + np.array([0.0, 0.0, math.radians(12.0)]))
    assert 0.0 <= right.prior_heading_drop < 0.05
    assert wrong.prior_heading_drop > 0.1  # the room fits 12 deg off clearly worse
    assert abs(se2.wrap_angle(wrong.pose[2] - truth[2])) < math.radians(0.5)


def _estimate_with(drop, **settings):
    """The sequential estimate of a front end whose match (ambiguous heading, 6 deg from the prediction)
    reports ``drop`` below its best at the prediction's heading."""
    import dataclasses

    from slam2d.matching.correlative import MatchResult

    fe = GraphFrontend(GraphSlamParams(**settings))
    fe.graph.add_node(np.zeros(3))
    predicted = np.array([1.0, 0.0, 0.0])
    match = MatchResult(pose=np.array([1.0, 0.0, math.radians(6.0)]), covariance=np.diag([1e-4, 1e-4, 1e-4]),
                        response=0.7, raw_response=0.7, evaluated=0, heading_variance_coarse=math.radians(5.0) ** 2,
                        prior_heading_drop=drop)
    fe.seq_matcher.match = lambda *a, **k: dataclasses.replace(match)
    pose, _, _ = fe._sequential_estimate(np.zeros((5, 2)), predicted)
    return pose


def test_odometry_is_fused_only_when_the_scan_fits_its_heading_about_as_well():
    fused = _estimate_with(0.02)
    assert 0.0 < fused[2] < math.radians(5.0)  # pulled towards the odometry's 0
    kept = _estimate_with(0.2)
    assert kept[2] == pytest.approx(math.radians(6.0))  # the scan rejects the odometry's heading
    old = _estimate_with(0.2, odometry_fusion_maximum_drop=1.0)
    np.testing.assert_allclose(old, fused)
