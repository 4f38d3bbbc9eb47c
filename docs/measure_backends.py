#!/usr/bin/env python3
"""Print the table of docs/backends.md: every back end on the 5000-node synthetic Manhattan graph.

    .venv/bin/python docs/measure_backends.py

CPU seconds (``time.process_time``), median of 3 runs, after loading the
compiled kernels on a small graph. ``gtsam`` rows appear only when it is installed.
"""

from __future__ import annotations

import numpy as np

from slam2d.backends import available_backends, get_backend
from slam2d.backends.synthetic import manhattan_graph

RUNS = [
    ("`spa` (block Cholesky)", "spa", "odometry", {}),
    ("`spa`, `linear_solver=splu`", "spa", "odometry", {"linear_solver": "splu"}),
    ("`spa`, `damping=diagonal` (Karto's)", "spa", "odometry", {"damping": "diagonal"}),
    ("`lago` (+1 Gauss-Newton step)", "lago", "zero", {}),
    ("`lago`, `refine_iterations=0`", "lago", "zero", {"refine_iterations": 0}),
    ("`gtsam` (when installed)", "gtsam", "odometry", {}),
]


def main() -> None:
    names = available_backends()
    small = manhattan_graph(30, 60, seed=1)[0]
    for name in names:
        get_backend(name).optimize(small)
    graphs = {init: manhattan_graph(5000, 10000, seed=0, initial=init) for init in ("odometry", "zero")}
    g, truth = graphs["odometry"]
    print(f"start cost from odometry {g.cost():.4g}, cost of the true poses {g.cost(truth):.6g}\n")
    print("| back end | start | iterations | final cost | CPU s (median of 3) |")
    print("|---|---|---|---|---|")
    spa_cost = None
    for label, name, init, opts in RUNS:
        if name not in names:
            continue
        runs = [get_backend(name, **opts).optimize(graphs[init][0]) for _ in range(3)]
        r = runs[-1]
        if spa_cost is None and name == "spa":
            spa_cost = r.cost_after
        ratio = f" ({r.cost_after / spa_cost:.6f} x `spa`)" if name == "lago" and spa_cost else ""
        start = "all poses 0" if init == "zero" else init
        cpu = float(np.median([x.cpu_s for x in runs]))
        print(f"| {label} | {start} | {r.iterations} | {r.cost_after:.2f}{ratio} | {cpu:.2f} |")


if __name__ == "__main__":
    main()
