"""A run's session (``RUN/session/``): what a method needs to go on mapping another day.

A session holds the frames the method was fed (every scan and its odometry), the places where the
robot was put down in the map (``relocations``: where a resumed recording started), where localization
in the saved map placed the new recording's frames (``map_anchors``, see ``SlamMethod.anchor_to_map``) and the settings
and seed of the run. Resuming feeds them to the method again, which rebuilds its state (the methods are
deterministic for a seed and a version; ranges are kept as 32-bit floats, so poses agree to a tenth of a
millimetre), and then goes on with the new recording.

Files: ``session.json`` (format, slam2d version, method, settings, seed, relocations, map anchors, the frames'
file name, size and SHA-256) and ``frames.npz`` (numpy arrays, no pickled objects: a session from a
stranger cannot run code). A session of another format, version or method, or whose frames do not
match their checksum (cut short, edited), is refused with the reason.

``frames.npz``: ``time`` (N,), ``beam_start`` (N + 1,) into ``ranges`` (float32, NaN = no return),
``angle_min``, ``angle_increment``, ``range_min``, ``range_max`` (N,), ``mount`` (N, 3),
``odometry`` (N, 3) and ``has_odometry`` (N,).
"""

from __future__ import annotations

import hashlib
import io
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slam2d.core.frames import Frame
from slam2d.core.scan import LaserScan
from slam2d.errors import InputError

__all__ = ["SESSION_FORMAT", "SessionRecorder", "Session", "read_session", "write_session"]

SESSION_FORMAT = "slam2d-session-1"
_ARRAYS = ("time", "beam_start", "ranges", "angle_min", "angle_increment", "range_min", "range_max", "mount",
           "odometry", "has_odometry")


class SessionRecorder:
    """The frames of a run, kept compactly (float32 ranges) as they are fed."""

    def __init__(self) -> None:
        self.ranges: list[NDArray[np.float32]] = []
        self.rows: list[tuple] = []
        self.relocations: list[dict[str, Any]] = []
        self.map_anchors: list[dict[str, Any]] = []

    def __len__(self) -> int:
        return len(self.rows)

    def add(self, frame: Frame) -> None:
        s = frame.scan
        self.ranges.append(np.asarray(s.ranges, dtype=np.float32))
        odom = frame.odometry
        self.rows.append((s.timestamp, s.angle_min, s.angle_increment, s.range_min, s.range_max,
                          tuple(float(v) for v in s.mount),
                          (math.nan,) * 3 if odom is None else tuple(float(v) for v in odom), odom is not None))

    def relocated(self, pose: NDArray[np.float64]) -> None:
        """The robot was put down at ``pose`` (map frame) before the next frame."""
        self.relocations.append({"before_frame": len(self.rows), "pose": [float(v) for v in pose]})

    def anchored(self, pose: NDArray[np.float64]) -> None:
        """Localization in the saved map placed the next frame at ``pose``."""
        self.map_anchors.append({"before_frame": len(self.rows), "pose": [float(v) for v in pose]})

    def arrays(self) -> dict[str, NDArray]:
        n = len(self.rows)
        lengths = np.array([len(r) for r in self.ranges], dtype=np.int64)
        cols = list(zip(*self.rows)) if n else [()] * 8
        return {
            "time": np.array(cols[0], dtype=np.float64),
            "beam_start": np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64),
            "ranges": np.concatenate(self.ranges) if n else np.zeros(0, np.float32),
            "angle_min": np.array(cols[1], dtype=np.float64),
            "angle_increment": np.array(cols[2], dtype=np.float64),
            "range_min": np.array(cols[3], dtype=np.float64),
            "range_max": np.array(cols[4], dtype=np.float64),
            "mount": np.array(cols[5], dtype=np.float64).reshape(n, 3),
            "odometry": np.array(cols[6], dtype=np.float64).reshape(n, 3),
            "has_odometry": np.array(cols[7], dtype=np.bool_),
        }


@dataclass
class Session:
    """A session read back: its record (``session.json``) and its frames."""

    path: Path
    record: dict[str, Any]
    arrays: dict[str, NDArray] = field(repr=False)

    @property
    def method(self) -> str:
        return str(self.record["method"])

    def __len__(self) -> int:
        return int(len(self.arrays["time"]))

    def frames(self):
        """The frames, in the order they were fed: ``(frame, relocation pose or None, map anchor or None)``."""
        a = self.arrays

        def by_frame(key: str) -> dict[int, NDArray[np.float64]]:
            return {int(r["before_frame"]): np.asarray(r["pose"], dtype=np.float64) for r in self.record.get(key, [])}

        moves, anchors = by_frame("relocations"), by_frame("map_anchors")
        for k in range(len(self)):
            ranges = a["ranges"][a["beam_start"][k]:a["beam_start"][k + 1]].astype(np.float64)
            scan = LaserScan(float(a["time"][k]), ranges, float(a["angle_min"][k]), float(a["angle_increment"][k]),
                             float(a["range_min"][k]), float(a["range_max"][k]), mount=a["mount"][k].copy())
            odom = a["odometry"][k].copy() if a["has_odometry"][k] else None
            yield Frame(k, scan, odom), moves.get(k), anchors.get(k)


def write_session(folder: Path, recorder: SessionRecorder, *, method: str, params: dict[str, Any], seed: int,
                  version: str) -> list[Path]:
    """Write ``folder/frames.npz`` and ``folder/session.json`` (atomically, each)."""
    from slam2d.io.atomic import write_bytes_atomic, write_json_atomic

    folder.mkdir(parents=True, exist_ok=True)
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **recorder.arrays())
    data = buffer.getvalue()
    frames_path = folder / "frames.npz"
    write_bytes_atomic(frames_path, data)
    record = {
        "format": SESSION_FORMAT,
        "slam2d": version,
        "method": method,
        "params": params,
        "seed": seed,
        "frames": {"file": frames_path.name, "count": len(recorder), "bytes": len(data),
                   "sha256": hashlib.sha256(data).hexdigest()},
        "relocations": recorder.relocations,
        "map_anchors": recorder.map_anchors,
    }
    json_path = folder / "session.json"
    write_json_atomic(json_path, record)
    return [frames_path, json_path]


def read_session(run: str | Path, *, version: str, method: str | None = None) -> Session:
    """The session of a run folder (``RUN/session``), checked: format, version, method, checksum."""
    run = Path(run)
    folder = run / "session" if (run / "session").is_dir() else run
    json_path = folder / "session.json"
    if not json_path.is_file():
        raise InputError("has no session (session/session.json): runs of slam2d before sessions, or not a run folder",
                         path=run)
    try:
        record = json.loads(json_path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"is not JSON: {exc}", path=json_path) from None
    if not isinstance(record, dict) or record.get("format") != SESSION_FORMAT:
        got = record.get("format") if isinstance(record, dict) else None
        raise InputError(f"format {got!r}, this slam2d reads {SESSION_FORMAT!r}", path=json_path, field="format")
    if record.get("slam2d") != version:
        raise InputError(f"written by slam2d {record.get('slam2d')}, this is {version}: a method rebuilt by another "
                         "version may differ; rerun the first recording with this one", path=json_path, field="slam2d")
    if method is not None and record.get("method") != method:
        raise InputError(f"a session of {record.get('method')}, not of {method}", path=json_path, field="method")
    info = record.get("frames") or {}
    frames_path = folder / str(info.get("file", "frames.npz"))
    if not frames_path.is_file():
        raise InputError("is missing", path=frames_path)
    data = frames_path.read_bytes()
    if hashlib.sha256(data).hexdigest() != info.get("sha256"):
        raise InputError(f"does not match its SHA-256 in session.json ({len(data)} bytes, {info.get('bytes')} "
                         "written): cut short or edited", path=frames_path, field="frames.sha256")
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as npz:
            arrays = {name: npz[name] for name in _ARRAYS}
    except (ValueError, KeyError, OSError) as exc:
        raise InputError(f"cannot be read: {exc}", path=frames_path) from None
    return Session(folder, record, arrays)
