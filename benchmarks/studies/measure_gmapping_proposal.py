#!/usr/bin/env python3
"""gmapping (or ``--method``) on the simulated office (120 s, URG-04LX by default), seeds 0-2, with given settings.

    .venv/bin/python benchmarks/studies/measure_gmapping_proposal.py [--method gmapping] [--laser urg-04lx] [--world office] \
        [--seeds 0,1,2] [key=value ...]
    .venv/bin/python benchmarks/studies/measure_gmapping_proposal.py --log ../shared/datasets/intel/intel.clf.gz \
        [--seeds 0,1,2,3,4] [key=value ...]

A lighter `gmapping-sim-lasers`: the same recordings (written once under --cache), run in-process
with `run_method` and the settings given, judged as `slam2d evaluate --truth`. Prints per seed the
ATE (m), map error (mean truth-to-map, m), resamplings and the CPU seconds of the run. With
``--log`` a real log is run instead, with the seeds as the filter's seeds, and judged against the
``reference.tum`` beside it (as `slam2d evaluate --reference`).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from slam2d.eval.evaluate import evaluate_run, load_reference, load_run, load_truth
from slam2d.methods.runner import run_method
from slam2d.sim.simulate import SimulationParams, simulate, write_outputs


def cached_recording(cache: str, world: str, laser: str, seed: int) -> Path:
    """The simulated recording of (world, laser, seed) under ``cache``, simulated once.

    The office runs 120 s (as `gmapping-sim-lasers` and `karto-sim-lasers`), other worlds one pass.
    """
    sim_dir = Path(cache) / f"{world}-{laser}-{seed}"
    if not (sim_dir / "recording.log.gz").exists():
        duration = 120.0 if world == "office" else None
        write_outputs(simulate(world, SimulationParams(duration=duration, seed=seed, laser=laser)), sim_dir)
    return sim_dir


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--method", default="gmapping", help="any registered method (karto's sweep on its page used this)")
    ap.add_argument("--laser", default="urg-04lx")
    ap.add_argument("--world", default="office")
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--cache", default="/tmp/slam2d-proposal")
    ap.add_argument("--log", default=None, help="a real log (reference.tum beside it); seeds: the filter's")
    ap.add_argument("settings", nargs="*")
    a = ap.parse_args()
    settings = dict(s.split("=", 1) for s in a.settings)
    if a.log:
        log = Path(a.log)
        reference = load_reference(log.parent / "reference.tum")
        ates = []
        for seed in (int(s) for s in a.seeds.split(",")):
            run_dir = Path(a.cache) / f"run-{a.method}-{log.parent.name}-{seed}-{abs(hash(tuple(a.settings)))}"
            cpu = time.process_time()
            run_method(a.method, log, run_dir, settings=settings, seed=seed)
            cpu = time.process_time() - cpu
            ate = evaluate_run(load_run(run_dir), reference)["trajectory"]["ate"]["translation_m"]["rmse"]
            diag = json.loads((run_dir / "diagnostics.json").read_text())
            counts = diag["counters"]
            refine = diag["summary"].get("wall_refinement")  # karto's wall_refinement, when on
            refined = (f", wall_refinement {refine['walls']:.0f} walls over {refine['poses']:.0f} poses, cpu "
                       f"{refine['cpu_s']:.1f} s" if refine else "")
            ates.append(ate)
            print(f"{log.parent.name} filter seed {seed}: ATE {ate:.3f} m, {counts.get('match_failures', 0)} match "
                  f"failures, {counts.get('degenerate_matches', 0)} degenerate matches, cpu {cpu:.0f} s{refined}", flush=True)
        print(f"mean ATE {sum(ates) / len(ates):.3f} m; settings {' '.join(a.settings) or '(defaults)'}")
        return
    ates, maps = [], []
    for seed in (int(s) for s in a.seeds.split(",")):
        sim_dir = cached_recording(a.cache, a.world, a.laser, seed)
        run_dir = Path(a.cache) / f"run-{a.method}-{a.world}-{a.laser}-{seed}-{abs(hash(tuple(a.settings)))}"
        cpu = time.process_time()
        run_method(a.method, sim_dir / "recording.log.gz", run_dir, settings=settings)
        cpu = time.process_time() - cpu
        e = evaluate_run(load_run(run_dir), load_truth(sim_dir))
        ate = e["trajectory"]["ate"]["translation_m"]["rmse"]
        err = e["map_truth"]["truth_to_map_m"]["mean"]
        counts = json.loads((run_dir / "diagnostics.json").read_text())["counters"]
        ates.append(ate)
        maps.append(err)
        print(f"{a.world} {a.laser} seed {seed}: ATE {ate:.3f} m, map {err:.3f} m, "
              f"{counts.get('resamples', 0)} resamplings, {counts.get('match_failures', 0)} match failures, "
              f"{counts.get('degenerate_matches', 0)} degenerate matches, "
              f"cpu {cpu:.0f} s", flush=True)
    print(f"mean ATE {sum(ates) / len(ates):.3f} m, max {max(ates):.3f}; mean map {sum(maps) / len(maps):.3f} m; "
          f"settings {' '.join(a.settings) or '(defaults)'}")


if __name__ == "__main__":
    main()
