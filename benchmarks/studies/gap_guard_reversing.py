#!/usr/bin/env python3
"""The odometry guard on every recording, forwards and played backwards: recoveries and a hash of its output.

    .venv/bin/python benchmarks/studies/gap_guard_reversing.py [--logs intel,aces,fr079,fr101,csail] [--worlds office,corridor-loop]

Every method that reads odometry is fed the guard's corrected odometry (slam2d.matching.odometry_gaps), so a change
to the guard that leaves its output bit for bit the same on a recording leaves every method's run on it the same.
Each recording is checked as it is and played backwards (the robot reversing along its path with its laser still
looking forwards, as benchmarks/memory.py's repeated log drives every second pass); printed: recoveries and
the output's hash for the default check and for hector's (``refine``).
"""

from __future__ import annotations

import argparse
import hashlib
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "src"))
SHARED = ROOT.parent / "shared" / "datasets"


def guard_run(frames, check) -> tuple[int, str]:
    from slam2d.matching.odometry_gaps import OdometryGapGuard

    guard = OdometryGapGuard(check)
    out = []
    for f in frames:
        if f.odometry is None:
            continue
        out.append(guard.correct(f.scan.points_in_base(), np.asarray(f.odometry, dtype=np.float64))[0])
    return guard.recoveries, hashlib.sha256(np.asarray(out).tobytes()).hexdigest()[:12]


def main() -> int:
    from slam2d.io import open_recording
    from slam2d.matching.odometry_gaps import GapCheck

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--logs", default="intel,aces,fr079,fr101,csail")
    ap.add_argument("--worlds", default="office,corridor-loop")
    args = ap.parse_args()
    recordings = [(name, SHARED / name / f"{name}.clf.gz") for name in args.logs.split(",") if name]
    with tempfile.TemporaryDirectory(prefix="slam2d-guard-") as tmp:
        from slam2d.sim.simulate import SimulationParams, simulate, write_outputs

        for world in (w for w in args.worlds.split(",") if w):
            write_outputs(simulate(world, SimulationParams(seed=0)), Path(tmp) / world)
            recordings.append((world, Path(tmp) / world / "recording.log.gz"))
        print("| recording | direction | recoveries (default) | hash | recoveries (refine) | hash |")
        print("|---|---|---|---|---|---|")
        for name, path in recordings:
            if not path.is_file():
                print(f"| {name} | (missing) | | | | |")
                continue
            frames = list(open_recording(path).frames())
            for direction, seq in (("forwards", frames), ("backwards", frames[::-1])):
                plain = guard_run(seq, GapCheck())
                refine = guard_run(seq, GapCheck(refine=True))
                print(f"| {name} | {direction} | {plain[0]} | {plain[1]} | {refine[0]} | {refine[1]} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
