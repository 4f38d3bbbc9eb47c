"""The sequential matcher's step along a corridor is unbiased (no systematic shrink of the trajectory).

A corridor with door recesses, scanned by exact ray casting with a 1 deg, 180 deg laser:
one scan is the reference, a second taken 0.2-1 m further along (either way, the
whole world turned to several headings) is matched against it. Walls seen at a
glancing angle come back as dots ever further apart away from the robot; smeared as
dots, the denser part near the reference's robot pulls the match toward it and steps
came out 1-2 cm short. Filling the gaps between neighbouring reference points
(``reference_gap_fill``) removes that.
"""

from __future__ import annotations

import numpy as np

from slam2d.core import se2
from slam2d.graph import GraphSlamParams
from slam2d.graph.frontend import GraphFrontend
from slam2d.graph.nodes import _fill_gaps

_ANGLES = np.radians(np.arange(-90.0, 90.5, 1.0))


def _corridor():
    segs = [(-15, -1.2, 15, -1.2), (-15, 1.2, 15, 1.2), (-15, -1.2, -15, 1.2), (15, -1.2, 15, 1.2)]
    for x in np.arange(-12, 12, 3.0):
        segs += [(x, 1.2, x, 1.5), (x + 1, 1.2, x + 1, 1.5), (x, 1.5, x + 1, 1.5)]
    for x in np.arange(-10.5, 12, 4.0):
        segs += [(x, -1.2, x, -1.45), (x + 0.9, -1.2, x + 0.9, -1.45), (x, -1.45, x + 0.9, -1.45)]
    return np.array(segs, dtype=float)


def _scan(segs, pose, rng, max_range=8.0):
    """Endpoints (robot frame) of the beams hitting a segment within ``max_range``, 1 cm range noise."""
    th = pose[2] + _ANGLES
    dx, dy = np.cos(th)[:, None], np.sin(th)[:, None]
    x1, y1, x2, y2 = (c[None, :] for c in segs.T)
    ex, ey = x2 - x1, y2 - y1
    den = dx * ey - dy * ex
    wx, wy = x1 - pose[0], y1 - pose[1]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (wx * ey - wy * ex) / den
        u = (wx * dy - wy * dx) / den
    r = np.where((t > 1e-9) & (u >= 0) & (u <= 1), t, np.inf).min(axis=1)
    r = r + rng.normal(0.0, 0.01, r.shape)
    ok = r < max_range
    return np.c_[r * np.cos(_ANGLES), r * np.sin(_ANGLES)][ok], r[ok]


def _along_errors(fill: float, trials: int = 120, seed: int = 3):
    p = GraphSlamParams(reference_gap_fill=fill)
    m = GraphFrontend(p).sequential
    rng = np.random.default_rng(seed)
    segs0 = _corridor()
    out = {1: [], -1: []}
    for k in range(trials):
        turn = (0.0, 0.5, 2.0, np.pi, -1.2)[k % 5]
        rot = np.array([0.0, 0.0, turn])
        segs = np.c_[se2.transform_points(rot, segs0[:, :2]), se2.transform_points(rot, segs0[:, 2:])]
        sign = 1 if k % 2 else -1
        a = np.array([rng.uniform(-8, 8), rng.uniform(-0.3, 0.3), (0.0 if sign > 0 else np.pi) + rng.normal(0, 0.05)])
        b = a + np.array([sign * rng.uniform(0.2, 1.0), rng.normal(0, 0.05), rng.normal(0, 0.03)])
        a, b = se2.compose(rot, a), se2.compose(rot, b)
        pa, ra = _scan(segs, a, rng)
        pb, _ = _scan(segs, b, rng)
        sig = np.sqrt(p.correlation_search_space_smear_deviation**2 + (p.smear_beam_spacing * ra * np.radians(1.0)) ** 2)
        sig = np.minimum(sig, 10 * m.resolution)
        ref, ref_sig = _fill_gaps(pa, sig, fill, 2.0 * m.resolution)
        prior = b + np.array([rng.normal(0, 0.01), rng.normal(0, 0.01), rng.normal(0, 0.003)])
        got = m.match(se2.transform_points(a, ref), ref_sig, pb, prior).pose
        step = (b[:2] - a[:2]) / np.hypot(*(b[:2] - a[:2]))
        out[sign].append(float((got[:2] - b[:2]) @ step))
    return {s: np.array(v) for s, v in out.items()}


def test_gap_fill_removes_most_of_the_short_step_bias():
    filled = _along_errors(0.5)
    dots = _along_errors(0.0)
    for sign in (1, -1):
        # As dots (Karto's way, the default) the steps come out 1.5-2 cm short, both ways along the corridor.
        assert dots[sign].mean() < -0.012, dots[sign].mean()
        assert abs(filled[sign].mean()) < 0.5 * abs(dots[sign].mean()), (filled[sign].mean(), dots[sign].mean())


def test_reference_range_margin_keeps_far_returns_for_the_reference_only():
    from slam2d.core.frames import Frame
    from slam2d.core.scan import make_scan

    ranges = np.full(181, 5.0)
    ranges[::10] = 14.0  # beyond the 12 m range threshold
    scan = make_scan(0.0, ranges, -np.pi / 2, np.radians(1.0), range_max=80.0)
    counts = {}
    for margin in (0.0, 4.0):
        fe = GraphFrontend(GraphSlamParams(reference_range_margin=margin))
        fe.process(Frame(0, scan, np.zeros(3)))
        query, _ = fe.node_points(0)
        ref, sig = fe._node_reference(0)
        assert ref.shape[0] == sig.shape[0]
        counts[margin] = (query.shape[0], ref.shape[0])
    assert counts[0.0] == (162, 162)
    assert counts[4.0] == (162, 181)
