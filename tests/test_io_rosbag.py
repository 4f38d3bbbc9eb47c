"""ROS 1 and ROS 2 bags: round trips, tf handling, the damaged demo bag, and bad input."""

from __future__ import annotations

import math
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Writer as Ros2Writer
from rosbags.typesys import Stores, get_typestore
from scipy.spatial.transform import Rotation

from slam2d.core import se2
from slam2d.core.frames import Frame, OdometryReading
from slam2d.core.scan import LaserScan, make_scan
from slam2d.errors import InputError
from slam2d.io import open_recording
from slam2d.io.base import ReadOptions
from slam2d.io.rosbag import RosBag, write_rosbag

from tests.conftest import dataset_file

FORMATS = [("ros2", "sqlite3"), ("ros2", "mcap"), ("ros1", "sqlite3")]
FORMAT_IDS = ["ros2-sqlite3", "ros2-mcap", "ros1"]
TS2 = get_typestore(Stores.ROS2_HUMBLE)


# -- helpers -------------------------------------------------------------------------------


def bag_path(folder: Path, version: str, storage: str, name: str = "bag") -> Path:
    return folder / (f"{name}.bag" if version == "ros1" else f"{name}_{storage}")


def stamp_ns(t: float) -> int:
    """The nanosecond stamp nearest to ``t`` (what a ROS header can hold)."""
    sec = math.floor(t)
    return sec * 1_000_000_000 + round((t - sec) * 1e9)


def seconds(ns: int) -> float:
    return ns // 1_000_000_000 + (ns % 1_000_000_000) * 1e-9


def split(messages):
    scans = [m for m in messages if isinstance(m, LaserScan)]
    odometry = [m for m in messages if isinstance(m, OdometryReading)]
    return scans, odometry


def assert_scan_round_trip(got: LaserScan, sent: LaserScan) -> None:
    """``got`` is ``sent`` after a trip through float32 message fields."""
    assert stamp_ns(got.timestamp) == stamp_ns(sent.timestamp)
    assert got.num_beams == sent.num_beams
    # No-return stays no-return and every return is the float32 of what was sent.
    np.testing.assert_array_equal(np.isnan(got.ranges), np.isnan(sent.ranges))
    ok = ~np.isnan(sent.ranges)
    np.testing.assert_array_equal(got.ranges[ok], sent.ranges[ok].astype(np.float32).astype(np.float64))
    assert got.angle_min == float(np.float32(sent.angle_min))
    assert got.angle_increment == float(np.float32(sent.angle_increment))
    np.testing.assert_allclose(got.angles, sent.angles, rtol=0, atol=1e-5)
    assert got.range_min == float(np.float32(sent.range_min))
    assert got.range_max == float(np.float32(sent.range_max))
    np.testing.assert_allclose(got.mount, sent.mount, rtol=0, atol=1e-9)
    if sent.intensities is None:
        assert got.intensities is None
    else:
        np.testing.assert_array_equal(got.intensities, sent.intensities.astype(np.float32).astype(np.float64))


def raw_ros2_bag(path: Path, connections: dict[str, str], messages: list[tuple[str, int, object]]) -> Path:
    """A ROS 2 sqlite3 bag written with plain rosbags: ``messages`` are (topic, time ns, message)."""
    with Ros2Writer(path, version=8) as writer:
        conns = {t: writer.add_connection(t, msgtype, typestore=TS2) for t, msgtype in connections.items()}
        for topic, time_ns, msg in messages:
            data = msg if isinstance(msg, bytes) else TS2.serialize_cdr(msg, connections[topic])
            writer.write(conns[topic], time_ns, data)
    return path


def ros2_header(time_ns: int, frame_id: str):
    Time = TS2.types["builtin_interfaces/msg/Time"]
    return TS2.types["std_msgs/msg/Header"](
        stamp=Time(sec=time_ns // 1_000_000_000, nanosec=time_ns % 1_000_000_000), frame_id=frame_id
    )


def ros2_scan(time_ns: int, ranges, angle_min=-1.0, increment=0.01, frame_id="laser", range_max=20.0):
    return TS2.types["sensor_msgs/msg/LaserScan"](
        header=ros2_header(time_ns, frame_id),
        angle_min=angle_min,
        angle_max=angle_min + increment * (len(ranges) - 1),
        angle_increment=increment,
        time_increment=0.0,
        scan_time=0.0,
        range_min=0.05,
        range_max=range_max,
        ranges=np.asarray(ranges, dtype=np.float32),
        intensities=np.zeros(0, dtype=np.float32),
    )


def ros2_transform(time_ns: int, parent: str, child: str, xyz, quat_xyzw):
    t = TS2.types
    return t["geometry_msgs/msg/TransformStamped"](
        header=ros2_header(time_ns, parent),
        child_frame_id=child,
        transform=t["geometry_msgs/msg/Transform"](
            translation=t["geometry_msgs/msg/Vector3"](x=xyz[0], y=xyz[1], z=xyz[2]),
            rotation=t["geometry_msgs/msg/Quaternion"](
                x=quat_xyzw[0], y=quat_xyzw[1], z=quat_xyzw[2], w=quat_xyzw[3]
            ),
        ),
    )


def tf_message(*transforms):
    return TS2.types["tf2_msgs/msg/TFMessage"](transforms=list(transforms))


def yaw_quat(yaw: float):
    return Rotation.from_euler("z", yaw).as_quat()  # x, y, z, w


def sample_messages(n_scans: int, beams: int, *, t0: float = 1_700_000_000.0, seed: int = 0):
    """Scans at 10 Hz with odometry between them, the way a recording interleaves them."""
    rng = np.random.default_rng(seed)
    mount = np.array([0.25, -0.05, 0.1])
    out: list[LaserScan | OdometryReading] = []
    for i in range(n_scans):
        t = t0 + 0.1 * i
        ranges = rng.uniform(0.2, 29.0, beams)
        ranges[rng.random(beams) < 0.1] = np.nan
        out.append(OdometryReading(t - 0.03, np.array([0.05 * i, 0.01 * i, se2.wrap_angle(0.2 * i)]), "test"))
        out.append(
            make_scan(
                t,
                ranges,
                -2.0,
                4.0 / max(beams - 1, 1),
                0.1,
                30.0,
                mount=mount,
                intensities=rng.uniform(0, 1000, beams),
            )
        )
    return out


# -- round trips -----------------------------------------------------------------------------


@st.composite
def scans_and_odometry(draw):
    """A short, time-ordered recording with awkward but legal values."""
    epoch = draw(st.booleans())
    base_ns = draw(st.integers(1_500_000_000, 1_800_000_000) if epoch else st.integers(0, 100_000))
    base_ns = base_ns * 1_000_000_000 + draw(st.integers(0, 999_999_999))
    # At least 1 us apart: closer epoch stamps are the same float64 time.
    steps = draw(st.lists(st.integers(1_000, 2_000_000_000), min_size=1, max_size=6))
    times = np.cumsum([base_ns, *steps]).tolist()
    beams = draw(st.integers(1, 40))
    range_min = draw(st.floats(0.0, 1.0))
    range_max = draw(st.one_of(st.just(math.inf), st.floats(range_min + 1.0, 200.0)))
    mount = [draw(st.floats(-2, 2)), draw(st.floats(-2, 2)), draw(st.floats(-3.14, 3.14))]
    with_intensities = draw(st.booleans())
    hi = min(range_max, 300.0)
    messages: list[LaserScan | OdometryReading] = []
    for k, t_ns in enumerate(times):
        t = seconds(t_ns)
        if draw(st.booleans()) or k == 0:
            # Ranges kept a little inside the limits so float32 rounding cannot move them across.
            values = draw(
                st.lists(
                    st.one_of(st.floats(range_min * 1.001 + 1e-3, hi * 0.999), st.just(math.nan)),
                    min_size=beams,
                    max_size=beams,
                )
            )
            inten = (
                draw(st.lists(st.floats(0, 1e4), min_size=beams, max_size=beams))
                if with_intensities
                else None
            )
            messages.append(
                make_scan(
                    t,
                    values,
                    draw(st.floats(-math.pi, math.pi)),
                    draw(st.floats(1e-3, 0.1)),
                    range_min,
                    range_max,
                    mount=mount,
                    intensities=inten,
                )
            )
        else:
            pose = [draw(st.floats(-1e3, 1e3)), draw(st.floats(-1e3, 1e3)), draw(st.floats(-3.1, 3.1))]
            messages.append(OdometryReading(t, np.array(pose)))
    return messages


@pytest.mark.parametrize(("version", "storage"), FORMATS, ids=FORMAT_IDS)
@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(messages=scans_and_odometry())
def test_round_trip_property(version, storage, messages):
    with tempfile.TemporaryDirectory() as folder:
        path = write_rosbag(
            bag_path(Path(folder), version, storage), messages, version=version, storage=storage
        )
        bag = RosBag(path)
        got_scans, got_odom = split(list(bag.messages()))
        sent_scans, sent_odom = split(messages)
        assert len(got_scans) == len(sent_scans)
        for got, sent in zip(got_scans, sent_scans):
            assert_scan_round_trip(got, sent)
            # The stamp is written to the nanosecond and read back to the nearest float.
            assert got.timestamp == seconds(stamp_ns(sent.timestamp))
        assert len(got_odom) == len(sent_odom)
        for got, sent in zip(got_odom, sent_odom):
            assert got.timestamp == seconds(stamp_ns(sent.timestamp))
            np.testing.assert_allclose(got.pose[:2], sent.pose[:2], rtol=0, atol=1e-9)
            assert abs(se2.wrap_angle(got.pose[2] - sent.pose[2])) < 1e-9
            assert got.source == "/odom"
        assert not bag.problems, bag.problems.lines()


@pytest.mark.parametrize(("version", "storage"), FORMATS, ids=FORMAT_IDS)
def test_round_trip_ten_thousand_beams_and_ros_tools_read_it(tmp_path, version, storage):
    messages = sample_messages(5, 10_000)
    path = write_rosbag(bag_path(tmp_path, version, storage), messages, version=version, storage=storage)
    bag = RosBag(path)
    assert bag.format.startswith("ROS 1 bag v2.0" if version == "ros1" else f"ROS 2 bag ({storage})")
    assert bag.odometry_source == "/odom (nav_msgs/Odometry)"
    got_scans, got_odom = split(list(bag.messages()))
    sent_scans, sent_odom = split(messages)
    assert [s.num_beams for s in got_scans] == [10_000] * 5
    for got, sent in zip(got_scans, sent_scans, strict=True):
        assert_scan_round_trip(got, sent)
        assert got.timestamp == sent.timestamp  # epoch times survive the nanosecond split exactly
        assert got.frame_id == "laser"
    for got, sent in zip(got_odom, sent_odom, strict=True):
        assert got.timestamp == sent.timestamp
        np.testing.assert_allclose(got.pose, sent.pose, rtol=0, atol=1e-9)
    # frames() pairs each scan with the odometry interpolated at its time
    frames = list(RosBag(path).frames())
    assert len(frames) == 5 and all(f.odometry is not None for f in frames[:-1])

    streams = {s.name: (s.type, s.count, s.used_as) for s in bag.streams()}
    spell = (lambda t: t.replace("/msg/", "/")) if version == "ros1" else str  # each ROS's own spelling
    assert streams == {
        "/scan": (spell("sensor_msgs/msg/LaserScan"), 5, "scans"),
        "/odom": (spell("nav_msgs/msg/Odometry"), 5, "odometry"),
        "/tf": (spell("tf2_msgs/msg/TFMessage"), 5, ""),
        "/tf_static": (spell("tf2_msgs/msg/TFMessage"), 1, "laser mount"),
    }

    # A plain rosbags reader (what ROS tooling uses) sees the same topics, types and counts.
    with AnyReader([path], default_typestore=TS2) as reader:
        counts = {c.topic: (spell(c.msgtype), c.msgcount) for c in reader.connections}
        assert counts == {k: v[:2] for k, v in streams.items()}
        for conn, time_ns, raw in reader.messages([c for c in reader.connections if c.topic == "/scan"]):
            msg = reader.deserialize(raw, conn.msgtype)
            assert time_ns == msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            assert msg.ranges.dtype == np.float32 and len(msg.ranges) == 10_000
        first = next(reader.messages([c for c in reader.connections if c.topic == "/scan"]))
        msg = reader.deserialize(first[2], first[0].msgtype)
        # REP 117: no return is written as +inf
        assert np.isposinf(msg.ranges[np.isnan(sent_scans[0].ranges)]).all()
        assert msg.header.frame_id == "laser"
        static = next(reader.messages([c for c in reader.connections if c.topic == "/tf_static"]))
        tf = reader.deserialize(static[2], static[0].msgtype).transforms[0]
        assert (tf.header.frame_id, tf.child_frame_id) == ("base_link", "laser")
        assert static[1] <= min(stamp_ns(m.timestamp) for m in messages)


def test_ros2_static_tf_is_latched(tmp_path):
    import yaml
    from rosbags.interfaces import QosDurability
    from rosbags.rosbag2 import Reader

    path = write_rosbag(tmp_path / "latched", sample_messages(2, 10), version="ros2")
    with Reader(path) as reader:
        qos = {c.topic: c.ext.offered_qos_profiles for c in reader.connections}
    assert [q.durability for q in qos["/tf_static"]] == [QosDurability.TRANSIENT_LOCAL]
    assert qos["/scan"] == []
    meta = yaml.safe_load((path / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    # the storage file carries the bag's own name, not the temporary one it was written under
    assert sorted(p.name for p in path.iterdir()) == ["latched.db3", "metadata.yaml"]
    assert meta["relative_file_paths"] == ["latched.db3"]


def test_frames_round_trip_and_tf_odometry(tmp_path):
    sent = list(RosBag(write_rosbag(tmp_path / "a", sample_messages(6, 50))).frames())
    path = write_rosbag(tmp_path / "b.bag", sent, version="ros1")
    bag = RosBag(path, ReadOptions(odometry="tf"))
    assert bag.odometry_source == "/tf odom -> base_link"
    got = list(bag.frames())
    assert len(got) == len(sent)
    for g, s in zip(got, sent):
        assert g.timestamp == s.timestamp
        assert_scan_round_trip(g.scan, s.scan)
        if s.odometry is not None:
            np.testing.assert_allclose(g.odometry, s.odometry, rtol=0, atol=1e-9)
    assert {m.source for m in bag.messages() if isinstance(m, OdometryReading)} == {"/tf odom->base_link"}


def test_lone_storage_files_are_read(tmp_path):
    messages = sample_messages(3, 20)
    for storage in ("sqlite3", "mcap"):
        folder = write_rosbag(tmp_path / storage, messages, storage=storage)
        (storage_file,) = [p for p in folder.iterdir() if p.suffix in (".db3", ".mcap")]
        bag = open_recording(storage_file)
        assert bag.format == f"ROS 2 bag ({storage})"
        got_scans, _ = split(list(bag.messages()))
        for got, s in zip(got_scans, split(messages)[0], strict=True):
            assert_scan_round_trip(got, s)


def test_progress_is_reported_in_messages(tmp_path):
    path = write_rosbag(tmp_path / "p", sample_messages(300, 5))
    calls: list[tuple[int, int]] = []
    n = sum(1 for _ in RosBag(path).messages(lambda done, total: calls.append((done, total))))
    assert n == 600
    assert calls[-1] == (600, 600)
    assert len(calls) >= 3 and all(a <= b for (a, _), (b, _) in zip(calls, calls[1:]))


# -- the writer -----------------------------------------------------------------------------


def test_writer_is_atomic(tmp_path):
    def broken():
        yield from sample_messages(3, 10)
        raise RuntimeError("source failed")

    for version in ("ros1", "ros2"):
        target = bag_path(tmp_path, version, "sqlite3")
        with pytest.raises(RuntimeError):
            write_rosbag(target, broken(), version=version)
        assert not target.exists()
    assert list(tmp_path.iterdir()) == []


def test_writer_rejects_mixed_mounts_and_bad_times(tmp_path):
    a = make_scan(1.0, [1.0], 0.0, 0.1, mount=[0.1, 0, 0])
    b = make_scan(2.0, [1.0], 0.0, 0.1, mount=[0.2, 0, 0])
    with pytest.raises(InputError, match="mount") as err:
        write_rosbag(tmp_path / "m", [a, b])
    assert str(tmp_path / "m") in str(err.value) and "item 1" in str(err.value)
    with pytest.raises(InputError, match="timestamp"):
        write_rosbag(tmp_path / "t", [make_scan(-1.0, [1.0], 0.0, 0.1)])
    with pytest.raises(InputError, match="version"):
        write_rosbag(tmp_path / "v", [a], version="ros3")
    assert list(tmp_path.iterdir()) == []


# -- tf -----------------------------------------------------------------------------------


def odometry_path(n: int):
    return [np.array([0.1 * i, 0.02 * i * i, se2.wrap_angle(0.3 * i)]) for i in range(n)]


@pytest.fixture()
def tf_only_bag(tmp_path):
    """/scan, /tf odom->base_footprint, /tf_static base_footprint->base_link->laser (3D, yawed)."""
    t0 = 1_650_000_000_000_000_000
    step = 100_000_000
    static = tf_message(
        ros2_transform(t0, "base_footprint", "base_link", (0.05, 0.0, 0.1), yaw_quat(0.3)),
        ros2_transform(t0, "base_link", "laser", (0.2, -0.1, 0.3), yaw_quat(0.5)),
    )
    messages: list[tuple[str, int, object]] = [("/tf_static", t0, static)]
    for i, pose in enumerate(odometry_path(20)):
        t = t0 + i * step
        messages.append(
            (
                "/tf",
                t,
                tf_message(
                    ros2_transform(t, "odom", "base_footprint", (pose[0], pose[1], 0.0), yaw_quat(pose[2]))
                ),
            )
        )
        messages.append(("/scan", t + step // 2, ros2_scan(t + step // 2, [1.0, 2.0, 3.0])))
    return raw_ros2_bag(
        tmp_path / "tf_only",
        {
            "/tf_static": "tf2_msgs/msg/TFMessage",
            "/tf": "tf2_msgs/msg/TFMessage",
            "/scan": "sensor_msgs/msg/LaserScan",
        },
        messages,
    )


def test_tf_only_odometry_and_mount(tf_only_bag):
    bag = RosBag(tf_only_bag)  # odometry "auto": no /odom topic, so /tf
    assert bag.odometry_source == "/tf odom -> base_footprint"
    scans, odom = split(list(bag.messages()))
    assert len(scans) == 20 and len(odom) == 20
    expected_mount = se2.compose([0.05, 0.0, 0.3], [0.2, -0.1, 0.5])
    for s in scans:
        np.testing.assert_allclose(s.mount, expected_mount, atol=1e-12)
    for got, pose in zip(odom, odometry_path(20), strict=True):
        np.testing.assert_allclose(got.pose, pose, atol=1e-12)
        assert got.source == "/tf odom->base_footprint"
    assert {s.name: s.used_as for s in bag.streams()} == {
        "/scan": "scans",
        "/tf": "odometry",
        "/tf_static": "laser mount",
    }
    assert not bag.problems, bag.problems.lines()


def test_tf_odometry_of_a_deeper_base_frame(tf_only_bag):
    bag = RosBag(tf_only_bag, ReadOptions(odometry="tf", base_frame="base_link"))
    assert bag.odometry_source == "/tf odom -> base_footprint -> base_link"
    scans, odom = split(list(bag.messages()))
    np.testing.assert_allclose(scans[0].mount, [0.2, -0.1, 0.5], atol=1e-12)
    for got, pose in zip(odom, odometry_path(20), strict=True):
        np.testing.assert_allclose(got.pose, se2.compose(pose, [0.05, 0.0, 0.3]), atol=1e-12)


def test_tf_options_that_cannot_be_met(tf_only_bag):
    with pytest.raises(InputError) as err:
        RosBag(tf_only_bag, ReadOptions(odometry="odom"))
    assert str(tf_only_bag) in str(err.value) and "odom_topic" in str(err.value)
    with pytest.raises(InputError, match="odom_frame") as err:
        RosBag(tf_only_bag, ReadOptions(odometry="tf", odom_frame="world")).odometry_source
    assert "odom -> base_footprint" in str(err.value)  # it lists what /tf does hold
    with pytest.raises(InputError, match="base_frame"):
        list(RosBag(tf_only_bag, ReadOptions(odometry="tf", base_frame="camera")).messages())
    with pytest.raises(InputError, match="embedded"):
        RosBag(tf_only_bag, ReadOptions(odometry="embedded"))
    none = RosBag(tf_only_bag, ReadOptions(odometry="none"))
    assert none.odometry_source == "none"
    scans, odom = split(list(none.messages()))
    assert odom == [] and len(scans) == 20


@pytest.mark.parametrize("yaw", [0.0, 0.7, -2.0])
def test_upside_down_laser_is_mirrored(tmp_path, yaw):
    # The laser is rolled by pi (z axis down) and yawed; a point measured in the
    # laser frame must land where the full 3D transform puts it in the base frame.
    rotation = Rotation.from_euler("z", yaw) * Rotation.from_euler("x", math.pi)
    offset = np.array([0.3, 0.1, 0.4])
    t = 1_000_000_000
    ranges = [np.inf, 2.0, np.inf, np.inf, 3.0]
    angle_min, inc = -0.4, 0.2
    path = raw_ros2_bag(
        tmp_path / "upside",
        {"/tf_static": "tf2_msgs/msg/TFMessage", "/scan": "sensor_msgs/msg/LaserScan"},
        [
            (
                "/tf_static",
                t,
                tf_message(ros2_transform(t, "base_link", "laser", offset, rotation.as_quat())),
            ),
            ("/scan", t, ros2_scan(t, ranges, angle_min=angle_min, increment=inc)),
        ],
    )
    (scan,) = list(RosBag(path).messages())
    angles = angle_min + inc * np.array([1, 4])
    in_laser = np.stack([[2.0, 3.0] * np.cos(angles), [2.0, 3.0] * np.sin(angles), np.zeros(2)], axis=-1)
    expected = rotation.apply(in_laser.astype(np.float32).astype(np.float64))[:, :2] + offset[:2]
    got = scan.points_in_base()
    got = got[np.lexsort(got.T[::-1])]
    expected = expected[np.lexsort(expected.T[::-1])]
    np.testing.assert_allclose(got, expected, atol=1e-6)


def test_static_transform_published_on_tf_gives_the_mount(tmp_path):
    # ROS 1 style: static_transform_publisher repeating base_link->laser on /tf.
    t0 = 2_000_000_000
    messages = []
    for i in range(10):
        t = t0 + i * 50_000_000
        messages.append(
            (
                "/tf",
                t,
                tf_message(ros2_transform(t, "base_link", "laser", (0.4, 0.0, 0.2), yaw_quat(math.pi))),
            )
        )
        messages.append(("/scan", t + 1, ros2_scan(t + 1, [1.0])))
    path = raw_ros2_bag(
        tmp_path / "tfmount",
        {"/tf": "tf2_msgs/msg/TFMessage", "/scan": "sensor_msgs/msg/LaserScan"},
        messages,
    )
    bag = RosBag(path)
    assert bag.odometry_source == "none"  # no odom frame in /tf
    scans, _ = split(list(bag.messages()))
    np.testing.assert_allclose(scans[0].mount[:2], [0.4, 0.0], atol=1e-12)
    assert abs(se2.wrap_angle(scans[0].mount[2] - math.pi)) < 1e-12


def test_missing_laser_transform_is_noted_when_odometry_comes_from_tf(tmp_path):
    t = 5_000_000_000
    path = raw_ros2_bag(
        tmp_path / "nolaser",
        {"/tf": "tf2_msgs/msg/TFMessage", "/scan": "sensor_msgs/msg/LaserScan"},
        [
            ("/tf", t, tf_message(ros2_transform(t, "odom", "base_link", (1.0, 2.0, 0.0), yaw_quat(0.1)))),
            ("/scan", t, ros2_scan(t, [1.0, 2.0])),
        ],
    )
    bag = RosBag(path)
    scans, odom = split(list(bag.messages()))
    np.testing.assert_array_equal(scans[0].mount, [0.0, 0.0, 0.0])
    np.testing.assert_allclose(odom[0].pose, [1.0, 2.0, 0.1], atol=1e-12)
    assert any("laser assumed at the base origin" in k for k in bag.problems.counts)


# -- real files ---------------------------------------------------------------------------------


@pytest.mark.datasets
def test_damaged_demo_bag_is_read_sequentially():
    path = dataset_file("robustness/laser_scan_matcher_demo.bag")
    bag = open_recording(path)
    assert isinstance(bag, RosBag)
    # rosbag plays this bag: its index records state wrong lengths but their entry counts are right. Not "damaged".
    assert "read sequentially" in bag.format and "damaged" not in bag.format
    assert "index records state wrong lengths" in bag.format
    assert [(s.name, s.type, s.count, s.used_as) for s in bag.streams()] == [
        ("/scan", "sensor_msgs/LaserScan", 360, "scans")  # a ROS 1 bag's own spelling
    ]
    assert bag.odometry_source == "none"
    frames = list(bag.frames())
    assert bag.problems.counts["bag index record states a wrong length (read by its entry count, as rosbag does)"] == 2
    assert not any("damaged" in kind for kind in bag.problems.counts)
    assert len(frames) == 360
    assert {f.scan.num_beams for f in frames} == {681}
    assert all(f.odometry is None for f in frames)
    span = frames[-1].timestamp - frames[0].timestamp
    assert 35.0 < span < 37.0
    assert all(b.timestamp > a.timestamp for a, b in zip(frames, frames[1:]))
    fov = frames[0].scan.field_of_view
    assert math.degrees(fov) == pytest.approx(239, abs=1.0)
    assert 0.5 < np.nanmedian(frames[0].scan.ranges) < 5.6


@pytest.mark.datasets
def test_old_bag_version_is_rejected_in_one_line():
    path = dataset_file("robustness/laser_scan_sparsifier_demo.bag")
    with pytest.raises(InputError, match="unsupported bag version 1.2") as err:
        open_recording(path)
    assert str(path) in str(err.value) and "\n" not in str(err.value)


# -- bad input -----------------------------------------------------------------------------------


@pytest.fixture()
def small_bag(tmp_path):
    return write_rosbag(tmp_path / "small", sample_messages(3, 8))


def test_requested_topic_that_does_not_exist(small_bag):
    with pytest.raises(InputError) as err:
        RosBag(small_bag, ReadOptions(scan_topic="/front_scan"))
    text = str(err.value)
    assert str(small_bag) in text and "scan_topic" in text and "/front_scan" in text
    assert "/scan (sensor_msgs/LaserScan)" in text  # lists what is there


def test_topic_of_an_unsupported_type(tmp_path):
    String = TS2.types["std_msgs/msg/String"]
    path = raw_ros2_bag(
        tmp_path / "strings", {"/scan": "std_msgs/msg/String"}, [("/scan", 1, String(data="hello"))]
    )
    with pytest.raises(InputError) as err:
        RosBag(path, ReadOptions(scan_topic="/scan"))
    text = str(err.value)
    assert str(path) in text
    assert (
        "unknown/unsupported message type std_msgs/String on topic /scan, expected sensor_msgs/LaserScan"
        in text
    )
    with pytest.raises(
        InputError, match=r"no sensor_msgs/LaserScan topic; topics: /scan \(std_msgs/String\)"
    ):
        RosBag(path)


def test_two_scan_topics_need_a_choice(tmp_path):
    path = raw_ros2_bag(
        tmp_path / "two",
        {"/front": "sensor_msgs/msg/LaserScan", "/rear": "sensor_msgs/msg/LaserScan"},
        [("/front", 10, ros2_scan(10, [1.0])), ("/rear", 20, ros2_scan(20, [2.0, 2.0]))],
    )
    with pytest.raises(InputError) as err:
        RosBag(path)
    text = str(err.value)
    assert str(path) in text and "/front" in text and "/rear" in text and "--scan-topic" in text
    (scan,) = list(RosBag(path, ReadOptions(scan_topic="rear")).messages())
    assert scan.num_beams == 2


def test_truncated_ros1_bag_keeps_what_is_intact(tmp_path):
    sent = sample_messages(400, 360)
    full = write_rosbag(tmp_path / "full.bag", sent, version="ros1")
    data = full.read_bytes()
    cut = tmp_path / "cut.bag"
    cut.write_bytes(data[: len(data) // 2])
    bag = RosBag(cut)
    assert "read sequentially" in bag.format
    got_scans, _ = split(list(bag.messages()))
    assert 0 < len(got_scans) < 400
    for got, s in zip(got_scans, split(sent)[0]):
        assert_scan_round_trip(got, s)
    assert bag.problems.counts["bag truncated (kept the complete messages before the cut)"] == 1


@pytest.mark.parametrize("fraction", [0.0005, 0.01, 0.2, 0.5, 0.77, 0.999, 0.99999])
def test_bag_cut_anywhere_gives_data_or_a_clear_error(tmp_path, fraction):
    data = write_rosbag(tmp_path / "full.bag", sample_messages(200, 100), version="ros1").read_bytes()
    cut = tmp_path / "cut.bag"
    cut.write_bytes(data[: max(1, int(len(data) * fraction))])
    try:
        bag = open_recording(cut)
        n = sum(1 for _ in bag.frames())
    except InputError as exc:
        assert str(cut) in str(exc)
    else:
        assert n <= 200
        assert bag.problems  # never silently short


def test_unindexed_ros1_bag_is_read(tmp_path):
    data = bytearray(
        write_rosbag(tmp_path / "full.bag", sample_messages(20, 30), version="ros1").read_bytes()
    )
    at = data.index(b"index_pos=") + len(b"index_pos=")
    data[at : at + 8] = bytes(8)  # what a recorder killed before closing leaves
    path = tmp_path / "unindexed.bag"
    path.write_bytes(bytes(data))
    bag = RosBag(path)
    assert bag.format == "ROS 1 bag v2.0 (no index: read sequentially)"
    assert sum(1 for m in bag.messages() if isinstance(m, LaserScan)) == 20


def test_damage_in_the_middle_stops_unless_skipping(tmp_path):
    data = bytearray(
        write_rosbag(tmp_path / "full.bag", sample_messages(600, 360), version="ros1").read_bytes()
    )
    chunk_ops = [i for i in range(len(data)) if data.startswith(b"op=\x05", i)]
    assert len(chunk_ops) >= 3
    at = chunk_ops[1]
    data[at - 8 : at + 20] = b"\xff" * 28  # wreck the second chunk's header
    path = tmp_path / "wrecked.bag"
    path.write_bytes(bytes(data))
    with pytest.raises(InputError, match="--skip-bad-records") as err:
        list(RosBag(path).messages())
    assert str(path) in str(err.value) and "byte" in str(err.value)
    bag = RosBag(path, ReadOptions(skip_bad_records=True))
    n = sum(1 for m in bag.messages() if isinstance(m, LaserScan))
    assert 0 < n < 600
    assert bag.problems.counts["damaged bytes skipped in bag"] == 1


def test_empty_and_garbage_files(tmp_path):
    empty = tmp_path / "empty.bag"
    empty.write_bytes(b"")
    for opener in (RosBag, open_recording):
        with pytest.raises(InputError, match="empty") as err:
            opener(empty)
        assert str(empty) in str(err.value)
    rng = np.random.default_rng(1)
    for name in ("garbage.db3", "garbage.mcap"):
        garbage = tmp_path / name
        garbage.write_bytes(rng.integers(0, 256, 4096, dtype=np.uint8).tobytes())
        for opener in (RosBag, open_recording):
            with pytest.raises(InputError) as err:
                opener(garbage)
            assert str(garbage) in str(err.value)
    not_a_bag = tmp_path / "notes.bag"
    not_a_bag.write_text("hello\n")
    with pytest.raises(InputError, match="ROSBAG"):
        RosBag(not_a_bag)


def test_corrupt_scan_message_names_message_and_field(tmp_path):
    good = bytes(TS2.serialize_cdr(ros2_scan(1_000, [1.0, 2.0]), "sensor_msgs/msg/LaserScan"))
    path = raw_ros2_bag(
        tmp_path / "corrupt",
        {"/scan": "sensor_msgs/msg/LaserScan"},
        [
            ("/scan", 1_000, good),
            ("/scan", 2_000, bytes(good[:30])),
            ("/scan", 3_000, ros2_scan(3_000, [1.0])),
        ],
    )
    with pytest.raises(InputError) as err:
        list(RosBag(path).messages())
    text = str(err.value)
    assert str(path) in text and "message 2 on /scan" in text and "data" in text
    bag = RosBag(path, ReadOptions(skip_bad_records=True))
    assert len(list(bag.messages())) == 2
    assert bag.problems.counts["skipped message with bad data"] == 1


def test_invalid_scan_fields_name_the_field(tmp_path):
    path = raw_ros2_bag(
        tmp_path / "zero_inc",
        {"/scan": "sensor_msgs/msg/LaserScan"},
        [
            ("/scan", 1_000, ros2_scan(1_000, [1.0])),
            ("/scan", 2_000, ros2_scan(2_000, [1.0, 2.0], increment=0.0)),
        ],
    )
    with pytest.raises(InputError) as err:
        list(RosBag(path).messages())
    assert "message 2 on /scan" in str(err.value) and "angle_increment" in str(err.value)
    assert err.value.field == "angle_increment"


def test_zero_stamp_falls_back_to_bag_time(tmp_path):
    path = raw_ros2_bag(
        tmp_path / "zero",
        {"/scan": "sensor_msgs/msg/LaserScan"},
        [("/scan", 7_500_000_000, ros2_scan(0, [1.0]))],
    )
    bag = RosBag(path)
    (scan,) = list(bag.messages())
    assert scan.timestamp == 7.5
    assert bag.problems.counts["zero header stamp (bag time used)"] == 1


def test_frames_input_accepts_frames(tmp_path):
    scan = make_scan(3.0, [1.0, 2.0], 0.0, 0.5)
    path = write_rosbag(
        tmp_path / "f.bag", [Frame(0, scan, np.array([1.0, 2.0, 0.5])), Frame(1, scan, None)], version="ros1"
    )
    with pytest.raises(InputError):
        write_rosbag(tmp_path / "bad", ["not a message"])  # type: ignore[list-item]
    _, odom = split(list(RosBag(path).messages()))
    assert len(odom) == 1 and odom[0].timestamp == 3.0


def test_ros1_bag_with_old_tf_type_and_slashed_frames(tmp_path):
    # Pre-Hydro bags: /tf as tf/tfMessage, frame ids with a leading slash.
    from rosbags.rosbag1 import Writer as Ros1Writer
    from rosbags.typesys import get_types_from_msg

    ts1 = get_typestore(Stores.ROS1_NOETIC)
    ts1.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf/msg/tfMessage"))
    t = ts1.types
    Time = t["builtin_interfaces/msg/Time"]

    def header(ns, frame):
        return t["std_msgs/msg/Header"](
            seq=0, stamp=Time(sec=ns // 10**9, nanosec=ns % 10**9), frame_id=frame
        )

    def transform(ns, parent, child, x, yaw):
        q = yaw_quat(yaw)
        return t["geometry_msgs/msg/TransformStamped"](
            header=header(ns, parent),
            child_frame_id=child,
            transform=t["geometry_msgs/msg/Transform"](
                translation=t["geometry_msgs/msg/Vector3"](x=x, y=0.0, z=0.0),
                rotation=t["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
            ),
        )

    path = tmp_path / "old.bag"
    with Ros1Writer(path) as writer:
        tf_conn = writer.add_connection("/tf", "tf/msg/tfMessage", typestore=ts1)
        scan_conn = writer.add_connection("/base_scan", "sensor_msgs/msg/LaserScan", typestore=ts1)
        for i in range(5):
            ns = 10**9 * (100 + i)
            links = [
                transform(ns, "/odom", "/base_link", 0.5 * i, 0.1 * i),
                transform(ns, "/base_link", "/laser", 0.2, 0.0),
            ]
            writer.write(
                tf_conn, ns, ts1.serialize_ros1(t["tf/msg/tfMessage"](transforms=links), "tf/msg/tfMessage")
            )
            scan = t["sensor_msgs/msg/LaserScan"](
                header=header(ns, "/laser"),
                angle_min=-1.0,
                angle_max=1.0,
                angle_increment=1.0,
                time_increment=0.0,
                scan_time=0.0,
                range_min=0.1,
                range_max=10.0,
                ranges=np.array([1.0, 2.0, 3.0], dtype=np.float32),
                intensities=np.zeros(0, dtype=np.float32),
            )
            writer.write(scan_conn, ns, ts1.serialize_ros1(scan, "sensor_msgs/msg/LaserScan"))
    bag = RosBag(path)
    assert bag.odometry_source == "/tf odom -> base_link"
    scans, odom = split(list(bag.messages()))
    assert len(scans) == 5 and len(odom) == 5
    np.testing.assert_allclose(scans[0].mount, [0.2, 0.0, 0.0], atol=1e-12)  # constant /tf link
    np.testing.assert_allclose(
        [o.pose for o in odom], [[0.5 * i, 0.0, 0.1 * i] for i in range(5)], atol=1e-12
    )


def test_indexed_reader_failing_midway_resumes_sequentially(tmp_path, monkeypatch):
    from rosbags.rosbag1 import Reader

    sent = sample_messages(200, 20)  # 20 s: discovery (first 5 s) stays below the failure
    path = write_rosbag(tmp_path / "mid.bag", sent, version="ros1")
    expected = [(type(m).__name__, m.timestamp) for m in RosBag(path).messages()]
    original = Reader.messages

    def failing(self, *args, **kwargs):
        for k, item in enumerate(original(self, *args, **kwargs)):
            if k == 300:
                raise AssertionError  # what rosbags raises on inconsistent index records
            yield item

    monkeypatch.setattr(Reader, "messages", failing)
    bag = RosBag(path)
    bag.odometry_source  # discovery reads only the start: still indexed
    assert bag.format == "ROS 1 bag v2.0"
    got = [(type(m).__name__, m.timestamp) for m in bag.messages()]
    assert got == expected  # nothing lost, nothing repeated
    assert "index damaged: read sequentially" in bag.format
    assert bag.problems.counts["bag index damaged; read sequentially"] == 1


def test_odometry_topic_with_a_deeper_base_frame(small_bag):
    # Asking for the laser frame as the base: poses move to the laser and the mount vanishes.
    plain = split(list(RosBag(small_bag).messages()))
    bag = RosBag(small_bag, ReadOptions(base_frame="laser"))
    scans, odom = split(list(bag.messages()))
    np.testing.assert_allclose(scans[0].mount, [0.0, 0.0, 0.0], atol=1e-12)
    mount = plain[0][0].mount
    for got, base in zip(odom, plain[1], strict=True):
        np.testing.assert_allclose(got.pose, se2.compose(base.pose, mount), atol=1e-9)


@pytest.mark.parametrize("compression", ["bz2", "lz4"])
def test_compressed_chunks_are_read_sequentially(tmp_path, compression):
    from rosbags.rosbag1 import Reader as Ros1Reader
    from rosbags.rosbag1 import Writer as Ros1Writer

    sent = sample_messages(300, 2000)  # several 1 MB chunks: bz2 cannot decode a cut block
    plain = write_rosbag(tmp_path / "plain.bag", sent, version="ros1")
    packed = tmp_path / "packed.bag"
    writer = Ros1Writer(packed)
    writer.set_compression(getattr(Ros1Writer.CompressionFormat, compression.upper()))
    with Ros1Reader(plain) as reader, writer:
        conns = {
            c.id: writer.add_connection(c.topic, c.msgtype, msgdef=c.msgdef.data, md5sum=c.digest)
            for c in reader.connections
        }
        for conn, time_ns, raw in reader.messages():
            writer.write(conns[conn.id], time_ns, raw)
    data = bytearray(packed.read_bytes())
    assert f"compression={compression}".encode() in data
    at = data.index(b"index_pos=") + len(b"index_pos=")
    data[at : at + 8] = bytes(8)
    unindexed = tmp_path / "unindexed.bag"
    unindexed.write_bytes(bytes(data))
    got_scans, got_odom = split(list(RosBag(unindexed).messages()))
    assert len(got_scans) == 300 and len(got_odom) == 300
    for got, s in zip(got_scans, split(sent)[0]):
        assert_scan_round_trip(got, s)
    # Cut inside a compressed chunk: the complete messages before the cut are kept.
    cut = tmp_path / "cut.bag"
    cut.write_bytes(bytes(data[: int(len(data) * 0.6)]))
    bag = RosBag(cut)
    got_scans, _ = split(list(bag.messages()))
    assert 0 < len(got_scans) < 300
    for got, s in zip(got_scans, split(sent)[0]):
        assert_scan_round_trip(got, s)
    assert bag.problems.counts["bag truncated (kept the complete messages before the cut)"] == 1


def test_a_second_pass_does_not_count_problems_twice():
    from tests.conftest import dataset_file

    bag = RosBag(dataset_file("robustness/laser_scan_matcher_demo.bag"))
    list(bag.frames())
    first = dict(bag.problems.counts)
    list(bag.frames())
    assert dict(bag.problems.counts) == first
    assert first  # the damaged index is reported


def test_range_min_option_raises_the_bag_minimum(tmp_path):
    ranges = [0.06, 0.5, 0.08, 3.0]  # the message states range_min 0.05
    path = raw_ros2_bag(
        tmp_path / "short", {"/scan": "sensor_msgs/msg/LaserScan"},
        [("/scan", stamp_ns(1.0), ros2_scan(stamp_ns(1.0), ranges))],
    )
    (stated,) = [m for m in open_recording(path).messages() if isinstance(m, LaserScan)]
    assert stated.range_min == pytest.approx(0.05) and not np.isnan(stated.ranges).any()
    (raised,) = [m for m in open_recording(path, ReadOptions(range_min=0.1)).messages() if isinstance(m, LaserScan)]
    assert raised.range_min == 0.1
    np.testing.assert_array_equal(np.isnan(raised.ranges), [True, False, True, False])


def test_a_broken_ros2_metadata_file_is_one_line_naming_the_bag(tmp_path):
    path = write_rosbag(tmp_path / "broken", sample_messages(2, 10), version="ros2")
    (path / "metadata.yaml").write_text("rosbag2_bagfile_information: [1\n")
    with pytest.raises(InputError) as info:
        open_recording(path)
    text = str(info.value)
    assert text.startswith(f"{path}: cannot be read as a ROS 2 bag") and "metadata.yaml" in text
    assert "\n" not in text  # the YAML parser's message spans several lines
