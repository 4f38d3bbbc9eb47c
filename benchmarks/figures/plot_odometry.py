#!/usr/bin/env python3
"""Draw docs/images/odometry-drift.png: how simulated odometry drifts (see docs/robots.md).

Left: a youBot drives three laps of a 5 m x 4 m rectangle; the true path and
the odometry of five seeds with GMapping's default noise and with a tenth of it.
Right: the spread of the odometry's forward error along a straight drive over
500 seeds, against the model's prediction srr * sqrt(distance * reference_distance).

Run from the repository root: ``.venv/bin/python benchmarks/figures/plot_odometry.py``. The
picture depends only on the code and the fixed seeds.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from slam2d.io.atomic import atomic_path  # noqa: E402
from slam2d.sensors.motion_noise import OdometryNoise, simulate_odometry  # noqa: E402
from slam2d.sim.robot import follow_waypoints, robot_preset, scripted  # noqa: E402

OUT = Path(__file__).resolve().parents[2] / "docs" / "images" / "odometry-drift.png"
RATE = 50.0


def main() -> None:
    youbot = robot_preset("youbot")
    rectangle = [[5.0, 0.0], [5.0, 4.0], [0.0, 4.0], [0.0, 0.0]]
    times, truth = follow_waypoints(youbot, [0.0, 0.0, 0.0], rectangle, rate=RATE, duration=90.0, loop=True)
    gmapping = OdometryNoise()
    tenth = dataclasses.replace(gmapping, srr=0.01, srt=0.02, str=0.01, stt=0.02)

    fig, (paths, spread) = plt.subplots(1, 2, figsize=(11, 4.8), gridspec_kw={"width_ratios": [1.15, 1]})
    for noise, colour, label in ((gmapping, "tab:red", "GMapping defaults"), (tenth, "tab:blue", "a tenth of them")):
        for seed in range(5):
            odom = simulate_odometry(times, truth, noise, np.random.default_rng(seed))
            paths.plot(odom[:, 0], odom[:, 1], color=colour, lw=0.8, alpha=0.7, label=label if seed == 0 else None)
    paths.plot(truth[:, 0], truth[:, 1], color="black", lw=2.0, label="true path (3 laps)")
    paths.set_aspect("equal")
    paths.set_xlabel("x (m)")
    paths.set_ylabel("y (m)")
    paths.set_title("youBot, 90 s: odometry of 5 seeds per setting")
    paths.legend(loc="upper left", fontsize=8)
    paths.grid(alpha=0.3)

    only_srr = OdometryNoise(srr=0.1, srt=0.0, str=0.0, stt=0.0)
    times, straight = scripted(youbot, [0.0, 0.0, 0.0], [(40.0, 0.5, 0.0, 0.0)], rate=RATE)
    errors = np.array(
        [simulate_odometry(times, straight, only_srr, np.random.default_rng(seed))[:, 0] - straight[:, 0]
         for seed in range(500)]
    )
    distance = straight[:, 0]
    spread.plot(distance, errors.std(axis=0, ddof=1), color="tab:red", label="measured std over 500 seeds")
    spread.plot(distance, only_srr.srr * np.sqrt(distance * only_srr.reference_distance), "k--",
                label="model: srr * sqrt(d * reference_distance)")
    spread.plot(distance, only_srr.srr * distance, ":", color="grey", label="srr * d (if the error never averaged)")
    spread.set_ylim(0.0, 0.8)
    spread.set_xlabel("distance driven straight, d (m)")
    spread.set_ylabel("std of forward odometry error (m)")
    spread.set_title("srr = 0.1, other terms 0")
    spread.legend(loc="upper left", fontsize=8)
    spread.grid(alpha=0.3)

    fig.tight_layout()
    OUT.parent.mkdir(exist_ok=True)
    with atomic_path(OUT) as tmp:
        fig.savefig(tmp, format="png", dpi=110, metadata={"Software": None})
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
