"""``slam2d ros METHOD``: a method as a ROS 1 node that drops into a slam_gmapping launch file.

In: ``scan`` (sensor_msgs/LaserScan); odometry from tf (``odom_frame`` -> ``base_frame``, looked up
at each scan's stamp, waiting up to ``transform_timeout``); the laser's mount from tf
(``base_frame`` -> the scan's frame). Out: ``map`` and ``map_metadata`` (latched, every
``map_update_interval``), tf ``map_frame`` -> ``odom_frame`` (every ``transform_publish_period``,
stamped that far ahead as slam_gmapping does), ``~pose``, ``~diagnostics``; services ``dynamic_map``
and ``~save``. On shutdown (SIGINT) with ``~output`` set, the run folder is written, as
``slam2d run`` writes it.

Threads: the scan callback only queues the message (bounded: the oldest is dropped and counted); one
worker takes scans from the queue, looks their odometry up and feeds the method, so a slow update
never blocks the callbacks. The ROS-free parts (message conversion, the queue, the map message) are
plain functions the tests call without a ROS master.
"""

from __future__ import annotations

import dataclasses
import math
import threading
import time
from collections import deque
from dataclasses import dataclass, fields
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slam2d.core import se2
from slam2d.core.frames import Frame
from slam2d.core.scan import LaserScan, make_scan
from slam2d.errors import InputError
from slam2d.io.session import SessionRecorder
from slam2d.localization.localizer import map_anchor
from slam2d.io.rosbag import planar_transform  # tf as the bag reader reads it: (x, y, yaw), upside down
from slam2d.params import param

__all__ = ["NodeParams", "ScanQueue", "scan_from_message", "planar_transform", "map_to_odom", "grid_message_fields",
           "run_node"]


@dataclass
class NodeParams:
    """The node's own ROS parameters (private: ``_map_frame:=world``), as slam_gmapping names them."""

    base_frame: str = param("base_link", help="the robot's tf frame")
    odom_frame: str = param("odom", help="the odometry's tf frame (odom_frame -> base_frame gives the odometry)")
    map_frame: str = param("map", help="the frame the node publishes the map in (map_frame -> odom_frame)")
    map_update_interval: float = param(5.0, unit="s", low=0.0, help="how often the map is published")
    transform_publish_period: float = param(
        0.05, unit="s", low=0.0,
        help="how often map_frame -> odom_frame is published, stamped this far ahead (0: never)")
    transform_timeout: float = param(0.2, unit="s", low=0.0, help="how long to wait for a scan's odometry in tf")
    output: str = param("", help="run folder written on shutdown and by ~save (empty: none)")
    queue_size: int = param(100, low=1, help="scans queued while the method works; beyond, the oldest is dropped")
    mode: str = param("mapping", choices=("mapping", "localization"),
                      help="mapping: the method maps; localization: localize in ~session's map, which stays fixed")
    session: str = param("", help="a run folder to start from: mapping goes on in its map (its session/), "
                                   "localization localizes in its map (or a map_server YAML)")


#: ROS-only parameters a node takes (slam_gmapping's) that slam2d's node has no use for: accepted, ignored
_IGNORED = ("throttle_scans", "tf_delay", "use_sim_time", "scan_topic")
# with ~session: the live scans kept until the robot is found in the saved map (then traced back and mapped); a
# search that takes longer maps only the last of them (5 minutes of a 10 Hz laser)
_WAITING_SCANS = 3000


class TfFeed:
    """tf's listener, minus its race with a replayed bag.

    tf2_ros's listener clears its buffer when ROS time (``/clock``) jumps back, and ``/clock`` arrives
    on its own connection: the first transforms of a replay could land before the clear and be lost
    with it, and the first scan of the new map skipped. Here the buffer is cleared when the
    transforms' own stamps jump back (by more than a second), just before the first of them is stored.
    The node's own broadcasts (map -> odom) are not stored: its lookups never need them, and their
    stamps follow ``/clock``, not the bag.
    """

    def __init__(self, rospy: Any, buffer: Any) -> None:
        from tf2_msgs.msg import TFMessage

        self.buffer, self.own_name = buffer, rospy.get_name()
        self.latest: float | None = None
        self.static: dict[str, tuple[Any, str]] = {}  # child frame -> (transform, authority): put back after a clear
        self.lock = threading.Lock()
        self.clears = 0
        rospy.Subscriber("/tf", TFMessage, self._dynamic, queue_size=100, buff_size=1 << 20)
        rospy.Subscriber("/tf_static", TFMessage, self._static, queue_size=100, buff_size=1 << 20)

    def _dynamic(self, msg: Any) -> None:
        who = msg._connection_header.get("callerid", "default_authority")
        if who == self.own_name or not msg.transforms:
            return
        newest = max(t.header.stamp.to_sec() for t in msg.transforms)
        with self.lock:
            if self.latest is not None and newest < self.latest - 1.0:
                self.buffer.clear()
                self.clears += 1
                for transform, authority in self.static.values():
                    self.buffer.set_transform_static(transform, authority)
                self.latest = None
            self.latest = newest if self.latest is None else max(self.latest, newest)
            for transform in msg.transforms:
                self.buffer.set_transform(transform, who)

    def _static(self, msg: Any) -> None:
        who = msg._connection_header.get("callerid", "default_authority")
        with self.lock:
            for transform in msg.transforms:
                self.static[transform.child_frame_id] = (transform, who)
                self.buffer.set_transform_static(transform, who)


class ScanQueue:
    """A bounded queue between the callback and the worker: the oldest is dropped (and counted) when full."""

    def __init__(self, size: int) -> None:
        self._items: deque[Any] = deque()
        self._size = int(size)
        self._ready = threading.Condition()
        self.dropped = 0
        self.closed = False

    def put(self, item: Any) -> None:
        with self._ready:
            if len(self._items) >= self._size:
                self._items.popleft()
                self.dropped += 1
            self._items.append(item)
            self._ready.notify()

    def get(self, timeout: float) -> Any | None:
        """The oldest item, or None after ``timeout`` seconds (or at once when closed and empty)."""
        with self._ready:
            if not self._items and not self.closed:
                self._ready.wait(timeout)
            return self._items.popleft() if self._items else None

    def close(self) -> None:
        with self._ready:
            self.closed = True
            self._ready.notify_all()

    def __len__(self) -> int:
        return len(self._items)


def scan_from_message(msg: Any, mount: NDArray[np.float64], upside_down: bool = False) -> LaserScan:
    """A sensor_msgs/LaserScan message as slam2d's scan (raises ``ValueError`` naming the bad field)."""
    stamp = msg.header.stamp
    t = float(stamp.secs) + 1e-9 * float(stamp.nsecs)
    intensities = msg.intensities if len(msg.intensities) == len(msg.ranges) and len(msg.intensities) else None
    return make_scan(t, msg.ranges, msg.angle_min, msg.angle_increment, msg.range_min, msg.range_max,
                     mount=mount, intensities=intensities, upside_down=upside_down,
                     frame_id=msg.header.frame_id.lstrip("/"))


def map_to_odom(pose: NDArray[np.float64], odometry: NDArray[np.float64]) -> NDArray[np.float64]:
    """The map -> odom transform that puts the odometry's pose at the method's: ``pose * odometry^-1``."""
    return se2.compose(pose, se2.inverse(odometry))


def grid_message_fields(grid: Any) -> dict[str, Any]:
    """What a nav_msgs/OccupancyGrid needs from slam2d's grid: size, resolution, origin and row-major data."""
    rows, cols = grid.shape
    ox, oy = grid.origin
    return {"width": int(cols), "height": int(rows), "resolution": float(grid.resolution), "origin": (ox, oy),
            "data": grid.occupancy().reshape(-1)}


class _Node:
    """The rospy side: subscriptions, publishers, services, the worker thread."""

    def __init__(self, rospy: Any, method: str, build: dict[str, Any], node: NodeParams, command: str) -> None:
        import tf2_ros
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import PoseWithCovarianceStamped
        from nav_msgs.msg import MapMetaData, OccupancyGrid
        from nav_msgs.srv import GetMap
        from sensor_msgs.msg import LaserScan as LaserScanMsg
        from std_srvs.srv import Trigger

        self.rospy = rospy
        self.method_name, self.build, self.p, self.command = method, build, node, command
        self.counts = {"scans_without_tf": 0, "scans_other_beam_count": 0, "resets": 0, "scans_out_of_order": 0}
        self.localizer: Any = None
        self.localization_log: Any = None
        self.placing: Any = None  # with ~session while mapping: where the live scans start in its map
        self.holding: Any = None  # then the same localization, going on: where it places each scan (map anchors)
        self.session = SessionRecorder()
        self.replayed, self.shift, self.session_last_t = 0, 0.0, None
        if node.mode == "localization":
            from slam2d.io.map_server import load_map_grid
            from slam2d.localization.run import LocalizationLog

            if not node.session:
                raise InputError("localization needs a map: a run folder or a map_server YAML", field="~session")
            self.map_grid, self.map_path = load_map_grid(node.session)
            self.localizer = self._new_localizer()
            self.localization_log = LocalizationLog()
            self.needs_odometry = True
        else:
            self._start_mapping()
            self.needs_odometry = self.slam._uses_odometry_now()
        self.queue = ScanQueue(node.queue_size)
        self.lock = threading.Lock()  # the method and what the timers read of it
        self.tf_buffer = tf2_ros.Buffer(rospy.Duration(30.0))
        self.tf_feed = TfFeed(rospy, self.tf_buffer)
        self.tf_broadcaster = tf2_ros.TransformBroadcaster()
        self.map_pub = rospy.Publisher("map", OccupancyGrid, queue_size=1, latch=True)
        self.meta_pub = rospy.Publisher("map_metadata", MapMetaData, queue_size=1, latch=True)
        self.pose_pub = rospy.Publisher("~pose", PoseWithCovarianceStamped, queue_size=10)
        self.diag_pub = rospy.Publisher("~diagnostics", DiagnosticArray, queue_size=10)
        self.map_msg: Any = None
        self.mounts: dict[str, tuple[NDArray[np.float64], bool]] = {}
        # (map -> odom, "odom"), or (map -> base, "base_link") without odometry in tf; None until the first pose
        self.tf_state: tuple[NDArray[np.float64] | None, str] = (None, node.odom_frame)
        self.last_tf_stamp: Any = None
        self.frames = 0
        self.beams: int | None = None
        self.first_t: float | None = None
        self.last_t: float | None = None
        self.last_map_wall = -math.inf
        self.last_scan_wall = time.monotonic()
        self.warned_silence = False
        self.started = datetime.now(timezone.utc)
        self.busy_s = 0.0
        self.latency: list[float] = []
        rospy.Service("dynamic_map", GetMap, self._dynamic_map)
        rospy.Service("~save", Trigger, self._save_service)
        rospy.Subscriber("scan", LaserScanMsg, self._on_scan, queue_size=max(10, node.queue_size))
        if self.localizer is not None or self.placing is not None:
            rospy.Subscriber("initialpose", PoseWithCovarianceStamped, self._on_initial_pose, queue_size=1)
        if self.localizer is not None:
            self.map_msg = self._map_message()  # the fixed map, latched once
            self.map_pub.publish(self.map_msg)
            self.meta_pub.publish(self.map_msg.info)
        if node.transform_publish_period > 0:
            rospy.Timer(rospy.Duration(node.transform_publish_period), self._publish_transform)
        # on the wall clock: under use_sim_time with no /clock yet (no bag playing), ROS time stands still
        threading.Thread(target=self._watch_silence, name="slam2d-silence", daemon=True).start()
        self.worker = threading.Thread(target=self._work, name="slam2d-worker", daemon=True)
        self.worker.start()

    # -- callbacks ------------------------------------------------------------------------------------

    def _on_scan(self, msg: Any) -> None:
        self.last_scan_wall = time.monotonic()
        self.queue.put((msg, time.monotonic()))

    def _start_mapping(self) -> None:
        """The method, new; or with ``~session`` rebuilt from that run's session, to be put down where the
        first live scans are found in its map (as ``slam2d run --resume``)."""
        from slam2d.methods.runner import build_method

        self.session = SessionRecorder()  # the frames fed: the run folder's session/
        self.placing: Any = None
        self.holding: Any = None
        # with ~session: the live scans (and odometry) until they are placed
        self.waiting: deque[tuple[LaserScan, Any]] = deque(maxlen=_WAITING_SCANS)
        self.replayed, self.shift, self.session_last_t = 0, 0.0, None
        if not self.p.session:
            self.slam = build_method(self.method_name, **self.build)
            return
        from slam2d import __version__
        from slam2d.io.session import read_session
        from slam2d.localization.localizer import LocalizationParams, Localizer
        from slam2d.io.map_server import load_map_grid
        from slam2d.methods.runner import replay_session

        saved = read_session(self.p.session, version=__version__, method=self.method_name)
        self.slam = build_method(self.method_name, settings=saved.record["params"], seed=int(saved.record["seed"]))
        if not self.slam.can_relocate():
            raise InputError(f"{self.method_name} cannot go on from a saved session", field="~session")
        self.replayed, self.session_last_t = replay_session(self.slam, saved, self.session)
        self.map_grid, self.map_path = load_map_grid(self.p.session)
        self.placing = Localizer(self.map_grid, LocalizationParams(method="match"), seed=self.slam.seed)
        self.counts["scans_before_placed"] = 0

    def _new_localizer(self, initial_pose: Any = None) -> Any:
        from slam2d.localization.localizer import LocalizationParams, Localizer
        from slam2d.params import from_mapping

        params = from_mapping(LocalizationParams, self.build.get("settings") or {})
        return Localizer(self.map_grid, params, seed=int(self.build.get("seed") or 0), initial_pose=initial_pose)

    def _on_initial_pose(self, msg: Any) -> None:
        """RViz's "2D Pose Estimate": search again around it (in the map's frame)."""
        from slam2d.core.se2 import quaternion_to_yaw

        q = msg.pose.pose.orientation
        pose = np.array([msg.pose.pose.position.x, msg.pose.pose.position.y,
                         float(quaternion_to_yaw([q.x, q.y, q.z, q.w]))])
        with self.lock:
            target = self.localizer if self.localizer is not None else self.placing
            if target is None:
                self.rospy.logwarn("slam2d: an initial pose while mapping: ignored (the method places the robot)")
                return
            target.restart(pose, t=msg.header.stamp.to_sec())
            self.tf_state = (None, self.p.odom_frame)
        self.rospy.loginfo(f"slam2d: initial pose ({pose[0]:.2f}, {pose[1]:.2f}, {pose[2]:.2f}): searching there")

    def _watch_silence(self) -> None:
        while not self.rospy.is_shutdown() and not self.warned_silence:
            time.sleep(1.0)
            if time.monotonic() - self.last_scan_wall > 10.0:
                self.warned_silence = True
                self.rospy.logwarn("slam2d: no scan for 10 s on %s: is a laser publishing it?",
                                   self.rospy.resolve_name("scan"))

    def _publish_transform(self, _event: Any) -> None:
        from geometry_msgs.msg import TransformStamped

        # no lock: a map being drawn must not hold tf back; one tuple is read whole
        correction, child = self.tf_state
        stamp = self.rospy.Time.now() + self.rospy.Duration(self.p.transform_publish_period)
        if correction is None or (self.last_tf_stamp is not None and stamp <= self.last_tf_stamp):
            return  # nothing yet, or the clock stood still (a paused bag): tf refuses a repeated stamp
        self.last_tf_stamp = stamp
        t = TransformStamped()
        # stamped one period ahead, as slam_gmapping does: tf users at "now" need not wait for the next one
        t.header.stamp = stamp
        t.header.frame_id = self.p.map_frame
        t.child_frame_id = child
        _fill_transform(t.transform, correction)
        self.tf_broadcaster.sendTransform(t)

    def _dynamic_map(self, _request: Any) -> Any:
        from nav_msgs.srv import GetMapResponse

        with self.lock:
            if self.map_msg is None and self.frames:
                self.map_msg = self._map_message()
            return GetMapResponse(map=self.map_msg) if self.map_msg is not None else GetMapResponse()

    def _save_service(self, _request: Any) -> Any:
        from std_srvs.srv import TriggerResponse

        if not self.p.output:
            return TriggerResponse(success=False, message="~output is not set: nowhere to write the run folder")
        try:
            with self.lock:
                path = self.save()
        except Exception as exc:  # noqa: BLE001 - a service answers with the reason, the node goes on
            return TriggerResponse(success=False, message=f"{type(exc).__name__}: {exc}")
        return TriggerResponse(success=True, message=str(path))

    # -- the worker -----------------------------------------------------------------------------------

    def _work(self) -> None:
        while not (self.queue.closed and not len(self.queue)):
            item = self.queue.get(0.2)
            if item is None:
                continue
            msg, arrived = item
            try:
                self._process(msg, arrived)
            except Exception as exc:  # noqa: BLE001 - a bad scan is skipped and said, the node lives on
                self.rospy.logerr_throttle(5.0, f"slam2d: scan skipped: {type(exc).__name__}: {exc}")

    def _lookup(self, target: str, source: str, stamp: Any, timeout: float) -> Any:
        import tf2_ros

        # polled on the wall clock: tf2's own wait sleeps on ROS time, which raises when a replay jumps back
        deadline = time.monotonic() + timeout
        while True:
            try:
                return self.tf_buffer.lookup_transform_core(target, source, stamp)
            except (tf2_ros.LookupException, tf2_ros.ConnectivityException, tf2_ros.ExtrapolationException):
                if time.monotonic() >= deadline or self.rospy.is_shutdown():
                    return None
            time.sleep(0.002)

    def _mount(self, frame_id: str, stamp: Any) -> tuple[NDArray[np.float64], bool] | None:
        frame_id = frame_id.lstrip("/")
        if not frame_id or frame_id == self.p.base_frame:
            return np.zeros(3), False
        if frame_id not in self.mounts:
            found = self._lookup(self.p.base_frame, frame_id, stamp, self.p.transform_timeout)
            if found is None:
                return None
            self.mounts[frame_id] = planar_transform(found.transform)
        return self.mounts[frame_id]

    def _process(self, msg: Any, arrived: float) -> None:
        rospy = self.rospy
        stamp = msg.header.stamp
        t = stamp.to_sec()
        if self.last_t is not None and t < self.last_t:
            if t < self.last_t - 1.0:  # time went back: a rosbag play restarted, or a new clock
                rospy.logwarn(f"slam2d: time went back {self.last_t - t:.1f} s: starting a new map")
                self._reset()
            else:
                self.counts["scans_out_of_order"] += 1
                return
        mount = self._mount(msg.header.frame_id, stamp)
        if mount is None:
            self.counts["scans_without_tf"] += 1
            rospy.logwarn_throttle(5.0, f"slam2d: no transform {self.p.base_frame} -> {msg.header.frame_id} at "
                                        f"{t:.3f}: scan skipped ({self.counts['scans_without_tf']} so far)")
            return
        odometry = None
        found = self._lookup(self.p.odom_frame, self.p.base_frame, stamp, self.p.transform_timeout)
        if found is not None:
            odometry = planar_transform(found.transform)[0]
        elif self.needs_odometry:
            self.counts["scans_without_tf"] += 1
            rospy.logwarn_throttle(5.0, f"slam2d: no odometry {self.p.odom_frame} -> {self.p.base_frame} at "
                                        f"{t:.3f}: scan skipped ({self.counts['scans_without_tf']} so far)")
            return
        if self.beams is not None and len(msg.ranges) != self.beams:
            self.counts["scans_other_beam_count"] += 1
            rospy.logwarn_throttle(5.0, f"slam2d: a scan of {len(msg.ranges)} beams after {self.beams}: skipped")
            return
        scan = scan_from_message(msg, *mount)
        if self.localizer is not None:
            self._localize(msg, stamp, t, scan, odometry, arrived)
            return
        started = time.process_time()
        with self.lock:
            backlog: list[tuple[LaserScan, Any]] = []
            anchor = None
            if self.holding is not None:
                anchor = map_anchor(self.holding.feed(Frame(self.frames, scan, odometry)))
            elif self.placing is not None:  # ~session: where in the saved map do the live scans start?
                found = self.placing.feed(Frame(self.frames, scan, odometry))
                if found.pose is None:
                    self.counts["scans_before_placed"] += 1
                    self.waiting.append((scan, odometry))
                    return
                # the scans before it was found, traced back from there along the odometry in the saved map (as
                # `slam2d run --resume` does), are mapped first; without odometry they are left out
                waiting = [Frame(k, w, o) for k, (w, o) in enumerate([*self.waiting, (scan, odometry)])]
                traced = self.placing.traced_back(waiting, found.pose) if len(waiting) > 1 else None
                start = found.pose if traced is None else traced[0]
                if traced is not None:
                    backlog = list(self.waiting)
                    self.counts["scans_before_placed"] -= len(backlog)  # (those the buffer could not hold stay)
                self.waiting.clear()
                self.slam.relocate(start)
                self.session.relocated(start)
                self.placing, self.holding, anchor = None, self.placing, found.pose
                # the method's clock goes on after the session's (a replayed bag starts earlier)
                t0 = backlog[0][0].timestamp if backlog else t
                self.shift = max(0.0, (self.session_last_t or t0) + 0.1 - t0)
                rospy.loginfo("slam2d: found in %s at (%.2f, %.2f, %.2f) after %d scans: mapping on", self.p.session,
                              *found.pose, len(waiting) - 1)
            self.beams = len(msg.ranges)
            for k, (earlier, earlier_odometry) in enumerate([*backlog, (scan, odometry)]):
                if self.shift:
                    earlier = dataclasses.replace(earlier, timestamp=earlier.timestamp + self.shift)
                frame = Frame(self.frames, earlier, earlier_odometry)
                if anchor is not None and k == len(backlog):  # (the backlog's scans were placed by tracing back)
                    self.slam.anchor_to_map(anchor)
                    self.session.anchored(anchor)
                self.session.add(frame)
                self.slam.feed(frame)
                self.frames += 1
            self.first_t = (backlog[0][0].timestamp if backlog else t) if self.first_t is None else self.first_t
            self.last_t = t
            pose = self.slam.current_pose()
            if pose is not None:
                pose = np.asarray(pose, dtype=np.float64)
                if odometry is not None:
                    self.tf_state = (map_to_odom(pose, odometry), self.p.odom_frame)
                else:  # no odometry in tf: the map places the robot itself
                    self.tf_state = (pose, self.p.base_frame)
            self.busy_s += time.process_time() - started
            self.latency.append(time.monotonic() - arrived)
            publish_map = time.monotonic() - self.last_map_wall >= self.p.map_update_interval
            if publish_map:
                self.map_msg = self._map_message()
                self.last_map_wall = time.monotonic()
            values = self.slam.diagnostics.last_values()
        if pose is not None:
            self._publish_pose(stamp, pose)
        if publish_map and self.map_msg is not None:
            self.map_pub.publish(self.map_msg)
            self.meta_pub.publish(self.map_msg.info)
        self._publish_diagnostics(stamp, values)

    def _localize(self, msg: Any, stamp: Any, t: float, scan: LaserScan, odometry: Any, arrived: float) -> None:
        started = time.process_time()
        with self.lock:
            self.beams = len(msg.ranges)
            r = self.localization_log.feed(self.localizer, Frame(self.frames, scan, odometry))
            self.frames += 1
            self.first_t = t if self.first_t is None else self.first_t
            self.last_t = t
            if r.pose is not None:
                self.tf_state = (map_to_odom(np.asarray(r.pose), odometry), self.p.odom_frame)
            self.busy_s += time.process_time() - started
            self.latency.append(time.monotonic() - arrived)
        if r.pose is not None:
            self._publish_pose(stamp, np.asarray(r.pose))
        self._publish_diagnostics(stamp, {"state": r.state, "fit": r.fit, "spread_m": r.spread,
                                          "particles": r.particles})

    def _reset(self) -> None:
        with self.lock:
            if self.localizer is not None:
                self.localizer.restart(t=None)
            else:
                self._start_mapping()
            self.frames, self.first_t, self.last_t, self.beams = 0, None, None, None
            self.tf_state = (None, self.p.odom_frame)
            self.last_tf_stamp = None  # map -> odom goes out again, at the new clock's stamps
            self.counts["resets"] += 1
        # (TfFeed clears the tf buffer itself when the transforms jump back; clearing it here as well could lose
        # the transforms of the scan that showed the jump)

    # -- messages -------------------------------------------------------------------------------------

    def _map_message(self) -> Any:
        from nav_msgs.msg import OccupancyGrid

        fields_ = grid_message_fields(self.map_grid if self.localizer is not None else self.slam.map())
        msg = OccupancyGrid()
        msg.header.stamp = self.rospy.Time.now()
        msg.header.frame_id = self.p.map_frame
        msg.info.map_load_time = msg.header.stamp
        msg.info.resolution = fields_["resolution"]
        msg.info.width, msg.info.height = fields_["width"], fields_["height"]
        msg.info.origin.position.x, msg.info.origin.position.y = fields_["origin"]
        msg.info.origin.orientation.w = 1.0
        msg.data = fields_["data"].tolist()
        return msg

    def _publish_pose(self, stamp: Any, pose: NDArray[np.float64]) -> None:
        from geometry_msgs.msg import PoseWithCovarianceStamped

        msg = PoseWithCovarianceStamped()
        msg.header.stamp = stamp
        msg.header.frame_id = self.p.map_frame
        msg.pose.pose.position.x, msg.pose.pose.position.y = float(pose[0]), float(pose[1])
        _, _, msg.pose.pose.orientation.z, msg.pose.pose.orientation.w = map(float, se2.yaw_to_quaternion(pose[2]))
        self.pose_pub.publish(msg)

    def _publish_diagnostics(self, stamp: Any, values: dict[str, Any]) -> None:
        from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

        status = DiagnosticStatus(name=f"slam2d/{self.method_name}", hardware_id="slam2d")
        status.level = DiagnosticStatus.OK if not self.queue.dropped else DiagnosticStatus.WARN
        status.message = f"{self.frames} scans, {self.queue.dropped} dropped"
        pairs = {**values, **self.counts, "scans_dropped": self.queue.dropped, "scans_queued": len(self.queue)}
        status.values = [KeyValue(key=str(k), value=str(v)) for k, v in pairs.items()]
        array = DiagnosticArray(status=[status])
        array.header.stamp = stamp
        self.diag_pub.publish(array)

    # -- the run folder -------------------------------------------------------------------------------

    def save(self) -> Path:
        """Write the run folder to ``~output`` (the caller holds the lock)."""
        from slam2d.methods.runner import write_live_run

        if self.localizer is not None:
            from slam2d.localization.run import write_localization

            write_localization(Path(self.p.output), self.localization_log, self.localizer, map_path=self.map_path,
                               data={"source": f"ROS topic {self.rospy.resolve_name('scan')}", "format": "ros"},
                               seed=int(self.build.get("seed") or 0), initial_pose=None, command=self.command)
            return Path(self.p.output)
        self.slam.diagnostics.summary.update({
            **{f"live_{k}": v for k, v in self.counts.items()}, "live_scans_dropped": self.queue.dropped,
            "live_latency_median_s": float(np.median(self.latency)) if self.latency else None,
            "live_latency_p95_s": float(np.percentile(self.latency, 95)) if self.latency else None,
        })
        source = f"ROS topic {self.rospy.resolve_name('scan')}"
        slam, extra = self.slam, None
        if self.p.session:  # the live scans' poses alone, at their own times
            from slam2d.methods.runner import OwnTrajectory

            times, poses = self.slam.trajectory()
            slam = OwnTrajectory(self.slam, times[self.replayed:] - self.shift, poses[self.replayed:])
            extra = {"resumed": {"from": str(Path(self.p.session).resolve()), "scans_before_placed":
                                 self.counts.get("scans_before_placed", 0), "time_shift_s": self.shift}}
        write_live_run(slam, Path(self.p.output), source=source, frames=self.frames,
                       span=(self.first_t, self.last_t), started=self.started, seconds=self.busy_s,
                       command=self.command, session=self.session, extra=extra)
        return Path(self.p.output)

    def shutdown(self) -> None:
        """Stop taking scans, finish the queued ones, and write the run folder when ``~output`` is set."""
        self.queue.close()
        self.worker.join()
        if self.p.output and self.frames:
            with self.lock:
                path = self.save()
            print(f"slam2d: wrote the run folder {path}", flush=True)


def _fill_transform(transform: Any, pose: NDArray[np.float64]) -> None:
    transform.translation.x, transform.translation.y, transform.translation.z = float(pose[0]), float(pose[1]), 0.0
    _, _, transform.rotation.z, transform.rotation.w = map(float, se2.yaw_to_quaternion(pose[2]))


def _split_private(private: dict[str, Any], method_fields: set[str],
                   other_methods: dict[str, set[str]] | None = None,
                   ) -> tuple[NodeParams, dict[str, Any], list[str]]:
    """The node's parameters, the method's settings and warnings, from the private ROS parameters.

    A name no method has is a typo and refused. Another method's parameter is ignored with a warning:
    the parameter server keeps a node's private parameters after it exits, so a node started again
    under the same name with another method finds the first one's.
    """
    node_names = {f.name for f in fields(NodeParams)}
    node_values, settings, warnings = {}, {}, []
    for key, value in private.items():
        if key in node_names:
            node_values[key] = value
        elif key in method_fields:
            settings[key] = value
        elif key in _IGNORED:
            continue
        else:
            owners = sorted(m for m, names in (other_methods or {}).items() if key in names)
            if not owners:
                raise InputError(f"unknown parameter: not one of the node's ({', '.join(sorted(node_names))}) "
                                 "or any method's", field=f"~{key}")
            warnings.append(f"~{key} ignored: a parameter of {', '.join(owners)}, not of this method")
    from slam2d.params import from_mapping

    return from_mapping(NodeParams, node_values), settings, warnings


def run_node(method: str, build: dict[str, Any], command: str = "", output: Path | None = None,
             overwrite: bool = False) -> int:
    """Run the node until shutdown; ``build`` as :func:`~slam2d.methods.runner.build_method` takes it
    (``--set`` settings win over the private ROS parameters), ``output`` over ``~output``."""
    import dataclasses

    from slam2d.io.atomic import check_output_folder
    from slam2d.methods import get_method
    from slam2d.ros import import_rospy

    rospy = import_rospy()
    rospy.init_node("slam2d")  # reads the remappings and _private:=parameters of sys.argv
    from slam2d.methods import available

    cls = get_method(method)
    private = rospy.get_param("~", {})
    if private.get("mode") == "localization":  # the settings are the localizer's; the methods' are ignored
        from slam2d.localization.localizer import LocalizationParams

        own = {f.name for f in fields(LocalizationParams)}
        others = {name: {f.name for f in fields(c.Params)} - own for name, c in available().items()}
        build = {**build, "settings": {}}  # (--set was checked against the method, which does not run)
    else:
        own = {f.name for f in fields(cls.Params)}
        others = {name: {f.name for f in fields(c.Params)} for name, c in available().items() if name != cls.name}
    node_params, ros_settings, warnings = _split_private(private, own, others)
    for warning in warnings:
        rospy.logwarn(f"slam2d: {warning}")
    if output is not None:
        node_params = dataclasses.replace(node_params, output=str(output))
    elif node_params.output:
        check_output_folder(node_params.output, "ros", overwrite=overwrite)
    build = {**build, "settings": {**ros_settings, **(build.get("settings") or {})}}
    node = _Node(rospy, method, build, node_params, command)
    what = (f"localizing in {node.map_path}" if node.localizer is not None else method)
    rospy.loginfo(f"slam2d: {what} on {rospy.resolve_name('scan')}, odometry {node_params.odom_frame} -> "
                  f"{node_params.base_frame}, map in {node_params.map_frame}")
    rospy.spin()
    node.shutdown()
    return 0
