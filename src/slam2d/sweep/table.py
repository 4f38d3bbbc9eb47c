"""The results table: one row per run, written as Parquet (pyarrow) and CSV.

Columns, in order: ``run_id``, ``method``, ``dataset``, ``dataset_seed``,
``seed``, ``data.NAME`` (simulation settings the spec sweeps), ``param.NAME``
(every parameter of the method as run: the swept ones first), one column per
metric (units in :data:`slam2d.sweep.spec.METRICS`), then ``status``
(``ok``/``failed``), ``error``, ``lost`` (attempts lost to a dead worker),
``attempts``, ``scans``, ``run_s``, ``eval_s``, ``task_s``, ``cpu_s``, ``worker``,
``finished``. A missing value is null in Parquet and empty in CSV.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path
from typing import Any

__all__ = ["TIMING_COLUMNS", "columns", "flatten", "write_table", "read_table"]

#: Columns that depend on the machine, the load and the executor, not on the seeds.
TIMING_COLUMNS = ("attempts", "lost", "run_s", "eval_s", "task_s", "cpu_s", "worker", "finished")
_HEAD = ("run_id", "method", "dataset", "dataset_seed", "seed")
_TAIL = ("status", "error", "lost", "attempts", "scans", "run_s", "eval_s", "task_s", "cpu_s", "worker", "finished")


def columns(rows: list[dict[str, Any]], metrics: list[str]) -> list[str]:
    data, swept, params = [], [], []
    for r in rows:
        for k in r.get("data_settings", {}):
            if f"data.{k}" not in data:
                data.append(f"data.{k}")
        for k in r.get("swept", {}):
            if f"param.{k}" not in swept:
                swept.append(f"param.{k}")
    for r in rows:
        for k in r.get("params", {}):
            c = f"param.{k}"
            if c not in swept and c not in params:
                params.append(c)
    return [*_HEAD, *data, *swept, *params, *metrics, *_TAIL]


def flatten(row: dict[str, Any], metrics: list[str]) -> dict[str, Any]:
    out = {k: row.get(k) for k in (*_HEAD, *_TAIL)}
    for k, v in row.get("data_settings", {}).items():
        out[f"data.{k}"] = v
    for k, v in {**row.get("params", {}), **row.get("swept", {})}.items():
        out[f"param.{k}"] = v
    for m in metrics:
        out[m] = (row.get("metrics") or {}).get(m)
    return out


def _arrow_column(values: list[Any]) -> Any:
    import pyarrow as pa

    kinds = {type(v) for v in values if v is not None}
    if kinds <= {int, float} and float in kinds:
        values = [None if v is None else float(v) for v in values]
    try:
        return pa.array(values)
    except (pa.ArrowInvalid, pa.ArrowTypeError):  # one parameter name, different types in two methods
        return pa.array([None if v is None else str(v) for v in values], type=pa.string())


def write_table(rows: list[dict[str, Any]], metrics: list[str], out_dir: Path) -> list[Path]:
    """``results.parquet`` and ``results.csv`` in ``out_dir``, each written atomically."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from slam2d.io.atomic import atomic_path, write_text_atomic

    cols = columns(rows, metrics)
    flat = [flatten(r, metrics) for r in rows]
    table = pa.table({c: _arrow_column([f.get(c) for f in flat]) for c in cols})
    parquet = out_dir / "results.parquet"
    with atomic_path(parquet) as tmp:
        pq.write_table(table, tmp)
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(cols)
    for f in flat:
        w.writerow(["" if f.get(c) is None else _csv_value(f.get(c)) for c in cols])
    csv_path = out_dir / "results.csv"
    write_text_atomic(csv_path, buf.getvalue())
    return [parquet, csv_path]


def _csv_value(v: Any) -> Any:
    return repr(v) if isinstance(v, float) else v


def read_table(path: str | Path) -> dict[str, list[Any]]:
    """A results table (Parquet) as columns of Python values."""
    import pyarrow.parquet as pq

    return pq.read_table(path).to_pydict()
