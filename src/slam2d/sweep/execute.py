"""What a worker does: simulate a dataset, or run one method and evaluate it. Plain functions of plain dicts.

Both executors (the local pool and Dask) call these same functions, so a run
gives the same row wherever it ran. Everything a run produces goes into its
own folder, and its ``result.json`` (the row of the results table) is written
atomically, last: a folder with ``result.json`` is a finished run, whatever
happened to the worker or the sweep afterwards.

Every attempt leaves a ``started-N`` marker before it starts. An attempt that
finds markers of earlier attempts knows they were lost (their worker died),
which the row reports; after :data:`MAX_ATTEMPTS` lost attempts the run is
given up as failed instead of taking down worker after worker (Dask would
otherwise retry it on every worker it kills).
"""

from __future__ import annotations

import json
import os
import socket
import time
import traceback
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

__all__ = ["MAX_ATTEMPTS", "RESULT", "warm_imports", "prepare_dataset", "execute_run", "read_result", "write_result",
           "clear_attempts", "attempts_started"]

MAX_ATTEMPTS = 2  # a run whose worker dies is retried once
RESULT = "result.json"
_MARKER = "started-"
_TRUTH_CACHE: dict[tuple[str | None, ...], Any] = {}  # per worker process: truths are reused by many runs


def _worker_name() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


def _error_line(exc: BaseException) -> str:
    from slam2d.errors import Slam2dError

    text = str(exc) if isinstance(exc, Slam2dError) else f"{type(exc).__name__}: {exc}"
    return text.strip().splitlines()[0] if text.strip() else type(exc).__name__


def warm_imports() -> None:
    """Import what every run needs, so that forked workers inherit it instead of each importing it again."""
    import matplotlib.figure  # noqa: F401  (map previews)
    import matplotlib.image  # noqa: F401

    import slam2d.eval.evaluate  # noqa: F401
    import slam2d.eval.map_metrics  # noqa: F401
    import slam2d.eval.trajectory_metrics  # noqa: F401
    import slam2d.io  # noqa: F401
    import slam2d.io.carmen  # noqa: F401
    import slam2d.methods.runner  # noqa: F401
    import slam2d.report.map_outputs  # noqa: F401
    from slam2d.methods.registry import available

    available()  # imports every method module


# --------------------------------------------------------------------------- datasets

def prepare_dataset(task: dict[str, Any]) -> dict[str, Any]:
    """Write a simulated recording with its truth (nothing to do for a file, or when it was written before)."""
    t0 = time.perf_counter()
    sim = task.get("simulate")
    out: dict[str, Any] = {"id": task["id"], "status": "ok", "error": None, "reused": True, "seconds": 0.0}
    if sim is None:
        return out
    folder = Path(sim["out"])
    if (folder / "simulation.json").is_file() and (folder / "recording.log.gz").is_file():
        return out  # write_outputs writes simulation.json last
    try:
        from slam2d.params import from_mapping
        from slam2d.sensors.motion_noise import OdometryNoise
        from slam2d.sim.simulate import SimulationParams, simulate, write_outputs

        params = from_mapping(SimulationParams, {**sim["simulation"], "seed": sim["seed"], "duration": sim["duration"]})
        noise = from_mapping(OdometryNoise, dict(sim["odometry_noise"]))
        (folder / "simulation.json").unlink(missing_ok=True)
        write_outputs(simulate(sim["world"], params, odometry_noise=noise), folder)
        out["reused"] = False
    except Exception as exc:  # reported as this dataset's failure; its runs fail with it
        out.update(status="failed", error=_error_line(exc), details=traceback.format_exc())
    out["seconds"] = time.perf_counter() - t0
    return out


# --------------------------------------------------------------------------- runs

def attempts_started(run_dir: Path) -> int:
    return len(list(run_dir.glob(f"{_MARKER}*"))) if run_dir.is_dir() else 0


def clear_attempts(run_dir: Path) -> None:
    """Forget the attempts of an earlier sweep (it was stopped, not the run's fault)."""
    if run_dir.is_dir():
        for m in run_dir.glob(f"{_MARKER}*"):
            m.unlink(missing_ok=True)


def read_result(run_dir: Path) -> dict[str, Any] | None:
    """A finished run's row, or None (no result, or an unreadable one: then the run is redone)."""
    try:
        row = json.loads((run_dir / RESULT).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return row if isinstance(row, dict) else None  # valid JSON but not a row: unreadable too


def write_result(run_dir: Path, row: dict[str, Any]) -> None:
    from slam2d.io.atomic import write_json_atomic

    run_dir.mkdir(parents=True, exist_ok=True)
    write_json_atomic(run_dir / RESULT, row)


def base_row(task: dict[str, Any]) -> dict[str, Any]:
    """The row's identity columns, the same whether the run finished, failed or was lost."""
    return {
        "run_id": task["id"], "index": task["index"], "method": task["method"], "dataset": task["dataset"],
        "dataset_seed": task["dataset_seed"], "seed": task["seed"], "swept": dict(task["swept"]),
        "data_settings": dict(task["data_settings"]), "params": dict(task["settings"]),
        "metrics": {m: None for m in task["metrics"]}, "status": "failed", "error": None, "attempts": 0,
        "lost": "; ".join(task.get("lost", [])) or None, "scans": None, "run_s": None, "eval_s": None,
        "task_s": None, "cpu_s": None, "worker": None, "finished": None,
    }


def _truth(data: dict[str, Any]) -> tuple[Any, Any]:
    key = (data["truth"], data["reference"], data["truth_map"], data["relations"])
    if key not in _TRUTH_CACHE:
        from slam2d.eval.evaluate import GroundTruth, load_reference, load_truth
        from slam2d.io.map_server import read_map
        from slam2d.io.relations import read_relations

        truth = None
        if data["truth"]:
            truth = load_truth(data["truth"])
            if data["truth_map"]:
                truth.map, truth.map_path = read_map(data["truth_map"]).to_grid(), Path(data["truth_map"])
        elif data["reference"]:
            truth = load_reference(data["reference"], truth_map=data["truth_map"])
        elif data["truth_map"]:
            grid = read_map(data["truth_map"]).to_grid()
            truth = GroundTruth("truth", Path(data["truth_map"]), None, None, grid, Path(data["truth_map"]))
        relations = read_relations(data["relations"]) if data["relations"] else None
        if len(_TRUTH_CACHE) > 8:
            _TRUTH_CACHE.clear()
        _TRUTH_CACHE[key] = (truth, relations)
    return _TRUTH_CACHE[key]


def execute_run(task: dict[str, Any]) -> dict[str, Any]:
    """Run one method on one recording, evaluate it, write ``result.json``; return the row. Never raises."""
    t0 = time.perf_counter()
    c0 = time.process_time()
    run_dir = Path(task["run_dir"])
    row = base_row(task)
    row["worker"] = _worker_name()
    run_dir.mkdir(parents=True, exist_ok=True)
    done = read_result(run_dir)
    if done is not None and done.get("run_id") == task["id"]:
        return done  # an earlier attempt finished; only its reply was lost (the scheduler recomputes lost results)
    attempt = attempts_started(run_dir) + 1
    row["attempts"] = attempt
    if attempt > MAX_ATTEMPTS:
        row["error"] = f"given up: the worker running it died in each of {attempt - 1} attempts"
        row["lost"] = row["lost"] or row["error"]
        return _finish(row, run_dir, t0, c0)
    if attempt > 1 and not row["lost"]:
        row["lost"] = f"{attempt - 1} earlier attempt(s) lost: the worker died"
    (run_dir / f"{_MARKER}{attempt}").write_text(f"{row['worker']} {datetime.now(timezone.utc).isoformat()}\n")
    data = task["data"]
    if task.get("data_error"):  # its recording could not be simulated
        row["error"] = f"dataset {task['dataset']}: {task['data_error']}"
        return _finish(row, run_dir, t0, c0)
    try:
        from slam2d.eval.evaluate import evaluate_run, load_run
        from slam2d.io.atomic import write_json_atomic
        from slam2d.methods.runner import json_params, run_method

        from slam2d.methods.registry import get_method
        from slam2d.params import as_dict, from_mapping

        settings = dict(task["settings"])
        if task["method"] == "known-poses" and "poses" not in settings:
            poses = Path(data["truth"]) / "truth.tum" if data["truth"] else data["reference"]
            if poses is None:
                raise ValueError("known-poses needs a dataset with 'truth' or 'reference' (or set its 'poses')")
            settings["poses"] = str(poses)
        row["params"] = as_dict(from_mapping(get_method(task["method"]).Params, settings))  # every value, even if it fails
        summary = run_method(task["method"], data["recording"], run_dir, settings=settings, seed=task["seed"],
                             command=f"slam2d sweep (run {task['id']})")
        # every value as run (run.json holds the advanced ones only where changed)
        row["params"] = json_params(as_dict(from_mapping(get_method(task["method"]).Params, summary.record["params"])))
        row["scans"] = summary.frames
        row["run_s"] = summary.seconds
        t1 = time.perf_counter()
        truth, relations = _truth(data)
        evaluation = evaluate_run(load_run(run_dir), truth, relations=relations)
        write_json_atomic(run_dir / "evaluation.json", evaluation)
        from slam2d.sweep.spec import METRICS

        row["metrics"] = {m: METRICS[m].value(evaluation) for m in task["metrics"]}
        row["eval_s"] = time.perf_counter() - t1
        row["status"] = "ok"
    except Exception as exc:  # a failed run is a row with its error; the sweep goes on (Ctrl-C is not a result)
        row["error"] = _error_line(exc)
        row["details"] = traceback.format_exc()
    return _finish(row, run_dir, t0, c0)


def _finish(row: dict[str, Any], run_dir: Path, t0: float, c0: float) -> dict[str, Any]:
    row["task_s"] = time.perf_counter() - t0
    row["cpu_s"] = time.process_time() - c0  # the worker's CPU time: a load-independent cost
    row["finished"] = datetime.now(timezone.utc).isoformat(timespec="seconds")
    write_result(run_dir, row)
    return row
