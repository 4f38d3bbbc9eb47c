"""What every reader of recorded laser data provides.

A :class:`Recording` is opened cheaply (headers only) and then streamed:
:meth:`Recording.messages` yields cleaned scans and odometry readings in time
order, in constant memory, and :meth:`Recording.frames` pairs them into
frames. Non-fatal problems go to ``recording.problems``; fatal ones raise
:class:`~slam2d.errors.InputError` naming the file, the line or message, and
the field.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from slam2d.core.frames import Frame, OdometryReading, TimestampCheck, assemble_frames
from slam2d.core.scan import LaserScan
from slam2d.errors import ProblemLog
from slam2d.params import param

__all__ = [
    "ReadOptions", "Recording", "StreamInfo", "ProgressCallback", "Message", "MAX_COORDINATE", "far_coordinate",
    "pose_problem",
]

#: Farther from the origin than any map reaches (the Earth's radius is 6.4e6 m): a pose beyond is corrupt, and
#: a map or search sized to reach it overflows (an odometry x of 1e308 was an OverflowError traceback).
MAX_COORDINATE = 1e7  # m


def far_coordinate(value: float) -> str | None:
    """What is wrong with a position coordinate (m) read from a file beyond MAX_COORDINATE, or None."""
    if abs(value) > MAX_COORDINATE:
        return f"{float(value)!r} m is farther than any map (over {MAX_COORDINATE:g} m: corrupt)"
    return None


def pose_problem(pose) -> str | None:
    """Why a pose ``[x, y, theta]`` read from a file is unusable (not finite, or beyond MAX_COORDINATE), or None."""
    pose = np.asarray(pose, dtype=np.float64)
    if not np.all(np.isfinite(pose)):
        return f"{pose.tolist()} is not finite"
    for name, value in zip("xy", pose[:2]):
        problem = far_coordinate(value)
        if problem:
            return f"{name}: {problem}"
    return None

#: ``progress(done, total)``; units are the reader's own (bytes of the file for
#: logs, messages for bags); ``total`` is 0 when unknown.
ProgressCallback = Callable[[int, int], None]

Message = LaserScan | OdometryReading


@dataclass
class ReadOptions:
    """How to read a recording. Every reader takes the same options."""

    odometry: str = param(
        "auto",
        choices=("auto", "embedded", "odom", "tf", "none"),
        help="where odometry comes from: auto picks the pose embedded in CARMEN laser lines, "
        "else ODOM lines / the odometry topic, else /tf; embedded = the pose in FLASER or "
        "ROBOTLASER1 lines; odom = ODOM lines or nav_msgs/Odometry; tf = odom->base transforms",
    )
    scan_topic: str | None = param(
        None, help="bag topic with sensor_msgs/LaserScan (auto-detected when there is one)"
    )
    odom_topic: str | None = param(
        None, help="bag topic with nav_msgs/Odometry (auto-detected when there is one)"
    )
    odom_frame: str | None = param(None, help="odometry frame in /tf (auto: 'odom' if present)")
    base_frame: str | None = param(
        None, help="robot base frame in /tf (auto: the child of the odometry frame)"
    )
    skip_bad_records: bool = param(
        False,
        help="skip corrupt lines or messages and report them at the end instead of stopping",
    )
    time_tolerance: float = param(
        1.0, unit="s", low=0.0, help="how far a scan timestamp may step back before it is an error"
    )
    max_time_jump: float = param(
        3600.0, unit="s", low=0.0,
        help="a forward jump in time larger than this is reported as a warning (a pause or a reset clock); the "
        "read goes on"
    )
    max_odometry_gap: float = param(
        0.5,
        unit="s",
        low=0.0,
        help="a scan further than this from any odometry reading gets no odometry",
    )
    range_min: float | None = param(
        None,
        unit="m",
        low=0.0,
        help="readings closer than this are no return, whatever the recording states (0.02 for a Hokuyo "
        "URG, whose readings below 20 mm are error codes; CARMEN logs state no minimum); unset: the "
        "recording's own minimum",
    )
    range_max: float | None = param(
        None,
        unit="m",
        low=0.0,
        help="readings at or beyond this are no return, whatever the recording states or the reader "
        "infers (a CARMEN log that states no maximum has its no-return code inferred, e.g. 50 m in "
        "aces; this replaces the inference); unset: the recording's own maximum",
    )


@dataclass
class StreamInfo:
    """One stream in a recording: a bag topic or a CARMEN message type."""

    name: str
    type: str
    count: int
    used_as: str = ""  # "scans", "odometry", "laser mount", or "" when not used


class Recording(ABC):
    """A recording of laser scans and odometry, streamed on demand.

    Subclasses open the file in ``__init__`` (reading headers only, raising
    :class:`~slam2d.errors.InputError` for a file they cannot read) and
    implement :meth:`messages`.
    """

    #: human-readable format name, e.g. "CARMEN log (gzip)", "ROS 1 bag v2.0"
    format: str = "unknown"

    def __init__(self, path: str | Path, options: ReadOptions | None = None) -> None:
        self.path = Path(path)
        self.options = options if options is not None else ReadOptions()
        self.problems = ProblemLog()

    @abstractmethod
    def messages(self, progress: ProgressCallback | None = None) -> Iterator[Message]:
        """Scans and odometry readings in time order, cleaned, in constant memory."""

    def range_min(self, stated: float) -> float:
        """The minimum range a scan is cleaned with: the recording's ``stated`` one, raised to ``--range-min``."""
        floor = self.options.range_min
        return stated if floor is None else max(float(stated), float(floor))

    def range_max(self, stated: float) -> float:
        """The maximum range a scan is cleaned with: the recording's ``stated`` one, lowered to ``--range-max``."""
        ceiling = self.options.range_max
        return stated if ceiling is None else min(float(stated), float(ceiling))

    def frames(self, progress: ProgressCallback | None = None) -> Iterator[Frame]:
        """Scans paired with the odometry pose at their timestamps."""
        return assemble_frames(self.messages(progress), max_gap=self.options.max_odometry_gap)

    def streams(self) -> list[StreamInfo]:
        """Topics or message types with their counts (complete after a full read)."""
        return []

    def notes(self) -> list[str]:
        """What the reader inferred rather than read (e.g. a no-return code); complete after a full read."""
        return []

    @property
    def odometry_source(self) -> str:
        """Where odometry comes from, as ``slam2d info`` prints it ("none" if absent)."""
        return "none"

    def timestamp_check(self) -> TimestampCheck:
        """A fresh checker configured from the options; readers call it per record."""
        o = self.options
        return TimestampCheck(
            self.path,
            self.problems,
            skip=o.skip_bad_records,
            tolerance=o.time_tolerance,
            max_jump=o.max_time_jump,
        )
