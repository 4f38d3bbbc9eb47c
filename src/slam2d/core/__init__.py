"""The data model: SE(2) poses, laser scans, odometry and frames."""

from slam2d.core import se2
from slam2d.core.frames import Frame, OdometryReading, TimestampCheck, assemble_frames
from slam2d.core.scan import LaserScan, make_scan

__all__ = [
    "se2",
    "LaserScan",
    "make_scan",
    "OdometryReading",
    "Frame",
    "assemble_frames",
    "TimestampCheck",
]
