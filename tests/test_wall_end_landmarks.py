"""Wall ends as landmarks: the detector, the association, the landmark edges in SPA, LAGO skipping them."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np

from slam2d.backends import PoseGraph, get_backend
from slam2d.backends.graph import edge_jacobians
from slam2d.backends.landmarks import (
    PointObservations,
    augmented_graph,
    landmark_positions,
    optimize_with_landmarks,
    point_errors,
    point_jacobians,
)
from slam2d.core import make_scan, se2
from slam2d.graph.params import GraphSlamParams
from slam2d.graph.wall_end_landmarks import WallEndLandmarks
from slam2d.matching.wall_ends import detect_wall_ends
from slam2d.sim.laser import cast_rays

URG_STEP = 2.0 * math.pi / 1024.0


def _world(segments):
    seg = np.asarray(segments, dtype=np.float64).reshape(-1, 4)
    return SimpleNamespace(segments=seg, segment_material=np.zeros(len(seg), np.int64),
                           circles=np.zeros((0, 3)), circle_material=np.zeros(0, np.int64))


def _scan(world, pose, *, n=682, step=URG_STEP, range_max=5.6, noise=0.0, rng=None):
    angles = -0.5 * step * (n - 1) + step * np.arange(n)
    r, _, _ = cast_rays(world, pose, angles)
    if noise:
        r = r + rng.normal(0.0, noise, r.shape)
    return make_scan(0.0, np.where(np.isfinite(r), r, np.nan), float(angles[0]), step, 0.02, range_max)


# A corridor along x (walls y = +-1) with a door 1.2 m wide in its north wall at x = 1 .. 2.2 and a room
# behind it (north wall y = 4); the south wall runs on past the laser's reach.
DOOR = _world([[-5, 1, 1, 1], [2.2, 1, 30, 1], [-5, -1, 30, -1], [0.5, 1, 0.5, 4], [0.5, 4, 3, 4], [3, 4, 3, 1]])


def _nearest(points, targets):
    d = np.hypot(*(points[:, None, :] - np.asarray(targets, dtype=float)[None]).transpose(2, 0, 1))
    return d.min(axis=1), d.argmin(axis=1)


def test_doorway_jambs_found_and_nothing_else():
    scan = _scan(DOOR, [0.0, 0.0, 0.0])
    ends = detect_wall_ends(scan, 0.01)
    d, which = _nearest(ends.points, [[1.0, 1.0], [2.2, 1.0]])
    # Both jambs, each once, within the gap between two beams there (3.7 cm at the east jamb); the
    # south wall running out of range gives none, nor do the room's walls seen through the door.
    assert sorted(which.tolist()) == [0, 1]
    assert np.all(d < 0.02)
    # Each point's covariance covers its error (chi-square, 2 DOF, well inside 3 sigma).
    e = ends.points - np.array([[1.0, 1.0], [2.2, 1.0]])[which]
    chi2 = np.einsum("ki,kij,kj->k", e, np.linalg.inv(ends.covariances), e)
    assert np.all(chi2 < 11.8)
    # The side says which way the wall ends: beams turn left with their index, so the west jamb's wall
    # ends towards decreasing index (the beam before it passes through the door), the east's towards increasing.
    assert ends.side[which == 0][0] == -1 and ends.side[which == 1][0] == 1


def test_doorway_with_noise_and_mount():
    rng = np.random.default_rng(3)
    mount = np.array([0.1, 0.0, 0.0])
    hits = []
    for x in np.linspace(-2.0, 0.5, 6):
        laser = se2.compose(np.array([x, 0.0, 0.0]), mount)
        angles = -0.5 * URG_STEP * 681 + URG_STEP * np.arange(682)
        r, _, _ = cast_rays(DOOR, laser, angles)
        r = r + rng.normal(0.0, 0.01, r.shape)
        scan = make_scan(0.0, np.where(np.isfinite(r), r, np.nan), float(angles[0]), URG_STEP, 0.02, 5.6, mount=mount)
        ends = detect_wall_ends(scan, 0.01)
        world = se2.transform_points(np.array([x, 0.0, 0.0]), ends.points)  # robot frame -> world
        d, _ = _nearest(world, [[1.0, 1.0], [2.2, 1.0]])
        hits.append(d)
    d = np.concatenate(hits)
    assert d.size >= 10 and np.all(d < 0.05) and np.median(d) < 0.02


def test_box_corner():
    # A box 1 x 1 m in a large room: from a corner-on view both silhouette corners are wall ends.
    box = [[2, -0.5, 3, -0.5], [3, -0.5, 3, 0.5], [3, 0.5, 2, 0.5], [2, 0.5, 2, -0.5]]
    room = [[-5, -5, 8, -5], [8, -5, 8, 5], [8, 5, -5, 5], [-5, 5, -5, -5]]
    scan = _scan(_world(box + room), [0.0, 0.0, 0.0], range_max=20.0)
    ends = detect_wall_ends(scan, 0.01)
    d, which = _nearest(ends.points, [[2.0, 0.5], [2.0, -0.5]])
    assert sorted(which.tolist()) == [0, 1] and np.all(d < 0.02)


def test_self_occluding_grazing_wall_is_not_an_end():
    # A wall at y = 0.3 seen along its length with 1 deg beams: its points step by metres from beam to
    # beam (a range jump) though the wall goes on. Only its true end (x = 10) may come out, and even
    # that is refused at the default incidence limit.
    wall = _world([[0.5, 0.3, 10.0, 0.3], [30.0, -50.0, 30.0, 50.0]])
    step = math.radians(1.0)
    scan = _scan(wall, [0.0, 0.0, 0.0], n=181, step=step, range_max=40.0)
    loose = detect_wall_ends(scan, 0.01, max_incidence=math.radians(89.9))
    # None at the self-occlusion steps (0.6 < x < 8.6); the wall's near end (0.5, 0.3) is a true one.
    start = np.hypot(loose.points[:, 0] - 0.5, loose.points[:, 1] - 0.3) < 0.02
    assert np.all(start | (loose.points[:, 0] > 8.0)) and start.sum() == 1
    strict = detect_wall_ends(scan, 0.01)
    assert len(strict) == 1 and np.hypot(*(strict.points[0] - [0.5, 0.3])) < 0.02


def test_single_dropout_is_not_a_doorway():
    wall = _world([[-5, 1, 30, 1], [-5, -1, 30, -1]])  # both run out of the laser's reach
    scan = _scan(wall, [0.0, 0.0, 0.0])
    r = scan.ranges.copy()
    k = int(np.argmin(np.abs(scan.angles - math.radians(60))))
    r[k] = np.nan  # one lost return on the north wall
    scan = make_scan(0.0, r, scan.angle_min, scan.angle_increment, 0.02, 5.6)
    assert len(detect_wall_ends(scan, 0.01)) == 0


# ---------------------------------------------------------------- association


def _drive(n, step=0.2, along_error=0.0, rng=None):
    """Poses driving east along the door corridor; odometry-like estimates with an along-track error."""
    truth = np.column_stack([-4.0 + step * np.arange(n), np.zeros(n), np.zeros(n)])
    est = truth.copy()
    if along_error:
        est[:, 0] += np.cumsum(rng.normal(0.0, along_error, n))
    return truth, est


def test_association_tracks_the_jambs():
    p = GraphSlamParams(wall_end_landmarks=True)
    lm = WallEndLandmarks(p)
    truth, _ = _drive(30)
    fe = SimpleNamespace(graph=SimpleNamespace(poses=truth.copy()), optimize=lambda: None)
    rng = np.random.default_rng(0)
    for i in range(len(truth)):
        scan = _scan(DOOR, truth[i], noise=0.01, rng=rng)
        lm.observe(fe, i, scan, np.full(scan.num_beams, 0.01))
    pos = lm.positions()
    obs = lm.observations()
    # The two jambs are landmarks seen from many nodes, each sighting of one landmark.
    used = np.unique(obs.landmark)
    d, which = _nearest(pos[used], [[1.0, 1.0], [2.2, 1.0]])
    assert set(which.tolist()) == {0, 1} and np.all(d < 0.02)
    counts = np.bincount(obs.landmark)
    assert counts[used].min() >= 12
    # No landmark holds two points of one scan.
    key = obs.pose * (lm.num_landmarks + 1) + obs.landmark
    assert np.unique(key).size == key.size


def test_association_refuses_ambiguous_and_far():
    p = GraphSlamParams(wall_end_landmarks=True, wall_end_pose_sigma=0.05)
    lm = WallEndLandmarks(p)
    poses = np.zeros((3, 3))
    fe = SimpleNamespace(graph=SimpleNamespace(poses=poses))

    def ends(points):
        pts = np.asarray(points, dtype=float)
        return SimpleNamespace(points=pts, covariances=np.broadcast_to(np.eye(2) * 1e-4, (len(pts), 2, 2)).copy(),
                               direction=np.tile([1.0, 0.0], (len(pts), 1)), __len__=lambda: len(pts))

    lm._associate(fe.graph.poses, 0, ends([[1.0, 0.0], [1.1, 0.0]]))  # two landmarks 0.1 m apart
    assert lm.num_landmarks == 2
    # A point between them is within the gate of both: not associated, no new landmark.
    lm._associate(fe.graph.poses, 1, ends([[1.05, 0.0]]))
    assert lm.num_landmarks == 2 and lm._k == 2
    # A point 1 m away starts a new one.
    lm._associate(fe.graph.poses, 2, ends([[2.05, 0.0]]))
    assert lm.num_landmarks == 3


# ---------------------------------------------------------------- the back end


def test_point_jacobians_by_finite_differences():
    rng = np.random.default_rng(1)
    poses = np.column_stack([rng.normal(size=(4, 2)), rng.uniform(-3, 3, 4)])
    lms = rng.normal(size=(3, 2)) * 3
    obs = PointObservations(np.array([0, 1, 2, 3, 1]), np.array([0, 0, 1, 2, 2]), rng.normal(size=(5, 2)),
                            np.broadcast_to(np.eye(2), (5, 2, 2)).copy())
    e, jp, jl = point_jacobians(poses, lms, obs)
    h = 1e-6
    for k in range(len(obs)):
        i, l = obs.pose[k], obs.landmark[k]
        for c in range(3):
            dp = np.zeros(3)
            dp[c] = h
            pp = poses.copy()
            pp[i] = se2.compose(poses[i], dp)  # the local perturbation SPA uses
            pm = poses.copy()
            pm[i] = se2.compose(poses[i], -dp)
            fd = (point_errors(pp, lms, obs)[k] - point_errors(pm, lms, obs)[k]) / (2 * h)
            np.testing.assert_allclose(jp[k][:, c], fd, atol=1e-6)
        for c in range(2):
            lp, lmn = lms.copy(), lms.copy()
            lp[l, c] += h
            lmn[l, c] -= h
            fd = (point_errors(poses, lp, obs)[k] - point_errors(poses, lmn, obs)[k]) / (2 * h)
            np.testing.assert_allclose(jl[k][:, c], fd, atol=1e-6)
    # The augmented graph's landmark edges are the same errors and the same Jacobians in SPA's terms.
    g = PoseGraph()
    g.add_nodes(poses)
    ag = augmented_graph(g, lms, obs)
    ea, A, B = edge_jacobians(ag.poses, ag.edge_i, ag.edge_j, ag.measurements)
    np.testing.assert_allclose(ea[:, :2], e, atol=1e-12)
    np.testing.assert_allclose(A[:, :2, :], jp, atol=1e-12)
    # The landmark node is perturbed locally too; at heading 0 that is the world frame.
    np.testing.assert_allclose(B[:, :2, :2], jl, atol=1e-12)
    np.testing.assert_allclose(B[:, :2, 2], 0.0, atol=1e-12)


def _corridor_graph(n, rng):
    """A drive east with odometry edges that each measure the step 5 % long (along-track drift) and
    true-ish headings; the truth and the graph."""
    truth = np.column_stack([0.25 * np.arange(n), np.zeros(n), np.zeros(n)])
    g = PoseGraph()
    g.add_node(truth[0])
    est = truth[0].copy()
    for i in range(1, n):
        z = se2.relative(truth[i - 1], truth[i]) * np.array([1.05, 1.0, 1.0]) + np.array([0, 0, 1e-4 * rng.normal()])
        est = se2.compose(est, z)
        g.add_node(est)
        # Along the corridor the step is barely known (as a flat correlative match), across it well.
        g.add_edge(i - 1, i, z, np.diag([1 / 0.3**2, 1 / 0.005**2, 1 / 0.002**2]))
    return truth, g


def test_landmarks_fix_along_track_drift_odometry_cannot():
    rng = np.random.default_rng(2)
    truth, g = _corridor_graph(40, rng)
    spa = get_backend("spa")
    alone = spa.optimize(g).poses
    err_alone = np.abs(alone[:, 0] - truth[:, 0]).max()
    assert err_alone > 0.4  # the odometry's 5 % over 10 m stays: nothing else says where along
    # Door jambs every 3 m at y = 1.5, each seen from the poses within 4 m, to 1 cm.
    marks = np.column_stack([np.arange(1.0, 10.0, 3.0), np.full(3, 1.5)])
    pose_idx, lm_idx = np.nonzero(np.abs(truth[:, None, 0] - marks[None, :, 0]) < 4.0)
    z = point_errors(truth, marks, PointObservations(pose_idx, lm_idx, np.zeros((len(pose_idx), 2)),
                                                     np.zeros((len(pose_idx), 2, 2))))
    z = z + rng.normal(0.0, 0.01, z.shape)
    obs = PointObservations(pose_idx, lm_idx, z, np.broadcast_to(np.eye(2) / 0.01**2, (len(z), 2, 2)).copy())
    res, pos = optimize_with_landmarks(spa, g, obs, len(marks))
    assert res.poses.shape == truth.shape and res.converged
    # Aligned at the fixed first node as the graph is: the landmarks hold every pose within centimetres.
    err = np.abs(res.poses[:, 0] - truth[:, 0]).max()
    assert err < 0.05 < err_alone / 8
    np.testing.assert_allclose(pos, marks, atol=0.05)
    # The landmarks' positions are the least-squares ones given the optimised poses.
    pos2, _ = landmark_positions(res.poses, obs, len(marks))
    np.testing.assert_allclose(pos2, pos, atol=1e-4)


def test_lago_skips_landmark_edges():
    rng = np.random.default_rng(2)
    truth, g = _corridor_graph(20, rng)
    obs = PointObservations(np.array([1, 2, 3]), np.array([0, 0, 0]), np.array([[1.0, 1.0], [0.75, 1.0], [0.5, 1.0]]),
                            np.broadcast_to(np.eye(2) * 1e4, (3, 2, 2)).copy())
    lago = get_backend("lago")
    res, pos = optimize_with_landmarks(lago, g, obs, 1)
    assert res.extra["landmarks_skipped"] is True
    np.testing.assert_allclose(res.poses, lago.optimize(g).poses)
    assert np.all(np.isfinite(pos))


# ---------------------------------------------------------------- in the method


def test_karto_and_lago_with_wall_end_landmarks_on_a_simulated_office():
    from slam2d.eval.trajectory_metrics import absolute_trajectory_error, associate
    from slam2d.methods import get_method
    from slam2d.sim.simulate import SimulationParams, simulate

    sim = simulate("office", SimulationParams(duration=25.0, seed=1))
    cls = get_method("karto")
    runs = {}
    for backend in ("spa", "lago"):
        slam = cls(cls.Params(wall_end_landmarks=True, backend=backend)).run(sim.frames())
        t, p = slam.trajectory()
        runs[backend] = (p, absolute_trajectory_error(associate(t, p, sim.scan_times, sim.scan_truth))["translation_m"]["rmse"])
        c = slam.diagnostics.counters
        assert c["wall_end_sightings"] > 50 and c["wall_end_landmarks"] > 5
        assert slam.diagnostics.summary["optimizations"]  # landmark edges made the front end optimise
        assert runs[backend][1] < 0.2
    # Deterministic: the same run again gives the same trajectory bit for bit.
    again = cls(cls.Params(wall_end_landmarks=True)).run(sim.frames()).trajectory()[1]
    np.testing.assert_array_equal(again, runs["spa"][0])


def test_mixed_return_at_the_edge_and_beam_width():
    scan = _scan(DOOR, [0.0, 0.0, 0.0])
    ends = detect_wall_ends(scan, 0.01)
    k = int(ends.beams[np.argmin(np.hypot(*(ends.points - [1.0, 1.0]).T))])
    # The end beam returns a mix of the jamb and the room behind it, 0.15 m behind the jamb: that end
    # is not taken at the wrong range (the other jamb still is).
    r = scan.ranges.copy()
    r[k] += 0.15
    mixed = detect_wall_ends(make_scan(0.0, r, scan.angle_min, scan.angle_increment, 0.02, 5.6), 0.01)
    d, which = _nearest(mixed.points, [[1.0, 1.0], [2.2, 1.0]])
    assert which.tolist() == [1] and d[0] < 0.02
    # A bearing sigma (a real beam's width) widens the covariance along the wall only.
    wide = detect_wall_ends(scan, 0.01, bearing_sigma=math.radians(0.5))
    np.testing.assert_allclose(wide.points, ends.points)
    u = ends.direction
    along = np.einsum("ki,kij,kj->k", u, ends.covariances, u)
    along_wide = np.einsum("ki,kij,kj->k", u, wide.covariances, u)
    n = np.stack([-u[:, 1], u[:, 0]], -1)
    assert np.all(along_wide > along + (1.0 * math.radians(0.5)) ** 2)
    np.testing.assert_allclose(np.einsum("ki,kij,kj->k", n, wide.covariances, n),
                               np.einsum("ki,kij,kj->k", n, ends.covariances, n))


def test_wall_end_auto_range_turns_them_on_for_short_range_lasers_only():
    from slam2d.methods import get_method
    from slam2d.sim.simulate import SimulationParams, simulate

    cls = get_method("karto")
    urg = simulate("office", SimulationParams(duration=8.0, seed=1, laser="urg-04lx"))
    slam = cls(cls.Params(wall_end_auto_range=8.0)).run(urg.frames())
    assert slam.frontend.wall_ends is not None and slam.diagnostics.counters["wall_end_landmarks_auto"] == 1
    assert slam.diagnostics.counters["wall_end_sightings"] > 10
    # Same as asking for them outright.
    on = cls(cls.Params(wall_end_landmarks=True)).run(urg.frames())
    np.testing.assert_array_equal(on.trajectory()[1], slam.trajectory()[1])
    # A 12 m laser: exactly the run without them.
    rp = simulate("office", SimulationParams(duration=8.0, seed=1, laser="rplidar-a1"))
    auto = cls(cls.Params(wall_end_auto_range=8.0)).run(rp.frames())
    assert auto.frontend.wall_ends is None and "wall_end_landmarks_auto" not in auto.diagnostics.counters
    np.testing.assert_array_equal(auto.trajectory()[1], cls(cls.Params()).run(rp.frames()).trajectory()[1])
