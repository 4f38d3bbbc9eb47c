"""The Cramer-Rao bound of slam2d.eval.accuracy_bound against cases known in closed form."""

from __future__ import annotations

import math

import numpy as np
import pytest

from slam2d.eval.accuracy_bound import (
    BoundSetup,
    accuracy_bound,
    chain_marginals,
    laser_information,
    odometry_covariances,
    setup_from_simulation,
)
from slam2d.errors import InputError
from slam2d.sensors.motion_noise import OdometryNoise
from slam2d.sensors.range_noise import ConstantSigma
from slam2d.sim.laser import cast_rays, laser_preset
from slam2d.sim.world import World


def _world(segments, circles=()) -> World:
    seg = np.asarray(segments, dtype=np.float64).reshape(-1, 4)
    cir = np.asarray(circles, dtype=np.float64).reshape(-1, 3)
    return World("test", "", seg, np.zeros(len(seg), dtype=np.int64), cir, np.zeros(len(cir), dtype=np.int64))


def _setup(world, truth, *, every=5, laser="urg-04lx", sigma=0.01, noise=None, mount=(0.0, 0.0, 0.0)):
    spec = laser_preset(laser)
    return BoundSetup(
        world=world, odometry_truth=np.asarray(truth, dtype=np.float64),
        scan_indices=np.arange(0, len(truth), every, dtype=np.int64), angles=spec.angles,
        angle_increment=spec.angle_increment, range_min=spec.range_min, range_max=spec.range_max,
        mount=np.asarray(mount, dtype=np.float64), range_noise=ConstantSigma(sigma), dropouts=False,
        odometry_noise=noise if noise is not None else OdometryNoise(),
    )


def _straight(length, step=0.01, y=0.0):
    x = np.arange(0.0, length + 1e-9, step)
    return np.stack([x, np.full_like(x, y), np.zeros_like(x)], axis=1)


def test_featureless_corridor_along_track_is_the_odometry_random_walk():
    # Walls at y = +-1 far longer than the laser's 5.6 m: no beam can tell where along the corridor the
    # robot is, so the along-track variance is the odometry's: srr^2 * reference_distance * distance.
    world = _world([[-200, -1, 200, -1], [-200, 1, 200, 1]])
    truth = _straight(20.0)
    setup = _setup(world, truth)
    r = accuracy_bound(setup, map="known", align=False)
    x = setup.scan_truth[:, 0]
    expected = OdometryNoise().srr * np.sqrt(OdometryNoise().reference_distance * x)
    np.testing.assert_allclose(np.sqrt(r["covariance"][1:, 0, 0]), expected[1:], rtol=1e-3)
    # across the corridor and in heading the walls hold the robot to millimetres
    assert np.sqrt(r["covariance"][:, 1, 1]).max() < 0.002
    assert r["edges_used"] == 0
    # unknown walls change nothing along the corridor (nothing there to learn it from either)
    w = accuracy_bound(setup, map="walls", align=False)
    np.testing.assert_allclose(np.sqrt(w["covariance"][1:, 0, 0]), expected[1:], rtol=1e-3)


def test_corridor_end_in_range_bounds_the_along_track_error():
    # The same corridor closed by a wall 3 m ahead of the end: the last poses see it and are held.
    world = _world([[-200, -1, 23, -1], [-200, 1, 23, 1], [23, -1, 23, 1]])
    r = accuracy_bound(_setup(world, _straight(20.0)), map="known", align=False)
    assert math.sqrt(r["covariance"][-1, 0, 0]) < 0.005
    assert math.sqrt(r["covariance"][1, 0, 0]) < math.sqrt(r["covariance"][len(r["covariance"]) // 3, 0, 0])


def _square_loop(turns=3):
    # Around a 2 m square inside a 4 m room, turning on the spot at the corners.
    corners = np.array([[1.0, 1.0], [3.0, 1.0], [3.0, 3.0], [1.0, 3.0]])
    poses = []
    for k in range(4 * turns):
        a, b = corners[k % 4], corners[(k + 1) % 4]
        heading = math.atan2(b[1] - a[1], b[0] - a[0])
        if poses:
            for h in np.linspace(poses[-1][2], poses[-1][2] + math.pi / 2, 40)[1:]:
                poses.append([a[0], a[1], h])
        t = np.linspace(0.0, 1.0, 100)[1:] if poses else np.linspace(0.0, 1.0, 100)
        poses += [[a[0] + s * (b[0] - a[0]), a[1] + s * (b[1] - a[1]), poses[-1][2] if poses else heading] for s in t]
    return np.array(poses)


def test_square_room_stays_bounded_and_less_knowledge_means_a_larger_bound():
    world = _world([[0, 0, 4, 0], [4, 0, 4, 4], [4, 4, 0, 4], [0, 4, 0, 0], [2.0, 2.0, 2.3, 2.0]])
    truth = _square_loop(turns=3)
    setup = _setup(world, truth)
    known = accuracy_bound(setup, map="known", align=False)
    walls = accuracy_bound(setup, map="walls", align=False)
    bare = accuracy_bound(setup, map="walls", edges=False, align=False)
    driven = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(truth[:, :2], axis=0).T))])
    odometry_only = OdometryNoise().srr * math.sqrt(driven[-1])
    assert known["position_std_m"].max() < 0.01 < odometry_only
    # a third lap is no worse than the first: the room holds the error
    n = len(known["position_std_m"])
    assert walls["position_std_m"][2 * n // 3:].max() < 1.5 * walls["position_std_m"][: n // 3].max()
    tol = 1e-9
    assert np.all(known["position_std_m"] <= walls["position_std_m"] + tol)
    assert np.all(walls["position_std_m"] <= bare["position_std_m"] + tol)
    aligned = accuracy_bound(setup, map="walls")
    assert aligned["ate_m"] <= walls["ate_m"] + tol


def test_laser_information_of_a_round_room_in_closed_form():
    # From the centre of a round room every beam hits square on at the same range: each gives
    # d d^T / sigma^2 for the position and nothing for the heading (turning changes no range).
    sigma = 0.02
    world = _world([], circles=[[0.0, 0.0, 3.0]])
    setup = _setup(world, np.zeros((6, 3)), laser="rplidar-a1", sigma=sigma)
    info = laser_information(setup, edges=False)
    beams = len(setup.angles)
    np.testing.assert_allclose(info.pose[0, :2, :2], beams / (2 * sigma**2) * np.eye(2), rtol=1e-9, atol=1e-6)
    assert abs(info.pose[0, 2, 2]) < 1e-6 * beams / sigma**2


def test_range_derivatives_match_finite_differences_of_the_ray_caster():
    from slam2d.sim.world import load_world

    world = load_world("office")
    mount = np.array([0.3, 0.05, 0.1])
    pose = np.r_[world.start[:2] + [0.4, 0.2], 0.3]
    setup = _setup(world, np.tile(pose, (6, 1)), mount=mount)
    info = laser_information(setup, edges=False)
    first = info.scan == 0
    g = info.d_pose[first]
    from slam2d.core import se2

    def ranges(p):
        return cast_rays(world, se2.compose(p, mount), setup.angles)[0]

    base = ranges(pose)
    used = np.flatnonzero(np.isfinite(base) & (base < setup.range_max) & (base >= setup.range_min))
    assert len(used) == first.sum()
    eps = 1e-6
    numeric = np.stack([(ranges(pose + e) - ranges(pose - e)) / (2 * eps) for e in np.eye(3) * eps], axis=1)[used]
    smooth = np.all(np.abs(numeric) < 1e3, axis=1)  # beams across an edge jump; the rest are smooth
    assert smooth.mean() > 0.95
    np.testing.assert_allclose(g[smooth], numeric[smooth], rtol=1e-4, atol=1e-5)


def test_odometry_covariance_of_a_straight_drive_and_a_turn():
    noise = OdometryNoise()
    truth = _straight(1.0, step=0.02)[:51]
    cov = odometry_covariances(_setup(_world([[0, 5, 1, 5]]), truth, every=50))
    # 1 m straight: x variance srr^2 D, heading srt^2 D
    assert cov.shape == (1, 3, 3)
    assert cov[0, 0, 0] == pytest.approx(noise.srr**2 * 1.0, rel=1e-9)
    assert cov[0, 2, 2] == pytest.approx(noise.srt**2 * 1.0, rel=1e-9)
    # the heading noise of early steps turns later travel into cross-track error
    assert cov[0, 1, 1] > (0.3 * noise.srr) ** 2 * 1.0
    turn = np.zeros((11, 3))
    turn[:, 2] = np.linspace(0.0, 0.5, 11)
    c = odometry_covariances(_setup(_world([[0, 5, 1, 5]]), turn, every=10))
    assert c[0, 2, 2] == pytest.approx(noise.stt**2 * 0.5 * 0.5, rel=1e-9)


def test_chain_marginals_equal_the_dense_inverse():
    rng = np.random.default_rng(3)
    n = 7
    a = rng.standard_normal((3 * n, 3 * n)) * 0.1
    mask = np.abs(np.subtract.outer(np.arange(3 * n) // 3, np.arange(3 * n) // 3)) <= 1
    m = (a @ a.T) * mask + 3 * np.eye(3 * n)
    diag = np.stack([m[3 * i:3 * i + 3, 3 * i:3 * i + 3] for i in range(n)])
    off = np.stack([m[3 * i:3 * i + 3, 3 * i + 3:3 * i + 6] for i in range(n - 1)])
    inv = np.linalg.inv(m)
    got = chain_marginals(diag, off)
    for i in range(n):
        np.testing.assert_allclose(got[i], inv[3 * i:3 * i + 3, 3 * i:3 * i + 3], rtol=1e-10, atol=1e-12)


def test_bad_map_model_is_an_input_error():
    setup = _setup(_world([[0, 5, 1, 5]]), _straight(1.0))
    with pytest.raises(InputError, match="map"):
        accuracy_bound(setup, map="grid")
    with pytest.raises(InputError, match="edge_sigma"):
        accuracy_bound(setup, edge_sigma=-1.0)


@pytest.mark.slow
@pytest.mark.parametrize("laser", ["rplidar-a1", "urg-04lx"])
def test_no_method_beats_the_bound(laser):
    # karto (and the odometry it starts from) on a real simulated recording: if either came out
    # below the bound, the bound would be wrong. The bound is on the RMS over runs; one run's
    # error would need a wild fluctuation (several times the bound) to dip under it.
    from slam2d.eval.trajectory_metrics import absolute_trajectory_error, associate
    from slam2d.methods import get_method
    from slam2d.sim.simulate import SimulationParams, simulate

    sim = simulate("office", SimulationParams(duration=40.0, seed=0, laser=laser))
    walls = accuracy_bound(sim, map="walls")
    known = accuracy_bound(sim, map="known")
    assert 0.0 < known["ate_m"] <= walls["ate_m"]
    slam = get_method("karto")(seed=0).run(sim.frames())
    t, p = slam.trajectory()
    karto = absolute_trajectory_error(associate(t, p, sim.scan_times, sim.scan_truth))["translation_m"]["rmse"]
    odometry = absolute_trajectory_error(
        associate(sim.scan_times, sim.odometry[sim.scan_indices], sim.scan_times, sim.scan_truth)
    )["translation_m"]["rmse"]
    assert walls["ate_m"] < karto
    assert walls["ate_m"] < odometry


def test_aligned_bound_matches_monte_carlo_through_the_real_alignment():
    # Draw trajectory errors from the bound's own joint covariance, align each with the ATE's
    # align_se2 and compare the mean squared ATE with the bound's (linearised) expectation.
    from slam2d.core import se2
    from slam2d.eval.accuracy_bound import joint_information
    from slam2d.eval.trajectory_metrics import align_se2

    world = _world([[0, 0, 4, 0], [4, 0, 4, 4], [4, 4, 0, 4], [0, 4, 0, 0], [2.0, 2.0, 2.3, 2.0]])
    setup = _setup(world, _square_loop(turns=1), every=10, noise=OdometryNoise(srr=0.3, srt=0.5, str=0.3, stt=0.5))
    for map_model in ("known", "walls"):
        r = accuracy_bound(setup, map=map_model)
        j = joint_information(setup, map=map_model).toarray()
        cov = np.linalg.inv(j)[: 3 * (r["scans"] - 1), : 3 * (r["scans"] - 1)]
        np.testing.assert_allclose(cov.reshape(r["scans"] - 1, 3, r["scans"] - 1, 3)[
            np.arange(r["scans"] - 1), :, np.arange(r["scans"] - 1)], r["covariance"][1:], rtol=1e-6, atol=1e-14)
        rng = np.random.default_rng(0)
        chol = np.linalg.cholesky(cov)
        truth = setup.scan_truth
        sq = []
        for _ in range(400):
            est = truth.copy()
            est[1:] += (chol @ rng.standard_normal(chol.shape[0])).reshape(-1, 3)
            aligned = se2.compose(align_se2(est[:, :2], truth[:, :2]), est)
            sq.append(np.mean(np.sum((aligned[:, :2] - truth[:, :2]) ** 2, axis=1)))
        assert math.sqrt(np.mean(sq)) == pytest.approx(r["ate_m"], rel=0.05)


@pytest.mark.parametrize("world", ["paper-arena", "office"])
def test_the_oracle_smoother_reaches_the_bound_on_real_readings(world):
    # The maximum-likelihood smoother that knows which surface each beam hit, run on what the
    # simulator actually reported (its range noise, dropouts, odometry drift): its RMS error over
    # seeds must sit at the bound. A sigma, a dropout rate or an odometry variance counted wrong
    # by the bound would show here as a ratio far from 1 (a factor 2 in sigma gives 2).
    from slam2d.eval.accuracy_bound import oracle_smoother
    from slam2d.sim.simulate import SimulationParams, simulate

    for map_model in ("known", "walls"):
        ates = []
        for seed in range(4):
            sim = simulate(world, SimulationParams(duration=20.0, seed=seed))
            if seed == 0:
                bound = accuracy_bound(sim, map=map_model)["ate_m"]
            ates.append(oracle_smoother(sim, map=map_model)["ate_m"])
        ratio = math.sqrt(np.mean(np.square(ates))) / bound
        assert 0.75 < ratio < 1.3, (map_model, ratio, ates, bound)


def test_the_oracle_smoothers_masks_leave_out_exactly_the_readings_they_mark():
    # beam_mask / edge_mask restrict the oracle to a method's inputs (docs/methods/what-was-tried.md, karto: which
    # inputs hold the last centimetres): all True is the unmasked solve, no wall end at all is edges=False,
    # and a masked beam's reading is gone from the count and from the solve.
    from slam2d.eval.accuracy_bound import oracle_smoother
    from slam2d.sim.simulate import SimulationParams, simulate

    sim = simulate("office", SimulationParams(duration=10.0, seed=0, laser="urg-04lx"))
    shape = (len(sim.scans), sim.scans[0].num_beams)
    full = oracle_smoother(sim)
    same = oracle_smoother(sim, beam_mask=np.ones(shape, bool), edge_mask=np.ones(shape, bool))
    np.testing.assert_allclose(same["estimate"], full["estimate"], atol=1e-12)
    assert same["readings_used"] == full["readings_used"]
    no_ends = oracle_smoother(sim, edge_mask=np.zeros(shape, bool))
    without = oracle_smoother(sim, edges=False)
    np.testing.assert_allclose(no_ends["estimate"], without["estimate"], atol=1e-9)
    assert no_ends["readings_used"] == without["readings_used"] < full["readings_used"]
    assert no_ends["ate_m"] > full["ate_m"]  # the office's wall ends hold the position along the corridors
    # every other beam of every scan left out: the returns among them are gone from the count
    half = np.ones(shape, bool)
    half[:, ::2] = False
    masked = oracle_smoother(sim, beam_mask=half, edges=False)
    returned = np.stack([np.isfinite(s.ranges) for s in sim.scans])
    info = laser_information(setup_from_simulation(sim), edges=False)
    lost = int((returned.reshape(-1)[info.beam] & ~half.reshape(-1)[info.beam]).sum())
    assert 0 < lost and masked["readings_used"] == without["readings_used"] - lost
    assert np.abs(masked["estimate"] - without["estimate"]).max() > 1e-6
    with pytest.raises(InputError):
        oracle_smoother(sim, beam_mask=np.ones((shape[0], shape[1] - 1), bool))
