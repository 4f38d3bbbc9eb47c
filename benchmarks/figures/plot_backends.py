#!/usr/bin/env python3
"""Draw docs/images/backends-manhattan.png: the pose-graph back ends on a synthetic Manhattan graph.

A 1500-node, 3000-edge graph (``slam2d.backends.synthetic.manhattan_graph``,
seed 2). Left: the odometry guess against the truth. Middle: ``lago`` with no
initial guess (every pose at 0), the linear estimate alone. Right: ``spa``
from the odometry guess. Each panel's title gives the cost ``sum e^T Omega e``.

Run from the repository root: ``.venv/bin/python benchmarks/figures/plot_backends.py``.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from slam2d.backends import get_backend  # noqa: E402
from slam2d.backends.synthetic import manhattan_graph  # noqa: E402
from slam2d.io.atomic import atomic_path  # noqa: E402

OUT = Path(__file__).resolve().parents[2] / "docs" / "images" / "backends-manhattan.png"


def main() -> None:
    g, truth = manhattan_graph(1500, 3000, seed=2)
    gz, _ = manhattan_graph(1500, 3000, seed=2, initial="zero")
    lago = get_backend("lago", refine_iterations=0).optimize(gz)
    spa = get_backend("spa").optimize(g)
    panels = [
        ("odometry guess", g.poses, g.cost()),
        ("lago, no initial guess (linear only)", lago.poses, lago.cost_after),
        (f"spa from odometry ({spa.iterations} iterations)", spa.poses, spa.cost_after),
    ]
    fig, axes = plt.subplots(1, 3, figsize=(13, 4.6), sharex=True, sharey=True)
    for ax, (title, poses, cost) in zip(axes, panels):
        ax.plot(truth[:, 0], truth[:, 1], color="0.75", lw=2.5, label="truth")
        ax.plot(poses[:, 0], poses[:, 1], color="tab:blue", lw=0.8, label="estimate")
        ax.set_title(f"{title}\ncost {cost:.4g}", fontsize=10)
        ax.set_aspect("equal")
        ax.set_xlabel("x [m]")
    axes[0].set_ylabel("y [m]")
    axes[0].legend(loc="best", fontsize=8)
    fig.tight_layout()
    with atomic_path(OUT) as tmp:
        fig.savefig(tmp, format="png", dpi=90, metadata={"Software": None})
    plt.close(fig)
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
