#!/usr/bin/env python3
"""What a laser lets a scan matcher observe: the table in docs/methods/gmapping.md ("office").

    .venv/bin/slam2d simulate office --duration 120 --seed 0 --laser urg-04lx --out SIM
    .venv/bin/python benchmarks/studies/measure_gmapping.py SIM [SIM ...]

For every scan of a recording the surface normal at each endpoint is taken from its two
neighbours (when both are close enough to lie on the same surface) and the scan's translation
information is ``sum(n n^T)`` over its endpoints. Where every wall the laser reaches is parallel
(a corridor whose ends are out of range) the smallest eigenvalue is near zero: the scan does
not say where along the corridor the robot is, and a scan matcher's error there is the
odometry's. Printed per recording: the share of scans whose smallest eigenvalue is under 5 % and
10 % of the largest, and the median ratio.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from slam2d.io import open_recording


def normal_ratio(ranges: np.ndarray, angles: np.ndarray, valid: np.ndarray) -> float:
    """Smallest over largest eigenvalue of the scan's sum of endpoint normals' outer products (NaN: too few)."""
    x, y = ranges * np.cos(angles), ranges * np.sin(angles)
    tx, ty = x[2:] - x[:-2], y[2:] - y[:-2]
    # neighbours on one surface: closer than a few beam spacings at that range
    near = np.hypot(tx, ty) < 0.1 + 6.0 * ranges[1:-1] * abs(angles[1] - angles[0])
    good = valid[2:] & valid[:-2] & valid[1:-1] & near
    if good.sum() < 10:
        return float("nan")
    n = np.stack([-ty[good], tx[good]], axis=1)
    n /= np.linalg.norm(n, axis=1)[:, None]
    w = np.linalg.eigvalsh(n.T @ n)
    return float(w[0] / w[1])


def main(folders: list[str]) -> None:
    print("| recording | scans | ratio < 5 % | ratio < 10 % | median ratio |")
    print("|---|---|---|---|---|")
    for folder in folders:
        ratios = []
        for frame in open_recording(Path(folder) / "recording.log.gz").frames():
            s = frame.scan
            with np.errstate(invalid="ignore"):
                valid = np.isfinite(s.ranges) & (s.ranges > s.range_min) & (s.ranges < s.range_max)
            ratios.append(normal_ratio(np.nan_to_num(s.ranges), s.angles, valid))
        r = np.nan_to_num(np.array(ratios), nan=0.0)  # too few surfaces: nothing constrained
        print(f"| {Path(folder).name} | {r.size} | {np.mean(r < 0.05):.2f} | {np.mean(r < 0.10):.2f} | "
              f"{np.median(r):.3f} |")


if __name__ == "__main__":
    main(sys.argv[1:])
