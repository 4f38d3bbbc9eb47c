#!/usr/bin/env python3
"""How much a scan says along a corridor, and how much of it gmapping's score and `flat_ratio` keep.

    .venv/bin/python benchmarks/studies/measure_gmapping_wall_ends.py [--world office] [--laser urg-04lx] [--seeds 0,1,2] \
        [--sigma 0.03]

docs/methods/what-was-tried.md, "gmapping, the wall ends' information". Simulates WORLD (120 s; corridor-loop: its own
path) and registers the scans at their *true* poses into one gmapping map (5 cm cells, as the filter's
updates: one scan per metre or 0.5 rad). At every such update scan, before it is added, along the
robot's true heading:

* ``fisher``: the Cramér-Rao information of the scan about its position along the heading
  (src/slam2d/eval/accuracy_bound.py, the laser's true noise; with and without the wall-end bearing
  terms), ``1/sqrt``: the best standard deviation one scan allows;
* ``score``: gmapping's score curvature by central differences of one cell (what ``flat_ratio``
  judges), its smaller / larger eigenvalue, and whether ``flat_ratio=0.1`` holds the climb there;
* ``ends``: the curvature of the beams' one-cell-smoothed point distances
  (:func:`slam2d.matching.hill_climb.along_terms`, end-point sigma ``--sigma``, window ``--kernel``
  cells, beams within the last update's reach less 3 cells): the information the
  particle's map gives along the heading once the walls' cell ripple has cancelled;
* ``recovered``: from the true pose moved -10, -5, 0, +5, +10 cm along the heading, where the Newton
  step (:func:`_wall_end_step`, odometry prior of 0.1 m, a metre at ``srr=0.1``) puts it: the rms
  error left (against the starts' rms) and the signed mean per start, once with the end points'
  distances above, once with the scan's explicit wall ends matched to the map's
  (:func:`~slam2d.matching.hill_climb.wall_ends`, :func:`~slam2d.matching.hill_climb.wall_end_terms`,
  gmapping's ``flat_sigma``), with their count per scan and the share of scans that have one.

Corridor-like scans are those whose endpoint normals' ratio (benchmarks/studies/measure_gmapping.py) is under 0.10.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from slam2d.core import se2
from slam2d.eval.accuracy_bound import laser_information, setup_from_simulation
from slam2d.grids.tiled import TiledMaps
from slam2d.matching.hill_climb import BeamSet, _wall_end_step, along_terms, score_particles, wall_ends
from slam2d.sim.simulate import SimulationParams, simulate

sys.path.insert(0, str(Path(__file__).parent))
from measure_gmapping import normal_ratio  # noqa: E402

RES = 0.05
OFFSETS = np.array([-0.10, -0.05, 0.0, 0.05, 0.10])


def _score_curvature(maps, s, beams, pose):
    """gmapping's score at the pose and one cell off in x, y and the diagonals: its 2 x 2 negative curvature."""
    d = np.array([[0, 0], [1, 0], [-1, 0], [0, 1], [0, -1], [1, 1], [-1, -1], [1, -1], [-1, 1]]) * RES
    poses = np.repeat(pose[None], 9, axis=0)
    poses[:, :2] += d
    score, like, matched = np.empty(9), np.empty(9), np.empty(9, np.int64)
    score_particles(maps.pool, maps.occ, maps.table, maps.origin[0], maps.origin[1], RES, 1, poses,
                    np.asarray(s.mount, dtype=np.float64), beams.ex, beams.ey, beams.div_score,
                    beams.div_like, score, like, matched)
    s0, sxp, sxm, syp, sym, spp, smm, spm, smp = score
    a = -(sxp + sxm - 2 * s0) / RES**2
    c = -(syp + sym - 2 * s0) / RES**2
    b = -(spp + smm - spm - smp) / (4 * RES**2)
    return np.array([[a, b], [b, c]])


def measure(world: str, laser: str, seed: int, sigma: float, kernel: int) -> dict[str, np.ndarray]:
    sim = simulate(world, SimulationParams(duration=None if world == "corridor-loop" else 120.0, seed=seed,
                                           laser=laser))
    setup = setup_from_simulation(sim)
    with_ends = laser_information(setup, edges=True).pose
    without = laser_information(setup, edges=False).pose
    frames, truth = sim.frames(), sim.scan_truth
    maps = TiledMaps(9, RES, (truth[0, 0] - 100, truth[0, 1] - 100, truth[0, 0] + 100, truth[0, 1] + 100))
    max_range = frames[0].scan.range_max - 0.01

    def register(i: int) -> None:
        s = frames[i].scan
        maps.register(np.zeros(1, np.int64), se2.compose(truth[i:i + 1], s.mount), s.ranges[None], s.angles,
                      max_range=max_range, usable_range=max_range, generate_map=False)

    register(0)
    last = 0
    rows = []
    for i in range(1, len(frames)):
        d = se2.relative(truth[last], truth[i])
        if np.hypot(d[0], d[1]) < 1.0 and abs(d[2]) < 0.5:
            continue
        maps.resample(np.zeros(9, np.int64))  # the score's nine poses each look at "their" map: all the same
        s = frames[i].scan
        with np.errstate(invalid="ignore"):
            use = (s.ranges > 0) & (s.ranges <= max_range)
            valid = np.isfinite(s.ranges) & (s.ranges > s.range_min) & (s.ranges < s.range_max)
        beams = BeamSet(s.ranges, s.angles, use, np.full(s.num_beams, 0.05), np.full(s.num_beams, 0.075))
        th = truth[i, 2]
        f = np.array([np.cos(th), np.sin(th)])
        curv = _score_curvature(maps, s, beams, truth[i])
        ev = np.linalg.eigvalsh(curv)
        mount = np.asarray(s.mount, dtype=np.float64)
        end_w = np.full(len(beams), 0.5 / sigma**2)
        args = (maps.pool, maps.occ, maps.table, 0, maps.origin[0], maps.origin[1], RES, kernel)
        lp = se2.compose(truth[last], mount)
        reach = np.array([lp[0], lp[1], max_range - (2 * 1 + 1) * RES])  # as gmapping's flat_sigma (kernelSize 1)
        _, ends, used = along_terms(*args, truth[i, 0], truth[i, 1], th, f[0], f[1], RES, mount, beams.ex, beams.ey,
                                    end_w, reach)
        features = wall_ends(s.ranges, s.angles, use, max_range)
        left_ends = []
        for e in OFFSETS:
            x, y = truth[i, 0] + e * f[0], truth[i, 1] + e * f[1]
            off = _wall_end_step(*args, x, y, th, f[0], f[1], RES, mount, beams.ex, beams.ey, end_w, reach, 100.0,
                                 4, features, 1.0 / sigma**2)
            left_ends.append(e + off)
        left = []
        for e in OFFSETS:
            x, y = truth[i, 0] + e * f[0], truth[i, 1] + e * f[1]
            off = _wall_end_step(*args, x, y, th, f[0], f[1], RES, mount, beams.ex, beams.ey, end_w, reach, 100.0,
                                 4, np.zeros((0, 5)), 0.0)
            left.append(e + off)
        rows.append((normal_ratio(np.nan_to_num(s.ranges), s.angles, valid), f @ with_ends[i, :2, :2] @ f,
                     f @ without[i, :2, :2] @ f, f @ curv @ f, ev[0] / ev[1] if ev[1] > 0 else 0.0, ends, used,
                     len(features), *left, *left_ends))
        register(i)
        last = i
    r = np.array(rows)
    return {"ratio": np.nan_to_num(r[:, 0]), "fisher": r[:, 1], "fisher_no_ends": r[:, 2], "score": r[:, 3],
            "eig_ratio": r[:, 4], "ends": r[:, 5], "used": r[:, 6], "n_ends": r[:, 7],
            "left": r[:, 8:8 + OFFSETS.size], "left_ends": r[:, 8 + OFFSETS.size:]}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--world", default="office")
    ap.add_argument("--laser", default="urg-04lx")
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--sigma", type=float, default=0.03, help="end-point standard deviation of the wall-end term, m")
    ap.add_argument("--kernel", type=int, default=3, help="the wall-end term's window (cells; gmapping: kernelSize + 2)")
    a = ap.parse_args()
    print("| seed | scans | corridor-like | Fisher along (1/m^2), median: with wall ends / without | 1/sqrt | "
          "score curvature along, median | held by flat_ratio=0.1 | wall-end term along (1/m^2), median | "
          "error left from +-5, +-10 cm (rms, m) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for seed in (int(s) for s in a.seeds.split(",")):
        m = measure(a.world, a.laser, seed, a.sigma, a.kernel)
        c = m["ratio"] < 0.10
        med = lambda v: float(np.median(v[c]))  # noqa: E731
        print(f"| {seed} | {c.size} | {c.sum()} | {med(m['fisher']):.0f} / {med(m['fisher_no_ends']):.0f} | "
              f"{1 / np.sqrt(med(m['fisher'])):.3f} m | {med(m['score']):.0f} | "
              f"{(m['eig_ratio'][c] < 0.1).mean():.0%} | {med(m['ends']):.0f} (beams {med(m['used']):.0f}) | "
              f"{np.sqrt(np.mean(m['left'][c] ** 2)):.3f} (starts {np.sqrt(np.mean(OFFSETS ** 2)):.3f}); "
              f"not corridor-like {np.sqrt(np.mean(m['left'][~c] ** 2)):.3f} |", flush=True)
        print("  end points' distances: signed mean left per start offset (corridor-like):",
              np.round(m["left"][c].mean(axis=0), 3))
        print(f"  explicit wall ends ({med(m['n_ends']):.0f} per scan, median): rms left "
              f"{np.sqrt(np.mean(m['left_ends'][c] ** 2)):.3f}, not corridor-like "
              f"{np.sqrt(np.mean(m['left_ends'][~c] ** 2)):.3f}; signed mean per start offset",
              np.round(m["left_ends"][c].mean(axis=0), 3), "rms",
              np.round(np.sqrt((m["left_ends"][c] ** 2).mean(axis=0)), 3),
              "; scans with a wall end used:", f"{(m['n_ends'][c] > 0).mean():.0%}", flush=True)


if __name__ == "__main__":
    main()
