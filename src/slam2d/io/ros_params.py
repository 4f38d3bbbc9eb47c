"""ROS users' parameter files: slam_toolbox / slam_karto and slam_gmapping YAML, read as slam2d's.

A team that already runs slam_toolbox or slam_gmapping has its tuned YAML. It
is accepted by ``--params`` as it is:

- a ROS 2 file (``slam_toolbox: {ros__parameters: {...}}``, any node name) or a
  ROS 1 file (flat, recognised by its ROS-only keys such as ``base_frame``);
- each key that slam2d has is taken under slam2d's name and units. Names are
  mostly the originals' own (karto's and gmapping's fields keep them). Where the
  original converts a value, slam2d converts it the same way: slam_karto and
  slam_toolbox square ``distance_variance_penalty``, ``angle_variance_penalty``
  and ``loop_match_maximum_variance_coarse`` before use, and slam2d's fields
  hold the squared value;
- a key that only matters to the ROS node (frames, topics, publishing periods,
  the solver plugin) is reported once with what it does there, and dropped;
- a wrong value is an error naming the file and the key.

The tables below are the documentation (docs/methods/karto.md and gmapping.md
show them).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from slam2d.errors import InputError

__all__ = ["RosParams", "ros_params", "mapping_table", "TOOLBOX_SQUARED", "TOOLBOX_RENAMED", "ROS_ONLY"]

#: the method parameters of slam_toolbox's (and slam_karto's) shipped YAML files
TOOLBOX_PARAMETERS = (
    "resolution", "max_laser_range", "minimum_time_interval", "use_scan_matching", "use_scan_barycenter",
    "minimum_travel_distance", "minimum_travel_heading", "scan_buffer_size", "scan_buffer_maximum_scan_distance",
    "link_match_minimum_response_fine", "link_scan_maximum_distance", "loop_search_maximum_distance",
    "do_loop_closing", "loop_match_minimum_chain_size", "loop_match_maximum_variance_coarse",
    "loop_match_minimum_response_coarse", "loop_match_minimum_response_fine", "correlation_search_space_dimension",
    "correlation_search_space_resolution", "correlation_search_space_smear_deviation", "loop_search_space_dimension",
    "loop_search_space_resolution", "loop_search_space_smear_deviation", "distance_variance_penalty",
    "angle_variance_penalty", "fine_search_angle_offset", "coarse_search_angle_offset", "coarse_angle_resolution",
    "minimum_angle_penalty", "minimum_distance_penalty", "use_response_expansion",
)
#: the method parameters slam_gmapping reads
GMAPPING_PARAMETERS = (
    "maxUrange", "maxRange", "sigma", "kernelSize", "lstep", "astep", "iterations", "lsigma", "ogain", "lskip",
    "minimumScore", "srr", "srt", "str", "stt", "linearUpdate", "angularUpdate", "temporalUpdate",
    "resampleThreshold", "particles", "xmin", "ymin", "xmax", "ymax", "delta", "llsamplerange", "llsamplestep",
    "lasamplerange", "lasamplestep", "occ_thresh",
)

#: slam_karto / slam_toolbox keys whose value the original squares before use (slam2d holds the square)
TOOLBOX_SQUARED = ("distance_variance_penalty", "angle_variance_penalty", "loop_match_maximum_variance_coarse")
#: slam_toolbox keys slam2d has under another name: ``{ros key: (slam2d field, why)}``
TOOLBOX_RENAMED = {
    "max_laser_range": ("range_threshold", "slam_toolbox gives it to Karto as the laser's range threshold: "
                                           "longer returns are not matched"),
}
#: keys only the ROS node uses: ``{key: what it does there}``
ROS_ONLY = {
    "base_frame": "the robot's tf frame (the live node's, not a recording's)",
    "odom_frame": "the odometry's tf frame (the live node's)",
    "map_frame": "the map's tf frame (the live node's)",
    "scan_topic": "the topic the node subscribes to (slam2d run reads the recording's scan topic; see --scan-topic)",
    "use_sim_time": "ROS time source",
    "mode": "slam_toolbox's mapping or localization mode",
    "debug_logging": "slam_toolbox's log level",
    "throttle_scans": "the node keeps every n-th scan (slam2d run uses every scan)",
    "transform_publish_period": "how often the node publishes map -> odom",
    "map_update_interval": "how often the node publishes the map",
    "map_update_interval_sec": "how often the node publishes the map",
    "transform_timeout": "how long the node waits for a transform",
    "tf_buffer_duration": "the node's tf buffer length",
    "tf_delay": "slam_gmapping's tf publishing delay",
    "transform_tolerance": "the node's tf future-dating",
    "transform_cache_size": "the node's tf cache",
    "stack_size_to_use": "slam_toolbox's thread stack for serialising maps",
    "enable_interactive_mode": "slam_toolbox's RViz graph editing",
    "use_map_saver": "slam_toolbox's map saver service",
    "solver_plugin": "slam_toolbox's pose-graph solver (slam2d's is the 'backend' parameter)",
    "ceres_linear_solver": "a Ceres solver option (slam2d's optimizer is the 'backend' parameter)",
    "ceres_preconditioner": "a Ceres solver option",
    "ceres_trust_strategy": "a Ceres solver option",
    "ceres_dogleg_type": "a Ceres solver option",
    "ceres_loss_function": "a Ceres solver option",
    "min_laser_range": "slam_toolbox's shortest range when rastering the map (slam2d uses the scan's range_min)",
    "occupancy_threshold": "slam_toolbox's occupied threshold when publishing the map",
    "min_pass_through": "slam_toolbox's free-cell count when publishing the map",
    "position_covariance_scale": "scales the published pose covariance",
    "yaw_covariance_scale": "scales the published pose covariance",
    "map_file_name": "a serialized map to start from (slam2d: not yet)",
    "map_start_pose": "the pose to start in a loaded map",
    "map_start_at_dock": "start at the loaded map's first node",
    "paused_new_measurements": "slam_toolbox's pause service state",
    "restamp_tf": "slam_toolbox's tf restamping",
    "scan_queue_size": "the node's subscription queue",
    "provide_odom_frame": "publish an odom frame",
    "odom_topic": "the node's odometry topic",
    "inverted_laser": "slam_gmapping's upside-down laser flag (slam2d normalises reversed lasers when reading)",
}
#: the ROS-only keys slam_gmapping reads (the rest of ROS_ONLY are slam_toolbox's)
GMAPPING_ROS_ONLY = ("base_frame", "map_frame", "odom_frame", "map_update_interval", "throttle_scans",
                     "transform_publish_period", "tf_delay", "use_sim_time", "inverted_laser")
#: keys that mark a flat file as a ROS node's (a slam2d file has none of them)
_ROS_MARKERS = ("base_frame", "odom_frame", "map_frame", "scan_topic", "map_update_interval", "solver_plugin",
                "transform_publish_period", "throttle_scans", "use_sim_time", "mode")
#: keys that say which original a file is for
_TOOLBOX_KEYS = ("solver_plugin", "correlation_search_space_dimension", "loop_search_maximum_distance",
                 "minimum_travel_distance", "scan_buffer_size", "do_loop_closing", "link_match_minimum_response_fine")
_GMAPPING_KEYS = ("maxUrange", "linearUpdate", "angularUpdate", "srr", "srt", "lskip", "ogain", "kernelSize")


@dataclass
class RosParams:
    """A ROS node's parameter file, translated: ``values`` under slam2d's names, ``notes`` one line per key dropped
    or converted."""

    origin: str  # "slam_toolbox" (also slam_karto) or "slam_gmapping"
    values: dict[str, Any]
    notes: list[str] = field(default_factory=list)


def _flatten(doc: dict[str, Any], path: Path) -> dict[str, Any] | None:
    """The parameters of a ROS 2 file (``node: {ros__parameters: {...}}``) or a flat ROS 1 file; None otherwise."""
    nested = [k for k, v in doc.items() if isinstance(v, dict) and "ros__parameters" in v]
    if nested:
        if len(doc) != 1:
            raise InputError("a ROS 2 parameter file for slam2d holds one node's section, found "
                             f"{', '.join(map(str, doc))}", path=path)
        params = doc[nested[0]]["ros__parameters"]
        if not isinstance(params, dict):
            raise InputError("expected a mapping of parameter names to values", path=path,
                             field=f"{nested[0]}.ros__parameters")
        return dict(params)
    if any(k in doc for k in _ROS_MARKERS):
        return dict(doc)
    return None


def ros_params(doc: dict[str, Any], path: str | Path, params_class: type, method: str) -> RosParams | None:
    """``doc`` (a parameter file's mapping) translated for ``params_class``; None when it is not a ROS node's file."""
    path = Path(path)
    params = _flatten(doc, path)
    if params is None:
        return None
    names = {f.name for f in fields(params_class)}
    toolbox = sum(k in params for k in _TOOLBOX_KEYS)
    gmapping = sum(k in params for k in _GMAPPING_KEYS)
    origin = "slam_toolbox" if toolbox > gmapping else "slam_gmapping" if gmapping else "ROS"
    if origin == "slam_toolbox" and "correlation_search_space_dimension" not in names:
        raise InputError(f"a slam_toolbox (Karto) parameter file: its parameters are karto's and lago's, not "
                         f"{method}'s (slam2d run karto --params {path.name})", path=path)
    if origin == "slam_gmapping" and "linearUpdate" not in names:
        raise InputError(f"a slam_gmapping parameter file: its parameters are gmapping's, not {method}'s "
                         f"(slam2d run gmapping --params {path.name})", path=path)
    values: dict[str, Any] = {}
    notes: list[str] = []
    for key, value in params.items():
        key = str(key)
        if key in ROS_ONLY:
            notes.append(f"{path.name}: {key} = {value!r} not used: {ROS_ONLY[key]}")
        elif key in TOOLBOX_RENAMED and TOOLBOX_RENAMED[key][0] in names:
            target, why = TOOLBOX_RENAMED[key]
            values[target] = value
            notes.append(f"{path.name}: {key} = {value!r} read as {target} ({why})")
        elif key in TOOLBOX_SQUARED and key in names and origin == "slam_toolbox":
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise InputError(f"{value!r} is not a number", path=path, field=key)
            values[key] = float(value) ** 2
            notes.append(f"{path.name}: {key} = {value!r} read as {float(value) ** 2:g} ({origin} squares it "
                         "before use; slam2d's value is the square)")
        elif key in names:
            values[key] = value
        else:
            notes.append(f"{path.name}: {key} = {value!r} not used: {method} has no such parameter")
    return RosParams(origin, values, notes)


def mapping_table(origin: str, params_class: type) -> str:
    """Markdown: how each of ``origin``'s parameters (``slam_toolbox`` or ``slam_gmapping``) is read (the docs)."""
    names = {f.name for f in fields(params_class)}
    keys = TOOLBOX_PARAMETERS if origin == "slam_toolbox" else GMAPPING_PARAMETERS
    rows = ["| " + origin + " | slam2d | how |", "|---|---|---|"]
    same = []
    for key in keys:
        if key in TOOLBOX_RENAMED and origin == "slam_toolbox":
            target, why = TOOLBOX_RENAMED[key]
            rows.append(f"| `{key}` | `{target}` | {why} |")
        elif key in TOOLBOX_SQUARED and origin == "slam_toolbox":
            rows.append(f"| `{key}` | `{key}` | squared ({origin} squares it before use; slam2d's value is the square) |")
        elif key in names:
            same.append(f"`{key}`")
        else:
            rows.append(f"| `{key}` | - | not used: slam2d has no such parameter |")
    rows.append(f"| {', '.join(same)} | the same name | as it is |")
    ros_only = sorted(set(ROS_ONLY) - {"tf_delay", "inverted_laser"}) if origin == "slam_toolbox" else GMAPPING_ROS_ONLY
    rows.append(f"| {', '.join(f'`{k}`' for k in ros_only)} | - | dropped with a warning saying what it does in "
                "the ROS node |")
    return "\n".join(rows) + "\n"
