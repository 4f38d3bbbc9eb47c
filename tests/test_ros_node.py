"""``slam2d ros``: the node's ROS-free parts, then the node against a real roscore and ``rosbag play``.

The live tests need ROS 1 (Debian's ros-core, python3-rospy, python3-tf2-ros and the message
packages; ``make test`` installs them where apt exists). Without it they skip, unless
``SLAM2D_REQUIRE_ROS=1`` (set by ``make test`` when roscore is there), when they fail.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from slam2d.core import se2
from slam2d.errors import InputError
from slam2d.ros.node import NodeParams, ScanQueue, _split_private, grid_message_fields, map_to_odom, \
    planar_transform, scan_from_message

# --------------------------------------------------------------------------- without ROS


def test_a_full_queue_drops_the_oldest_and_counts_it():
    q = ScanQueue(3)
    for k in range(5):
        q.put(k)
    assert q.dropped == 2 and len(q) == 3
    assert [q.get(0.0) for _ in range(3)] == [2, 3, 4]
    assert q.get(0.01) is None
    q.close()
    assert q.get(10.0) is None  # closed and empty: at once


def _quaternion(yaw):
    return SimpleNamespace(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2))


def test_planar_transform_reads_yaw_and_an_upside_down_laser():
    pose, down = planar_transform(SimpleNamespace(translation=SimpleNamespace(x=1.0, y=-2.0, z=0.3),
                                                  rotation=_quaternion(0.7)))
    np.testing.assert_allclose(pose, [1.0, -2.0, 0.7], atol=1e-12)
    assert not down
    flipped = SimpleNamespace(x=1.0, y=0.0, z=0.0, w=0.0)  # a half turn about x: the laser hangs upside down
    assert planar_transform(SimpleNamespace(translation=SimpleNamespace(x=0.0, y=0.0, z=0.0), rotation=flipped))[1]


def test_map_to_odom_puts_the_odometry_pose_where_the_method_says():
    pose, odometry = np.array([3.0, 1.0, 0.4]), np.array([-1.0, 2.0, -1.1])
    correction = map_to_odom(pose, odometry)
    np.testing.assert_allclose(se2.compose(correction, odometry), pose, atol=1e-12)


def test_map_message_is_row_major_from_the_lower_left_corner():
    from slam2d.grids.occupancy import GridParams, OccupancyGrid

    grid = OccupancyGrid.covering(0.0, 0.0, 1.0, 0.5, GridParams(resolution=0.1))
    grid.integrate_points((0.05, 0.05), np.array([[0.95, 0.05]]))  # a wall at the bottom row's right end
    f = grid_message_fields(grid)
    assert f["data"].shape == (f["width"] * f["height"],) and f["data"].dtype == np.int8
    rows, cols = grid.shape
    occ = grid.occupancy()
    assert (f["width"], f["height"]) == (cols, rows)
    np.testing.assert_array_equal(f["data"].reshape(rows, cols), occ)  # row 0 is the bottom, as in ROS
    ox, oy = f["origin"]
    wall = int((0.05 - oy) / 0.1) * cols + int((0.95 - ox) / 0.1)
    assert f["data"][wall] > 50 and f["data"].max() == f["data"][wall]


def test_private_parameters_split_between_node_and_method_and_typos_are_refused():
    node, settings, warnings = _split_private({"map_frame": "world", "particles": 12, "throttle_scans": 1},
                                              {"particles"})
    assert node.map_frame == "world" and node.base_frame == NodeParams().base_frame
    assert settings == {"particles": 12} and warnings == []
    with pytest.raises(InputError, match="unknown parameter") as err:
        _split_private({"partciles": 12}, {"particles"}, {"karto": {"resolution"}})
    assert err.value.field == "~partciles"
    with pytest.raises(InputError):
        _split_private({"map_update_interval": -1.0}, set())
    # another method's parameter, left on the parameter server by an earlier node of the same name: a warning
    _, settings, warnings = _split_private({"minimum_travel_distance": 0.3}, {"particles"},
                                           {"karto": {"minimum_travel_distance"}})
    assert settings == {} and warnings == ["~minimum_travel_distance ignored: a parameter of karto, not of this method"]


def test_a_scan_message_becomes_a_scan_with_its_mount():
    msg = SimpleNamespace(
        header=SimpleNamespace(stamp=SimpleNamespace(secs=1767225600, nsecs=500_000_000), frame_id="/laser"),
        ranges=[1.0, float("inf"), 2.0], intensities=[], angle_min=-0.1, angle_increment=0.1,
        range_min=0.02, range_max=5.6)
    scan = scan_from_message(msg, np.array([0.1, 0.0, 0.0]))
    assert scan.timestamp == pytest.approx(1767225600.5)
    assert scan.num_beams == 3 and math.isnan(scan.ranges[1]) and scan.frame_id == "laser"
    np.testing.assert_allclose(scan.mount, [0.1, 0.0, 0.0])


# --------------------------------------------------------------------------- against a real roscore


def _ros_or_skip() -> None:
    if shutil.which("roscore") and shutil.which("rosbag"):
        return
    reason = "ROS 1 is not installed (apt-get install ros-core python3-rospy python3-tf2-ros and the messages)"
    if os.environ.get("SLAM2D_REQUIRE_ROS") == "1":
        pytest.fail(f"{reason}; SLAM2D_REQUIRE_ROS=1 requires the live node's tests to run")
    pytest.skip(reason)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def ros(tmp_path_factory):
    """A roscore on a free port with use_sim_time, and the environment that points at it."""
    _ros_or_skip()
    home = tmp_path_factory.mktemp("ros-home")
    port = _free_port()
    env = {**os.environ, "ROS_MASTER_URI": f"http://localhost:{port}", "ROS_HOME": str(home),
           "ROS_LOG_DIR": str(home / "log"), "PYTHONUNBUFFERED": "1"}
    core = subprocess.Popen(["roscore", "-p", str(port)], env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.monotonic() + 30
    while subprocess.run(["rosparam", "set", "/use_sim_time", "true"], env=env, capture_output=True).returncode:
        if time.monotonic() > deadline:
            os.killpg(core.pid, signal.SIGINT)
            pytest.fail("roscore did not start within 30 s")
        time.sleep(0.5)
    yield env
    os.killpg(core.pid, signal.SIGINT)
    try:
        core.wait(timeout=20)
    except subprocess.TimeoutExpired:
        os.killpg(core.pid, signal.SIGKILL)


@pytest.fixture(scope="module")
def office_bag(tmp_path_factory) -> Path:
    from slam2d.cli import main

    out = tmp_path_factory.mktemp("office")
    assert main(["simulate", "office", "--ros1", "--duration", "12", "--out", str(out)]) == 0
    return out / "recording.bag"


# Every `rosbag play` waits 2 s after advertising its topics (-d 2): a subscriber that connects after the first
# messages went out misses them (the node would miss the first scan's tf under load).

# A listener in the system's Python (where rospy is): did /map and tf map -> odom arrive while the bag played?
_LISTENER = """
import json, sys, rospy
from nav_msgs.msg import OccupancyGrid
from tf2_msgs.msg import TFMessage
seen = {"map": 0, "map_to_odom": 0}
def on_map(msg): seen["map"] += 1
def on_tf(msg):
    seen["map_to_odom"] += sum(t.header.frame_id == "map" and t.child_frame_id == "odom" for t in msg.transforms)
rospy.init_node("listener", anonymous=True)
rospy.Subscriber("/map", OccupancyGrid, on_map)
rospy.Subscriber("/tf", TFMessage, on_tf)
open(sys.argv[1] + ".ready", "w").close()
while not rospy.is_shutdown():
    json.dump(seen, open(sys.argv[1], "w"))
    rospy.sleep(0.2)
"""


def _start_node(env, *args):
    # each test's node starts from a clean slate: the parameter server keeps an earlier node's private parameters
    subprocess.run(["rosparam", "delete", "/slam2d"], env=env, capture_output=True)
    return subprocess.Popen([sys.executable, "-m", "slam2d", "ros", *args], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)


def _stop(process, timeout=60) -> str:
    os.killpg(process.pid, signal.SIGINT)
    try:
        out, _ = process.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
        out, _ = process.communicate()
        pytest.fail(f"the node did not stop within {timeout} s on SIGINT:\n{out[-2000:]}")
    return out


def _wait_for_node(env, node, timeout=120) -> None:
    """Until the node offers its services; fails with the node's own output if it exits or never does."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if node.poll() is not None:
            pytest.fail(f"the node exited with status {node.returncode} before offering its services:\n"
                        f"{node.stdout.read()[-3000:]}")
        done = subprocess.run(["rosservice", "list"], env=env, capture_output=True, text=True)
        if "/slam2d/save" in done.stdout:
            return
        time.sleep(0.5)
    pytest.fail(f"the node offered no /slam2d/save within {timeout} s (rosservice list: {done.stdout[-500:]!r} "
                f"{done.stderr[-500:]!r}); the node said:\n{_stop(node)[-3000:]}")


def test_live_karto_publishes_while_the_bag_plays_and_writes_the_offline_run(ros, office_bag, tmp_path):
    out = tmp_path / "node"
    # a method parameter as a private ROS parameter, as a launch file sets it
    node = _start_node(ros, "karto", "--out", str(out), "_minimum_travel_distance:=0.25")
    listener = subprocess.Popen(["/usr/bin/python3", "-c", _LISTENER, str(tmp_path / "seen.json")], env=ros,
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        _wait_for_node(ros, node)
        deadline = time.monotonic() + 30
        while not (tmp_path / "seen.json.ready").exists() and time.monotonic() < deadline:
            time.sleep(0.2)
        subprocess.run(["rosbag", "play", "--clock", "-q", "-d", "2", str(office_bag)], env=ros, check=True, timeout=120,
                       capture_output=True)
        time.sleep(2.0)
        seen = json.loads((tmp_path / "seen.json").read_text())
        # the services: the map on request, and the run folder written while the node runs
        got_map = subprocess.run(["rosservice", "call", "/dynamic_map"], env=ros, capture_output=True, text=True,
                                 timeout=60)
        saved = subprocess.run(["rosservice", "call", "/slam2d/save"], env=ros, capture_output=True, text=True,
                               timeout=120)
    finally:
        os.killpg(listener.pid, signal.SIGINT)
        log = _stop(node)
    assert "resolution: 0.05" in got_map.stdout, got_map.stdout[-500:] + got_map.stderr
    assert "success: True" in saved.stdout and str(out) in saved.stdout, saved.stdout + saved.stderr
    assert seen["map"] >= 1, log
    assert seen["map_to_odom"] >= 1, log
    assert "wrote the run folder" in log, log
    # the same method on the same bag offline, with the parameters the node ran with
    from slam2d.cli import main
    from slam2d.io.tum import read_tum

    assert main(["run", "karto", str(office_bag), "--params", str(out / "run.json"), "--out",
                 str(tmp_path / "offline")]) == 0
    t_live, p_live = read_tum(out / "trajectory.tum")
    t_off, p_off = read_tum(tmp_path / "offline" / "trajectory.tum")
    assert len(t_live) == len(t_off) > 100
    np.testing.assert_array_equal(t_live, t_off)
    assert np.abs(p_live[:, :2] - p_off[:, :2]).max() < 0.01
    # and the same map, cell for cell
    assert (out / "map.pgm").read_bytes() == (tmp_path / "offline" / "map.pgm").read_bytes()
    summary = json.loads((out / "diagnostics.json").read_text())["summary"]
    assert summary["live_scans_dropped"] == 0 and summary["live_scans_without_tf"] == 0
    record = json.loads((out / "run.json").read_text())
    assert record["data"]["source"] == "ROS topic /scan"
    assert record["params"]["minimum_travel_distance"] == 0.25
    # its session holds the scans it was fed: another day goes on from it
    session = json.loads((out / "session" / "session.json").read_text())
    assert session["frames"]["count"] == record["scans"] and session["method"] == "karto"


@pytest.mark.slow
def test_live_node_survives_no_odometry_a_replay_and_a_typo(ros, office_bag, tmp_path):
    from slam2d.io.tum import read_tum

    # a typo in a private parameter: refused at start, non-zero exit, the name in the message
    typo = subprocess.run([sys.executable, "-m", "slam2d", "ros", "karto", "_partciles:=3", "__name:=typo"],
                          env=ros, capture_output=True, text=True, timeout=60)
    assert typo.returncode == 2 and "~partciles" in typo.stderr, typo.stderr
    out = tmp_path / "node"
    node = _start_node(ros, "karto", "--out", str(out))
    try:
        _wait_for_node(ros, node)
        # no odometry in tf (only the scans and the laser's mount): every scan skipped, counted, warned
        subprocess.run(["rosbag", "play", "--clock", "-q", "-d", "2", str(office_bag), "--topics", "/scan", "/tf_static"],
                       env=ros, check=True, timeout=120, capture_output=True)
        # then the whole bag, twice: the second play goes back in time and starts a new map
        for _ in range(2):
            subprocess.run(["rosbag", "play", "--clock", "-q", "-d", "2", str(office_bag)], env=ros, check=True, timeout=120,
                           capture_output=True)
        time.sleep(2.0)
    finally:
        log = _stop(node)
    assert "no odometry odom -> base_link" in log and "time went back" in log, log
    summary = json.loads((out / "diagnostics.json").read_text())["summary"]
    assert summary["live_resets"] >= 1 and summary["live_scans_without_tf"] > 0
    # after the reset the node mapped the last play alone: the offline run's trajectory
    from slam2d.cli import main

    assert main(["run", "karto", str(office_bag), "--params", str(out / "run.json"), "--out",
                 str(tmp_path / "offline")]) == 0
    t_live, p_live = read_tum(out / "trajectory.tum")
    t_off, p_off = read_tum(tmp_path / "offline" / "trajectory.tum")
    missing = sorted(set(np.round(t_off, 3)) - set(np.round(t_live, 3)))
    assert len(t_live) == len(t_off), (f"live missed {missing} (offline from {t_off[0]:.3f}); {summary}", log)
    assert np.abs(p_live[:, :2] - p_off[:, :2]).max() < 0.01


@pytest.mark.slow
def test_live_node_skips_scans_of_another_beam_count_and_says_when_no_scan_comes(ros, office_bag, tmp_path):
    import dataclasses

    from slam2d.io import open_recording
    from slam2d.io.rosbag import write_rosbag

    # the office bag with scans 40-49 cut to half their beams (a driver restarted with another setting)
    messages = list(open_recording(office_bag).messages())
    scans = [k for k, m in enumerate(messages) if hasattr(m, "ranges")]
    for k in scans[40:50]:
        m = messages[k]
        messages[k] = dataclasses.replace(m, ranges=m.ranges[: m.num_beams // 2])
    bag = write_rosbag(tmp_path / "mixed.bag", messages, version="ros1")
    out = tmp_path / "node"
    node = _start_node(ros, "hector", "--out", str(out))
    try:
        _wait_for_node(ros, node)
        time.sleep(11.0)  # no scan publisher for 10 s: one warning
        subprocess.run(["rosbag", "play", "--clock", "-q", "-d", "2", str(bag)], env=ros, check=True, timeout=120,
                       capture_output=True)
        time.sleep(2.0)
    finally:
        log = _stop(node)
    assert log.count("no scan for 10 s") == 1, log
    assert "beams after" in log, log
    summary = json.loads((out / "diagnostics.json").read_text())["summary"]
    assert summary["live_scans_other_beam_count"] == 10
    assert json.loads((out / "run.json").read_text())["scans"] == len(scans) - 10


@pytest.mark.slow
def test_roslaunch_finds_the_node_through_the_ros_package(office_bag, tmp_path):
    """ros/slam2d is a ROS 1 package: roslaunch runs its office.launch, and the node writes the run folder."""
    _ros_or_skip()
    root = Path(__file__).resolve().parents[1]
    if not (root / ".venv" / "bin" / "slam2d").is_file():
        pytest.skip("the package's node runs the clone's .venv/bin/slam2d, which is not there")
    env = {**os.environ, "ROS_PACKAGE_PATH": f"{root / 'ros'}:/usr/share", "ROS_HOME": str(tmp_path / "ros"),
           "ROS_LOG_DIR": str(tmp_path / "ros" / "log")}
    port = _free_port()
    env["ROS_MASTER_URI"] = f"http://localhost:{port}"
    out = tmp_path / "launched"
    done = subprocess.run(["roslaunch", "-p", str(port), "slam2d", "office.launch", f"bag:={office_bag}",
                           f"out:={out}"], env=env, capture_output=True, text=True, timeout=180)
    assert "wrote the run folder" in done.stdout + done.stderr, (done.stdout + done.stderr)[-3000:]
    assert json.loads((out / "run.json").read_text())["scans"] > 100


def _send_initial_pose(env, pose) -> None:
    """What RViz's "2D Pose Estimate" sends: /initialpose in the map's frame."""
    x, y, th = pose
    message = (f"{{header: {{frame_id: map}}, pose: {{pose: {{position: {{x: {x}, y: {y}}}, "
               f"orientation: {{z: {math.sin(th / 2)}, w: {math.cos(th / 2)}}}}}}}}}")
    subprocess.run(["rostopic", "pub", "-1", "/initialpose", "geometry_msgs/PoseWithCovarianceStamped", message],
                   env=env, check=True, timeout=60, capture_output=True)


@pytest.mark.slow
def test_live_localization_in_a_saved_map_from_rviz_initial_pose(ros, office_bag, tmp_path):
    from slam2d.io.tum import read_tum

    truth_t, truth = read_tum(office_bag.parent / "truth.tum")
    out = tmp_path / "node"
    node = _start_node(ros, "karto", "--out", str(out), "_mode:=localization",
                       f"_session:={office_bag.parent / 'truth-map.yaml'}", "_method:=match")
    try:
        _wait_for_node(ros, node)
        # RViz's "2D Pose Estimate": the true start, 20 cm and 3 degrees off
        _send_initial_pose(ros, truth[0] + [0.2, -0.1, 0.05])
        subprocess.run(["rosbag", "play", "--clock", "-q", "-d", "2", str(office_bag)], env=ros, check=True,
                       timeout=120, capture_output=True)
        time.sleep(2.0)
    finally:
        log = _stop(node)
    rec = json.loads((out / "localization.json").read_text())
    assert rec["method"] == "match" and rec["localized"], (rec["events"], log)
    assert rec["events"][0]["why"].startswith("restarted around (") and rec["lost"] == 0
    t, p = read_tum(out / "trajectory.tum")
    k = np.searchsorted(truth_t, t).clip(0, len(truth_t) - 1)
    err = np.hypot(p[:, 0] - truth[k, 0], p[:, 1] - truth[k, 1])
    assert len(t) > 0.9 * rec["scans"] and np.median(err) < 0.05, (np.median(err), log)
    # a map that is not there: refused at start, with the parameter's name
    bad = subprocess.run([sys.executable, "-m", "slam2d", "ros", "karto", "_mode:=localization",
                          f"_session:={tmp_path / 'nowhere.yaml'}", "__name:=nomap"],
                         env=ros, capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "nowhere.yaml" in bad.stderr, bad.stderr


@pytest.mark.slow
def test_live_mapping_goes_on_from_a_saved_session(ros, office_bag, tmp_path):
    from slam2d.cli import main
    from slam2d.io.tum import read_tum

    # Monday, offline; Tuesday, the same office live from where the session says (RViz's initial pose)
    assert main(["run", "karto", str(office_bag), "--out", str(tmp_path / "monday")]) == 0
    truth_t, truth = read_tum(office_bag.parent / "truth.tum")
    out = tmp_path / "tuesday"
    node = _start_node(ros, "karto", "--out", str(out), f"_session:={tmp_path / 'monday'}")
    try:
        _wait_for_node(ros, node)
        _send_initial_pose(ros, truth[0])
        subprocess.run(["rosbag", "play", "--clock", "-q", "-d", "2", str(office_bag)], env=ros, check=True,
                       timeout=120, capture_output=True)
        time.sleep(2.0)
    finally:
        log = _stop(node)
    assert (out / "run.json").is_file(), log
    record = json.loads((out / "run.json").read_text())
    # (found once the robot has moved; the scans before are traced back from there and mapped too)
    assert record["resumed"]["scans_before_placed"] == 0, log
    assert "scans: mapping on" in log and " after 0 scans" not in log, log  # there were scans before it
    monday = json.loads((tmp_path / "monday" / "run.json").read_text())
    session = json.loads((out / "session" / "session.json").read_text())
    assert session["frames"]["count"] == monday["scans"] + record["scans"] and len(session["relocations"]) == 1
    # the localization in Monday's map goes on: the scans it places hold karto's new nodes there (map anchors)
    assert len(session["map_anchors"]) > 0.5 * record["scans"]
    t, p = read_tum(out / "trajectory.tum")  # Tuesday's poses, at Tuesday's times, in Monday's frame
    mt, mp = read_tum(tmp_path / "monday" / "trajectory.tum")
    assert t[0] >= truth_t[0] and len(t) > 0.9 * record["scans"]
    k = np.searchsorted(mt, t).clip(0, len(mt) - 1)
    assert np.median(np.hypot(p[:, 0] - mp[k, 0], p[:, 1] - mp[k, 1])) < 0.1  # where Monday put the same scans
