"""``slam2d evaluate``: how good is a run, against ground truth, a reference, or nothing.

:func:`evaluate_run` computes, for one run folder (what ``slam2d run`` wrote):

* trajectory error against a ground-truth or reference trajectory: ATE after
  the best SE(2) alignment (and before it), RPE per frame and per metre
  (:mod:`slam2d.eval.trajectory_metrics`);
* the relation metric of Kümmerle et al. 2009 on a Freiburg ``.relations`` file;
* map quality against a ground-truth map (Santos et al. 2013's mean distance
  from each true obstacle cell to the nearest map obstacle, the reverse
  direction, precision and recall at a tolerance), with the map brought into
  the truth's frame by the trajectory alignment (or ICP on the obstacle cells
  when there is a truth map but no truth trajectory);
* map quality without ground truth (Filatov et al. 2017);
* cost: wall and CPU time per scan, real-time factor, peak memory.
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterable

import numpy as np
from numpy.typing import NDArray

from slam2d.errors import InputError
from slam2d.io.atomic import json_ready

__all__ = ["MetricColumn", "METRIC_COLUMNS", "GroundTruth", "RunFiles", "load_truth", "load_reference", "load_run", "evaluate_run", "cost_metrics"]

TRUTH_TRAJECTORY = "truth.tum"
TRUTH_MAP = "truth-map.yaml"


@dataclass(frozen=True)
class MetricColumn:
    """One column of a comparison table: where the value sits in an evaluation, and which way is better."""

    key: tuple[str, ...]  # path into the dict evaluate_run returns
    label: str
    unit: str
    better: str | None  # "lower", "higher", or None when the direction is disputed
    digits: int = 3
    scale: float = 1.0  # shown value = stored value * scale (seconds shown as ms)
    help: str = ""

    def value(self, evaluation: dict[str, Any] | None) -> float | None:
        node: Any = evaluation
        for k in self.key:
            if not isinstance(node, dict) or k not in node:
                return None
            node = node[k]
        if node is None or not isinstance(node, (int, float)) or not math.isfinite(float(node)):
            return None
        return float(node) * self.scale

    def best(self, values: list[float | None]) -> float | None:
        """The best of the values (None when no direction or no values)."""
        present = [v for v in values if v is not None]
        if not present or self.better is None:
            return None
        return min(present) if self.better == "lower" else max(present)


#: The trajectory's ATE (translation RMSE, m) in an evaluation: ``ATE.value(evaluation)``, None without one.
ATE = MetricColumn(("trajectory", "ate", "translation_m", "rmse"), "ATE", "m", "lower", 3,
                   help="absolute trajectory error (RMSE) after the best SE(2) alignment")

#: The metric table of ``slam2d compare``, its report and the benchmarks, in order.
METRIC_COLUMNS: tuple[MetricColumn, ...] = (
    ATE,
    MetricColumn(("trajectory", "ate", "rotation_deg", "rmse"), "ATE rot.", "deg", "lower", 2,
                 help="heading error (RMSE) after alignment"),
    MetricColumn(("trajectory", "rpe_per_metre", "translation_percent", "mean"), "RPE", "%", "lower", 2,
                 help="relative translation error per metre travelled"),
    MetricColumn(("trajectory", "rpe_per_frame", "rotation_deg", "rmse"), "RPE rot./frame", "deg", "lower", 3,
                 help="relative heading error between consecutive frames (RMSE)"),
    MetricColumn(("relations", "translation_abs_m", "mean"), "Rel. trans.", "m", "lower", 3,
                 help="Kümmerle et al. 2009 relation metric, mean absolute translational error"),
    MetricColumn(("relations", "rotation_abs_deg", "mean"), "Rel. rot.", "deg", "lower", 2,
                 help="Kümmerle et al. 2009 relation metric, mean absolute rotational error"),
    MetricColumn(("self_consistency", "inconsistency"), "Self-disagreement", "%", "lower", 2, 100.0,
                 help="share of beams, each judged against the map of the run's other visits (scans within 5 m "
                 "of travel left out), that contradict it: a wall drawn twice, a bent corridor; no reference "
                 "needed (docs/evaluation.md)"),
    MetricColumn(("self_consistency", "travel_scale"), "Travel/odometry", "", None, 3,
                 help="metres the trajectory moved per metre of odometry (over 2 m stretches): compare between "
                 "runs; one that shrank along corridors moves less"),
    MetricColumn(("self_consistency", "area_m2"), "Map area", "m2", None, 0,
                 help="area the scans cover when mapped at the run's poses (0.1 m cells): compare between runs; "
                 "places drawn twice add area"),
    MetricColumn(("map_truth", "truth_to_map_m", "mean"), "Map error", "m", "lower", 3,
                 help="mean distance from each true obstacle cell to the nearest map obstacle (Santos et al. 2013)"),
    MetricColumn(("map_truth", "map_to_truth_m", "mean"), "Ghost walls", "m", "lower", 3,
                 help="mean distance from each map obstacle cell to the nearest true obstacle"),
    MetricColumn(("map_truth", "precision"), "Precision", "", "higher", 3,
                 help="share of map obstacle cells near a true obstacle"),
    MetricColumn(("map_truth", "recall"), "Recall", "", "higher", 3,
                 help="share of true obstacle cells near a map obstacle"),
    MetricColumn(("map_quality", "occupied_fraction"), "Occupied/known", "", None, 3,
                 help="occupied share of the known cells (Filatov et al. 2017): higher means thicker, blurred "
                 "walls, but grossly wrong maps score low too (free-space rays erase misplaced walls)"),
    MetricColumn(("map_quality", "uncertain_fraction"), "Uncertain/known", "", "lower", 3,
                 help="share of the known cells that are neither clearly free nor clearly occupied"),
    MetricColumn(("map_quality", "corners"), "Corners", "", None, 0,
                 help="corner count (Filatov et al. 2017); double walls add corners, but the direction is disputed"),
    MetricColumn(("map_quality", "enclosed_areas"), "Enclosed areas", "", "lower", 0,
                 help="separate free regions (Filatov et al. 2017): misaligned walls close off false rooms"),
    MetricColumn(("cost", "wall_s_per_scan", "median"), "Time/scan", "ms", "lower", 2, 1000.0,
                 help="median wall time per scan"),
    MetricColumn(("cost", "wall_s_per_scan", "p95"), "Time/scan p95", "ms", "lower", 2, 1000.0,
                 help="95th percentile of the wall time per scan"),
    MetricColumn(("cost", "real_time_factor"), "Real-time factor", "x", "higher", 1,
                 help="recording duration / processing time"),
    MetricColumn(("cost", "peak_rss_mb"), "Peak memory", "MB", "lower", 0,
                 help="peak resident memory of the process that ran the method"),
)


@dataclass
class GroundTruth:
    """A trajectory (and maybe a map) to judge runs against.

    ``kind`` is ``"truth"`` (exact, from a simulation) or ``"reference"`` (a
    trajectory someone trusts, such as the datasets' GMapping-corrected
    ``reference.tum``: good, but not independent ground truth).
    """

    kind: str
    source: Path
    times: NDArray[np.float64] | None
    poses: NDArray[np.float64] | None
    map: Any = None  # OccupancyGrid
    map_path: Path | None = None
    #: The simulated laser (``angle_min``, ``angle_increment``, ``beams``, ``range_max``, ``mount``)
    #: when known: then only the walls it could have seen count in the map comparison.
    laser: dict[str, Any] | None = None
    _visible: Any = None

    @property
    def has_trajectory(self) -> bool:
        return self.times is not None and len(self.times) > 0

    def visible_walls(self, max_poses: int = 3000) -> Any:
        """The true obstacle cells the laser could have hit along the true trajectory (cached), or None."""
        if self._visible is None and self.laser is not None and self.map is not None and self.has_trajectory:
            from slam2d.core import se2
            from slam2d.eval.map_metrics import visible_walls

            step = max(1, len(self.times) // max_poses)
            laser_poses = se2.compose(self.poses[::step], np.asarray(self.laser.get("mount", [0.0, 0.0, 0.0])))
            angles = self.laser["angle_min"] + self.laser["angle_increment"] * np.arange(self.laser["beams"])
            self._visible = visible_walls(self.map, laser_poses, angles=angles, max_range=self.laser["range_max"])
        return self._visible


def load_truth(folder: str | Path) -> GroundTruth:
    """A ground-truth folder as ``slam2d simulate`` writes it: ``truth.tum`` and, if present, ``truth-map.yaml``."""
    from slam2d.io.map_server import read_map
    from slam2d.io.tum import read_tum

    folder = Path(folder)
    if not folder.exists():
        raise InputError("no such folder", path=folder)
    if not folder.is_dir():
        raise InputError("is a file; --truth takes a folder holding truth.tum (use --reference for a TUM file)",
                         path=folder)
    traj = folder / TRUTH_TRAJECTORY
    if not traj.is_file():
        raise InputError(f"the truth folder has no trajectory: {TRUTH_TRAJECTORY} is missing", path=folder)
    times, poses = read_tum(traj)
    grid = None
    map_path = folder / TRUTH_MAP
    if map_path.is_file():
        grid = read_map(map_path).to_grid()
    else:
        map_path = None
    return GroundTruth("truth", folder, times, poses, grid, map_path, laser=_simulated_laser(folder))


def _simulated_laser(folder: Path) -> dict[str, Any] | None:
    """The laser of a simulation (``simulation.json``), or None when the folder has none or it is unreadable."""
    try:
        doc = json.loads((folder / "simulation.json").read_text(encoding="utf-8"))
        laser = dict(doc["laser"])
        laser["mount"] = list(doc.get("robot", {}).get("laser_mount", [0.0, 0.0, 0.0]))
        float(laser["angle_min"]), float(laser["angle_increment"]), int(laser["beams"]), float(laser["range_max"])
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return laser


def load_reference(path: str | Path, *, truth_map: str | Path | None = None) -> GroundTruth:
    """A reference trajectory (TUM), and optionally a reference map (map_server YAML)."""
    from slam2d.io.map_server import read_map
    from slam2d.io.tum import read_tum

    times, poses = read_tum(path)
    grid = read_map(truth_map).to_grid() if truth_map is not None else None
    return GroundTruth("reference", Path(path), times, poses, grid, Path(truth_map) if truth_map else None)


class RunFiles:
    """A run folder, loaded: what ``slam2d run`` wrote.

    ``map_image`` is the map as read (:class:`~slam2d.io.map_server.MapImage`, one byte a cell); ``map`` the
    :class:`~slam2d.grids.occupancy.OccupancyGrid` made from it on first use (six bytes a cell: the map quality
    measures need only the image, and a diverged run's map can hold 40 million cells).
    """

    def __init__(self, folder: Path, times: NDArray[np.float64], poses: NDArray[np.float64], map_image: Any,
                 diagnostics: dict[str, Any], run: dict[str, Any]) -> None:
        self.folder, self.times, self.poses = folder, times, poses
        self.map_image, self.diagnostics, self.run = map_image, diagnostics, run
        self._map: Any = None

    @property
    def map(self) -> Any:
        """The map as an OccupancyGrid (or what was assigned), None without one."""
        if self._map is None and self.map_image is not None:
            self._map = self.map_image.to_grid()
        return self._map

    @map.setter
    def map(self, value: Any) -> None:
        self._map = value


def load_run(path: str | Path) -> RunFiles:
    """A run folder (``trajectory.tum``, ``map.yaml``, ``diagnostics.json``, ``run.json``), or a bare TUM file."""
    from slam2d.io.map_server import read_map
    from slam2d.io.tum import read_tum

    path = Path(path)
    if not path.exists():
        raise InputError("no such file or folder", path=path)
    if path.is_file():
        times, poses = read_tum(path)
        return RunFiles(path, times, poses, None, {}, {})
    traj = path / "trajectory.tum"
    if not traj.is_file():
        raise InputError("not a run folder: trajectory.tum is missing (write one with 'slam2d run')", path=path)
    times, poses = read_tum(traj)
    image = read_map(path / "map.yaml") if (path / "map.yaml").is_file() else None
    if image is not None:
        image.require_unrotated()  # said now, not at the grid's first use
    docs = {}
    for name in ("diagnostics", "run"):
        f = path / f"{name}.json"
        if f.is_file():
            try:
                docs[name] = json.loads(f.read_text(encoding="utf-8"))
            except (UnicodeDecodeError, json.JSONDecodeError) as exc:
                where = getattr(exc, "lineno", None)
                raise InputError(f"not valid JSON: {exc}", path=f, where=where) from None
            if not isinstance(docs[name], dict):
                raise InputError(f"expected a JSON object, got {type(docs[name]).__name__}", path=f)
        else:
            docs[name] = {}
    return RunFiles(path, times, poses, image, docs["diagnostics"], docs["run"])


def recording_frames(run: RunFiles, digests: dict[Path, str] | None = None,
                     ) -> tuple[Callable[[], Iterable[Any]] | None, str | None]:
    """``(frames, None)``: a function reading the recording the run read (``run.json``'s ``data``, with its
    read options), checked by its SHA-256; or ``(None, why not)`` when it cannot be found. Raises
    InputError when the file there is not the one the run read. ``digests`` keeps each file's SHA-256
    between calls (runs of one recording hash it once)."""
    from slam2d.io import open_recording
    from slam2d.io.base import ReadOptions
    from slam2d.methods.runner import input_digest

    data = run.run.get("data") if isinstance(run.run.get("data"), dict) else {}
    if not data.get("path"):
        return None, "run.json names no recording"
    path = Path(data["path"])
    if not path.exists():
        return None, f"the recording {path} (named in run.json) is missing"
    if digests is None:
        digests = {}
    if data.get("sha256") and path not in digests:
        digests[path] = input_digest(path)["sha256"]
    if data.get("sha256") and digests[path] != data["sha256"]:
        raise InputError(f"{path} is not the recording this run read: its SHA-256 differs from run.json's",
                         path=run.folder / "run.json", field="data.sha256")
    known = {f.name for f in dataclasses.fields(ReadOptions)}
    stored = run.run.get("read_options") if isinstance(run.run.get("read_options"), dict) else {}
    options = ReadOptions(**{k: v for k, v in stored.items() if k in known})
    return (lambda: open_recording(path, options).frames()), None


def _stats(values: NDArray[np.float64]) -> dict[str, float]:
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return {"median": math.nan, "p95": math.nan, "max": math.nan, "mean": math.nan}
    return {
        "median": float(np.median(v)),
        "p95": float(np.percentile(v, 95)),
        "max": float(v.max()),
        "mean": float(v.mean()),
    }


def cost_metrics(diagnostics: dict[str, Any], run: dict[str, Any]) -> dict[str, Any]:
    """Wall and CPU time per scan (median, p95, max, mean), real-time factor and peak memory.

    The real-time factor is the recording's duration divided by the time the
    method spent on it (updates plus the final step): 10 means ten times faster
    than the data was recorded.
    """
    series = diagnostics.get("series", {})
    wall = np.array([np.nan if v is None else v for v in series.get("wall_s", [])], dtype=np.float64)
    cpu = np.array([np.nan if v is None else v for v in series.get("cpu_s", [])], dtype=np.float64)
    stamps = np.array([np.nan if v is None else v for v in series.get("timestamp", [])], dtype=np.float64)
    summary = diagnostics.get("summary", {})
    finish = float(summary.get("finish_wall_s", 0.0) or 0.0)
    total_wall = float(np.nansum(wall)) + finish
    duration = float(np.nanmax(stamps) - np.nanmin(stamps)) if stamps.size > 1 else 0.0
    out: dict[str, Any] = {
        "scans": int(wall.size),
        "wall_s_per_scan": _stats(wall),
        "cpu_s_per_scan": _stats(cpu),
        "total_wall_s": total_wall,
        "total_cpu_s": float(np.nansum(cpu)),
        "finish_wall_s": finish,
        "data_duration_s": duration,
        "real_time_factor": duration / total_wall if total_wall > 0 else math.nan,
        "peak_rss_mb": run.get("peak_rss_mb", math.nan),
        "rss_growth_mb": run.get("rss_growth_mb", math.nan),
    }
    return out


def evaluate_run(
    run: RunFiles,
    truth: GroundTruth | None = None,
    *,
    relations: Any = None,
    tolerance: float = 0.1,
    max_gap: float = 0.5,
    rpe_distance: float = 1.0,
    frames: Callable[[], Iterable[Any]] | None = None,
) -> dict[str, Any]:
    """Every metric that the inputs allow, as a JSON-friendly dict.

    Keys (each present only when its inputs are):

    * ``alignment``: ``[x, y, theta]`` taking the run's frame into the
      truth's (from the ATE alignment, else ICP of the maps);
      ``alignment_source``: ``"trajectory"`` or ``"map"``.
    * ``trajectory``: ``{"truth", "kind", "pairs", "unmatched", "ate",
      "rpe_per_frame", "rpe_per_metre"}`` where ``ate`` is
      :func:`~slam2d.eval.trajectory_metrics.absolute_trajectory_error`'s
      result and the RPEs are
      :func:`~slam2d.eval.trajectory_metrics.relative_pose_error`'s.
    * ``relations``: :func:`~slam2d.eval.trajectory_metrics.relations_error`'s result plus ``"file"``.
    * ``map_truth``: :func:`~slam2d.eval.map_metrics.map_to_truth`'s result.
    * ``map_quality``: :func:`~slam2d.eval.map_metrics.map_quality`'s result.
    * ``cost``: :func:`cost_metrics`'s result (run folders only).
    * ``self_consistency``: :func:`~slam2d.eval.self_consistency.judge_trajectory`'s result, the
      reference-free measures, when ``frames`` (a function giving the run's recording's frames) is given.
    """
    from slam2d.eval import map_metrics, trajectory_metrics

    result: dict[str, Any] = {"run": str(run.folder)}
    if run.run:
        result["method"] = run.run.get("method")
    alignment = None
    if truth is not None and truth.has_trajectory:
        assoc = trajectory_metrics.associate(
            run.times, run.poses, truth.times, truth.poses, max_gap=max_gap,
            est_name=str(run.folder), ref_name=str(truth.source),
        )
        ate = trajectory_metrics.absolute_trajectory_error(assoc, align=True)
        alignment = [float(v) for v in ate["alignment"]]
        result["alignment"] = alignment
        result["alignment_source"] = "trajectory"
        result["trajectory"] = {
            "truth": str(truth.source),
            "kind": truth.kind,
            "pairs": assoc.times.shape[0],
            "unmatched": assoc.unmatched,
            "ate": ate,
            "rpe_per_frame": trajectory_metrics.relative_pose_error(assoc, per="frame", delta=1),
            "rpe_per_metre": trajectory_metrics.relative_pose_error(assoc, per="metre", delta=rpe_distance),
        }
    if relations is not None:
        rel = trajectory_metrics.relations_error(run.times, run.poses, relations, max_gap=max_gap,
                                                 est_name=str(run.folder))
        result["relations"] = {"file": str(relations.path), **rel}
    if run.map_image is not None:
        if truth is not None and truth.map is not None:
            try:
                if alignment is None:
                    transform, info = map_metrics.align_maps(run.map, truth.map)
                    alignment = [float(v) for v in transform]
                    result["alignment"] = alignment
                    result["alignment_source"] = "map"
                    result["map_alignment"] = info
                result["map_truth"] = map_metrics.map_to_truth(
                    run.map, truth.map, transform=np.asarray(alignment), tolerance=tolerance,
                    truth_visible=truth.visible_walls(),
                )
            except InputError as exc:  # e.g. a truth map with no occupied cell: name its file
                if truth.map_path is None:
                    raise
                raise exc.in_file(truth.map_path) from None
            result["map_truth"]["walls"] = "seen" if truth.visible_walls() is not None else "all"
        result["map_quality"] = map_metrics.map_quality(run.map_image)
    if frames is not None and run.times.shape[0]:
        from slam2d.eval.self_consistency import judge_trajectory

        result["self_consistency"] = judge_trajectory(frames(), run.times, run.poses)
    if run.diagnostics:
        try:
            result["cost"] = cost_metrics(run.diagnostics, run.run)
        except (TypeError, ValueError, AttributeError) as exc:  # a hand-edited or foreign file
            raise InputError(f"unexpected content, not what 'slam2d run' writes ({exc})",
                             path=run.folder / "diagnostics.json") from None
    return json_ready(result)  # NaN ("no value": no pairs, no obstacle cells...) as null
