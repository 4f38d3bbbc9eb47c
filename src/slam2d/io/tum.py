"""TUM trajectories: ``t x y z qx qy qz qw`` per line, as evo and the TUM RGB-D tools read them.

slam2d keeps planar poses ``[x, y, theta]``: reading takes the heading from
the quaternion (:func:`~slam2d.core.se2.quaternion_to_yaw`) and drops z;
writing puts z = 0 and a rotation about z. Numbers are written with the
shortest representation that parses back to the same float, so a trajectory
written and read again is bit-identical in t, x, y (and within 1e-12 rad in
heading, which goes through a quaternion).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator
from itertools import islice
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from slam2d.core import se2
from slam2d.errors import InputError
from slam2d.io.atomic import atomic_path
from slam2d.io.base import far_coordinate
from slam2d.io.numeric_text import numeric_rows

__all__ = ["read_tum", "write_tum", "by_time", "interpolate_poses", "poses_at_scans"]

_COLUMNS = ("timestamp", "x", "y", "z", "qx", "qy", "qz", "qw")
#: How far a quaternion's norm may be from 1 (files are written with ~9 decimals).
_UNIT_TOLERANCE = 1e-3


def read_tum(
    path: str | Path, *, time_tolerance: float = 1.0
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Read a TUM trajectory; return ``(timestamps (N,), poses (N, 3))`` in file order.

    ``#`` comment lines and blank lines are skipped. Timestamps must increase;
    a step back of at most ``time_tolerance`` seconds is accepted because a
    trajectory with one pose per scan inherits the scans' timestamps, and real
    logs have small steps back (the Intel log has four, up to 0.86 s). Any
    other problem (wrong column count, a value that is not a finite number, a
    quaternion that is not unit length, no poses) raises :class:`InputError`
    naming ``file:line`` and the column.
    """
    path = Path(path)
    times: list[float] = []
    rows: list[tuple[float, float, float, float, float, float]] = []
    last_time = -math.inf
    for lineno, values in numeric_rows(path, _COLUMNS, "TUM trajectory file"):
        t, x, y, _z, qx, qy, qz, qw = values
        for name, v in (("x", x), ("y", y)):
            problem = far_coordinate(v)
            if problem:
                raise InputError(problem, path=path, where=lineno, field=name)
        norm = math.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
        if abs(norm - 1.0) > _UNIT_TOLERANCE:
            raise InputError(
                f"({qx}, {qy}, {qz}, {qw}) has norm {norm:.6g}, not 1: not a rotation",
                path=path,
                where=lineno,
                field="quaternion",
            )
        if t <= last_time and last_time - t > time_tolerance:
            raise InputError(
                f"{t!r} is {last_time - t:.6g} s before the previous pose ({last_time!r}); "
                "timestamps must increase",
                path=path,
                where=lineno,
                field="timestamp",
            )
        if t == last_time:
            raise InputError(
                f"{t!r} repeats the previous pose's time; timestamps must increase",
                path=path,
                where=lineno,
                field="timestamp",
            )
        last_time = max(last_time, t)
        times.append(t)
        rows.append((x, y, qx, qy, qz, qw))
    if not times:
        raise InputError("file is empty" if path.stat().st_size == 0 else "no poses in the file", path=path)
    data = np.array(rows, dtype=np.float64)
    poses = np.empty((len(times), 3))
    poses[:, :2] = data[:, :2]
    poses[:, 2] = se2.quaternion_to_yaw(data[:, 2:6])
    return np.array(times, dtype=np.float64), poses


def write_tum(path: str | Path, timestamps: ArrayLike, poses: ArrayLike) -> Path:
    """Write ``timestamps (N,)`` and planar ``poses (N, 3)`` as a TUM trajectory; return its path.

    z is written 0 and the heading as a rotation about z. The file appears only
    when complete. Raises ``ValueError`` for arrays of the wrong shape or
    non-finite values (a program error, not user input).
    """
    path = Path(path)
    t = np.asarray(timestamps, dtype=np.float64).reshape(-1)
    p = se2.as_poses(poses)
    if p.ndim != 2 or p.shape[0] != t.shape[0]:
        raise ValueError(f"poses: shape {p.shape} does not match {t.shape[0]} timestamps")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(p))):
        raise ValueError("timestamps and poses must be finite")
    q = se2.yaw_to_quaternion(p[:, 2])
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8", newline="\n") as out:
        out.write("# timestamp x y z qx qy qz qw\n")
        # repr of a Python float is its shortest exact form, so a round trip loses nothing.
        for ti, (x, y, _), (_qx, _qy, qz, qw) in zip(t.tolist(), p.tolist(), q.tolist()):
            out.write(f"{ti!r} {x!r} {y!r} 0.0 0.0 0.0 {qz!r} {qw!r}\n")
    return path


def by_time(timestamps: NDArray[np.float64], poses: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """A trajectory sorted by time, stably (poses with equal timestamps keep their order); as given when sorted."""
    if timestamps.shape[0] > 1 and np.any(timestamps[1:] < timestamps[:-1]):
        order = np.argsort(timestamps, kind="stable")
        return timestamps[order], poses[order]
    return timestamps, poses


def interpolate_poses(
    timestamps: ArrayLike,
    poses: ArrayLike,
    query_times: ArrayLike,
    max_gap: float,
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Poses of a trajectory at ``query_times``; return ``(poses (M, 3), valid (M,))``.

    A query equal to a trajectory timestamp gets that pose exactly. One
    between two neighbouring poses gets the pose interpolated between them
    (:func:`~slam2d.core.se2.interpolate`) if they are at most ``max_gap``
    seconds apart. Queries outside the trajectory's time span or across a
    larger gap are invalid (their pose is NaN). Trajectory timestamps need
    not be sorted (they are sorted here, stably).
    """
    t = np.asarray(timestamps, dtype=np.float64).reshape(-1)
    p = se2.as_poses(poses).reshape(-1, 3)
    q = np.asarray(query_times, dtype=np.float64).reshape(-1)
    if p.shape[0] != t.shape[0]:
        raise ValueError(f"poses: {p.shape[0]} poses for {t.shape[0]} timestamps")
    out = np.full((q.shape[0], 3), np.nan)
    valid = np.zeros(q.shape[0], dtype=bool)
    if t.shape[0] == 0 or q.shape[0] == 0:
        return out, valid
    t, p = by_time(t, p)
    # right: the last trajectory time <= query is at index k - 1
    k = np.searchsorted(t, q, side="right")
    before = k - 1
    has_before = before >= 0
    b = np.clip(before, 0, t.shape[0] - 1)
    exact = has_before & (t[b] == q)
    out[exact] = p[b[exact]]
    valid[exact] = True

    a = np.clip(k, 0, t.shape[0] - 1)
    between = ~exact & has_before & (k < t.shape[0])
    gap = t[a] - t[b]
    between &= gap <= max_gap
    if np.any(between):
        t0 = t[b[between]]
        fraction = (q[between] - t0) / gap[between]
        out[between] = se2.interpolate(p[b[between]], p[a[between]], fraction)
        valid[between] = True
    return out, valid


def poses_at_scans(
    frames: Iterable[Any], timestamps: ArrayLike, poses: ArrayLike, max_gap: float, *, chunk: int = 256,
) -> Iterator[tuple[Any, NDArray[np.float64] | None]]:
    """Each frame with the trajectory's pose at its scan's timestamp, or None where it has none.

    As :func:`interpolate_poses` (exact at a trajectory timestamp, interpolated across gaps of at
    most ``max_gap`` s), looked up ``chunk`` frames at a time: one vectorised look-up per few
    hundred scans instead of one per scan, while the frames still stream.
    """
    t, p = by_time(np.asarray(timestamps, dtype=np.float64).reshape(-1), se2.as_poses(poses).reshape(-1, 3))
    it = iter(frames)
    while batch := list(islice(it, chunk)):
        found, valid = interpolate_poses(t, p, [frame.scan.timestamp for frame in batch], max_gap)
        for frame, pose, ok in zip(batch, found, valid):
            yield frame, (pose if ok else None)
