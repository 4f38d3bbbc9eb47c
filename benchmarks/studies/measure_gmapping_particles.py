#!/usr/bin/env python3
"""gmapping's ATE, CPU time and peak memory per seed at a particle count (docs/methods/what-was-tried.md, "gmapping, 300 and 500 particles").

    NUMBA_NUM_THREADS=1 SLAM2D_THREADS=1 .venv/bin/python benchmarks/studies/measure_gmapping_particles.py \
        ../shared/datasets/aces/aces.clf.gz --particles 300 --seeds 10-19 \
        --set srt=0.05 --set stt=0.05 --set ogain=0.3

Every seed is a separate ``slam2d run gmapping`` process (so its peak memory, read from its
run.json, is its own), judged as ``slam2d evaluate`` judges it against the ``reference.tum``
beside the log. Printed per seed: the ATE (RMSE, metres), the child's CPU time (user + sys,
whole process: reading, filter, map, writing; the numba kernels come from the on-disk cache),
its peak RSS; then how many seeds are under ``--target``. Run folders go to ``--work``
(a temporary folder by default).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
from pathlib import Path

from slam2d.eval.evaluate import evaluate_run, load_reference, load_run


def seed_list(text: str) -> list[int]:
    """``"10-19"`` or ``"0,3,5"`` (or a mix) as a list of seeds."""
    seeds: list[int] = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        seeds.extend(range(int(lo), int(hi or lo) + 1))
    return seeds


def child_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log", type=Path)
    ap.add_argument("--particles", type=int, default=30)
    ap.add_argument("--seeds", type=seed_list, default=seed_list("0-9"), help="e.g. 10-19 or 0,2,4")
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE", help="a method parameter (repeatable)")
    ap.add_argument("--target", type=float, default=0.15, help="ATE bound counted in the summary, m")
    ap.add_argument("--work", type=Path, default=None, help="where the run folders go (default: a temporary folder)")
    a = ap.parse_args()
    reference = load_reference(a.log.parent / "reference.tum")
    work = a.work or Path(tempfile.mkdtemp(prefix="gmapping-particles-"))
    settings = [f"particles={a.particles}", *a.set]
    print(f"gmapping on {a.log.name}, {' '.join(settings)}")
    print("| seed | ATE (m) | CPU (s) | peak (MB) |")
    print("|---|---|---|---|")
    ates = []
    for seed in a.seeds:
        out = work / f"{a.log.parent.name}-{a.particles}-s{seed}"
        cmd = [sys.executable, "-m", "slam2d", "run", "gmapping", str(a.log), "--out", str(out), "--seed", str(seed)]
        for s in settings:
            cmd += ["--set", s]
        cpu0 = child_cpu()
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, env=os.environ.copy())
        cpu = child_cpu() - cpu0
        ate = evaluate_run(load_run(out), reference)["trajectory"]["ate"]["translation_m"]["rmse"]
        peak = json.loads((out / "run.json").read_text())["peak_rss_mb"]
        ates.append(ate)
        print(f"| {seed} | {ate:.3f} | {cpu:.0f} | {peak:.0f} |", flush=True)
    passed = sum(x < a.target for x in ates)
    print(f"{passed}/{len(ates)} seeds under {a.target} m; worst {max(ates):.3f} m, mean {sum(ates) / len(ates):.3f} m")


if __name__ == "__main__":
    main()
