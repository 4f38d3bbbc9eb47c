"""A small built-in recording: a robot driving laps in a rectangular room.

This is the data ``make demo`` and the tests use until the full simulator
lands (worlds from files, materials, youBot and URG-04LX models). It is exact
where it matters for testing the readers and the mapper: beams are intersected
with the wall segments in closed form, the true trajectory is known, and
odometry drifts by a seeded, motion-proportional noise.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from slam2d.core import Frame, make_scan, se2

__all__ = ["DemoRoom", "room_segments", "cast_rays", "demo_room_frames"]


@dataclass(frozen=True)
class DemoRoom:
    """A rectangular room with two boxes inside (the source study's set-up, simplified)."""

    width: float = 6.0  # m
    depth: float = 4.0  # m


def room_segments(room: DemoRoom = DemoRoom()) -> NDArray[np.float64]:
    """Wall segments ``(M, 4)`` as ``x0, y0, x1, y1`` in metres."""
    w, d = room.width, room.depth

    def box(x0, y0, x1, y1):
        return [(x0, y0, x1, y0), (x1, y0, x1, y1), (x1, y1, x0, y1), (x0, y1, x0, y0)]

    return np.array(box(0.0, 0.0, w, d) + box(1.2, 1.6, 1.8, 2.4) + box(4.0, 2.6, 4.8, 3.0), dtype=np.float64)


def cast_rays(origin: NDArray[np.float64], directions: NDArray[np.float64], segments: NDArray[np.float64]) -> NDArray[np.float64]:
    """Distance along each unit direction ``(N,)`` from ``origin`` to the nearest segment (inf if none).

    Whole-array: an ``N x M`` system of ray-segment intersections solved at once.
    """
    p = origin[:2]
    d = np.stack([np.cos(directions), np.sin(directions)], axis=-1)  # (N, 2)
    a = segments[:, :2]
    e = segments[:, 2:] - a  # (M, 2)
    denom = d[:, None, 0] * e[None, :, 1] - d[:, None, 1] * e[None, :, 0]  # (N, M)
    ap = a - p  # (M, 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (ap[None, :, 0] * e[None, :, 1] - ap[None, :, 1] * e[None, :, 0]) / denom
        u = (ap[None, :, 0] * d[:, None, 1] - ap[None, :, 1] * d[:, None, 0]) / denom
    hit = (np.abs(denom) > 1e-12) & (t > 0.0) & (u >= 0.0) & (u <= 1.0)
    t = np.where(hit, t, np.inf)
    return t.min(axis=1)


def _lap_waypoints(room: DemoRoom) -> NDArray[np.float64]:
    m = 0.7
    return np.array(
        [(m, m), (room.width - m, m), (room.width - m, room.depth - m), (m, room.depth - m), (m, m)],
        dtype=np.float64,
    )


def _true_trajectory(room: DemoRoom, laps: int, rate: float, speed: float, turn_rate: float) -> NDArray[np.float64]:
    """Poses at ``rate`` Hz: drive each edge, then turn on the spot at each corner."""
    wp = _lap_waypoints(room)
    poses = []
    heading = 0.0
    for _ in range(laps):
        for a, b in zip(wp[:-1], wp[1:], strict=True):
            target = np.arctan2(b[1] - a[1], b[0] - a[0])
            turn = se2.wrap_angle(target - heading)
            n_turn = max(1, int(np.ceil(abs(turn) / (turn_rate / rate))))
            for k in range(1, n_turn + 1):
                poses.append((a[0], a[1], heading + turn * k / n_turn))
            heading = target
            length = float(np.hypot(*(b - a)))
            n_drive = max(1, int(np.ceil(length / (speed / rate))))
            for k in range(1, n_drive + 1):
                q = a + (b - a) * k / n_drive
                poses.append((q[0], q[1], heading))
    out = np.array(poses, dtype=np.float64)
    out[:, 2] = se2.wrap_angle(out[:, 2])
    return out


def demo_room_frames(
    *,
    seed: int = 0,
    laps: int = 2,
    rate: float = 10.0,
    speed: float = 0.3,
    turn_rate: float = 0.6,
    beams: int = 682,
    fov: float = np.deg2rad(239.77),
    range_max: float = 5.6,
    range_sigma: float = 0.005,
    odometry_noise: tuple[float, float, float, float] = (0.05, 0.01, 0.02, 0.05),
    mount: tuple[float, float, float] = (0.145, 0.0, 0.0),
    room: DemoRoom = DemoRoom(),
) -> tuple[list[Frame], NDArray[np.float64]]:
    """Frames of a robot doing ``laps`` laps of the room, and its true poses ``(N, 3)``.

    The laser defaults mimic a Hokuyo URG-04LX (682 beams over 239.77 deg,
    5.6 m, 10 Hz); ``odometry_noise`` is (srr, srt, str, stt) as GMapping names
    them: standard deviation of translation per metre, of translation per
    radian, of rotation per metre, of rotation per radian.
    """
    rng = np.random.default_rng(seed)
    truth = _true_trajectory(room, laps, rate, speed, turn_rate)
    segments = room_segments(room)
    mount_arr = np.array(mount, dtype=np.float64)
    angle_min = -fov / 2.0
    inc = fov / (beams - 1)
    beam_angles = angle_min + inc * np.arange(beams)
    srr, srt, str_, stt = odometry_noise

    odom = truth[0].copy()
    frames = []
    for i, pose in enumerate(truth):
        if i > 0:
            step = se2.relative(truth[i - 1], pose)
            dist = float(np.hypot(step[0], step[1]))
            rot = abs(float(step[2]))
            sxy = srr * dist + srt * rot
            sth = str_ * dist + stt * rot
            noisy = step + rng.normal(0.0, 1.0, 3) * np.array([sxy, sxy, sth])
            odom = se2.compose(odom, noisy)
        laser = se2.compose(pose, mount_arr)
        ranges = cast_rays(laser, laser[2] + beam_angles, segments)
        ranges = ranges + rng.normal(0.0, range_sigma, beams)
        scan = make_scan(i / rate, ranges, angle_min, inc, 0.02, range_max, mount=mount_arr)
        frames.append(Frame(i, scan, odom.copy()))
    return frames, truth
