"""Scan clean-up, frame assembly and the timestamp checks readers rely on."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from slam2d.core import Frame, OdometryReading, TimestampCheck, assemble_frames, make_scan, se2
from slam2d.errors import InputError, ProblemLog


def test_invalid_readings_become_no_return():
    s = make_scan(0.0, [1.0, np.nan, np.inf, -np.inf, 0.0, -2.0, 0.01, 30.0, 29.99], -1.0, 0.1, 0.02, 30.0)
    expected_valid = [True, False, False, False, False, False, False, False, True]
    assert s.valid.tolist() == expected_valid
    assert np.isnan(s.ranges[~s.valid]).all()
    assert s.ranges[0] == 1.0 and s.ranges[-1] == 29.99


def test_negative_increment_is_normalised():
    ranges = np.arange(1.0, 6.0)
    s = make_scan(0.0, ranges, 1.0, -0.5, 0.0, 10.0)
    assert s.angle_increment == 0.5
    assert s.angle_min == pytest.approx(-1.0)
    # the beam that pointed at +1 rad still measures 1 m, wherever it sits in the array
    assert s.ranges[np.argmin(np.abs(s.angles - 1.0))] == 1.0
    assert s.ranges[np.argmin(np.abs(s.angles + 1.0))] == 5.0


def test_upside_down_laser_mirrors_points():
    # a reading straight to the laser's left (+90 deg) is on the robot's right when mounted upside down
    s = make_scan(0.0, [2.0], np.pi / 2, 0.1, 0.0, 10.0, upside_down=True)
    (x, y), = s.points()
    assert x == pytest.approx(0.0, abs=1e-12) and y == pytest.approx(-2.0)


@given(st.integers(1, 10_000))
def test_any_beam_count_up_to_ten_thousand(n):
    s = make_scan(0.0, np.full(n, 3.0), -np.pi, 2 * np.pi / max(n, 1), 0.0, 10.0)
    assert s.num_beams == n
    assert s.points().shape == (n, 2)
    assert np.allclose(np.hypot(*s.points().T), 3.0)


def test_points_in_base_use_the_mount():
    s = make_scan(0.0, [1.0], 0.0, 0.01, 0.0, 10.0, mount=[0.145, 0.0, np.pi / 2])
    (x, y), = s.points_in_base()
    assert x == pytest.approx(0.145) and y == pytest.approx(1.0)


@pytest.mark.parametrize(
    "kwargs, field",
    [
        (dict(ranges=[]), "ranges"),
        (dict(angle_increment=0.0), "angle_increment"),
        (dict(angle_min=np.nan), "angle_min"),
        (dict(range_min=-1.0), "range_min"),
        (dict(range_max=0.0), "range_max"),
        (dict(mount=[0.0, 0.0]), "mount"),
        (dict(intensities=[1.0]), "intensities"),
    ],
)
def test_bad_scans_name_the_field(kwargs, field):
    args = dict(timestamp=0.0, ranges=[1.0, 2.0], angle_min=0.0, angle_increment=0.1, range_min=0.0, range_max=5.0)
    args.update(kwargs)
    with pytest.raises(ValueError, match=field):
        make_scan(**args)


def _scan(t):
    return make_scan(t, [1.0, 2.0], 0.0, 0.1, 0.0, 5.0)


def test_frames_interpolate_odometry_at_scan_time():
    msgs = [
        OdometryReading(0.0, np.array([0.0, 0.0, 0.0])),
        _scan(0.25),
        OdometryReading(1.0, np.array([1.0, 2.0, 0.4])),
        _scan(1.0),
    ]
    frames = list(assemble_frames(msgs))
    assert [f.index for f in frames] == [0, 1]
    assert np.allclose(frames[0].odometry, [0.25, 0.5, 0.1])
    assert np.allclose(frames[1].odometry, [1.0, 2.0, 0.4])


def test_frames_without_odometry_and_beyond_the_gap():
    msgs = [_scan(0.0), _scan(0.1), OdometryReading(5.0, np.ones(3)), _scan(5.2), _scan(9.0)]
    frames = list(assemble_frames(msgs, max_gap=0.5))
    assert frames[0].odometry is None and frames[1].odometry is None
    assert np.allclose(frames[2].odometry, 1.0)  # held: 0.2 s after the last reading
    assert frames[3].odometry is None  # 4 s after it


def test_frames_keep_scan_order_and_ignore_stale_odometry():
    msgs = [OdometryReading(0.0, np.zeros(3)), _scan(0.5), OdometryReading(2.0, np.array([2.0, 0, 0]))]
    msgs.insert(2, OdometryReading(-1.0, np.full(3, 99.0)))  # stale, must be ignored
    (f,) = assemble_frames(msgs)
    assert isinstance(f, Frame)
    assert np.allclose(f.odometry, [0.5, 0.0, 0.0])


def test_frame_assembly_streams_in_bounded_memory():
    def stream(n):
        for i in range(n):
            yield OdometryReading(i * 0.1, np.array([i * 0.1, 0.0, 0.0]))
            yield _scan(i * 0.1 + 0.05)

    count = 0
    for f in assemble_frames(stream(20_000)):
        count += 1
        assert f.odometry[0] == pytest.approx(f.timestamp, abs=1e-9) or f.index == 19_999
    assert count == 20_000


def test_timestamp_check_rules():
    problems = ProblemLog()
    check = TimestampCheck("x.log", problems, tolerance=1.0, max_jump=100.0)
    assert check.scan(10.0, 1)
    assert check.scan(9.9, 2)  # small step back: kept, counted
    assert problems.counts["scan timestamp stepped back (kept)"] == 1
    assert check.odometry(5.0, 3) and not check.odometry(4.0, 4)  # out of order: dropped
    with pytest.raises(InputError, match=r"x\.log:5: timestamp: .*before the previous scan"):
        check.scan(5.0, 5)
    with pytest.raises(InputError, match=r"x\.log:6: stamp: -1\.0 is negative"):
        check.scan(-1.0, 6, field="stamp")
    assert check.scan(3e9, 7)  # a jump forward (a pause, a reset clock) is kept, with a warning
    assert problems.counts["time jumped forward (kept: a pause or a reset clock)"] == 1
    with pytest.raises(InputError, match="after the year 2096"):
        check.odometry(4.29497e9, 7)
    with pytest.raises(InputError, match="not a finite"):
        check.odometry(float("nan"), 8)


def test_timestamp_check_skip_mode_counts():
    problems = ProblemLog()
    check = TimestampCheck("x.log", problems, skip=True, max_jump=100.0)
    assert check.scan(1.0, 1)
    assert not check.scan(4.1e9, 2)  # after 2096
    assert not check.scan(-3.0, 3)
    assert check.scan(2.0, 4)  # the bad ones did not move the clock
    assert check.scan(2.0, 5)  # a repeated stamp is kept and counted
    assert problems.counts["scan timestamp repeated (kept)"] == 1
    assert problems.total() == 3


def test_relative_odometry_between_frames_matches_se2():
    a, b = np.array([1.0, 1.0, 0.3]), np.array([2.0, 0.5, -0.2])
    f0 = Frame(0, _scan(0.0), a)
    f1 = Frame(1, _scan(1.0), b)
    assert np.allclose(se2.compose(f0.odometry, se2.relative(f0.odometry, f1.odometry)), b)
