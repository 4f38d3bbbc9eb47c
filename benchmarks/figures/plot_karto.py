#!/usr/bin/env python3
"""Draw docs/images/karto-corridor-loop.png: `karto` on a simulated loop with GMapping's noisy odometry.

Left: the map `karto` built, with the true path, the odometry and the
estimate, and the accepted loop-closure edges. Right: the position error of
odometry and of `karto` along the run (after the best rigid alignment).

Run from the repository root: ``.venv/bin/python benchmarks/figures/plot_karto.py``. The
picture depends only on the code and the fixed seed.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from slam2d.core import se2  # noqa: E402
from slam2d.eval.trajectory_metrics import align_se2, associate  # noqa: E402
from slam2d.io.atomic import atomic_path  # noqa: E402
from slam2d.methods import get_method  # noqa: E402
from slam2d.sim.simulate import SimulationParams, simulate  # noqa: E402

OUT = Path(__file__).resolve().parents[2] / "docs" / "images" / "karto-corridor-loop.png"


def _aligned(times, poses, sim):
    assoc = associate(times, poses, sim.scan_times, sim.scan_truth)
    t = align_se2(assoc.estimate[:, :2], assoc.reference[:, :2])
    moved = se2.compose(t, assoc.estimate)
    return assoc.times, moved, np.hypot(*(moved[:, :2] - assoc.reference[:, :2]).T)


def main() -> None:
    sim = simulate("corridor-loop", SimulationParams(duration=100.0, seed=5))
    slam = get_method("karto")(seed=0).run(sim.frames())
    t, p = slam.trajectory()
    t, est, err = _aligned(t, p, sim)
    odo_t, odo, odo_err = _aligned(sim.scan_times, sim.odometry[sim.scan_indices], sim)
    grid = slam.map()
    # the map is drawn in the estimate's frame: move it with the same alignment as the trajectory
    assoc = associate(*slam.trajectory(), sim.scan_times, sim.scan_truth)
    align = align_se2(assoc.estimate[:, :2], assoc.reference[:, :2])
    occ = grid.occupied()
    rows, cols = np.nonzero(occ)
    pts = se2.transform_points(align, grid.cell_to_world(np.stack([rows, cols], axis=-1)))

    fig, (ax, ex) = plt.subplots(1, 2, figsize=(12, 5), gridspec_kw={"width_ratios": [1.2, 1]})
    ax.scatter(pts[:, 0], pts[:, 1], s=0.3, c="black", label="karto map (occupied cells)")
    ax.plot(sim.scan_truth[:, 0], sim.scan_truth[:, 1], color="tab:green", lw=2.5, alpha=0.6, label="true path")
    ax.plot(odo[:, 0], odo[:, 1], color="tab:red", lw=0.8, label="odometry")
    ax.plot(est[:, 0], est[:, 1], color="tab:blue", lw=1.0, label="karto")
    nodes = se2.compose(align, slam.pose_graph().poses)
    for c in slam.diagnostics.summary["loop_closures"]:
        a, b = nodes[c["frm"]], nodes[c["to"]]
        ax.plot([a[0], b[0]], [a[1], b[1]], color="tab:orange", lw=2.0)
    ax.plot([], [], color="tab:orange", lw=2.0, label="loop closures")
    ax.set_aspect("equal")
    ax.set_xlim(sim.scan_truth[:, 0].min() - 4, sim.scan_truth[:, 0].max() + 4)
    ax.set_ylim(sim.scan_truth[:, 1].min() - 4, sim.scan_truth[:, 1].max() + 4)
    ax.legend(loc="upper right", fontsize=7)
    ax.set_title("corridor-loop, 100 s, GMapping's odometry noise (seed 5)")
    ex.plot(odo_t, odo_err, color="tab:red", label="odometry")
    ex.plot(t, err, color="tab:blue", label="karto")
    ex.set_yscale("log")
    ex.set_xlabel("time (s)")
    ex.set_ylabel("position error after alignment (m)")
    ex.grid(alpha=0.3)
    ex.legend()
    fig.tight_layout()
    with atomic_path(OUT) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
