#!/usr/bin/env python3
"""A real log whose odometry misses one turn: the issue's "fourth log", made from the shared logs.

    .venv/bin/python benchmarks/missed_turn.py [--logs intel,aces,fr101,csail] [--turn 80] [--methods karto,lago,gmapping]
    .venv/bin/python benchmarks/missed_turn.py --logs csail --methods gmapping --seeds 0-4 --guard-only

At a third of each log the odometry loses ``--turn`` degrees (every later reading rotated about
the robot's pose there, so each later increment is right and one is wrong, as when a turn in
place was never reported). Each method runs with its defaults (gmapping seed 0, or each of ``--seeds``)
with the odometry gap guard on and off; ATE against the log's reference.tum (a GMapping result).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "datasets"


def missed_turn(frames, k, turn):
    """The frames with the odometry from frame ``k`` on missing a turn of ``turn`` rad."""
    from slam2d.sim.faults import frames_with_odometry_missing

    return frames_with_odometry_missing(frames, k, np.array([0.0, 0.0, turn]))


def main() -> int:
    from slam2d.eval.trajectory_metrics import absolute_trajectory_error, associate
    from slam2d.io import open_recording
    from slam2d.io.tum import read_tum
    from slam2d.methods.runner import build_method_for

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--logs", default="intel,aces,fr101,csail")
    parser.add_argument("--methods", default="karto,lago,gmapping")
    parser.add_argument("--turn", type=float, default=80.0, help="degrees the odometry misses")
    parser.add_argument("--seeds", default="0", help="seeds of the stochastic methods, e.g. 0-4 (one row each)")
    parser.add_argument("--guard-only", action="store_true", help="skip the runs with the guard off")
    args = parser.parse_args()
    first, _, last = args.seeds.partition("-")
    seeds = list(range(int(first), int(last or first) + 1))
    print("| log | method | guard on: ATE (m), corrections | guard off: ATE (m) |\n|---|---|---|---|")
    for log in args.logs.split(","):
        data = SHARED / log / f"{log}.clf.gz"
        if not data.is_file():
            print(f"skip {log}: {data} missing", file=sys.stderr)
            continue
        frames = list(open_recording(data).frames())
        broken = missed_turn(frames, len(frames) // 3, math.radians(args.turn))
        rt, rp = read_tum(data.parent / "reference.tum")
        for method in args.methods.split(","):
            for seed in seeds if method == "gmapping" else seeds[:1]:
                cells = []
                for check in (True,) if args.guard_only else (True, False):
                    slam = build_method_for(method, broken, settings={"odometry_gap_check": check}, seed=seed).run(broken)
                    t, p = slam.trajectory()
                    ate = absolute_trajectory_error(associate(t, p, rt, rp))["translation_m"]["rmse"]
                    n = slam.diagnostics.counters.get("odometry_recoveries", 0)
                    cells.append(f"{ate:.3f}, {n}" if check else f"{ate:.3f}")
                label = f"`{method}`" + (f" seed {seed}" if len(seeds) > 1 and method == "gmapping" else "")
                print(f"| {log} | {label} | {cells[0]} | {cells[1] if len(cells) > 1 else '-'} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
