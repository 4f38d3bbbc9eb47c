"""The wall bundle adjustment of karto's finished graph (`wall_refinement`): lines, association, the joint solve."""

from __future__ import annotations

import math

import numpy as np

from slam2d.backends import PoseGraph
from slam2d.core import se2
from slam2d.graph.params import GraphSlamParams
from slam2d.graph.wall_refinement import (EndSightings, associate_ends, associate_segments, extract_segments,
                                          place_points, refine_walls, scan_segments, scan_wall_ends)
from slam2d.methods import get_method
from slam2d.params import from_mapping
from slam2d.sim.simulate import SimulationParams, simulate

from tests._room import PILLAR, ROOM, room_scan


def _line_of(alpha, d):
    """(alpha, d) with alpha in [0, pi): one form per line."""
    alpha = float(alpha) % (2 * math.pi)
    if alpha >= math.pi:
        alpha, d = alpha - math.pi, -d
    return alpha, float(d)


def _same(line, other, angle, offset):
    """Whether two lines (alpha, d) agree to ``angle`` and ``offset``, in either of their forms."""
    (a, d), (b, e) = line, other
    da = math.remainder(a - b, 2 * math.pi)
    if abs(da) > math.pi / 2:  # the other form: the normal turned round
        da, e = math.remainder(da + math.pi, 2 * math.pi), -e
    return abs(da) < angle and abs(d - e) < offset


def test_line_extraction_recovers_the_room_walls():
    rng = np.random.default_rng(3)
    pose = np.array([0.3, -0.4, 0.2])
    scan = room_scan(pose, n=721, fov=np.radians(360) * 720 / 721)
    scan.ranges[:] = scan.ranges + rng.normal(0.0, 0.005, scan.ranges.shape)
    ok = scan.valid
    pts = se2.transform_points(pose, scan.points())  # world frame: the walls are the room's
    starts, ends, alpha, d, rms = extract_segments(pts, np.flatnonzero(ok), break_distance=0.2, split_distance=0.04,
                                                   min_points=10, max_rms=0.02)
    xmin, ymin, xmax, ymax = ROOM
    truth = {_line_of(0.0, xmax), _line_of(math.pi, -xmin), _line_of(math.pi / 2, ymax), _line_of(-math.pi / 2, -ymin)}
    found = [_line_of(a, dd) for a, dd in zip(alpha, d)]
    for ta, td in truth:  # every room wall is found, to 0.5 deg and 1 cm
        assert any(_same(f, (ta, td), math.radians(0.5), 0.01) for f in found), (ta, td, found)
    # every segment lies on a wall of the room or a face of the pillar
    px0, py0, px1, py1 = PILLAR
    faces = truth | {_line_of(0.0, px0), _line_of(0.0, px1), _line_of(math.pi / 2, py0), _line_of(math.pi / 2, py1)}
    for f in found:
        assert any(_same(f, face, math.radians(1), 0.02) for face in faces), f
    assert np.all(rms < 0.01) and np.all(ends - starts + 1 >= 10)
    # a corner is split: no segment spans two walls
    assert len(found) >= 4


def _room_problem(seed=0, nodes=30):
    """Poses round the room, exact scans (5 mm noise), noisy relative-pose edges, and noisy poses to start from."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 2 * math.pi, nodes, endpoint=False)
    truth = np.stack([0.4 + 2.0 * np.cos(t), 0.6 + 1.5 * np.sin(t), t + math.pi / 2], -1)
    scans = []
    for i, pose in enumerate(truth):
        s = room_scan(pose, n=361, t=float(i))
        s.ranges[:] = s.ranges + rng.normal(0.0, 0.005, s.ranges.shape)
        scans.append(s)
    graph = PoseGraph()
    sig = np.array([0.05, 0.05, math.radians(2)])
    info = np.diag(1.0 / sig**2)
    start = truth + rng.normal(0.0, 1.0, truth.shape) * np.array([0.06, 0.06, math.radians(1.5)])
    start[0] = truth[0]
    graph.add_nodes(start)
    for i in range(nodes - 1):
        graph.add_edge(i, i + 1, se2.relative(truth[i], truth[i + 1]) + rng.normal(0.0, sig), info)
    return truth, scans, graph


def _rms(poses, truth):
    return float(np.sqrt(((poses[:, :2] - truth[:, :2]) ** 2).sum(1).mean()))


def test_refinement_reduces_the_pose_error_on_a_room():
    truth, scans, graph = _room_problem()
    p = GraphSlamParams(wall_refinement=True)
    segs = scan_segments(scans, [None] * len(scans), p)
    walls = associate_segments(segs, truth, p)
    assert walls.max() + 1 >= 4  # the room's four walls at least
    before = _rms(graph.poses, truth)
    res = refine_walls(graph, segs, p, ends=scan_wall_ends(scans, [None] * len(scans), p))
    after = _rms(res.poses, truth)
    assert before > 0.05, before
    assert after < 0.2 * before and after < 0.01, (before, after)
    heading = np.abs(se2.wrap_angle(res.poses[:, 2] - truth[:, 2])).max()
    assert heading < math.radians(0.5), heading
    np.testing.assert_array_equal(res.poses[0], graph.poses[0])  # the gauge: the fixed node stays
    assert res.cost_after <= res.cost_before


def test_segments_of_one_wall_seen_from_many_nodes_share_it():
    truth, scans, _ = _room_problem(nodes=12)
    p = GraphSlamParams(wall_refinement=True)
    segs = scan_segments(scans, [None] * len(scans), p)
    walls = associate_segments(segs, truth, p)
    # at the true poses nearly every segment finds its wall (a pillar face seen from under 3 nodes is dropped)
    assert np.mean(walls >= 0) > 0.9 and walls.max() + 1 >= 4
    # each wall's segments lie on one face of the room or the pillar
    xmin, ymin, xmax, ymax = ROOM
    px0, py0, px1, py1 = PILLAR
    faces = [(0.0, xmax), (0.0, xmin), (math.pi / 2, ymax), (math.pi / 2, ymin),
             (0.0, px0), (0.0, px1), (math.pi / 2, py0), (math.pi / 2, py1)]
    alpha = segs.seg_alpha + truth[segs.seg_node, 2]
    tx, ty = truth[segs.seg_node, 0], truth[segs.seg_node, 1]
    d = segs.seg_d + np.cos(alpha) * tx + np.sin(alpha) * ty  # the line in the world frame
    face = np.array([[_same((a, dd), f, math.radians(2), 0.03) for f in faces] for a, dd in zip(alpha, d)])
    on_face = face.sum(1) >= 1  # (a short piece round a corner can be off both faces by more than 2 deg)
    assert on_face.mean() > 0.95
    for w in np.unique(walls[walls >= 0]):
        assert np.any(np.all(face[(walls == w) & on_face], axis=0)), w  # one face holds all of them


def _karto(sim, **settings):
    cls = get_method("karto")
    slam = cls(from_mapping(cls.Params, settings), seed=0)
    return slam.run(sim.frames())


def test_off_leaves_karto_bit_for_bit_and_on_changes_it():
    sim = simulate("office", SimulationParams(duration=20.0, seed=1))
    base = _karto(sim)
    off = _karto(sim, wall_refinement=False, wall_refinement_iterations=1, wall_refinement_range_sigma=0.5)
    t0, p0 = base.trajectory()
    t1, p1 = off.trajectory()
    np.testing.assert_array_equal(t0, t1)
    np.testing.assert_array_equal(p0, p1)
    np.testing.assert_array_equal(base.map().logodds, off.map().logodds)
    assert "wall_refinement" not in base.diagnostics.summary
    on = _karto(sim, wall_refinement=True)
    _, p2 = on.trajectory()
    assert not np.array_equal(p0, p2)
    s = on.diagnostics.summary["wall_refinement"]
    assert s["walls"] > 0 and s["objective_after"] <= s["objective_before"]


def _greedy_walls_numpy(segs, poses, p):
    """The association's former numpy form (one wall scan per segment in Python): the compiled pass must match it."""
    from slam2d.graph.wall_refinement import place_points

    ns = segs.seg_node.size
    wall = np.full(ns, -1, np.int64)
    pose = poses[segs.seg_node]
    ends = np.stack([place_points(pose, segs.seg_ends[:, 0, :]), place_points(pose, segs.seg_ends[:, 1, :])], 1)
    alpha = segs.seg_alpha + pose[:, 2]
    wa, wd, lo, hi = np.zeros(ns), np.zeros(ns), np.zeros(ns), np.zeros(ns)
    nw = 0
    gate_a, gate_d, gap = p.wall_refinement_angle_gate, p.wall_refinement_offset_gate, p.wall_refinement_overlap_gap
    for s in np.argsort(-segs.seg_count, kind="stable"):
        e = ends[s]
        if nw:
            a = wa[:nw]
            da = np.abs(se2.wrap_angle(alpha[s] - a))
            da = np.where(da > 0.5 * math.pi, math.pi - da, da)
            n = np.stack([np.cos(a), np.sin(a)], -1)
            off = np.maximum(np.abs(e[0] @ n.T - wd[:nw]), np.abs(e[1] @ n.T - wd[:nw]))
            t = np.stack([-n[:, 1], n[:, 0]], -1)
            along = np.stack([e[0] @ t.T, e[1] @ t.T], 0)
            g = np.maximum(along.min(0) - hi[:nw], lo[:nw] - along.max(0))
            ok = (da < gate_a) & (off < gate_d) & (g < gap)
            if ok.any():
                cand = np.flatnonzero(ok)
                k = int(cand[np.argmin(off[cand] / gate_d + da[cand] / gate_a)])
                wall[s] = k
                lo[k] = min(lo[k], float(along[:, k].min()))
                hi[k] = max(hi[k], float(along[:, k].max()))
                continue
        a = float(alpha[s])
        n = np.array([math.cos(a), math.sin(a)])
        wa[nw] = a
        wd[nw] = float(e[0] @ n + e[1] @ n) * 0.5
        t = np.array([-n[1], n[0]])
        lo[nw], hi[nw] = min(float(e[0] @ t), float(e[1] @ t)), max(float(e[0] @ t), float(e[1] @ t))
        wall[s] = nw
        nw += 1
    ok = wall >= 0
    pairs = np.unique(np.stack([wall[ok], segs.seg_node[ok]], 1), axis=0)
    keep = np.bincount(pairs[:, 0], minlength=nw) >= p.wall_refinement_minimum_nodes
    index = np.full(nw, -1, np.int64)
    index[keep] = np.arange(int(keep.sum()))
    return np.where(ok, index[np.maximum(wall, 0)], -1)


def test_compiled_association_matches_the_numpy_loop():
    truth, scans, graph = _room_problem(nodes=12)
    p = GraphSlamParams(wall_refinement=True)
    segs = scan_segments(scans, [None] * len(scans), p)
    rng = np.random.default_rng(5)
    for poses in (truth, graph.poses, truth + rng.normal(0, [0.05, 0.05, 0.03], truth.shape)):
        walls = associate_segments(segs, poses, p)
        np.testing.assert_array_equal(walls, _greedy_walls_numpy(segs, poses, p))
        assert walls.max() >= 3  # walls were found, so the comparison is not of two empty answers


def _associate_ends_numpy(ends, poses, gate, min_nodes):
    """The end association's former numpy form (a Python loop over the nodes): the compiled pass must match it."""
    k = len(ends)
    lm = np.full(k, -1, np.int64)
    world = place_points(poses[ends.node], ends.z)
    total, count, last = np.zeros((k, 2)), np.zeros(k), np.full(k, -1, np.int64)
    nl = 0
    for idx in np.split(np.arange(k), np.flatnonzero(np.diff(ends.node)) + 1):
        node = int(ends.node[idx[0]])
        if nl:
            mean = total[:nl] / count[:nl, None]
            d = np.hypot(world[idx, None, 0] - mean[None, :, 0], world[idx, None, 1] - mean[None, :, 1])
            d[:, last[:nl] == node] = np.inf
            for _ in range(idx.size):
                a, b = np.unravel_index(np.argmin(d), d.shape)
                if not d[a, b] < gate:
                    break
                lm[idx[a]] = b
                d[a, :] = np.inf
                d[:, b] = np.inf
        for j in idx:
            if lm[j] < 0:
                lm[j] = nl
                nl += 1
            total[lm[j]] += world[j]
            count[lm[j]] += 1
            last[lm[j]] = node
    keep = np.bincount(lm, minlength=nl) >= min_nodes
    index = np.full(nl, -1, np.int64)
    index[keep] = np.arange(int(keep.sum()))
    return index[lm]


def test_compiled_end_association_matches_the_numpy_loop():
    truth, scans, graph = _room_problem(nodes=12)
    p = GraphSlamParams(wall_refinement=True)
    ends = scan_wall_ends(scans, [None] * len(scans), p)
    assert len(ends) > 10  # the pillar's corners, seen from many nodes
    rng = np.random.default_rng(7)
    for poses in (truth, graph.poses, truth + rng.normal(0, [0.05, 0.05, 0.03], truth.shape)):
        for gate in (0.05, 0.15, 1.0):
            got = associate_ends(ends, poses, gate, 3)
            np.testing.assert_array_equal(got, _associate_ends_numpy(ends, poses, gate, 3))
    # crowded sightings (many per node, landmarks close together): the nearest pair is taken first
    node = np.repeat(np.arange(30), 6)
    z = rng.uniform(-1.0, 1.0, (node.size, 2))
    crowd = EndSightings(node, z, np.tile(np.eye(2), (node.size, 1, 1)))
    poses = rng.normal(0.0, 0.05, (30, 3))
    got = associate_ends(crowd, poses, 0.3, 2)
    assert got.max() >= 1
    np.testing.assert_array_equal(got, _associate_ends_numpy(crowd, poses, 0.3, 2))


def test_frozen_and_given_associations(monkeypatch):
    """The diagnostics' hooks (benchmarks/studies/measure_wall_refinement.py ``freeze=``): frozen associations are
    the first round's, kept; given ones are used instead of the refinement's own."""
    from slam2d.graph import wall_refinement as wr

    truth, scans, graph = _room_problem()
    p = GraphSlamParams(wall_refinement=True)
    segs = scan_segments(scans, [None] * len(scans), p)
    ends = scan_wall_ends(scans, [None] * len(scans), p)
    free = refine_walls(graph, segs, p, ends=ends)
    monkeypatch.setattr(wr, "_FREEZE", {"walls", "ends"})
    frozen = refine_walls(graph, segs, p, ends=ends)
    # the same associations, made at the start poses, as given ones: the same solve, bit for bit
    walls0 = associate_segments(segs, graph.poses, p)
    lm0 = associate_ends(ends, graph.poses, p.wall_refinement_end_gate, p.wall_refinement_minimum_nodes)
    monkeypatch.setattr(wr, "_FREEZE", set())
    monkeypatch.setattr(wr, "_GIVEN", {"walls": lambda s: walls0, "ends": lambda e: lm0})
    given = refine_walls(graph, segs, p, ends=ends)
    np.testing.assert_array_equal(frozen.poses, given.poses)
    assert {r["beams"] for r in frozen.rounds} == {float((walls0[segs.segment] >= 0).sum())}
    assert {r["sightings"] for r in frozen.rounds} == {float((lm0 >= 0).sum())}
    # from 6 cm off the association changes as the poses improve when it is redone, so the two solves differ
    assert not np.array_equal(free.poses, frozen.poses)
    assert len({r["beams"] for r in free.rounds}) > 1
    # given "none": nothing to solve, the poses stay
    monkeypatch.setattr(wr, "_GIVEN", {"walls": lambda s: np.full(s.seg_node.size, -1, np.int64),
                                       "ends": lambda e: np.full(len(e), -1, np.int64)})
    none = refine_walls(graph, segs, p, ends=ends)
    np.testing.assert_array_equal(none.poses, graph.poses)


class _EndPrior:
    """An extra block for refine_walls: the last pose's x held at ``target`` (sigma 1 cm)."""

    def __init__(self, n, target):
        self.n, self.target = n, target

    def associate(self, x):
        return 1

    def objective(self, x):
        return float(((x[-1, 0] - self.target) / 0.01) ** 2)

    def rows(self, x, row0):
        return (np.array([row0]), np.array([3 * (self.n - 1)]), np.array([1.0 / 0.01]),
                np.array([(x[-1, 0] - self.target) / 0.01]))


def test_carried_damping_reaches_the_optimum_of_a_long_chain():
    """A chain of 2000 poses tied by odometry 5 % long, the last one held at its true x: the along-chain mode is
    far weaker than the diagonal the damping scales, so the solve restarted at 1e-4 each round (3 rounds of 2
    steps) stops short of the optimum (a linear problem: the odometry's error spread evenly, up to the prior's
    give); carried over the rounds it gets there."""
    n = 2000
    truth = np.stack([0.01 * np.arange(n), np.zeros(n), np.zeros(n)], -1)
    inc = se2.relative(truth[:-1], truth[1:])
    inc[:, 0] *= 1.05
    start = np.zeros_like(truth)
    for i in range(n - 1):
        start[i + 1] = se2.compose(start[i], inc[i])
    graph = PoseGraph()
    graph.add_nodes(start)
    graph.add_edges(np.arange(n - 1), np.arange(1, n), inc, np.diag(1.0 / np.array([0.01, 0.01, 0.01]) ** 2))
    optimum = start[:, 0] * (truth[-1, 0] / start[-1, 0])  # the odometry's stretch spread evenly
    segs = scan_segments([], [], GraphSlamParams())
    off = [float(np.abs(refine_walls(graph, segs, GraphSlamParams(wall_refinement_carry_damping=carry),
                                     extra=_EndPrior(n, truth[-1, 0]), iterations=3, steps=2).poses[:, 0]
                              - optimum).max())
           for carry in (False, True)]
    assert start[-1, 0] - truth[-1, 0] > 0.9  # 1 m to take out
    assert off[0] > 0.3 and off[1] < 0.02, off


def _box_scene_scan(lost=()):
    """A scan of the room with a box standing 0.25 m in front of its wall at y = 3.5, from (-1, 0) facing +y;
    ``lost``: beams with no return."""
    from slam2d.core import make_scan
    from tests._room import ROOM, _box_hits

    box = (0.0, 2.75, 0.6, 3.25)
    n, fov = 721, math.radians(240)
    a = math.pi / 2 - fov / 2 + fov * np.arange(n) / (n - 1)
    r = np.fmin(_box_hits(-1.0, 0.0, np.cos(a), np.sin(a), ROOM, True),
                _box_hits(-1.0, 0.0, np.cos(a), np.sin(a), box, False))
    r[list(lost)] = np.nan
    return make_scan(0.0, r, -fov / 2, fov / (n - 1), 0.02, 20.0)


def _ends_near(scan, p, point):
    """Whether the refinement's wall-end detection finds an end within 5 cm of ``point`` (world; robot at (-1, 0),
    facing +y)."""
    from slam2d.graph.wall_refinement import scan_wall_ends

    e = scan_wall_ends([scan], [None], p)
    world = np.stack([-1.0 - e.z[:, 1], e.z[:, 0]], 1)
    return bool(np.any(np.hypot(world[:, 0] - point[0], world[:, 1] - point[1]) < 0.05))


def test_end_jump_and_run_of_the_refinement():
    # A box 0.25 m in front of a wall: its far corner is a wall end with only 0.26 m behind it, missed with the
    # 0.3 m jump of wall_end_landmarks and found with wall_refinement_end_jump=0.2; its near corner (a full jump)
    # is lost when a return among the 5 beams before it is lost, and found again with wall_refinement_end_run=3.
    from slam2d.matching.wall_ends import detect_wall_ends

    p = from_mapping(GraphSlamParams, {"wall_refinement": True})
    scan = _box_scene_scan()
    assert not _ends_near(scan, p, (0.0, 3.25)) and _ends_near(scan, p, (0.6, 2.75))
    assert _ends_near(scan, from_mapping(GraphSlamParams, {"wall_refinement": True, "wall_refinement_end_jump": 0.2}),
                      (0.0, 3.25))
    ends = detect_wall_ends(scan, 0.01, max_incidence=p.wall_refinement_end_incidence)
    k = int(ends.beams[np.argmin(np.abs(ends.points[:, 1] + 1.6))])  # the near corner, 1.6 m to the right
    side = int(ends.side[np.argmin(np.abs(ends.points[:, 1] + 1.6))])
    gappy = _box_scene_scan(lost=[k - 3 * side])
    assert not _ends_near(gappy, p, (0.6, 2.75))
    assert _ends_near(gappy, from_mapping(GraphSlamParams, {"wall_refinement": True, "wall_refinement_end_run": 3}),
                      (0.6, 2.75))


def test_two_pass_refines_with_the_landmarks_detector_first_then_its_own():
    # wall_refinement_end_two_pass: a first refinement with wall_end_jump / wall_end_run (here a pillar 0.25 m
    # deep is not an end at a 0.5 m jump), its poses the start of the second with the refinement's own jump
    # (0.2 m: the pillar's corners are); the same as the two solves by hand, bit for bit, and not the one-pass solve.
    from slam2d.graph.wall_refinement import refine_path

    truth, scans, graph = _room_problem()
    settings = {"wall_refinement": True, "wall_end_jump": 0.5, "wall_refinement_end_jump": 0.2}
    one = from_mapping(GraphSlamParams, settings)
    two = from_mapping(GraphSlamParams, {**settings, "wall_refinement_end_two_pass": True})
    few = scan_wall_ends(scans, [None] * len(scans), two, jump=0.5, run=two.wall_end_run)
    many = scan_wall_ends(scans, [None] * len(scans), two)
    assert len(few) < len(many)
    segs = scan_segments(scans, [None] * len(scans), two)
    first = refine_walls(graph, segs, two, ends=few)
    g = graph.copy()
    g.poses = first.poses
    second = refine_walls(g, segs, two, ends=many)
    res, _ = refine_path(scans, graph.poses, two, graph=graph)
    np.testing.assert_array_equal(res.poses, second.poses)
    assert len(res.rounds) == len(first.rounds) + len(second.rounds) and res.cost_before == first.cost_before
    single, _ = refine_path(scans, graph.poses, one, graph=graph)
    assert len(single.rounds) == len(second.rounds) and np.abs(single.poses - res.poses).max() > 0
    assert _rms(res.poses, truth) < 0.01


def test_no_odometry_edge_into_a_break_where_another_recording_starts():
    """A resumed session's new recording: its odometry does not follow on from the old one's last frame, so the
    refinement over all frames must not tie the two by it (the graph's relocation edge does)."""
    from slam2d.graph.wall_refinement import odometry_graph

    p = from_mapping(GraphSlamParams, {})
    poses = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [2.1, 5.0, 1.0], [3.1, 5.0, 1.0]])
    # the second recording's odometry starts anywhere (here: far off and turned)
    odom = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [-7.0, 3.0, -2.0], [-6.0, 3.0, -2.0]])
    whole = odometry_graph(poses, odom, p)
    cut = odometry_graph(poses, odom, p, breaks=np.array([3]))
    assert whole.num_edges == 4 and cut.num_edges == 3
    assert [(int(i), int(j)) for i, j in zip(cut.edge_i, cut.edge_j)] == [(0, 1), (1, 2), (3, 4)]
    assert np.allclose(cut.measurements[2], se2.relative(odom[3], odom[4]))
