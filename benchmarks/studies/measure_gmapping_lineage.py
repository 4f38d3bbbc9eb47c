#!/usr/bin/env python3
"""Why a gmapping run keeps or loses the particles that would close a loop (docs/methods/what-was-tried.md, "gmapping, aces seeds 3 and 4").

    NUMBA_NUM_THREADS=1 .venv/bin/python benchmarks/studies/measure_gmapping_lineage.py ../shared/datasets/aces/aces.clf.gz \
        --seed 3 --set srt=0.05 --set stt=0.05

Feeds the log's frames to ``gmapping`` and, at every filter update, compares every particle
with the log's ``reference.tum`` *relative to the start* (the reference is moved so that its
pose at the first scan is the first odometry pose; no other alignment): that is the error a
particle carries into a loop that returns to the start's map. Printed per time window: the
updates, resamplings and mean Neff; the best particle's error and the nearest particle's; the
particle cloud's standard deviation along its two principal axes; how many distinct ancestors
the particles have 30 and 100 updates back; the particles' spread of the scan's log-likelihood
(the weight increment before the ``ogain * N`` divisor) and its correlation with their
(negated) error, i.e. whether the weights favour the particles that are right.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from slam2d.core import se2
from slam2d.eval.trajectory_metrics import align_se2, associate
from slam2d.io import open_recording
from slam2d.io.tum import interpolate_poses, read_tum
from slam2d.methods.runner import build_method


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE")
    ap.add_argument("--window", type=float, default=100.0, help="seconds per printed row")
    a = ap.parse_args()
    settings = dict(s.split("=", 1) for s in a.set)  # text values: build_method coerces them
    rt, rp = read_tum(Path(a.log).parent / "reference.tum")
    m = build_method("gmapping", settings=settings, seed=a.seed)
    start = None
    rows = []
    for f in open_recording(a.log).frames():
        before = m._weight_sum.copy()
        v = m.update(f)
        ref, ok = interpolate_poses(rt, rp, np.array([f.timestamp]), 0.5)
        if start is None and m._nodes == 1 and ok[0]:
            start = se2.compose(m._node_poses[0, 0], se2.inverse(ref[0]))
        if not v or v.get("updated") != 1.0 or m._nodes < 2 or not ok[0] or start is None:
            continue
        k = m._nodes - 1
        truth = se2.compose(start, ref[0])
        pose = m._state
        err = np.hypot(pose[:, 0] - truth[0], pose[:, 1] - truth[1])
        like = m._weight_sum - before[m._node_parents[k]]  # this scan's log-likelihood, per (resampled) particle
        corr = float(np.corrcoef(like, -err)[0, 1]) if like.std() > 0 and err.std() > 0 else np.nan
        lineage, ancestors = np.arange(m._n), {}
        for d in range(1, min(k, 100) + 1):
            lineage = m._node_parents[k - d + 1][lineage]
            if d in (30, 100):
                ancestors[d] = len(np.unique(lineage))
        axes = np.sqrt(np.maximum(np.linalg.eigvalsh(np.cov(pose[:, :2].T)), 0.0))
        rows.append((f.timestamp, v["neff"], v["resampled"], err[m.best_particle()], err.min(), axes[0], axes[1],
                     ancestors.get(30, np.nan), ancestors.get(100, np.nan), like.std(), corr))
    r = np.array(rows, dtype=float)
    print(f"seed {a.seed}, settings {settings}")
    print("| log time (s) | updates | resamplings | mean Neff | best particle's error (m) | nearest particle's (m) | "
          "cloud sd minor / major (m) | ancestors 30 / 100 back | log-lik sd | corr(log-lik, -error) |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for lo in np.arange(a.window * np.floor(r[0, 0] / a.window), r[-1, 0] + 1e-9, a.window):
        w = r[(r[:, 0] >= lo) & (r[:, 0] < lo + a.window)]
        if not len(w):
            continue
        print(f"| {lo:.0f}-{lo + a.window:.0f} | {len(w)} | {int(w[:, 2].sum())} | {w[:, 1].mean():.1f} | "
              f"{w[-1, 3]:.2f} | {w[-1, 4]:.2f} | {w[-1, 5]:.2f} / {w[-1, 6]:.2f} | {w[-1, 7]:.0f} / {w[-1, 8]:.0f} | "
              f"{np.median(w[:, 9]):.0f} | {np.nanmean(w[:, 10]):+.2f} |")
    times, poses = m.trajectory()
    pair = associate(times, poses, rt, rp)
    moved = se2.compose(align_se2(pair.estimate[:, :2], pair.reference[:, :2]), pair.estimate)
    ate = float(np.sqrt(np.mean(np.sum((moved[:, :2] - pair.reference[:, :2]) ** 2, axis=1))))
    print(f"ATE {ate:.3f} m (as slam2d evaluate), {int(r[:, 2].sum())} resamplings in {len(r)} updates")


if __name__ == "__main__":
    main()
