"""Run a method on a recording and write a run folder that says how to repeat it.

A run folder holds

* ``trajectory.tum``: the estimated robot base pose at every scan that got one;
* ``map.yaml`` + ``map.pgm`` (map_server), ``preview.png``, ``map.json``;
* ``diagnostics.json``: per-update timing and the method's own values;
* ``run.json``: the method, its parameter values (the advanced ones only where
  changed from their defaults), the seed, the input file's
  SHA-256, the reading options, the versions of slam2d, Python and every
  dependency, and the peak memory. ``slam2d run METHOD DATA --params run.json``
  repeats the run with the same parameters and seed.

``run.json`` is written last, so a folder without it is not a finished run.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import platform
import resource
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime, timezone
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

import numpy as np

from slam2d.core.compile_time import compile_clock
from slam2d.core.memory import resident_bytes
from slam2d.errors import InputError
from slam2d.io.base import ProgressCallback, ReadOptions
from slam2d.io.session import SessionRecorder
from slam2d.methods.base import SlamMethod
from slam2d.methods.registry import get_method
from slam2d.params import as_dict, as_record, from_mapping
from slam2d.sensors.recording_profile import measure_profile

__all__ = ["RunSummary", "build_method", "build_method_for", "json_params", "read_params_file", "run_method",
           "write_live_run", "input_digest", "versions"]

RUN_FORMAT = 1
_DEPENDENCIES = ("numpy", "scipy", "numba", "rosbags", "matplotlib", "pyyaml", "pillow", "rich")


@dataclass
class RunSummary:
    """What :func:`run_method` did and where it wrote it."""

    method: str
    out_dir: Path
    written: list[Path]
    frames: int
    poses: int
    seconds: float
    record: dict[str, Any]  # the content of run.json


def versions() -> dict[str, str]:
    """slam2d, Python and dependency versions, for run.json and the benchmarks."""
    import slam2d

    out = {"slam2d": slam2d.__version__, "python": platform.python_version()}
    for name in _DEPENDENCIES:
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            out[name] = "not installed"
    out["platform"] = platform.platform()
    return out


def input_digest(path: str | Path) -> dict[str, Any]:
    """SHA-256 of a recording: of the file, or of every file in a folder (a ROS 2 bag), names included."""
    path = Path(path)
    h = hashlib.sha256()
    files = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
    size = 0
    for f in files:
        if path.is_dir():
            h.update(str(f.relative_to(path)).encode() + b"\0")
        with open(f, "rb") as stream:
            while chunk := stream.read(1 << 20):
                h.update(chunk)
                size += len(chunk)
    return {"sha256": h.hexdigest(), "bytes": size}


def read_params_file(path: str | Path) -> tuple[dict[str, Any], dict[str, Any]]:
    """A YAML (or JSON) parameter file: ``(parameters, extras)``.

    Either a flat mapping ``name: value``, or a mapping with a ``params``
    section (as ``run.json`` has), whose ``method``, ``seed`` and
    ``sensor_model`` come back in ``extras``.
    """
    from slam2d.io.yaml_file import read_yaml

    path = Path(path)
    doc = read_yaml(path, "parameter file")
    if doc is None:
        return {}, {}
    if not isinstance(doc, dict):
        raise InputError(f"expected a mapping of parameter names to values, got {type(doc).__name__}", path=path)
    if "params" in doc:
        params = doc["params"]
        if not isinstance(params, dict):
            raise InputError("'params' must be a mapping of parameter names to values", path=path, field="params")
        extras = {k: doc[k] for k in ("method", "seed", "sensor_model") if k in doc}
        return dict(params), extras
    return dict(doc), {}


def build_method(
    method: str,
    *,
    settings: Mapping[str, Any] | None = None,
    params_file: str | Path | None = None,
    seed: int | None = None,
    sensor_model: Any = None,
    profile: Any = None,
) -> SlamMethod:
    """Construct a method by name from a parameter file and ``name=value`` settings (settings win).

    The seed is the one given, else the parameter file's (a ``run.json``), else 0.
    ``sensor_model`` is a range noise model, or its ``--sensor-model`` text (a
    model file, ``study``, ``constant:SIGMA``); without one, a ``run.json``'s
    model is used again.
    """
    cls = get_method(method)
    values: dict[str, Any] = {}
    extras: dict[str, Any] = {}
    file_seed = None
    notes: list[str] = []
    if params_file is not None:
        values, extras = read_params_file(params_file)
        if not extras:  # a slam_toolbox or slam_gmapping YAML: under slam2d's names and units
            from slam2d.io.ros_params import ros_params

            ros = ros_params(values, params_file, cls.Params, cls.name)
            if ros is not None:
                values, notes = ros.values, ros.notes
        if extras.get("method") not in (None, cls.name):
            raise InputError(
                f"this file is for method {extras['method']!r}, not {cls.name!r}", path=params_file, field="method"
            )
        file_seed = extras.get("seed")
        if file_seed is not None and (not isinstance(file_seed, int) or isinstance(file_seed, bool) or file_seed < 0):
            raise InputError(f"{file_seed!r} is not a whole number >= 0", path=params_file, field="seed")
        params = from_mapping(cls.Params, values, path=params_file)
        values = as_dict(params)
    if settings:
        values.update(settings)
    params = from_mapping(cls.Params, values)
    chosen_seed = seed if seed is not None else (int(file_seed) if file_seed is not None else 0)
    from_file = False
    if sensor_model is None and params_file is not None:
        recorded = extras.get("sensor_model")
        if isinstance(recorded, dict) and recorded.get("spec"):
            sensor_model, from_file = recorded["spec"], True
    if isinstance(sensor_model, str):
        from slam2d.sensors.calibration.model import sensor_model_from_spec

        try:
            sensor_model = sensor_model_from_spec(sensor_model)
        except InputError as exc:  # the model a run.json recorded and that is gone: say which file named it
            if not from_file or exc.path is not None:
                raise
            raise InputError(f"{exc.message} (the model this file recorded)", path=params_file,
                             field="sensor_model.spec") from None
    slam = cls(params, seed=chosen_seed, sensor_model=sensor_model, profile=profile)
    slam.param_notes = notes
    return slam


def build_method_for(method: str, frames: Sequence[Any], **kwargs: Any) -> SlamMethod:
    """:func:`build_method` with its ``auto`` parameters resolved from ``frames`` (a recording's, in order).

    The recording is measured (:func:`~slam2d.sensors.recording_profile.measure_profile`) only when
    some parameter is still ``auto``; the profile and the time it took go into the diagnostics' summary.
    """
    slam = build_method(method, **kwargs)
    return _with_profile(method, frames, kwargs) if slam.auto else slam


def _with_profile(method: str, frames: Sequence[Any], kwargs: Mapping[str, Any]) -> SlamMethod:
    """The method built again with the profile of ``frames`` (its ``auto`` parameters resolved)."""
    t0 = time.perf_counter()
    profile = measure_profile(frames)
    slam = build_method(method, profile=profile, **kwargs)
    slam.diagnostics.summary["profile_wall_s"] = time.perf_counter() - t0
    slam.diagnostics.summary["profile"] = profile.as_dict() if profile is not None else None
    return slam


def _rss_mb() -> float:
    """Resident memory now (MB), from /proc; NaN where there is none."""
    resident = resident_bytes()
    return float("nan") if resident is None else resident / 1e6


def _peak_rss_mb() -> float:
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / 1024.0 if sys.platform != "darwin" else peak / 1e6  # KiB on Linux, bytes on macOS


def run_method(
    method: str | SlamMethod,
    data: str | Path,
    out_dir: str | Path,
    *,
    settings: Mapping[str, Any] | None = None,
    params_file: str | Path | None = None,
    seed: int | None = None,
    read_options: ReadOptions | None = None,
    progress: ProgressCallback | None = None,
    command: str = "",
    sensor_model: Any = None,
) -> RunSummary:
    """Run a method (a name, or an instance already built) over every frame of ``data``; write the run folder.

    ``sensor_model`` (a model or its ``--sensor-model`` text) is for a method given by name.
    """
    from slam2d.io import detect_format, open_recording

    data = Path(data)
    out_dir = Path(out_dir)
    options = read_options if read_options is not None else ReadOptions()
    recording = open_recording(data, options)
    source: Any = recording.frames(progress)
    rss_before = _rss_mb()
    compile0 = compile_clock()[0]
    wall0 = time.perf_counter()  # reading is part of a run's time, and so is measuring the recording
    if isinstance(method, SlamMethod):
        slam = method
    else:
        build = {"settings": settings, "params_file": params_file, "seed": seed, "sensor_model": sensor_model}
        slam = build_method(method, **build)
        if slam.auto:  # auto parameters: measure the recording first, then build the method again with them
            source = list(source)
            slam = _with_profile(method, source, build)
    digest = input_digest(data)
    started = datetime.now(timezone.utc)
    frames = 0
    first_t = last_t = None
    # read already (to measure it for the auto parameters): the progress is the frames run, not the bytes read
    count = len(source) if isinstance(source, list) and progress is not None else 0
    session = SessionRecorder()
    for frame in source:
        session.add(frame)
        try:
            slam.feed(frame)
        except InputError as exc:  # e.g. a corrupt pose that would grow the map without bound
            raise exc.in_file(data, f"scan {frames + 1} at t={frame.timestamp:.3f} s") from None
        frames += 1
        if count:
            progress(frames, count)
        if first_t is None:
            first_t = frame.timestamp
        last_t = frame.timestamp
    if frames == 0:
        raise InputError("no laser scans in the recording", path=data)
    seconds = _finish(slam, compile0, wall0)
    peak = _peak_rss_mb()
    return _write_run(
        slam, out_dir,
        data=data, data_format=detect_format(data), digest=digest, options=options, frames=frames,
        span=(first_t, last_t), started=started, seconds=seconds, rss_before=rss_before, peak=peak,
        problems=recording.problems.lines(), command=command, session=session,
    )


def _finish(slam: SlamMethod, compile0: float, wall0: float) -> float:
    """End the run (the method's finish); its wall time since ``wall0``, compiling kernels (a fresh install)
    not counted, and that compile time kept in the diagnostics."""
    slam.timed_finish()
    compiled = compile_clock()[0] - compile0
    slam.diagnostics.summary["compile_s"] = compiled
    return time.perf_counter() - wall0 - compiled


def _odometry_warnings(slam: SlamMethod, frames: int) -> list[str]:
    """A method that needs odometry, run on scans without it: say so (it ran, but on guesses)."""
    missing = int(slam.diagnostics.counters.get("frames_without_odometry", 0))
    if slam.odometry_role() != "required" or missing == 0:
        return []
    from slam2d.methods.registry import available

    free = [n for n, cls in available().items() if cls.odometry_role() != "required"]
    return [f"{missing} of {frames} scans had no odometry: {slam.name} needs it and placed them from the last pose "
            f"(check --odometry and the topics with 'slam2d info'; methods that need none: {', '.join(free)})"]


def write_live_run(slam: SlamMethod, out_dir: Path, *, source: str, frames: int,
                   span: tuple[float | None, float | None], started: datetime, seconds: float,
                   command: str, session: SessionRecorder | None = None,
                   extra: dict[str, Any] | None = None) -> RunSummary:
    """The run folder of a method fed live (``slam2d ros``): what ``slam2d run`` writes, ``source`` for the data.

    Written whole into a staging folder that then replaces ``out_dir`` (an earlier output of the node).
    """
    from slam2d.io.atomic import staged_folder

    peak = _peak_rss_mb()
    with staged_folder(out_dir, "ros") as stage:
        summary = _write_run(slam, stage, data=source, data_format="live", digest={}, options=ReadOptions(),
                             frames=frames, span=span, started=started, seconds=seconds, rss_before=math.nan,
                             peak=peak, problems=[], command=command, session=session, extra=extra)
    return summary


def json_params(values: Mapping[str, Any]) -> dict[str, Any]:
    """Parameter values as a run records them: as text where not finite ("inf"), as JSON has no infinity and a
    rerun with --params run.json reads it back."""
    return {k: (str(v) if isinstance(v, float) and not math.isfinite(v) else v) for k, v in values.items()}


def _recorded_params(slam: SlamMethod) -> dict[str, Any]:
    """The parameters ``run.json`` and the session record: :func:`~slam2d.params.as_record`'s, the advanced ones
    only where changed (:func:`build_method` fills in the rest)."""
    return json_params(as_record(slam.params))


def _write_run(
    slam: SlamMethod,
    out_dir: Path,
    *,
    data: Path | str,
    data_format: str,
    digest: dict[str, Any],
    options: ReadOptions,
    frames: int,
    span: tuple[float | None, float | None],
    started: datetime,
    seconds: float,
    rss_before: float,
    peak: float,
    problems: list[str],
    command: str,
    session: SessionRecorder | None = None,
    extra: dict[str, Any] | None = None,
) -> RunSummary:
    from slam2d.io.atomic import write_json_atomic
    from slam2d.io.tum import write_tum
    from slam2d.report.map_outputs import write_map_outputs

    times, poses = slam.trajectory()
    if len(times) == 0:
        raise InputError(
            f"{slam.name} placed none of the {frames} scans (no odometry or no poses for them)", path=data
        )
    grid = slam.written_map()
    if not grid.observed.any():  # refused before anything is written: no run folder without its map
        raise InputError(
            f"{slam.name} mapped nothing: none of the {frames} scans had a return it could use "
            "(every beam no-return, or too few beams)", path=data,
        )
    out_dir.mkdir(parents=True, exist_ok=True)
    written = [write_tum(out_dir / "trajectory.tum", times, poses)]
    written += write_map_outputs(grid, out_dir)
    written += slam.extra_outputs(out_dir)
    if session is not None:
        from slam2d import __version__
        from slam2d.io.session import write_session

        written += write_session(out_dir / "session", session, method=slam.name, params=_recorded_params(slam),
                                 seed=slam.seed, version=__version__)
    slam.diagnostics.summary.update({"peak_rss_mb": peak, "rss_before_mb": rss_before})
    diag = {"method": slam.name, "descriptions": {**slam.COMMON_DIAGNOSTICS, **slam.DIAGNOSTICS},
            **slam.diagnostics.as_dict()}
    diag_path = out_dir / "diagnostics.json"
    write_json_atomic(diag_path, diag, indent=None)
    written.append(diag_path)
    from slam2d.sensors.calibration.model import describe_sensor_model

    record = {
        "format": RUN_FORMAT,
        "method": slam.name,
        "params": _recorded_params(slam),
        "seed": slam.seed,
        "auto": slam.auto,
        "sensor_model": describe_sensor_model(slam.sensor_model),
        # a recording's file, or a live source (a ROS topic) with no file to name
        "data": ({"path": str(data.resolve()), "format": data_format, **digest} if isinstance(data, Path)
                 else {"source": str(data), "format": data_format}),
        "read_options": as_dict(options),
        "scans": frames,
        "poses": int(len(times)),
        "data_span_s": [span[0], span[1]],
        "started": started.isoformat(timespec="seconds"),
        "wall_s": seconds,
        "compile_s": slam.diagnostics.summary.get("compile_s", 0.0),
        "peak_rss_mb": peak,
        "rss_growth_mb": peak - rss_before,
        "input_problems": problems,
        "warnings": slam.param_notes + _odometry_warnings(slam, frames),
        "versions": versions(),
        "command": command,
        **(extra or {}),
    }
    run_path = out_dir / "run.json"
    write_json_atomic(run_path, record)
    written.append(run_path)
    return RunSummary(slam.name, out_dir, written, frames, int(len(times)), seconds, record)


def replay_session(slam: SlamMethod, session: Any, recorder: SessionRecorder) -> tuple[int, float | None]:
    """Feed a session's frames (and relocations, map anchors) to ``slam`` and ``recorder``: ``(poses it placed,
    last time)``."""
    last_t = None
    for frame, relocation, anchor in session.frames():
        if relocation is not None:
            slam.relocate(relocation)
            recorder.relocated(relocation)
        if anchor is not None:
            slam.anchor_to_map(anchor)
            recorder.anchored(anchor)
        recorder.add(frame)
        slam.feed(frame)
        last_t = frame.timestamp
    return len(slam.trajectory()[0]), last_t


def resume_run(
    method: str,
    run: str | Path,
    data: str | Path,
    out_dir: str | Path,
    *,
    initial_pose: Any = None,
    read_options: ReadOptions | None = None,
    progress: ProgressCallback | None = None,
    command: str = "",
) -> RunSummary:
    """Go on mapping in ``run``'s map with the recording ``data``; write the joined run folder.

    The session's frames are fed again (the method's state rebuilt, same settings and seed),
    the new recording's start is found in ``run``'s map (:class:`~slam2d.localization.Localizer`,
    matching from ``initial_pose`` or a global search), the scans before that traced back along the
    odometry in the same map, the method is put down at the first one, and the new frames follow,
    their times moved after the session's when they start earlier; the localization goes on in the saved map
    and where it places a frame the method is told (:meth:`SlamMethod.anchor_to_map`, which holds a graph
    method's new nodes to the saved map). ``trajectory.tum`` holds the new
    recording's poses (at its own times), in the saved map's frame.
    """
    from slam2d import __version__
    from slam2d.io import detect_format, open_recording
    from slam2d.io.session import read_session
    from slam2d.localization.localizer import LocalizationParams, Localizer, map_anchor
    from slam2d.io.map_server import load_map_grid

    run, data, out_dir = Path(run), Path(data), Path(out_dir)
    session = read_session(run, version=__version__, method=method)
    slam = build_method(method, settings=session.record["params"], seed=int(session.record["seed"]))
    if not slam.can_relocate():
        raise InputError(f"{slam.name} cannot go on from a saved session", field="--resume")
    grid, _ = load_map_grid(run)
    options = read_options if read_options is not None else ReadOptions()
    recording = open_recording(data, options)
    new = list(recording.frames(progress))
    if not new:
        raise InputError("no laser scans in the recording", path=data)
    # where the new recording starts in the saved map
    localizer = Localizer(grid, LocalizationParams(method="match"), seed=slam.seed, initial_pose=initial_pose)
    start = None
    for k, frame in enumerate(new):
        r = localizer.feed(frame)
        if r.pose is not None:
            start = (k, r.pose)
            break
    if start is None:
        raise InputError(f"its robot was never found in {run / 'map.yaml'}: no place fits its scans well and for long "
                         "enough (is it the same building? try --initial-pose X,Y,THETA)", path=data)
    found, pose = start
    # the scans before it was found are mapped too: their poses traced back from there along the odometry,
    # matched to the saved map (the search told the place apart on them); without odometry they cannot be
    traced = localizer.traced_back(new[:found + 1], pose) if found else None
    first, placed = (0, traced[0]) if traced is not None else (found, pose)
    rss_before = _rss_mb()
    compile0 = compile_clock()[0]
    wall0 = time.perf_counter()
    started = datetime.now(timezone.utc)
    recorder = SessionRecorder()
    replayed, old_last_t = replay_session(slam, session, recorder)
    period = float(np.median(np.diff([f.timestamp for f in new[first:]]))) if len(new) - first > 1 else 0.1
    shift = max(0.0, (old_last_t or 0.0) + period - new[first].timestamp)
    slam.relocate(placed)
    recorder.relocated(placed)
    for k, frame in enumerate(new[first:], start=first):
        moved = dataclasses.replace(frame, scan=dataclasses.replace(frame.scan, timestamp=frame.scan.timestamp + shift))
        at = pose if k == found else map_anchor(localizer.feed(frame)) if k > found else None
        if at is not None:
            slam.anchor_to_map(at)
            recorder.anchored(at)
        recorder.add(moved)
        try:
            slam.feed(moved)
        except InputError as exc:
            raise exc.in_file(data, f"scan {frame.index + 1} at t={frame.timestamp:.3f} s") from None
    seconds = _finish(slam, compile0, wall0)
    times, poses = slam.trajectory()
    own = times[replayed:] - shift  # the new recording's poses, at its own times
    extra = {"resumed": {"from": str(run.resolve()), "session_frames": len(session),
                         "found_at_scan": found, "found_at": [float(v) for v in pose],
                         "placed_at": [float(v) for v in placed], "scans_before_placed": first, "time_shift_s": shift}}
    return _write_run(
        OwnTrajectory(slam, own, poses[replayed:]), out_dir, data=data, data_format=detect_format(data),
        digest=input_digest(data), options=options, frames=len(new) - first,
        span=(new[first].timestamp, new[-1].timestamp), started=started, seconds=seconds, rss_before=rss_before,
        peak=_peak_rss_mb(), problems=recording.problems.lines(), command=command, session=recorder, extra=extra,
    )


class OwnTrajectory:
    """A resumed method whose trajectory is the new recording's alone (at its own times); the rest is the method."""

    def __init__(self, slam: SlamMethod, times: Any, poses: Any) -> None:
        self._slam, self._times, self._poses = slam, times, poses

    def trajectory(self) -> tuple[Any, Any]:
        return self._times, self._poses

    def __getattr__(self, name: str) -> Any:
        return getattr(self._slam, name)
