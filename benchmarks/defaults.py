#!/usr/bin/env python3
"""Defaults on every real log: each method with no ``--set`` and no ``--params``, on every log.

    .venv/bin/python benchmarks/defaults.py                      # the whole table (markdown on stdout)
    .venv/bin/python benchmarks/defaults.py --methods karto --logs intel,csail
    .venv/bin/python benchmarks/defaults.py --set karto:search_window=0.5   # a candidate, on every log
    .venv/bin/python benchmarks/defaults.py --json out.json       # every run's numbers too
    .venv/bin/python benchmarks/defaults.py --write BENCHMARKS.md # the whole table into its section there
    .venv/bin/python benchmarks/defaults.py --from-json out.json --write BENCHMARKS.md  # from an earlier --json

A default changes only when the change is measured on every log of this table
and on the simulated worlds (``--logs sim`` adds them). Each (method, log, seed)
runs in its own worker process (``--jobs``, default 2) so a run's CPU time is
its own; the time reported is the method's CPU seconds over the frames, reading
excluded, after a warm-up that compiles its kernels (compilation is not a
method's time). ATE is against the log's ``reference.tum`` (a GMapping result,
not independent ground truth) after SE(2) alignment; simulated worlds against
their exact truth. The stochastic methods (gmapping) run seeds 0-4 and show
median and worst; the others run seed 0.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import statistics
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
SHARED = ROOT.parent / "shared" / "datasets"
sys.path.insert(0, str(HERE))

#: the real logs of the table: SICK, about a scan a metre except fr079 (dense)
REAL_LOGS = ("intel", "aces", "fr079", "fr101", "csail")
#: the simulated worlds a default change is also measured on (the simulator's default odometry noise)
SIM_LOGS = ("office-120s", "corridor-loop", "office-120s-rplidar", "corridor-loop-rplidar")
#: what each method runs with: the defaults, except odometry on for the odometry-optional methods
#: (every table log is a SICK log with odometry; without it they have nothing to bridge a scan a metre)
METHODS = {
    "gmapping": {},
    "karto": {},
    "lago": {},
    "hector": {"use_odometry": True},
    "coreslam": {"use_odometry": True},
}
STOCHASTIC = {"gmapping": (0, 1, 2, 3, 4), "coreslam": (0, 1, 2, 3, 4)}


def _recording(log: str, workdir: Path) -> tuple[Path, Path | None] | None:
    """The recording and its reference (real) or truth folder (simulated); None when missing."""
    if log in REAL_LOGS or (SHARED / log).is_dir():
        data = SHARED / log / f"{log}.clf.gz"
        return (data, SHARED / log / "reference.tum") if data.is_file() else None
    from methods import DATASETS, prepare

    (ds,) = [d for d in DATASETS if d.name == log]
    data, _ = prepare(ds, workdir)
    return data, data.parent / "truth.tum"


def _one(task: tuple) -> dict:
    method, log, seed, settings, data, reference = task
    import numpy as np

    from slam2d.eval.trajectory_metrics import absolute_trajectory_error, associate
    from slam2d.io import open_recording
    from slam2d.io.tum import read_tum
    from slam2d.methods.runner import build_method_for

    frames = list(open_recording(data).frames())
    # warm-up on a few frames: compiles the kernels (cache=True keeps them on disk) outside the timing
    build_method_for(method, frames, settings=settings, seed=seed).run(frames[: min(len(frames), 40)])
    c0, t0 = time.process_time(), time.perf_counter()
    slam = build_method_for(method, frames, settings=settings, seed=seed)  # measures the recording (auto)
    slam.run(frames)
    cpu, wall = time.process_time() - c0, time.perf_counter() - t0
    t, p = slam.trajectory()
    rt, rp = read_tum(reference)
    ate = absolute_trajectory_error(associate(t, p, rt, rp))["translation_m"]["rmse"]
    recoveries = slam.diagnostics.counters.get("odometry_recoveries", 0)
    return {"method": method, "log": log, "seed": seed, "ate": float(ate), "cpu_s": cpu, "wall_s": wall,
            "scans": len(frames), "recoveries": recoveries, "settings": {k: str(v) for k, v in settings.items()},
            "auto": {k: v["value"] for k, v in slam.auto.items()},
            "finite": bool(np.all(np.isfinite(p)))}


def _parse_sets(items: list[str]) -> dict[str, dict[str, str]]:
    out: dict[str, dict[str, str]] = {}
    for item in items:
        target, _, kv = item.partition(":")
        if not kv or "=" not in kv:
            raise SystemExit(f"--set {item!r}: expected METHOD:NAME=VALUE")
        k, _, v = kv.partition("=")
        out.setdefault(target, {})[k.strip()] = v.strip()
    return out


def markdown(results: list[dict], logs: list[str], methods: list[str]) -> list[str]:
    lines = ["| method | " + " | ".join(logs) + " | CPU s (sum) |", "|---|" + "---|" * (len(logs) + 1)]
    for m in methods:
        cells, cpu = [], 0.0
        for log in logs:
            rs = [r for r in results if r["method"] == m and r["log"] == log]
            if not rs:
                cells.append("-")
                continue
            ates = [r["ate"] for r in rs]
            cpu += statistics.median(r["cpu_s"] for r in rs)
            if len(ates) > 1:
                cells.append(f"{statistics.median(ates):.3f} / {max(ates):.3f}")
            else:
                cells.append(f"{ates[0]:.3f}")
        extra = METHODS.get(m, {})
        label = f"`{m}`" + (" (" + ", ".join(f"{k}={v}" for k, v in extra.items()) + ")" if extra else "")
        seeds = sorted({r["seed"] for r in results if r["method"] == m})
        if len(seeds) > 1:
            label += f" median / worst, seeds {', '.join(map(str, seeds))}"
        lines.append(f"| {label} | " + " | ".join(cells) + f" | {cpu:.1f} |")
    return lines


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--methods", default=",".join(METHODS), help="comma-separated methods")
    parser.add_argument("--logs", default=",".join(REAL_LOGS),
                        help="comma-separated logs; 'sim' stands for the simulated worlds")
    parser.add_argument("--seeds", help="seeds for the stochastic methods (e.g. 0-4 or 1,3)")
    parser.add_argument("--set", action="append", default=[], metavar="METHOD:NAME=VALUE",
                        help="a setting on top of the defaults ('*:' for every method)")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--json", type=Path, help="write every run's numbers here")
    parser.add_argument("--from-json", type=Path, metavar="FILE",
                        help="make the table from an earlier --json file instead of running (--methods, --logs)")
    parser.add_argument("--write", type=Path, metavar="BENCHMARKS.md",
                        help="replace the 'Defaults on every real log' section of this file with the table")
    args = parser.parse_args()
    methods = args.methods.split(",")
    logs = []
    for log in args.logs.split(","):
        logs.extend(SIM_LOGS if log == "sim" else (log,))
    sets = _parse_sets(args.set)
    seeds = None
    if args.seeds:
        a, _, b = args.seeds.partition("-")
        seeds = tuple(range(int(a), int(b) + 1)) if b else tuple(int(s) for s in args.seeds.split(","))
    if args.from_json:
        results = [r for r in json.loads(args.from_json.read_text())
                   if r["method"] in methods and r["log"] in logs]
        table = markdown(results, logs, methods)
        print("\n".join(table))
        if args.write:
            write_section(args.write, table)
        return 0
    with tempfile.TemporaryDirectory(prefix="slam2d-defaults-") as tmp:
        tasks = []
        for log in logs:
            rec = _recording(log, Path(tmp))
            if rec is None:
                print(f"skip {log}: not in {SHARED}", file=sys.stderr)
                continue
            for m in methods:
                settings = {**METHODS.get(m, {}), **sets.get("*", {}), **sets.get(m, {})}
                for seed in (seeds or STOCHASTIC.get(m, (0,))) if m in STOCHASTIC else (0,):
                    tasks.append((m, log, seed, settings, rec[0], rec[1]))
        # longest logs first so the pool ends together
        tasks.sort(key=lambda t: (t[1] != "fr079", t[0] != "gmapping"))
        results = []
        ctx = multiprocessing.get_context("spawn")
        with ctx.Pool(args.jobs, maxtasksperchild=1) as pool:
            for r in pool.imap_unordered(_one, tasks):
                results.append(r)
                rec = f" recoveries {r['recoveries']}" if r["recoveries"] is not None else ""
                print(f"{r['method']:9s} {r['log']:22s} seed {r['seed']}: ATE {r['ate']:.3f} m, "
                      f"CPU {r['cpu_s']:.1f} s{rec}", file=sys.stderr, flush=True)
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))
    table = markdown(results, [l for l in logs], methods)
    print("\n".join(table))
    if args.write:
        write_section(args.write, table)
    return 0


SECTION_BEGIN = "<!-- BEGIN defaults-on-every-log (benchmarks/defaults.py --write) -->"
SECTION_END = "<!-- END defaults-on-every-log -->"


def section(table: list[str]) -> list[str]:
    from datetime import datetime, timezone

    return [
        SECTION_BEGIN,
        "## Defaults on every real log",
        "",
        "Every method with its defaults (no `--set`, no `--params`; `hector` and `coreslam` with "
        "`use_odometry=true`, as a SICK log with odometry needs), ATE in metres after SE(2) alignment "
        "against each log's `reference.tum` (a GMapping result, not independent ground truth). "
        "Stochastic methods: median / worst over seeds 0-4. CPU: the method's seconds over the frames "
        "(measuring the recording for the `auto` defaults included, reading and compilation not), summed "
        "over the logs (medians over the seeds). Measured "
        f"{datetime.now(timezone.utc).strftime('%Y-%m-%d %H:%M UTC')}; command: "
        "`.venv/bin/python benchmarks/defaults.py --write BENCHMARKS.md`.",
        "",
        *table,
        "",
        SECTION_END,
    ]


def write_section(path: Path, table: list[str]) -> None:
    """Replace (or add) this table's section in BENCHMARKS.md."""
    replace_section(path, SECTION_BEGIN, SECTION_END, "\n".join(section(table)))


def emit_section(begin: str, end: str, title: str, head: str, table: list[str], write: Path | None) -> None:
    """Print a BENCHMARKS.md section (markers, ``## title``, ``head``, ``table``) and, with ``write``, put it there."""
    block = "\n".join([begin, f"## {title}", "", head, "", *table, "", end])
    print(block)
    if write:
        replace_section(write, begin, end, block)


def replace_section(path: Path, begin: str, end: str, block: str) -> None:
    """Replace the text from ``begin`` to ``end`` in BENCHMARKS.md with ``block`` (which holds both markers), or
    add it before the methods x datasets table; atomically."""
    text = path.read_text() if path.is_file() else "# Benchmarks\n"
    if begin in text and end in text:
        head, rest = text.split(begin, 1)
        text = head + block + rest.split(end, 1)[1]
    elif "## Methods x datasets" in text:
        head, rest = text.split("## Methods x datasets", 1)
        text = head + block + "\n\n## Methods x datasets" + rest
    else:
        text = text.rstrip("\n") + "\n\n" + block + "\n"
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    tmp.replace(path)


if __name__ == "__main__":
    raise SystemExit(main())
