#!/usr/bin/env python3
"""How well gmapping's score places a scan along the robot's heading on a perfect map (docs/methods/what-was-tried.md, "gmapping, where the URG's error accrues").

    .venv/bin/python benchmarks/studies/measure_gmapping_along_track.py office urg-04lx 0
    .venv/bin/python benchmarks/studies/measure_gmapping_along_track.py office rplidar-a1 0

Simulates WORLD (120 s, or the world's own path for corridor-loop) with LASER and SEED, and
registers the scans at their *true* poses into one hit-point map (gmapping's cells), one scan per
metre or 0.5 rad as the filter's updates do. Before each is added, the scan's score (gmapping's,
default ``sigma`` and ``kernelSize``) is evaluated at the true pose moved -0.2..0.2 m along the
robot's heading in 1 cm steps. Printed: how far from the truth the score's maximum is, and the
share of scans whose score is *flat* along the heading (it drops by less than 1 at +-5 cm): there
the scan does not say where along the corridor the robot is, and where the maximum lies is the
cells' ripple, not the world.
"""

from __future__ import annotations

import sys

import numpy as np

from slam2d.core import se2
from slam2d.grids.tiled import TiledMaps
from slam2d.matching.hill_climb import BeamSet, score_particles
from slam2d.sim.simulate import SimulationParams, simulate


def main() -> None:
    world, laser, seed = sys.argv[1], sys.argv[2], int(sys.argv[3])
    sim = simulate(world, SimulationParams(duration=None if world == "corridor-loop" else 120.0, seed=seed,
                                           laser=laser))
    frames, truth = sim.frames(), sim.scan_truth
    offsets = np.round(np.arange(-0.2, 0.2001, 0.01), 2)
    n, zero, five = len(offsets), len(offsets) // 2, 5
    maps = TiledMaps(n, 0.05, (truth[0, 0] - 100, truth[0, 1] - 100, truth[0, 0] + 100, truth[0, 1] + 100))
    max_range = frames[0].scan.range_max - 0.01  # gmapping's maxRange default

    def register(i: int) -> None:
        s = frames[i].scan
        maps.register(np.zeros(1, np.int64), se2.compose(truth[i:i + 1], s.mount), s.ranges[None], s.angles,
                      max_range=max_range, usable_range=max_range, generate_map=False)

    register(0)
    last, peak, drop = 0, [], []
    for i in range(1, len(frames)):
        d = se2.relative(truth[last], truth[i])
        if np.hypot(d[0], d[1]) < 1.0 and abs(d[2]) < 0.5:
            continue
        maps.resample(np.zeros(n, np.int64))  # every "particle" shares the one map
        s = frames[i].scan
        with np.errstate(invalid="ignore"):
            use = (s.ranges > 0) & (s.ranges <= max_range)
        beams = BeamSet(s.ranges, s.angles, use, np.full(s.num_beams, 0.05), np.full(s.num_beams, 0.075))
        poses = np.repeat(truth[i:i + 1], n, axis=0)
        poses[:, 0] += np.cos(truth[i, 2]) * offsets
        poses[:, 1] += np.sin(truth[i, 2]) * offsets
        score, like, matched = np.empty(n), np.empty(n), np.empty(n, np.int64)
        score_particles(maps.pool, maps.occ, maps.table, maps.origin[0], maps.origin[1], maps.resolution, 1,
                        poses, np.asarray(s.mount, dtype=np.float64), beams.ex, beams.ey,
                        beams.div_score, beams.div_like, score, like, matched)
        peak.append(abs(offsets[int(np.argmax(score))]))
        drop.append(score[zero] - 0.5 * (score[zero - five] + score[zero + five]))
        register(i)
        last = i
    peak, drop = np.array(peak), np.array(drop)
    flat = drop < 1.0
    print(f"{world} {laser} seed {seed}: {len(peak)} update scans; score maximum {peak.mean() * 100:.1f} cm from the "
          f"truth on average; flat along the heading: {flat.mean():.0%} of the scans (maximum "
          f"{peak[flat].mean() * 100:.1f} cm off there, {peak[~flat].mean() * 100:.1f} cm elsewhere)")


if __name__ == "__main__":
    main()
