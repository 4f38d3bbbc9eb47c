#!/usr/bin/env python3
"""karto with wall-end landmarks on the simulated URG-04LX recordings: ATE, map error and the merges' truth.

    .venv/bin/python benchmarks/studies/measure_wall_end_revisits.py [--world office] [--laser urg-04lx] \
        [--seeds 0,1,2,3,4,5] [key=value ...]

The recordings of `karto-sim-lasers` (office 120 s, corridor-loop one pass; written once under
--cache, as benchmarks/studies/measure_gmapping_proposal.py writes them), run in-process with the settings
given and judged as `slam2d evaluate --truth`. Per seed: ATE (m), map error (mean truth-to-map,
m), landmarks, loop closures (and how many within 0.2 m and 1 deg of the truth), merges of a
tracked landmark into an older one (`wall_end_revisits`) and how many of those were wrong: the
sightings of the two merged parts, placed at the *true* poses of their nodes, more than 0.05 m
apart (their means; the largest such gap is printed too); missed: pairs of landmarks left in the
graph whose true means are within 0.1 m and never seen from one node.
With ``--diagnose``, also: the mean chi-square at the *true* node poses of the landmark sightings
(2 expected for a right covariance) and of the pose-graph edges (3 expected; also per kind:
sequential, link = running-scan and near-chain links, loop; edge counts in brackets), and the mean
position error (after the evaluation's alignment) in each twelfth of the trajectory, and per merged
pair its estimated distance, Mahalanobis distance and the largest sigma of the difference. Also the CPU seconds of the run,
and with ``wall_refinement=true`` the refinement's walls, wall-end landmarks, poses and CPU seconds.
"""

from __future__ import annotations

import argparse
import sys
import json
import time
from pathlib import Path

import numpy as np

from slam2d.core import se2
from slam2d.eval.evaluate import evaluate_run, load_run, load_truth
from slam2d.graph.evaluation import loop_closure_precision
from slam2d.methods.runner import build_method, run_method

sys.path.insert(0, str(Path(__file__).parent))
from measure_gmapping_proposal import cached_recording  # noqa: E402


def merge_truth(wall_ends, node_times, truth, minimum_sightings: int = 3) -> tuple[int, int, int, float]:
    """(merges, wrong merges, missed, largest gap in m) of the tracker, judged at the true poses of the nodes.

    Missed: pairs of landmarks in the graph at the end (seen from ``minimum_sightings`` nodes),
    never seen from one node, whose sightings' true means are within 0.1 m: one wall end twice.
    """
    node, lm, origin, z, _ = wall_ends.sightings()
    idx = np.searchsorted(truth.times, np.asarray(node_times)[node])
    idx = np.clip(idx, 0, len(truth.times) - 1)
    world = se2.transform_points(truth.poses[idx], z[:, None, :])[:, 0, :]
    merges = wrong = 0
    worst = 0.0
    for target in np.unique(lm[origin != lm]):  # landmarks that absorbed others (a few per run)
        sel = lm == target
        parts = np.unique(origin[sel])
        means = np.array([world[sel & (origin == o)].mean(axis=0) for o in parts])
        merges += parts.size - 1
        gaps = np.hypot(*(means[1:] - means[0]).T)
        wrong += int((gaps > 0.05).sum())
        worst = max(worst, float(gaps.max()))
    alive_lm, first = np.unique(lm, return_index=True)
    mean = np.array([world[lm == t].mean(axis=0) for t in alive_lm])
    nodes = [set(node[lm == t].tolist()) for t in alive_lm]
    big = np.array([len(s) >= minimum_sightings for s in nodes])
    d = np.hypot(*(mean[:, None, :] - mean[None, :, :]).transpose(2, 0, 1))
    ia, ib = np.nonzero(np.triu(d < 0.1, 1) & big[:, None] & big[None, :])
    missed = sum(1 for x, y in zip(ia, ib) if not (nodes[x] & nodes[y]))
    return merges, wrong, missed, worst


def diagnose(fe, truth, run_dir: Path) -> str:
    """Chi-squares at the true node poses (landmark sightings, pose edges) and the error per twelfth."""
    from slam2d.backends.graph import edge_errors
    from slam2d.backends.landmarks import landmark_positions, point_errors
    from slam2d.io.tum import read_tum

    idx = np.clip(np.searchsorted(truth.times, fe.node_times()), 0, len(truth.times) - 1)
    tp = truth.poses[idx]
    g = fe.graph
    e = edge_errors(tp, g.edge_i, g.edge_j, g.measurements)
    chi = np.einsum("ki,kij,kj->k", e, g.information, e)
    # Edge kinds: loop closures as the front end logged them, sequential (node to the next), the rest
    # links (running-scan and near-chain LinkChainToScan edges).
    ei, ej = np.asarray(g.edge_i), np.asarray(g.edge_j)
    loops = {(c.frm, c.to) for c in fe.loop_closures}
    is_loop = np.array([(int(a), int(b)) in loops for a, b in zip(ei, ej)], dtype=bool)
    is_seq = (ej == ei + 1) & ~is_loop
    kinds = " ".join(f"{name} {float(chi[m].mean()) if m.any() else float('nan'):.2f} ({int(m.sum())})"
                     for name, m in (("sequential", is_seq), ("link", ~is_seq & ~is_loop), ("loop", is_loop)))
    out = f"pose edges at the truth: mean chi2 {float(chi.mean()):.2f} [{kinds}]"
    if fe.wall_ends is not None and len(fe.wall_ends.observations()):
        obs = fe.wall_ends.observations()
        pos, _ = landmark_positions(tp, obs, fe.wall_ends.num_landmarks)
        el = point_errors(tp, pos, obs)
        out += f", landmark sightings {float(np.einsum('ki,kij,kj->k', el, obs.information, el).mean()):.2f}"
    # Per twelfth: the run's trajectory against the truth at its times, after a least-squares fit.
    rt, rp = read_tum(run_dir / "trajectory.tum")
    b = truth.poses[np.clip(np.searchsorted(truth.times, rt), 0, len(truth.times) - 1), :2]
    a = rp[:, :2]
    u, _, vt = np.linalg.svd((a - a.mean(0)).T @ (b - b.mean(0)))
    rot = vt.T @ np.diag([1.0, np.sign(np.linalg.det(vt.T @ u.T))]) @ u.T
    err = np.hypot(*((a - a.mean(0)) @ rot.T + b.mean(0) - b).T)
    return out + "; error per twelfth (m): " + " ".join(f"{err[k].mean():.2f}" for k in np.array_split(np.arange(err.size), 12))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--laser", default="urg-04lx")
    ap.add_argument("--world", default="office")
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--cache", default="/tmp/slam2d-proposal")
    ap.add_argument("--diagnose", action="store_true", help="chi-squares at the truth and the error per twelfth")
    ap.add_argument("settings", nargs="*")
    a = ap.parse_args()
    settings = dict(s.split("=", 1) for s in a.settings)
    settings.setdefault("wall_end_landmarks", "true")
    ates, maps = [], []
    for seed in (int(s) for s in a.seeds.split(",")):
        sim_dir = cached_recording(a.cache, a.world, a.laser, seed)
        run_dir = Path(a.cache) / f"run-revisits-{a.world}-{a.laser}-{seed}"
        slam = build_method("karto", settings=settings)
        cpu = time.process_time()
        run_method(slam, sim_dir / "recording.log.gz", run_dir)
        cpu = time.process_time() - cpu
        truth = load_truth(sim_dir)
        e = evaluate_run(load_run(run_dir), truth)
        ate = e["trajectory"]["ate"]["translation_m"]["rmse"]
        err = e["map_truth"]["truth_to_map_m"]["mean"]
        fe = slam.frontend
        diag = json.loads((run_dir / "diagnostics.json").read_text())
        counts = diag["counters"]
        prec = loop_closure_precision(diag["summary"]["loop_closures"], truth.times, truth.poses)
        merges, wrong, missed, worst = (merge_truth(fe.wall_ends, fe.node_times(), truth, fe.params.wall_end_minimum_sightings)
                                 if fe.wall_ends is not None else (0, 0, 0, 0.0))
        ates.append(ate)
        maps.append(err)
        refine = diag["summary"].get("wall_refinement")
        refined = (f", wall_refinement {refine['walls']:.0f} walls, {refine['points']:.0f} wall ends over "
                   f"{refine['poses']:.0f} poses, cpu {refine['cpu_s']:.1f} s" if refine else "")
        print(f"{a.world} {a.laser} seed {seed}: ATE {ate:.3f} m, map {err:.3f} m, "
              f"{counts.get('wall_end_landmarks', 0)} landmarks, {merges} merges ({wrong} wrong, {missed} missed, "
              f"largest true gap {worst:.3f} m), "
              f"{counts.get('loop_closures', 0)} loop closures ({prec['correct']} within 0.2 m and 1 deg of the truth), "
              f"cpu {cpu:.0f} s{refined}", flush=True)
        if a.diagnose:
            print("  " + diagnose(fe, truth, run_dir), flush=True)
            for node, x, y, dist, maha, sigma in (fe.wall_ends.merge_log if fe.wall_ends is not None else []):
                print(f"  merge at node {node}: landmarks {x} and {y} {dist:.3f} m apart, {maha:.2f} sigma, "
                      f"largest sigma {sigma:.3f} m", flush=True)
    print(f"mean ATE {sum(ates) / len(ates):.3f} m, max {max(ates):.3f}; mean map {sum(maps) / len(maps):.3f} m; "
          f"settings {' '.join(a.settings) or '(wall_end_landmarks=true)'}")


if __name__ == "__main__":
    main()
