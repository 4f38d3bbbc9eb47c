#!/usr/bin/env python3
"""Are gmapping's weight increments noise or a particle's lasting merit? (docs/methods/what-was-tried.md, "gmapping, aces seeds 3 and 4").

    NUMBA_NUM_THREADS=1 .venv/bin/python benchmarks/studies/measure_gmapping_weight_noise.py ../shared/datasets/aces/aces.clf.gz \
        --seed 3 --set srt=0.05 --set stt=0.05

At every filter update, each particle's scan log-likelihood relative to the particles' mean; printed per
100 s of log: the median spread of it, and its correlation with the same particle's value at the previous
update (both updates without a resampling, so the index is the same particle): about 0 if the
differences are fresh noise every scan, towards 1 if a particle keeps scoring better or worse.
"""

from __future__ import annotations

import argparse

import numpy as np

from slam2d.io import open_recording
from slam2d.methods.runner import build_method


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE")
    a = ap.parse_args()
    m = build_method("gmapping", settings=dict(s.split("=", 1) for s in a.set), seed=a.seed)
    rows, prev = [], None
    for f in open_recording(a.log).frames():
        before = m._weight_sum.copy()
        v = m.update(f)
        if not v or v.get("updated") != 1.0 or m._nodes < 2:
            continue
        like = m._weight_sum - before[m._node_parents[m._nodes - 1]]  # this scan's log-likelihood per particle
        rel = like - like.mean()
        corr = np.nan
        if prev is not None and not prev[1] and not v["resampled"] and rel.std() > 0 and prev[0].std() > 0:
            corr = float(np.corrcoef(prev[0], rel)[0, 1])
        rows.append((f.timestamp, rel.std(), corr, v["resampled"]))
        prev = (rel, v["resampled"])
    r = np.array(rows)
    print("| log time (s) | median spread of a scan's log-likelihood | lag-1 correlation (pairs) | resamplings |")
    print("|---|---|---|---|")
    for lo in np.arange(0.0, r[-1, 0] - r[0, 0] + 1e-9, 100.0):
        w = r[(r[:, 0] - r[0, 0] >= lo) & (r[:, 0] - r[0, 0] < lo + 100.0)]
        if len(w):
            print(f"| {lo:.0f}-{lo + 100:.0f} | {np.median(w[:, 1]):.1f} | {np.nanmean(w[:, 2]):+.2f} "
                  f"({int(np.isfinite(w[:, 2]).sum())}) | {int(w[:, 3].sum())} |")


if __name__ == "__main__":
    main()
