"""crsm on the mines logs, seed by seed: scan_consistency and heading agreement with hector's trajectory.

    .venv/bin/python benchmarks/studies/crsm_mines_seeds.py [--seeds 0 1 2 3 4] [--set NAME=VALUE ...] [--cache DIR]
        [--departures DEG]

Prints one row per log and seed. ``heading_p95_deg`` is the 95th percentile, over scans, of
|crsm's heading - hector's| after the best rigid alignment of crsm's positions onto hector's (as ATE
aligns); ``rel50_p95_deg`` the 95th percentile of the difference in heading change over 50 scans
(local turns, insensitive to a slow drift). hector's trajectories are cached in ``--cache``.
``--departures DEG`` also lists the scans whose turn differs from hector's by more than DEG degrees,
with crsm's per-scan diagnostics (rays, rays on unknown space, turn_z, turn_rejected), and the
cumulative turn difference every 50 scans (where the heading drifts away).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from slam2d.eval import scan_consistency  # noqa: E402
from slam2d.eval.trajectory_metrics import heading_agreement  # noqa: E402
from slam2d.core import se2  # noqa: E402
from slam2d.io import open_recording  # noqa: E402
from slam2d.methods.runner import build_method  # noqa: E402

LOGS = {"mines-exp1": "mines-exp1/mines-exp1.clf.gz", "mines-exp2": "mines-exp2/mines-exp2.clf.gz"}


def _value(text: str):
    for cast in (int, float):
        try:
            return cast(text)
        except ValueError:
            pass
    return text


def run(frames, name, seed, settings):
    slam = build_method(name, settings=settings, seed=seed)
    slam.run(frames)
    times, poses = slam.trajectory()
    return np.asarray(times), np.asarray(poses), slam


def departures(times, poses, ref_times, ref_poses, series, threshold_deg) -> None:
    """Print the scans whose turn differs from the reference's by more than ``threshold_deg``."""
    idx = np.clip(np.searchsorted(ref_times, times), 0, len(ref_times) - 1)
    mine = np.degrees(se2.wrap_angle(np.diff(poses[:, 2])))
    ref = np.degrees(se2.wrap_angle(np.diff(ref_poses[idx, 2])))
    excess = mine - ref
    cum = np.concatenate([[0.0], np.cumsum(excess)])
    print("    cumulative turn difference every 50 scans:", " ".join(f"{c:+.0f}" for c in cum[::50]))

    def get(name, i):
        v = np.asarray(series.get(name, []), dtype=float)
        return v[i] if i < v.shape[0] else np.nan

    for i in np.flatnonzero(np.abs(excess) > threshold_deg) + 1:
        print(f"    scan {i}: crsm turns {mine[i - 1]:+.1f} deg, hector {ref[i - 1]:+.1f}; rays {get('rays', i):.0f}, "
              f"on unknown {get('rays_on_unknown', i):.0f}, turn_z {get('turn_z', i):.2f}, "
              f"turn_rejected {get('turn_rejected', i):.0f}")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    ap.add_argument("--logs", nargs="+", default=list(LOGS))
    ap.add_argument("--set", nargs="*", default=[])
    ap.add_argument("--cache", default="/tmp/crsm_mines_cache")
    ap.add_argument("--departures", type=float, default=None, help="list scans whose turn differs by more (deg)")
    ap.add_argument("--save", default=None, help="folder for crsm's trajectories (npz per log and seed)")
    args = ap.parse_args()
    settings = {k: _value(v) for k, v in (s.split("=", 1) for s in args.set)}
    cache = Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    datasets = ROOT / ".." / "shared" / "datasets"
    for log in args.logs:
        frames = list(open_recording(datasets / LOGS[log]).frames())
        hfile = cache / f"hector-{log}.npz"
        if hfile.exists():
            h = np.load(hfile)
            ht, hp = h["t"], h["p"]
        else:
            ht, hp, _ = run(frames, "hector", 0, {})
            np.savez(hfile, t=ht, p=hp)
        hc = scan_consistency(frames, ht, hp)["mean"]
        print(f"{log} hector consistency {hc:.3f}", flush=True)
        for seed in args.seeds:
            t, p, slam = run(frames, "crsm", seed, settings)
            c = scan_consistency(frames, t, p)["mean"]
            h = heading_agreement(t, p, ht, hp)
            cpu = np.asarray(slam.diagnostics.series.get("cpu_s", [np.nan]), dtype=float)
            rej = slam.diagnostics.counters.get("turns_rejected", 0)
            print(f"{log} seed {seed} consistency {c:.3f} ({c / hc:.3f} of hector) heading_p95_deg "
                  f"{h['heading_p95_deg']:.1f} rel50_p95_deg {h['relative_p95_deg']:.1f} "
                  f"cpu_median_ms {1e3 * np.nanmedian(cpu):.2f} turns_rejected {rej}", flush=True)
            if args.departures is not None:
                departures(t, p, ht, hp, slam.diagnostics.series, args.departures)
            if args.save:
                Path(args.save).mkdir(parents=True, exist_ok=True)
                np.savez(Path(args.save) / f"crsm-{log}-{seed}.npz", t=t, p=p)


if __name__ == "__main__":
    main()
