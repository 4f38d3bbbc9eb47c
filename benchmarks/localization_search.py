"""Global search without an initial pose: how often `slam2d localize` settles in the wrong place.

Second drives of office and corridor-loop (as benchmarks/localization.py makes them) and 40 s of
office (seed 3), each localized in its world's true map with seeds 0-2 (mcl, defaults). A run counts
as wrong when more than 1 % of its localized poses are over 0.5 m from the truth. Module constants of
slam2d.localization.localizer can be overridden to compare settings, e.g.

    .venv/bin/python benchmarks/localization_search.py _SEARCH_NEFF=0.5
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT / "benchmarks"))


def main() -> int:
    import slam2d.localization.localizer as localizer
    from localization import second_drive
    from slam2d.io.tum import read_tum
    from slam2d.localization.run import localize_recording
    from slam2d.sim.simulate import SimulationParams, simulate, write_outputs

    for setting in sys.argv[1:]:
        name, value = setting.split("=")
        setattr(localizer, name, float(value) if "." in value else int(value))
    wrong_runs = 0
    with tempfile.TemporaryDirectory(prefix="slam2d-search-") as tmp:
        work = Path(tmp)
        cases = []
        for world in ("office", "corridor-loop"):
            write_outputs(simulate(str(second_drive(world, work)), SimulationParams(seed=2)), work / f"{world}-d2")
            cases.append(work / f"{world}-d2")
        write_outputs(simulate("office", SimulationParams(duration=40.0, seed=3)), work / "office-40s")
        cases.append(work / "office-40s")
        for d in cases:
            cells = []
            for seed in (0, 1, 2):
                rec = localize_recording(d / "truth-map.yaml", d / "recording.log.gz", work / "out", seed=seed).record
                if not rec["localized"]:
                    cells.append("never localized")
                    wrong_runs += 1
                    continue
                t, p = read_tum(work / "out" / "trajectory.tum")
                tt, tp = read_tum(d / "truth.tum")
                k = np.searchsorted(tt, t).clip(0, len(tt) - 1)
                err = np.hypot(p[:, 0] - tp[k, 0], p[:, 1] - tp[k, 1])
                wrong = float(np.mean(err > 0.5))
                wrong_runs += wrong > 0.01
                cells.append(f"seed {seed}: found {100 * rec['first_localized']['fraction_of_scans']:.0f} % in, "
                             f"median error {np.median(err):.3f} m, {100 * wrong:.0f} % wrong, lost {rec['lost']}x")
            print(f"{d.name}: " + " | ".join(cells), flush=True)
    print(f"runs with wrong poses: {wrong_runs} of {3 * len(cases)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
