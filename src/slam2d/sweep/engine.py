"""Run a sweep: expand the spec, skip finished runs, hand the rest to an executor, write the results.

Layout of the output folder::

    OUT/spec.yaml               the spec as it was run
    OUT/data/ID/                each simulated recording with its truth (slam2d simulate's files)
    OUT/runs/RUN_ID/            each run's folder (slam2d run's files, evaluation.json, result.json)
    OUT/results.parquet, .csv   one row per run
    OUT/plots/METRIC-vs-PARAM.png
    OUT/summary.html            best settings per method, spread over seeds, failures
    OUT/sweep.json              counts, timing, executor

A run is finished when its folder holds ``result.json``; a rerun reuses those
rows and runs only the rest (``retry_failed`` also reruns the failed ones).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from slam2d.errors import InputError
from slam2d.sweep.execute import (
    MAX_ATTEMPTS, RESULT, base_row, clear_attempts, execute_run, prepare_dataset, read_result, write_result,
)
from slam2d.sweep.expand import RunTask, expand
from slam2d.sweep.spec import SweepSpec, check_methods

__all__ = ["SweepResult", "run_sweep", "require_pyarrow"]


@dataclass
class SweepResult:
    out_dir: Path
    rows: list[dict[str, Any]]  # one per run, in expansion order
    executed: int = 0  # runs done by this call (the rest were finished before)
    reused: int = 0
    lost: list[str] = field(default_factory=list)  # one line per lost attempt
    run_phase_s: float = 0.0  # wall time from the first run submitted to the last result
    task_s: float = 0.0  # the workers' time inside the runs of this call
    workers: int = 1
    executor: str = ""
    written: list[Path] = field(default_factory=list)

    @property
    def failed(self) -> list[dict[str, Any]]:
        return [r for r in self.rows if r["status"] != "ok"]

    @property
    def overhead_per_run_s(self) -> float | None:
        """Scheduling and collection per run: worker-time not spent inside a run, per run executed."""
        if not self.executed:
            return None
        return max(0.0, self.run_phase_s * self.workers - self.task_s) / self.executed


def require_pyarrow() -> None:
    try:
        import pyarrow  # noqa: F401
        import pyarrow.parquet  # noqa: F401
    except ImportError:
        raise InputError("the results table is written as Parquet with pyarrow, which is not installed: "
                         "pip install 'slam2d[sweep]'") from None


def _run_task(run: RunTask, out_dir: Path, spec: SweepSpec, lost: list[str], data_error: str | None) -> dict[str, Any]:
    return {
        "id": run.id, "index": run.index, "method": run.method, "settings": run.settings, "swept": run.swept,
        "seed": run.seed, "dataset": run.data.name, "dataset_seed": run.data.seed,
        "data_settings": run.data.swept, "data": run.data.as_task(), "run_dir": str(out_dir / "runs" / run.id),
        "metrics": [m.name for m in spec.metrics], "lost": list(lost), "data_error": data_error,
    }


def _drain(executor: Any, tasks: dict[str, Any], fn: Callable[[Any], Any],
           on_result: Callable[[str, dict[str, Any] | None, str | None], None],
           on_lost: Callable[[str, str, int], Any]) -> None:
    """Submit every task, collect every result; a lost task is resubmitted until MAX_ATTEMPTS."""
    tries: dict[str, int] = {}
    for key, arg in tasks.items():
        tries[key] = 1
        executor.submit(key, fn, arg)
    outstanding = len(tasks)
    while outstanding:
        key, kind, value = executor.next_done()
        if kind == "lost":
            arg = on_lost(key, value, tries[key])
            if tries[key] < MAX_ATTEMPTS and arg is not None:
                tries[key] += 1
                executor.submit(key, fn, arg)
                continue
            on_result(key, None, value)
        elif kind == "error":
            on_result(key, None, value)
        else:
            on_result(key, value, None)
        outstanding -= 1


def run_sweep(
    spec: SweepSpec,
    out_dir: str | Path,
    *,
    scheduler: str | None = None,
    workers: int | None = None,
    retry_failed: bool = False,
    executor: Any = None,
    on_row: Callable[[dict[str, Any], int, int], None] | None = None,
    on_note: Callable[[str], None] | None = None,
) -> SweepResult:
    """Run every unfinished run of ``spec`` into ``out_dir`` and write the table, the plots and the summary.

    Runs go to a :class:`~slam2d.sweep.executors.LocalPool` of ``workers``
    processes, or to the Dask scheduler at ``scheduler``; ``executor`` (an
    object with the same calls) overrides both. ``on_row(row, done, total)``
    is called as each run's row arrives; ``on_note(line)`` for lost workers
    and other events.
    """
    from slam2d.io.atomic import write_json_atomic, write_text_atomic
    from slam2d.sweep.executors import make_executor
    from slam2d.sweep.report import write_outputs

    note = on_note or (lambda _line: None)
    check_methods(spec)
    require_pyarrow()
    out_dir = Path(out_dir).resolve()  # workers (Dask's) have their own working directory: absolute paths only
    data, runs = expand(spec, out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out_dir / "spec.yaml", spec.text)

    rows: dict[str, dict[str, Any]] = {}
    todo: list[RunTask] = []
    for run in runs:
        run_dir = out_dir / "runs" / run.id
        row = read_result(run_dir)
        if row is not None and row.get("run_id") == run.id and (row.get("status") == "ok" or not retry_failed):
            rows[run.id] = row
            continue
        clear_attempts(run_dir)
        (run_dir / RESULT).unlink(missing_ok=True)  # a failed run being retried, or an unreadable result
        todo.append(run)
    result = SweepResult(out_dir, [], reused=len(rows))
    if todo:
        needed = {r.data.id: r.data for r in todo}
        prep = {k: d.as_task() for k, d in needed.items() if d.simulate is not None}
        own_executor = executor is None
        if own_executor:
            wanted = workers if workers is not None else None
            if scheduler is None and wanted is None:
                import os

                wanted = os.cpu_count() or 1
            if scheduler is None:
                wanted = max(1, min(wanted, len(todo)))
            executor = make_executor(scheduler, wanted)
        result.executor = executor.describe()
        result.workers = executor.capacity
        note(f"{len(todo)} run(s) to do, {len(rows)} finished before; on {result.executor}")
        try:
            data_errors: dict[str, str] = {}
            if prep:
                def prep_done(key: str, value: dict[str, Any] | None, error: str | None) -> None:
                    if value is None or value["status"] != "ok":
                        data_errors[key] = (value or {}).get("error") or error or "unknown error"
                        note(f"dataset {key} failed: {data_errors[key]}")

                def prep_lost(key: str, how: str, attempt: int) -> dict[str, Any]:
                    note(f"dataset {key}: attempt {attempt} lost ({how})")
                    return prep[key]

                note(f"simulating {len(prep)} recording(s)")
                _drain(executor, prep, prepare_dataset, prep_done, prep_lost)
            lost_reasons: dict[str, list[str]] = {r.id: [] for r in todo}
            tasks = {r.id: _run_task(r, out_dir, spec, [], data_errors.get(r.data.id)) for r in todo}
            done = len(rows)

            def run_done(key: str, row: dict[str, Any] | None, error: str | None) -> None:
                nonlocal done
                if row is None:  # lost twice, or the executor failed it: the engine writes its row
                    row = base_row({**tasks[key], "lost": lost_reasons[key]})
                    row["error"] = ("lost twice: " if lost_reasons[key] else "") + (error or "").splitlines()[0]
                    row["attempts"] = len(lost_reasons[key])
                    write_result(Path(tasks[key]["run_dir"]), row)
                if row.get("lost") and not lost_reasons[key]:  # the scheduler retried it without telling us
                    result.lost.append(f"run {key}: {row['lost']}")
                    note(f"run {key}: {row['lost']}")
                rows[key] = row
                result.executed += 1
                result.task_s += float(row.get("task_s") or 0.0)
                done += 1
                if on_row is not None:
                    on_row(row, done, len(runs))

            def run_lost(key: str, how: str, attempt: int) -> dict[str, Any]:
                line = f"run {key}: attempt {attempt} lost: {how}"
                lost_reasons[key].append(f"attempt {attempt} lost: {how}")
                result.lost.append(line)
                note(line + ("; retrying" if attempt < MAX_ATTEMPTS else "; giving up"))
                return {**tasks[key], "lost": list(lost_reasons[key])}

            t0 = time.perf_counter()
            _drain(executor, tasks, execute_run, run_done, run_lost)
            result.run_phase_s = time.perf_counter() - t0
        finally:
            if own_executor:
                executor.close()
    result.rows = [rows[r.id] for r in runs]
    result.written = write_outputs(spec, result)
    sweep_doc = {
        "name": spec.name, "spec": str(spec.path), "runs": len(runs), "ok": len(runs) - len(result.failed),
        "failed": len(result.failed), "executed": result.executed, "reused": result.reused, "lost": result.lost,
        "executor": result.executor, "workers": result.workers, "run_phase_s": result.run_phase_s,
        "task_s": result.task_s, "overhead_per_run_s": result.overhead_per_run_s,
    }
    write_json_atomic(out_dir / "sweep.json", sweep_doc)
    result.written.append(out_dir / "sweep.json")
    return result
