"""`slam2d simulate` end to end: outputs, determinism, ground truth, and bad input."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

from slam2d.cli import main
from slam2d.core import se2
from slam2d.errors import InputError
from slam2d.sim.simulate import SimulationParams, simulate

SHORT = ["--duration", "20"]


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def digest(folder: Path) -> dict[str, str]:
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


@pytest.fixture(scope="module")
def arena(tmp_path_factory):
    out = tmp_path_factory.mktemp("arena")
    assert main(["simulate", "paper-arena", "--out", str(out), *SHORT, "--seed", "7"]) == 0
    return out


def test_outputs_are_all_there(arena):
    names = {p.name for p in arena.iterdir()}
    assert {"recording.log.gz", "recording", "truth.tum", "truth-map.yaml", "truth-map.pgm", "world.yaml",
            "simulation.json"} <= names
    settings = json.loads((arena / "simulation.json").read_text())
    assert settings["simulation"]["seed"] == 7 and settings["world"] == "paper-arena"
    assert settings["scans"] == pytest.approx(200, abs=2)  # 20 s at 10 Hz


def test_same_seed_same_bytes_other_seed_other_bytes(arena, tmp_path):
    again = tmp_path / "again"
    assert main(["simulate", "paper-arena", "--out", str(again), *SHORT, "--seed", "7"]) == 0
    assert digest(again) == digest(arena)
    other = tmp_path / "other"
    assert main(["simulate", "paper-arena", "--out", str(other), *SHORT, "--seed", "8"]) == 0
    a, b = digest(arena), digest(other)
    assert a["recording.log.gz"] != b["recording.log.gz"]
    assert a["truth.tum"] == b["truth.tum"]  # the truth does not depend on the noise seed


def test_recordings_read_back_with_truth_and_odometry(arena):
    from slam2d.io import open_recording
    from slam2d.io.tum import read_tum

    t, truth = read_tum(arena / "truth.tum")
    for rec in (arena / "recording.log.gz", arena / "recording"):
        frames = list(open_recording(rec).frames())
        assert len(frames) == len(t)
        assert np.allclose([f.timestamp for f in frames], t, atol=1e-9)
        assert all(f.odometry is not None for f in frames)
        scan = frames[0].scan
        assert scan.num_beams == 682 and scan.range_max == pytest.approx(5.6)
        assert scan.mount[0] > 0.0  # the youBot's laser sits ahead of its centre
    # odometry starts at the truth and drifts away from it, a little
    odo = np.array([f.odometry for f in frames])
    err = np.hypot(*(odo[:, :2] - truth[:, :2]).T)
    assert err[0] < 1e-9 and 0.0 < err.max() < 1.0


def test_bag_plays_in_rosbags(arena):
    from rosbags.highlevel import AnyReader

    with AnyReader([arena / "recording"]) as reader:
        topics = {c.topic: c.msgtype for c in reader.connections}
        assert topics["/scan"] == "sensor_msgs/msg/LaserScan"
        assert topics["/odom"] == "nav_msgs/msg/Odometry"
        assert "/tf" in topics and "/tf_static" in topics
        counts = {c.topic: c.msgcount for c in reader.connections}
        assert counts["/odom"] == 5 * (counts["/scan"] - 1) + 1  # 50 Hz odometry, 10 Hz laser, both at t=0 and the end


def test_scans_agree_with_the_true_map(arena):
    """Endpoints of noise-free-ish scans placed at the true poses land on the true walls."""
    from slam2d.io import open_recording
    from slam2d.io.map_server import read_map
    from slam2d.io.tum import read_tum

    m = read_map(arena / "truth-map.yaml")
    occupied = m.occupancy == 100
    t, truth = read_tum(arena / "truth.tum")
    hits = total = 0
    for f, pose in zip(open_recording(arena / "recording.log.gz").frames(), truth, strict=True):
        pts = se2.transform_points(se2.compose(pose, f.scan.mount), f.scan.points())
        col = np.floor((pts[:, 0] - m.origin[0]) / m.resolution).astype(int)
        row = np.floor((pts[:, 1] - m.origin[1]) / m.resolution).astype(int)
        ok = (row >= 0) & (row < occupied.shape[0]) & (col >= 0) & (col < occupied.shape[1])
        # a 5 mm-noise endpoint lies in its wall's cell or the next one
        near = np.zeros(ok.sum(), bool)
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                r = np.clip(row[ok] + dr, 0, occupied.shape[0] - 1)
                c = np.clip(col[ok] + dc, 0, occupied.shape[1] - 1)
                near |= occupied[r, c]
        hits += int(near.sum())
        total += int(len(pts))
    assert hits / total > 0.99


def test_ros1_option(tmp_path):
    from slam2d.io import open_recording

    out = tmp_path / "r1"
    assert main(["simulate", "static-can", "--out", str(out), "--duration", "3", "--ros1"]) == 0
    assert (out / "recording.bag").is_file()
    assert len(list(open_recording(out / "recording.bag").frames())) == pytest.approx(30, abs=1)


def test_distortion_moves_the_endpoints():
    base = SimulationParams(duration=5.0, range_noise="none", dropouts=False)
    still = simulate("paper-arena", base)
    skewed = simulate("paper-arena", SimulationParams(duration=5.0, range_noise="none", dropouts=False, distortion=True))
    moving = np.flatnonzero(np.hypot(*np.diff(still.truth[:, :2], axis=0).T) > 0)
    k = int(np.searchsorted(still.scan_indices, moving[len(moving) // 2]))
    a, b = still.scans[k].ranges, skewed.scans[k].ranges
    ok = ~np.isnan(a) & ~np.isnan(b)
    assert np.nanmax(np.abs(a[ok] - b[ok])) > 1e-3


def test_turn_rate_cap():
    """--max-turn-rate caps the robot's turning as --max-speed caps its speed; the rest of the path is kept."""
    def rates(sim):
        dt = np.diff(sim.times)
        return np.abs(se2.wrap_angle(np.diff(sim.truth[:, 2]))) / dt, np.hypot(*np.diff(sim.truth[:, :2], axis=0).T) / dt

    free = simulate("paper-arena", SimulationParams(duration=30.0, max_speed=0.3))
    capped = simulate("paper-arena", SimulationParams(duration=30.0, max_speed=0.3, max_turn_rate=0.5))
    assert capped.robot.max_turn_rate == 0.5 and capped.robot.max_speed == free.robot.max_speed == 0.3
    turn_free, speed_free = rates(free)
    turn_capped, speed_capped = rates(capped)
    assert turn_free.max() > 0.6  # the preset turns faster than the cap ...
    assert turn_capped.max() <= 0.5 * (1 + 1e-6)  # ... and capped it does not
    assert speed_capped.max() <= 0.3 * (1 + 1e-6)
    # a cap above the preset's rate leaves the robot as it was
    assert simulate("paper-arena", SimulationParams(duration=1.0, max_turn_rate=99.0)).robot.max_turn_rate == \
        free.robot.max_turn_rate


# ---------------------------------------------------------------- bad input


def test_path_through_a_wall(capsys, tmp_path):
    path = tmp_path / "bad-path.yaml"
    path.write_text("waypoints: [[1.0, 1.0], [100.0, 1.0]]\n")
    code, _, err = run(capsys, "simulate", "paper-arena", "--out", tmp_path / "o", "--path", path)
    assert code == 2 and "bad-path.yaml" in err and "path" in err and "wall" in err
    assert err.strip().count("\n") == 0 and not (tmp_path / "o").exists()


def test_malformed_path_file(capsys, tmp_path):
    path = tmp_path / "p.yaml"
    path.write_text("waypoints: [[1.0], [2.0, 3.0]]\n")
    code, _, err = run(capsys, "simulate", "paper-arena", "--out", tmp_path / "o", "--path", path)
    assert code == 2 and "p.yaml" in err and "waypoints" in err


def test_unknown_world_robot_laser(capsys, tmp_path):
    for argv, needle in (
        (["no-such-world"], "no-such-world"),
        (["paper-arena", "--robot", "roomba"], "robot"),
        (["paper-arena", "--laser", "velodyne"], "laser"),
        (["paper-arena", "--range-noise", "loud"], "range_noise"),
        (["paper-arena", "--srr", "-1"], "srr"),
    ):
        code, _, err = run(capsys, "simulate", *argv, "--out", tmp_path / "o")
        assert code == 2 and needle in err, (argv, err)
        assert "Traceback" not in err
    assert not (tmp_path / "o").exists()


def test_start_outside_the_world(tmp_path):
    world = tmp_path / "w.yaml"
    world.write_text(
        "name: box\nwalls:\n  - {box: {min: [0, 0], max: [4, 3]}, material: cardboard}\n"
        "start: [10, 10, 0]\npath: [[2, 1.5]]\n"
    )
    with pytest.raises(InputError) as err:
        simulate(world, SimulationParams(duration=1.0))
    assert "w.yaml" in str(err.value) and "start" in str(err.value)


def test_the_last_beam_of_a_distorted_sweep_is_cast_from_the_pose_at_the_sweeps_end():
    # Beam N-1 is measured N-1 mirror steps after beam 0 (LaserSpec.sweep_duration), not N:
    # the end pose was one beam step late (RPLidar: 0.5 ms of motion).
    from slam2d.sim.laser import LaserSimulator
    from slam2d.io.tum import interpolate_poses
    from slam2d.sensors.range_noise import ConstantSigma

    params = SimulationParams(duration=6.0, range_noise="none", dropouts=False, distortion=True, laser="rplidar-a1")
    sim = simulate("paper-arena", params)
    lidar = LaserSimulator(sim.laser, sim.world, ConstantSigma(0.0), dropouts=False)
    mount = np.asarray(sim.robot.laser_mount, dtype=np.float64)
    checked = 0
    times = sim.times - params.start_time  # the simulator's own clock: stamps from 1970 lose digits
    for k, i in enumerate(sim.scan_indices[:-2]):
        end = interpolate_poses(times, sim.truth, times[i] + sim.laser.sweep_duration, np.inf)[0][0]
        start = sim.truth[i]
        if np.hypot(*(end[:2] - start[:2])) < 0.01 or np.isnan(sim.scans[k].ranges[-1]):
            continue
        expected = lidar.cast(se2.compose(end, mount))[0][-1]
        # 20 microns: the stamps from 1970 round the recovered clock (one beam step late moves it 250 microns)
        assert sim.scans[k].ranges[-1] == pytest.approx(expected, abs=2e-5)
        checked += 1
    assert checked > 5


def test_an_absurd_duration_is_refused_before_planning_its_laps():
    with pytest.raises(InputError, match="samples, more than") as info:
        simulate("paper-arena", SimulationParams(duration=1e12))
    assert info.value.field == "duration"


def test_a_negative_seed_is_refused_by_name():
    with pytest.raises(InputError, match="below the minimum 0") as info:
        simulate("paper-arena", SimulationParams(seed=-1, duration=1.0))
    assert info.value.field == "seed"


def test_command_file_errors_name_the_file(tmp_path):
    path = tmp_path / "drive.yaml"
    path.write_text("commands: [[-1, 0.1, 0, 0]]\n")
    with pytest.raises(InputError) as info:
        simulate("paper-arena", SimulationParams(duration=None), path=path)
    assert info.value.path == str(path) and info.value.field == "commands[0].duration"


def test_a_truth_map_too_large_writes_nothing(tmp_path):
    from slam2d.sim.simulate import write_outputs

    sim = simulate("paper-arena", SimulationParams(duration=2.0))
    with pytest.raises(InputError, match="too large"):
        write_outputs(sim, tmp_path / "out", map_resolution=1e-7)
    assert not (tmp_path / "out").exists()  # not a recording without its truth map


def test_the_simulated_bag_states_a_real_epoch_the_laser_timing_and_the_odometry_noise(tmp_path):
    """tf takes a stamp of 0 as 'not yet valid'; a driver states its sweep timing, odometry its twist and
    covariance: a simulated bag says all of it, from the simulator's own laser and noise model."""
    from rosbags.highlevel import AnyReader

    from slam2d.sim.simulate import write_outputs

    params = SimulationParams(duration=4.0)
    sim = simulate("paper-arena", params)
    write_outputs(sim, tmp_path, ros1=True)
    scans, odometry = [], []
    with AnyReader([tmp_path / "recording.bag"]) as reader:
        for conn, _, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            (scans if conn.topic == "/scan" else odometry if conn.topic == "/odom" else []).append(msg)
    first = scans[0].header.stamp.sec + 1e-9 * scans[0].header.stamp.nanosec
    assert first == pytest.approx(params.start_time, abs=1e-6)
    assert scans[0].scan_time == pytest.approx(1.0 / sim.laser.rate)
    assert scans[0].time_increment == pytest.approx(sim.laser.sweep_duration / (len(scans[0].ranges) - 1))
    moving = [m for m in odometry if abs(m.twist.twist.linear.x) + abs(m.twist.twist.linear.y) > 0.05]
    assert moving, "the robot drives: some odometry reports speed"
    last = odometry[-1]
    assert last.pose.covariance[0] > 0 and last.pose.covariance[7] > 0 and last.pose.covariance[35] > 0
    # dead reckoning only grows less certain
    assert last.pose.covariance[35] >= odometry[len(odometry) // 2].pose.covariance[35] > 0
    assert moving[-1].twist.covariance[0] > 0
    # the twist is the odometry's own motion: speed times the period is its step
    a, b = sim.odometry[-2], sim.odometry[-1]
    step = np.hypot(*(b[:2] - a[:2]))
    speed = np.hypot(last.twist.twist.linear.x, last.twist.twist.linear.y)
    assert speed * (sim.times[-1] - sim.times[-2]) == pytest.approx(step, rel=1e-6, abs=1e-9)
    # the CARMEN log and the truth share the stamps
    from slam2d.io.tum import read_tum

    t, _ = read_tum(tmp_path / "truth.tum")
    assert t[0] == pytest.approx(params.start_time, abs=1e-6)
