#!/usr/bin/env python3
"""gmapping's islands one by one: each island's score (what `islands` chooses by) and ATE, per run seed.

    NUMBA_NUM_THREADS=1 SLAM2D_THREADS=1 PYTHONPATH=src .venv/bin/python benchmarks/studies/measure_gmapping_islands.py \
        ../shared/datasets/aces/aces.clf.gz --seeds 3,6 --islands 10 --set srt=0.05 --set stt=0.05

For each run seed, island k is gmapping run alone with ``island_seed(seed, k)`` (island 0: the run's own
seed), exactly as ``islands=K`` runs it. Printed per island: its score (the best particle's accumulated
log-likelihood per filter update), its ATE against the ``reference.tum`` beside the log (RMSE after SE(2)
alignment, m) and which island ``islands=K`` reports (the largest score).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from measure_gmapping_particles import seed_list  # noqa: E402


def main() -> None:
    from slam2d.eval.trajectory_metrics import absolute_trajectory_error, associate
    from slam2d.io import open_recording
    from slam2d.io.tum import read_tum
    from slam2d.methods.gmapping import island_seed
    from slam2d.methods.runner import build_method

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log", type=Path)
    ap.add_argument("--seeds", type=seed_list, default=seed_list("0"))
    ap.add_argument("--islands", type=int, default=10)
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE")
    a = ap.parse_args()
    settings = dict(item.split("=", 1) for item in a.set)  # parsed as `slam2d run --set` parses them
    frames = list(open_recording(a.log).frames())
    rt, rp = read_tum(a.log.parent / "reference.tum")
    for seed in a.seeds:
        rows = []
        for k in range(a.islands):
            slam = build_method("gmapping", settings=settings, seed=island_seed(seed, k)).run(frames)
            t, p = slam.trajectory()
            ate = absolute_trajectory_error(associate(t, p, rt, rp))["translation_m"]["rmse"]
            rows.append((float(slam._weight_sum.max() / slam._nodes), ate))
        chosen = int(np.argmax([r[0] for r in rows]))
        print(f"seed {seed}: reported island {chosen}, ATE {rows[chosen][1]:.3f} m; best island ATE "
              f"{min(r[1] for r in rows):.3f} m")
        for k in np.argsort([-r[0] for r in rows]):
            print(f"  island {k}: score {rows[k][0]:.2f}, ATE {rows[k][1]:.3f} m", flush=True)


if __name__ == "__main__":
    main()
