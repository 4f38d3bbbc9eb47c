"""Localization benchmark (issue 34): `slam2d localize` in a map made by another drive.

Simulated worlds: drive 1 (the world's path, seed 1) is mapped by karto with its defaults and with
params/karto-short-range.yaml (its setting for a short-range laser, as the simulated URG-04LX); drive 2
(another seed, starting half-way along the path and driving it backwards) is localized in that map
and in the world's true map, with no initial pose. ATE is the localized poses' error against the
truth, in the map's frame as drive 1 fixes it (the SE(2) alignment of karto's drive-1 trajectory to
its truth; no alignment of drive 2's own). A kidnapping: drive 2 in the true map with the robot carried
at least 4 m, to where it faces another way, odometry unaware: scans until found again (localized within
0.3 m). Real data: the second half of fr079, intel, aces, csail and fr101 localized in karto's and gmapping's maps of its first half, against the
log's reference (GMapping-corrected, not independent truth). CPU per scan excludes compilation.

    .venv/bin/python benchmarks/localization.py [--write BENCHMARKS.md]
    .venv/bin/python benchmarks/localization.py --set lost_after=3   # a candidate setting, every row
    .venv/bin/python benchmarks/localization.py --set _SEARCH_PRIOR_XY=10.0 --set _REACH=0.5,0.15  # constants
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT / "benchmarks"))

from defaults import emit_section  # noqa: E402

SHARED = ROOT.parent / "shared" / "datasets"
SHORT_RANGE = ROOT / "params" / "karto-short-range.yaml"
SECTION = ("<!-- BEGIN localization (benchmarks/localization.py --write) -->", "<!-- END localization -->")


def second_drive(world: str, out: Path) -> Path:
    """The world with the robot starting half-way along its path and driving back along it."""
    w = yaml.safe_load((ROOT / "src" / "slam2d" / "sim" / "worlds" / f"{world}.yaml").read_text())
    path = [[float(v) for v in p] for p in w["path"]]
    first_start = [float(v) for v in w["start"][:2]]
    k = len(path) // 2
    start, towards = path[k], path[k - 1]
    w["start"] = [start[0], start[1], math.atan2(towards[1] - start[1], towards[0] - start[0])]
    w["path"] = path[k - 1::-1] + [first_start]
    w["name"] = f"{world}-second-drive"
    target = out / f"{world}-2.yaml"
    target.write_text(yaml.safe_dump(w))
    return target


def frame_of(run_traj: Path, truth: Path) -> np.ndarray:
    from slam2d.eval.trajectory_metrics import absolute_trajectory_error, associate
    from slam2d.io.tum import read_tum

    return np.asarray(absolute_trajectory_error(associate(*read_tum(run_traj), *read_tum(truth)))["alignment"])


def ate_in_frame(traj: Path, truth: Path, frame: np.ndarray | None, shift: float = 0.0) -> float:
    from slam2d.core import se2
    from slam2d.eval.trajectory_metrics import absolute_trajectory_error, associate
    from slam2d.io.tum import read_tum

    t, p = read_tum(traj)
    if frame is not None:
        p = se2.compose(frame, p)
    return float(absolute_trajectory_error(associate(t - shift, p, *read_tum(truth)), align=False)["translation_m"]["rmse"])


def errors_at(traj: Path, truth: Path, frame: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Each pose of ``traj`` (moved by ``frame``) against ``truth`` at its time: the error vectors and the true
    positions."""
    from slam2d.core import se2
    from slam2d.io.tum import read_tum

    t, p = read_tum(traj)
    if frame is not None:
        p = se2.compose(frame, p)
    tt, tp = read_tum(truth)
    k = np.searchsorted(tt, t).clip(0, len(tt) - 1)
    return p[:, :2] - tp[k, :2], tp[k, :2]


def map_error_floor(map_run: Path, map_truth: Path, traj: Path, truth: Path, frame: np.ndarray | None) -> float:
    """What a perfect localizer in ``map_run``'s map would score: the RMS of the map's own error (its run's pose
    against the truth) at the map-run pose nearest each pose of ``traj``. A localizer that agrees with the map
    inherits its error there."""
    map_err, map_at = errors_at(map_run / "trajectory.tum", map_truth, frame)
    _, at = errors_at(traj, truth, frame)
    nearest = np.argmin(np.hypot(at[:, 0][:, None] - map_at[:, 0][None], at[:, 1][:, None] - map_at[:, 1][None]), axis=1)
    return float(np.sqrt(np.mean(np.sum(map_err[nearest] ** 2, axis=1))))


def map_offset(map_source: Path, data: Path, out: Path, truth: Path, frame: np.ndarray | None) -> str:
    """The map's disagreement with the truth as the scans see it: each localized scan of ``out`` matched into the map
    from its true pose (``truth`` moved into the map's frame), the RMS and median of how far matching moves it. Where
    the map's walls sit off the truth the scan fits them off it too, and a localizer that agrees with the map errs
    as much; a scan that fits the map poorly can slide further (an RMS over the localizer's)."""
    import csv

    from slam2d.core import se2
    from slam2d.io import open_recording
    from slam2d.io.map_server import load_map_grid
    from slam2d.io.tum import read_tum
    from slam2d.localization.localizer import Localizer

    localizer = Localizer(load_map_grid(map_source)[0])
    tt, tp = read_tum(truth)
    if frame is not None:  # the truth in the map's frame
        tp = se2.compose(se2.inverse(frame), tp)
    with open(out / "localization.csv", newline="") as f:
        localized = {round(float(r["time"]), 6) for r in csv.DictReader(f) if r["state"] == "localized"}
    offsets = []
    for fr in open_recording(data).frames():
        if round(fr.timestamp, 6) not in localized:
            continue
        true_pose = tp[min(int(np.searchsorted(tt, fr.timestamp)), len(tt) - 1)]
        matched, _ = localizer.match(fr.scan, true_pose)
        offsets.append(math.hypot(matched[0] - true_pose[0], matched[1] - true_pose[1]))
    if not offsets:
        return "-"
    return f"{np.sqrt(np.mean(np.square(offsets))):.3f} m (median {np.median(offsets):.3f} m)"


#: localizer settings to measure instead of the defaults (``--set NAME=VALUE``)
OVERRIDES: dict[str, object] = {}


def localize(map_source: Path, data: Path, out: Path, method: str) -> dict:
    from slam2d.localization.localizer import LocalizationParams
    from slam2d.localization.run import localize_recording

    params = LocalizationParams(method=method, **OVERRIDES)
    return localize_recording(map_source, data, out, params=params).record


def sim_rows(world: str, work: Path) -> list[str]:
    from slam2d.methods.runner import run_method
    from slam2d.sim.simulate import SimulationParams, simulate, write_outputs

    d1, d2 = work / f"{world}-d1", work / f"{world}-d2"
    write_outputs(simulate(world, SimulationParams(seed=1)), d1)
    write_outputs(simulate(str(second_drive(world, work)), SimulationParams(seed=2)), d2)
    run_method("karto", d1 / "recording.log.gz", work / f"{world}-karto")
    # karto's setting for a short-range laser in a building of straight walls (docs/methods/karto.md), as the
    # simulated URG-04LX is: a map of drive 1 as good as karto makes it
    run_method("karto", d1 / "recording.log.gz", work / f"{world}-karto-short-range", params_file=SHORT_RANGE)
    rows = []
    for label, map_source, fr in (
            ("karto map of drive 1", work / f"{world}-karto",
             frame_of(work / f"{world}-karto" / "trajectory.tum", d1 / "truth.tum")),
            ("karto map of drive 1, `params/karto-short-range.yaml`", work / f"{world}-karto-short-range",
             frame_of(work / f"{world}-karto-short-range" / "trajectory.tum", d1 / "truth.tum")),
            ("true map", d1 / "truth-map.yaml", None)):
        for method in ("mcl", "match"):
            out = work / f"{world}-{method}-{len(rows)}"
            rec = localize(map_source, d2 / "recording.log.gz", out, method)
            if not rec["localized"]:
                rows.append(f"| {world} | {label} | `{method}` | never | - | - | {rec['cpu_ms_per_scan']['median']:.1f} |")
                continue
            floor = "" if fr is None else (
                f" (the map's own error there "
                f"{map_error_floor(map_source, d1 / 'truth.tum', out / 'trajectory.tum', d2 / 'truth.tum', fr):.3f} m, "
                f"at the scans {map_offset(map_source, d2 / 'recording.log.gz', out, d2 / 'truth.tum', fr)})")
            rows.append(f"| {world} | {label} | `{method}` | {100 * rec['first_localized']['fraction_of_scans']:.0f} % | "
                        f"{ate_in_frame(out / 'trajectory.tum', d2 / 'truth.tum', fr):.3f} m{floor} | {rec['lost']} | "
                        f"{rec['cpu_ms_per_scan']['median']:.1f} |")
            print(rows[-1], file=sys.stderr, flush=True)
    rows.append(kidnap_row(world, d2, work))
    print(rows[-1], file=sys.stderr, flush=True)
    for method, short_range in (("karto", False), ("karto", True), ("gmapping", False)):
        CONTINUE_ROWS.append(continue_row(method, world, d1, d2, work, short_range))
        print(CONTINUE_ROWS[-1], file=sys.stderr, flush=True)
    return rows


CONTINUE_ROWS: list[str] = []


def map_error(run: Path, truth: Path) -> float:
    from slam2d.eval.evaluate import evaluate_run, load_run, load_truth

    return float(evaluate_run(load_run(run), load_truth(truth))["map_truth"]["truth_to_map_m"]["mean"])


def continue_row(method: str, world: str, d1: Path, d2: Path, work: Path, short_range: bool = False) -> str:
    """``method``'s run of drive 1 resumed with drive 2 (no initial pose): where it was placed, its ATE, the maps.
    ``short_range``: karto with ``params/karto-short-range.yaml`` (its run of drive 1 made by :func:`sim_rows`)."""
    import json

    from slam2d.methods.runner import resume_run, run_method

    name = f"{method}-short-range" if short_range else method
    first, out = work / f"{world}-{name}-1", work / f"{world}-{name}-resumed"
    if method != "karto":
        run_method(method, d1 / "recording.log.gz", first)
    else:
        first = work / f"{world}-{name}"
    frame = frame_of(first / "trajectory.tum", d1 / "truth.tum")
    try:
        resume_run(method, first, d2 / "recording.log.gz", out)
    except Exception as exc:  # noqa: BLE001 - a row says what happened
        return f"| {world} | `{method}` | failed: {exc} | | | |"
    rec = json.loads((out / "run.json").read_text())["resumed"]
    first_ate = ate_in_frame(first / "trajectory.tum", d1 / "truth.tum", frame)
    floor = map_error_floor(first, d1 / "truth.tum", out / "trajectory.tum", d2 / "truth.tum", frame)
    # the peer: the same method on drive 2 alone, from scratch
    alone = work / f"{world}-{name}-2-alone"
    run_method(method, d2 / "recording.log.gz", alone, params_file=SHORT_RANGE if short_range else None)

    def own_ate(run: Path) -> float:
        return ate_in_frame(run / "trajectory.tum", d2 / "truth.tum", frame_of(run / "trajectory.tum", d2 / "truth.tum"))

    left_out = f", {rec['scans_before_placed']} left out" if rec["scans_before_placed"] else ""
    label = f"`{method}`, `params/karto-short-range.yaml`" if short_range else f"`{method}`"
    return (f"| {world} | {label} | {rec['found_at_scan']}{left_out} | "
            f"{ate_in_frame(out / 'trajectory.tum', d2 / 'truth.tum', frame):.3f} m (drive 1: {first_ate:.3f} m; "
            f"drive 1's error where drive 2 drives: {floor:.3f} m) | {own_ate(out):.3f} m ({own_ate(alone):.3f} m) | "
            f"{map_error(first, d1):.3f} m | {map_error(out, d2):.3f} m ({map_error(alone, d2):.3f} m) |")


def kidnap_row(world: str, d2: Path, work: Path) -> str:
    import csv

    from slam2d.io import open_recording
    from slam2d.io.carmen import write_carmen
    from slam2d.io.tum import read_tum
    from slam2d.sim.faults import kidnapped

    frames = list(open_recording(d2 / "recording.log.gz").frames())
    tt, tp = read_tum(d2 / "truth.tum")

    def truth(t: float) -> np.ndarray:
        return tp[int(np.argmin(np.abs(tt - t)))]

    at = len(frames) // 2
    before = truth(frames[at - 1].timestamp)
    resume = next((k for k in range(at + 10, len(frames))
                   if np.hypot(*(truth(frames[k].timestamp)[:2] - before[:2])) >= 4.0
                   and abs(math.remainder(truth(frames[k].timestamp)[2] - before[2], math.tau)) > 1.0), None)
    if resume is None:
        return f"| {world} | true map, kidnapped | - | no place 4 m away facing another way | - | - | - |"
    moved, shift = kidnapped(frames, at, resume)
    write_carmen(work / f"{world}-kidnapped.log", moved)
    cells = []
    for method in ("mcl", "match"):
        out = work / f"{world}-kidnapped-{method}"
        rec = localize(d2 / "truth-map.yaml", work / f"{world}-kidnapped.log", out, method)
        rows = list(csv.DictReader((out / "localization.csv").open()))
        found = None
        for k in range(at, len(rows)):
            r = rows[k]
            if r["state"] == "localized":
                p = truth(float(r["time"]) - shift)
                if math.hypot(float(r["x"]) - p[0], float(r["y"]) - p[1]) < 0.3 and all(
                        q["state"] == "localized" for q in rows[k:k + 10]):
                    found = k - at
                    break
        cells.append(f"`{method}`: {'never' if found is None else f'{found} scans'} (lost {rec['lost']}x)")
    jump = float(np.hypot(*(truth(frames[resume].timestamp)[:2] - before[:2])))
    return f"| {world} | true map, carried {jump:.1f} m at scan {at} | found again after | {'; '.join(cells)} | - | - | - |"


#: the real logs whose second half is localized in a map of the first (the issue's target is fr079's)
REAL_LOGS = ("fr079", "intel", "aces", "csail", "fr101")
#: ... made by these methods with their defaults (gmapping's seed 0; the logs' reference is a GMapping result too,
#: from another implementation)
MAP_MAKERS = ("karto", "gmapping")


def split_halves(name: str, work: Path) -> tuple[int, int] | None:
    """A shared log's two halves written as ``work/NAME-1.log`` and ``NAME-2.log``: its scan count and the first
    half's, or None when the log is not in ../shared/datasets."""
    from slam2d.io import open_recording
    from slam2d.io.carmen import write_carmen

    log = SHARED / name / f"{name}.clf.gz"
    if not log.is_file():
        return None
    frames = list(open_recording(log).frames())
    half = len(frames) // 2
    write_carmen(work / f"{name}-1.log", frames[:half])
    write_carmen(work / f"{name}-2.log", frames[half:])
    return len(frames), half


def real_rows(work: Path) -> list[str]:
    from slam2d.methods.runner import run_method

    rows = []
    for name in REAL_LOGS:
        split = split_halves(name, work)
        if split is None:
            rows.append(f"| {name} | (not in ../shared/datasets) | | | | | |")
            continue
        total, half = split
        ref = SHARED / name / "reference.tum"
        for maker in MAP_MAKERS:
            map_run = work / f"{name}-{maker}"
            run_method(maker, work / f"{name}-1.log", map_run)
            frame = frame_of(map_run / "trajectory.tum", ref)
            for method in ("mcl", "match"):
                out = work / f"{name}-{maker}-{method}"
                rec = localize(map_run, work / f"{name}-2.log", out, method)
                label = f"| {name} (2nd half, {total - half} scans) | {maker} map of the 1st half | `{method}` |"
                if not rec["localized"]:
                    rows.append(f"{label} never | - | {rec['lost']} | {rec['cpu_ms_per_scan']['median']:.1f} |")
                    continue
                ate = ate_in_frame(out / "trajectory.tum", ref, frame)
                err = np.hypot(*errors_at(out / "trajectory.tum", ref, frame)[0].T)
                # the reference is one trajectory through both halves: the truth for the map run and the localizer
                floor = map_error_floor(map_run, ref, out / "trajectory.tum", ref, frame)
                offset = map_offset(map_run, work / f"{name}-2.log", out, ref, frame)
                rows.append(f"{label} {100 * rec['first_localized']['fraction_of_scans']:.0f} % | {ate:.3f} m (median "
                            f"{np.median(err):.3f} m, {100 * np.mean(err < 0.3):.0f} % within 0.3 m; the map's own error "
                            f"there {floor:.3f} m, at the scans {offset}; {rec['localized_scans']} scans localized, "
                            f"{rec['off_map_scans']} off the map) | {rec['lost']} | {rec['cpu_ms_per_scan']['median']:.1f} |")
                print(rows[-1], file=sys.stderr, flush=True)
            if maker == "karto":
                REAL_CONTINUE_ROWS.append(real_continue_row(name, map_run, work / f"{name}-2.log", ref, frame, work))
                print(REAL_CONTINUE_ROWS[-1], file=sys.stderr, flush=True)
    return rows


REAL_CONTINUE_ROWS: list[str] = []

#: logs without a reference whose second half drives a room the first half never saw (karto and gmapping on the
#: whole log agree): a localizer should not place it in the first half's rooms
UNMAPPED_LOGS = ("mines-exp1", "mines-exp2")


def unmapped_rows(work: Path) -> list[str]:
    from slam2d.methods.runner import run_method

    rows = []
    for name in UNMAPPED_LOGS:
        split = split_halves(name, work)
        if split is None:
            rows.append(f"| {name} | (not in ../shared/datasets) | | | | | |")
            continue
        total, half = split
        run_method("karto", work / f"{name}-1.log", work / f"{name}-karto")
        for method in ("mcl", "match"):
            rec = localize(work / f"{name}-karto", work / f"{name}-2.log", work / f"{name}-{method}", method)
            refused = sum("runs through the map's walls" in e["why"] for e in rec["events"])
            placed = f"{rec['localized_scans']} scans localized" if rec["localized"] else "never"
            rows.append(f"| {name} (2nd half, {total - half} scans; no reference) | karto map of the 1st half | "
                        f"`{method}` | {placed} | - (the 2nd half drives a room the 1st never saw; {refused} places "
                        f"refused, their paths through the map's walls) | {rec['lost']} | "
                        f"{rec['cpu_ms_per_scan']['median']:.1f} |")
            print(rows[-1], file=sys.stderr, flush=True)
    return rows


def real_continue_row(name: str, map_run: Path, second: Path, ref: Path, frame: np.ndarray, work: Path) -> str:
    """karto's run of the 1st half resumed with the 2nd half: ATE in the 1st half's frame, with the map anchors and
    without them (every anchor refused), against the map's own error there and karto on the 2nd half alone."""
    import json

    import slam2d.graph.frontend as frontend
    from slam2d.methods.runner import resume_run, run_method

    gate = frontend.MAP_ANCHOR_GATE
    anchored, unanchored = work / f"{name}-resumed-anchored", work / f"{name}-resumed-no-anchors"
    for out, g in ((anchored, gate), (unanchored, 0.0)):  # a zero gate refuses every anchor
        frontend.MAP_ANCHOR_GATE = g
        try:
            resume_run("karto", map_run, second, out)
        finally:
            frontend.MAP_ANCHOR_GATE = gate
    anchors = json.loads((anchored / "diagnostics.json").read_text())["counters"].get("map_anchors", 0)
    cells = [f"{ate_in_frame(anchored / 'trajectory.tum', ref, frame):.3f} m ({anchors} anchors)",
             f"{ate_in_frame(unanchored / 'trajectory.tum', ref, frame):.3f} m"]
    floor = map_error_floor(map_run, ref, anchored / "trajectory.tum", ref, frame)
    alone = work / f"{name}-karto-2-alone"
    run_method("karto", second, alone)
    own = ate_in_frame(alone / "trajectory.tum", ref, frame_of(alone / "trajectory.tum", ref))
    return f"| {name} | {cells[0]} | {cells[1]} | {floor:.3f} m | {own:.3f} m |"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--worlds", default="office,corridor-loop")
    parser.add_argument("--no-real", action="store_true", help="skip the real logs")
    parser.add_argument("--write", type=Path, metavar="BENCHMARKS.md")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                        help="a localizer setting to measure instead of its default (not with --write)")
    args = parser.parse_args()
    if args.set and args.write:
        parser.error("--set measures a candidate; the table in BENCHMARKS.md is the defaults'")
    from slam2d.localization.localizer import LocalizationParams

    import slam2d.localization.localizer as localizer

    defaults = LocalizationParams()
    for item in args.set:
        name, _, value = item.partition("=")
        if name.startswith("_") and hasattr(localizer, name):  # a module constant of the localizer
            current = getattr(localizer, name)
            setattr(localizer, name, tuple(float(v) for v in value.split(",")) if isinstance(current, tuple)
                    else type(current)(value))
            continue
        if not hasattr(defaults, name):
            parser.error(f"--set {item}: LocalizationParams has no field {name!r}")
        OVERRIDES[name] = type(getattr(defaults, name))(value)
    rows = ["| recording | map | method | localized from (share of scans in) | ATE after | times lost | CPU ms/scan (median) |",
            "|---|---|---|---|---|---|---|"]
    with tempfile.TemporaryDirectory(prefix="slam2d-localization-") as tmp:
        work = Path(tmp)
        for world in args.worlds.split(","):
            rows += sim_rows(world, work)
        if not args.no_real:
            rows += real_rows(work)
            rows += unmapped_rows(work)
    intro = ("`slam2d localize` with no initial pose (defaults: `mcl` 100-5000 particles; `match`), "
             "targets from issue 34: ATE < 0.05 m after convergence, localized within the first 20 % of the scans, "
             "< 10 ms (mcl) / < 5 ms (match) CPU per scan, found again within 50 scans of a kidnapping; fr079 < 0.10 m. "
             "The real logs' reference is a GMapping result, not independent truth; the shared intel, aces, csail and fr101 "
             "logs hold a scan every 0.5-3.4 s (fr079 0.23 s). "
             "Drive 2 of each world starts half-way along the path and drives it backwards (seed 2); its map is karto's "
             "(defaults, or with its setting for a short-range laser as the simulated URG-04LX) of drive 1 (seed 1), or "
             "the world's true map. ATE in the map's frame as drive 1 fixes it. "
             "The map's own error there (drive 1's RMS error at its poses nearest drive 2's) is what a localizer "
             "that agrees with the map perfectly would score; at the scans: each localized scan matched into the map "
             "from its true pose, how far matching moves it (RMS and median): where the map's walls sit off the truth, "
             "as they do far from the run that mapped them, the scan fits them off it too. The Mines logs have no "
             "reference; their second halves drive a room the first half never saw (karto and gmapping on the whole "
             "log agree), in rooms of rough rock walls alike: a localizer should not place them.")
    rows += ["", "Continue mapping (`slam2d run METHOD DRIVE2 --resume DRIVE1_RUN`, no initial pose; the settings of drive 1's run): the scan "
             "of drive 2 at which it was found in drive 1's map (the scans before it traced back and mapped too), "
             "drive 2's ATE in drive 1's frame and with its own alignment, and the map error (mean distance from a "
             "true wall cell to the map's nearest) of drive 1's map and of the joined map (target: ATE < 0.10 m, "
             "joined map no worse). In brackets, the peer: the same method on drive 2 alone, from scratch.", "",
             "| world | method | found at scan | drive 2 ATE in drive 1's frame | drive 2 ATE, own alignment (alone) | "
             "drive 1 map error | joined map error (drive 2 alone) |",
             "|---|---|---|---|---|---|---|", *CONTINUE_ROWS]
    if REAL_CONTINUE_ROWS:
        rows += ["", "Continue mapping on the real logs: karto's run of the 1st half resumed with the 2nd half (defaults), "
                 "the 2nd half's ATE in the 1st half's frame against the log's reference, with the map anchors (the "
                 "localization in the 1st half's map holding the new nodes where it places them) and without; the map's "
                 "own error where the 2nd half drives; karto on the 2nd half alone (its own alignment).", "",
                 "| log | ATE, anchored | ATE, no anchors | the map's own error there | karto alone, own alignment |",
                 "|---|---|---|---|---|", *REAL_CONTINUE_ROWS]
    from datetime import datetime, timezone

    when = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    emit_section(*SECTION, "Localization", f"{intro} Measured {when}; command: "
                 "`.venv/bin/python benchmarks/localization.py --write BENCHMARKS.md`.", rows, args.write)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
