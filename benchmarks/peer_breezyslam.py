#!/usr/bin/env python3
"""The original CoreSLAM (BreezySLAM's ``RMHC_SLAM``) with odometry on the shared SICK logs: the peer of ``coreslam``.

    git clone https://github.com/simondlevy/BreezySLAM /tmp/BreezySLAM
    (cd /tmp/BreezySLAM/python && ../../path/to/.venv/bin/python setup.py build_ext --inplace)
    .venv/bin/python benchmarks/peer_breezyslam.py --breezyslam /tmp/BreezySLAM/python [--logs aces,csail]

BreezySLAM is not on PyPI and is not a dependency: it runs here only to show how
the original behaves on the logs of the "defaults on every real log" table. It
gets each log's scans in millimetres (no return as 0: free space up to the
range limit, BreezySLAM's convention), trimmed to be symmetric about straight
ahead (its laser model assumes that), and the odometry as ``pose_change``
(signed step length, turn in degrees, seconds). Defaults otherwise:
``sigma_xy_mm`` 100, ``sigma_theta_degrees`` 20, ``max_search_iter`` 1000,
``map_quality`` 50, ``hole_width_mm`` 600; a 160 m map of 5 cm pixels with the
start at its centre. Seeds 1-5: ``RMHC_SLAM`` replaces seed 0 by the clock.
``--algo det`` (``Deterministic_SLAM``: the odometry only) checks the
conventions: it must reproduce the odometry's ATE. ATE as in
``benchmarks/defaults.py``, against ``reference.tum`` after SE(2) alignment.
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
SHARED = ROOT.parent / "shared" / "datasets"
LOGS = ("intel", "aces", "fr079", "fr101", "csail")
MAP_SIZE_METERS = 160.0  # the start at the centre: +-80 m (the logs reach 44 m from their start)
MAP_SIZE_PIXELS = 3200  # 5 cm
SCAN_RATE_HZ = 75.0  # a SICK's mirror: BreezySLAM's de-skew is then negligible


def _symmetric_beams(scan) -> slice:
    """The beams of ``scan`` that lie symmetric about 0 rad (BreezySLAM centres its field of view there)."""
    lo, hi = 0, scan.num_beams - 1
    a, inc = scan.angle_min, scan.angle_increment
    while hi > lo and abs(2 * a + (lo + hi) * inc) > inc / 4:
        if -(a + lo * inc) > a + hi * inc:
            lo += 1
        else:
            hi -= 1
    return slice(lo, hi + 1)


def run_peer(frames, seed: int, algo: str = "rmhc") -> np.ndarray:
    from breezyslam.algorithms import Deterministic_SLAM, RMHC_SLAM
    from breezyslam.sensors import Laser

    from slam2d.core import se2

    first = frames[0].scan
    beams = _symmetric_beams(first)
    size = beams.stop - beams.start
    laser = Laser(size, SCAN_RATE_HZ, math.degrees(first.angle_increment * (size - 1)), first.range_max * 1000.0, 0, 0)
    slam = (RMHC_SLAM(laser, MAP_SIZE_PIXELS, MAP_SIZE_METERS, random_seed=seed) if algo == "rmhc"
            else Deterministic_SLAM(laser, MAP_SIZE_PIXELS, MAP_SIZE_METERS))
    x0, y0, t0 = slam.getpos()
    out = np.zeros((len(frames), 3))
    previous = None
    for k, frame in enumerate(frames):
        mm = np.nan_to_num(frame.scan.ranges[beams] * 1000.0, nan=0.0)
        mm[mm >= first.range_max * 1000.0] = 0.0  # no return
        odom = np.asarray(frame.odometry, dtype=float)
        change = (0.0, 0.0, 0.0)
        if previous is not None:
            (po, pt) = previous
            turn = float(se2.wrap_angle(odom[2] - po[2]))
            mid = po[2] + turn / 2
            forward = (odom[0] - po[0]) * math.cos(mid) + (odom[1] - po[1]) * math.sin(mid)
            step = math.copysign(math.hypot(odom[0] - po[0], odom[1] - po[1]), forward)
            change = (step * 1000.0, math.degrees(turn), max(frame.timestamp - pt, 0.0))
        previous = (odom, frame.timestamp)
        slam.update([int(v) for v in mm], pose_change=change)
        x, y, t = slam.getpos()
        relative = np.array([(x - x0) / 1000.0, (y - y0) / 1000.0, math.radians(t - t0)])
        out[k] = se2.compose(np.asarray(frames[0].odometry, dtype=float), relative)
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--breezyslam", type=Path, required=True,
                        help="BreezySLAM's python/ folder, its extension built in place")
    parser.add_argument("--logs", default=",".join(LOGS))
    parser.add_argument("--seeds", default="1,2,3,4,5")
    parser.add_argument("--algo", choices=("rmhc", "det"), default="rmhc")
    args = parser.parse_args()
    sys.path.insert(0, str(args.breezyslam))
    sys.path.insert(0, str(ROOT / "src"))
    from slam2d.eval.trajectory_metrics import absolute_trajectory_error, associate
    from slam2d.io import open_recording
    from slam2d.io.tum import read_tum

    seeds = [int(s) for s in args.seeds.split(",")] if args.algo == "rmhc" else [0]
    rows = []
    for log in args.logs.split(","):
        frames = [f for f in open_recording(SHARED / log / f"{log}.clf.gz").frames() if f.odometry is not None]
        times = np.array([f.timestamp for f in frames])
        rt, rp = read_tum(SHARED / log / "reference.tum")

        def ate(poses):
            return absolute_trajectory_error(associate(times, poses, rt, rp))["translation_m"]["rmse"]

        odometry = ate(np.array([f.odometry for f in frames], dtype=float))
        ates = []
        for seed in seeds:
            ates.append(ate(run_peer(frames, seed, args.algo)))
            print(f"{log} seed {seed}: ATE {ates[-1]:.3f} m (odometry alone {odometry:.3f} m)", flush=True)
        rows.append(f"| {log} | {statistics.median(ates):.3f} / {max(ates):.3f} | {odometry:.3f} |")
    print(f"| log | BreezySLAM {args.algo} median / worst, seeds {args.seeds} | odometry alone |\n|---|---|---|")
    print("\n".join(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
