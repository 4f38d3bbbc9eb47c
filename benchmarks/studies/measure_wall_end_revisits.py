#!/usr/bin/env python3
"""karto with wall-end landmarks on the simulated URG-04LX recordings: ATE and map error.

    .venv/bin/python benchmarks/studies/measure_wall_end_revisits.py [--world office] [--laser urg-04lx] \
        [--seeds 0,1,2,3,4,5] [key=value ...]

The recordings of `karto-sim-lasers` (office 120 s, corridor-loop one pass; written once under
--cache, as benchmarks/studies/measure_gmapping_proposal.py writes them), run in-process with the settings
given and judged as `slam2d evaluate --truth`. Per seed: ATE (m), map error (mean truth-to-map,
m), landmarks, loop closures (and how many within 0.2 m and 1 deg of the truth). (Named for the
landmark merges it also judged, `wall_end_revisits`, removed since: see
docs/methods/what-was-tried.md.)
With ``--diagnose``, also: the mean chi-square at the *true* node poses of the landmark sightings
(2 expected for a right covariance) and of the pose-graph edges (3 expected; also per kind:
sequential, link = running-scan and near-chain links, loop; edge counts in brackets), and the mean
position error (after the evaluation's alignment) in each twelfth of the trajectory. Also the CPU seconds of the run,
and with ``wall_refinement=true`` the refinement's walls, wall-end landmarks, poses and CPU seconds.
"""

from __future__ import annotations

import argparse
import sys
import json
import time
from pathlib import Path

import numpy as np

from slam2d.eval.evaluate import evaluate_run, load_run, load_truth
from slam2d.graph.evaluation import loop_closure_precision
from slam2d.methods.runner import build_method, run_method

sys.path.insert(0, str(Path(__file__).parent))
from measure_gmapping_proposal import cached_recording  # noqa: E402


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
        ates.append(ate)
        maps.append(err)
        refine = diag["summary"].get("wall_refinement")
        refined = (f", wall_refinement {refine['walls']:.0f} walls, {refine['points']:.0f} wall ends over "
                   f"{refine['poses']:.0f} poses, cpu {refine['cpu_s']:.1f} s" if refine else "")
        print(f"{a.world} {a.laser} seed {seed}: ATE {ate:.3f} m, map {err:.3f} m, "
              f"{counts.get('wall_end_landmarks', 0)} landmarks, "
              f"{counts.get('loop_closures', 0)} loop closures ({prec['correct']} within 0.2 m and 1 deg of the truth), "
              f"cpu {cpu:.0f} s{refined}", flush=True)
        if a.diagnose:
            print("  " + diagnose(fe, truth, run_dir), flush=True)
    print(f"mean ATE {sum(ates) / len(ates):.3f} m, max {max(ates):.3f}; mean map {sum(maps) / len(maps):.3f} m; "
          f"settings {' '.join(a.settings) or '(wall_end_landmarks=true)'}")


if __name__ == "__main__":
    main()
