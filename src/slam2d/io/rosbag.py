"""ROS 1 and ROS 2 bags: reading laser scans and odometry, and writing them back.

:class:`RosBag` reads a ROS 1 ``.bag`` file (v2.0) or a ROS 2 bag (a folder
with ``metadata.yaml``, or a lone ``.db3`` / ``.mcap`` file) through the
``rosbags`` library. Scans come from a ``sensor_msgs/LaserScan`` topic,
odometry from a ``nav_msgs/Odometry`` topic or from the ``odom -> base``
transforms in ``/tf``, and the laser's mount on the robot from ``/tf_static``.
A ROS 1 bag whose index is damaged is read sequentially instead (see
:mod:`slam2d.io.ros1_fallback`).

:func:`write_rosbag` writes scans and odometry as a ROS 1 bag or a ROS 2 bag
(sqlite3 or mcap) that the ROS tools read.

Frame names are compared without a leading ``/`` (ROS 1 bags often have
``/odom``), as tf2 does.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Collection, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slam2d.core import se2
from slam2d.core.frames import Frame, OdometryReading
from slam2d.core.scan import LaserScan, make_scan
from slam2d.errors import InputError, one_line
from slam2d.io.atomic import atomic_path
from slam2d.io.base import Message, ProgressCallback, ReadOptions, Recording, StreamInfo, pose_problem
from slam2d.io.ros1_fallback import DATA_LOSS, BagDamaged, Ros1SequentialReader

__all__ = ["RosBag", "write_rosbag", "planar_transform", "SCAN_TYPE", "ODOMETRY_TYPE", "TF_TYPE"]

SCAN_TYPE = "sensor_msgs/msg/LaserScan"
ODOMETRY_TYPE = "nav_msgs/msg/Odometry"
TF_TYPE = "tf2_msgs/msg/TFMessage"
# Bags from before ROS Hydro carry /tf as tf/tfMessage, which has the same layout.
_TF_TYPES = (TF_TYPE, "tf/msg/tfMessage")

# How much of the start of the bag is read to learn the tf tree (seconds of bag time).
_TF_DISCOVERY_WINDOW = 5.0
# Report progress every this many messages.
_PROGRESS_EVERY = 200
# Corrupt sequence lengths must not make the decoder allocate gigabytes.
_MAX_SEQUENCE_LENGTH = 1 << 24


#: Mounts closer than this (m, rad) are the same mount: one recomputed from a
#: CARMEN line's laser and robot poses differs from the original in the last bits.
_MOUNT_TOLERANCE = 1e-9


def _short_type(msgtype: str) -> str:
    """``sensor_msgs/msg/LaserScan`` -> ``sensor_msgs/LaserScan`` (the ROS 1 spelling)."""
    return msgtype.replace("/msg/", "/")


def _frame(name: str) -> str:
    return name.lstrip("/")


def _stamp_seconds(stamp: Any) -> float:
    # sec + nanosec * 1e-9 rounds to the float nearest the stamp; dividing the
    # integer nanoseconds would lose precision above 2**53 ns.
    return float(stamp.sec) + float(stamp.nanosec) * 1e-9


def _is_zero_stamp(stamp: Any) -> bool:
    return stamp.sec == 0 and stamp.nanosec == 0


def _typestore(ros_version: int) -> Any:
    """The message types of ROS 1 Noetic or ROS 2 Humble, plus tf2_msgs/TFMessage for ROS 1."""
    import importlib

    from rosbags.typesys import Stores, get_types_from_msg
    from rosbags.typesys.store import Typestore

    name = Stores.ROS1_NOETIC if ros_version == 1 else Stores.ROS2_HUMBLE
    module = importlib.import_module(f"rosbags.typesys.stores.{name.value}")
    store = Typestore(module, max_sequence_length=_MAX_SEQUENCE_LENGTH)
    if TF_TYPE not in store.fielddefs:
        # rosbags' Noetic store lacks it; its definition is one line.
        store.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", TF_TYPE))
    return store


# -- 3D rigid transforms, just enough for tf chains ------------------------------------


def _quat_matrix(q: Any) -> NDArray[np.float64]:
    """Rotation matrix of a (possibly unnormalised) quaternion message."""
    x, y, z, w = float(q.x), float(q.y), float(q.z), float(q.w)
    n = x * x + y * y + z * z + w * w
    if not (n > 0.0 and math.isfinite(n)):
        raise ValueError("rotation: not a valid quaternion")
    s = 2.0 / n
    return np.array(
        [
            [1.0 - s * (y * y + z * z), s * (x * y - w * z), s * (x * z + w * y)],
            [s * (x * y + w * z), 1.0 - s * (x * x + z * z), s * (y * z - w * x)],
            [s * (x * z - w * y), s * (y * z + w * x), 1.0 - s * (x * x + y * y)],
        ]
    )


def _transform_matrix(tf: Any) -> NDArray[np.float64]:
    """4x4 homogeneous matrix of a geometry_msgs/Transform."""
    m = np.eye(4)
    m[:3, :3] = _quat_matrix(tf.rotation)
    m[:3, 3] = (tf.translation.x, tf.translation.y, tf.translation.z)
    if not np.all(np.isfinite(m)):
        raise ValueError("translation: not finite")
    return m


def _planar(m: NDArray[np.float64]) -> NDArray[np.float64]:
    """``[x, y, yaw]`` of a 3D transform: the yaw is that of its x axis (ZYX yaw)."""
    return np.array([m[0, 3], m[1, 3], math.atan2(m[1, 0], m[0, 0])])


def _mount_of(m: NDArray[np.float64]) -> tuple[NDArray[np.float64], bool]:
    """A laser's ``([x, y, yaw], upside_down)`` on the base from the 4x4 transform base <- laser.

    The laser's z axis pointing down means its scan sweeps clockwise seen from above; make_scan mirrors
    the beam angles for it.
    """
    return _planar(m), bool(m[2, 2] < 0.0)


def planar_transform(transform: Any) -> tuple[NDArray[np.float64], bool]:
    """``([x, y, yaw], upside_down)`` of a geometry_msgs/Transform (raises ``ValueError`` when it is not valid)."""
    return _mount_of(_transform_matrix(transform))


@dataclass
class _TfTree:
    """Static transforms: child frame -> (parent frame, 4x4 transform parent <- child)."""

    links: dict[str, tuple[str, NDArray[np.float64]]] = field(default_factory=dict)

    def add(self, parent: str, child: str, m: NDArray[np.float64]) -> None:
        self.links[child] = (parent, m)

    def __contains__(self, frame: str) -> bool:
        return frame in self.links or any(p == frame for p, _ in self.links.values())

    def _to_root(self, frame: str) -> tuple[str, NDArray[np.float64]]:
        m = np.eye(4)
        seen = {frame}
        while frame in self.links:
            parent, link = self.links[frame]
            if parent in seen:  # a cycle: stop rather than loop forever
                break
            m = link @ m
            frame = parent
            seen.add(frame)
        return frame, m

    def root(self, frame: str) -> str:
        return self._to_root(frame)[0]

    def lookup(self, target: str, source: str) -> NDArray[np.float64] | None:
        """Pose of frame ``source`` in frame ``target`` (4x4), or None if not connected."""
        if target == source:
            return np.eye(4)
        root_t, m_t = self._to_root(target)
        root_s, m_s = self._to_root(source)
        if root_t != root_s:
            return None
        return np.linalg.inv(m_t) @ m_s


# -- storage backends --------------------------------------------------------------------


@dataclass
class _Topic:
    name: str
    msgtype: str
    count: int
    msgdef: str = ""  # ROS 1 message definition text, used to decode unknown types


class _Backend:
    """A bag's topics and a raw message stream: ``(topic, bag time ns, bytes)``."""

    ros_version: int = 2
    format: str = ""
    indexed: bool = True  # messages come time-sorted and topics can be read selectively
    topics: dict[str, _Topic]

    def read(self, topics: Collection[str]) -> Iterator[tuple[str, int, bytes]]:
        raise NotImplementedError


class _Ros1Sequential(_Backend):
    """ROS 1 bag read record by record (index damaged or missing)."""

    ros_version = 1
    indexed = False

    def __init__(self, path: Path, bag: RosBag, failure: str) -> None:
        """``failure`` says why the indexed reader gave up; it goes to the problem log."""
        self.path = path
        self.bag = bag
        try:
            self.reader = Ros1SequentialReader(path, self._problem)
        except (BagDamaged, OSError) as exc:
            raise InputError(f"cannot be read as a ROS 1 bag: {one_line(exc)}", path=path) from None
        # index_pos 0 is what a recorder killed before closing the bag leaves.
        if self.reader.index_pos == 0:
            self.format = "ROS 1 bag v2.0 (no index: read sequentially)"
            bag.problems.add("bag has no index; read sequentially", failure)
        elif self.reader.only_index_lengths_wrong():
            # rosbag plays such a bag: it reads index records by their counts. The data is whole.
            # (each such record is in the problem log, from the read itself)
            self.format = "ROS 1 bag v2.0 (index records state wrong lengths: read sequentially, nothing lost)"
        else:
            self.format = "ROS 1 bag v2.0 (index damaged: read sequentially)"
            bag.problems.add("bag index damaged; read sequentially", failure)
        try:
            self.reader.read_metadata()
        except (BagDamaged, OSError) as exc:
            raise InputError(f"cannot be read as a ROS 1 bag: {one_line(exc)}", path=path) from None
        self.topics = {}
        for conn in self.reader.connections.values():
            topic = self.topics.setdefault(conn.topic, _Topic(conn.topic, conn.msgtype, 0, conn.msgdef))
            topic.count += self.reader.counts.get(conn.id, 0)

    def _problem(self, kind: str, example: str, offset: int | None) -> None:
        # A cut-off tail is how a killed recording ends: keep what is intact.
        # Damage in the middle loses data, which stops the read unless the
        # user asked to skip bad records.
        if kind in DATA_LOSS and not self.bag.options.skip_bad_records:
            raise InputError(
                f"bag is damaged in the middle ({example}); --skip-bad-records skips the damaged part",
                path=self.path,
                where=None if offset is None else f"byte {offset}",
                field="chunk",
            )
        self.bag.problems.add(kind, example)

    def read(self, topics: Collection[str]) -> Iterator[tuple[str, int, bytes]]:
        for conn, time_ns, raw in self.reader.messages():
            if conn.topic in topics:
                yield conn.topic, time_ns, raw


class _Ros1Indexed(_Backend):
    """ROS 1 bag read through its index by ``rosbags`` (time-sorted)."""

    ros_version = 1
    format = "ROS 1 bag v2.0"

    def __init__(self, path: Path, reader: Any, bag: RosBag) -> None:
        self.path = path
        self.bag = bag
        self.topics = {
            name: _Topic(name, info.msgtype or "", info.msgcount, info.msgdef.data)
            for name, info in reader.topics.items()
        }
        self.fallback: _Ros1Sequential | None = None

    def read(self, topics: Collection[str]) -> Iterator[tuple[str, int, bytes]]:
        if self.fallback is not None:
            yield from self.fallback.read(topics)
            return
        from rosbags.rosbag1 import Reader

        # What was yielded, so a switch to the sequential reader midway can
        # skip it: everything up to ``last`` in time, and ``at_last`` messages
        # per topic stamped exactly ``last``.
        last = -1
        at_last: Counter[str] = Counter()
        try:
            with Reader(self.path) as reader:
                wanted = [c for c in reader.connections if c.topic in topics]
                if not wanted:
                    return
                for conn, time_ns, raw in reader.messages(wanted):
                    yield conn.topic, time_ns, raw
                    if time_ns != last:
                        last = time_ns
                        at_last.clear()
                    at_last[conn.topic] += 1
            return
        except Exception as exc:  # noqa: BLE001 - any failure of the index means: read sequentially
            failure = _describe_failure(exc)
        self.fallback = _Ros1Sequential(self.path, self.bag, failure)
        self.format = self.fallback.format
        for topic, time_ns, raw in self.fallback.read(topics):
            if time_ns < last:
                continue
            if time_ns == last and at_last[topic] > 0:
                at_last[topic] -= 1
                continue
            yield topic, time_ns, raw


class _Ros2(_Backend):
    """ROS 2 bag (folder, or lone .db3 / .mcap file) read by ``rosbags``."""

    ros_version = 2

    def __init__(self, path: Path) -> None:
        from rosbags.rosbag2 import Reader

        self.path = path
        target = path
        if path.is_dir() and not (path / "metadata.yaml").is_file():
            # A bag folder that lost its metadata: read its one storage file.
            files = sorted(p for p in path.iterdir() if p.suffix in (".db3", ".mcap"))
            if len(files) != 1:
                raise InputError(
                    f"ROS 2 bag folder has no metadata.yaml and {len(files)} storage files "
                    "(.db3/.mcap); open one storage file directly",
                    path=path,
                    field="metadata.yaml",
                )
            target = files[0]
        self.target = target
        try:
            with Reader(target) as reader:
                self.topics = {
                    name: _Topic(name, info.msgtype or "", info.msgcount)
                    for name, info in reader.topics.items()
                }
                storage = self._storage_name(reader, target)
        except InputError:
            raise
        except Exception as exc:  # noqa: BLE001 - sqlite/mcap/yaml errors of a corrupt file
            raise InputError(f"cannot be read as a ROS 2 bag: {one_line(exc)}", path=path) from None
        self.format = f"ROS 2 bag ({storage})"

    @staticmethod
    def _storage_name(reader: Any, target: Path) -> str:
        if target.is_dir():
            import yaml

            meta = yaml.safe_load((target / "metadata.yaml").read_text(encoding="utf-8"))
            return str(meta["rosbag2_bagfile_information"]["storage_identifier"])
        return {".db3": "sqlite3", ".mcap": "mcap"}.get(target.suffix, target.suffix.lstrip("."))

    def read(self, topics: Collection[str]) -> Iterator[tuple[str, int, bytes]]:
        from rosbags.rosbag2 import Reader

        try:
            with Reader(self.target) as reader:
                wanted = [c for c in reader.connections if c.topic in topics]
                if not wanted:
                    return
                for conn, time_ns, raw in reader.messages(wanted):
                    yield conn.topic, time_ns, raw
        except InputError:
            raise
        except Exception as exc:  # noqa: BLE001 - a storage file damaged after the metadata
            raise InputError(f"bag storage is damaged: {exc}", path=self.path) from None


def _describe_failure(exc: BaseException) -> str:
    what = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
    return f"the indexed reader failed ({what})"


def _open_backend(path: Path, bag: RosBag) -> _Backend:
    if path.is_dir() or path.suffix in (".db3", ".mcap"):
        return _Ros2(path)
    try:
        with open(path, "rb") as f:
            head = f.read(16)
    except OSError as exc:
        raise InputError(f"cannot be read: {exc.strerror}", path=path) from None
    if not head:
        raise InputError("file is empty", path=path)
    if head.startswith(b"SQLite format 3") or head.startswith(b"\x89MCAP"):
        return _Ros2(path)
    if not head.startswith(b"#ROSBAG V2.0"):
        raise InputError("is not a ROS bag (it does not start with '#ROSBAG V2.0')", path=path)

    from rosbags.rosbag1 import Reader

    reader = Reader(path)
    try:
        reader.open()
    except Exception as exc:  # noqa: BLE001 - rosbags asserts on inconsistent index records
        return _Ros1Sequential(path, bag, _describe_failure(exc))
    try:
        return _Ros1Indexed(path, reader, bag)
    finally:
        reader.close()


# -- the reader ------------------------------------------------------------------------------


@dataclass
class _Plan:
    """What the message stream is made of, decided once from the start of the bag."""

    odometry: str = "none"  # "odom", "tf" or "none"
    odom_frame: str = ""
    tf_child: str = ""  # child of the odometry frame in /tf (the dynamic link)
    base_frame: str = ""
    base_offset: NDArray[np.float64] | None = None  # tf_child (or odometry child) -> base, 4x4
    tree: _TfTree = field(default_factory=_TfTree)
    has_static_tf: bool = False


class RosBag(Recording):
    """A ROS 1 bag (v2.0) or ROS 2 bag (sqlite3 or mcap), streamed as scans and odometry.

    Opening reads the bag's connection records or metadata only; topic
    problems (missing scan topic, wrong type, ambiguous choice) raise
    :class:`~slam2d.errors.InputError` right away. The start of the bag (all of
    ``/tf_static`` and the first seconds of ``/tf``) is read once, on first
    need, to learn the tf tree: the odometry frames and the laser mount.

    Messages are numbered from 1 per topic in error messages
    (``"message 12 on /scan"``).
    """

    def __init__(self, path: str | Path, options: ReadOptions | None = None) -> None:
        super().__init__(path, options)
        self._pass_baseline: tuple | None = None
        if not self.path.exists():
            raise InputError("no such file or folder", path=self.path)
        self._backend = _open_backend(self.path, self)
        self._plan_cache: _Plan | None = None
        self._mounts: dict[str, tuple[NDArray[np.float64], bool]] = {}
        self._typestore: Any = None
        topics = self._backend.topics
        self.scan_topic = self._choose_scan_topic()
        self.odom_topic: str | None = None
        self.tf_topic = next(
            (t for t in ("/tf", "tf") if t in topics and topics[t].msgtype in _TF_TYPES), None
        )
        self.tf_static_topic = next(
            (t for t in ("/tf_static", "tf_static") if t in topics and topics[t].msgtype in _TF_TYPES),
            None,
        )
        self._choose_odometry_topic()

    # -- public properties ----------------------------------------------------------------

    @property
    def format(self) -> str:  # type: ignore[override]
        return self._backend.format

    @property
    def odometry_source(self) -> str:
        plan = self._plan()
        if plan.odometry == "odom":
            return f"{self.odom_topic} ({_short_type(ODOMETRY_TYPE)})"
        if plan.odometry == "tf":
            chain = f"{plan.odom_frame} -> {plan.tf_child}"
            if plan.base_frame != plan.tf_child:
                chain += f" -> {plan.base_frame}"
            return f"{self.tf_topic} {chain}"
        return "none"

    def streams(self) -> list[StreamInfo]:
        """Every topic with its type, message count and what it is used for."""
        plan = self._plan()
        used: dict[str, str] = {self.scan_topic: "scans"}
        if plan.odometry == "odom" and self.odom_topic:
            used[self.odom_topic] = "odometry"
        if self.tf_static_topic and plan.has_static_tf:
            used[self.tf_static_topic] = "laser mount"
        if plan.odometry == "tf" and self.tf_topic:
            used[self.tf_topic] = "odometry"
        # each bag in its own ROS's spelling: sensor_msgs/LaserScan in a ROS 1 bag, sensor_msgs/msg/LaserScan in ROS 2
        spell = _short_type if self._backend.ros_version == 1 else str
        return [
            StreamInfo(t.name, spell(t.msgtype), t.count, used.get(t.name, ""))
            for t in sorted(self._backend.topics.values(), key=lambda t: t.name)
        ]

    # -- topic choice ---------------------------------------------------------------------------

    def _topic_listing(self) -> str:
        listing = ", ".join(
            f"{t.name} ({_short_type(t.msgtype)})"
            for t in sorted(self._backend.topics.values(), key=lambda t: t.name)
        )
        if not listing and self.problems:
            # An empty bag after damage: say why rather than only "none".
            return "none (" + "; ".join(self.problems.counts) + ")"
        return listing or "none"

    def _find_topic(self, name: str) -> str | None:
        topics = self._backend.topics
        for candidate in (name, "/" + name.lstrip("/"), name.lstrip("/")):
            if candidate in topics:
                return candidate
        return None

    def _requested_topic(self, wanted: str, msgtype: str, field: str) -> str:
        """The topic the user named, checked to exist and to carry ``msgtype``."""
        found = self._find_topic(wanted)
        if found is None:
            raise InputError(
                f"no topic {wanted} in the bag; topics: {self._topic_listing()}",
                path=self.path,
                field=field,
            )
        actual = self._backend.topics[found].msgtype
        if actual != msgtype:
            raise InputError(
                f"unknown/unsupported message type {_short_type(actual)} on topic {found}, "
                f"expected {_short_type(msgtype)}",
                path=self.path,
                field=field,
            )
        return found

    def _choose_scan_topic(self) -> str:
        topics = self._backend.topics
        wanted = self.options.scan_topic
        if wanted:
            return self._requested_topic(wanted, SCAN_TYPE, "scan_topic")
        scans = sorted(t.name for t in topics.values() if t.msgtype == SCAN_TYPE)
        if not scans:
            raise InputError(
                f"no sensor_msgs/LaserScan topic; topics: {self._topic_listing()}",
                path=self.path,
                field="scan_topic",
            )
        if len(scans) > 1:
            raise InputError(
                f"{len(scans)} sensor_msgs/LaserScan topics ({', '.join(scans)}); "
                "choose one with --scan-topic",
                path=self.path,
                field="scan_topic",
            )
        return scans[0]

    def _choose_odometry_topic(self) -> None:
        mode = self.options.odometry
        topics = self._backend.topics
        if mode == "embedded":
            raise InputError(
                "odometry 'embedded' means the pose inside CARMEN laser lines; "
                "for a bag use auto, odom, tf or none",
                path=self.path,
                field="odometry",
            )
        if mode not in ("auto", "odom", "tf", "none"):
            raise InputError(f"unknown odometry source {mode!r}", path=self.path, field="odometry")
        if mode in ("auto", "odom"):
            wanted = self.options.odom_topic
            if wanted:
                self.odom_topic = self._requested_topic(wanted, ODOMETRY_TYPE, "odom_topic")
                return
            odoms = sorted(t.name for t in topics.values() if t.msgtype == ODOMETRY_TYPE)
            if len(odoms) > 1:
                raise InputError(
                    f"{len(odoms)} nav_msgs/Odometry topics ({', '.join(odoms)}); "
                    "choose one with --odom-topic",
                    path=self.path,
                    field="odom_topic",
                )
            if odoms:
                self.odom_topic = odoms[0]
            elif mode == "odom":
                raise InputError(
                    f"no nav_msgs/Odometry topic; topics: {self._topic_listing()}",
                    path=self.path,
                    field="odom_topic",
                )
        if mode == "tf" and self.tf_topic is None:
            raise InputError(
                f"odometry from tf needs a /tf topic; topics: {self._topic_listing()}",
                path=self.path,
                field="odometry",
            )

    # -- decoding ---------------------------------------------------------------------------------

    def _decode(self, raw: bytes, topic: str, index: int) -> Any:
        """Deserialise one message; a corrupt one raises InputError (or returns None to skip)."""
        msgtype = self._backend.topics[topic].msgtype
        try:
            store = self._store(msgtype, topic)
            if self._backend.ros_version == 1:
                return store.deserialize_ros1(raw, msgtype)
            return store.deserialize_cdr(raw, msgtype)
        except InputError:
            raise
        except Exception as exc:  # noqa: BLE001 - the decoder raises many kinds on corrupt bytes
            return self._bad_record(
                f"cannot decode {_short_type(msgtype)} ({type(exc).__name__}: {exc})", topic, index, "data"
            )

    def _store(self, msgtype: str, topic: str) -> Any:
        if self._typestore is None:
            self._typestore = _typestore(self._backend.ros_version)
        store = self._typestore
        if msgtype not in store.fielddefs:
            from rosbags.typesys import get_types_from_msg

            msgdef = self._backend.topics[topic].msgdef
            if not msgdef:
                raise InputError(
                    f"message type {_short_type(msgtype)} is unknown and the bag has no definition for it",
                    path=self.path,
                    where=f"topic {topic}",
                    field="type",
                )
            try:
                store.register(get_types_from_msg(msgdef, msgtype))
            except Exception as exc:  # noqa: BLE001 - a malformed definition in the bag
                raise InputError(
                    f"cannot parse the definition of {_short_type(msgtype)}: {exc}",
                    path=self.path,
                    where=f"topic {topic}",
                    field="message_definition",
                ) from None
        return store

    def _bad_record(self, why: str, topic: str, index: int, field_name: str) -> None:
        where = f"message {index} on {topic}"
        if not self.options.skip_bad_records:
            raise InputError(
                f"{why} (--skip-bad-records skips such messages)",
                path=self.path,
                where=where,
                field=field_name,
            )
        self.problems.add(f"skipped message with bad {field_name}", f"{where}: {why}")
        return None

    # -- tf discovery ------------------------------------------------------------------------------

    def _plan(self) -> _Plan:
        if self._plan_cache is None:
            self._plan_cache = self._make_plan()
        return self._plan_cache

    def _make_plan(self) -> _Plan:
        plan = _Plan()
        mode = self.options.odometry
        want_tf = self.tf_topic is not None and (mode == "tf" or (mode == "auto" and self.odom_topic is None))
        static: dict[tuple[str, str], NDArray[np.float64]] = {}
        # /tf links seen early: (parent, child) -> first transform, and whether it ever moved.
        dynamic: dict[tuple[str, str], NDArray[np.float64]] = {}
        moved: set[tuple[str, str]] = set()
        first_scan_frame: str | None = None
        first_odom: Any = None

        def take_tf(msg: Any, into_static: bool) -> None:
            for ts in msg.transforms:
                key = (_frame(ts.header.frame_id), _frame(ts.child_frame_id))
                try:
                    m = _transform_matrix(ts.transform)
                except ValueError:
                    continue
                if into_static:
                    static[key] = m
                elif key not in dynamic:
                    dynamic[key] = m
                elif key not in moved and not np.allclose(dynamic[key], m, atol=1e-9, rtol=0.0):
                    moved.add(key)

        early = [t for t in (self.tf_topic, self.scan_topic, self.odom_topic) if t]
        if self.tf_static_topic:
            if self._backend.indexed:
                # Cheap on an indexed bag: read every /tf_static message, wherever it is.
                for topic, _, raw in self._backend.read([self.tf_static_topic]):
                    msg = self._decode_quiet(raw, topic)
                    if msg is not None:
                        take_tf(msg, True)
            else:
                early.append(self.tf_static_topic)
        start_ns: int | None = None
        stream = self._backend.read(early)
        try:
            for topic, time_ns, raw in stream:
                if start_ns is None:
                    start_ns = time_ns
                if topic == self.scan_topic:
                    if first_scan_frame is None:
                        msg = self._decode_quiet(raw, topic)
                        if msg is not None:
                            first_scan_frame = _frame(msg.header.frame_id)
                elif topic == self.odom_topic:
                    if first_odom is None:
                        first_odom = self._decode_quiet(raw, topic)
                else:
                    msg = self._decode_quiet(raw, topic)
                    if msg is not None:
                        take_tf(msg, topic == self.tf_static_topic)
                past_window = time_ns - start_ns > _TF_DISCOVERY_WINDOW * 1e9
                if (
                    past_window
                    and first_scan_frame is not None
                    and (self.odom_topic is None or first_odom is not None)
                ):
                    break
        finally:
            stream.close()

        plan.has_static_tf = bool(static)
        for (parent, child), m in static.items():
            plan.tree.add(parent, child, m)
        # /tf links that never moved are static transforms published the ROS 1 way
        # (static_transform_publisher on /tf); they may carry the laser mount.
        odom_frame = _frame(self.options.odom_frame) if self.options.odom_frame else "odom"
        for (parent, child), m in dynamic.items():
            if (parent, child) in moved or parent == odom_frame or child == odom_frame:
                continue
            if child not in plan.tree.links:
                plan.tree.add(parent, child, m)

        if self.odom_topic is not None and mode in ("auto", "odom"):
            plan.odometry = "odom"
            child = _frame(first_odom.child_frame_id) if first_odom is not None else ""
            plan.tf_child = child or "base_link"
            plan.base_frame = _frame(self.options.base_frame) if self.options.base_frame else plan.tf_child
            plan.base_offset = self._base_offset(plan, plan.tf_child, "odom child_frame_id")
        elif want_tf:
            children: Counter[str] = Counter()
            for parent, child in dynamic:
                if parent == odom_frame:
                    children[child] += 1
            if not children:
                if mode == "tf":
                    seen = ", ".join(f"{p} -> {c}" for p, c in sorted(dynamic)) or "none"
                    raise InputError(
                        f"no transform from frame {odom_frame!r} in the first {_TF_DISCOVERY_WINDOW:g} s "
                        f"of {self.tf_topic} (transforms seen: {seen}); set --odom-frame",
                        path=self.path,
                        field="odom_frame",
                    )
            else:
                plan.odometry = "tf"
                plan.odom_frame = odom_frame
                base = _frame(self.options.base_frame) if self.options.base_frame else None
                if base is not None and base in children:
                    plan.tf_child = base
                elif base is not None:
                    # The base frame hangs below the odometry frame's child through static links.
                    plan.tf_child = next(
                        (c for c in children if plan.tree.lookup(c, base) is not None and base in plan.tree),
                        "",
                    )
                    if not plan.tf_child:
                        raise InputError(
                            f"base frame {base!r} is not linked to the child of {odom_frame!r} "
                            f"({', '.join(children)}) by static transforms",
                            path=self.path,
                            field="base_frame",
                        )
                else:
                    plan.tf_child = children.most_common(1)[0][0]
                plan.base_frame = base or plan.tf_child
                plan.base_offset = self._base_offset(plan, plan.tf_child, "odometry frame's child")
        if plan.odometry == "none":
            plan.base_frame = self._guess_base_frame(plan, dynamic, odom_frame, first_scan_frame)
        return plan

    def _base_offset(self, plan: _Plan, child: str, what: str) -> NDArray[np.float64] | None:
        """Static transform from the odometry child frame to the chosen base frame."""
        if plan.base_frame == child:
            return None
        m = plan.tree.lookup(child, plan.base_frame) if plan.base_frame in plan.tree else None
        if m is None:
            raise InputError(
                f"base frame {plan.base_frame!r} is not linked by static transforms to {child!r} "
                f"(the {what})",
                path=self.path,
                field="base_frame",
            )
        return m

    def _guess_base_frame(
        self, plan: _Plan, dynamic: dict[tuple[str, str], Any], odom_frame: str, laser: str | None
    ) -> str:
        if self.options.base_frame:
            return _frame(self.options.base_frame)
        for parent, child in dynamic:
            if parent == odom_frame:
                return child
        for name in ("base_link", "base_footprint"):
            if name in plan.tree:
                return name
        if laser and laser in plan.tree:
            return plan.tree.root(laser)
        return "base_link"

    def _decode_quiet(self, raw: bytes, topic: str) -> Any:
        """Decode during discovery; a corrupt message is left for the main pass to report."""
        try:
            store = self._store(self._backend.topics[topic].msgtype, topic)
            msgtype = self._backend.topics[topic].msgtype
            if self._backend.ros_version == 1:
                return store.deserialize_ros1(raw, msgtype)
            return store.deserialize_cdr(raw, msgtype)
        except Exception:  # noqa: BLE001
            return None

    def _mount(self, laser_frame: str) -> tuple[NDArray[np.float64], bool]:
        """Laser pose on the base ``[x, y, yaw]`` and whether it is upside down."""
        cached = self._mounts.get(laser_frame)
        if cached is not None:
            return cached
        plan = self._plan()
        result = (np.zeros(3), False)
        if laser_frame and laser_frame != plan.base_frame:
            m = plan.tree.lookup(plan.base_frame, laser_frame)
            if m is None:
                if plan.odometry == "tf" or plan.has_static_tf:
                    self.problems.add(
                        "no static transform to the laser; laser assumed at the base origin",
                        f"{plan.base_frame} -> {laser_frame} not found in /tf_static",
                    )
            else:
                result = _mount_of(m)
        self._mounts[laser_frame] = result
        return result

    # -- the stream -----------------------------------------------------------------------------------

    def messages(self, progress: ProgressCallback | None = None) -> Iterator[Message]:
        """Scans and odometry readings in bag time order, cleaned, in constant memory."""
        plan = self._plan()
        topics = [self.scan_topic]
        if plan.odometry == "odom" and self.odom_topic:
            topics.append(self.odom_topic)
        if plan.odometry == "tf" and self.tf_topic:
            topics.append(self.tf_topic)
        total = sum(self._backend.topics[t].count for t in topics)
        check = self.timestamp_check()
        index: Counter[str] = Counter()
        done = 0
        odom_source = (
            self.odom_topic
            if plan.odometry == "odom"
            else f"{self.tf_topic} {plan.odom_frame}->{plan.base_frame}"
        )
        for topic, time_ns, raw in self._backend.read(topics):
            done += 1
            if progress is not None and done % _PROGRESS_EVERY == 0:
                progress(done, max(total, done))
            index[topic] += 1
            i = index[topic]
            msg = self._decode(raw, topic, i)
            if msg is None:
                continue
            if topic == self.scan_topic:
                scan = self._scan(msg, topic, i, time_ns, check)
                if scan is not None:
                    yield scan
            elif topic == self.odom_topic:
                reading = self._odometry(msg, topic, i, time_ns, check, odom_source or "")
                if reading is not None:
                    yield reading
            else:
                for ts in msg.transforms:
                    if (
                        _frame(ts.header.frame_id) == plan.odom_frame
                        and _frame(ts.child_frame_id) == plan.tf_child
                    ):
                        reading = self._tf_odometry(ts, topic, i, time_ns, check, odom_source)
                        if reading is not None:
                            yield reading
        if progress is not None:
            progress(done, max(total, done))
        # Every full pass meets the same problems: report those of the first one, not their sum.
        if self._pass_baseline is None:
            self._pass_baseline = self.problems.snapshot()
        else:
            self.problems.restore(self._pass_baseline)

    def _time(self, stamp: Any, time_ns: int, topic: str, i: int) -> float:
        if _is_zero_stamp(stamp) and time_ns != 0:
            self.problems.add("zero header stamp (bag time used)", f"message {i} on {topic}")
            return time_ns // 1_000_000_000 + (time_ns % 1_000_000_000) * 1e-9
        return _stamp_seconds(stamp)

    def _scan(self, msg: Any, topic: str, i: int, time_ns: int, check: Any) -> LaserScan | None:
        where = f"message {i} on {topic}"
        t = self._time(msg.header.stamp, time_ns, topic, i)
        if not check.scan(t, where, "header.stamp"):
            return None
        frame_id = _frame(msg.header.frame_id)
        mount, upside_down = self._mount(frame_id)
        intensities = msg.intensities
        if len(intensities) and len(intensities) != len(msg.ranges):
            self.problems.add(
                "intensities count differs from ranges (intensities dropped)",
                f"{where}: {len(intensities)} intensities for {len(msg.ranges)} ranges",
            )
            intensities = None
        try:
            return make_scan(
                t,
                msg.ranges,
                msg.angle_min,
                msg.angle_increment,
                self.range_min(msg.range_min),
                self.range_max(msg.range_max),
                mount=mount,
                intensities=intensities if intensities is not None and len(intensities) else None,
                upside_down=upside_down,
                frame_id=frame_id,
            )
        except ValueError as exc:
            field_name, _, why = str(exc).partition(": ")
            return self._bad_record(why or str(exc), topic, i, field_name if why else "data")

    def _odometry(
        self, msg: Any, topic: str, i: int, time_ns: int, check: Any, source: str
    ) -> OdometryReading | None:
        plan = self._plan()
        where = f"message {i} on {topic}"
        t = self._time(msg.header.stamp, time_ns, topic, i)
        if not check.odometry(t, where, "header.stamp"):
            return None
        pose = msg.pose.pose
        p = pose.position
        q = pose.orientation
        if plan.base_offset is None:
            xy_yaw = np.array([p.x, p.y, float(se2.quaternion_to_yaw([q.x, q.y, q.z, q.w]))])
        else:
            try:
                m = np.eye(4)
                m[:3, :3] = _quat_matrix(q)
                m[:3, 3] = (p.x, p.y, p.z)
            except ValueError:
                return self._bad_record(
                    "orientation is not a valid quaternion", topic, i, "pose.pose.orientation"
                )
            xy_yaw = _planar(m @ plan.base_offset)
        problem = pose_problem(xy_yaw)
        if problem:
            return self._bad_record(f"pose {problem}", topic, i, "pose.pose")
        return OdometryReading(t, xy_yaw, source)

    def _tf_odometry(
        self, ts: Any, topic: str, i: int, time_ns: int, check: Any, source: str
    ) -> OdometryReading | None:
        plan = self._plan()
        where = f"message {i} on {topic}"
        t = self._time(ts.header.stamp, time_ns, topic, i)
        if not check.odometry(t, where, "transforms.header.stamp"):
            return None
        tr = ts.transform.translation
        q = ts.transform.rotation
        if plan.base_offset is None:
            xy_yaw = np.array([tr.x, tr.y, float(se2.quaternion_to_yaw([q.x, q.y, q.z, q.w]))])
        else:
            try:
                xy_yaw = _planar(_transform_matrix(ts.transform) @ plan.base_offset)
            except ValueError as exc:
                return self._bad_record(str(exc), topic, i, "transforms.transform")
        problem = pose_problem(xy_yaw)
        if problem:
            return self._bad_record(f"transform {problem}", topic, i, "transforms.transform")
        return OdometryReading(t, xy_yaw, source)


# -- the writer ------------------------------------------------------------------------------------------


def _split_stamp(t: float, where: str, path: Path) -> tuple[int, int]:
    """Seconds -> (sec, nanosec), rounding to the nearest nanosecond."""
    if not (math.isfinite(t) and t >= 0.0):
        raise InputError(
            f"{t} is not a time a bag can store (finite, >= 0)", path=path, where=where, field="timestamp"
        )
    sec = math.floor(t)
    nsec = round((t - sec) * 1e9)  # t - floor(t) is exact in floating point
    if nsec >= 1_000_000_000:
        sec, nsec = sec + 1, nsec - 1_000_000_000
    if sec >= 2**32 - 1:
        raise InputError(f"{t} is past the year 2106", path=path, where=where, field="timestamp")
    return sec, nsec


class _BagWriter:
    """Serialises scans and odometry into one open rosbags writer."""

    def __init__(
        self,
        target: Path,
        user_path: Path,
        version: str,
        storage: str,
        topics: dict[str, str],
        frames: dict[str, str],
        write_tf: bool,
        scan_timing: tuple[float, float] = (0.0, 0.0),
    ) -> None:
        self.user_path = user_path
        self.ros1 = version == "ros1"
        self.store = _typestore(1 if self.ros1 else 2)
        self.types = self.store.types
        self.topics = topics
        self.frames = frames
        self.write_tf = write_tf
        self.scan_timing = scan_timing  # LaserScan scan_time, time_increment (s); 0: unknown
        if self.ros1:
            from rosbags.rosbag1 import Writer as Writer1

            self.writer: Any = Writer1(target)
        else:
            from rosbags.rosbag2 import StoragePlugin, Writer as Writer2

            plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
            # Version 8 metadata: the newest that ROS 2 Humble and later all read.
            self.writer = Writer2(target, version=8, storage_plugin=plugin)
        self.writer.open()
        self.connections: dict[str, Any] = {}
        self.mount: NDArray[np.float64] | None = None
        self.earliest_ns: int | None = None
        self.seq = 0

    def close(self) -> None:
        self.writer.close()

    def abort(self) -> None:
        try:
            self.writer.abort()
        except Exception:  # noqa: BLE001 - the temporary output is deleted anyway
            pass

    def _connection(self, topic: str, msgtype: str, latched: bool = False) -> Any:
        conn = self.connections.get(topic)
        if conn is None:
            if self.ros1:
                conn = self.writer.add_connection(
                    topic, msgtype, typestore=self.store, callerid="/slam2d", latching=1 if latched else None
                )
            else:
                qos: list[Any] = []
                if latched:
                    from rosbags.interfaces import (
                        Qos,
                        QosDurability,
                        QosHistory,
                        QosLiveliness,
                        QosReliability,
                        QosTime,
                    )

                    qos = [
                        Qos(
                            QosHistory.KEEP_LAST,
                            1,
                            QosReliability.RELIABLE,
                            QosDurability.TRANSIENT_LOCAL,
                            QosTime(0, 0),
                            QosTime(0, 0),
                            QosLiveliness.AUTOMATIC,
                            QosTime(0, 0),
                            False,
                        )
                    ]
                conn = self.writer.add_connection(
                    topic, msgtype, typestore=self.store, offered_qos_profiles=qos
                )
            self.connections[topic] = conn
        return conn

    def _write(self, topic: str, msgtype: str, msg: Any, time_ns: int, latched: bool = False) -> None:
        conn = self._connection(topic, msgtype, latched)
        data = (
            self.store.serialize_ros1(msg, msgtype) if self.ros1 else self.store.serialize_cdr(msg, msgtype)
        )
        self.writer.write(conn, time_ns, data)

    def _header(self, sec: int, nsec: int, frame_id: str) -> Any:
        stamp = self.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec)
        if self.ros1:
            self.seq += 1
            return self.types["std_msgs/msg/Header"](seq=self.seq, stamp=stamp, frame_id=frame_id)
        return self.types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id)

    def _transform(self, sec: int, nsec: int, parent: str, child: str, pose: NDArray[np.float64]) -> Any:
        t = self.types
        q = se2.yaw_to_quaternion(pose[2])
        return t["geometry_msgs/msg/TransformStamped"](
            header=self._header(sec, nsec, parent),
            child_frame_id=child,
            transform=t["geometry_msgs/msg/Transform"](
                translation=t["geometry_msgs/msg/Vector3"](x=float(pose[0]), y=float(pose[1]), z=0.0),
                rotation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=float(q[2]), w=float(q[3])),
            ),
        )

    def _note_time(self, time_ns: int) -> None:
        if self.earliest_ns is None or time_ns < self.earliest_ns:
            self.earliest_ns = time_ns

    def scan(self, scan: LaserScan, where: str) -> None:
        sec, nsec = _split_stamp(scan.timestamp, where, self.user_path)
        time_ns = sec * 1_000_000_000 + nsec
        self._note_time(time_ns)
        mount = np.asarray(scan.mount, dtype=np.float64)
        if self.mount is None:
            self.mount = mount.copy()
            if self.write_tf:
                # Stamped at the earliest time written so far, so readers that go
                # by bag time meet the laser mount before the first scan.
                assert self.earliest_ns is not None
                s0, n0 = divmod(self.earliest_ns, 1_000_000_000)
                tf = self._transform(s0, n0, self.frames["base"], self.frames["laser"], mount)
                self._write(
                    "/tf_static",
                    TF_TYPE,
                    self.types[TF_TYPE](transforms=[tf]),
                    self.earliest_ns,
                    latched=True,
                )
        elif not np.allclose(mount, self.mount, rtol=0.0, atol=_MOUNT_TOLERANCE):
            raise InputError(
                f"laser mount {mount.tolist()} differs from the first scan's {self.mount.tolist()}; "
                "a bag holds one static laser mount",
                path=self.user_path,
                where=where,
                field="mount",
            )
        ranges = np.where(np.isnan(scan.ranges), np.inf, scan.ranges).astype(np.float32)  # REP 117
        intensities = (
            np.asarray(scan.intensities, dtype=np.float32)
            if scan.intensities is not None
            else np.zeros(0, dtype=np.float32)
        )
        msg = self.types[SCAN_TYPE](
            header=self._header(sec, nsec, self.frames["laser"]),
            angle_min=float(scan.angle_min),
            angle_max=float(scan.angle_max),
            angle_increment=float(scan.angle_increment),
            time_increment=self.scan_timing[1],
            scan_time=self.scan_timing[0],
            range_min=float(scan.range_min),
            range_max=float(scan.range_max),
            ranges=ranges,
            intensities=intensities,
        )
        self._write(self.topics["scan"], SCAN_TYPE, msg, time_ns)

    def odometry(self, reading: OdometryReading, where: str) -> None:
        t = reading.timestamp
        pose = np.asarray(reading.pose, dtype=np.float64)
        if pose.shape != (3,) or not np.all(np.isfinite(pose)):
            raise InputError(
                f"{pose.tolist()} is not a finite pose [x, y, theta]",
                path=self.user_path,
                where=where,
                field="pose",
            )
        sec, nsec = _split_stamp(t, where, self.user_path)
        time_ns = sec * 1_000_000_000 + nsec
        self._note_time(time_ns)
        ty = self.types
        q = se2.yaw_to_quaternion(pose[2])
        twist = np.zeros(3) if reading.twist is None else np.asarray(reading.twist, dtype=np.float64)
        # 6x6 row-major (x, y, z, roll, pitch, yaw): the planar variances on x, y and yaw; zeros: unknown
        pose_cov, twist_cov = np.zeros(36, dtype=np.float64), np.zeros(36, dtype=np.float64)
        for cov, var in ((pose_cov, reading.pose_variance), (twist_cov, reading.twist_variance)):
            if var is not None:
                cov[[0, 7, 35]] = np.asarray(var, dtype=np.float64)
        vec3 = ty["geometry_msgs/msg/Vector3"]
        msg = ty[ODOMETRY_TYPE](
            header=self._header(sec, nsec, self.frames["odom"]),
            child_frame_id=self.frames["base"],
            pose=ty["geometry_msgs/msg/PoseWithCovariance"](
                pose=ty["geometry_msgs/msg/Pose"](
                    position=ty["geometry_msgs/msg/Point"](x=float(pose[0]), y=float(pose[1]), z=0.0),
                    orientation=ty["geometry_msgs/msg/Quaternion"](
                        x=0.0, y=0.0, z=float(q[2]), w=float(q[3])
                    ),
                ),
                covariance=pose_cov,
            ),
            twist=ty["geometry_msgs/msg/TwistWithCovariance"](
                twist=ty["geometry_msgs/msg/Twist"](linear=vec3(x=float(twist[0]), y=float(twist[1]), z=0.0),
                                                    angular=vec3(x=0.0, y=0.0, z=float(twist[2]))),
                covariance=twist_cov,
            ),
        )
        self._write(self.topics["odom"], ODOMETRY_TYPE, msg, time_ns)
        if self.write_tf:
            tf = self._transform(sec, nsec, self.frames["odom"], self.frames["base"], pose)
            self._write("/tf", TF_TYPE, ty[TF_TYPE](transforms=[tf]), time_ns)


def write_rosbag(
    path: str | Path,
    frames_or_messages: Iterable[Frame | LaserScan | OdometryReading],
    *,
    version: str = "ros2",
    storage: str = "sqlite3",
    scan_topic: str = "/scan",
    odom_topic: str = "/odom",
    odom_frame: str = "odom",
    base_frame: str = "base_link",
    laser_frame: str = "laser",
    write_tf: bool = True,
    scan_time: float = 0.0,
    time_increment: float = 0.0,
) -> Path:
    """Write scans and odometry as a ROS bag; returns ``path``.

    ``version="ros2"`` writes a ROS 2 bag folder (``storage`` "sqlite3" or
    "mcap"), ``version="ros1"`` a ROS 1 bag v2.0 file. The input is streamed:
    :class:`~slam2d.core.frames.Frame` objects (a scan plus the odometry pose
    at its time) or :class:`LaserScan` / :class:`OdometryReading` messages.

    Written topics: ``scan_topic`` (sensor_msgs/LaserScan, float32 ranges with
    "no return" as +inf per REP 117, intensities when present), ``odom_topic``
    (nav_msgs/Odometry, zero covariance), and with ``write_tf`` ``/tf`` (one
    ``odom_frame -> base_frame`` transform per odometry reading) and
    ``/tf_static`` (``base_frame -> laser_frame`` from the first scan's mount,
    latched). All scans must share that mount. Each message's bag time is its
    header stamp. The output appears complete or not at all.
    """
    out = Path(path)
    if version not in ("ros1", "ros2"):
        raise InputError(f"unknown bag version {version!r}; use ros1 or ros2", path=out, field="version")
    if version == "ros2" and storage not in ("sqlite3", "mcap"):
        raise InputError(f"unknown ROS 2 storage {storage!r}; use sqlite3 or mcap", path=out, field="storage")
    topics = {"scan": scan_topic, "odom": odom_topic}
    frames = {"odom": odom_frame, "base": base_frame, "laser": laser_frame}
    with atomic_path(out) as tmp:
        if version == "ros2":
            # rosbag2 names the storage file after its folder and records that
            # name in the metadata, so write under the final name inside the
            # temporary folder and lift the files out once complete.
            tmp.mkdir()
            target = tmp / (out.name or "bag")
        else:
            target = tmp
        for name, value in (("scan_time", scan_time), ("time_increment", time_increment)):
            if not (math.isfinite(value) and value >= 0.0):
                raise InputError(f"{value} must be a finite time >= 0", path=out, field=name)
        writer = _BagWriter(target, out, version, storage, topics, frames, write_tf,
                            (float(scan_time), float(time_increment)))
        try:
            for k, item in enumerate(frames_or_messages):
                where = f"item {k}"
                if isinstance(item, Frame):
                    writer.scan(item.scan, where)
                    if item.odometry is not None:
                        writer.odometry(OdometryReading(item.scan.timestamp, item.odometry), where)
                elif isinstance(item, LaserScan):
                    writer.scan(item, where)
                elif isinstance(item, OdometryReading):
                    writer.odometry(item, where)
                else:
                    raise InputError(
                        f"cannot write a {type(item).__name__}; expected Frame, LaserScan or OdometryReading",
                        path=out,
                        where=where,
                    )
            writer.close()
        except BaseException:
            writer.abort()
            raise
        if target != tmp:
            for item_path in target.iterdir():
                item_path.rename(tmp / item_path.name)
            target.rmdir()
    return out
