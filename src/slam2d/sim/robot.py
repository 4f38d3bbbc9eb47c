"""Robots for the simulator: presets, true trajectories from waypoints or commands, odometry.

A robot is a :class:`RobotSpec`: how it drives (``omni``: mecanum wheels, any
direction; ``diff``: two driven wheels, no sideways motion), its speed, turn
rate and acceleration limits, its size (for clearance checks) and where its
laser sits. Two functions produce the *true* trajectory, sampled at a fixed
rate:

* :func:`follow_waypoints` plans a path through waypoints and drives it as
  fast as the limits allow (docs/robots.md explains the planner);
* :func:`scripted` integrates body-frame velocity commands exactly.

:func:`simulate_odometry` (from :mod:`slam2d.sensors.motion_noise`) turns the
truth into drifting odometry.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray

from slam2d.core import se2
from slam2d.errors import InputError
from slam2d.params import param, validate
from slam2d.sensors.motion_noise import OdometryNoise, simulate_odometry

__all__ = [
    "RobotSpec",
    "ROBOT_PRESETS",
    "robot_preset",
    "check_robot",
    "follow_waypoints",
    "scripted",
    "OdometryNoise",
    "simulate_odometry",
]

DRIVES = ("omni", "diff")


@dataclass(frozen=True)
class RobotSpec:
    """A mobile base: drive type, motion limits, footprint and laser mount."""

    name: str = param("custom", help="name of the robot")
    drive: str = param("omni", choices=DRIVES, help="omni: moves in any direction; diff: no sideways motion")
    max_speed: float = param(0.5, unit="m/s", help="top translational speed (> 0)")
    max_turn_rate: float = param(1.0, unit="rad/s", help="top rotational speed (> 0)")
    max_acceleration: float = param(
        0.5, unit="m/s^2", help="top acceleration of the base, tangential and centripetal together (> 0)"
    )
    max_angular_acceleration: float = param(
        2.0, unit="rad/s^2", help="top angular acceleration of turns in place and omni heading changes (> 0)"
    )
    radius: float = param(0.3, unit="m", low=0.0, help="radius of a circle around the footprint, for clearance")
    laser_mount: tuple[float, float, float] = param(
        (0.0, 0.0, 0.0), unit="m, m, rad", help="laser pose on the base (x forward, y left, yaw)"
    )


# KUKA youBot omnidirectional base. Footprint 0.580 x 0.380 m and top speed 0.8 m/s
# are KUKA's datasheet numbers; the wheel layout (wheel centres 0.471 m front to
# rear and 0.300 m left to right, mecanum wheels of radius 0.0475 m) is the one
# KUKA's youbot_driver uses. With every wheel at the speed that gives 0.8 m/s, the
# mecanum kinematics turn in place at 0.8 / (0.471/2 + 0.300/2) = 2.08 rad/s.
# Accelerations are not published: 1 m/s^2 and 2 rad/s^2 are assumptions. The
# front Hokuyo sits 0.3 m ahead of the base centre on the centre line, as in
# KUKA's youbot_description model.
_YOUBOT_HALF_LENGTH = 0.471 / 2.0
_YOUBOT_HALF_WIDTH = 0.300 / 2.0

ROBOT_PRESETS: dict[str, RobotSpec] = {
    "youbot": RobotSpec(
        name="youbot",
        drive="omni",
        max_speed=0.8,
        max_turn_rate=round(0.8 / (_YOUBOT_HALF_LENGTH + _YOUBOT_HALF_WIDTH), 3),
        max_acceleration=1.0,
        max_angular_acceleration=2.0,
        radius=round(math.hypot(0.580 / 2.0, 0.380 / 2.0), 3),
        laser_mount=(0.3, 0.0, 0.0),
    ),
    # A generic small indoor differential-drive base (assumed numbers, typical of
    # research platforms of the TurtleBot/Pioneer class), laser 0.1 m ahead.
    "diff-drive": RobotSpec(
        name="diff-drive",
        drive="diff",
        max_speed=0.5,
        max_turn_rate=1.5,
        max_acceleration=0.5,
        max_angular_acceleration=2.0,
        radius=0.2,
        laser_mount=(0.1, 0.0, 0.0),
    ),
}


def robot_preset(name: str) -> RobotSpec:
    """The preset called ``name`` (a copy); :class:`InputError` listing the presets when unknown."""
    spec = ROBOT_PRESETS.get(str(name).strip().lower())
    if spec is None:
        raise InputError(
            f"unknown robot {name!r}; presets: {', '.join(ROBOT_PRESETS)}", field="robot"
        )
    return dataclasses.replace(spec)


def check_robot(spec: RobotSpec) -> None:
    """Raise :class:`InputError` naming the field when a limit is not a positive number or the drive is unknown."""
    for name in ("max_speed", "max_turn_rate", "max_acceleration", "max_angular_acceleration", "radius"):
        value = getattr(spec, name)
        if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
            raise InputError(f"{value!r} is not a number", field=name)
        if not math.isfinite(value):
            raise InputError(f"{value} is not finite", field=name)
        if name != "radius" and value <= 0.0:
            raise InputError(f"must be positive, got {value}", field=name)
    validate(spec)
    try:
        mount = np.asarray(spec.laser_mount, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{spec.laser_mount!r} is not (x, y, theta)", field="laser_mount") from None
    if mount.shape != (3,) or not np.all(np.isfinite(mount)):
        raise InputError(f"{spec.laser_mount!r} is not (x, y, theta)", field="laser_mount")


# --------------------------------------------------------------------------- helpers


def _as_pose(value: ArrayLike, field: str) -> NDArray[np.float64]:
    try:
        pose = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{value!r} is not a pose [x, y, theta]", field=field) from None
    if pose.shape != (3,) or not np.all(np.isfinite(pose)):
        raise InputError(f"expected a finite pose [x, y, theta], got {value!r}", field=field)
    return pose


def _as_rate(rate: float) -> float:
    try:
        value = float(rate)
    except (TypeError, ValueError):
        raise InputError(f"{rate!r} is not a number", field="rate") from None
    if not (math.isfinite(value) and value > 0.0):
        raise InputError(f"must be a positive number of samples per second, got {rate!r}", field="rate")
    return value


def _positive(value: object, field: str, unit: str) -> float:
    try:
        number = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise InputError(f"{value!r} is not a number", field=field) from None
    if not (math.isfinite(number) and number > 0.0):
        raise InputError(f"must be a positive number of {unit}, got {value!r}", field=field)
    return number


# Refuse absurd sample counts before allocating them (10 h at 1 kHz).
_MAX_SAMPLES = 36_000_000


def _sample_count(total_time: float, rate: float, *, inclusive_ceil: bool) -> int:
    n = total_time * rate
    count = (math.ceil(n - 1e-9) if inclusive_ceil else math.floor(n + 1e-9)) + 1
    if count > _MAX_SAMPLES:
        raise InputError(
            f"{total_time:g} s at {rate:g} Hz is {count} samples, more than {_MAX_SAMPLES}", field="duration"
        )
    return max(count, 1)


# --------------------------------------------------------------------------- scripted motion


def _twist_displacement(
    vx: NDArray[np.float64], vy: NDArray[np.float64], omega: NDArray[np.float64], tau: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Pose reached in ``tau`` seconds at constant body velocity ``(vx, vy, omega)``: exact arcs."""
    angle = omega * tau
    small = np.abs(angle) < 1e-6
    safe_omega = np.where(small, 1.0, omega)
    # sin(a)/omega and (1 - cos a)/omega, with their Taylor series where omega*tau ~ 0
    along = np.where(small, tau * (1.0 - angle**2 / 6.0), np.sin(angle) / safe_omega)
    across = np.where(small, tau * (angle / 2.0 - angle**3 / 24.0), (1.0 - np.cos(angle)) / safe_omega)
    dx = along * vx - across * vy
    dy = across * vx + along * vy
    return np.stack([dx, dy, angle], axis=-1)


def scripted(
    spec: RobotSpec,
    start: ArrayLike,
    commands: Sequence[Sequence[float]],
    *,
    rate: float,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The true trajectory of body-frame velocity commands, sampled at ``rate`` Hz from time 0.

    Each command is ``(duration s, vx m/s, vy m/s, omega rad/s)`` in the robot's
    frame, held for its duration and integrated exactly (a constant twist is a
    straight line or a circular arc). Speeds above ``spec.max_speed`` or turn
    rates above ``spec.max_turn_rate`` are refused, and so is ``vy != 0`` for a
    differential drive. Velocity changes between commands are instantaneous:
    the acceleration limits do not apply to scripted motion. Samples are at
    ``k / rate`` up to the total duration (the end is included when the total
    is a whole number of sample periods).
    """
    check_robot(spec)
    rate = _as_rate(rate)
    pose0 = _as_pose(start, "start")
    table = []
    for i, command in enumerate(commands):
        where = f"commands[{i}]"
        try:
            values = [float(v) for v in command]
        except (TypeError, ValueError):
            raise InputError(f"{command!r} is not (duration, vx, vy, omega) numbers", field=where) from None
        if len(values) != 4:
            raise InputError(f"expected (duration, vx, vy, omega), got {len(values)} values", field=where)
        duration, vx, vy, omega = values
        if not all(math.isfinite(v) for v in values):
            raise InputError(f"{command!r} has a value that is not finite", field=where)
        if duration <= 0.0:
            raise InputError(f"duration must be positive, got {duration:g} s", field=f"{where}.duration")
        if spec.drive == "diff" and vy != 0.0:
            raise InputError(
                f"a differential drive cannot move sideways (vy = {vy:g} m/s)", field=f"{where}.vy"
            )
        speed = math.hypot(vx, vy)
        if speed > spec.max_speed * (1.0 + 1e-9):
            raise InputError(
                f"speed {speed:g} m/s exceeds the robot's max_speed {spec.max_speed:g} m/s", field=where
            )
        if abs(omega) > spec.max_turn_rate * (1.0 + 1e-9):
            raise InputError(
                f"turn rate {abs(omega):g} rad/s exceeds the robot's max_turn_rate {spec.max_turn_rate:g} rad/s",
                field=f"{where}.omega",
            )
        table.append(values)
    if not table:
        return np.zeros(1), pose0[None, :].copy()
    cmd = np.asarray(table, dtype=np.float64)
    durations, vx, vy, omega = cmd.T
    starts = np.concatenate([[0.0], np.cumsum(durations)])
    # pose at the start of each command (a Python loop over commands, not samples)
    steps = _twist_displacement(vx, vy, omega, durations)
    anchors = np.empty((len(cmd) + 1, 3))
    anchors[0] = pose0
    for i in range(len(cmd)):
        anchors[i + 1] = se2.compose(anchors[i], steps[i])
    total = float(starts[-1])
    times = np.arange(_sample_count(total, rate, inclusive_ceil=True)) / rate
    k = np.clip(np.searchsorted(starts, times, side="right") - 1, 0, len(cmd) - 1)
    tau = np.minimum(times - starts[k], durations[k])
    poses = se2.compose(anchors[k], _twist_displacement(vx[k], vy[k], omega[k], tau))
    return times, poses


# --------------------------------------------------------------------------- waypoint following

# Turns sharper than this at a waypoint make a differential drive stop and turn
# in place; gentler ones are rounded with a circular arc.
_ARC_TURN_LIMIT = math.radians(100.0)
# Share of the acceleration budget on an arc: centripetal <= 0.6 a and
# tangential <= 0.8 a keep the total (their root sum square) within a.
_ARC_CENTRIPETAL_SHARE = 0.6
_ARC_TANGENTIAL_SHARE = 0.8
# Arc-length step of the speed profile. Each step has constant acceleration, so
# samples are exact for the profile; the step only limits how finely speed caps
# are resolved.
_PROFILE_STEP = 0.005
_EPS = 1e-9
# Waypoints closer than this to the previous one are dropped, and corners whose
# arc would be tighter than _MIN_ARC_RADIUS are turned in place: such tiny
# pieces change nothing physically and only cost floating-point accuracy.
_MIN_LEG = 1e-6
_MIN_ARC_RADIUS = 0.01


@dataclass
class _Path:
    """Translation primitives (lines and arcs) joined end to end, plus the stops on them."""

    s0: NDArray[np.float64]  # arc length at the start of each primitive
    length: NDArray[np.float64]
    x0: NDArray[np.float64]
    y0: NDArray[np.float64]
    heading0: NDArray[np.float64]  # tangent heading at the start
    curvature: NDArray[np.float64]  # signed, 1/m; 0 for lines
    cap: NDArray[np.float64]  # speed cap on the primitive, m/s
    tangential: NDArray[np.float64]  # tangential acceleration limit, m/s^2
    stop_before: NDArray[np.bool_]  # the robot stands still where this primitive begins
    turn_before: NDArray[np.float64]  # in-place rotation done while standing there, rad
    heading_gain0: NDArray[np.float64]  # heading gained on arcs before this primitive
    leg: NDArray[np.int64]  # index of the waypoint leg the primitive belongs to
    leg_heading: NDArray[np.float64]  # direction of each leg


def _polyline(start_xy: NDArray[np.float64], waypoints: NDArray[np.float64], laps: int) -> NDArray[np.float64]:
    """Start, then the waypoints ``laps`` times (``laps = 0``: once, no return), consecutive repeats dropped."""
    if laps <= 0:
        points = np.vstack([start_xy[None, :], waypoints])
    else:
        points = np.vstack([start_xy[None, :]] + [waypoints] * laps + [waypoints[:1]])
    keep = np.ones(len(points), dtype=bool)
    # compare with the last kept point, so a run of tiny steps cannot add up unnoticed
    last = points[0]
    for i in range(1, len(points)):
        if math.hypot(points[i, 0] - last[0], points[i, 1] - last[1]) <= _MIN_LEG:
            keep[i] = False
        else:
            last = points[i]
    return points[keep]


def _build_path(
    spec: RobotSpec, points: NDArray[np.float64], start_heading: float, cruise: float, corner_tolerance: float
) -> _Path:
    deltas = np.diff(points, axis=0)
    lengths = np.hypot(deltas[:, 0], deltas[:, 1])
    headings = np.arctan2(deltas[:, 1], deltas[:, 0])
    n_legs = len(lengths)
    turns = se2.wrap_angle(headings[1:] - headings[:-1])  # at interior waypoints
    a = spec.max_acceleration

    # fillet arc at each interior corner (diff drive, gentle turns); tangent length t = r tan(phi/2)
    arc_radius = np.zeros(max(n_legs - 1, 0))
    tangent = np.zeros(max(n_legs - 1, 0))
    if spec.drive == "diff" and n_legs > 1:
        half = np.abs(turns) / 2.0
        rounded = (np.abs(turns) > _EPS) & (np.abs(turns) <= _ARC_TURN_LIMIT)
        with np.errstate(divide="ignore", invalid="ignore"):
            # the arc's midpoint passes the waypoint at r (1/cos(phi/2) - 1)
            r_tol = corner_tolerance / (1.0 / np.cos(half) - 1.0)
            t = np.minimum(r_tol * np.tan(half), 0.5 * np.minimum(lengths[:-1], lengths[1:]))
            r = t / np.tan(half)
        rounded &= r >= _MIN_ARC_RADIUS
        tangent = np.where(rounded, t, 0.0)
        arc_radius = np.where(rounded, r, 0.0)

    rows: list[tuple] = []  # (s0, length, x0, y0, heading0, curvature, cap, tangential, stop, turn, leg)
    trim_start = np.concatenate([[0.0], tangent])  # length taken off each leg by the arcs at its ends
    trim_end = np.concatenate([tangent, [0.0]])
    s = 0.0
    pending_stop = True
    pending_turn = float(se2.wrap_angle(headings[0] - start_heading)) if spec.drive == "diff" else 0.0
    for k in range(n_legs):
        u = deltas[k] / lengths[k]
        line_len = lengths[k] - trim_start[k] - trim_end[k]
        if line_len > _EPS:
            p = points[k] + u * trim_start[k]
            rows.append((s, line_len, p[0], p[1], headings[k], 0.0, cruise, a, pending_stop, pending_turn, k))
            s += line_len
            pending_stop, pending_turn = False, 0.0
        if k == n_legs - 1:
            break
        if tangent[k] > 0.0:
            r = arc_radius[k]
            q = points[k + 1] - u * tangent[k]
            arc_cap = min(cruise, spec.max_turn_rate * r, math.sqrt(_ARC_CENTRIPETAL_SHARE * a * r))
            # keep omega' = kappa a_t within the angular acceleration limit too
            arc_tang = min(_ARC_TANGENTIAL_SHARE * a, spec.max_angular_acceleration * r)
            arc_len = r * abs(turns[k])
            rows.append((s, arc_len, q[0], q[1], headings[k], math.copysign(1.0 / r, turns[k]),
                         arc_cap, arc_tang, pending_stop, pending_turn, k + 1))
            s += arc_len
            pending_stop, pending_turn = False, 0.0
        elif abs(turns[k]) > _EPS:
            # a direction change without an arc: stop there (and turn in place if diff)
            pending_stop = True
            pending_turn = float(turns[k]) if spec.drive == "diff" else 0.0
    cols = list(zip(*rows, strict=True))
    f64 = [np.asarray(c, dtype=np.float64) for c in cols[:8]]
    curvature, lens = f64[5], f64[1]
    return _Path(
        s0=f64[0], length=lens, x0=f64[2], y0=f64[3], heading0=f64[4], curvature=curvature,
        cap=f64[6], tangential=f64[7], stop_before=np.asarray(cols[8], dtype=bool),
        turn_before=np.asarray(cols[9], dtype=np.float64),
        heading_gain0=np.concatenate([[0.0], np.cumsum(curvature * lens)])[:-1],
        leg=np.asarray(cols[10], dtype=np.int64), leg_heading=headings,
    )


@njit(cache=True)
def _speed_profile(cap: NDArray[np.float64], accel: NDArray[np.float64], ds: NDArray[np.float64]) -> NDArray[np.float64]:
    """Fastest node speeds under per-node caps and per-step acceleration limits (forward then backward pass)."""
    n = cap.shape[0]
    v = cap.copy()
    for i in range(n - 1):
        reach = math.sqrt(v[i] * v[i] + 2.0 * accel[i] * ds[i])
        if v[i + 1] > reach:
            v[i + 1] = reach
    for i in range(n - 2, -1, -1):
        reach = math.sqrt(v[i + 1] * v[i + 1] + 2.0 * accel[i] * ds[i])
        if v[i] > reach:
            v[i] = reach
    return v


@dataclass
class _Timeline:
    """Pieces of constant acceleration: translation along the path or rotation in place."""

    t0: NDArray[np.float64]
    duration: NDArray[np.float64]
    s0: NDArray[np.float64]
    v0: NDArray[np.float64]
    acc: NDArray[np.float64]
    q0: NDArray[np.float64]  # in-place rotation done before the piece
    w0: NDArray[np.float64]
    alpha: NDArray[np.float64]

    @property
    def end(self) -> float:
        return float(self.t0[-1] + self.duration[-1]) if len(self.t0) else 0.0

    def at(self, times: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Path arc length and in-place rotation at ``times`` (held after the end)."""
        if len(self.t0) == 0:
            return np.zeros_like(times), np.zeros_like(times)
        k = np.clip(np.searchsorted(self.t0, times, side="right") - 1, 0, len(self.t0) - 1)
        tau = np.clip(times - self.t0[k], 0.0, self.duration[k])
        s = self.s0[k] + self.v0[k] * tau + 0.5 * self.acc[k] * tau**2
        q = self.q0[k] + self.w0[k] * tau + 0.5 * self.alpha[k] * tau**2
        return s, q


def _turn_pieces(angle: float, omega_max: float, alpha: float) -> list[tuple[float, float, float]]:
    """Trapezoidal rotation from rest to rest: ``(duration, start rate, angular acceleration)`` pieces."""
    sign = math.copysign(1.0, angle)
    mag = abs(angle)
    if mag < _EPS:
        return []
    if mag >= omega_max**2 / alpha:
        t_ramp = omega_max / alpha
        t_cruise = (mag - omega_max**2 / alpha) / omega_max
        peak = omega_max
    else:
        peak = math.sqrt(mag * alpha)
        t_ramp = peak / alpha
        t_cruise = 0.0
    pieces = [(t_ramp, 0.0, sign * alpha)]
    if t_cruise > 0.0:
        pieces.append((t_cruise, sign * peak, 0.0))
    pieces.append((t_ramp, sign * peak, -sign * alpha))
    return pieces


def _timeline(spec: RobotSpec, path: _Path) -> _Timeline:
    """Time the path: the fastest speed profile within the limits, with in-place turns at stops."""
    n_prim = len(path.length)
    if n_prim == 0:
        return _Timeline(*(np.zeros(0) for _ in range(8)))
    # at least two steps per primitive, so a short one between two stops still has a moving node
    steps = np.maximum(2, np.ceil(path.length / _PROFILE_STEP).astype(np.int64))
    prim_of_step = np.repeat(np.arange(n_prim), steps)
    first_step = np.concatenate([[0], np.cumsum(steps)[:-1]])
    within = np.arange(len(prim_of_step)) - first_step[prim_of_step]
    ds = path.length[prim_of_step] / steps[prim_of_step]
    node_s = np.concatenate([path.s0[prim_of_step] + within * ds, [path.s0[-1] + path.length[-1]]])
    # node caps: a step's own cap inside a primitive, the smaller one at a junction, 0 at stops and the end
    cap = np.empty(len(node_s))
    cap[:-1] = path.cap[prim_of_step]
    cap[1:-1] = np.minimum(cap[1:-1], path.cap[prim_of_step][:-1])
    cap[first_step[path.stop_before]] = 0.0
    cap[-1] = 0.0
    v = _speed_profile(cap, path.tangential[prim_of_step], ds)
    v_start, v_end = v[:-1], v[1:]
    step_time = 2.0 * ds / (v_start + v_end)  # exact for constant acceleration; speeds never both 0
    step_acc = (v_end**2 - v_start**2) / (2.0 * ds)

    # order: each stop's turn pieces come just before the first step of its primitive
    keys, durations, s0, v0, acc, w0, alpha, q_delta = [], [], [], [], [], [], [], []
    keys.append(np.arange(len(ds), dtype=np.float64))
    durations.append(step_time); s0.append(node_s[:-1]); v0.append(v_start); acc.append(step_acc)
    w0.append(np.zeros(len(ds))); alpha.append(np.zeros(len(ds))); q_delta.append(np.zeros(len(ds)))
    for j in np.flatnonzero(path.turn_before != 0.0):
        pieces = _turn_pieces(float(path.turn_before[j]), spec.max_turn_rate, spec.max_angular_acceleration)
        for m, (dur, rate0, ang_acc) in enumerate(pieces):
            keys.append(np.array([first_step[j] - 0.5 + 0.1 * m]))
            durations.append(np.array([dur])); s0.append(np.array([path.s0[j]])); v0.append(np.zeros(1))
            acc.append(np.zeros(1)); w0.append(np.array([rate0])); alpha.append(np.array([ang_acc]))
            q_delta.append(np.array([rate0 * dur + 0.5 * ang_acc * dur**2]))
    order = np.argsort(np.concatenate(keys), kind="stable")
    cat = lambda parts: np.concatenate(parts)[order]  # noqa: E731
    duration = cat(durations)
    q_step = cat(q_delta)
    t0 = np.concatenate([[0.0], np.cumsum(duration)[:-1]])
    q0 = np.concatenate([[0.0], np.cumsum(q_step)[:-1]])
    return _Timeline(t0, duration, cat(s0), cat(v0), cat(acc), q0, cat(w0), cat(alpha))


def _path_poses(path: _Path, s: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64]]:
    """Positions ``(N, 2)``, heading gained on arcs and primitive index at arc lengths ``s``."""
    k = np.clip(np.searchsorted(path.s0, s, side="right") - 1, 0, len(path.s0) - 1)
    u = np.clip(s - path.s0[k], 0.0, path.length[k])
    h0, kappa = path.heading0[k], path.curvature[k]
    half = 0.5 * kappa * u
    # chord of an arc of length u: 2 sin(kappa u / 2) / kappa, written to stay exact as kappa -> 0
    straight = half == 0.0
    chord = np.where(straight, u, np.sin(half) / np.where(straight, 1.0, 0.5 * kappa))
    x = path.x0[k] + chord * np.cos(h0 + half)
    y = path.y0[k] + chord * np.sin(h0 + half)
    return np.stack([x, y], axis=-1), path.heading_gain0[k] + kappa * u, k


@njit(cache=True)
def _track_heading(
    start: float, target: NDArray[np.float64], dt: float, omega_max: float, alpha: float
) -> NDArray[np.float64]:
    """Heading that turns toward ``target[k]`` at each sample within the turn-rate and angular-acceleration limits."""
    n = target.shape[0]
    out = np.empty(n)
    theta, omega = start, 0.0
    out[0] = theta
    two_pi = 2.0 * math.pi
    for k in range(1, n):
        err = (target[k - 1] - theta + math.pi) % two_pi - math.pi
        # fastest rate from which the remaining error can still be braked to rest in
        # whole steps: braking from n*alpha*dt covers alpha*dt^2*n(n+1)/2
        brake = alpha * dt * (math.sqrt(0.25 + 2.0 * abs(err) / (alpha * dt * dt)) - 0.5)
        want = min(omega_max, brake, abs(err) / dt)
        want = want if err >= 0.0 else -want
        omega = min(max(want, omega - alpha * dt), omega + alpha * dt)
        theta = theta + omega * dt
        out[k] = theta
    return out


def _plan(spec, start, waypoints, laps, cruise, corner_tolerance):
    points = _polyline(start[:2], waypoints, laps)
    if len(points) < 2:
        return None, None
    path = _build_path(spec, points, float(start[2]), cruise, corner_tolerance)
    return path, _timeline(spec, path)


def follow_waypoints(
    spec: RobotSpec,
    start: ArrayLike,
    waypoints: ArrayLike,
    *,
    rate: float,
    duration: float | None = None,
    loop: bool = False,
    speed: float | None = None,
    corner_tolerance: float = 0.1,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The true trajectory through ``waypoints``, sampled at ``rate`` Hz from time 0.

    The robot starts at rest at ``start`` and visits the waypoints in order as
    fast as ``spec``'s limits allow (cruising at ``speed``, default its
    ``max_speed``), never exceeding its speed, turn rate, acceleration or
    angular acceleration:

    * ``diff``: turns in place to face the first waypoint; at each waypoint a
      turn of up to 100 degrees is rounded with a circular arc that passes
      within ``corner_tolerance`` metres of it (slower on tight arcs); a
      sharper turn stops there and turns in place. The heading always follows
      the direction of travel, so it never moves sideways. The turn rate steps
      at the start and end of an arc (no clothoids).
    * ``omni``: drives straight to each waypoint, stopping there, and turns its
      heading toward the current direction of travel within the turn-rate and
      angular-acceleration limits, so it moves sideways while turning.

    A waypoint within 1 micrometre of the previous one is skipped. With
    ``loop`` the path returns to the first waypoint and repeats. With
    ``duration`` the samples cover exactly ``[0, duration]`` (a looping robot is
    stopped mid-motion; a single pass that finishes early stands still).
    Without it, one pass (one lap with ``loop``) is sampled until the robot
    stands at the end, with the last sample at or just after it stops.
    """
    check_robot(spec)
    rate = _as_rate(rate)
    pose0 = _as_pose(start, "start")
    try:
        wp = np.asarray(waypoints, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError("waypoints must be a list of [x, y] numbers", field="waypoints") from None
    if wp.ndim != 2 or wp.shape[1] != 2 or len(wp) == 0:
        raise InputError(f"expected a non-empty list of [x, y] points, got shape {wp.shape}", field="waypoints")
    if not np.all(np.isfinite(wp)):
        raise InputError("waypoints must be finite numbers", field="waypoints")
    if duration is not None:
        try:
            duration = float(duration)
        except (TypeError, ValueError):
            raise InputError(f"{duration!r} is not a number of seconds", field="duration") from None
        if not (math.isfinite(duration) and duration >= 0.0):
            raise InputError(f"must be a non-negative number of seconds, got {duration!r}", field="duration")
        _sample_count(duration, rate, inclusive_ceil=False)  # refuse an absurd duration before planning its laps
    cruise = float(spec.max_speed)
    if speed is not None:
        cruise = _positive(speed, "speed", "m/s")
        if cruise > spec.max_speed * (1.0 + 1e-9):
            raise InputError(
                f"{cruise:g} m/s exceeds the robot's max_speed {spec.max_speed:g} m/s", field="speed"
            )
    corner_tolerance = _positive(corner_tolerance, "corner_tolerance", "m")

    # a loop needs a lap of non-zero length
    lap_points = np.vstack([wp, wp[:1]])
    looping = bool(loop) and bool(np.any(np.hypot(*(np.diff(lap_points, axis=0).T)) > _MIN_LEG))
    laps = 1 if looping else 0
    path, timeline = _plan(spec, pose0, wp, laps, cruise, corner_tolerance)
    if looping and duration is not None and timeline.end < duration:
        # enough laps to fill the duration: time one more lap, then extrapolate
        _, two = _plan(spec, pose0, wp, 2, cruise, corner_tolerance)
        lap_time = max(two.end - timeline.end, 1e-6)
        laps = 3 + math.ceil((duration - two.end) / lap_time) if two.end < duration else 2
        path, timeline = _plan(spec, pose0, wp, laps, cruise, corner_tolerance)

    end = timeline.end if timeline is not None else 0.0
    settle = 0.0
    if spec.drive == "omni" and path is not None:
        # time for the heading to finish turning after the robot stops
        settle = math.pi / spec.max_turn_rate + 2.0 * spec.max_turn_rate / spec.max_angular_acceleration + 1.0
    if duration is not None:
        times = np.arange(_sample_count(duration, rate, inclusive_ceil=False)) / rate
    else:
        times = np.arange(_sample_count(end + settle, rate, inclusive_ceil=True)) / rate
    poses = np.empty((len(times), 3))
    if path is None:
        poses[:] = pose0
        return times, poses

    s, q = timeline.at(times)
    xy, arc_gain, prim = _path_poses(path, s)
    poses[:, :2] = xy
    if spec.drive == "diff":
        poses[:, 2] = se2.wrap_angle(pose0[2] + q + arc_gain)
        if duration is None:
            last = _sample_count(end, rate, inclusive_ceil=True)
            times, poses = times[:last], poses[:last]
        return times, poses

    target = path.leg_heading[path.leg[prim]]
    heading = _track_heading(float(pose0[2]), target, 1.0 / rate, spec.max_turn_rate, spec.max_angular_acceleration)
    poses[:, 2] = se2.wrap_angle(heading)
    if duration is None:
        # stop sampling once the robot stands still facing its last direction
        moving_until = _sample_count(end, rate, inclusive_ceil=True) - 1
        err = np.abs(se2.wrap_angle(heading - target))
        still = np.concatenate([[False], np.abs(np.diff(heading)) < 1e-12]) & (err < 1e-9)
        settled = np.flatnonzero(still[moving_until:])
        last = moving_until + (int(settled[0]) if len(settled) else len(times) - 1 - moving_until) + 1
        times, poses = times[:last], poses[:last]
    return times, poses
