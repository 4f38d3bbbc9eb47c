#!/usr/bin/env python3
"""The verdict without a reference: does ``slam2d compare`` rank first a method whose map is good?

    .venv/bin/python benchmarks/verdict.py                         # every recording (markdown on stdout)
    .venv/bin/python benchmarks/verdict.py --recordings intel,sim-office-1
    .venv/bin/python benchmarks/verdict.py --keep DIR              # keep the comparisons in DIR
    .venv/bin/python benchmarks/verdict.py --rejudge DIR           # judge DIR's runs again, without running them
    .venv/bin/python benchmarks/verdict.py --recordings aces,csail --seed 2   # the stochastic methods' other seeds
    .venv/bin/python benchmarks/verdict.py --write BENCHMARKS.md   # the table into its section there

Each recording is compared as a user would (``slam2d compare``'s code, with the methods gmapping,
karto, lago, hector and coreslam with ``use_odometry=true``, and odometry; seed 0). The ranking in
``comparison.json`` comes from the reference-free measures only; the reference (a GMapping result on
the real logs) or the exact truth (simulated) is used afterwards, to score it: the first-ranked
method's ATE must be at most max(1.25 x the best ATE, best + 0.05 m), and Kendall's tau between the
reference-free ranking and the ATE values is reported. The measures' time for one fr079 run is
``slam2d evaluate``'s: reading the recording and judging the trajectory (CPU seconds, after a
warm-up that compiles the kernels).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from defaults import REAL_LOGS, SHARED, emit_section  # noqa: E402

METHODS = ["gmapping", "karto", "lago", "hector", "coreslam", "odometry"]
SETTINGS = {"hector.use_odometry": True, "coreslam.use_odometry": True}
#: simulated recordings: name -> (world, seed, duration s); the simulator's default (strong) odometry noise
SIMULATED = {
    "sim-office-1": ("office", 1, 120.0),
    "sim-office-2": ("office", 2, 120.0),
    "sim-corridor-loop-1": ("corridor-loop", 1, None),
    "sim-corridor-loop-2": ("corridor-loop", 2, None),
    "sim-office-3": ("office", 3, 120.0),
    "sim-office-4": ("office", 4, 120.0),
    "sim-corridor-loop-3": ("corridor-loop", 3, None),
    "sim-corridor-loop-4": ("corridor-loop", 4, None),
}
#: recordings the measures' settings were not chosen on
HELD_OUT = ("sim-office-3", "sim-office-4", "sim-corridor-loop-3", "sim-corridor-loop-4")
SECTION_BEGIN = "<!-- BEGIN verdict (benchmarks/verdict.py --write) -->"
SECTION_END = "<!-- END verdict -->"


def _recording(name: str, workdir: Path):
    """``(data, truth)`` of a recording, simulated into ``workdir/NAME`` when it is one; None when missing."""
    from methods import Dataset, prepare

    if name in SIMULATED:
        world, seed, duration = SIMULATED[name]
        return prepare(Dataset(name, "sim", world, duration, seed=seed), workdir)
    return prepare(Dataset(name, "shared", f"{name}/{name}.clf.gz"), workdir)


def _rejudge(data: Path, folder: Path, truth, settings: dict) -> dict:
    """The verdict of an earlier comparison's runs, judged again with the current code (and ``settings`` of
    :class:`~slam2d.eval.self_consistency.ConsistencyParams`)."""
    from slam2d.eval.compare import verdict
    from slam2d.eval.evaluate import evaluate_run, load_run
    from slam2d.eval.self_consistency import ConsistencyParams, judge_trajectory
    from slam2d.io import open_recording

    frames = list(open_recording(data).frames())
    params = ConsistencyParams(**settings)
    evaluations = {}
    for method in METHODS:
        folder_of_run = folder / "runs" / method
        if (folder_of_run / "trajectory.tum").is_file():
            run = load_run(folder_of_run)
            evaluations[method] = evaluate_run(run, truth)
            evaluations[method]["self_consistency"] = judge_trajectory(frames, run.times, run.poses, params)
    return verdict(evaluations)


def _compare(data: Path, folder: Path, truth, seed: int = 0) -> dict:
    from slam2d.eval.compare import compare

    compare(data, METHODS, folder, truth=truth, settings=SETTINGS, seed=seed, jobs=2)
    document = json.loads((folder / "comparison.json").read_text())
    return {"reference_free": document["reference_free"], "reference": document["reference"],
            "sentence": document["verdict"]}


def score(judged: dict) -> dict:
    """The first-ranked method against the best by ATE, and Kendall's tau of the two rankings."""
    from scipy.stats import kendalltau

    order = judged["reference_free"]["ranking"]
    ate = judged["reference"]["ate_rmse_m"]
    order = [m for m in order if m in ate]
    best = min(ate.values())
    first = order[0]
    ok = ate[first] <= max(1.25 * best, best + 0.05)
    tau = float(kendalltau(range(len(order)), [ate[m] for m in order]).statistic)
    return {"first": first, "first_ate": ate[first], "best": min(ate, key=ate.get), "best_ate": best, "ok": ok,
            "tau": tau, "confidence": judged["reference_free"]["confidence"], "order": order, "ate": ate}


def measure_time(runs_folder: Path | None) -> float | None:
    """CPU seconds of the measures for one fr079 run (reading included), karto's trajectory; None without it."""
    from slam2d.eval.self_consistency import judge_trajectory
    from slam2d.io import open_recording
    from slam2d.io.tum import read_tum

    data = SHARED / "fr079" / "fr079.clf.gz"
    run = runs_folder / "cmp-fr079" / "runs" / "karto" / "trajectory.tum" if runs_folder else None
    if not data.is_file() or run is None or not run.is_file():
        return None
    times, poses = read_tum(run)
    judge_trajectory(open_recording(data).frames(), times[:50], poses[:50])  # compiles the kernels
    cpu = []
    for _ in range(3):
        t0 = time.process_time()
        judge_trajectory(open_recording(data).frames(), times, poses)
        cpu.append(time.process_time() - t0)
    return statistics.median(cpu)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--recordings", help="comma-separated: real logs and " + ", ".join(SIMULATED))
    ap.add_argument("--keep", type=Path, help="keep the comparisons in this folder")
    ap.add_argument("--rejudge", type=Path, help="judge the runs of an earlier --keep folder again, without running")
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                    help="with --rejudge: a ConsistencyParams setting to try (resolution=0.05, max_range=10, ...)")
    ap.add_argument("--seed", type=int, default=0,
                    help="the comparisons' seed (gmapping's and coreslam's runs change with it; the table is seed 0)")
    ap.add_argument("--write", type=Path, metavar="BENCHMARKS.md")
    args = ap.parse_args()
    settings = {k: (float(v) if "." in v else int(v)) for k, v in (item.split("=", 1) for item in args.set)}
    if settings and not args.rejudge:
        ap.error("--set needs --rejudge (a comparison judges with the defaults)")
    if args.write and args.seed != 0:
        ap.error("--write is for the seed-0 table; other seeds are printed only")
    names = args.recordings.split(",") if args.recordings else [*REAL_LOGS, *SIMULATED]
    rows = []
    with tempfile.TemporaryDirectory(prefix="slam2d-verdict-") as tmp:
        work = args.rejudge or args.keep or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        for name in names:
            found = _recording(name, work)
            if found is None:
                print(f"skip {name}: {SHARED / name} is missing", file=sys.stderr)
                continue
            data, truth = found
            t0 = time.perf_counter()
            folder = work / f"cmp-{name}"
            judged = _rejudge(data, folder, truth, settings) if args.rejudge else _compare(data, folder, truth, args.seed)
            row = {"recording": name + (" (held out)" if name in HELD_OUT else ""), "held_out": name in HELD_OUT,
                   **score(judged), "sentence": judged["sentence"]}
            rows.append(row)
            print(f"{name}: first {row['first']} ({row['first_ate']:.3f} m), best {row['best']} "
                  f"({row['best_ate']:.3f} m), {'ok' if row['ok'] else 'FAIL'}, tau {row['tau']:.2f}, "
                  f"confidence {row['confidence']}; {time.perf_counter() - t0:.0f} s", file=sys.stderr)
        seconds = measure_time(work) if "fr079" in names else None
    table = markdown(rows)
    head = (
        "`slam2d compare` without a reference ranks the methods by how far each one's map disagrees with "
        "itself (docs/evaluation.md, \"Which map to trust\"). Scored here against each recording's "
        "reference (real logs: a GMapping result) or exact truth (simulated: the simulator's default odometry "
        "noise, URG-04LX): first-ranked ATE within max(1.25 x best, best + 0.05 m), and Kendall's tau "
        "between the reference-free order and the ATE values. Methods gmapping, karto, lago, hector and "
        "coreslam (`use_odometry=true`), odometry; seed 0. The measures' settings were chosen on the real logs "
        "and simulated seeds 1 and 2; seeds 3 and 4 are held out."
        + (f" The measures for one fr079 run (reading the recording included): {seconds:.1f} s CPU (median "
           "of 3)." if seconds is not None else "")
        + f" Measured {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; command: "
        "`.venv/bin/python benchmarks/verdict.py --write BENCHMARKS.md`."
    )
    emit_section(SECTION_BEGIN, SECTION_END, "Verdict without a reference", head, table, args.write)
    return 0 if all(r["ok"] for r in rows) else 1


def markdown(rows: list[dict]) -> list[str]:
    out = ["| recording | ranked first (ATE m) | best by ATE (m) | within bound | Kendall tau | confidence | "
           "order, reference-free (ATE m) |",
           "|---|---|---|---|---|---|---|"]
    for r in rows:
        order = ", ".join(f"{m} ({r['ate'][m]:.3f})" for m in r["order"])
        conf = "-" if r["confidence"] is None else f"{r['confidence']:.2f}"
        out.append(f"| {r['recording']} | {r['first']} ({r['first_ate']:.3f}) | {r['best']} ({r['best_ate']:.3f}) "
                   f"| {'yes' if r['ok'] else '**no**'} | {r['tau']:.2f} | {conf} | {order} |")
    for label, part in (("chosen on", [r for r in rows if not r["held_out"]]),
                        ("held out", [r for r in rows if r["held_out"]]),
                        ("all", rows)):
        if part:
            out.append(f"| **{label}: {len(part)}** | | | {sum(r['ok'] for r in part)} of {len(part)} | "
                       f"**{statistics.mean(r['tau'] for r in part):.2f}** (mean) | | |")
    return out


if __name__ == "__main__":
    raise SystemExit(main())
