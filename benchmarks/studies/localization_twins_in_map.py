#!/usr/bin/env python3
"""How far the scans put corridor-loop's second drive ahead of its twins, in the true map and in karto's map.

    .venv/bin/python benchmarks/studies/localization_twins_in_map.py [--world corridor-loop] [--scans 45,90,...]

The drives are benchmarks/localization.py's (drive 1 seed 1 mapped by karto with its defaults, drive 2 seed
2). At each listed scan the second drive's true pose (in karto's map: moved into the map's frame by the
SE(2) fit of karto's drive-1 trajectory to the truth) is traced back over the filter updates so far, matched
to the map at each step, as `slam2d localize` scores a hypothesis; the whole-map check's best places over
1 m away are traced the same way. Printed: the truth's lead over the best of them in summed log-likelihood
(the search needs 3). A lead that stays under 3 in karto's map but not in the true one means the map of the
first drive lacks what tells the places apart.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT / "benchmarks"))


def main() -> int:
    from localization import frame_of, second_drive
    from localization_bound import filter_updates

    import slam2d.localization.localizer as lz
    from slam2d.core import se2
    from slam2d.io import open_recording
    from slam2d.io.map_server import read_map
    from slam2d.io.tum import read_tum
    from slam2d.methods.runner import run_method
    from slam2d.sim.simulate import SimulationParams, simulate, write_outputs

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--world", default="corridor-loop")
    ap.add_argument("--scans", default="45,90,135,180,225,270")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="slam2d-twins-") as tmp:
        work = Path(tmp)
        d1, d2, karto = work / "d1", work / "d2", work / "karto"
        write_outputs(simulate(args.world, SimulationParams(seed=1)), d1)
        write_outputs(simulate(str(second_drive(args.world, work)), SimulationParams(seed=2)), d2)
        run_method("karto", d1 / "recording.log.gz", karto)
        frames = list(open_recording(d2 / "recording.log.gz").frames())
        tt, tp = read_tum(d2 / "truth.tum")
        truth = tp[np.searchsorted(tt, [f.timestamp for f in frames]).clip(0, len(tt) - 1)]
        in_karto = se2.compose(se2.inverse(frame_of(karto / "trajectory.tum", d1 / "truth.tum")), truth)
        for label, source, path in (("true map", d2 / "truth-map.yaml", truth),
                                    ("karto map of drive 1", karto / "map.yaml", in_karto)):
            cells = []
            for n in (int(v) for v in args.scans.split(",")):
                loc = lz.Localizer(read_map(source).to_grid(), lz.LocalizationParams(), seed=0)
                for i, frame in filter_updates(frames[: n + 1], loc.p):
                    loc.search_scans.append((np.asarray(frame.odometry, dtype=np.float64),
                                             *loc._beams(frame.scan.points_in_base(), loc.p.match_beams)))
                points = frames[n].scan.points_in_base()
                own = loc._path_score(path[n])
                rivals = loc._unseen_rivals(-math.inf, *loc._beams(points, loc.p.beams),
                                            *loc._beams(points, loc.p.match_beams))
                far = [r for r in rivals if math.hypot(*(r["pose"][:2] - path[n][:2])) > 1.0
                       or abs(math.remainder(r["pose"][2] - path[n][2], math.tau)) > 0.3]
                best = max(far, key=lambda r: r["score"]) if far else None
                cells.append(f"scan {n}: " + (f"lead {own - best['score']:.2f} over ({best['pose'][0]:.1f}, "
                                              f"{best['pose'][1]:.1f}, {math.degrees(best['pose'][2]):.0f} deg)"
                                              if best else "no other place fits"))
            print(f"{label}: " + "; ".join(cells), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
