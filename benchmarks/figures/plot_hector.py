#!/usr/bin/env python3
"""Draw docs/images/hector-long-corridor.png: `hector` in the simulated `long-corridor` (see docs/methods/hector.md).

Top: the map `hector` made with odometry, and its trajectory against the truth,
coloured where the match was flagged degenerate. Bottom: position along the
corridor over time for the truth, `hector` without odometry (stuck: the scan
cannot see it move) and with odometry (it takes the motion along the corridor
from the odometry where the match is degenerate).

Run from the repository root: ``.venv/bin/python benchmarks/figures/plot_hector.py``. The
picture depends only on the code and the fixed seed.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from slam2d.io import open_recording  # noqa: E402
from slam2d.io.atomic import atomic_path  # noqa: E402
from slam2d.methods.runner import build_method  # noqa: E402
from slam2d.sim.simulate import SimulationParams, simulate, write_outputs  # noqa: E402

OUT = Path(__file__).resolve().parents[2] / "docs" / "images" / "hector-long-corridor.png"


def main() -> None:
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        sim_dir = Path(tmp) / "corridor"
        sim = simulate("long-corridor", SimulationParams(seed=0))
        write_outputs(sim, sim_dir)
        frames = list(open_recording(sim_dir / "recording.log.gz").frames())
        truth = np.loadtxt(sim_dir / "truth.tum")
    blind = build_method("hector").run(frames)
    helped = build_method("hector", settings={"use_odometry": "true"}).run(frames)

    fig, (top, bottom) = plt.subplots(2, 1, figsize=(11, 6.4), gridspec_kw={"height_ratios": [1, 1.3]})
    grid = helped.map()
    xmin, ymin, xmax, ymax = grid.extent()
    occ = grid.occupancy().astype(float)
    image = np.where(occ < 0, 0.8, 1.0 - occ / 100.0)
    top.imshow(image, origin="lower", extent=(xmin, xmax, ymin, ymax), cmap="gray", vmin=0, vmax=1)
    t, poses = helped.trajectory()
    flags = helped.diagnostics.array("degenerate")
    top.plot(truth[:, 1], truth[:, 2], color="black", lw=3, alpha=0.4, label="truth")
    top.scatter(poses[:, 0], poses[:, 1], c=np.where(flags == 1, "tab:red", "tab:blue"), s=4,
                label="hector with odometry (red: degenerate match)")
    top.set_xlim(-1, 31)
    top.set_ylim(-1.5, 3.5)
    top.set_aspect("equal")
    top.set_xlabel("x (m)")
    top.set_title("long-corridor: 30 m x 2 m, URG-04LX (5.6 m); map and trajectory of `hector --set use_odometry=true`")
    top.legend(loc="upper center", fontsize=8, ncol=2)

    t0 = truth[0, 0]
    bottom.plot(truth[:, 0] - t0, truth[:, 1], color="black", lw=2, label="truth")
    for slam, colour, label in ((blind, "tab:orange", "hector, no odometry"),
                                (helped, "tab:blue", "hector with odometry")):
        tt, pp = slam.trajectory()
        # both runs start at their own origin; shift to the truth's start for the picture
        bottom.plot(tt - t0, pp[:, 0] - pp[0, 0] + truth[0, 1], color=colour, label=label)
    degenerate = helped.diagnostics.array("degenerate") == 1
    times = helped.diagnostics.array("timestamp") - t0
    bottom.fill_between(times, 0, 31, where=degenerate, color="tab:red", alpha=0.12, step="mid",
                        label="match flagged degenerate")
    bottom.set_ylim(0, 31)
    bottom.set_xlabel("time (s)")
    bottom.set_ylabel("x along the corridor (m)")
    bottom.legend(loc="upper right", fontsize=8)
    bottom.grid(alpha=0.3)

    fig.tight_layout()
    OUT.parent.mkdir(exist_ok=True)
    with atomic_path(OUT) as tmp:
        fig.savefig(tmp, format="png", dpi=100, metadata={"Software": None})
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
