#!/usr/bin/env python3
"""Which of gmapping's final particles is right, and where the right ones were lost (docs/methods/what-was-tried.md, "gmapping, aces on ten seeds").

    NUMBA_NUM_THREADS=1 .venv/bin/python benchmarks/studies/measure_gmapping_final_choice.py ../shared/datasets/aces/aces.clf.gz \
        --seed 3 --set srt=0.05 --set stt=0.05

Runs the filter over the log and keeps, at every update, every particle's pose *before* the
resampling, its normalised weight and the resampling's parents. Printed:

* the ATE (aligned as ``slam2d evaluate`` does) of *every* final particle's path through its
  ancestors: the one GMapping returns (largest accumulated log-likelihood, ``weightSum``), the
  one with the largest weight since the last resampling, and the best and the median of them
  (what choosing among the final particles could get at most);
* the first loop return (the first update where the reference comes within ``--loop-radius``
  of where it was ``--loop-gap`` seconds or more before) and, just before it, the particles'
  error *relative to the start* (the reference moved so that its pose at the first scan is the
  first odometry pose; no other alignment): the returned particle's, the nearest's, how many are
  within ``--good`` m;
* every ``--window`` seconds up to the loop: the particles' weighted mean error relative to the
  start, the nearest particle's, and the weighted standard deviation of their heading;
* every resampling before the loop where some particle was within ``--good`` m: its time, Neff,
  the lines it kept, the good particles' share of the weight times N (the children they should
  get), the children they got, and whether any of them has descendants at the loop.

``--save FILE.npz`` keeps the per-update arrays for further looks.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import slam2d.methods.gmapping as gmapping_module
from slam2d.core import se2
from slam2d.eval.trajectory_metrics import align_se2, associate
from slam2d.filters import backtrack, normalized_weights
from slam2d.io import open_recording
from slam2d.io.tum import interpolate_poses, read_tum
from slam2d.methods.runner import build_method


def particle_path(m, i: int) -> tuple[np.ndarray, np.ndarray]:
    """Particle ``i``'s path at every frame: its ancestors' nodes, the odometry composed on in between."""
    nodes = backtrack(m._node_poses[: m._nodes], m._node_parents[: m._nodes], i)
    k = np.asarray(m._frame_node)
    rel = se2.relative(m._node_odom[k], np.stack(m._frame_odom))
    return np.array(m._frame_times), se2.compose(nodes[k], rel)


def ate(times, poses, rt, rp) -> float:
    pair = associate(times, poses, rt, rp)
    moved = se2.compose(align_se2(pair.estimate[:, :2], pair.reference[:, :2]), pair.estimate)
    return float(np.sqrt(np.mean(np.sum((moved[:, :2] - pair.reference[:, :2]) ** 2, axis=1))))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE")
    ap.add_argument("--loop-radius", type=float, default=2.0, help="m")
    ap.add_argument("--loop-gap", type=float, default=200.0, help="s")
    ap.add_argument("--good", type=float, default=0.2, help="m: a particle this close to the truth is 'right'")
    ap.add_argument("--window", type=float, default=50.0, help="s")
    ap.add_argument("--save", type=Path, default=None, help="write the per-update arrays here (.npz)")
    a = ap.parse_args()
    settings = dict(s.split("=", 1) for s in a.set)
    rt, rp = read_tum(Path(a.log).parent / "reference.tum")
    m = build_method("gmapping", settings=settings, seed=a.seed)
    hook = {}
    resample = gmapping_module.systematic_resample

    def recording_resample(w, u):  # the filter sets its matched poses before it resamples
        hook["pre"], hook["w"] = m._state.copy(), np.asarray(w).copy()
        return resample(w, u)

    gmapping_module.systematic_resample = recording_resample
    start = None
    times, pre, weights, neffs, resampled, truths, parents, chosen = [], [], [], [], [], [], [], []
    for f in open_recording(a.log).frames():
        hook.clear()
        v = m.update(f)
        ref, ok = interpolate_poses(rt, rp, np.array([f.timestamp]), 0.5)
        if start is None and m._nodes == 1 and ok[0]:
            start = se2.compose(m._node_poses[0, 0], se2.inverse(ref[0]))
        if not v or v.get("updated") != 1.0 or m._nodes < 2:
            continue
        times.append(f.timestamp)
        if hook:
            pre.append(hook["pre"])
            weights.append(hook["w"])
        else:
            pre.append(m._state.copy())
            weights.append(normalized_weights(m._weight, 1.0 / (m.params.ogain * m._n)))
        neffs.append(v["neff"])
        resampled.append(bool(v["resampled"]))
        parents.append(m._node_parents[m._nodes - 1].copy())
        chosen.append(m.best_particle())
        truths.append(se2.compose(start, ref[0]) if ok[0] and start is not None else np.full(3, np.nan))
    gmapping_module.systematic_resample = resample
    times, truths, pre, weights, parents = map(np.array, (times, truths, pre, weights, parents))
    err = np.hypot(pre[..., 0] - truths[:, None, 0], pre[..., 1] - truths[:, None, 1])  # before resampling

    n = m._n
    ates = np.array([ate(*particle_path(m, i), rt, rp) for i in range(n)])
    best = m.best_particle()
    current = int(np.argmax(m._weight))
    print(f"seed {a.seed}, settings {settings}: {len(times)} updates, {int(np.sum(resampled))} resamplings")
    print(f"final particles' ATE (m): returned (weightSum) {ates[best]:.3f}, largest weight since the last "
          f"resampling {ates[current]:.3f}, best {ates.min():.3f}, median {np.median(ates):.3f}; "
          f"{int(np.sum(ates < 0.15))} of {n} under 0.15 m")

    ok = np.isfinite(truths[:, 0])
    loop = None
    for k in np.flatnonzero(ok):
        old = ok & (times < times[k] - a.loop_gap)
        if old.any() and np.min(np.hypot(*(truths[old, :2] - truths[k, :2]).T)) < a.loop_radius:
            loop = int(k)
            break
    if loop is None:
        print("no loop return found")
        return
    e = err[loop]
    print(f"first loop return: t = {times[loop]:.0f} s (update {loop}); the particles' error relative to the start "
          f"there (before its resampling): the best by weightSum {e[chosen[loop - 1]]:.2f} m, nearest "
          f"{np.nanmin(e):.2f} m, {int(np.sum(e < a.good))} within {a.good} m; Neff {neffs[loop]:.1f}")
    heading = (pre[..., 2] - truths[:, None, 2] + np.pi) % (2 * np.pi) - np.pi
    print("| t (s) | weighted mean error (m) | nearest (m) | heading sd (rad) |")
    print("|---|---|---|---|")
    for lo in np.arange(a.window * np.ceil(times[0] / a.window), times[loop] + 1e-9, a.window):
        k = min(int(np.searchsorted(times, lo)), loop)
        h = float(np.dot(weights[k], heading[k]))
        print(f"| {times[k]:.0f} | {np.dot(weights[k], err[k]):.2f} | {np.nanmin(err[k]):.2f} | "
              f"{np.sqrt(np.dot(weights[k], (heading[k] - h) ** 2)):.3f} |")
    # which particles at update k (before its resampling) have descendants at the loop (before its resampling)
    reach = np.ones(n, dtype=bool)
    reaches = np.zeros((loop + 1, n), dtype=bool)
    reaches[loop] = reach
    for k in range(loop, 0, -1):
        anc = np.zeros(n, dtype=bool)
        anc[parents[k - 1][reach]] = True  # update k's particles descend from update k-1's resampled set
        reach = anc
        reaches[k - 1] = reach
    print(f"| t (s) | Neff | lineages kept | nearest (m) | within {a.good} m | their weight x N | their children | "
          "a right one reaches the loop |")
    print("|---|---|---|---|---|---|---|---|")
    last = None
    for k in range(loop):
        good = err[k] < a.good
        if good.any() and reaches[k][good].any():
            last = k
        if not resampled[k] or not good.any():
            continue
        kids = np.bincount(parents[k], minlength=n)
        print(f"| {times[k]:.0f} | {neffs[k]:.1f} | {int(np.sum(kids > 0))} | {np.nanmin(err[k]):.2f} | "
              f"{int(good.sum())} | {weights[k][good].sum() * n:.1f} | {int(kids[good].sum())} | "
              f"{'yes' if reaches[k][good].any() else 'no'} |")
    print("last update with a right particle whose line reaches the loop: "
          + (f"t = {times[last]:.0f} s" if last is not None else "none"))
    if a.save is not None:
        np.savez(a.save, times=times, truths=truths, pre=pre, weights=weights, parents=parents,
                 neffs=np.array(neffs), resampled=np.array(resampled), ates=ates)


if __name__ == "__main__":
    main()
