"""A simulated recording with exact ground truth: world + robot + laser -> scans, odometry, truth.

:func:`simulate` drives a robot along a path in a world, samples its true
trajectory, derives drifting odometry from it, and measures laser scans from
the true poses. :func:`write_outputs` writes what ``slam2d simulate`` promises:
a CARMEN log, a ROS 2 (or ROS 1) bag, the true trajectory, the true occupancy
map, the world file and the settings. The same settings and seed give the same
bytes.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray

import slam2d
from slam2d.core import Frame, OdometryReading, make_scan, se2
from slam2d.core.scan import LaserScan
from slam2d.errors import InputError
from slam2d.io.tum import interpolate_poses
from slam2d.params import param, validate
from slam2d.sensors.motion_noise import OdometryNoise
from slam2d.sensors.range_noise import ConstantSigma, RangeNoiseModel, StudyModel

__all__ = ["SimulationParams", "Simulation", "simulate", "write_outputs", "load_path"]


@dataclass
class SimulationParams:
    """What to simulate. The world is given separately (a built-in name or a file)."""

    robot: str = param("youbot", help="robot preset (youbot: omnidirectional; diff-drive)")
    laser: str = param("urg-04lx", help="laser preset (urg-04lx, sick-lms, rplidar-a1)")
    duration: float | None = param(
        None, unit="s", low=0.0,
        help="how long to drive, looping the path; default: one pass along the path",
    )
    max_speed: float | None = param(
        None, unit="m/s", low=0.0,
        help="cap the robot's speed (the study slowed the youBot down for Hector); default: the preset's",
    )
    max_turn_rate: float | None = param(
        None, unit="rad/s", low=0.0, help="cap the robot's turn rate; default: the preset's",
    )
    seed: int = param(0, low=0, help="random seed of odometry and range noise; the same seed gives the same bytes")
    start_time: float = param(
        1767225600.0, unit="s", low=0.0,
        help="stamp of the first message, seconds since 1970 (default: 2026-01-01 00:00 UTC; ROS tf takes "
        "a stamp of 0 for 'not yet valid')",
    )
    odometry_rate: float = param(
        50.0, unit="Hz", low=0.1,
        help="odometry rate, rounded to a whole multiple of the laser rate (truth is sampled at it too)",
    )
    range_noise: str = param(
        "study", choices=("study", "constant", "none"),
        help="range noise: the study's sigma(distance, incidence, material), a constant sigma, or none",
    )
    range_sigma: float = param(
        0.0041, unit="m", low=0.0, help="sigma of the constant range noise (the study's choice for GMapping)"
    )
    dropouts: bool = param(True, help="lose returns on dark and grazing surfaces")
    distortion: bool = param(False, help="skew each scan by the robot's motion during the sweep")


@dataclass
class Simulation:
    """The simulated recording in memory: everything :func:`write_outputs` needs."""

    world: Any
    params: SimulationParams
    noise: OdometryNoise
    robot: Any
    laser: Any
    times: NDArray[np.float64]  # truth and odometry sample times (s)
    truth: NDArray[np.float64]  # true base poses (N, 3) at ``times``
    odometry: NDArray[np.float64]  # odometry poses (N, 3) at ``times``
    scan_indices: NDArray[np.int64]  # indices into ``times`` at which a scan starts
    scans: list[LaserScan] = field(default_factory=list)

    def frames(self) -> list[Frame]:
        """One frame per scan, with the odometry pose at the scan's time."""
        return [Frame(k, s, self.odometry[i].copy()) for k, (i, s) in enumerate(zip(self.scan_indices, self.scans, strict=True))]

    def messages(self) -> Iterator[LaserScan | OdometryReading]:
        """Odometry at its own rate with the scans in between, as a robot records them.

        Each odometry reading carries what a driver publishes with it: the twist (its last increment over the
        sample period) and the variances of the noise model, the pose's summed over the drive so far (dead
        reckoning only grows less certain), the twist's of the last increment over the period squared.
        """
        from slam2d.sensors.motion_noise import odometry_increments, step_variances

        steps = step_variances(odometry_increments(self.truth), self.noise)
        dt = np.diff(self.times)
        # each step's variance in the odometry frame (the heading's effect on position is left out)
        c, s = np.cos(self.odometry[:-1, 2]), np.sin(self.odometry[:-1, 2])
        world = np.stack([c * c * steps[:, 0] + s * s * steps[:, 1], s * s * steps[:, 0] + c * c * steps[:, 1],
                          steps[:, 2]], axis=1)
        pose_variance = np.vstack([np.zeros((1, 3)), np.cumsum(world, axis=0)])
        increments = odometry_increments(self.odometry)
        k = 0
        n_scans = len(self.scans)
        for i, t in enumerate(self.times):
            if i == 0 or not dt[i - 1] > 0.0:
                twist, twist_variance = np.zeros(3), np.zeros(3)
            else:
                twist, twist_variance = increments[i - 1] / dt[i - 1], steps[i - 1] / (dt[i - 1] * dt[i - 1])
            yield OdometryReading(float(t), self.odometry[i].copy(), source="odom", twist=twist,
                                  pose_variance=pose_variance[i].copy(), twist_variance=twist_variance)
            if k < n_scans and self.scan_indices[k] == i:
                yield self.scans[k]
                k += 1

    @property
    def scan_times(self) -> NDArray[np.float64]:
        return self.times[self.scan_indices]

    @property
    def scan_truth(self) -> NDArray[np.float64]:
        """True base poses at the scans' timestamps (what ``truth.tum`` holds)."""
        return self.truth[self.scan_indices]


def load_path(path: str | Path) -> dict[str, NDArray[np.float64]]:
    """Read a path file: YAML with ``waypoints: [[x, y], ...]`` or ``commands: [[seconds, vx, vy, omega], ...]``."""
    p = Path(path)
    if not p.is_file():
        raise InputError("no such file", path=p, field="path")
    try:
        doc = yaml.safe_load(p.read_text(encoding="utf-8"))
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise InputError(f"not valid YAML: {exc}".splitlines()[0], path=p) from None
    if not isinstance(doc, dict) or not doc or set(doc) - {"waypoints", "commands"} or len(doc) != 1:
        raise InputError(
            "expected exactly one key: 'waypoints' ([[x, y], ...]) or 'commands' ([[seconds, vx, vy, omega], ...])",
            path=p,
        )
    (key, value), = doc.items()
    width = 2 if key == "waypoints" else 4
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"rows must be lists of {width} numbers", path=p, field=key) from None
    if arr.ndim != 2 or arr.shape[1] != width or arr.shape[0] == 0 or not np.all(np.isfinite(arr)):
        raise InputError(f"rows must be lists of {width} finite numbers", path=p, field=key)
    return {key: arr}


def _range_noise(params: SimulationParams) -> RangeNoiseModel:
    if params.range_noise == "study":
        return StudyModel()
    return ConstantSigma(params.range_sigma if params.range_noise == "constant" else 0.0)


def simulate(
    world_name: str | Path,
    params: SimulationParams | None = None,
    *,
    odometry_noise: OdometryNoise | None = None,
    path: str | Path | None = None,
) -> Simulation:
    """Drive a robot through a world and record what its laser and odometry would have said."""
    from slam2d.sim.laser import LaserSimulator, laser_preset
    from slam2d.sim.robot import follow_waypoints, robot_preset, scripted, simulate_odometry
    from slam2d.sim.world import check_pose, first_blocked, load_world

    params = params if params is not None else SimulationParams()
    validate(params)
    noise = odometry_noise if odometry_noise is not None else OdometryNoise()
    world = load_world(world_name)
    robot = robot_preset(params.robot)
    laser = laser_preset(params.laser)
    if params.max_speed is not None:
        robot = type(robot)(**{**asdict(robot), "max_speed": min(robot.max_speed, params.max_speed)})
    if params.max_turn_rate is not None:
        robot = type(robot)(**{**asdict(robot), "max_turn_rate": min(robot.max_turn_rate, params.max_turn_rate)})

    start = world.start
    if start is None:
        raise InputError("the world has no start pose", path=world.source, field="start")
    check_pose(world, start, robot.radius, field="start")

    samples_per_scan = max(1, int(round(params.odometry_rate / laser.rate)))
    rate = laser.rate * samples_per_scan
    plan = load_path(path) if path is not None else {"waypoints": world.waypoints}
    if "commands" in plan:
        try:
            times, truth = scripted(robot, start, [tuple(c) for c in plan["commands"]], rate=rate)
        except InputError as exc:  # a command the robot cannot follow: name the path file
            raise exc.in_file(path) from None
    else:
        waypoints = plan["waypoints"]
        if waypoints is None or len(waypoints) == 0:
            raise InputError("the world has no default path; give one with --path", path=world.source, field="path")
        where = str(path) if path is not None else world.source
        legs = np.vstack([start[:2], waypoints])
        if params.duration is not None:
            legs = np.vstack([legs, waypoints[:1]])  # looping returns to the first waypoint
        for k in range(len(legs) - 1):
            blocked = first_blocked(world, legs[k], legs[k + 1], robot.radius)
            if blocked is not None:
                raise InputError(
                    f"leg {k + 1} from ({legs[k][0]:g}, {legs[k][1]:g}) to ({legs[k + 1][0]:g}, {legs[k + 1][1]:g}) "
                    f"runs into a wall at ({blocked[0]:.3g}, {blocked[1]:.3g}) (robot radius {robot.radius:g} m)",
                    path=where, field="path",
                )
        times, truth = follow_waypoints(
            robot, start, waypoints, rate=rate, duration=params.duration, loop=params.duration is not None
        )

    seeds = np.random.SeedSequence(params.seed).spawn(2)
    odometry = simulate_odometry(times, truth, noise, np.random.default_rng(seeds[0]))
    scan_rng = np.random.default_rng(seeds[1])
    lidar = LaserSimulator(laser, world, _range_noise(params), dropouts=params.dropouts, distortion=params.distortion)

    mount = np.asarray(robot.laser_mount, dtype=np.float64)
    scan_indices = np.arange(0, len(times), samples_per_scan, dtype=np.int64)
    laser_start = se2.compose(truth[scan_indices], mount)
    # From the first beam to the last: N - 1 steps of the mirror (pose_end is the last beam's pose).
    sweep_end_times = times[scan_indices] + laser.sweep_duration
    # The last sweeps end after the last sample: held at it.
    sweep_end_poses, _ = interpolate_poses(times, truth, np.minimum(sweep_end_times, times[-1]), math.inf)
    laser_end = se2.compose(sweep_end_poses, mount)
    # everything above runs on times from 0 (the same noise and bytes whatever the start); stamped from start_time
    t0 = float(params.start_time)
    scans = []
    for k, i in enumerate(scan_indices):
        ranges = lidar.measure(laser_start[k], laser_end[k] if params.distortion else None, scan_rng)
        scans.append(
            make_scan(
                t0 + float(times[i]), ranges, laser.angle_min, laser.angle_increment, laser.range_min, laser.range_max,
                mount=mount, frame_id="laser",
            )
        )
    return Simulation(world, params, noise, robot, laser, t0 + times, truth, odometry, scan_indices, scans)


#: The true map's cell size: finer than the 0.05 m maps it usually judges, so that map error is
#: measured against the cells a perfect map on their own lattice would mark (eval.map_metrics).
TRUTH_MAP_RESOLUTION = 0.02


def write_outputs(sim: Simulation, out_dir: str | Path, *, ros1: bool = False,
                  map_resolution: float = TRUTH_MAP_RESOLUTION) -> list[Path]:
    """Write the recording and its ground truth into ``out_dir``; return the paths written.

    - ``recording.log.gz``: CARMEN log (ROBOTLASER1 + ODOM at the odometry rate);
    - ``recording/`` ROS 2 bag (sqlite3), or ``recording.bag`` with ``ros1``:
      /scan, /odom, /tf, /tf_static;
    - ``truth.tum``: the true base pose at every scan;
    - ``truth-map.yaml`` + ``truth-map.pgm``: the world rasterised at ``map_resolution``;
    - ``world.yaml``: the world, loadable by ``slam2d simulate``;
    - ``simulation.json``: every setting, the seed and the slam2d version.
    """
    from slam2d.io.atomic import write_json_atomic, write_text_atomic
    from slam2d.io.carmen import write_carmen
    from slam2d.io.map_server import save_grid
    from slam2d.io.rosbag import write_rosbag
    from slam2d.io.tum import write_tum
    from slam2d.sim.world import rasterize

    out = Path(out_dir)
    truth_map = rasterize(sim.world, resolution=map_resolution)  # a map too large fails before anything is written
    out.mkdir(parents=True, exist_ok=True)
    written = [write_carmen(out / "recording.log.gz", sim.messages())]
    # the laser's timing as its driver states it: a sweep per period, beam to beam a mirror step apart
    timing = {"scan_time": 1.0 / sim.laser.rate,
              "time_increment": sim.laser.sweep_duration / max(1, sim.scans[0].num_beams - 1) if sim.scans else 0.0}
    if ros1:
        written.append(write_rosbag(out / "recording.bag", sim.messages(), version="ros1", **timing))
    else:
        written.append(write_rosbag(out / "recording", sim.messages(), version="ros2", **timing))
    written.append(write_tum(out / "truth.tum", sim.scan_times, sim.scan_truth))
    yaml_path, image_path = save_grid(truth_map, out / "truth-map.yaml")
    written += [yaml_path, image_path]
    world_path = out / "world.yaml"
    write_text_atomic(world_path, sim.world.to_yaml())
    written.append(world_path)
    settings = {
        "slam2d": slam2d.__version__,
        "world": sim.world.name,
        "world_source": sim.world.source,
        "simulation": asdict(sim.params),
        "odometry_noise": asdict(sim.noise),
        "robot": asdict(sim.robot),
        "laser": asdict(sim.laser),
        "scans": len(sim.scans),
        "duration_s": float(sim.times[-1] - sim.times[0]) if len(sim.times) else 0.0,
    }
    settings_path = out / "simulation.json"
    write_json_atomic(settings_path, settings)
    written.append(settings_path)
    return written


