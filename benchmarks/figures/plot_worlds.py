#!/usr/bin/env python3
"""Draw every built-in simulator world into docs/images/world-NAME.png.

Walls and circles are coloured by material; the default start pose is an
arrow and the default path a dashed line. Run from anywhere:

    .venv/bin/python benchmarks/figures/plot_worlds.py [NAME ...]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.collections import LineCollection  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402

from slam2d.io.atomic import atomic_path  # noqa: E402
from slam2d.sim.world import MATERIALS, World, builtin_world_names, load_world  # noqa: E402
from slam2d.report.images import MATERIAL_COLOURS  # noqa: E402

IMAGES = Path(__file__).resolve().parents[2] / "docs" / "images"

COLOURS = MATERIAL_COLOURS


def draw(world: World, ax: plt.Axes) -> None:
    """Draw one world on ``ax``: walls and circles by material, start pose and path."""
    seg_names, circ_names = world.material_names()
    lines = world.segments.reshape(-1, 2, 2)
    ax.add_collection(LineCollection(lines, colors=[COLOURS[m] for m in seg_names], linewidths=2.0))
    for (cx, cy, r), m in zip(world.circles, circ_names):
        ax.add_patch(plt.Circle((cx, cy), r, fill=True, facecolor="none", edgecolor=COLOURS[m], linewidth=2.0))
        # A can is a few centimetres across; ring it so it is visible at room scale.
        ax.add_patch(plt.Circle((cx, cy), max(r, 0.0) + 0.08, fill=False, edgecolor="red", linewidth=0.8))
    xmin, ymin, xmax, ymax = world.bounds()
    span = max(xmax - xmin, ymax - ymin)
    if world.waypoints is not None:
        pts = world.waypoints if world.start is None else np.vstack([world.start[:2], world.waypoints])
        ax.plot(pts[:, 0], pts[:, 1], "--", color="tab:green", linewidth=1.2, zorder=3)
        ax.plot(world.waypoints[:, 0], world.waypoints[:, 1], "o", color="tab:green", markersize=3, zorder=3)
    if world.start is not None:
        x, y, th = world.start
        length = 0.06 * span
        ax.annotate(
            "", xy=(x + length * np.cos(th), y + length * np.sin(th)), xytext=(x, y),
            arrowprops={"arrowstyle": "-|>", "color": "tab:red", "linewidth": 1.5}, zorder=4,
        )
        ax.plot([x], [y], "o", color="tab:red", markersize=5, zorder=4)
    pad = 0.05 * span
    ax.set_xlim(xmin - pad, xmax + pad)
    ax.set_ylim(ymin - pad, ymax + pad)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.grid(True, linewidth=0.3, alpha=0.5)
    ax.set_title(f"{world.name} ({xmax - xmin:g} m x {ymax - ymin:g} m)")


def legend(ax: plt.Axes, world: World) -> None:
    used = sorted(set(world.material_names()[0]) | set(world.material_names()[1]), key=MATERIALS.index)
    handles = [Line2D([], [], color=COLOURS[m], linewidth=2.0, label=m) for m in used]
    handles.append(Line2D([], [], color="tab:red", marker="o", linewidth=0, label="start"))
    if world.waypoints is not None:
        handles.append(Line2D([], [], color="tab:green", linestyle="--", label="default path"))
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)


def render(name: str, out_dir: Path = IMAGES) -> Path:
    """Write ``out_dir/world-NAME.png`` for a built-in world; return its path."""
    world = load_world(name)
    xmin, ymin, xmax, ymax = world.bounds()
    aspect = (ymax - ymin) / (xmax - xmin)
    width = 7.5
    height = float(np.clip(width * 0.75 * aspect + 1.0, 2.5, 6.5))
    fig, ax = plt.subplots(figsize=(width, height), dpi=100)
    draw(world, ax)
    legend(ax, world)
    fig.tight_layout()
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / f"world-{name}.png"
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", bbox_inches="tight", metadata={"Software": None})
    plt.close(fig)
    return path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", help="worlds to draw (default: all built-in worlds)")
    args = parser.parse_args(argv)
    for name in args.names or builtin_world_names():
        print(render(name))
    return 0


if __name__ == "__main__":
    sys.exit(main())
