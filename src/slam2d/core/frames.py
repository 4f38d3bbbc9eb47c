"""Odometry readings, frames, and the streaming step that pairs them.

A :class:`Frame` is what a SLAM method is fed: one scan plus the robot's
odometry pose at the scan's timestamp. Readers produce a time-ordered stream of
:class:`~slam2d.core.scan.LaserScan` and :class:`OdometryReading` objects;
:func:`assemble_frames` turns it into frames in constant memory, holding a scan
back only until the first odometry reading at or after its time has arrived.
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from slam2d.core import se2
from slam2d.core.scan import LaserScan
from slam2d.errors import InputError, ProblemLog

__all__ = ["OdometryReading", "Frame", "assemble_frames", "TimestampCheck"]


@dataclass(frozen=True, slots=True, eq=False)
class OdometryReading:
    """The robot's pose in the odometry frame at ``timestamp`` (seconds).

    ``source`` names where it came from (``ODOM``, ``FLASER``, ``/odom``,
    ``/tf``...), which ``slam2d info`` reports. ``twist`` (``vx, vy, wz`` in
    the robot frame, m/s and rad/s) and the variances of the pose and the twist
    (``x, y, heading`` and ``vx, vy, wz``) are None where the source does not
    say (a bag writer then writes zeros: "unknown" in nav_msgs/Odometry).
    """

    timestamp: float
    pose: NDArray[np.float64]
    source: str = ""
    twist: NDArray[np.float64] | None = None
    pose_variance: NDArray[np.float64] | None = None
    twist_variance: NDArray[np.float64] | None = None


@dataclass(frozen=True, slots=True, eq=False)
class Frame:
    """One scan and the odometry pose of the robot base at the scan's time.

    ``odometry`` is None when the recording has no odometry near that time;
    odometry-free methods ignore it.
    """

    index: int
    scan: LaserScan
    odometry: NDArray[np.float64] | None

    @property
    def timestamp(self) -> float:
        return self.scan.timestamp


def assemble_frames(
    messages: Iterable[LaserScan | OdometryReading],
    *,
    max_gap: float = 0.5,
) -> Iterator[Frame]:
    """Pair each scan with the odometry pose interpolated at its timestamp.

    ``messages`` must be roughly time-ordered (as recorded). A scan between two
    odometry readings gets the pose interpolated between them. A scan with
    odometry on one side only gets the nearest reading's pose if it is at most
    ``max_gap`` seconds away, and no odometry otherwise. Odometry older than the
    newest reading is ignored (readers drop and report it before).
    """
    times: list[float] = []
    poses: list[NDArray[np.float64]] = []
    pending: deque[LaserScan] = deque()
    index = 0
    latest = -math.inf  # newest timestamp seen in the stream

    def resolve(scan: LaserScan) -> NDArray[np.float64] | None:
        t = scan.timestamp
        if not times:
            return None
        k = bisect.bisect_right(times, t)
        if k == 0:
            return poses[0].copy() if times[0] - t <= max_gap else None
        if k == len(times):
            return poses[-1].copy() if t - times[-1] <= max_gap else None
        t0, t1 = times[k - 1], times[k]
        if t == t0:
            return poses[k - 1].copy()
        return se2.interpolate(poses[k - 1], poses[k], (t - t0) / (t1 - t0))

    def ready(scan: LaserScan) -> bool:
        return (bool(times) and times[-1] >= scan.timestamp) or latest > scan.timestamp + max_gap

    def prune() -> None:
        # Keep one reading at or before the oldest scan still to be resolved.
        horizon = pending[0].timestamp if pending else latest
        cut = bisect.bisect_right(times, horizon - max_gap) - 1
        if cut > 64:
            del times[:cut]
            del poses[:cut]

    for msg in messages:
        if isinstance(msg, OdometryReading):
            if times and msg.timestamp < times[-1]:
                continue
            times.append(msg.timestamp)
            poses.append(np.asarray(msg.pose, dtype=np.float64))
        else:
            pending.append(msg)
        latest = max(latest, msg.timestamp)
        while pending and ready(pending[0]):
            scan = pending.popleft()
            yield Frame(index, scan, resolve(scan))
            index += 1
        prune()
    while pending:
        scan = pending.popleft()
        yield Frame(index, scan, resolve(scan))
        index += 1


class TimestampCheck:
    """Catches absurd and backwards timestamps as a reader streams a file.

    Scans set the timeline. A scan timestamp that is not finite, negative, or
    after 2096 is absurd; one that steps back by more than ``tolerance``
    seconds is out of order. Both stop the read (``skip=False``) or drop the
    record and count it (``skip=True``). A jump forward by more than
    ``max_jump`` seconds (a pause, a clock that was reset or rounded) is kept
    and counted as a warning: time that goes on is not corrupt. A small
    step back (real logs have them: the Intel log's scans step back up to 0.12 s
    four times) is kept and counted. Odometry out of order is always dropped and
    counted, because it cannot be interpolated (fr079 has 18 such readings).
    """

    def __init__(
        self,
        path: str | Path,
        problems: ProblemLog,
        *,
        skip: bool = False,
        tolerance: float = 1.0,
        max_jump: float = 3600.0,
    ) -> None:
        self.path = str(path)
        self.problems = problems
        self.skip = skip
        self.tolerance = tolerance
        self.max_jump = max_jump
        self.last_scan = -math.inf
        self.last_odom = -math.inf

    #: seconds since 1970 in 2096: later stamps come from a wrapped or garbage clock
    #: (the corrupt corridor log stamps 1937 scans 4.29497e9, about 2**32)
    LATEST_PLAUSIBLE = 4.0e9

    def _absurd(self, t: float, last: float, where: int | str) -> str | None:
        if not math.isfinite(t):
            return f"{t} is not a finite time"
        if t < 0.0:
            return f"{t} is negative"
        if t > self.LATEST_PLAUSIBLE:
            return f"{t} is after the year 2096 (a wrapped or garbage clock)"
        if math.isfinite(last) and t - last > self.max_jump:
            self.problems.add("time jumped forward (kept: a pause or a reset clock)",
                              f"{where}: {t - last:.6g} s past the previous record ({last})")
        return None

    def _reject(self, why: str, where: int | str, field: str) -> bool:
        if not self.skip:
            raise InputError(
                f"{why} (timestamps are corrupt; --skip-bad-records drops such records)",
                path=self.path,
                where=where,
                field=field,
            )
        self.problems.add(f"dropped record with bad {field}", f"{where}: {why}")
        return False

    def scan(self, t: float, where: int | str, field: str = "timestamp") -> bool:
        """True to keep a scan stamped ``t``; raises or returns False otherwise."""
        why = self._absurd(t, self.last_scan, where)
        if why:
            return self._reject(why, where, field)
        if t < self.last_scan:
            back = self.last_scan - t
            if back > self.tolerance:
                return self._reject(
                    f"{t} is {back:.6g} s before the previous scan ({self.last_scan})", where, field
                )
            self.problems.add("scan timestamp stepped back (kept)", f"{where}: by {back:.3g} s")
        elif t == self.last_scan:
            self.problems.add("scan timestamp repeated (kept)", f"{where}: {t}")
        self.last_scan = max(self.last_scan, t)
        return True

    def odometry(self, t: float, where: int | str, field: str = "timestamp") -> bool:
        """True to keep an odometry reading stamped ``t``."""
        why = self._absurd(t, self.last_odom, where)
        if why:
            return self._reject(why, where, field)
        if t < self.last_odom:
            self.problems.add(
                "odometry out of time order (dropped)", f"{where}: {t} after {self.last_odom}"
            )
            return False
        self.last_odom = t
        return True
