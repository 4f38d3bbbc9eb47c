"""Readers and writers: CARMEN logs, ROS 1 and ROS 2 bags, TUM trajectories, map_server maps.

:func:`open_recording` looks at a path and returns the right
:class:`~slam2d.io.base.Recording`; the format is recognised from the file's
first bytes, not trusted from its name.
"""

from __future__ import annotations

from pathlib import Path

from slam2d.errors import InputError
from slam2d.io.base import ReadOptions, Recording, StreamInfo

__all__ = ["open_recording", "ReadOptions", "Recording", "StreamInfo", "detect_format"]

_ROS2_SUFFIXES = (".db3", ".mcap")


def detect_format(path: str | Path) -> str:
    """``"carmen"``, ``"ros1"`` or ``"ros2"``; raises :class:`InputError` otherwise."""
    p = Path(path)
    if not p.exists():
        raise InputError("no such file or folder", path=p)
    if p.is_dir():
        if (p / "metadata.yaml").is_file() or any(
            q.suffix in _ROS2_SUFFIXES for q in p.iterdir()
        ):
            return "ros2"
        raise InputError(
            "is a folder; expected a CARMEN log, a ROS 1 .bag file or a ROS 2 bag folder", path=p
        )
    if not p.is_file():
        raise InputError("is not a regular file", path=p)
    try:
        with open(p, "rb") as f:
            head = f.read(64)
    except OSError as exc:
        raise InputError(f"cannot be read: {exc.strerror}", path=p) from None
    if not head:
        raise InputError("file is empty", path=p)
    if head.startswith(b"#ROSBAG V2.0"):
        return "ros1"
    if head.startswith(b"#ROSRECORD V1.") or head.startswith(b"#ROSBAG V1."):
        version = head.split(b"V", 1)[1].split(b"\n", 1)[0].decode("ascii", "replace")
        raise InputError(
            f"unsupported bag version {version}: only ROS 1 bag v2.0 (ROS Diamondback and later) "
            "is read; convert it with 'rosbag fix' in a ROS 1 install",
            path=p,
        )
    if head.startswith(b"#ROSBAG"):
        raise InputError("unsupported ROS bag version", path=p, field="header")
    if p.suffix in _ROS2_SUFFIXES or head.startswith(b"SQLite format 3") or head.startswith(b"\x89MCAP"):
        return "ros2"
    return "carmen"


def open_recording(path: str | Path, options: ReadOptions | None = None) -> Recording:
    """Open a CARMEN log (plain or gzipped), a ROS 1 bag or a ROS 2 bag for streaming."""
    kind = detect_format(path)
    if kind == "carmen":
        from slam2d.io.carmen import CarmenLog

        return CarmenLog(path, options)
    from slam2d.io.rosbag import RosBag

    return RosBag(path, options)
