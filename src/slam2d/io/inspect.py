"""What is in a recording, and what is wrong with it: the engine of ``slam2d info``."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from slam2d.io.base import ProgressCallback, Recording, StreamInfo

__all__ = ["RecordingSummary", "summarize"]

#: a gap between scans longer than this many median periods (and 1 s) is reported
GAP_FACTOR = 5.0


@dataclass
class RecordingSummary:
    path: str
    format: str
    file_bytes: int
    scans: int = 0
    beams_min: int = 0
    beams_max: int = 0
    field_of_view_deg: float = 0.0
    angular_resolution_deg: float = 0.0
    range_min: float = 0.0
    range_max: float = 0.0
    longest_return: float = 0.0
    no_return_fraction: float = 0.0
    rate_hz: float = 0.0
    start: float = 0.0
    end: float = 0.0
    duration: float = 0.0
    odometry_source: str = "none"
    frames_with_odometry: int = 0
    odometry_path_length: float = 0.0
    laser_mount: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    streams: list[dict[str, Any]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)  # what the reader inferred, not read
    problems: list[str] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def summarize(recording: Recording, progress: ProgressCallback | None = None,
              keep: list | None = None) -> RecordingSummary:
    """Read the whole recording once and describe it, collecting every problem found.

    ``keep``: a list every frame read is appended to, for a caller that needs the frames too."""
    path = recording.path
    size = path.stat().st_size if path.is_file() else sum(p.stat().st_size for p in path.rglob("*") if p.is_file())
    s = RecordingSummary(path=str(path), format=recording.format, file_bytes=size)
    stamps: list[float] = []
    beams_min, beams_max = None, 0
    fov = res = 0.0
    rmin, rmax = np.inf, 0.0
    longest = 0.0
    valid_total = beams_total = 0
    with_odom = 0
    path_length = 0.0
    last_odom = None
    mount = None
    for frame in recording.frames(progress):
        if keep is not None:
            keep.append(frame)
        scan = frame.scan
        stamps.append(scan.timestamp)
        n = scan.num_beams
        beams_min = n if beams_min is None else min(beams_min, n)
        beams_max = max(beams_max, n)
        fov = max(fov, scan.field_of_view)
        res = scan.angle_increment
        rmin = min(rmin, scan.range_min)
        rmax = max(rmax, scan.range_max)
        valid = scan.valid
        nv = int(valid.sum())
        valid_total += nv
        beams_total += n
        if nv:
            longest = max(longest, float(np.nanmax(scan.ranges)))
        if mount is None:
            mount = scan.mount
        if frame.odometry is not None:
            with_odom += 1
            if last_odom is not None:
                path_length += float(np.hypot(*(frame.odometry[:2] - last_odom[:2])))
            last_odom = frame.odometry

    problems = list(recording.problems.lines())
    s.scans = len(stamps)
    s.odometry_source = recording.odometry_source
    s.notes = list(recording.notes())
    s.streams = [asdict(st) if isinstance(st, StreamInfo) else dict(st) for st in recording.streams()]
    if s.scans:
        t = np.asarray(stamps)
        dt = np.diff(t)
        s.beams_min, s.beams_max = int(beams_min), int(beams_max)
        s.field_of_view_deg = float(np.rad2deg(fov))
        s.angular_resolution_deg = float(np.rad2deg(res))
        s.range_min, s.range_max = float(rmin), float(rmax)
        s.longest_return = longest
        s.no_return_fraction = 1.0 - valid_total / beams_total
        s.start, s.end = float(t[0]), float(t[-1])
        s.duration = float(t[-1] - t[0])
        s.frames_with_odometry = with_odom
        s.odometry_path_length = path_length
        s.laser_mount = [float(v) for v in (mount if mount is not None else np.zeros(3))]
        if dt.size:
            forward = dt[dt > 0]
            median = float(np.median(forward)) if forward.size else 0.0
            s.rate_hz = 1.0 / median if median > 0 else 0.0
            gaps = np.flatnonzero(dt > max(GAP_FACTOR * median, 1.0))
            if gaps.size:
                worst = gaps[np.argmax(dt[gaps])]
                problems.append(
                    f"{gaps.size} x gap between scans longer than {max(GAP_FACTOR * median, 1.0):.3g} s "
                    f"(longest {dt[worst]:.3g} s after scan {worst} at t={t[worst]:.6g})"
                )
            # Scan time going backwards is reported by the reader itself (TimestampCheck).
            if beams_min != beams_max:
                problems.append(f"beam count varies between scans ({beams_min} to {beams_max})")
        if s.odometry_source != "none" and with_odom < s.scans:
            problems.append(f"{s.scans - with_odom} scans have no odometry within the allowed gap")
    else:
        problems.append("no laser scans found")
    s.problems = problems
    return s
