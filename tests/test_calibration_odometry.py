"""Odometry calibration: maximum-likelihood srr, srt, str, stt and scales recover what the simulator injected."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from slam2d.cli import main
from slam2d.errors import InputError
from slam2d.io.tum import write_tum
from slam2d.params import from_mapping
from slam2d.sensors.calibration.odometry import calibrate_odometry, load_odometry_pairs, pairs_from_poses
from slam2d.sensors.motion_noise import OdometryNoise, simulate_odometry

INJECTED = OdometryNoise(srr=0.05, srt=0.15, str=0.08, stt=0.12, wheel_radius_scale=1.02, track_width_scale=0.97)


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def office():
    """Ten simulated minutes in `office` with known odometry noise (the issue's target case)."""
    from slam2d.sim.simulate import SimulationParams, simulate

    return simulate("office", SimulationParams(duration=600.0, seed=4), odometry_noise=INJECTED)


def _at_scans(sim):
    i = sim.scan_indices
    return pairs_from_poses(sim.times[i], sim.odometry[i], sim.truth[i])


def test_recovers_injected_noise_within_20_percent_on_ten_minutes(office):
    cal = calibrate_odometry(_at_scans(office))
    for name in ("srr", "srt", "str", "stt"):
        e = cal.noise[name]
        true = getattr(INJECTED, name)
        assert e.identifiable
        assert abs(e.value / true - 1) < 0.2, (name, e, true)
        assert e.low < e.value < e.high
    assert cal.wheel_radius_scale.value == pytest.approx(1.02, abs=0.015)
    assert cal.wheel_radius_scale.low <= 1.02 <= cal.wheel_radius_scale.high or abs(cal.wheel_radius_scale.value - 1.02) < 0.005
    assert cal.track_width_scale.value == pytest.approx(0.97, abs=0.05)
    assert cal.intervals == len(office.scans) - 1
    assert not cal.notes
    # standardised residuals are standard normal when the model fits
    assert np.std(cal.residuals, axis=0) == pytest.approx([1, 1, 1], abs=0.1)


@pytest.mark.slow
def test_estimate_does_not_depend_on_the_odometry_rate(office):
    half = len(office.times) // 2
    every = pairs_from_poses(office.times[:half], office.odometry[:half], office.truth[:half])  # 50 Hz, not 10
    fine = calibrate_odometry(every)
    coarse = calibrate_odometry(_at_scans(office))
    for name in ("srr", "srt"):
        assert fine.noise[name].value == pytest.approx(coarse.noise[name].value, rel=0.1)
        assert abs(fine.noise[name].value / getattr(INJECTED, name) - 1) < 0.2


def _wandering(duration: float) -> tuple[np.ndarray, np.ndarray]:
    """A true path at 10 Hz with changing speed, turns and stops."""
    t = np.arange(0, duration, 0.1)
    speed = np.clip(0.35 * np.sin(t / 6.0) + 0.15, 0.0, None)
    omega = 0.5 * np.sin(t / 4.0 + 1.0)
    heading = np.cumsum(omega) * 0.1
    truth = np.stack([np.cumsum(speed * np.cos(heading)) * 0.1, np.cumsum(speed * np.sin(heading)) * 0.1,
                      np.angle(np.exp(1j * heading))], axis=1)
    return t, truth


@pytest.mark.slow
@pytest.mark.parametrize("exact", [False, True])
def test_intervals_cover_the_truth_most_of_the_time(exact):
    """Over independent runs, the 95 % intervals contain the injected value in most of them."""
    t, truth = _wandering(200.0)
    hits = {k: 0 for k in ("srr", "srt", "str", "stt")}
    runs = 10
    for seed in range(runs):
        odo = simulate_odometry(t, truth, INJECTED, np.random.default_rng(seed))
        cal = calibrate_odometry(pairs_from_poses(t, odo, truth), exact_reference=exact)
        for k in hits:
            e = cal.noise[k]
            hits[k] += e.low <= getattr(INJECTED, k) <= e.high
    for k, n in hits.items():
        assert n >= runs - 3, (k, n, hits)


def test_uniform_speed_is_helped_by_an_exact_reference():
    t = np.arange(0, 200.0, 0.1)
    heading = np.angle(np.exp(1j * np.cumsum(0.4 * np.sin(t / 7.0)) * 0.1))
    truth = np.stack([np.cumsum(0.3 * np.cos(heading)) * 0.1, np.cumsum(0.3 * np.sin(heading)) * 0.1, heading], axis=1)
    odo = simulate_odometry(t, truth, INJECTED, np.random.default_rng(3))
    cal = calibrate_odometry(pairs_from_poses(t, odo, truth), exact_reference=True)
    for k in ("srr", "srt"):
        assert abs(cal.noise[k].value / getattr(INJECTED, k) - 1) < 0.1
    assert cal.reference_noise["xy_m"] < 1e-6


def test_straight_driving_cannot_identify_rotation_noise():
    t = np.arange(0, 120.0, 0.1)
    truth = np.stack([0.3 * t, np.zeros_like(t), np.zeros_like(t)], axis=1)
    odo = simulate_odometry(t, truth, INJECTED, np.random.default_rng(1))
    cal = calibrate_odometry(pairs_from_poses(t, odo, truth), exact_reference=True)
    assert cal.noise["srr"].identifiable and abs(cal.noise["srr"].value / 0.05 - 1) < 0.2
    for k in ("str", "stt"):
        assert not cal.noise[k].identifiable
        assert math.isnan(cal.noise[k].low)
    assert not cal.track_width_scale.identifiable
    assert set(cal.gmapping_params()) == {"srr", "srt"}
    assert any("str" in n for n in cal.notes)


def test_bad_inputs(tmp_path):
    t = np.arange(0, 10.0, 0.1)
    poses = np.zeros((len(t), 3))
    with pytest.raises(InputError, match="does not move"):
        calibrate_odometry(pairs_from_poses(t, poses, poses))
    with pytest.raises(InputError, match="at least 20"):
        calibrate_odometry(pairs_from_poses(t[:5], poses[:5], poses[:5]))
    odo = write_tum(tmp_path / "odo.tum", t, poses)
    late = write_tum(tmp_path / "late.tum", t + 100.0, poses)
    with pytest.raises(InputError, match="does not overlap") as exc:
        load_odometry_pairs(odo, late)
    assert exc.value.path == str(late)
    with pytest.raises(InputError, match="no such file"):
        load_odometry_pairs(tmp_path / "missing.log", odo)
    one = write_tum(tmp_path / "one.tum", t[:1], poses[:1])
    with pytest.raises(InputError, match="at least two"):
        load_odometry_pairs(one, odo)


def test_cli_end_to_end_writes_what_gmapping_reads(capsys, tmp_path):
    code, _, err = run(capsys, "simulate", "office", "--out", tmp_path / "sim", "--duration", "90", "--seed", "2",
                       "--srr", "0.05", "--stt", "0.1")
    assert code == 0, err
    out = tmp_path / "cal"
    code, text, err = run(capsys, "calibrate", "odometry", tmp_path / "sim" / "recording.log.gz",
                          "--reference", tmp_path / "sim" / "truth.tum", "--out", out)
    assert code == 0, err
    assert "srr = " in text and "track_width_scale" in text
    params = yaml.safe_load((out / "gmapping-params.yaml").read_text())
    assert set(params) <= {"srr", "srt", "str", "stt"} and "srr" in params
    noise = from_mapping(OdometryNoise, params)  # the simulator's own names and meaning
    assert abs(noise.srr / 0.05 - 1) < 0.3
    full = yaml.safe_load((out / "odometry.yaml").read_text())
    assert full["noise"]["srr"]["ci95"][0] < full["noise"]["srr"]["value"] < full["noise"]["srr"]["ci95"][1]
    assert full["intervals"] > 800
    for name in ("report.md", "report.html", "figures/odometry.png"):
        assert (out / name).is_file()
    # a TUM file of odometry poses works as DATA too
    from slam2d.io import open_recording

    frames = [(f.timestamp, f.odometry) for f in open_recording(tmp_path / "sim" / "recording.log.gz").frames()]
    odo = write_tum(tmp_path / "odo.tum", [f[0] for f in frames], [f[1] for f in frames])
    code, _, err = run(capsys, "calibrate", "odometry", odo, "--reference", tmp_path / "sim" / "truth.tum",
                       "--out", tmp_path / "cal2")
    assert code == 0, err
    again = yaml.safe_load((tmp_path / "cal2" / "gmapping-params.yaml").read_text())
    assert again == pytest.approx(params, rel=1e-4)  # headings went through quaternions
    code, _, err = run(capsys, "calibrate", "odometry", odo, "--reference", tmp_path / "nothing.tum",
                       "--out", tmp_path / "cal3")
    assert code == 2 and "nothing.tum" in err and "Traceback" not in err
    code, _, err = run(capsys, "calibrate", "odometry", odo, "--reference", odo, "--out", tmp_path / "c4",
                       "--max-gap", "0")
    assert code == 2 and "--max-gap" in err


@pytest.mark.parametrize("kwargs, field", [({"reference_distance": 0.0}, "--linear-update"),
                                           ({"reference_rotation": -1.0}, "--angular-update"),
                                           ({"reference_rotation": float("nan")}, "--angular-update")])
def test_each_reference_increment_is_named_when_it_is_bad(kwargs, field):
    t = np.arange(20.0)
    poses = np.stack([0.5 * t, np.zeros_like(t), 0.1 * t], axis=1)
    with pytest.raises(InputError) as info:
        calibrate_odometry(pairs_from_poses(t, poses, poses), **kwargs)
    assert info.value.field == field
