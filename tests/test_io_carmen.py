"""CARMEN logs: round trips through write_carmen, every real log, and bad input."""

from __future__ import annotations

import gzip
import math
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from slam2d.core import se2
from slam2d.core.frames import Frame, OdometryReading
from slam2d.core.scan import LaserScan, make_scan
from slam2d.errors import InputError
from slam2d.io import open_recording
from slam2d.io.base import ReadOptions
from slam2d.io.carmen import DEFAULT_SICK_MAX_RANGE, CarmenLog, infer_no_return_code, write_carmen
from slam2d.io.inspect import summarize
from slam2d.io.tum import interpolate_poses, read_tum
from tests.conftest import dataset_file

# ---------------------------------------------------------------------------- helpers


def _random_frames(n_frames: int, beams: int, *, seed: int = 0, odometry: bool = True) -> list[Frame]:
    rng = np.random.default_rng(seed)
    frames = []
    t = 1000.0 + rng.random()
    for i in range(n_frames):
        ranges = rng.uniform(0.1, 30.0, beams)
        ranges[rng.random(beams) < 0.2] = np.nan
        scan = make_scan(
            t,
            ranges,
            -2.0 + rng.random() * 0.1,
            0.0061359 + rng.random() * 1e-6,
            0.05,
            29.5,
            mount=[0.145 + rng.random() * 0.01, -0.02, rng.uniform(-0.1, 0.1)],
            intensities=rng.uniform(0, 1000, beams) if i % 2 else None,
        )
        pose = np.array([rng.normal() * 10, rng.normal() * 10, rng.uniform(-np.pi, np.pi)])
        frames.append(Frame(i, scan, pose if odometry else None))
        t += rng.uniform(0.05, 0.2)
    return frames


def _bits(a: np.ndarray) -> np.ndarray:
    return np.asarray(a, dtype=np.float64).view(np.int64)


def _assert_same_scan(read: LaserScan, written: LaserScan) -> None:
    assert read.timestamp == written.timestamp
    assert read.num_beams == written.num_beams
    assert np.array_equal(np.isnan(read.ranges), np.isnan(written.ranges))
    ok = ~np.isnan(written.ranges)
    assert np.array_equal(_bits(read.ranges[ok]), _bits(written.ranges[ok])), "ranges must be bit-exact"
    assert np.max(np.abs(read.angles - written.angles)) <= 1e-12
    assert read.range_min == written.range_min
    assert read.range_max == written.range_max
    assert np.allclose(read.mount[:2], written.mount[:2], rtol=0, atol=1e-9)
    assert abs(se2.wrap_angle(read.mount[2] - written.mount[2])) <= 1e-9
    if written.intensities is None:
        assert read.intensities is None
    else:
        assert np.array_equal(read.intensities, written.intensities, equal_nan=True)


def _write_lines(path: Path, lines: list[str]) -> Path:
    path.write_text("".join(line + "\n" for line in lines), encoding="utf-8")
    return path


def _flaser(ranges, t: float, pose=(0.0, 0.0, 0.0), keyword: str = "FLASER") -> str:
    r = " ".join(str(v) for v in ranges)
    p = " ".join(str(v) for v in pose)
    return f"{keyword} {len(ranges)} {r} {p} {p} {t} host {t}"


def _robotlaser(ranges, t: float, *, n_header: int | None = None, laser=(0.1, 0, 0), robot=(0, 0, 0)) -> str:
    n = len(ranges) if n_header is None else n_header
    r = " ".join(str(v) for v in ranges)
    lp = " ".join(str(v) for v in laser)
    rp = " ".join(str(v) for v in robot)
    return f"ROBOTLASER1 0 -1.5 3.0 0.01 20.0 0.01 0 {n} {r} 0 {lp} {rp} 0 0 0 0 0 {t} host {t}"


def _odom(pose, t: float) -> str:
    return f"ODOM {pose[0]} {pose[1]} {pose[2]} 0 0 0 {t} host {t}"


def _scans(recording) -> list[LaserScan]:
    return [m for m in recording.messages() if isinstance(m, LaserScan)]


# ---------------------------------------------------------------------------- round trips


@pytest.mark.parametrize("name", ["log.log", "log.log.gz"])
def test_frames_round_trip_exactly(tmp_path, name):
    frames = _random_frames(30, 682, seed=1)
    frames[3] = Frame(3, frames[3].scan, None)  # one frame without odometry
    path = write_carmen(tmp_path / name, frames)
    assert path == tmp_path / name
    assert (path.read_bytes()[:2] == b"\x1f\x8b") == name.endswith(".gz")
    assert list(tmp_path.iterdir()) == [path], "no temporary file left behind"
    assert "slam2d" in (gzip.open(path, "rt") if name.endswith(".gz") else open(path)).readline()

    log = CarmenLog(path)
    read = list(log.frames())
    assert len(read) == len(frames)
    for r, w in zip(read, frames):
        _assert_same_scan(r.scan, w.scan)
        expected = np.zeros(3) if w.odometry is None else w.odometry
        assert np.array_equal(r.odometry, expected), "the embedded robot pose is written exactly"

    # the ODOM lines carry the same poses (a frame without odometry has no ODOM line)
    via_odom = list(CarmenLog(path, ReadOptions(odometry="odom")).frames())
    for r, w in zip(via_odom, frames):
        if w.odometry is not None:
            assert np.array_equal(r.odometry, w.odometry)


def test_scan_without_limits_round_trips(tmp_path):
    # range_max infinite: no return is written as 0, which reads back as no return
    scan = make_scan(5.0, [1.0, np.nan, 2.5, 1e-3], 0.3, 0.25, 0.0, np.inf)
    path = write_carmen(tmp_path / "x.log", [Frame(0, scan, np.array([1.0, 2.0, 3.0]))])
    (read,) = _scans(CarmenLog(path))
    _assert_same_scan(read, scan)


def test_messages_round_trip(tmp_path):
    frames = _random_frames(10, 50, seed=2)
    messages: list = []
    for f in frames:
        messages.append(OdometryReading(f.timestamp - 0.01, f.odometry + 0.5, "ODOM"))
        messages.append(OdometryReading(f.timestamp, f.odometry, "ODOM"))
        messages.append(f.scan)
    path = write_carmen(tmp_path / "m.log.gz", messages)
    got = list(CarmenLog(path, ReadOptions(odometry="odom")).messages())
    assert len(got) == len(messages)
    for g, m in zip(got, messages):
        assert type(g) is type(m)
        if isinstance(m, OdometryReading):
            assert g.timestamp == m.timestamp and np.array_equal(g.pose, m.pose) and g.source == "ODOM"
        else:
            _assert_same_scan(g, m)
    # a bare scan takes the pose of the odometry reading with its own timestamp
    embedded = [f.odometry for f in CarmenLog(path).frames()]
    assert all(np.array_equal(a, f.odometry) for a, f in zip(embedded, frames))


finite = st.floats(-1e3, 1e3, allow_nan=False)


@st.composite
def frame_lists(draw):
    n_frames = draw(st.integers(1, 4))
    beams = draw(st.integers(1, 40))
    range_min = draw(st.sampled_from([0.0, 0.02, draw(st.floats(0.0, 1.0))]))
    range_max = draw(st.one_of(st.just(math.inf), st.floats(range_min + 0.01, 200.0)))
    angle_min = draw(st.floats(-math.pi, math.pi))
    increment = draw(st.floats(1e-5, 0.2))
    t = draw(st.floats(0.0, 2e9))
    frames = []
    for i in range(n_frames):
        ranges = draw(
            st.lists(
                st.one_of(st.floats(0.0, 250.0), st.just(math.nan), st.just(math.inf)),
                min_size=beams,
                max_size=beams,
            )
        )
        mount = [draw(st.floats(-2, 2)), draw(st.floats(-2, 2)), draw(st.floats(-math.pi, math.pi))]
        scan = make_scan(t, ranges, angle_min, increment, range_min, range_max, mount=mount)
        odometry = draw(st.one_of(st.none(), st.tuples(finite, finite, st.floats(-10, 10)).map(np.array)))
        frames.append(Frame(i, scan, odometry))
        t += draw(st.floats(0.0, 100.0))
    return frames


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(frame_lists(), st.booleans())
def test_round_trip_property(frames, gz):
    with tempfile.TemporaryDirectory() as folder:
        path = write_carmen(Path(folder) / ("p.log.gz" if gz else "p.log"), frames)
        read = list(CarmenLog(path).frames())
    assert len(read) == len(frames)
    for r, w in zip(read, frames):
        _assert_same_scan(r.scan, w.scan)
        assert np.array_equal(r.odometry, np.zeros(3) if w.odometry is None else w.odometry)


def test_writer_leaves_nothing_on_error(tmp_path):
    frames = _random_frames(3, 10)

    def broken():
        yield frames[0]
        raise RuntimeError("simulated failure mid-write")

    with pytest.raises(RuntimeError):
        write_carmen(tmp_path / "out.log.gz", broken())
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(TypeError):
        write_carmen(tmp_path / "out.log", [frames[0], "not a message"])
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------------------- real logs

REAL_LOGS = {
    # file: (scans, beams, laser keyword)
    "intel/intel.clf.gz": (910, 180, "FLASER"),
    "aces/aces.clf.gz": (440, 180, "FLASER"),
    "fr079/fr079.clf.gz": (4791, 360, "FLASER"),
    "fr101/fr101.clf.gz": (292, 360, "FLASER"),
    "csail/csail.clf.gz": (406, 361, "FLASER"),
    "mines-exp1/mines-exp1.clf.gz": (756, 682, "ROBOTLASER1"),
    "mines-exp2/mines-exp2.clf.gz": (641, 682, "ROBOTLASER1"),
    "robustness/csail-robotlaser1-corrected.log": (686, 361, "ROBOTLASER1"),
}


def test_every_shared_log_is_listed(datasets):
    found = {str(p.relative_to(datasets)) for p in datasets.glob("*/*.clf.gz")}
    assert found <= set(REAL_LOGS), f"add these logs to REAL_LOGS: {found - set(REAL_LOGS)}"


@pytest.mark.datasets
@pytest.mark.parametrize("name", sorted(REAL_LOGS))
def test_real_log_reads(name):
    path = dataset_file(name)
    n_scans, n_beams, keyword = REAL_LOGS[name]
    sizes: list[tuple[int, int]] = []
    log = open_recording(path)
    assert isinstance(log, CarmenLog)
    frames = list(log.frames(lambda done, total: sizes.append((done, total))))
    assert len(frames) == n_scans
    assert {f.scan.num_beams for f in frames} == {n_beams}
    assert all(f.odometry is not None and np.all(np.isfinite(f.odometry)) for f in frames)
    assert log.laser_keyword == keyword
    assert log.odometry_source == f"pose embedded in {keyword} lines"
    streams = {s.name: s for s in log.streams()}
    assert streams[keyword].count == n_scans and streams[keyword].used_as == "scans, odometry"
    # progress counts bytes of the file on disk and ends at its size
    assert sizes[-1] == (path.stat().st_size, path.stat().st_size)
    assert all(a[0] <= b[0] for a, b in zip(sizes, sizes[1:]))
    scan = frames[0].scan
    coverage = math.degrees(scan.angle_increment * scan.num_beams)
    if name.startswith("mines"):
        assert 239.4 <= coverage <= 240.0
        assert np.allclose(scan.mount, [0.145, 0.0, 0.0], atol=1e-5)
        assert scan.range_max == 5.6
    elif keyword == "FLASER":
        # 180 or 360 beams cover 180 deg; 361 (csail) span it end to end, half a degree more
        assert coverage == pytest.approx(180.0 + (math.degrees(scan.angle_increment) if n_beams % 2 else 0.0),
                                         abs=1e-9)
        assert scan.angle_min == pytest.approx(-math.pi / 2, abs=1e-12)
        # aces writes no return as exactly 50.00 m, inferred from the log (see below)
        assert scan.range_max == (50.0 if name.startswith("aces") else DEFAULT_SICK_MAX_RANGE)
        assert np.array_equal(scan.mount, np.zeros(3))
    # no reading at or beyond the maximum, or zero, survives as a return
    for f in frames[::25]:
        r = f.scan.ranges[f.scan.valid]
        assert np.all((r > 0) & (r < f.scan.range_max))
    times = np.array([f.timestamp for f in frames])
    assert np.all(np.diff(times) > -1.0), "timestamps may step back only a little"


@pytest.mark.datasets
def test_mines_zero_range_is_no_return():
    path = dataset_file("mines-exp1/mines-exp1.clf.gz")
    with gzip.open(path, "rt") as f:
        line = next(l for l in f if l.startswith("ROBOTLASER1"))
    tokens = line.split()
    raw = np.array(tokens[9 : 9 + int(tokens[8])], dtype=float)
    zero = raw == 0.0
    assert zero.any()
    (scan, *_rest) = _scans(CarmenLog(path))
    assert np.isnan(scan.ranges[zero]).all()
    assert np.array_equal(scan.ranges[~zero], raw[~zero])


@pytest.mark.datasets
def test_intel_steps_back_in_time_are_kept_with_their_own_pose():
    path = dataset_file("intel/intel.clf.gz")
    log = CarmenLog(path)
    frames = list(log.frames())
    assert log.problems.counts["scan timestamp stepped back (kept)"] == 4
    # each frame carries exactly the pose written on its own FLASER line
    embedded = []
    with gzip.open(path, "rt") as f:
        for line in f:
            if line.startswith("FLASER"):
                tokens = line.split()
                n = int(tokens[1])
                embedded.append([float(v) for v in tokens[n + 5 : n + 8]])
    assert np.array_equal(np.array([f.odometry for f in frames]), np.array(embedded))


@pytest.mark.datasets
def test_odom_lines_as_odometry_drop_out_of_order_readings():
    log = CarmenLog(dataset_file("fr079/fr079.clf.gz"), ReadOptions(odometry="odom"))
    frames = list(log.frames())
    assert log.odometry_source == "ODOM lines"
    assert len(frames) == 4791
    assert log.problems.counts["odometry out of time order (dropped)"] == 18
    assert {s.name: s.used_as for s in log.streams()}["ODOM"] == "odometry"
    # fr079's FLASER poses are the ODOM poses at the same times: both sources agree
    embedded = np.array([f.odometry for f in CarmenLog(log.path).frames()])
    from_odom = np.array([f.odometry for f in frames])
    assert np.allclose(embedded[:, :2], from_odom[:, :2], atol=1e-3)


@pytest.mark.datasets
@pytest.mark.parametrize("name", ["intel", "aces", "fr079", "fr101", "csail"])
def test_reference_trajectory_has_one_pose_per_scan(name):
    log = CarmenLog(dataset_file(f"{name}/{name}.clf.gz"), ReadOptions(odometry="none"))
    scan_times = np.array([s.timestamp for s in _scans(log)])
    times, poses = read_tum(dataset_file(f"{name}/reference.tum"))
    assert len(times) == len(scan_times)
    assert np.array_equal(times, scan_times)
    matched, valid = interpolate_poses(times, poses, scan_times, max_gap=0.0)
    assert valid.all()
    assert np.array_equal(matched, poses)


@pytest.mark.datasets
def test_corrupt_timestamps_are_reported():
    path = dataset_file("robustness/infinite-corridor-corrupt-timestamps.log.gz")
    with pytest.raises(InputError) as err:
        list(CarmenLog(path).messages())
    text = str(err.value)
    assert path.name in text and ":12:" in text and "FLASER timestamp" in text and "negative" in text

    # Skipping bad records leaves nothing: 4 scans are stamped negative, the other
    # 1937 all 4.29497e9 (a wrapped clock); none is sane, and the reader says so.
    log = CarmenLog(path, ReadOptions(skip_bad_records=True))
    with pytest.raises(InputError, match="no laser scans"):
        list(log.frames())
    assert log.problems.counts["dropped record with bad FLASER timestamp"] == 1941
    assert {s.name: s.count for s in log.streams()}["NEFF"] == 1941

    # its ODOM lines are corrupt too
    with pytest.raises(InputError, match=r":2: ODOM timestamp: -0.042 is negative"):
        list(CarmenLog(path, ReadOptions(odometry="odom")).messages())


# ---------------------------------------------------------------------------- PARAM lines, lasers


def test_param_lines_set_flaser_geometry_and_mount(tmp_path):
    params = [
        "PARAM robot_frontlaser_offset 0.2 host 0 0",
        "PARAM robot_frontlaser_side_offset -0.05 host 0 0",
        "PARAM robot_frontlaser_angular_offset 0.1 host 0 0",
        "PARAM laser_front_laser_fov 100 host 0 0",
        "PARAM laser_front_laser_resolution 0.5 host 0 0",
        "PARAM robot_front_laser_max 30.0 host 0 0",
        "PARAM robot_frontlaser_type LMS host 0 0",
    ]
    ranges = [1.0] * 200 + [30.0]
    path = _write_lines(tmp_path / "p.log", [*params, _flaser(ranges, 1.0)])
    log = CarmenLog(path)
    (scan,) = _scans(log)
    assert scan.angle_min == pytest.approx(math.radians(-50))
    assert scan.angle_increment == pytest.approx(math.radians(0.5))
    assert scan.range_max == 30.0 and np.isnan(scan.ranges[-1])
    assert np.allclose(scan.mount, [0.2, -0.05, 0.1])
    assert {s.name: s.used_as for s in log.streams()}["PARAM"] == "laser mount"


@pytest.mark.parametrize(
    ("beams", "step_deg"), [(180, 1.0), (181, 1.0), (360, 0.5), (361, 0.5), (721, 0.25), (100, 1.8)]
)
def test_flaser_default_geometry(tmp_path, beams, step_deg):
    path = _write_lines(tmp_path / "g.log", [_flaser([2.0] * beams, 1.0)])
    (scan,) = _scans(CarmenLog(path))
    assert scan.angle_min == pytest.approx(-math.pi / 2)
    assert scan.angle_increment == pytest.approx(math.radians(step_deg))
    assert np.all(scan.angles <= math.pi / 2 + 1e-12)


def test_sick_error_codes_are_no_return(tmp_path):
    path = _write_lines(tmp_path / "s.log", [_flaser([81.83, 81.91, 81.82, 0, 5.0], 1.0)])
    (scan,) = _scans(CarmenLog(path))
    assert np.isnan(scan.ranges[[0, 1, 3]]).all()
    assert scan.ranges[2] == 81.82 and scan.ranges[4] == 5.0


def test_rear_laser_is_used_only_without_a_front_laser(tmp_path):
    both = _write_lines(
        tmp_path / "both.log",
        [_flaser([1.0] * 5, 1.0, keyword="RLASER"), _flaser([2.0] * 5, 1.0), _flaser([2.0] * 5, 2.0)],
    )
    log = CarmenLog(both)
    scans = _scans(log)
    assert len(scans) == 2 and all(s.ranges[0] == 2.0 for s in scans)
    assert {s.name: s.used_as for s in log.streams()} == {"RLASER": "", "FLASER": "scans, odometry"}

    rear = _write_lines(tmp_path / "rear.log", [_flaser([1.0] * 5, 1.0, keyword="RLASER")])
    log = CarmenLog(rear)
    (scan,) = _scans(log)
    assert log.laser_keyword == "RLASER"
    assert abs(se2.wrap_angle(scan.mount[2] - math.pi)) < 1e-12  # faces backwards


def test_other_messages_and_comments_are_counted(tmp_path):
    path = _write_lines(
        tmp_path / "o.log",
        [
            "# a comment",
            "TRUEPOS 1 2 3 1 2 3 0.5 host 0.5",
            "NEFF 200",
            _odom((0, 0, 0), 0.9),
            _flaser([1.0] * 5, 1.0),
            "",
            "NEFF 199",
        ],
    )
    log = CarmenLog(path)
    messages = list(log.messages())
    assert [type(m).__name__ for m in messages] == ["OdometryReading", "LaserScan"]
    assert messages[0].source == "FLASER" and messages[0].timestamp == 1.0
    counts = {s.name: (s.count, s.used_as) for s in log.streams()}
    assert counts == {"#": (1, ""), "TRUEPOS": (1, ""), "NEFF": (2, ""), "ODOM": (1, ""), "FLASER": (1, "scans, odometry")}
    # reading again does not double the counts
    list(log.messages())
    assert {s.name: s.count for s in log.streams()}["NEFF"] == 2


def test_odometry_none_and_tf(tmp_path):
    path = _write_lines(tmp_path / "n.log", [_odom((1, 2, 3), 0.5), _flaser([1.0] * 5, 1.0)])
    log = CarmenLog(path, ReadOptions(odometry="none"))
    assert log.odometry_source == "none"
    assert [f.odometry for f in log.frames()] == [None]
    with pytest.raises(InputError) as err:
        CarmenLog(path, ReadOptions(odometry="tf"))
    assert "odometry" in str(err.value) and "n.log" in str(err.value)


def test_log_without_odom_lines_reports_it_in_odom_mode(tmp_path):
    path = _write_lines(tmp_path / "x.log", [_flaser([1.0] * 5, 1.0)])
    log = CarmenLog(path, ReadOptions(odometry="odom"))
    assert [f.odometry for f in log.frames()] == [None]
    assert log.problems.counts["no odometry"] == 1


# ---------------------------------------------------------------------------- bad input


def _error(path: Path, options: ReadOptions | None = None) -> str:
    with pytest.raises(InputError) as err:
        list(CarmenLog(path, options).messages())
    return str(err.value)


def test_truncated_line(tmp_path):
    line = _flaser([1.0] * 180, 2.0)
    path = _write_lines(tmp_path / "trunc.log", [_flaser([1.0] * 180, 1.0), line[: len(line) // 2]])
    text = _error(path)
    assert "trunc.log:2:" in text and "FLASER" in text and "191 expected for 180 beams" in text
    assert "truncated line?" in text


def test_non_numeric_field(tmp_path):
    ranges: list = [1.0] * 180
    ranges[16] = "abc"
    path = _write_lines(tmp_path / "nan.log", ["# header", _flaser(ranges, 1.0)])
    text = _error(path)
    assert "nan.log:2:" in text and "FLASER range 17" in text and "'abc' is not a number" in text


def test_non_numeric_pose_and_odom_fields(tmp_path):
    path = _write_lines(tmp_path / "pose.log", [_flaser([1.0] * 5, 1.0, pose=(0, "x1", 0))])
    text = _error(path)
    assert "pose.log:1:" in text and "FLASER y" in text
    path = _write_lines(tmp_path / "odom.log", ["ODOM 0 0 zz 0 0 0 1.0 host 1.0", _flaser([1.0] * 5, 1.0)])
    text = _error(path, ReadOptions(odometry="odom"))
    assert "odom.log:1:" in text and "ODOM theta" in text and "'zz'" in text
    path = _write_lines(tmp_path / "param.log", ["PARAM robot_frontlaser_offset abc", _flaser([1.0] * 5, 1.0)])
    text = _error(path)
    assert "param.log:1:" in text and "PARAM robot_frontlaser_offset" in text


def test_beam_count_not_matching_header(tmp_path):
    path = _write_lines(tmp_path / "count.log", [_flaser([1.0] * 178, 1.0).replace("FLASER 178", "FLASER 180")])
    text = _error(path)
    assert "count.log:1:" in text and "FLASER" in text and "189 fields, 191 expected for 180 beams" in text

    path = _write_lines(tmp_path / "rl.log", [_robotlaser([1.0] * 10, 1.0), _robotlaser([1.0] * 8, 2.0, n_header=10)])
    text = _error(path)
    assert "rl.log:2:" in text and "ROBOTLASER1 num_readings" in text and "header says 10 beams" in text


def test_unused_lines_are_still_checked(tmp_path):
    # ODOM lines are not used with embedded odometry, RLASER not next to FLASER: still checked
    path = _write_lines(tmp_path / "u.log", [_flaser([1.0] * 5, 1.0), "ODOM 0 0 zero 0 0 0 1.0 host 1.0"])
    text = _error(path)
    assert "u.log:2:" in text and "ODOM theta" in text
    path = _write_lines(tmp_path / "r.log", [_flaser([1.0] * 5, 1.0), "RLASER 3 1.0 oops"])
    text = _error(path)
    assert "r.log:2:" in text and "RLASER" in text and "truncated line?" in text


def test_robotlaser_non_numeric_field(tmp_path):
    line = _robotlaser([1.0] * 10, 1.0).replace("0 -1.5 3.0 0.01 20.0", "0 -1.5 3.0 0.01 far")
    text = _error(_write_lines(tmp_path / "rl.log", [line]))
    assert "rl.log:1:" in text and "ROBOTLASER1 maximum_range" in text and "'far'" in text


def test_timestamps_going_backwards(tmp_path):
    lines = [_flaser([1.0] * 5, t) for t in (10.0, 10.5, 10.3, 7.0, 11.0)]
    path = _write_lines(tmp_path / "back.log", lines)
    text = _error(path)
    assert "back.log:4:" in text and "FLASER timestamp" in text and "before the previous scan" in text
    # a small step back (line 3) is kept and counted; with skip mode line 4 is dropped
    log = CarmenLog(path, ReadOptions(skip_bad_records=True))
    assert [s.timestamp for s in _scans(log)] == [10.0, 10.5, 10.3, 11.0]
    assert log.problems.counts["scan timestamp stepped back (kept)"] == 1
    assert log.problems.counts["dropped record with bad FLASER timestamp"] == 1


def test_absurd_timestamp(tmp_path):
    # time that jumps forward (a pause, a reset clock) goes on, with a warning naming the line
    lines = [_flaser([1.0] * 5, t) for t in (10.0, 1e5, 1e5 + 0.5)]
    log = CarmenLog(_write_lines(tmp_path / "jump.log", lines))
    assert [s.timestamp for s in _scans(log)] == [10.0, 1e5, 1e5 + 0.5]
    assert log.problems.examples["time jumped forward (kept: a pause or a reset clock)"][0].startswith("2: 99990 s")
    lines = [_flaser([1.0] * 5, t) for t in (10.0, 4.29497e9)]
    text = _error(_write_lines(tmp_path / "wrapped.log", lines))
    assert "wrapped.log:2:" in text and "FLASER timestamp" in text and "2096" in text


def test_empty_file(tmp_path):
    empty = tmp_path / "empty.log"
    empty.write_bytes(b"")
    with pytest.raises(InputError, match=r"empty\.log: file is empty"):
        CarmenLog(empty)
    empty_gz = tmp_path / "empty.log.gz"
    empty_gz.write_bytes(gzip.compress(b""))
    with pytest.raises(InputError, match=r"empty\.log\.gz: file is empty"):
        CarmenLog(empty_gz)
    with pytest.raises(InputError, match="file is empty"):
        open_recording(empty)


def test_log_without_scans(tmp_path):
    path = _write_lines(tmp_path / "noscan.log", ["# only odometry", _odom((0, 0, 0), 1.0), "NEFF 2"])
    text = _error(path)
    assert "noscan.log" in text and "no laser scans found" in text and "ODOM x1" in text


def test_directory_is_refused(tmp_path):
    folder = tmp_path / "some.log"
    folder.mkdir()
    with pytest.raises(InputError) as err:
        open_recording(folder)
    assert "some.log" in str(err.value) and "folder" in str(err.value)
    with pytest.raises(InputError, match="folder"):
        CarmenLog(folder)
    with pytest.raises(InputError, match="no such file"):
        CarmenLog(tmp_path / "missing.log")


def test_truncated_gzip(tmp_path):
    frames = _random_frames(400, 360, seed=3)
    whole = write_carmen(tmp_path / "whole.log.gz", frames)
    data = whole.read_bytes()
    cut = tmp_path / "cut.log.gz"
    cut.write_bytes(data[: len(data) * 2 // 3])
    text = _error(cut)
    assert "cut.log.gz" in text and "gzip" in text and "truncated or corrupt gzip stream after line" in text

    log = CarmenLog(cut, ReadOptions(skip_bad_records=True))
    read = list(log.frames())
    assert 0 < len(read) < len(frames)
    for r, w in zip(read, frames):  # what was read is intact
        _assert_same_scan(r.scan, w.scan)
    assert sum(n for kind, n in log.problems.counts.items() if "gzip" in kind) == 1

    garbage = tmp_path / "garbage.log.gz"
    garbage.write_bytes(b"\x1f\x8b" + b"\x00" * 50)
    with pytest.raises(InputError, match=r"garbage\.log\.gz: gzip: "):
        list(CarmenLog(garbage).messages())


def test_undecodable_bytes(tmp_path):
    path = tmp_path / "bin.log"
    path.write_bytes((_flaser([1.0] * 5, 1.0) + "\n").encode() + b"FLASER \xff\xfe 1\n")
    text = _error(path)
    assert "bin.log:2:" in text and "not UTF-8" in text


def test_skip_mode_counts_skipped_lines(tmp_path):
    bad_range: list = [1.0] * 5
    bad_range[2] = "oops"
    lines = [
        _flaser([1.0] * 5, 1.0),
        _flaser(bad_range, 2.0),  # line 2
        _flaser([1.0] * 5, 3.0)[:20],  # line 3: truncated
        _flaser([1.0] * 5, 4.0),
        "FLASER \udcff",  # replaced below by undecodable bytes, line 5
        _flaser([1.0] * 5, 5.0),
    ]
    path = tmp_path / "skip.log"
    path.write_bytes(
        "".join(l + "\n" for l in lines).encode("utf-8", "surrogateescape")
    )
    log = CarmenLog(path, ReadOptions(skip_bad_records=True))
    frames = list(log.frames())
    assert [f.timestamp for f in frames] == [1.0, 4.0, 5.0]
    assert log.problems.counts["skipped bad FLASER line"] == 2
    assert log.problems.counts["skipped bad undecodable line"] == 1
    examples = " ".join(log.problems.examples["skipped bad FLASER line"])
    assert "line 2: FLASER range 3" in examples and "line 3: FLASER" in examples
    assert log.problems.total() == 3


# ---------------------------------------------------------------------------- --range-min


def test_range_min_option_turns_error_codes_into_no_return(tmp_path):
    # A Hokuyo URG reports failed readings as a few millimetres; CARMEN logs state no minimum range.
    ranges = [0.001, 1.0, 0.015, 2.0, 0.02]
    path = _write_lines(tmp_path / "urg.log", [_robotlaser(ranges, 1.0), _flaser(ranges, 2.0)])
    as_recorded = _scans(open_recording(path))
    assert all(np.count_nonzero(np.isnan(s.ranges)) == 0 for s in as_recorded)
    cleaned = _scans(open_recording(path, ReadOptions(range_min=0.02)))
    for scan in cleaned:
        assert scan.range_min == 0.02
        np.testing.assert_array_equal(np.isnan(scan.ranges), [True, False, True, False, False])


def test_range_max_option_turns_a_fixed_no_return_range_into_no_return(tmp_path):
    ranges = [50.0, 10.0, 49.95, 50.0]  # a laser that reports no return as 50 m
    path = _write_lines(tmp_path / "sick.log", [_flaser(ranges, 1.0)])
    (stated,) = _scans(open_recording(path))
    assert not np.isnan(stated.ranges).any()
    (cleaned,) = _scans(open_recording(path, ReadOptions(range_max=49.9)))
    assert cleaned.range_max == 49.9
    np.testing.assert_array_equal(np.isnan(cleaned.ranges), [True, False, True, True])


def test_range_min_beyond_the_maximum_names_the_line_and_field(tmp_path):
    path = _write_lines(tmp_path / "urg.log", [_robotlaser([1.0, 2.0], 1.0)])
    with pytest.raises(InputError) as err:
        _scans(open_recording(path, ReadOptions(range_min=25.0)))
    text = str(err.value)
    assert "urg.log:1" in text and "range_max" in text and "range_min" in text


# ---------------------------------------------------------------------------- inferred no-return code


def _saturating_log(path: Path, *, code_per_scan: int, scans: int = 30, seed: int = 0, params=()) -> Path:
    """FLASER lines of continuous readings up to ~49.9 m, ``code_per_scan`` of them written as 50.0."""
    rng = np.random.default_rng(seed)
    lines = list(params)
    for i in range(scans):
        ranges = np.round(rng.uniform(0.5, 49.9, 40), 2)
        ranges[:code_per_scan] = 50.0
        lines.append(_flaser(ranges.tolist(), 1.0 + i))
    text = "".join(line + "\n" for line in lines).encode()
    if path.name.endswith(".gz"):
        path.write_bytes(gzip.compress(text))
    else:
        path.write_bytes(text)
    return path


@pytest.mark.parametrize("name", ["sat.log", "sat.log.gz"])
def test_repeated_largest_value_is_inferred_as_no_return(tmp_path, name):
    path = _saturating_log(tmp_path / name, code_per_scan=2)
    log = open_recording(path)
    scans = _scans(log)
    assert all(s.range_max == 50.0 for s in scans)
    assert all(np.isnan(s.ranges[:2]).all() and not np.isnan(s.ranges[2:]).any() for s in scans)
    (note,) = log.notes()
    assert "no-return code inferred: 50 m (60 of 1200 readings" in note
    assert log.no_return_codes["FLASER"].count == 60
    summary = summarize(open_recording(path))
    assert summary.notes == [note] and summary.range_max == 50.0


def test_largest_value_occurring_once_is_kept(tmp_path):
    path = _saturating_log(tmp_path / "once.log", code_per_scan=0)
    lines = path.read_text().splitlines()
    tokens = lines[5].split()
    tokens[2] = "50.0"  # the log's largest reading, once
    lines[5] = " ".join(tokens)
    _write_lines(path, lines)
    log = open_recording(path)
    scans = _scans(log)
    assert log.notes() == [] and log.no_return_codes == {}
    assert all(s.range_max == DEFAULT_SICK_MAX_RANGE for s in scans)
    assert scans[5].ranges[0] == 50.0
    assert not any(np.isnan(s.ranges).any() for s in scans)


def test_rule_needs_count_dominance_and_readings_below():
    rng = np.random.default_rng(1)
    real = {float(v): 1 for v in np.round(rng.uniform(1.0, 49.9, 500), 2)}
    assert infer_no_return_code({**real, 50.0: 620}).value == 50.0
    assert infer_no_return_code({**real, 50.0: 19}) is None  # too rare to be a code
    # a value repeating as often as its neighbours is a wall, not a code
    assert infer_no_return_code({**real, 49.0: 30, 49.5: 10, 50.0: 60}) is None
    assert infer_no_return_code({**real, 44.0: 30, 49.5: 6, 50.0: 60}).value == 50.0  # 44 m: outside the band
    # every reading the same value, or nothing read near it: nothing to compare with
    assert infer_no_return_code({2.0: 500}) is None
    assert infer_no_return_code({1.0: 5, 2.0: 500}) is None
    # readings at or beyond the SICK codes are no return anyway and never candidates
    assert infer_no_return_code({**real, 81.83: 4000}) is None
    assert infer_no_return_code({**real, 0.0: 4000}) is None


def test_stated_maximum_wins_over_inference(tmp_path):
    stated = ["PARAM robot_front_laser_max 60.0 host 0 0"]
    path = _saturating_log(tmp_path / "stated.log", code_per_scan=2, params=stated)
    log = open_recording(path)
    scans = _scans(log)
    assert log.notes() == []
    assert all(s.range_max == 60.0 and not np.isnan(s.ranges).any() for s in scans)
    # a PARAM half-way: lines before it have no stated maximum and get the code, lines after it not
    lines = _saturating_log(tmp_path / "half.log", code_per_scan=2, scans=40).read_text().splitlines()
    lines.insert(20, stated[0])
    path = _write_lines(tmp_path / "half.log", lines)
    scans = _scans(open_recording(path))
    assert [s.range_max for s in scans] == [50.0] * 20 + [60.0] * 20
    assert np.isnan(scans[0].ranges[0]) and scans[-1].ranges[0] == 50.0


def test_range_max_option_wins_over_inference(tmp_path):
    path = _saturating_log(tmp_path / "sat.log", code_per_scan=2)
    log = open_recording(path, ReadOptions(range_max=60.0))
    scans = _scans(log)
    assert log.notes() == [] and log.no_return_codes == {}
    assert all(s.range_max == 60.0 and not np.isnan(s.ranges).any() for s in scans)
    (lower,) = {s.range_max for s in _scans(open_recording(path, ReadOptions(range_max=40.0)))}
    assert lower == 40.0


def test_written_logs_state_their_maximum_and_infer_nothing(tmp_path):
    # write_carmen (and so `slam2d simulate`) writes no return as the stated maximum, many times
    frames = _random_frames(40, 60)
    path = write_carmen(tmp_path / "sim.log.gz", frames)
    log = open_recording(path)
    read = list(log.frames())
    assert log.notes() == []
    for r, w in zip(read, frames):
        _assert_same_scan(r.scan, w.scan)


@pytest.mark.datasets
@pytest.mark.parametrize("name", sorted(REAL_LOGS) + ["robustness/infinite-corridor-corrupt-timestamps.log.gz"])
def test_real_logs_no_return_code(name):
    log = CarmenLog(dataset_file(name))
    codes = log._infer_no_return_codes()
    if name.startswith("aces"):
        assert set(codes) == {"FLASER"}
        code = codes["FLASER"]
        assert (code.value, code.count, code.readings) == (50.0, 620, 79200)
        assert code.band_count <= 4
    else:
        assert codes == {}, "intel, fr079, fr101 (SICK codes 81.83/81.91), mines and CSAIL must infer nothing"


def test_info_prints_what_was_inferred(tmp_path, capsys):
    from slam2d.cli import main

    path = _saturating_log(tmp_path / "sat.log.gz", code_per_scan=3)
    assert main(["info", str(path)]) == 0
    out = capsys.readouterr().out
    assert "inferred by the reader" in out and "no-return code inferred: 50 m" in out
    assert main(["info", str(path), "--range-max", "60"]) == 0
    assert "inferred by the reader" not in capsys.readouterr().out


def test_non_finite_pose_field_is_shown_as_a_plain_number(tmp_path):
    path = _write_lines(tmp_path / "inf.log", [_flaser([1.0] * 5, 1.0), _flaser([1.0] * 5, 2.0, pose=(0, 0, "inf"))])
    text = _error(path)
    assert "inf.log:2: FLASER odom_theta: inf is not a finite number" in text and "np.float64" not in text


def test_a_binary_file_is_described_without_control_characters(tmp_path):
    path = tmp_path / "image.log"
    path.write_bytes(b"\x00\x01\x02binary\n")
    text = _error(path)
    assert "no laser scans found" in text and r"'\x00\x01\x02binary' x1" in text
    assert text.isprintable()  # nothing that would garble the terminal


@pytest.mark.parametrize("gz", [False, True])
def test_a_byte_order_mark_does_not_hide_the_first_line(tmp_path, gz):
    text = "\ufeff" + _flaser([1.0] * 5, 1.0) + "\n" + _flaser([1.0] * 5, 2.0) + "\n"
    path = tmp_path / ("bom.log.gz" if gz else "bom.log")
    path.write_bytes(gzip.compress(text.encode()) if gz else text.encode())
    log = CarmenLog(path)
    scans = [m for m in log.messages() if isinstance(m, LaserScan)]
    assert len(scans) == 2 and [s.name for s in log.streams()] == ["FLASER"]


def test_a_tum_file_given_as_a_log_is_said_in_one_short_line(tmp_path):
    """A TUM trajectory read as a CARMEN log listed all its 910 timestamps (a 14 KB error line)."""
    lines = "".join(f"{10.0 + 0.5 * k:.6f} {0.1 * k} 0 0 0 0 0 1\n" for k in range(900))
    text = _error(_write_lines(tmp_path / "poses.tum", lines.splitlines()))
    assert len(text) < 400 and "and 895 other first words" in text and "a TUM trajectory" in text
