"""Methods x datasets: every registered method on every shared dataset and simulated world.

Used by ``benchmarks/run.py`` (which writes the table into BENCHMARKS.md); run
alone it prints the table::

    .venv/bin/python benchmarks/methods.py [--methods a,b] [--datasets fr079,paper-arena]

Each dataset goes through ``slam2d.eval.compare.compare`` with ``jobs=1``, so
every method runs alone in its own process: its time is not shared with
another method and its peak memory (max RSS) is its own. Real logs are judged
against their ``reference.tum`` (GMapping's corrected trajectory: a reference,
not independent ground truth); simulated worlds against their exact truth
(trajectory and map).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
SHARED = ROOT.parent / "shared" / "datasets"


@dataclass(frozen=True)
class Dataset:
    name: str
    kind: str  # "shared" (a real log) or "sim" (a built-in world, simulated here)
    source: str  # path under ../shared/datasets, or the world name
    duration: float | None = None  # simulated seconds (sim only; None = one pass of the world's path)
    laser: str = "urg-04lx"  # the simulated laser preset (sim only; see slam2d.sim.laser)
    seed: int = 0  # the simulation's seed (sim only)


DATASETS: tuple[Dataset, ...] = (
    Dataset("paper-arena", "sim", "paper-arena"),
    Dataset("office-120s", "sim", "office", 120.0),
    Dataset("corridor-loop", "sim", "corridor-loop"),
    Dataset("long-corridor", "sim", "long-corridor"),
    # The URG-04LX (5.6 m) cannot see along most corridors of these floors; the RPLidar A1
    # (12 m, 360 deg) is the laser most robots built today carry.
    Dataset("office-120s-rplidar", "sim", "office", 120.0, "rplidar-a1"),
    Dataset("corridor-loop-rplidar", "sim", "corridor-loop", None, "rplidar-a1"),
    Dataset("fr079", "shared", "fr079/fr079.clf.gz"),
    Dataset("intel", "shared", "intel/intel.clf.gz"),
    Dataset("aces", "shared", "aces/aces.clf.gz"),
    Dataset("fr101", "shared", "fr101/fr101.clf.gz"),
    Dataset("csail", "shared", "csail/csail.clf.gz"),
    Dataset("mines-exp1", "shared", "mines-exp1/mines-exp1.clf.gz"),
    Dataset("mines-exp2", "shared", "mines-exp2/mines-exp2.clf.gz"),
)

#: Columns of the table: (header, MetricColumn label in slam2d.eval.evaluate.METRIC_COLUMNS).
COLUMNS = (
    ("ATE (m)", "ATE"),
    ("RPE (%)", "RPE"),
    ("map error (m)", "Map error"),
    ("ghost walls (m)", "Ghost walls"),
    ("recall", "Recall"),
    ("occupied/known", "Occupied/known"),
    ("time/scan (ms)", "Time/scan"),
    ("p95 (ms)", "Time/scan p95"),
    ("real-time factor", "Real-time factor"),
    ("peak memory (MB)", "Peak memory"),
)


def describe_simulated(datasets: tuple[Dataset, ...] | list[Dataset] = DATASETS) -> str:
    """The simulated rows in words, for the text above the table: world, duration and laser of each."""
    parts = []
    for d in datasets:
        if d.kind != "sim":
            continue
        what = [f"{d.duration:g} s of `{d.source}`" if d.duration is not None else f"`{d.source}`"]
        if what[0] == f"`{d.name}`":
            what = []
        parts.append(f"`{d.name}` ({', '.join([*what, d.laser])})")
    return ", ".join(parts)


def prepare(ds: Dataset, workdir: Path) -> tuple[Path, object] | None:
    """The recording and the truth for a dataset (None when the shared data is missing)."""
    from slam2d.eval.evaluate import load_reference, load_truth

    if ds.kind == "sim":
        from slam2d.sim.simulate import SimulationParams, simulate, write_outputs

        out = workdir / ds.name
        if not (out / "truth.tum").is_file():
            write_outputs(simulate(ds.source, SimulationParams(duration=ds.duration, seed=ds.seed, laser=ds.laser)),
                          out)
        return out / "recording.log.gz", load_truth(out)
    data = SHARED / ds.source
    if not data.is_file():
        return None
    ref = data.parent / "reference.tum"
    return data, (load_reference(ref) if ref.is_file() else None)


def run_matrix(methods: list[str], datasets: list[Dataset], workdir: Path) -> list[dict]:
    """One row per (dataset, method): the metric values, or the failure."""
    from slam2d.eval.compare import compare
    from slam2d.eval.evaluate import METRIC_COLUMNS

    by_label = {c.label: c for c in METRIC_COLUMNS}
    rows = []
    for ds in datasets:
        prepared = prepare(ds, workdir)
        if prepared is None:
            print(f"skip {ds.name}: {SHARED / ds.source} is missing", file=sys.stderr)
            continue
        data, truth = prepared
        chosen = [m for m in methods if m != "known-poses" or truth is not None]
        t0 = time.perf_counter()
        comparison = compare(data, chosen, workdir / f"cmp-{ds.name}", truth=truth, jobs=1)
        print(f"{ds.name}: {', '.join(chosen)} in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
        for o in comparison.outcomes:
            row = {"dataset": ds.name, "method": o.method, "status": o.status, "error": o.error,
                   "truth": "exact truth" if truth is not None and truth.kind == "truth"
                   else ("reference" if truth is not None else "none"),
                   "scans": comparison.recording.get("scans")}
            for header, label in COLUMNS:
                row[header] = by_label[label].value(o.evaluation) if o.ok else None
                row[f"{header}:digits"] = by_label[label].digits
            rows.append(row)
    return rows


def markdown(rows: list[dict]) -> list[str]:
    headers = ["dataset", "judged against", "method", *[h for h, _ in COLUMNS]]
    lines = ["| " + " | ".join(headers) + " |", "|" + "---|" * len(headers)]
    for r in rows:
        if r["status"] != "ok":
            cells = [r["dataset"], r["truth"], f"`{r['method']}`", f"failed: {r['error']}"] + [""] * (len(COLUMNS) - 1)
        else:
            values = []
            for h, _ in COLUMNS:
                v = r[h]
                values.append("-" if v is None else f"{v:.{r[h + ':digits']}f}")
            cells = [r["dataset"], r["truth"], f"`{r['method']}`", *values]
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def main() -> int:
    from slam2d.methods import method_names

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--methods", help="comma-separated methods (default: every registered method)")
    parser.add_argument("--datasets", help="comma-separated dataset names (default: all)")
    args = parser.parse_args()
    methods = args.methods.split(",") if args.methods else method_names()
    datasets = [d for d in DATASETS if not args.datasets or d.name in args.datasets.split(",")]
    with tempfile.TemporaryDirectory(prefix="slam2d-bench-methods-") as tmp:
        rows = run_matrix(methods, datasets, Path(tmp))
    print("\n".join(markdown(rows)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
