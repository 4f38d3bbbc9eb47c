#!/usr/bin/env python3
"""Print the table of docs/backends.md: every back end on the 5000-node synthetic Manhattan graph.

    .venv/bin/python benchmarks/studies/measure_backends.py

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


def noise_table() -> None:
    """Heading noise against starting point: 2000 nodes, 4000 edges, seed 3."""
    print("\n| heading noise [rad] | `spa` from odometry: cost (iterations) | `lago` linear / `spa` | `lago` +1 GN / `spa` | `spa` from all-zero poses / `spa` |")
    print("|---|---|---|---|---|")
    for sth in (0.01, 0.05, 0.1, 0.2):
        sigma = (0.05, 0.05, sth)
        g, _ = manhattan_graph(2000, 4000, seed=3, sigma=sigma)
        gz, _ = manhattan_graph(2000, 4000, seed=3, sigma=sigma, initial="zero")
        spa = get_backend("spa").optimize(g)
        lin = get_backend("lago", refine_iterations=0).optimize(gz)
        gn = get_backend("lago").optimize(gz)
        cold = get_backend("spa").optimize(gz)
        print(f"| {sth:g} | {spa.cost_after:.1f} ({spa.iterations}) | {lin.cost_after / spa.cost_after:.4f} | "
              f"{gn.cost_after / spa.cost_after:.4f} | {cold.cost_after / spa.cost_after:.3g} ({cold.iterations}) |")


def stages() -> None:
    """Best-of-5 CPU time of each stage of one SPA solve on the 5000-node graph."""
    import time

    from slam2d.backends.graph import edge_errors
    from slam2d.backends.linear import BlockPattern, LinearSolver, assemble_normal_equations, node_ordering

    g, _ = manhattan_graph(5000, 10000, seed=0)
    ei, ej, z, info = g.edge_i, g.edge_j, g.measurements, np.ascontiguousarray(g.information)

    def best(f):
        times = []
        for _ in range(5):
            c = time.process_time()
            out = f()
            times.append(time.process_time() - c)
        return min(times) * 1e3, out

    t_order, _ = best(lambda: node_ordering(ei, ej, g.num_nodes, 0))
    t_pattern, pat = best(lambda: BlockPattern(ei, ej, g.num_nodes, 0))
    t_symbolic, solver = best(lambda: LinearSolver("block", pat))
    data, grad = np.zeros(pat.nnz), np.zeros(pat.size)
    t_assemble, _ = best(lambda: assemble_normal_equations(g.poses, ei, ej, z, info, pat.slots, pat.gslots, 0, 1.0, data, grad))
    damp = np.full(pat.size, 1e-5)
    t_factor, _ = best(lambda: solver._block.factor(data, damp))
    t_solve, _ = best(lambda: solver._block.solve(grad))
    t_cost, _ = best(lambda: float(np.einsum("ki,kij,kj->", e := edge_errors(g.poses, ei, ej, z), info, e)))
    print(f"\nstages [ms, best of 5]: ordering {t_order:.1f} (inside pattern), pattern {t_pattern:.1f}, "
          f"symbolic {t_symbolic:.1f}; per iteration: assembly {t_assemble:.1f}, factorisation {t_factor:.1f}, "
          f"solve {t_solve:.1f}, cost {t_cost:.1f}")


def incremental() -> None:
    """SPA after a late loop closure: optimise without the last tenth of the loop edges, add them, optimise again."""
    from slam2d.backends import PoseGraph

    print("\n| nodes | new loop edges | iterations | CPU s (median of 3) |")
    print("|---|---|---|---|")
    for n in (200, 1000, 5000):
        g, _ = manhattan_graph(n, 2 * n, seed=0)
        k = g.num_edges - (g.num_edges - (n - 1)) // 10
        h = PoseGraph()
        h.add_nodes(g.poses)
        h.add_edges(g.edge_i[:k], g.edge_j[:k], g.measurements[:k], g.information[:k])
        h.poses = get_backend("spa").optimize(h).poses
        h.add_edges(g.edge_i[k:], g.edge_j[k:], g.measurements[k:], g.information[k:])
        runs = [get_backend("spa").optimize(h) for _ in range(3)]
        cpu = float(np.median([r.cpu_s for r in runs]))
        print(f"| {n} | {g.num_edges - k} | {runs[0].iterations} | {cpu:.3f} |")


if __name__ == "__main__":
    main()
    noise_table()
    incremental()
    stages()
