"""`hector`: map pyramid, Gauss-Newton matcher (gradients, convergence, covariance, degeneracy), the method."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from slam2d.cli import main
from slam2d.core import se2
from slam2d.core.frames import Frame
from slam2d.core.scan import make_scan
from slam2d.errors import InputError
from slam2d.grids.occupancy import GridParams
from slam2d.grids.pyramid import MapPyramid
from slam2d.matching.gauss_newton import GaussNewtonMatcher, MatchSettings, accumulate
from slam2d.methods import get_method
from slam2d.methods.hector import Hector, HectorParams
from slam2d.methods.runner import build_method

ANGLES = np.linspace(-2.0, 2.0, 682)  # a URG-04LX-like fan


def _cast(walls, pose, angles=ANGLES, max_range=5.6):
    """Exact ranges from ``pose`` to line segments ``walls`` [(x0, y0, x1, y1)]; NaN beyond max_range."""
    x, y, th = pose
    d = np.stack([np.cos(th + angles), np.sin(th + angles)], axis=-1)
    best = np.full(angles.shape[0], np.inf)
    for x0, y0, x1, y1 in walls:
        e = np.array([x1 - x0, y1 - y0])
        w = np.array([x0 - x, y0 - y])
        den = d[:, 0] * (-e[1]) - d[:, 1] * (-e[0])
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (w[0] * (-e[1]) - w[1] * (-e[0])) / den
            u = (d[:, 0] * w[1] - d[:, 1] * w[0]) / den
        ok = (np.abs(den) > 1e-12) & (t > 0) & (u >= 0) & (u <= 1)
        best = np.where(ok & (t < best), t, best)
    best[best > max_range] = np.nan
    return best


# Walls through cell centres of the finest level (0.025 m): a wall on a cell boundary is drawn
# half a cell to one side, which would bias every match against the map by that much.
_H = 0.0125
ROOM = [(x0 + _H, y0 + _H, x1 + _H, y1 + _H) for x0, y0, x1, y1 in
        [(0, 0, 6, 0), (6, 0, 6, 4), (6, 4, 0, 4), (0, 4, 0, 0), (2, 1.5, 3, 1.5), (3, 1.5, 3, 2.5)]]
CORRIDOR = [(-30, _H, 30, _H), (-30, 2 + _H, 30, 2 + _H)]


def _points(walls, pose, noise=0.0, rng=None):
    r = _cast(walls, pose)
    if noise:
        r = r + rng.normal(0.0, noise, r.shape)
    ok = np.isfinite(r)
    return np.stack([r[ok] * np.cos(ANGLES[ok]), r[ok] * np.sin(ANGLES[ok])], axis=-1)


def _pyramid(walls, poses, resolution=0.025):
    pyr = MapPyramid(GridParams(resolution=resolution, p_hit=0.9, p_miss=0.4), levels=3)
    for pose in poses:
        world = se2.transform_points(np.asarray(pose, float), _points(walls, pose))
        pyr.integrate_points(np.asarray(pose[:2], float), world)
    return pyr


@pytest.fixture(scope="module")
def room():
    return _pyramid(ROOM, [(1.0, 3.0, 0.0), (4.5, 3.0, -2.0), (4.5, 1.0, 2.5), (1.0, 1.0, 0.7)])


# --------------------------------------------------------------------------- the pyramid


def test_pyramid_levels_halve_the_resolution_and_grow(room):
    assert [lv.resolution for lv in room.levels] == pytest.approx([0.025, 0.05, 0.1])
    for level in room.levels:
        xmin, ymin, xmax, ymax = level.grid.extent()
        assert xmin <= -0.1 and ymin <= -0.1 and xmax >= 6.1 and ymax >= 4.1  # grew to hold the room
        assert np.allclose(level.probability, level.grid.probability())  # window refresh kept it exact


# --------------------------------------------------------------------------- the matcher


def test_analytic_gradient_matches_finite_differences(room):
    """b = sum w J (1 - M) with J = dM/dxi: compare J with central differences of M for every point."""
    level = room[0]
    pts = _points(ROOM, (3.0, 2.0, 0.3))[::7]
    pose = np.array([3.02, 1.97, 0.31])
    ox, oy = level.origin
    checked = 0
    for p in pts:
        one = np.ascontiguousarray(p[None, :])
        w = np.ones(1)
        h, b, ss, wsum, msum, used = accumulate(level.probability, ox, oy, 0.025, one, w, pose)
        if used == 0 or ss == 0.0:
            continue
        jac = b / (1.0 - msum)  # J (1 - M) / (1 - M)
        eps = np.array([1e-6, 1e-6, 1e-7])
        for k in range(3):
            dp = np.zeros(3)
            dp[k] = eps[k]
            mp = accumulate(level.probability, ox, oy, 0.025, one, w, pose + dp)[4]
            mm = accumulate(level.probability, ox, oy, 0.025, one, w, pose - dp)[4]
            numeric = (mp - mm) / (2 * eps[k])
            assert jac[k] == pytest.approx(numeric, rel=1e-3, abs=1e-3 * (1 + abs(numeric))), (p, k)
        assert np.allclose(h, np.outer(jac, jac), rtol=1e-9, atol=1e-9)
        checked += 1
    assert checked > 20


@pytest.mark.parametrize("offset", [(0.15, -0.1, 0.08), (-0.25, 0.2, -0.15), (0.3, 0.3, 0.25)])
def test_matcher_converges_from_offsets(room, offset):
    truth = np.array([3.0, 2.2, 0.4])
    pts = _points(ROOM, truth)
    result = GaussNewtonMatcher().match(room, pts, np.ones(len(pts)), truth + np.array(offset))
    assert np.hypot(*(result.pose[:2] - truth[:2])) < 0.01
    assert abs(se2.wrap_angle(result.pose[2] - truth[2])) < 0.005
    assert not result.degenerate and result.score > 0.8


def test_coarse_levels_widen_the_basin(room):
    """The same offset that the finest level alone cannot undo, the pyramid can."""
    truth = np.array([3.0, 2.2, 0.4])
    pts = _points(ROOM, truth)
    start = truth + np.array([0.25, 0.25, 0.0])
    full = GaussNewtonMatcher().match(room, pts, np.ones(len(pts)), start)
    single = MapPyramid.__new__(MapPyramid)
    single.levels = room.levels[:1]
    fine = GaussNewtonMatcher().match(single, pts, np.ones(len(pts)), start)
    assert np.hypot(*(full.pose[:2] - truth[:2])) < 0.01
    assert np.hypot(*(fine.pose[:2] - truth[:2])) > 0.05


def test_convergence_test_stops_early_and_iteration_caps_hold(room):
    truth = np.array([3.0, 2.2, 0.4])
    pts = _points(ROOM, truth)
    loose = GaussNewtonMatcher(MatchSettings(tolerance_xy=1e-2, tolerance_theta=1e-2)).match(
        room, pts, np.ones(len(pts)), truth + 0.02)
    strict = GaussNewtonMatcher(MatchSettings(tolerance_xy=0.0, tolerance_theta=0.0)).match(
        room, pts, np.ones(len(pts)), truth + 0.02)
    capped = GaussNewtonMatcher(MatchSettings(iterations_coarse=1, iterations_fine=2, tolerance_xy=0.0,
                                              tolerance_theta=0.0)).match(room, pts, np.ones(len(pts)), truth + 0.02)
    assert strict.iterations <= 3 * 10
    assert loose.iterations < strict.iterations
    assert capped.iterations <= 1 + 1 + 2
    for res in (loose, strict, capped):
        assert np.hypot(*(res.pose[:2] - truth[:2])) < 0.01


def test_covariance_matches_the_spread_of_noisy_matches(room):
    """Over many noisy scans, the reported covariance has the size and shape of the actual scatter."""
    rng = np.random.default_rng(4)
    truth = np.array([3.0, 2.2, 0.4])
    matcher = GaussNewtonMatcher()
    poses, covs = [], []
    for _ in range(60):
        pts = _points(ROOM, truth, noise=0.02, rng=rng)
        res = matcher.match(room, pts, np.ones(len(pts)), truth)
        poses.append(res.pose)
        covs.append(res.covariance)
    err = np.array(poses) - truth
    empirical = np.cov(err.T)
    predicted = np.mean(covs, axis=0)
    assert np.all(np.linalg.eigvalsh(predicted) > 0)
    for k in range(3):
        ratio = predicted[k, k] / empirical[k, k]
        assert 0.2 < ratio < 5.0, (k, predicted[k, k], empirical[k, k])


def test_degeneracy_is_flagged_in_a_corridor_and_not_in_a_room(room):
    corridor = _pyramid(CORRIDOR, [(x, 1.0, 0.0) for x in (-4.0, -2.0, 0.0, 2.0, 4.0)])
    truth = np.array([0.3, 1.0, 0.0])
    pts = _points(CORRIDOR, truth)
    normals = np.tile([0.0, 1.0], (len(pts), 1))  # both walls run along x
    matcher = GaussNewtonMatcher()
    res = matcher.match(corridor, pts, np.ones(len(pts)), truth, normals=normals)
    assert res.degenerate and res.geometric_condition < 1e-6
    (direction,) = res.degenerate_directions
    assert abs(direction[0]) > 0.99  # along the corridor
    assert res.covariance[0, 0] > 1e3 * res.covariance[1, 1]
    # With a prior, the position along the corridor is the prior's, across it the scan's.
    prior = np.array([0.55, 1.03, 0.0])
    info = np.diag([400.0, 400.0, 400.0])
    res = matcher.match(corridor, pts, np.ones(len(pts)), prior, prior=prior, prior_information=info,
                        normals=normals)
    assert res.pose[0] == pytest.approx(0.55, abs=1e-4) and res.pose[1] == pytest.approx(1.0, abs=0.01)
    assert res.prior_used_along_degeneracy and res.covariance[0, 0] == pytest.approx(1 / 400.0, rel=0.05)

    room_truth = np.array([3.0, 2.2, 0.4])
    pts = _points(ROOM, room_truth)
    ok = GaussNewtonMatcher().match(room, pts, np.ones(len(pts)), room_truth)
    assert not ok.degenerate and ok.inverse_condition > 0.01


def test_weights_follow_the_beam_sigma(room):
    """Down-weighting the beams on one wall shrinks their pull: the weights reach the step."""
    truth = np.array([3.0, 2.2, 0.4])
    pts = _points(ROOM, truth)
    start = truth + np.array([0.05, 0.05, 0.02])
    st = MatchSettings(iterations_coarse=1, iterations_fine=1, tolerance_xy=0.0, tolerance_theta=0.0)
    even = GaussNewtonMatcher(st).match(room, pts, np.ones(len(pts)), start)
    w = np.where(np.arange(len(pts)) % 2 == 0, 1.0, 1e-3)
    uneven = GaussNewtonMatcher(st).match(room, pts, w, start)
    assert not np.allclose(even.pose, uneven.pose)


# --------------------------------------------------------------------------- the method


def _frames(walls, poses, odometry=None):
    out = []
    for i, pose in enumerate(poses):
        scan = make_scan(0.1 * i, _cast(walls, pose), ANGLES[0], ANGLES[1] - ANGLES[0], 0.02, 5.6)
        odom = None if odometry is None else odometry[i]
        out.append(Frame(i, scan, odom))
    return out


def _room_path():
    t = np.linspace(0, 1, 60)
    return np.stack([1.5 + 3.0 * t, 2.0 + 0.8 * np.sin(3 * t), 0.6 * np.sin(4 * t)], axis=-1)


def test_hector_tracks_without_odometry_and_is_deterministic():
    path = _room_path()
    frames = _frames(ROOM, path)
    runs = []
    for _ in range(2):
        slam = Hector(HectorParams(resolution=0.025, map_update_distance_thresh=0.4, map_update_angle_thresh=0.9))
        slam.run(frames)
        runs.append(slam)
    _, est = runs[0].trajectory()
    rel_est = se2.relative(est[0], est)
    rel_true = se2.relative(path[0], path)
    assert np.max(np.hypot(*(rel_est[:, :2] - rel_true[:, :2]).T)) < 0.02
    assert np.array_equal(runs[0].trajectory()[1], runs[1].trajectory()[1])
    assert np.array_equal(runs[0].map().logodds, runs[1].map().logodds)
    diag = runs[0].diagnostics
    assert np.nanmax(diag.array("degenerate")) == 0
    updates = diag.counters["map_updates"]
    assert 2 <= updates < len(frames) / 2  # only past the distance / angle thresholds
    assert get_method("hector").odometry_role() == "optional"


def test_hector_uses_odometry_along_a_corridor():
    xs = np.linspace(-3.0, 3.0, 40)
    path = np.stack([xs, np.full_like(xs, 1.0), np.zeros_like(xs)], axis=-1)
    odometry = path * np.array([1.02, 1.0, 1.0])  # 2 % scale error
    frames = _frames(CORRIDOR, path, odometry)
    blind = Hector(HectorParams()).run(frames)
    helped = Hector(HectorParams(use_odometry=True)).run(frames)
    for slam in (blind, helped):
        assert np.nanmean(slam.diagnostics.array("degenerate")[1:]) == 1.0
        assert slam.diagnostics.counters["degenerate_matches"] == len(frames) - 1
    moved_blind = blind.trajectory()[1][-1, 0] - blind.trajectory()[1][0, 0]
    moved_helped = helped.trajectory()[1][-1, 0] - helped.trajectory()[1][0, 0]
    assert abs(moved_blind) < 1.0  # without odometry it cannot see itself move
    assert moved_helped == pytest.approx(6.0 * 1.02, abs=0.05)


def test_hector_survives_degenerate_input():
    path = _room_path()[:6]
    frames = _frames(ROOM, path)
    empty = make_scan(9.0, np.full(ANGLES.shape[0], np.nan), ANGLES[0], ANGLES[1] - ANGLES[0], 0.02, 5.6)
    frames.insert(3, Frame(99, empty, None))
    slam = Hector(HectorParams(use_odometry=True)).run(frames)
    assert slam.diagnostics.counters["scans_too_few_points"] == 1
    assert slam.diagnostics.counters["frames_without_odometry"] >= 1
    assert len(slam.trajectory()[0]) == len(frames)


def test_hector_bad_parameters_are_input_errors():
    with pytest.raises(InputError, match="map_multi_res_levels"):
        build_method("hector", settings={"map_multi_res_levels": "0"})
    with pytest.raises(InputError, match="use_odometry"):
        build_method("hector", settings={"use_odometry": "maybe"})
    with pytest.raises(InputError, match="max_angle_step"):
        build_method("hector", settings={"max_angle_step": "-1"})


def test_hector_cli_run_on_a_simulated_arena(tmp_path):
    sim = tmp_path / "sim"
    assert main(["simulate", "paper-arena", "--out", str(sim), "--duration", "20", "--seed", "2"]) == 0
    out = tmp_path / "run"
    assert main(["run", "hector", str(sim / "recording.log.gz"), "--out", str(out)]) == 0
    assert main(["evaluate", str(out), "--truth", str(sim)]) == 0
    ev = json.loads((out / "evaluation.json").read_text())
    ate = ev["trajectory"]["ate"]["translation_m"]["rmse"]
    assert ate is not None and ate < 0.03
    diag = json.loads((out / "diagnostics.json").read_text())
    assert all(v is None or math.isfinite(v) for v in diag["series"]["sigma_x"])


def test_pyramid_unknown_cells_read_as_chosen():
    pyr = MapPyramid(GridParams(resolution=0.05), levels=2, unknown=0.3)
    for pose in [(1.0, 3.0, 0.0), (4.5, 1.0, 2.5)]:
        world = se2.transform_points(np.asarray(pose, float), _points(ROOM, pose))
        pyr.integrate_points(np.asarray(pose[:2], float), world)
    for level in pyr.levels:
        seen = level.grid.observed
        assert (~seen).any() and seen.any()
        assert np.all(level.probability[~seen] == np.float32(0.3))
        assert np.allclose(level.probability[seen], level.grid.probability()[seen])


def test_hector_weighs_beams_by_the_sensor_model():
    """A sensor model reaches the residual weights through beam_sigmas: the estimate changes."""
    from slam2d.sensors.range_noise import StudyModel

    frames = _frames(ROOM, _room_path()[:25])
    plain = Hector(HectorParams()).run(frames)
    modelled = Hector(HectorParams(), sensor_model=StudyModel()).run(frames)
    a, b = plain.trajectory()[1], modelled.trajectory()[1]
    assert not np.array_equal(a, b)
    assert np.max(np.hypot(*(a[:, :2] - b[:, :2]).T)) < 0.02  # both track the same exact scans


@pytest.mark.slow
@pytest.mark.datasets
def test_hector_maps_mines_exp1_without_odometry_better_than_odometry(tmp_path):
    from tests.conftest import dataset_file

    data = dataset_file("mines-exp1/mines-exp1.clf.gz")
    counts = {}
    for method in ("hector", "odometry"):
        out = tmp_path / method
        assert main(["run", method, str(data), "--out", str(out)]) == 0
        assert main(["evaluate", str(out)]) == 0
        quality = json.loads((out / "evaluation.json").read_text())["map_quality"]
        counts[method] = (quality["corners"], quality["enclosed_areas"])
    assert counts["hector"][0] < counts["odometry"][0] and counts["hector"][1] < counts["odometry"][1]
    diag = json.loads((tmp_path / "hector" / "diagnostics.json").read_text())
    assert diag["counters"].get("match_failures", 0) == 0
