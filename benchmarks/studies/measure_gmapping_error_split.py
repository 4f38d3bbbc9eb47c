#!/usr/bin/env python3
"""Where gmapping's ATE on the simulated office (URG-04LX) lies: along the robot's heading, across it, heading.

    .venv/bin/python benchmarks/studies/measure_gmapping_error_split.py [--world office] [--laser urg-04lx] [--seeds 0,1,2] \
        [--table] [key=value ...]

The recordings and runs of `benchmarks/studies/measure_gmapping_proposal.py` (same cache, same settings, run again
here): the estimate is aligned to the truth as `slam2d evaluate` aligns it (rigid, least squares over
the positions), and each pose's position error is split along and across the *true* heading. Printed
per seed: the ATE (m), the rms along and across (m) and the rms heading error after the alignment
(deg); with ``--table`` also the mean of each per 5 s of the run, with the true position at its start.
"""

from __future__ import annotations

import argparse
import sys
import math
from pathlib import Path

import numpy as np

from slam2d.core import se2
from slam2d.eval.evaluate import load_run, load_truth
from slam2d.eval.trajectory_metrics import align_se2, associate
from slam2d.methods.runner import run_method

sys.path.insert(0, str(Path(__file__).parent))
from measure_gmapping_proposal import cached_recording  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--laser", default="urg-04lx")
    ap.add_argument("--world", default="office")
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--cache", default="/tmp/slam2d-proposal")
    ap.add_argument("--table", action="store_true", help="also the errors per 5 s")
    ap.add_argument("settings", nargs="*")
    a = ap.parse_args()
    settings = dict(s.split("=", 1) for s in a.settings)
    for seed in (int(s) for s in a.seeds.split(",")):
        sim_dir = cached_recording(a.cache, a.world, a.laser, seed)
        run_dir = Path(a.cache) / f"split-gmapping-{a.world}-{a.laser}-{seed}-{'_'.join(a.settings)}"
        run_method("gmapping", sim_dir / "recording.log.gz", run_dir, settings=settings)
        run, truth = load_run(run_dir), load_truth(sim_dir)
        assoc = associate(run.times, run.poses, truth.times, truth.poses)
        t = align_se2(assoc.estimate[:, :2], assoc.reference[:, :2])
        est, ref = se2.compose(t, assoc.estimate), assoc.reference
        dx, dy = est[:, 0] - ref[:, 0], est[:, 1] - ref[:, 1]
        c, s = np.cos(ref[:, 2]), np.sin(ref[:, 2])
        along, across = dx * c + dy * s, -dx * s + dy * c
        dth = np.degrees(se2.wrap_angle(est[:, 2] - ref[:, 2]))
        rms = lambda v: math.sqrt(float(np.mean(v * v)))  # noqa: E731
        print(f"{a.world} {a.laser} seed {seed}: ATE {math.sqrt(rms(dx) ** 2 + rms(dy) ** 2):.3f} m, along "
              f"{rms(along):.3f} m, across {rms(across):.3f} m, heading {rms(dth):.2f} deg", flush=True)
        if a.table:
            tt = assoc.times - assoc.times[0]
            for k in range(0, int(tt[-1]) + 1, 5):
                m = (tt >= k) & (tt < k + 5)
                if m.any():
                    i = int(np.argmax(m))
                    print(f"  {k:4d} s at ({ref[i, 0]:5.1f}, {ref[i, 1]:5.1f}): along {along[m].mean():+.3f} m, "
                          f"across {across[m].mean():+.3f} m, heading {dth[m].mean():+.2f} deg")


if __name__ == "__main__":
    main()
