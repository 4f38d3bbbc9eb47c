#!/usr/bin/env python3
"""Draw the range noise model into docs/images/sensor-model.png.

Left: sigma against distance per material with the target square to the beam
(incidence 0, the study's "90 deg"); right: turned by 45 degrees. The study's
measured range (1-4 m) is shaded; outside it the curves are this project's
extension. Dots: Table I (each material's mean over the measured distances),
drawn at the mean of the measured distances. Run from anywhere:

    .venv/bin/python benchmarks/figures/plot_sensor_model.py
"""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from slam2d.report.images import MATERIAL_COLOURS  # noqa: E402
from slam2d.io.atomic import atomic_path  # noqa: E402
from slam2d.sensors.range_noise import (  # noqa: E402
    MATERIALS,
    STUDY_GMAPPING_SIGMA,
    TABLE_I_MM,
    StudyModel,
    sigma_45,
    sigma_90,
    sigma_eq1,
)

OUT = Path(__file__).resolve().parents[2] / "docs" / "images" / "sensor-model.png"
COLOURS = MATERIAL_COLOURS
STUDY_DISTANCES = np.array([1.0, 2.0, 3.0, 3.5, 4.0])


def main() -> None:
    model = StudyModel()
    d = np.linspace(0.02, 5.6, 400)
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.2), sharey=True, dpi=110)
    for ax, incidence, column, fit, title in (
        (axes[0], 0.0, 0, sigma_90, "target square to the beam (study: 90 deg)"),
        (axes[1], math.pi / 4, 1, sigma_45, "target turned 45 deg"),
    ):
        ax.axvspan(1.0, 4.0, color="#eeeeee", zorder=0, label="measured by the study")
        for k, name in enumerate(MATERIALS):
            ax.plot(d, 1000 * model.sigma(d, incidence, k), color=COLOURS[name], lw=1.6, label=name)
            if name in TABLE_I_MM:
                ax.plot(STUDY_DISTANCES.mean(), TABLE_I_MM[name][column], "o", color=COLOURS[name], ms=5)
        ax.plot(d, 1000 * fit(d), "k--", lw=1, label="fit (Fig. 6 / Fig. 7)")
        ax.plot(d, 1000 * sigma_eq1(d), ":", color="#cc3333", lw=1.2, label="eq. (1), both angles")
        ax.plot([2.5], [1000 * STUDY_GMAPPING_SIGMA], "*", color="#cc3333", ms=9)
        ax.set_title(title, fontsize=10)
        ax.set_xlabel("distance [m]")
        ax.set_xlim(0, 5.6)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("range sigma [mm]")
    axes[0].set_ylim(0, None)
    axes[1].legend(fontsize=7.5, loc="upper left")
    fig.suptitle("Hokuyo URG-04LX range noise: StudyModel (dots: Table I; star: 4.1 mm at 2.5 m)", fontsize=10)
    fig.tight_layout()
    with atomic_path(OUT) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
