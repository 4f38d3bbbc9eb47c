"""Loop correction of a finished path (gmapping's ``loop_correction``): karto's loop search over a given path."""

from __future__ import annotations

import math

import numpy as np
import pytest

from slam2d.core import make_scan, se2
from slam2d.graph.loop_correction import LoopCorrectionParams, correct_path, spread_node_corrections
from slam2d.methods.gmapping import GMapping, GMappingParams
from slam2d.eval.trajectory_metrics import align_se2
from tests._room import _box_hits
from tests.conftest import recording_frames
from tests.test_method_gmapping import arena  # noqa: F401  (the fixture)

# A hall with a block in the middle: the robot drives round the block and back to where it started.
HALL = (0.0, 0.0, 30.0, 12.0)
BLOCK = (4.0, 4.0, 26.0, 8.0)
# Pillars along the walls, so no stretch of corridor looks like another.
PILLARS = [(7.0, 0.0, 7.6, 0.7), (15.0, 11.2, 15.5, 12.0), (21.0, 0.0, 21.4, 1.0), (29.2, 5.0, 30.0, 5.8),
           (0.0, 7.0, 0.8, 7.4), (11.0, 3.4, 11.5, 4.0), (18.0, 8.0, 18.8, 8.5), (26.0, 2.0, 26.4, 2.5)]


def _scan(pose, t):
    a = np.radians(np.arange(-90.0, 90.5, 0.5))
    d = pose[2] + a
    dx, dy = np.cos(d), np.sin(d)
    r = _box_hits(pose[0], pose[1], dx, dy, HALL, True)
    for box in [BLOCK, *PILLARS]:
        r = np.fmin(r, _box_hits(pose[0], pose[1], dx, dy, box, False))
    r = np.where(r < 30.0, r, np.nan)
    return make_scan(t, r, a[0], math.radians(0.5), range_max=30.0)


def _loop_path():
    """Poses about 0.8 m apart round the block (counter-clockwise), then 12 m on over the start."""
    corners = [(2.0, 2.0), (28.0, 2.0), (28.0, 10.0), (2.0, 10.0), (2.0, 2.0), (14.0, 2.0)]
    poses = []
    for (x0, y0), (x1, y1) in zip(corners[:-1], corners[1:]):
        n = max(int(round(math.hypot(x1 - x0, y1 - y0) / 0.8)), 1)
        th = math.atan2(y1 - y0, x1 - x0)
        poses += [(x0 + (x1 - x0) * k / n, y0 + (y1 - y0) * k / n, th) for k in range(n)]
    return np.array(poses)


def _drifted(truth, heading_bias):
    """The truth's steps with a heading error added to each: a path that does not close."""
    steps = se2.relative(truth[:-1], truth[1:])
    steps[:, 2] += heading_bias
    out = [truth[0]]
    for s in steps:
        out.append(se2.compose(out[-1], s))
    return np.array(out)


def _aligned_errors(est, truth):
    """Position errors after the rigid transform that best fits ``est`` onto ``truth`` (as the ATE aligns)."""
    moved = se2.compose(align_se2(est[:, :2], truth[:, :2]), est)
    return np.hypot(*(moved[:, :2] - truth[:, :2]).T)


def _info(n):
    return np.tile(np.diag([1.0 / 0.05**2, 1.0 / 0.05**2, 1.0 / 0.01**2]), (n, 1, 1))


def test_a_drifted_loop_is_closed_and_the_path_brought_back():
    truth = _loop_path()
    scans = [_scan(p, float(k)) for k, p in enumerate(truth)]
    path = _drifted(truth, math.radians(0.1))  # 10 deg round the loop
    times = np.arange(len(truth), dtype=float)
    # the matcher's own covariance for the closure: the steps' information here is the test's own
    params = LoopCorrectionParams(loop_correction=True, loop_correction_distance=4.0, loop_correction_range=20.0,
                                  loop_correction_closure_scale=1.0)
    res = correct_path(scans, path, path, times, _info(len(truth) - 1), params)
    err_before = _aligned_errors(path, truth)
    err_after = _aligned_errors(res.poses, truth)
    assert err_before.max() > 1.0
    assert res.closures, "the return over the start must close the loop"
    assert all(c["to"] > 85 and c["frm"] < 20 for c in res.closures)
    assert err_after.max() < 0.2 * err_before.max(), (err_before.max(), err_after.max())
    assert np.sqrt((err_after**2).mean()) < 0.06
    summary = res.summary(path)
    assert summary["closure_count"] == len(res.closures) and summary["max_shift_m"] > 0.3
    assert summary["cost_after"] < 0.02 * summary["cost_before"]


def test_no_loop_no_change():
    """A path that never comes back gets no closure and comes back unchanged."""
    truth = _loop_path()[:40]  # along the bottom corridor and up the right side only
    scans = [_scan(p, float(k)) for k, p in enumerate(truth)]
    path = _drifted(truth, math.radians(0.4))
    params = LoopCorrectionParams(loop_correction=True, loop_correction_distance=4.0)
    res = correct_path(scans, path, path, np.arange(40.0), _info(39), params)
    assert res.closures == [] and np.array_equal(res.poses, path)


def test_frames_between_nodes_follow_their_nodes_corrections():
    nodes = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    steps = se2.relative(nodes[:-1], nodes[1:])
    corrected = nodes.copy()
    corrected[1:, 1] += 0.2  # node 1 and 2 moved sideways, node 0 not
    anchor = np.array([0, 0, 1, 2])
    offset = np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [0.0, 0.0, 0.0], [0.3, 0.0, 0.0]])
    out = spread_node_corrections(corrected, steps, anchor, offset)
    assert out[0] == pytest.approx([0.0, 0.0, 0.0])
    assert out[1] == pytest.approx([0.5, 0.1, 0.0])  # half way to node 1: half its correction
    assert out[2] == pytest.approx([1.0, 0.2, 0.0])
    assert out[3] == pytest.approx([2.3, 0.2, 0.0])  # after the last node: hung from it


def test_gmapping_default_off_is_untouched_and_on_keeps_the_filter(arena):  # noqa: F811
    """loop_correction off (the default) is the original; on, the filter's nodes are the same bit for bit."""
    frames = recording_frames(arena / "recording.log.gz")
    plain = GMapping(GMappingParams(particles=10), seed=3).run(frames)
    off = GMapping(GMappingParams(particles=10, loop_correction=False), seed=3).run(frames)
    on = GMapping(GMappingParams(particles=10, loop_correction=True), seed=3).run(frames)
    assert np.array_equal(plain.trajectory()[1], off.trajectory()[1])
    assert "loop_correction" not in off.diagnostics.summary
    assert np.array_equal(plain.best_nodes(), on.best_nodes())
    summary = on.diagnostics.summary["loop_correction"]
    assert summary["nodes"] == plain.best_nodes().shape[0]
    t, p = on.trajectory()
    assert len(t) == len(frames) and np.all(np.isfinite(p))
    if summary["closure_count"] == 0:  # nothing found: the path is the filter's
        assert np.array_equal(p, plain.trajectory()[1])
    again = GMapping(GMappingParams(particles=10, loop_correction=True), seed=3).run(frames)
    assert np.array_equal(again.trajectory()[1], p)
