"""coreslam with and without odometry on the mines logs, judged against hector's trajectory (no truth there).

    .venv/bin/python benchmarks/studies/coreslam_mines_odometry.py [--logs mines-exp1 mines-exp2] [--seeds 0 1 2]
        [--delay 0.15]

Per log: how far the odometry leads the scans (the delay at which the odometry heading's change from scan to
scan is closest to hector's), then one row per configuration and seed: scan_consistency at the trajectory
(poses at each scan's stamp, i.e. its first beam), scan_consistency with the poses moved to the middle of the
sweep (by half the sweep's share of the odometry increment read back by ``--delay``), heading agreement with
hector (95th percentile, degrees) and position agreement (RMSE after alignment, m). The mid-sweep column
checks whether a consistency gap is the de-skew's: scan_consistency rebuilds the map from the *raw* scans, which
fit best where the laser was half-way through its sweep. Used for docs/methods/coreslam.md; about 1 min CPU.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "src"))

from benchmarks.cases import DATA, _odometry_lead  # noqa: E402
from slam2d.core import se2  # noqa: E402
from slam2d.eval import scan_consistency  # noqa: E402
from slam2d.eval.trajectory_metrics import absolute_trajectory_error, associate, heading_agreement  # noqa: E402
from slam2d.io import open_recording  # noqa: E402
from slam2d.io.base import ReadOptions  # noqa: E402
from slam2d.methods.runner import build_method  # noqa: E402


def half_sweep(frames, delay: float) -> np.ndarray:
    """``(N, 3)``: per scan, the motion from its first beam to the middle of its sweep (odometry read back)."""
    stamps = np.array([f.timestamp for f in frames])
    odom = np.array([f.odometry for f in frames])
    back = np.stack([np.interp(stamps - delay, stamps, odom[:, 0]), np.interp(stamps - delay, stamps, odom[:, 1]),
                     np.interp(stamps - delay, stamps, np.unwrap(odom[:, 2]))], axis=-1)
    step = np.vstack([np.zeros(3), se2.relative(back[:-1], back[1:])])
    scan = frames[0].scan
    share = min(1.0, scan.num_beams * scan.angle_increment / (2.0 * math.pi))
    return se2.interpolate(np.zeros(3), step, 0.5 * share)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--logs", nargs="+", default=["mines-exp1", "mines-exp2"])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--delay", type=float, default=0.15)
    args = ap.parse_args()
    configs = {
        "without odometry": {},
        "use_odometry": {"use_odometry": True},
        f"use_odometry odometry_delay={args.delay:g}": {"use_odometry": True, "odometry_delay": args.delay},
        f"use_odometry odometry_delay={args.delay:g} deskew=none":
            {"use_odometry": True, "odometry_delay": args.delay, "deskew": "none"},
    }
    for ds in args.logs:
        frames = list(open_recording(DATA / ds / f"{ds}.clf.gz", ReadOptions(range_min=0.02)).frames())
        hector = build_method("hector", seed=0)
        hector.run(frames)
        ref_times, ref_poses = hector.trajectory()
        lead, rms_lead, rms_0 = _odometry_lead(frames, ref_times, ref_poses)
        print(f"{ds}: hector consistency {scan_consistency(frames, ref_times, ref_poses)['mean']:.3f}; odometry leads "
              f"by {lead:.2f} s ({rms_lead:.2f} deg rms per scan against hector, {rms_0:.2f} at the stamp)")
        half = half_sweep(frames, args.delay)
        for label, settings in configs.items():
            for seed in args.seeds:
                slam = build_method("coreslam", settings=settings, seed=seed)
                slam.run(frames)
                times, poses = slam.trajectory()
                stamp = scan_consistency(frames, times, poses)["mean"]
                mid = scan_consistency(frames, times, se2.compose(poses, half))["mean"]
                heading = heading_agreement(times, poses, ref_times, ref_poses)["heading_p95_deg"]
                ate = absolute_trajectory_error(associate(times, poses, ref_times, ref_poses))["translation_m"]["rmse"]
                print(f"  {label:45s} seed {seed}: consistency {stamp:.3f} (mid-sweep {mid:.3f}), "
                      f"heading p95 {heading:.1f} deg, position {ate:.2f} m", flush=True)


if __name__ == "__main__":
    main()
