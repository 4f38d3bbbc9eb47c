"""Robots, paths and odometry of the simulator (slam2d.sim.robot, slam2d.sensors.motion_noise)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from slam2d.core import se2
from slam2d.errors import InputError
from slam2d.sensors.motion_noise import OdometryNoise, simulate_odometry
from slam2d.sim.robot import ROBOT_PRESETS, follow_waypoints, robot_preset, scripted

RATE = 50.0
EXACT = OdometryNoise(srr=0.0, srt=0.0, str=0.0, stt=0.0)

# A loop with a gentle turn (~27 deg), right angles, a sharp turn (~153 deg) and a short leg.
LOOP = np.array([[4.0, 0.0], [6.0, 1.0], [6.0, 4.0], [1.0, 4.0], [5.0, 2.0], [5.0, 2.3], [0.0, 1.5]])


def _velocities(times, poses):
    dt = np.diff(times)
    v = np.diff(poses[:, :2], axis=0) / dt[:, None]
    w = se2.wrap_angle(np.diff(poses[:, 2])) / dt
    return v, w


def _lateral_steps(poses):
    """Sideways part of each step, measured across the mean heading of its two ends."""
    step = np.diff(poses[:, :2], axis=0)
    mid = poses[:-1, 2] + 0.5 * se2.wrap_angle(np.diff(poses[:, 2]))
    return -np.sin(mid) * step[:, 0] + np.cos(mid) * step[:, 1]


def _sideways_excess(poses, max_turn_per_step=None):
    """How far each step's chord strays beyond what a robot that only moves where it faces allows.

    If the velocity always points along the heading and the heading turns one way
    during a step, the chord lies within the headings swept, so its angle to the
    mean heading is at most half the heading change. Zero for a non-holonomic robot.
    When the turn may reverse within a step (an S-bend), pass the most the
    heading can turn in one step: the chord then stays within 1.5 times that.
    """
    step = np.diff(poses[:, :2], axis=0)
    if max_turn_per_step is None:
        deviation = 0.5 * np.abs(se2.wrap_angle(np.diff(poses[:, 2])))
    else:
        deviation = 1.5 * max_turn_per_step
    allowed = np.hypot(step[:, 0], step[:, 1]) * np.sin(deviation)
    return np.abs(_lateral_steps(poses)) - allowed


# ----------------------------------------------------------------------------- presets and bad input


def test_presets_are_valid_and_named():
    assert set(ROBOT_PRESETS) == {"youbot", "diff-drive"}
    youbot = robot_preset("youbot")
    assert youbot.drive == "omni" and youbot.max_speed == 0.8 and youbot.laser_mount == (0.3, 0.0, 0.0)
    assert robot_preset("diff-drive").drive == "diff"
    # a copy: changing it does not change the preset
    assert dataclasses.replace(youbot, max_speed=0.1) != ROBOT_PRESETS["youbot"]


def test_docs_table_matches_the_presets():
    from pathlib import Path

    page = (Path(__file__).resolve().parents[1] / "docs" / "robots.md").read_text()
    for name, spec in ROBOT_PRESETS.items():
        row = next(line for line in page.splitlines() if line.startswith(f"| `{name}` |"))
        cells = [c.strip() for c in row.strip("|").split("|")]
        numbers = [float(c.split()[0]) for c in cells[2:7]]
        assert cells[1] == spec.drive
        assert numbers == [spec.max_speed, spec.max_turn_rate, spec.max_acceleration,
                           spec.max_angular_acceleration, spec.radius], name
        assert tuple(float(v) for v in cells[7].strip("()").split(",")) == spec.laser_mount


def test_unknown_preset_lists_presets():
    with pytest.raises(InputError) as err:
        robot_preset("roomba")
    assert err.value.field == "robot"
    assert "youbot" in str(err.value) and "diff-drive" in str(err.value) and "roomba" in str(err.value)


@pytest.mark.parametrize(
    "field, value",
    [("max_speed", -0.5), ("max_turn_rate", 0.0), ("max_acceleration", -1.0),
     ("max_angular_acceleration", -2.0), ("radius", -0.1), ("max_speed", float("nan"))],
)
def test_bad_limits_name_the_field(field, value):
    spec = dataclasses.replace(robot_preset("diff-drive"), **{field: value})
    with pytest.raises(InputError) as err:
        follow_waypoints(spec, [0, 0, 0], [[1, 0]], rate=RATE)
    assert err.value.field == field
    with pytest.raises(InputError) as err:
        scripted(spec, [0, 0, 0], [(1.0, 0.1, 0.0, 0.0)], rate=RATE)
    assert err.value.field == field


def test_unknown_drive_is_refused():
    spec = dataclasses.replace(robot_preset("youbot"), drive="tracked")
    with pytest.raises(InputError) as err:
        follow_waypoints(spec, [0, 0, 0], [[1, 0]], rate=RATE)
    assert err.value.field == "drive" and "omni" in str(err.value)


def test_diff_drive_refuses_sideways_commands():
    with pytest.raises(InputError) as err:
        scripted(robot_preset("diff-drive"), [0, 0, 0], [(1.0, 0.2, 0.0, 0.0), (1.0, 0.1, 0.05, 0.0)], rate=RATE)
    assert err.value.field == "commands[1].vy" and "sideways" in str(err.value)
    # the same command is fine for an omnidirectional base
    scripted(robot_preset("youbot"), [0, 0, 0], [(1.0, 0.1, 0.05, 0.0)], rate=RATE)


@pytest.mark.parametrize(
    "command, field",
    [((1.0, 0.9, 0.0, 0.0), "commands[0]"),  # faster than the youBot's 0.8 m/s
     ((1.0, 0.0, 0.0, 3.0), "commands[0].omega"),
     ((-1.0, 0.1, 0.0, 0.0), "commands[0].duration"),
     ((1.0, 0.1, 0.0), "commands[0]"),
     (("a", 0.1, 0.0, 0.0), "commands[0]")],
)
def test_bad_commands_name_the_field(command, field):
    with pytest.raises(InputError) as err:
        scripted(robot_preset("youbot"), [0, 0, 0], [command], rate=RATE)
    assert err.value.field == field


@pytest.mark.parametrize(
    "kwargs, field",
    [({"waypoints": [[1, 0, 2]]}, "waypoints"), ({"waypoints": []}, "waypoints"),
     ({"waypoints": [[1, float("inf")]]}, "waypoints"), ({"start": [0, 0]}, "start"),
     ({"rate": 0.0}, "rate"), ({"duration": -1.0}, "duration"), ({"speed": 5.0}, "speed"),
     ({"speed": -0.1}, "speed")],
)
def test_bad_path_input_names_the_field(kwargs, field):
    args = {"start": [0, 0, 0], "waypoints": [[1, 0]], "rate": RATE} | kwargs
    with pytest.raises(InputError) as err:
        follow_waypoints(robot_preset("youbot"), args.pop("start"), args.pop("waypoints"), **args)
    assert err.value.field == field


# ----------------------------------------------------------------------------- following waypoints


@pytest.fixture(scope="module", params=["youbot", "diff-drive"])
def lap(request):
    spec = robot_preset(request.param)
    times, poses = follow_waypoints(spec, [0.0, 0.0, 2.0], LOOP, rate=RATE, loop=True)
    return spec, times, poses


def test_kinematic_limits_hold(lap):
    spec, times, poses = lap
    np.testing.assert_allclose(np.diff(times), 1.0 / RATE, rtol=1e-9)
    v, w = _velocities(times, poses)
    speed = np.hypot(v[:, 0], v[:, 1])
    accel = np.hypot(*(np.diff(v, axis=0) * RATE).T)
    assert speed.max() <= spec.max_speed * (1 + 1e-9)
    assert speed.max() > 0.95 * spec.max_speed  # the limits are used, not just respected
    assert accel.max() <= spec.max_acceleration * (1 + 1e-6)
    assert np.abs(w).max() <= spec.max_turn_rate * (1 + 1e-9)
    alpha = np.abs(np.diff(w) * RATE)
    if spec.drive == "omni":
        assert alpha.max() <= spec.max_angular_acceleration * (1 + 1e-6)
    else:
        # in-place turns respect it; arcs start with a step in turn rate (documented)
        standing = (speed[:-1] < 1e-9) & (speed[1:] < 1e-9)
        assert standing.sum() > 50
        assert alpha[standing].max() <= spec.max_angular_acceleration * (1 + 1e-6)


def test_waypoints_are_reached_in_order(lap):
    spec, times, poses = lap
    tolerance = 1e-3 if spec.drive == "omni" else 0.1 + 1e-3  # diff rounds corners by corner_tolerance
    index = 0
    for point in np.vstack([LOOP, LOOP[:1]]):
        dist = np.hypot(*(poses[index:, :2] - point).T)
        hits = np.flatnonzero(dist <= tolerance)
        assert len(hits), f"{point} not reached after sample {index} (closest {dist.min():.3f} m)"
        index += int(hits[0]) + 1
    # the lap ends at rest on the first waypoint
    np.testing.assert_allclose(poses[-1, :2], LOOP[0], atol=1e-9)
    v, _ = _velocities(times, poses)
    assert np.hypot(*v[-1]) <= spec.max_acceleration / RATE  # the last step only holds the end of braking


def test_diff_drive_never_moves_sideways_omni_does(lap):
    spec, times, poses = lap
    if spec.drive == "diff":
        assert _sideways_excess(poses).max() < 1e-12
        # and it faces the way it goes: forward motion only
        step = np.diff(poses[:, :2], axis=0)
        forward = np.cos(poses[:-1, 2]) * step[:, 0] + np.sin(poses[:-1, 2]) * step[:, 1]
        assert forward.min() > -1e-12
    else:
        # it starts facing 2 rad off its first leg and slides while turning
        assert _sideways_excess(poses).max() * RATE > 0.1


def test_omni_heading_turns_toward_the_direction_of_travel():
    spec = robot_preset("youbot")
    times, poses = follow_waypoints(spec, [0.0, 0.0, math.pi / 2], [[3.0, 0.0], [3.0, -3.0]], rate=RATE)
    assert abs(se2.wrap_angle(poses[-1, 2] + math.pi / 2)) < 1e-9  # faces along the last leg at the end
    at_corner = np.argmin(np.hypot(*(poses[:, :2] - [3.0, 0.0]).T))
    assert abs(poses[at_corner, 2]) < 1e-9  # had turned to face the first leg before reaching its end


def test_duration_loops_the_path_and_is_sampled_exactly():
    spec = robot_preset("diff-drive")
    square = [[2.0, 0.0], [2.0, 2.0], [0.0, 2.0], [0.0, 0.0]]
    times, poses = follow_waypoints(spec, [0, 0, 0], square, rate=RATE, duration=120.0, loop=True)
    assert len(times) == 6001 and times[-1] == pytest.approx(120.0)
    # corner (2, 2) is passed once per lap; a lap takes under 30 s, so at least four times
    near = np.hypot(*(poses[:, :2] - [2.0, 2.0]).T) < 0.2
    passes = np.count_nonzero(np.diff(near.astype(int)) == 1)
    assert passes >= 4
    # a single pass that ends early stands still until the duration
    times1, poses1 = follow_waypoints(spec, [0, 0, 0], square, rate=RATE, duration=120.0)
    assert len(times1) == 6001
    np.testing.assert_allclose(poses1[-500:, :2], [[0.0, 0.0]] * 500, atol=1e-9)


def test_speed_argument_caps_the_cruise_speed():
    spec = robot_preset("youbot")
    times, poses = follow_waypoints(spec, [0, 0, 0], [[5.0, 0.0]], rate=RATE, speed=0.3)
    speed = np.hypot(*_velocities(times, poses)[0].T)
    assert speed.max() == pytest.approx(0.3, rel=1e-6)
    # trapezoid: 0.3 s up at 1 m/s^2, 0.3 s down, cruise for the rest of 5 m
    assert times[-1] == pytest.approx(0.3 + 5.0 / 0.3, abs=1.0 / RATE)


def test_waypoint_at_the_start_stays_put():
    times, poses = follow_waypoints(robot_preset("youbot"), [1.0, 2.0, 0.5], [[1.0, 2.0]], rate=RATE)
    assert len(times) == 1 and np.allclose(poses, [[1.0, 2.0, 0.5]])


# ----------------------------------------------------------------------------- scripted commands


def test_constant_velocity_arc_ends_where_geometry_says():
    start = np.array([1.0, -2.0, 0.3])
    v, omega, duration = 0.5, 0.25, 4.0
    times, poses = scripted(robot_preset("diff-drive"), start, [(duration, v, 0.0, omega)], rate=RATE)
    assert len(times) == 201 and times[-1] == pytest.approx(duration)
    r = v / omega
    centre = start[:2] + r * np.array([-math.sin(start[2]), math.cos(start[2])])
    end_heading = start[2] + omega * duration
    expected = [centre[0] + r * math.sin(end_heading), centre[1] - r * math.cos(end_heading), end_heading]
    np.testing.assert_allclose(poses[-1], expected, atol=1e-12)
    np.testing.assert_allclose(np.hypot(*(poses[:, :2] - centre).T), r, atol=1e-12)  # every sample on the circle


def test_omni_twist_matches_numerical_integration():
    start = np.array([0.5, 0.2, -1.0])
    vx, vy, omega, duration = 0.3, -0.2, 0.7, 3.0
    _, poses = scripted(robot_preset("youbot"), start, [(duration, vx, vy, omega)], rate=RATE)
    # independent check: RK4 on the world-frame ODE
    state = start.copy()
    n = 20000
    h = duration / n

    def f(s):
        c, si = math.cos(s[2]), math.sin(s[2])
        return np.array([c * vx - si * vy, si * vx + c * vy, omega])

    for _ in range(n):
        k1 = f(state)
        k2 = f(state + h / 2 * k1)
        k3 = f(state + h / 2 * k2)
        k4 = f(state + h * k3)
        state = state + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    np.testing.assert_allclose(poses[-1, :2], state[:2], atol=1e-10)
    assert se2.wrap_angle(poses[-1, 2] - state[2]) == pytest.approx(0.0, abs=1e-10)


def test_scripted_square_closes_and_straight_lines_are_straight():
    quarter = math.pi / 2
    commands = [(4.0, 0.5, 0.0, 0.0), (quarter / 0.5, 0.0, 0.0, 0.5)] * 4
    times, poses = scripted(robot_preset("diff-drive"), [0, 0, 0], commands, rate=RATE)
    np.testing.assert_allclose(poses[-1], [0.0, 0.0, 0.0], atol=1e-9)
    first_leg = poses[times <= 4.0]
    np.testing.assert_allclose(first_leg[:, 1:], 0.0, atol=1e-12)
    np.testing.assert_allclose(first_leg[:, 0], 0.5 * times[times <= 4.0], atol=1e-12)
    assert _sideways_excess(poses).max() < 1e-12


# ----------------------------------------------------------------------------- odometry


def _straight(length=10.0, speed=0.5, rate=RATE):
    return scripted(robot_preset("youbot"), [0, 0, 0], [(length / speed, speed, 0.0, 0.0)], rate=rate)


def _spin(angle=2 * math.pi, omega=0.5, rate=RATE):
    return scripted(robot_preset("youbot"), [1.0, 1.0, 0.0], [(angle / omega, 0.0, 0.0, omega)], rate=rate)


def test_noise_free_odometry_equals_the_truth(lap):
    spec, times, poses = lap
    odom = simulate_odometry(times, poses, EXACT, np.random.default_rng(1))
    np.testing.assert_allclose(odom[:, :2], poses[:, :2], atol=1e-9)
    assert np.abs(se2.wrap_angle(odom[:, 2] - poses[:, 2])).max() < 1e-9


def test_systematic_scales_enter_as_documented(lap):
    spec, times, poses = lap
    biased = dataclasses.replace(EXACT, wheel_radius_scale=1.04, track_width_scale=0.9)
    odom = simulate_odometry(times, poses, biased, np.random.default_rng(1))
    true_steps = se2.relative(poses[:-1], poses[1:])
    odom_steps = se2.relative(odom[:-1], odom[1:])
    np.testing.assert_allclose(odom_steps[:, :2], 1.04 * true_steps[:, :2], atol=1e-12)
    np.testing.assert_allclose(odom_steps[:, 2], true_steps[:, 2] / 0.9, atol=1e-12)
    # end to end: a 10 m straight drive reads 10.4 m, a full turn reads 2 pi / 0.9
    times, poses = _straight()
    assert simulate_odometry(times, poses, biased, np.random.default_rng(0))[-1, 0] == pytest.approx(10.4)
    times, poses = _spin()
    heading = np.unwrap(simulate_odometry(times, poses, biased, np.random.default_rng(0))[:, 2])
    assert heading[-1] - heading[0] == pytest.approx(2 * math.pi / 0.9)


def test_slip_inflates_odometry_as_documented():
    times, poses = _straight()
    always = dataclasses.replace(EXACT, slip_probability=1.0, slip_fraction=0.2)
    assert simulate_odometry(times, poses, always, np.random.default_rng(0))[-1, 0] == pytest.approx(10.0 / 0.8)
    # a quarter of the steps slip: the excess is 0.25 * 0.2 / 0.8 = 6.25 % on average
    sometimes = dataclasses.replace(always, slip_probability=0.25)
    ends = np.array([simulate_odometry(times, poses, sometimes, np.random.default_rng(s))[-1, 0] for s in range(200)])
    steps = len(times) - 1
    per_run_std = 10.0 * 0.25 * math.sqrt(0.25 * 0.75 / steps)  # binomial count of slipping steps
    assert abs(ends.mean() - 10.0 * (1 + 0.0625)) < 5 * per_run_std / math.sqrt(len(ends))


def _end_errors(times, poses, noise, runs):
    ends = np.array([simulate_odometry(times, poses, noise, np.random.default_rng(s))[-1] for s in range(runs)])
    err = ends - poses[-1]
    err[:, 2] = se2.wrap_angle(err[:, 2])
    return err


def _assert_std(samples, expected):
    """Sample std within 5 standard errors of ``expected`` (std of a normal sample std: sigma / sqrt(2n))."""
    n = len(samples)
    assert abs(samples.mean()) < 5 * expected / math.sqrt(n)
    assert abs(samples.std(ddof=1) - expected) < 5 * expected / math.sqrt(2 * n), (samples.std(ddof=1), expected)


RUNS = 2000


@pytest.mark.parametrize("length", [2.5, 10.0])
def test_translation_spread_grows_as_configured(length):
    noise = OdometryNoise(srr=0.1, srt=0.0, str=0.0, stt=0.0)
    times, poses = _straight(length)
    err = _end_errors(times, poses, noise, RUNS)
    _assert_std(err[:, 0], 0.1 * math.sqrt(length * noise.reference_distance))
    _assert_std(err[:, 1], 0.3 * 0.1 * math.sqrt(length * noise.reference_distance))
    assert np.abs(err[:, 2]).max() == 0.0


def test_spread_does_not_depend_on_the_odometry_rate():
    noise = OdometryNoise(srr=0.1, srt=0.0, str=0.0, stt=0.0)
    for rate in (10.0, 200.0):
        times, poses = _straight(10.0, rate=rate)
        _assert_std(_end_errors(times, poses, noise, RUNS)[:, 0], 0.1 * math.sqrt(10.0))


def test_heading_spread_from_translation_srt():
    noise = OdometryNoise(srr=0.0, srt=0.05, str=0.0, stt=0.0)
    times, poses = _straight(10.0)
    _assert_std(_end_errors(times, poses, noise, RUNS)[:, 2], 0.05 * math.sqrt(10.0 * 1.0))


def test_heading_spread_after_pure_rotation():
    noise = OdometryNoise(srr=0.0, srt=0.0, str=0.0, stt=0.2)
    times, poses = _spin(2 * math.pi)
    err = _end_errors(times, poses, noise, RUNS)
    _assert_std(err[:, 2], 0.2 * math.sqrt(2 * math.pi * noise.reference_rotation))
    assert np.abs(err[:, :2]).max() < 1e-12  # rotating in place moves nothing


def test_translation_spread_from_rotation_str():
    noise = OdometryNoise(srr=0.0, srt=0.0, str=0.1, stt=0.0)
    times, poses = _spin(2 * math.pi)
    err = _end_errors(times, poses, noise, RUNS)
    expected = 0.1 * math.sqrt(2 * math.pi * noise.reference_rotation)
    _assert_std(err[:, 0], expected)
    _assert_std(err[:, 1], expected)


def test_one_reference_increment_has_gmappings_spread():
    """A single step of exactly 1 m has GMapping's std srr * 1 m (forward) and 0.3 srr (sideways)."""
    times = np.array([0.0, 1.0])
    poses = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    err = _end_errors(times, poses, OdometryNoise(srr=0.1, srt=0.0, str=0.0, stt=0.0), RUNS)
    _assert_std(err[:, 0], 0.1)
    _assert_std(err[:, 1], 0.03)


def test_odometry_is_deterministic_by_seed(lap):
    spec, times, poses = lap
    noise = OdometryNoise(slip_probability=0.1, slip_fraction=0.3)
    a = simulate_odometry(times, poses, noise, np.random.default_rng(7))
    b = simulate_odometry(times, poses, noise, np.random.default_rng(7))
    c = simulate_odometry(times, poses, noise, np.random.default_rng(8))
    assert np.array_equal(a, b)
    assert not np.allclose(a, c)
    np.testing.assert_array_equal(a[0], poses[0])
    # and the true trajectory itself has no randomness
    again = follow_waypoints(spec, [0.0, 0.0, 2.0], LOOP, rate=RATE, loop=True)
    assert np.array_equal(again[1], poses)


@pytest.mark.parametrize(
    "change, field",
    [({"srr": -0.1}, "srr"), ({"str": float("nan")}, "str"), ({"slip_fraction": 1.0}, "slip_fraction"),
     ({"slip_probability": 1.5}, "slip_probability"), ({"wheel_radius_scale": 0.0}, "wheel_radius_scale")],
)
def test_bad_noise_parameters_name_the_field(change, field):
    times, poses = _straight(1.0)
    with pytest.raises(InputError) as err:
        simulate_odometry(times, poses, dataclasses.replace(OdometryNoise(), **change), np.random.default_rng(0))
    assert err.value.field == field


def test_bad_trajectories_are_refused():
    rng = np.random.default_rng(0)
    with pytest.raises(InputError) as err:
        simulate_odometry([0.0, 1.0, 1.0], np.zeros((3, 3)), OdometryNoise(), rng)
    assert err.value.field == "times"
    with pytest.raises(InputError) as err:
        simulate_odometry([0.0, 1.0], np.zeros((3, 3)), OdometryNoise(), rng)
    assert err.value.field == "true_poses"
    with pytest.raises(InputError):
        simulate_odometry([0.0, 1.0], np.zeros((2, 2)), OdometryNoise(), rng)


def test_ten_minutes_of_driving():
    # Its speed is measured by the `simulate-office` benchmark.
    spec = robot_preset("youbot")
    times, poses = follow_waypoints(spec, [0, 0, 0], LOOP, rate=RATE, duration=600.0, loop=True)
    odom = simulate_odometry(times, poses, OdometryNoise(), np.random.default_rng(0))
    assert len(odom) == 30001
    assert np.all(np.isfinite(odom))


@settings(max_examples=60, deadline=None)
@given(
    drive=st.sampled_from(["youbot", "diff-drive"]),
    heading=st.floats(-math.pi, math.pi),
    points=st.lists(st.tuples(st.floats(-5, 5), st.floats(-5, 5)), min_size=1, max_size=6),
    loop=st.booleans(),
)
def test_limits_hold_on_random_paths(drive, heading, points, loop):
    spec = robot_preset(drive)
    times, poses = follow_waypoints(spec, [0.0, 0.0, heading], points, rate=RATE, loop=loop)
    end = points[0] if loop else points[-1]
    np.testing.assert_allclose(poses[-1, :2], end, atol=1e-6)  # waypoints within 1 um are merged
    if len(times) < 3:
        return
    v, w = _velocities(times, poses)
    assert np.hypot(*v.T).max() <= spec.max_speed * (1 + 1e-9)
    assert np.hypot(*(np.diff(v, axis=0) * RATE).T).max() <= spec.max_acceleration * (1 + 1e-6)
    assert np.abs(w).max() <= spec.max_turn_rate * (1 + 1e-9)
    if drive == "diff-drive":
        assert _sideways_excess(poses, spec.max_turn_rate / RATE).max() < 1e-12
