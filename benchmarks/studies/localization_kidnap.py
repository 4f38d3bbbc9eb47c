#!/usr/bin/env python3
"""A kidnapped robot, scan by scan: what `slam2d localize` says after it was carried off, and why.

    .venv/bin/python benchmarks/studies/localization_kidnap.py [--world corridor-loop] [--method mcl]
        [--scans 120] [--every 1] [--at 0.5] [--work DIR] [--quiet] [NAME=VALUE ...]

The recording is benchmarks/localization.py's kidnap row: drive 2 of the world (seed 2) in its true map,
cut at the middle scan by `slam2d.sim.faults.kidnapped` so the robot resumes at the first later scan >= 4 m
away and turned > 1 rad, the odometry unaware. Printed for each scan from the kidnapping on: the state, the
reported (or best) pose's error against the truth, the fit (share of the matched beams within two cells of a
wall: what the lost test compares with its floor), the floor, the misfit counters, the mean log-likelihood
per beam at the reported pose and at the true pose (the beam model the filter and the search use), the
tracked pose's worst summed log-likelihood over the last 20-30 filter updates (what the doubt check looks at;
it checks the whole map under -3), the particles' spread and count, the share of the particles' weight near
the truth, and the challenger (mcl) with its lead, or while searching the hypotheses: how many, and the one
nearest the truth against the best other.
``--work DIR`` keeps the simulated drive there between runs; ``NAME=VALUE`` overrides a module constant of
slam2d.localization.localizer (as benchmarks/localization_search.py does); ``--quiet`` prints the outcome only.

What it showed (corridor-loop, carried 6.6 m at scan 318 from the east corridor heading south to the south-east
corner heading west): the match slid onto a twin at once (fit 0.97), and the scans fitted the twin (0.9-1.0, per
beam -0.01 to -0.1) for 50 scans: one straight corridor fits another. When the twin's corridor ended (scans
+52..+77) the fit fell from 0.8 to 0.23, but only 7 scans in a row under the lost floor (half the usual fit, 0.48),
short of `lost_after` (10), and the match slid onto another twin; once localized, mcl's particles stay around the
tracked pose (no random ones), so they never went near the truth. Localized 5-17 m off for the rest of the drive,
never lost. With the doubt check (LocalizationParams unchanged): lost at +58 (a place fits the last 30 updates
better by 3.1), found again after 162 scans (mcl; match 165): the twins along the south corridor stay within the
search's margin until the robot passes the pillar at x = 5 m. ``--at 0.3/0.4/0.6/0.7`` and ``--world office``:
kidnappings at other scans, 4-14 m (never found at HEAD: corridor-loop 0.4 and 0.6, office 0.6 and 0.7, the last
one's drive ending 48 scans after). Since matching may not move the pose further from the odometry's prediction than
the motion model allows (_REACH): lost 2 scans after landing (3 far misfits), found again after 162 (mcl and match);
the search's runner-ups then are twins 1-14 m off that its loosely matched paths keep within the margin.
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


def kidnapped_drive(world: str, work: Path, where: float = 0.5):
    """Drive 2 of ``world`` cut as kidnap_row cuts it (at its middle scan, or the share ``where`` of its scans):
    (frames, scan of the kidnapping, time shift, truth(t), map)."""
    from localization import second_drive
    from slam2d.io import open_recording
    from slam2d.io.tum import read_tum
    from slam2d.sim.faults import kidnapped
    from slam2d.sim.simulate import SimulationParams, simulate, write_outputs

    d2 = work / f"{world}-d2"
    if not (d2 / "recording.log.gz").is_file():
        write_outputs(simulate(str(second_drive(world, work)), SimulationParams(seed=2)), d2)
    frames = list(open_recording(d2 / "recording.log.gz").frames())
    tt, tp = read_tum(d2 / "truth.tum")

    def truth(t: float) -> np.ndarray:
        return tp[int(np.argmin(np.abs(tt - t)))]

    at = int(len(frames) * where)
    before = truth(frames[at - 1].timestamp)
    resume = next(k for k in range(at + 10, len(frames))
                  if np.hypot(*(truth(frames[k].timestamp)[:2] - before[:2])) >= 4.0
                  and abs(math.remainder(truth(frames[k].timestamp)[2] - before[2], math.tau)) > 1.0)
    moved, shift = kidnapped(frames, at, resume)
    print(f"{world}: carried from ({before[0]:.2f}, {before[1]:.2f}, {before[2]:.2f}) to "
          f"{np.round(truth(frames[resume].timestamp), 2).tolist()} "
          f"({np.hypot(*(truth(frames[resume].timestamp)[:2] - before[:2])):.1f} m) at scan {at}", flush=True)
    return moved, at, shift, truth, d2 / "truth-map.yaml"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--world", default="corridor-loop")
    parser.add_argument("--method", default="mcl", choices=("mcl", "match"))
    parser.add_argument("--scans", type=int, default=120, help="scans printed after the kidnapping")
    parser.add_argument("--before", type=int, default=5, help="scans printed before it")
    parser.add_argument("--every", type=int, default=1, help="print every n-th scan")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--at", type=float, default=0.5, help="kidnapped at this share of the scans (kidnap_row: 0.5)")
    parser.add_argument("--work", type=Path, help="keep the simulated drive here")
    parser.add_argument("--quiet", action="store_true", help="print the outcome only")
    parser.add_argument("settings", nargs="*", metavar="NAME=VALUE")
    args = parser.parse_args()
    import slam2d.localization.localizer as localizer

    for setting in args.settings:
        name, value = setting.split("=")
        setattr(localizer, name, float(value) if "." in value else int(value))

    from slam2d.io.map_server import read_map
    from slam2d.localization.localizer import LocalizationParams, Localizer

    with tempfile.TemporaryDirectory(prefix="slam2d-kidnap-") as tmp:
        work = args.work or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        frames, at, shift, truth, map_yaml = kidnapped_drive(args.world, work, args.at)
        loc = Localizer(read_map(map_yaml).to_grid(), LocalizationParams(method=args.method), seed=args.seed)
        print("scan  state      err_m  fit   floor mis far  ll_pose ll_true  doubt   spread  parts  w_true  challenger",
              flush=True)
        found = None
        for k, frame in enumerate(frames):
            r = loc.feed(frame)
            true = truth(frame.timestamp - (shift if k >= at else 0.0))
            pose = r.pose if r.pose is not None else loc.pose
            err = math.hypot(pose[0] - true[0], pose[1] - true[1]) if pose is not None else float("nan")
            if k >= at and found is None and r.state == "localized" and err < 0.3:
                found = k - at
            if args.quiet or not (at - args.before <= k < at + args.scans) or (k - at) % args.every:
                continue
            mx, my = loc._beams(frame.scan.points_in_base(), loc.p.match_beams)
            ll = loc._log_likelihoods(np.array([pose if pose is not None else true, true]), mx, my)
            floor = (max(loc.p.lost_fit, 0.5 * float(np.median(loc.recent_fits))) if loc.recent_fits
                     else loc.p.lost_fit)
            w_true = float("nan")
            if len(loc.particles):
                w = loc._weights()
                w_true = float(w[np.hypot(*(loc.particles[:, :2] - true[:2]).T) < 1.0].sum())
            c = loc.challenger
            cs = (f"({c['pose'][0]:.1f},{c['pose'][1]:.1f}) lead {c['lead']:.1f}/{c['updates']}" if c else "-")
            if loc.hypotheses:  # a search: how many places, and the one at the truth against the best other
                hs = loc.hypotheses
                d = [math.hypot(h["pose"][0] - true[0], h["pose"][1] - true[1]) for h in hs]
                i = int(np.argmin(d))
                others = [j for j in range(len(hs)) if j != i]
                j = max(others, key=lambda j: hs[j]["score"]) if others else None
                other = hs[j]["score"] if j is not None else float("nan")
                cs = (f"{len(hs)} places; nearest the truth {d[i]:.2f} m, rank {i + 1}, "
                      f"lead {hs[i]['score'] - other:+.1f} after {hs[i]['updates']}")
                if j is not None:  # the runner-up: how far from the truth, and turned how much
                    turn = math.degrees(math.remainder(hs[j]["pose"][2] - true[2], math.tau))
                    cs += f"; next {d[j]:.1f} m off, turned {turn:+.0f} deg"
            # the doubt check's trigger: the tracked pose's worst summed log-likelihood over the last 20-30 updates
            track = np.array(getattr(loc, "track_ll", []))[::-1]
            doubt = float(np.min(np.cumsum(track)[19:])) if len(track) >= 20 else float("nan")
            print(f"{k - at:+4d}  {r.state:9s} {err:6.2f}  {r.fit:.2f}  {floor:.2f}  {loc.misfits:2d}  "
                  f"{loc.far_misfits:2d} {ll[0]:8.3f} {ll[1]:7.3f} {doubt:7.2f}  {r.spread:6.2f} {r.particles:6d}  "
                  f"{w_true:.2f}  {cs}", flush=True)
        print(f"found again (localized within 0.3 m) after {found} scans; events after the kidnapping:")
        t_at = frames[at].timestamp
        for e in loc.events:
            if e["time"] is not None and e["time"] >= t_at:
                print(f"  {e['time'] - t_at:+7.1f} s  {e['state']}: {e['why']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
