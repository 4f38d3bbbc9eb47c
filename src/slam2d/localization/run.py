"""``slam2d localize``: a recording localized in a fixed map, written as a folder.

Writes ``trajectory.tum`` (the poses while localized, in the map's frame), ``localization.csv`` (every
scan: its state, pose (also off the map: from the odometry), fit and particle spread) and ``localization.json`` (when it was localized,
lost and found again; time per scan; the settings).
"""

from __future__ import annotations

import csv
import io
import math
import time
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from slam2d.core.compile_time import compile_clock
from slam2d.errors import InputError
from slam2d.io.map_server import load_map_grid
from slam2d.localization.localizer import LocalizationParams, Localizer
from slam2d.params import as_dict

__all__ = ["load_map_grid", "localize_recording", "parse_pose", "LocalizationSummary", "LocalizationLog",
           "write_localization"]


def parse_pose(text: str, field: str = "--initial-pose") -> np.ndarray:
    """``"X,Y,THETA"`` (metres, metres, radians) as a pose."""
    parts = [p.strip() for p in str(text).split(",")]
    try:
        values = [float(p) for p in parts]
    except ValueError:
        values = []
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise InputError(f"{text!r} is not X,Y,THETA (three numbers: metres, metres, radians)", field=field)
    return np.array(values)


@dataclass
class LocalizationSummary:
    out_dir: Path
    written: list[Path]
    record: dict[str, Any]


class LocalizationLog:
    """Every scan's answer, and the CPU time it took (compilation not counted): what the outputs are made of."""

    def __init__(self) -> None:
        self.rows: list[tuple] = []
        self.cpu: list[float] = []
        self.started = datetime.now(timezone.utc)
        self.compile0 = compile_clock()[1]

    def feed(self, localizer: Localizer, frame: Any) -> Any:
        c0, k0 = time.process_time(), compile_clock()[1]
        r = localizer.feed(frame)
        self.cpu.append(time.process_time() - c0 - (compile_clock()[1] - k0))
        pose = r.pose if r.pose is not None else (np.nan, np.nan, np.nan)
        self.rows.append((r.timestamp, r.state, *pose, r.fit, r.spread, r.particles))
        return r


def write_localization(out_dir: Path, log: LocalizationLog, localizer: Localizer, *, map_path: Path,
                       data: dict[str, Any], seed: int, initial_pose: np.ndarray | None, command: str,
                       problems: list[str] | None = None) -> LocalizationSummary:
    """Write ``trajectory.tum`` (when localized at all), ``localization.csv`` and ``localization.json``."""
    from slam2d.io.atomic import write_json_atomic, write_text_atomic
    from slam2d.io.tum import write_tum
    from slam2d.methods.runner import versions

    rows, params = log.rows, localizer.p
    out_dir.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    localized = [row for row in rows if row[1] == "localized"]
    if localized:
        written.append(write_tum(out_dir / "trajectory.tum", [row[0] for row in localized],
                                 [row[2:5] for row in localized]))
    text = io.StringIO()
    w = csv.writer(text, lineterminator="\n")
    w.writerow(["time", "state", "x", "y", "theta", "fit", "spread_m", "particles"])
    for t, state, x, y, th, fit, spread, n in rows:
        w.writerow([f"{t:.6f}", state, *(("" if math.isnan(v) else f"{v:.5f}") for v in (x, y, th, fit, spread)), n])
    csv_path = out_dir / "localization.csv"
    write_text_atomic(csv_path, text.getvalue())
    written.append(csv_path)
    first = next((i for i, row in enumerate(rows) if row[1] == "localized"), None)
    cpu_ms = 1000.0 * np.asarray(log.cpu if log.cpu else [0.0])
    record = {
        "format": "slam2d-localization-1",
        "method": params.method,
        "params": as_dict(params),
        "seed": seed,
        "initial_pose": None if initial_pose is None else [float(v) for v in initial_pose],
        "map": str(map_path.resolve()),
        "data": data,
        "scans": len(rows),
        "data_span_s": [rows[0][0], rows[-1][0]] if rows else [None, None],
        "localized_scans": len(localized),
        "off_map_scans": sum(1 for row in rows if row[1] == "off_map"),
        "localized": first is not None,
        "first_localized": None if first is None else {"scan": first + 1, "time": rows[first][0],
                                                       "fraction_of_scans": (first + 1) / len(rows)},
        "events": localizer.events,
        "lost": sum(1 for e in localizer.events if e["state"] == "lost"),
        "cpu_ms_per_scan": {"median": float(np.median(cpu_ms)), "mean": float(np.mean(cpu_ms)),
                            "p95": float(np.percentile(cpu_ms, 95))},
        "compile_s": compile_clock()[1] - log.compile0,
        "started": log.started.isoformat(timespec="seconds"),
        "input_problems": problems or [],
        "versions": versions(),
        "command": command,
    }
    json_path = out_dir / "localization.json"
    write_json_atomic(json_path, record)
    written.append(json_path)
    return LocalizationSummary(out_dir, written, record)


def localize_recording(map_source: str | Path, data: str | Path, out_dir: str | Path, *,
                       params: LocalizationParams | None = None, seed: int = 0,
                       initial_pose: np.ndarray | None = None, read_options: Any = None,
                       progress: Any = None, command: str = "") -> LocalizationSummary:
    from slam2d.io import detect_format, open_recording
    from slam2d.methods.runner import input_digest

    params = params if params is not None else LocalizationParams()
    grid, yaml_path = load_map_grid(map_source)
    data, out_dir = Path(data), Path(out_dir)
    localizer = Localizer(grid, params, seed=seed, initial_pose=initial_pose)
    recording = open_recording(data, read_options)
    log = LocalizationLog()
    for frame in recording.frames(progress):
        try:
            log.feed(localizer, frame)
        except InputError as exc:
            raise exc.in_file(data, f"scan {len(log.rows) + 1} at t={frame.timestamp:.3f} s") from None
    if not log.rows:
        raise InputError("no laser scans in the recording", path=data)
    return write_localization(out_dir, log, localizer, map_path=yaml_path, seed=seed, initial_pose=initial_pose,
                              data={"path": str(data.resolve()), "format": detect_format(data), **input_digest(data)},
                              command=command, problems=recording.problems.lines())
