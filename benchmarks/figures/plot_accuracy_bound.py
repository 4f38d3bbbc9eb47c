#!/usr/bin/env python3
"""Draw docs/images/accuracy-bound-office.png: where along office's drive the URG-04LX bound is loose or tight.

Three panels, the trajectory coloured by the bound's position standard deviation (after
alignment): the known map, unknown walls (the SLAM bound), and unknown walls without the
bearings of wall ends. Run from anywhere:

    .venv/bin/python benchmarks/figures/plot_accuracy_bound.py
"""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.collections import LineCollection  # noqa: E402
from matplotlib.colors import LogNorm  # noqa: E402

from slam2d.eval.accuracy_bound import accuracy_bound  # noqa: E402
from slam2d.io.atomic import atomic_path  # noqa: E402
from slam2d.sim.simulate import SimulationParams, simulate  # noqa: E402

IMAGES = Path(__file__).resolve().parents[2] / "docs" / "images"


def main() -> int:
    sim = simulate("office", SimulationParams(duration=120.0, seed=0, laser="urg-04lx"))
    runs = [
        ("known map", accuracy_bound(sim, map="known")),
        ("unknown walls (the SLAM bound)", accuracy_bound(sim, map="walls")),
        ("unknown walls, wall ends not used", accuracy_bound(sim, map="walls", edges=False)),
    ]
    xy = sim.scan_truth[:, :2]
    fig, axes = plt.subplots(1, 3, figsize=(16, 4.6), constrained_layout=True)
    norm = LogNorm(vmin=1e-3, vmax=0.3)
    for ax, (title, r) in zip(axes, runs):
        ax.add_collection(LineCollection(sim.world.segments.reshape(-1, 2, 2), colors="0.3", linewidths=1.2))
        points = ax.scatter(xy[:, 0], xy[:, 1], c=r["position_std_m"], s=4, cmap="viridis", norm=norm)
        ax.set_title(f"{title}: expected ATE {r['ate_m'] * 100:.1f} cm", fontsize=10)
        ax.set_aspect("equal")
        ax.set_xlabel("x (m)")
    axes[0].set_ylabel("y (m)")
    fig.colorbar(points, ax=axes, label="position std after alignment (m)", shrink=0.9)
    fig.suptitle("Cramér-Rao bound, office 120 s, youBot + URG-04LX (5.6 m), GMapping-default odometry noise")
    IMAGES.mkdir(exist_ok=True)
    target = IMAGES / "accuracy-bound-office.png"
    with atomic_path(target) as tmp:
        fig.savefig(tmp, dpi=90, format="png")
    print(target)
    return 0


if __name__ == "__main__":
    sys.exit(main())
