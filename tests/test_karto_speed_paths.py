"""Speed paths of the karto front end and the grid cache give the plain numpy results bit for bit."""

from __future__ import annotations

import math

import numpy as np
import pytest

from slam2d.graph.kernels import _runs, _within
from slam2d.matching.correlative import CorrelativeMatcher
from slam2d.matching.correlative_search import _COVARIANCE_BAND, _band_on_part_edge
from slam2d.matching.grid_cache import GridCache


def _concat(parts):
    """(points, sigmas) of a list of per-node (points, sigmas), concatenated."""
    if not parts:
        return np.zeros((0, 2)), np.zeros(0)
    return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])


def _runs_numpy(mask):
    m = np.concatenate([[False], mask, [False]]).astype(np.int8)
    d = np.diff(m)
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist(), strict=True))


@pytest.mark.parametrize("seed", range(6))
def test_runs_are_numpys(seed):
    rng = np.random.default_rng(seed)
    for n in (0, 1, 2, 7, 300):
        mask = rng.random(n) < (0.2 + 0.15 * seed)
        assert [tuple(r) for r in _runs(mask)] == _runs_numpy(mask)
    assert _runs(np.ones(5, bool)) == [[0, 5]]


def test_within_is_numpys_squared_distance_test():
    rng = np.random.default_rng(3)
    xy = rng.uniform(-20.0, 20.0, (1500, 2))
    xy[7] = xy[3] + [3.0, 4.0]  # exactly on the limit (5 m): excluded by both
    for node in (0, 3, 1499):
        limit2 = 5.0**2 + 1e-9
        expect = ((xy - xy[node]) ** 2).sum(axis=1) < limit2
        assert np.array_equal(_within(xy, node, limit2), expect)


@pytest.mark.parametrize("seed", range(40))
def test_part_edge_test_is_the_numpy_one(seed):
    rng = np.random.default_rng(seed)
    na, n = 21, 17
    resp = rng.random((na, n, n)) * rng.random()
    k, h = int(rng.integers(0, 4)), int(rng.integers(1, 6))
    a_lo = int(rng.integers(0, na - 2 * k))
    i_lo, j_lo = (int(v) for v in rng.integers(0, n - 2 * h, 2))
    best = float(resp[a_lo:a_lo + 2 * k + 1, i_lo:i_lo + 2 * h + 1, j_lo:j_lo + 2 * h + 1].max())
    band = resp[a_lo:a_lo + 2 * k + 1, i_lo:i_lo + 2 * h + 1, j_lo:j_lo + 2 * h + 1] >= best - _COVARIANCE_BAND
    expect = bool((a_lo > 0 and band[0].any()) or (a_lo + 2 * k < na - 1 and band[-1].any())
                  or (i_lo > 0 and band[:, 0].any()) or (i_lo + 2 * h < n - 1 and band[:, -1].any())
                  or (j_lo > 0 and band[:, :, 0].any()) or (j_lo + 2 * h < n - 1 and band[:, :, -1].any()))
    got = _band_on_part_edge(resp, best - _COVARIANCE_BAND, a_lo, 2 * k + 1, i_lo, j_lo, 2 * h + 1)
    assert got == expect


def test_entry_columns_are_the_concatenated_points_of_its_nodes():
    rng = np.random.default_rng(5)
    parts = [rng.uniform(-3.0, 3.0, (int(rng.integers(0, 50)), 2)) for _ in range(12)]
    sig = [rng.uniform(0.01, 0.05, p.shape[0]) for p in parts]
    m = CorrelativeMatcher(search_size=0.3, resolution=0.01)
    cache = GridCache(m, lambda i: (parts[i], sig[i]))
    lo, hi = np.array([-1.0, -1.0]), np.array([1.0, 1.0])
    e = cache.reserve([0, 1, 2], lo, hi)
    for nodes in ([0, 1, 2, 3], [0, 1, 2, 3, 4], list(range(12))):  # grows by one node, then by several
        e = cache.reserve(nodes, lo, hi, max_extra=20)
        cache._parts(e)
        n = len(e["order"])
        for k0, k1 in ((0, n), (0, 1), (2, n), (n, n)):
            px, py, s = cache._columns(e, k0, k1)
            pts, ss = _concat([(parts[i], sig[i]) for i in e["order"][k0:k1]])
            assert np.array_equal(px, pts[:, 0]) and np.array_equal(py, pts[:, 1]) and np.array_equal(s, ss)


def test_compiled_box_reductions_equal_the_numpy_ones():
    """_boxes_extent and _boxes_sigma (GridCache._extent, _sigma_of) against the numpy reductions they replace."""
    from slam2d.matching.correlative_search import _boxes_extent, _boxes_sigma

    rng = np.random.default_rng(3)
    for trial in range(300):
        n = int(rng.integers(1, 12))
        box = np.empty((20, 6))
        box[:, :2] = rng.normal(0.0, 5.0, (20, 2))
        box[:, 2:4] = box[:, :2] + rng.uniform(0.0, 3.0, (20, 2))
        box[:, 4] = rng.uniform(0.0, 0.2, 20)
        # The one sigma: shared, mixed, NaN (not one), or inf (a node without points).
        box[:, 5] = rng.choice([0.02, 0.03, np.nan, np.inf], 20, p=[0.7, 0.1, 0.1, 0.1]) if trial % 2 else 0.02
        empty = rng.random(20) < 0.1
        box[empty, :2], box[empty, 2:4], box[empty, 4], box[empty, 5] = np.inf, -np.inf, 0.0, np.inf
        idx = rng.choice(20, n, replace=False).astype(np.int64)
        b = box[idx]
        out = _boxes_extent(box, idx)
        assert np.array_equal(out[0:2], b[:, :2].min(axis=0))
        assert np.array_equal(out[2:4], b[:, 2:4].max(axis=0))
        assert out[4] == b[:, 4].max()
        u = box[idx, 5]
        u = u[u != np.inf]
        want = None if (u.size == 0 or np.isnan(u[0]) or not np.all(u == u[0])) else float(u[0])
        ok, got = _boxes_sigma(box, idx)
        assert (float(got) if ok else None) == want


def test_compiled_point_transforms_equal_transform_points():
    """kernels' _transform_xy and _beam_points against se2.transform_points (bit for bit)."""
    import math

    from slam2d.core import se2
    from slam2d.graph.kernels import _beam_points, _transform_xy

    rng = np.random.default_rng(11)
    for _ in range(200):
        pose = np.array([rng.normal(0, 50), rng.normal(0, 50), rng.uniform(-4, 4)])
        pts = rng.normal(0, 20, (int(rng.integers(0, 700)), 2))
        c, s = math.cos(pose[2]), math.sin(pose[2])
        assert np.array_equal(_transform_xy(pose[0], pose[1], c, s, pts), se2.transform_points(pose, pts))
        n = int(rng.integers(1, 1100))
        ranges = rng.uniform(0.0, 80.0, n)
        a = rng.uniform(-math.pi, math.pi, n)
        cos, sin = np.cos(a), np.sin(a)
        use = rng.random(n) < 0.8
        r = ranges[use]
        want = se2.transform_points(pose, np.stack([r * cos[use], r * sin[use]], axis=-1))
        assert np.array_equal(_beam_points(pose[0], pose[1], c, s, ranges, cos, sin, use), want)


def test_compiled_smear_sigmas_equal_sigmas_for_and_the_gap_share():
    """The compiled reference sigmas (CorrelativeMatcher.reference_sigmas, sigmas_for) against their numpy
    arithmetic: the smear and the range sigma in quadrature, clipped, then the beam-gap share in quadrature."""

    rng = np.random.default_rng(13)
    for trial in range(200):
        res = float(rng.choice([0.01, 0.05]))
        m = CorrelativeMatcher(search_size=0.3, resolution=res, smear_deviation=float(rng.uniform(0.005, 0.08)))
        n = int(rng.integers(1, 800))
        sig = rng.uniform(0.0, 0.1, n)
        sig[rng.random(n) < 0.1] = np.nan
        if trial % 10 == 0:
            sig[0] = np.inf
        ranges = rng.uniform(0.0, 80.0, n)
        use = rng.random(n) < 0.8
        spacing = float(rng.choice([0.0, 0.5, 1.0]))
        inc = float(rng.uniform(0.001, 0.02))
        with np.errstate(over="ignore"):  # an infinite sigma becomes the largest float, then squared
            b = np.nan_to_num(sig[use], nan=0.0)
            base = np.full(b.shape[0], m.smear_deviation)
            want = np.clip(np.sqrt(base * base + b * b), 0.5 * res, 10.0 * res)
        assert np.array_equal(m.sigmas_for(sig[use], int(use.sum())), want)
        if spacing > 0:
            gap = spacing * ranges[use] * abs(inc)
            want = np.minimum(np.sqrt(want * want + gap * gap), 10.0 * res)
        got = m.reference_sigmas(sig, use, ranges, spacing, -inc if trial % 2 else inc)
        assert np.array_equal(got, want)
    m = CorrelativeMatcher(resolution=0.01, smear_deviation=0.03)
    assert np.array_equal(m.sigmas_for(None, 5), np.full(5, 0.03))  # no range sigma: the smear itself


def test_reference_positions_updated_row_by_row_are_the_whole_transform():
    """The cached reference positions, redone for appended or moved last nodes only, equal the transform of every node."""
    from slam2d.core import se2
    from slam2d.graph.frontend import GraphFrontend
    from slam2d.graph.params import GraphSlamParams

    rng = np.random.default_rng(11)
    fe = GraphFrontend(GraphSlamParams())

    def whole():
        return se2.transform_points(fe.graph.poses, fe._bary_base[:, None, :])[:, 0, :]

    for step in range(60):
        action = rng.integers(0, 4) if fe.graph.num_nodes else 0
        if action == 0:  # a kept scan: a new node with its barycentre
            fe.graph.add_node(rng.uniform(-5.0, 5.0, 3))
            fe._bary_base = np.vstack([fe._bary_base, rng.uniform(-3.0, 3.0, (1, 2))])
        elif action == 1:  # the near links' mean moves the newest node
            fe.graph.poses[-1] = fe.graph.poses[-1] + rng.normal(0.0, 0.05, 3)
        elif action == 2:  # an optimisation moves every node
            fe.graph.poses[:] = fe.graph.poses + rng.normal(0.0, 0.01, fe.graph.poses.shape)
        else:  # an older node alone moves (in place)
            fe.graph.poses[int(rng.integers(0, fe.graph.num_nodes))] += 0.01
        got = fe.reference_positions()
        assert np.array_equal(got, whole()), step
        assert np.array_equal(fe.reference_positions(), got)  # asked again: the cached answer


@pytest.mark.parametrize("n", [0, 1, 31, 64, 65, 95, 96, 97, 500, 723])
def test_interleaved_points_are_the_argsort_gather(n):
    from slam2d.matching.correlative_search import _PRUNE_CHUNK, _interleaved

    q = np.random.default_rng(n).normal(size=(n, 2))
    stride = n // _PRUNE_CHUNK
    expect = q if stride < 2 else q[np.argsort(np.arange(n) % stride, kind="stable")]
    got = _interleaved(q)
    assert got.flags.c_contiguous
    assert np.array_equal(got, expect)
    if stride >= 2:
        assert got is not q and sorted(map(tuple, got)) == sorted(map(tuple, q))


def test_search_offsets_are_the_arange_product():
    from slam2d.matching.correlative import _offsets

    for n_steps, half, step_m in ((31, 15, 0.02), (9, 4, 0.01), (5, 2, 0.1), (61, 30, 2 * 0.05)):
        expect = (np.arange(n_steps) - half) * step_m
        assert np.array_equal(_offsets(n_steps, half, step_m), expect)
        assert _offsets(n_steps, half, step_m) is _offsets(n_steps, half, step_m)


@pytest.mark.parametrize("seed", range(5))
def test_in_range_beams_are_valid_and_below_the_threshold(seed):
    from slam2d.core.scan import make_scan
    from slam2d.graph.kernels import _in_range, _valid_within

    rng = np.random.default_rng(seed)
    r = rng.uniform(0.0, 30.0, 361)
    r[rng.random(361) < 0.2] = np.nan
    r[5] = 12.5  # exactly on the threshold: kept by both
    r[6] = np.inf
    for thr in (12.5, 0.0, 40.0, np.inf):
        with np.errstate(invalid="ignore"):
            expect = ~np.isnan(r) & (r <= thr)
        use, count = _valid_within(r, thr)
        assert use.dtype == np.bool_ and np.array_equal(use, expect) and count == int(expect.sum())
    scan = make_scan(0.0, r, -1.5, 3.0 / 360, range_max=29.0)
    with np.errstate(invalid="ignore"):
        expect = scan.valid & (scan.ranges <= 12.5)
    use, any_use = _in_range(scan, 12.5)
    assert np.array_equal(use, expect) and any_use == bool(expect.any())
    none, any_none = _in_range(scan, -1.0)
    assert not none.any() and not any_none


@pytest.mark.parametrize("seed", range(8))
def test_closest_row_is_numpys_argmin(seed):
    from slam2d.graph.kernels import _closest_row

    rng = np.random.default_rng(seed)
    ref = np.round(rng.uniform(-5.0, 5.0, (400, 2)), 1)  # coarse values: ties happen
    for _ in range(20):
        idx = rng.choice(400, int(rng.integers(1, 80)), replace=False).astype(np.int64)
        t = np.round(rng.uniform(-5.0, 5.0, 2), 1)
        expect = int(np.argmin(((ref[idx] - t) ** 2).sum(axis=1)))
        assert _closest_row(ref, idx, float(t[0]), float(t[1])) == expect
    ref[7] = np.nan
    idx = np.array([3, 9, 7, 12], np.int64)
    assert _closest_row(ref, idx, 0.0, 0.0) == int(np.argmin(((ref[idx] - 0.0) ** 2).sum(axis=1))) == 2


def _peaks_numpy(surface, floor):
    padded = np.pad(surface, 1, constant_values=-np.inf)
    ny, nx = surface.shape
    peak = surface >= floor
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            if dy or dx:
                peak &= surface >= padded[1 + dy : 1 + dy + ny, 1 + dx : 1 + dx + nx]
    return peak


@pytest.mark.parametrize("seed", range(8))
def test_peaks_are_the_padded_comparisons(seed):
    from slam2d.matching.correlative_search import _peaks

    rng = np.random.default_rng(seed)
    for shape in ((1, 1), (2, 3), (21, 21), (40, 17)):
        s = np.round(rng.uniform(-1.0, 1.0, shape), 1)  # plateaus: equal neighbours count as peaks
        if seed % 2:
            s[rng.random(shape) < 0.05] = np.nan
        for floor in (-np.inf, -1.0, 0.3, 0.9):
            expect = _peaks_numpy(s, floor)
            assert np.array_equal(_peaks(s, floor), expect)


@pytest.mark.parametrize("seed", range(5))
def test_query_box_is_the_array_arithmetic(seed):
    from slam2d.matching.correlative import _ANGLES
    from slam2d.matching.correlative_search import _rotated_extent

    rng = np.random.default_rng(seed)
    m = CorrelativeMatcher(search_size=0.3, resolution=0.01)
    q = rng.uniform(-8.0, 8.0, (300, 2))
    prior = rng.uniform(-50.0, 50.0, 3)
    for offset in (0.35, 1.4):
        lo, hi = m.query_box(q, prior, offset)
        lin = _ANGLES[("box", offset)]
        angles = prior[2] + lin
        x_lo, y_lo, x_hi, y_hi, reach = _rotated_extent(np.cos(angles), np.sin(angles), q)
        pad = 0.5 * m.search_size + reach * (1.0 - math.cos(0.5 * (angles[1] - angles[0]))) + m.resolution
        assert np.array_equal(lo, np.array([x_lo, y_lo]) + prior[:2] - pad)
        assert np.array_equal(hi, np.array([x_hi, y_hi]) + prior[:2] + pad)


@pytest.mark.parametrize("seed", range(6))
def test_equal_rows_and_transform_rows_are_numpys(seed):
    from slam2d.core import se2
    from slam2d.graph.kernels import _equal_rows, _transform_rows

    rng = np.random.default_rng(seed)
    a = rng.uniform(-5.0, 5.0, (int(rng.integers(1, 40)), 3))
    b = np.concatenate([a, rng.uniform(-5.0, 5.0, (int(rng.integers(0, 5)), 3))])
    if seed % 3 == 1:
        b[int(rng.integers(0, a.shape[0])), int(rng.integers(0, 3))] += 1e-12
    if seed % 3 == 2:
        a[int(rng.integers(0, a.shape[0])), 0] = np.nan
        b[: a.shape[0]] = a  # NaN == NaN is False: array_equal stops there too
    same = _equal_rows(a, b)
    m = min(a.shape[0], b.shape[0])
    expect = next((i for i in range(m) if not np.array_equal(a[i], b[i])), m)
    assert same == expect
    assert _equal_rows(b, a) == expect
    base = rng.uniform(-3.0, 3.0, (b.shape[0], 2))
    for first in range(b.shape[0] + 1):
        out = np.full((b.shape[0], 2), 7.0)
        _transform_rows(b, base, np.cos(b[first:, 2]), np.sin(b[first:, 2]), first, out)
        # What reference_positions transformed before: the rows from ``first`` (their cos and sin as one array).
        rows = se2.transform_points(b[first:], base[first:, None, :])[:, 0, :]
        assert np.array_equal(out[first:], rows, equal_nan=True) and np.all(out[:first] == 7.0)


@pytest.mark.parametrize("seed", range(6))
def test_runs_counted_are_runs_and_their_flag_counts(seed):
    from slam2d.graph.kernels import _runs_counted

    rng = np.random.default_rng(seed)
    for n in (0, 1, 5, 300):
        mask = rng.random(n) < 0.6
        flags = rng.random(n) < 0.3
        expect = [[a, b, int(flags[a:b].sum())] for a, b in _runs_numpy(mask)]
        assert _runs_counted(mask, flags) == expect


@pytest.mark.parametrize("seed", range(6))
def test_unknown_nodes_are_the_masked_index(seed):
    from slam2d.matching.correlative_search import _unknown_nodes

    rng = np.random.default_rng(seed)
    known = rng.random(50) < 0.5
    for size in (1, 7, 40):
        idx = rng.integers(0, 60, size).astype(np.int64)  # some past known's end, some repeated
        top, unknown = _unknown_nodes(known, idx)
        padded = np.concatenate([known, np.zeros(61, bool)])
        assert top == int(idx.max()) + 1
        assert np.array_equal(unknown, idx[~padded[idx]])


def test_barycentre_store_is_the_stacked_rows():
    """_append_node's growing store of barycentres holds what stacking them row by row gives, also after
    a caller replaced ``_bary_base`` (as tests do)."""
    from slam2d.core.scan import make_scan
    from slam2d.graph.frontend import GraphFrontend
    from slam2d.graph.params import GraphSlamParams

    rng = np.random.default_rng(2)
    fe = GraphFrontend(GraphSlamParams())
    stacked = np.zeros((0, 2))
    for k in range(40):
        if k == 17:  # replaced from outside: the store starts again from it
            fe._bary_base = stacked = np.vstack([stacked, [[1.5, -2.0]]])
            fe.graph.add_node(np.zeros(3))
        scan = make_scan(float(k), rng.uniform(1.0, 9.0, 181), -1.5, 3.0 / 180, range_max=10.0)
        use = scan.valid
        sig = np.full(181, 0.01)
        points, sigmas = fe._scan_points(scan, sig, use)
        fe._append_node(scan, points, sigmas, rng.uniform(-1.0, 1.0, 3), np.zeros(3), float(k))
        stacked = np.vstack([stacked, points.mean(axis=0)[None, :]])
        assert np.array_equal(fe._bary_base, stacked)


def test_match_heading_wrap_in_floats_is_numpys():
    rng = np.random.default_rng(0)
    t = np.concatenate([rng.uniform(-20.0, 20.0, 20000), [np.pi, -np.pi, 3 * np.pi, 0.0, -0.0, 1e-300]])
    for v in t:
        a = np.array([0.0, 0.0, v])
        a[2] = (a[2] + np.pi) % (2 * np.pi) - np.pi
        assert np.float64((float(v) + math.pi) % (2 * math.pi) - math.pi).tobytes() == a[2].tobytes()


def test_edge_between_is_numpys_any():
    from slam2d.graph.kernels import _edge_between

    rng = np.random.default_rng(4)
    ei = rng.integers(0, 30, 200).astype(np.int64)
    ej = rng.integers(0, 30, 200).astype(np.int64)
    for i in range(30):
        for j in range(30):
            expect = bool(np.any(((ei == i) & (ej == j)) | ((ei == j) & (ej == i))))
            assert bool(_edge_between(ei, ej, i, j)) == expect
    assert not _edge_between(ei[:0], ej[:0], 1, 2)


@pytest.mark.parametrize("seed", range(5))
def test_plane_max_is_numpys(seed):
    from slam2d.matching.correlative_search import _plane_max

    rng = np.random.default_rng(seed)
    resp = rng.uniform(-1.0, 1.0, (7, 9, 9))
    resp[2] = -1.0  # an unscored angle
    if seed % 2:
        resp[4, 3, 3] = np.nan
    for a in range(7):
        expect = float(resp[a].max())
        got = _plane_max(resp, a)
        assert (np.isnan(got) and np.isnan(expect)) or got == expect


@pytest.mark.parametrize("seed", range(6))
def test_max_argmax0_is_numpys(seed):
    from slam2d.matching.correlative_search import _max_argmax0

    rng = np.random.default_rng(seed)
    resp = np.round(rng.uniform(-1.0, 1.0, (21, 13, 13)), 1)  # ties across angles
    if seed % 2:
        resp[rng.random(resp.shape) < 0.01] = np.nan
    best, at = _max_argmax0(resp)
    assert np.array_equal(best, resp.max(axis=0), equal_nan=True)
    assert np.array_equal(at, resp.argmax(axis=0))


def test_wrap_of_a_float_difference_is_wrap_angles():
    from slam2d.core import se2

    rng = np.random.default_rng(1)
    a = rng.uniform(-10.0, 10.0, 5000)
    b = rng.uniform(-10.0, 10.0, 5000)
    for x, y in zip(a, b):
        d = np.float64(x) - np.float64(y)
        assert np.float64(se2.wrap_scalar(float(d))).tobytes() == np.float64(float(se2.wrap_angle(d))).tobytes()


def test_pose_graph_single_node_and_edge_paths_are_the_batch_ones():
    from slam2d.backends import PoseGraph

    rng = np.random.default_rng(9)
    one, batch = PoseGraph(), PoseGraph()
    poses = rng.uniform(-12.0, 12.0, (60, 3))
    poses[5, 2] = np.pi
    poses[6, 2] = -np.pi
    for p in poses:
        one.add_node(p)
    batch.add_nodes(poses)
    assert np.array_equal(one.poses, batch.poses)
    info = np.diag([4.0, 5.0, 6.0])
    for k in range(59):
        z = rng.uniform(-9.0, 9.0, 3)
        one.add_edge(k, k + 1, z, info)
        batch.add_edges([k], [k + 1], z[None], info[None])
    assert np.array_equal(one.measurements, batch.measurements)
    assert np.array_equal(one.information, batch.information)
    with pytest.raises(Exception):
        one.add_node(np.array([0.0, np.nan, 0.0]))  # the checked path still refuses it


@pytest.mark.parametrize("seed", range(4))
def test_node_blocks_of_points_is_node_blocks_at_the_largest_sigma(seed):
    from slam2d.matching.correlative_search import _BOUND_BLOCK, _node_blocks, _node_blocks_of

    rng = np.random.default_rng(seed)
    pts = rng.uniform(-4.0, 4.0, (int(rng.integers(0, 300)), 2))
    sig = rng.uniform(0.005, 0.08, pts.shape[0])
    got = _node_blocks_of(pts, sig, 0.03, 0.01, _BOUND_BLOCK)
    smax = float(sig.max()) if sig.size else 0.03
    want = _node_blocks(np.ascontiguousarray(pts[:, 0]), np.ascontiguousarray(pts[:, 1]), smax, 0.01, _BOUND_BLOCK)
    for g, w in zip(got, want, strict=True):
        assert g.dtype == w.dtype and np.array_equal(g, w)
    if sig.size > 3:  # the largest sigma decides the reach: a wider one gives other blocks
        wide = sig.copy()
        wide[3] = 0.2
        assert not all(np.array_equal(g, w) for g, w in zip(_node_blocks_of(pts, wide, 0.03, 0.01, _BOUND_BLOCK), want))


def _chain_covariance_before(seq_steps, i, last, step, step_cov):
    """GraphFrontend._chain_covariance as it was written first (the whole relative pose composed)."""
    from slam2d.core import se2

    rel = np.zeros(3)
    acc = np.zeros((3, 3))
    for z, c in [seq_steps[k] for k in range(i, last)] + [(step, step_cov)]:
        ct, st = math.cos(rel[2]), math.sin(rel[2])
        ja = np.array([[1.0, 0.0, -st * z[0] - ct * z[1]], [0.0, 1.0, ct * z[0] - st * z[1]], [0.0, 0.0, 1.0]])
        jb = np.array([[ct, -st, 0.0], [st, ct, 0.0], [0.0, 0.0, 1.0]])
        acc = ja @ acc @ ja.T + jb @ c @ jb.T
        rel = se2.compose(rel, z)
    return 0.5 * (acc + acc.T) + np.eye(3) * 1e-12


@pytest.mark.parametrize("seed", range(4))
def test_chain_covariance_is_the_composed_one(seed):
    from slam2d.graph.frontend import GraphFrontend
    from slam2d.graph.params import GraphSlamParams

    rng = np.random.default_rng(seed)
    fe = GraphFrontend(GraphSlamParams())

    def cov():
        a = rng.normal(0.0, 0.1, (3, 3))
        return a @ a.T + np.eye(3) * 1e-4

    fe._seq_steps = [(np.array([rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), rng.uniform(-2.0, 2.0)]), cov())
                     for _ in range(40)]
    step, step_cov = rng.uniform(-0.5, 0.5, 3), cov()
    for i, last in ((0, 0), (0, 39), (12, 30), (38, 39)):
        got = fe._chain_covariance(i, last, step, step_cov)
        assert np.array_equal(got, _chain_covariance_before(fe._seq_steps, i, last, step, step_cov))


def test_reserve_of_a_range_is_reserve_of_its_list():
    """GridCache.reserve with node ranges (near chains) keeps the same entries as with the lists."""
    rng = np.random.default_rng(8)
    parts = [(rng.uniform(-3.0, 3.0, (30, 2)) + [0.2 * i, 0.0], rng.uniform(0.01, 0.03, 30)) for i in range(80)]
    m = CorrelativeMatcher(search_size=0.3, resolution=0.01)
    a = GridCache(m, lambda i: parts[i], max_entries=4)
    b = GridCache(m, lambda i: parts[i], max_entries=4)
    for _ in range(200):
        lo_n = int(rng.integers(0, 70))
        hi_n = lo_n + int(rng.integers(1, 10))
        c = rng.uniform(-2.0, 2.0, 2)
        lo, hi = c - 1.0, c + 1.0
        extra = int(rng.integers(0, 4))
        ea = a.reserve(range(lo_n, hi_n), lo, hi, max_extra=extra)
        eb = b.reserve(list(range(lo_n, hi_n)), lo, hi, max_extra=extra)
        assert ea["order"] == eb["order"] and ea["nodes"] == eb["nodes"] and ea["span"] == eb["span"]
        assert [x["order"] for x in a._entries] == [x["order"] for x in b._entries]
    assert a.extensions == b.extensions > 0 and a.builds == b.builds


@pytest.mark.parametrize("seed", range(5))
def test_column_means_are_numpys_mean(seed):
    from slam2d.graph.kernels import _column_means

    rng = np.random.default_rng(seed)
    for n in (1, 2, 7, 8, 9, 100, 361, 1081, 4000):
        p = rng.normal(0.0, 10.0, (n, 2)) * rng.uniform(0.1, 100.0)
        assert np.array_equal(_column_means(p), p.mean(axis=0))


def test_take3_is_the_three_fancy_indexes():
    from slam2d.matching.grid_cache import _take3

    rng = np.random.default_rng(6)
    store = rng.normal(size=(3, 500))
    px, py, sig = store[0, 40:400], store[1, 40:400], store[2, 40:400]  # row slices, as _columns gives
    for idx in (np.zeros(0, np.int64), np.array([0, 359], np.int64), np.sort(rng.choice(360, 120, replace=False))):
        got = _take3(px, py, sig, idx.astype(np.int64))
        for g, w in zip(got, (px[idx], py[idx], np.ascontiguousarray(sig[idx])), strict=True):
            assert g.flags.c_contiguous and np.array_equal(g, w)


def test_point_columns_are_the_slices_and_their_ranges():
    from slam2d.matching.correlative_search import _point_columns, _ranges

    q = np.random.default_rng(7).normal(0.0, 5.0, (333, 2))
    qx, qy, rng = _point_columns(q)
    ex, ey = np.ascontiguousarray(q[:, 0]), np.ascontiguousarray(q[:, 1])
    assert np.array_equal(qx, ex) and np.array_equal(qy, ey) and np.array_equal(rng, _ranges(ex, ey))
    assert qx.flags.c_contiguous and qy.flags.c_contiguous


@pytest.mark.parametrize("seed", range(6))
def test_columns_copied_like_another_entry_are_the_parts(seed):
    from slam2d.matching.grid_cache import _copy_like

    rng = np.random.default_rng(seed)
    parts = [(rng.uniform(-3.0, 3.0, (int(rng.integers(0, 40)), 2)), None) for _ in range(30)]
    parts = [(p, rng.uniform(0.01, 0.05, p.shape[0])) for p, _ in parts]
    m = CorrelativeMatcher(search_size=0.3, resolution=0.01)
    cache = GridCache(m, lambda i: parts[i])
    like = {"parts": [], "order": list(range(5, 25))}
    cache._columns(like, 0, 20)  # like's rows hold nodes 5..24
    # nodes in runs of like's, out of its order, not in it, and one moved (new arrays for node 12)
    order = [3, 4] + list(range(8, 15)) + [20, 19, 26] + list(range(21, 25))
    mine = [parts[i] for i in order]
    mine[order.index(12)] = (parts[12][0].copy(), parts[12][1])
    size = sum(p[0].shape[0] for p in mine)
    cols = np.full((3, size + 5), 9.0)
    _copy_like(cols, mine, like)
    pts, sig = _concat(mine)
    assert np.array_equal(cols[0, :size], pts[:, 0]) and np.array_equal(cols[1, :size], pts[:, 1])
    assert np.array_equal(cols[2, :size], sig) and np.all(cols[:, size:] == 9.0)
