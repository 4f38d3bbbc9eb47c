#!/usr/bin/env python3
"""Draw docs/images/gmapping-arena.png: gmapping on the simulated paper arena (see docs/methods/gmapping.md).

Left: the map gmapping publishes (rebuilt along the best particle's path) with the
true path, the odometry and the estimate. Right: Neff and the weight entropy per
filter update, with resampling marked.

Run from the repository root: ``.venv/bin/python benchmarks/figures/plot_gmapping.py``. The
picture depends only on the code and the fixed seeds.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from slam2d.io import open_recording  # noqa: E402
from slam2d.io.atomic import atomic_path  # noqa: E402
from slam2d.io.tum import read_tum  # noqa: E402
from slam2d.methods.gmapping import GMapping, GMappingParams  # noqa: E402
from slam2d.sim.simulate import SimulationParams, simulate, write_outputs  # noqa: E402

OUT = Path(__file__).resolve().parents[2] / "docs" / "images" / "gmapping-arena.png"


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        sim = simulate("paper-arena", SimulationParams(seed=1))
        write_outputs(sim, Path(tmp) / "arena")
        frames = list(open_recording(Path(tmp) / "arena" / "recording.log.gz").frames())
        truth_t, truth = read_tum(Path(tmp) / "arena" / "truth.tum")
    params = GMappingParams()  # the defaults (between_updates=matched)
    slam = GMapping(params, seed=0).run(frames)
    _, est = slam.trajectory()
    odom = np.stack([f.odometry for f in frames])
    grid = slam.map()
    occ = grid.occupancy().astype(float)
    shown = np.where(occ < 0, 0.5, 1.0 - occ / 100.0)
    ox, oy, x1, y1 = grid.extent()

    fig, (ax, diag) = plt.subplots(1, 2, figsize=(11, 4.6), gridspec_kw={"width_ratios": [1.2, 1]})
    ax.imshow(shown, cmap="gray", origin="lower", extent=(ox, x1, oy, y1), vmin=0, vmax=1)
    ax.plot(truth[:, 0], truth[:, 1], "k-", lw=2, label="truth")
    ax.plot(odom[:, 0], odom[:, 1], color="tab:red", lw=1, label="odometry")
    ax.plot(est[:, 0], est[:, 1], color="tab:blue", lw=1.2, label="gmapping (best particle)")
    ax.set_title("paper-arena, 30 particles, delta 0.025 m")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.legend(loc="upper right", fontsize=8)
    d = slam.diagnostics
    updated = np.nan_to_num(d.array("updated")) == 1
    k = np.arange(int(updated.sum()))
    diag.plot(k, d.array("neff")[updated], color="tab:green", label="Neff (particles)")
    diag.axhline(0.5 * params.particles, color="tab:green", ls=":", lw=1, label="resampleThreshold x N")
    twin = diag.twinx()
    twin.plot(k, d.array("weight_entropy")[updated], color="tab:purple", label="weight entropy (nats)")
    twin.axhline(np.log(params.particles), color="tab:purple", ls=":", lw=1, label="ln N = 3.40")
    res = (np.nan_to_num(d.array("resampled")) == 1)[updated]
    diag.plot(k[res], d.array("neff")[updated][res], "kv", ms=5, label="resampled")
    diag.set_xlabel("filter update")
    diag.set_ylabel("Neff")
    twin.set_ylabel("entropy (nats)")
    diag.legend(loc="lower left", fontsize=8)
    twin.legend(loc="lower right", fontsize=8)
    diag.set_title("particle diversity per update")
    fig.tight_layout()
    with atomic_path(OUT) as tmp_png:
        fig.savefig(tmp_png, dpi=110, format="png")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
