"""ROS users' parameter files (slam_toolbox, slam_gmapping) read by --params under slam2d's names and units."""

from __future__ import annotations

import json
import math

import pytest

from slam2d.cli import main
from slam2d.errors import InputError
from slam2d.methods.runner import build_method

# the shape of slam_toolbox's mapper_params_online_async.yaml (ROS 2), values as a user tuned them
TOOLBOX_ROS2 = """\
slam_toolbox:
  ros__parameters:
    solver_plugin: solver_plugins::CeresSolver
    ceres_linear_solver: SPARSE_NORMAL_CHOLESKY
    odom_frame: odom
    map_frame: map
    base_frame: base_footprint
    scan_topic: /scan
    mode: mapping
    transform_publish_period: 0.02
    map_update_interval: 5.0
    resolution: 0.04
    max_laser_range: 18.0
    minimum_time_interval: 0.5
    use_scan_matching: true
    minimum_travel_distance: 0.3
    minimum_travel_heading: 0.4
    scan_buffer_size: 12
    loop_search_maximum_distance: 3.5
    do_loop_closing: true
    loop_match_maximum_variance_coarse: 3.0
    correlation_search_space_dimension: 0.6
    distance_variance_penalty: 0.5
    angle_variance_penalty: 1.0
    coarse_search_angle_offset: 0.349
"""

# the shape of a slam_gmapping launch's rosparam YAML (ROS 1, flat)
GMAPPING_ROS1 = """\
base_frame: base_link
odom_frame: odom
map_update_interval: 2.0
throttle_scans: 1
maxUrange: 15.0
particles: 12
srr: 0.1
srt: 0.15
str: 0.1
stt: 0.15
linearUpdate: 0.7
angularUpdate: 0.4
delta: 0.05
"""


def test_a_slam_toolbox_file_is_read_under_karto_names_and_units(tmp_path):
    path = tmp_path / "mapper_params_online_async.yaml"
    path.write_text(TOOLBOX_ROS2)
    slam = build_method("karto", params_file=path)
    p = slam.params
    assert p.resolution == 0.04 and p.minimum_travel_distance == 0.3 and p.scan_buffer_size == 12
    assert p.correlation_search_space_dimension == 0.6 and p.minimum_time_interval == 0.5
    # the originals square these before use; slam2d holds the square
    assert math.isclose(p.distance_variance_penalty, 0.25)
    assert math.isclose(p.angle_variance_penalty, 1.0)
    assert math.isclose(p.loop_match_maximum_variance_coarse, 9.0)
    assert p.range_threshold == 18.0
    notes = "\n".join(slam.param_notes)
    for key in ("base_frame", "scan_topic", "solver_plugin", "map_update_interval", "transform_publish_period"):
        assert f"{key} = " in notes
    assert "read as 0.25" in notes and "squares" in notes
    # lago shares karto's front end and takes the same file
    assert math.isclose(build_method("lago", params_file=path).params.distance_variance_penalty, 0.25)


def test_a_slam_gmapping_file_is_read_and_its_ros_keys_reported(tmp_path):
    path = tmp_path / "gmapping.yaml"
    path.write_text(GMAPPING_ROS1)
    slam = build_method("gmapping", params_file=path)
    p = slam.params
    assert (p.maxUrange, p.particles, p.srt, p.linearUpdate, p.angularUpdate, p.delta) == (15.0, 12, 0.15, 0.7, 0.4, 0.05)
    assert len(slam.param_notes) == 4  # base_frame, odom_frame, map_update_interval, throttle_scans
    assert any("throttle_scans" in n and "every scan" in n for n in slam.param_notes)


def test_a_file_for_another_original_is_refused_with_the_method_it_is_for(tmp_path):
    path = tmp_path / "toolbox.yaml"
    path.write_text(TOOLBOX_ROS2)
    with pytest.raises(InputError, match="karto") as err:
        build_method("gmapping", params_file=path)
    assert str(err.value.path) == str(path)
    gm = tmp_path / "gm.yaml"
    gm.write_text(GMAPPING_ROS1)
    with pytest.raises(InputError, match="gmapping"):
        build_method("karto", params_file=gm)


def test_a_wrong_value_names_the_file_and_the_key(tmp_path):
    path = tmp_path / "toolbox.yaml"
    path.write_text(TOOLBOX_ROS2.replace("resolution: 0.04", "resolution: -1"))
    with pytest.raises(InputError) as err:
        build_method("karto", params_file=path)
    assert err.value.field == "resolution" and str(err.value.path) == str(path)
    path.write_text(TOOLBOX_ROS2.replace("distance_variance_penalty: 0.5", "distance_variance_penalty: wide"))
    with pytest.raises(InputError) as err:
        build_method("karto", params_file=path)
    assert err.value.field == "distance_variance_penalty"


def test_two_nodes_in_one_ros2_file_are_refused(tmp_path):
    path = tmp_path / "two.yaml"
    path.write_text(TOOLBOX_ROS2 + "other_node:\n  ros__parameters:\n    resolution: 0.1\n")
    with pytest.raises(InputError, match="one node"):
        build_method("karto", params_file=path)


def test_run_reports_the_dropped_keys_once_and_records_the_converted_values(tmp_path, capsys, paper_arena):
    path = tmp_path / "toolbox.yaml"
    path.write_text(TOOLBOX_ROS2)
    out = tmp_path / "run"
    assert main(["run", "karto", str(paper_arena / "recording.log.gz"), "--params", str(path), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert err.count("base_frame = ") == 1
    record = json.loads((out / "run.json").read_text())
    assert record["params"]["distance_variance_penalty"] == 0.25
    assert any("scan_topic" in w for w in record["warnings"])
    # the run folder's run.json repeats the run: no ROS keys left in it
    again = build_method("karto", params_file=out / "run.json")
    assert again.params.distance_variance_penalty == 0.25 and not again.param_notes
