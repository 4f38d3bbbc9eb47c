#!/usr/bin/env python3
"""Where and why gmapping's scan matches fail or slide with a short-range laser (docs/methods/what-was-tried.md, "gmapping, match failures and the slide").

    .venv/bin/python benchmarks/studies/measure_gmapping_failures.py [--laser urg-04lx] [--world office] [--seeds 0] \
        [key=value ...]

Runs gmapping in-process on the simulated recording (written once under --cache) with the settings
given and, at every filter update, records for every particle: whether its match failed (score not
above ``minimumScore``), the scan's translation constraint (``normal_ratio`` of
benchmarks/studies/measure_gmapping.py: smallest over largest eigenvalue of the endpoints' normal outer products,
< 0.10 "corridor-like"), and the error of the climb's correction along and across the true heading
(how far the climb moved the particle, against how far the truth says it should have moved).
Prints the failures by place (the scan's constraint ratio, the number of valid beams, the particle's
distance from the best particle) and the climb's along-track error in degenerate and
well-constrained scans.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

import slam2d.methods.gmapping as gm
from slam2d.core import se2
from slam2d.eval.evaluate import evaluate_run, load_run, load_truth
from slam2d.methods.runner import build_method, run_method
from slam2d.sim.simulate import SimulationParams, simulate, write_outputs

sys.path.insert(0, str(Path(__file__).parent))
from measure_gmapping import normal_ratio  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--laser", default="urg-04lx")
    ap.add_argument("--world", default="office")
    ap.add_argument("--seeds", default="0")
    ap.add_argument("--cache", default="/tmp/slam2d-failures")
    ap.add_argument("settings", nargs="*")
    a = ap.parse_args()
    settings = dict(s.split("=", 1) for s in a.settings)
    duration = None if a.world == "corridor-loop" else 120.0
    original = gm.match_particles
    original_hold = gm.hold_flat_direction
    for seed in (int(s) for s in a.seeds.split(",")):
        sim_dir = Path(a.cache) / f"{a.world}-{a.laser}-{seed}"
        sim = simulate(a.world, SimulationParams(duration=duration, seed=seed, laser=a.laser))
        if not (sim_dir / "recording.log.gz").exists():
            write_outputs(sim, sim_dir)
        truth = sim.scan_truth
        scans = sim.scans
        m = build_method("gmapping", settings=settings, seed=0)
        rows = []
        state: dict = {}

        def spy(*args, m=m, rows=rows, state=state, truth=truth, scans=scans):
            original(*args)
            if args[8] is not m._state:  # the coarse climb's extra call
                return
            i = len(m._frame_times)  # the frame being updated
            start, out_poses, score, ok = args[8], args[-4], args[-3], args[-1]
            s = scans[i]
            with np.errstate(invalid="ignore"):
                valid = np.isfinite(s.ranges) & (s.ranges > s.range_min) & (s.ranges < s.range_max)
            ratio = normal_ratio(np.nan_to_num(s.ranges), s.angles, valid)
            j = state.get("last", 0)
            true_inc = se2.relative(truth[j], truth[i])
            th = truth[i, 2]
            fwd = np.array([np.cos(th), np.sin(th)])
            left = np.array([-np.sin(th), np.cos(th)])
            should = se2.compose(m._update_poses, true_inc)
            need = should[:, :2] - start[:, :2]  # where it should be - start
            head = (should[:, 2] - start[:, 2] + np.pi) % (2 * np.pi) - np.pi
            moved = out_poses[:, :2] - start[:, :2]
            rows.append({"i": i, "ratio": ratio, "valid": int(valid.sum()), "fail": int((~ok).sum()),
                         "score_min": float(score.min()), "score_med": float(np.median(score)),
                         "along_need": need @ fwd, "along_moved": moved @ fwd,
                         "cross_need": need @ left, "cross_moved": moved @ left, "ok": ok.copy(),
                         "head": head, "since": j, "turn": float(true_inc[2]), "dist": float(np.hypot(*true_inc[:2])),
                         "fwd": fwd, "left": left, "flat": 0})
            state["last"] = i

        def spy_hold(*args, m=m, rows=rows):
            original_hold(*args)
            if args[9] is not m._state or not rows:  # a tracked scan's climb
                return
            r = rows[-1]
            moved = args[10][:, :2] - args[9][:, :2]
            r["along_moved"], r["cross_moved"] = moved @ r["fwd"], moved @ r["left"]
            r["flat"] = int((args[-1] > 0).sum())

        gm.match_particles = spy
        gm.hold_flat_direction = spy_hold
        run_dir = Path(a.cache) / f"run-{a.world}-{a.laser}-{seed}"
        run_method(m, sim_dir / "recording.log.gz", run_dir)
        e = evaluate_run(load_run(run_dir), load_truth(sim_dir))
        print(f"ATE {e['trajectory']['ate']['translation_m']['rmse']:.3f} m, "
              f"map {e['map_truth']['truth_to_map_m']['mean']:.3f} m")
        fails = [r for r in rows if r["fail"]]
        print(f"{a.world} {a.laser} seed {seed}: {len(rows)} updates, {sum(r['fail'] for r in rows)} failed matches "
              f"in {len(fails)} updates")
        for r in fails:
            print(f"  scan {r['i']} at true ({truth[r['i'], 0]:.1f}, {truth[r['i'], 1]:.1f}): {r['fail']} particles failed, "
                  f"valid beams {r['valid']}, constraint ratio {r['ratio']:.3f}, score min {r['score_min']:.1f} "
                  f"median {r['score_med']:.1f}; since scan {r['since']}: true move {r['dist']:.2f} m, "
                  f"turn {np.degrees(r['turn']):.0f} deg; heading error at the start (deg): failed "
                  f"{np.degrees(np.sqrt(np.mean(r['head'][~r['ok']] ** 2))):.1f} rms, matched "
                  f"{np.degrees(np.sqrt(np.mean(r['head'][r['ok']] ** 2))) if r['ok'].any() else float('nan'):.1f} rms, "
                  f"position error failed {np.sqrt(np.mean(r['along_need'][~r['ok']] ** 2 + r['cross_need'][~r['ok']] ** 2)):.2f} m")
        ratio = np.nan_to_num(np.array([r["ratio"] for r in rows]), nan=0.0)
        for name, sel in (("degenerate (ratio < 0.10)", ratio < 0.10), ("constrained", ratio >= 0.10)):
            if not sel.any():
                continue
            need = np.concatenate([r["along_need"][r["ok"]] for r, s in zip(rows, sel) if s])
            moved = np.concatenate([r["along_moved"][r["ok"]] for r, s in zip(rows, sel) if s])
            cneed = np.concatenate([r["cross_need"][r["ok"]] for r, s in zip(rows, sel) if s])
            cmoved = np.concatenate([r["cross_moved"][r["ok"]] for r, s in zip(rows, sel) if s])
            print(f"  {name}: {sel.sum()} updates, {sum(r['flat'] for r, s in zip(rows, sel) if s)} matches held; along track rms error before the climb {np.sqrt(np.mean(need ** 2)):.3f} m, "
                  f"after {np.sqrt(np.mean((need - moved) ** 2)):.3f} m, climb moved rms {np.sqrt(np.mean(moved ** 2)):.3f} m; "
                  f"across {np.sqrt(np.mean(cneed ** 2)):.3f} -> {np.sqrt(np.mean((cneed - cmoved) ** 2)):.3f} m")


if __name__ == "__main__":
    main()
