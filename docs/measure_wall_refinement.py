#!/usr/bin/env python3
"""karto's wall bundle adjustment (`wall_refinement`) on the simulated URG-04LX recordings: several settings per karto run.

    .venv/bin/python docs/measure_wall_refinement.py [--world office] [--laser urg-04lx] [--seeds 0,1,2] \
        [--base "key=value ..."] [--from-truth] ["key=value ..." ...]

Per seed, karto runs once (the `karto-sim-lasers` recordings, written once under --cache as
docs/measure_gmapping_proposal.py writes them; `--base` settings, `wall_end_landmarks` false unless
given) with the refinement held back; then the refinement runs on the finished graph once per
setting (each a quoted list of key=value, "" = the defaults), from the same poses, exactly as
`GraphSlam.finish` runs it. Printed per seed: karto's ATE / map error (m, judged as `slam2d
evaluate --truth`), then per setting ATE / map error, walls, and the refinement's CPU seconds; at
the end the mean ATE per setting. The same numbers as docs/measure_wall_end_revisits.py gives with
`wall_refinement=true` and the setting, at one karto run per seed.

With ``--from-truth`` each setting also runs from the *true* poses of the frames (instead of karto's)
and prints that ATE: what the refinement's own optimum is worth with the readings it uses, apart
from where it starts.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from slam2d.eval.evaluate import evaluate_run, load_run, load_truth
from slam2d.io.tum import write_tum
from slam2d.methods.runner import build_method, run_method
from slam2d.report.map_outputs import write_map_outputs

sys.path.insert(0, str(Path(__file__).parent))
from measure_gmapping_proposal import cached_recording  # noqa: E402


def _judge(slam, truth, out: Path) -> tuple[float, float]:
    out.mkdir(parents=True, exist_ok=True)
    t, p = slam.trajectory()
    write_tum(out / "trajectory.tum", t, p)
    write_map_outputs(slam.map(), out)
    e = evaluate_run(load_run(out), truth)
    return e["trajectory"]["ate"]["translation_m"]["rmse"], e["map_truth"]["truth_to_map_m"]["mean"]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--laser", default="urg-04lx")
    ap.add_argument("--world", default="office")
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--cache", default="/tmp/slam2d-proposal")
    ap.add_argument("--base", default="", help="karto settings of the run, key=value separated by spaces")
    ap.add_argument("--from-truth", action="store_true", help="also refine from the true frame poses")
    ap.add_argument("settings", nargs="*", help='refinement settings, one quoted "key=value ..." each ("" = defaults)')
    a = ap.parse_args()
    base = dict(s.split("=", 1) for s in a.base.split())
    base.setdefault("wall_end_landmarks", "false")
    variants = [dict(s.split("=", 1) for s in v.split()) for v in (a.settings or [""])]
    means: dict[int, list[float]] = {}
    for seed in (int(s) for s in a.seeds.split(",")):
        sim_dir = cached_recording(a.cache, a.world, a.laser, seed)
        truth = load_truth(sim_dir)
        run_dir = Path(a.cache) / f"run-refine-{a.world}-{a.laser}-{seed}"
        slam = build_method("karto", settings={**base, "wall_refinement": "true"})
        slam.refine_walls = lambda: None  # held back: run below, once per setting
        run_method(slam, sim_dir / "recording.log.gz", run_dir)
        del slam.refine_walls
        fe = slam.frontend
        poses0 = fe.graph.poses.copy()
        done = len(fe.optimizations)
        e = evaluate_run(load_run(run_dir), truth)
        line = [f"karto {e['trajectory']['ate']['translation_m']['rmse']:.3f} / "
                f"{e['map_truth']['truth_to_map_m']['mean']:.3f}"]
        times, _ = slam.trajectory()
        true_frames = truth.poses[np.clip(np.searchsorted(truth.times, times), 0, len(truth.times) - 1)]
        for k, v in enumerate(variants):
            slam.params = fe.params = build_method("karto", settings={**base, **v, "wall_refinement": "true"}).params
            fe.graph.poses = poses0
            slam._refined = None
            del fe.optimizations[done:]
            cpu = time.process_time()
            slam.refine_walls()
            cpu = time.process_time() - cpu
            walls = slam.diagnostics.summary["wall_refinement"]["walls"]
            ate, err = _judge(slam, truth, Path(a.cache) / f"run-refine-variant-{a.world}-{seed}")
            means.setdefault(k, []).append(ate)
            text = f"[{' '.join(f'{x}={y}' for x, y in v.items()) or 'defaults'}] {ate:.3f} / {err:.3f} ({walls:.0f} walls, cpu {cpu:.1f} s"
            if a.from_truth:
                # The same refinement started at the true poses of the frames (and of the nodes among them).
                node_frame = np.asarray(slam._frame_node)
                fe.graph.poses = true_frames[node_frame >= 0]
                slam._refined = None
                del fe.optimizations[done:]
                slam.trajectory = lambda: (times, true_frames.copy())
                slam.refine_walls()
                del slam.trajectory
                ate_t, _ = _judge(slam, truth, Path(a.cache) / f"run-refine-truth-{a.world}-{seed}")
                means.setdefault(-1 - k, []).append(ate_t)
                text += f"; from the truth {ate_t:.3f}"
            line.append(text + ")")
        print(f"{a.world} {a.laser} seed {seed}: " + ", ".join(line), flush=True)
    for k, v in enumerate(variants):
        extra = f", from the truth {np.mean(means[-1 - k]):.3f}" if a.from_truth else ""
        print(f"mean ATE {np.mean(means[k]):.3f} m{extra}: {' '.join(f'{x}={y}' for x, y in v.items()) or 'defaults'}")


if __name__ == "__main__":
    main()
