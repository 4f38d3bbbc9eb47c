"""Benchmark cases. ``python benchmarks/cases.py NAME WORKDIR`` runs one and prints JSON.

A case is a function that does the work and returns the seconds it measured
(or None to let the runner time the whole process) and an optional note. Add
a case by writing the function and listing it in ``CASES``.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "datasets"
SHARED = "../shared/datasets"


@dataclass(frozen=True)
class Case:
    name: str
    what: str
    run: Callable[[Path], tuple[float | None, str]]
    target: str = ""
    max_seconds: float | None = None
    max_peak_mb: float | None = None
    needs: tuple[str, ...] = ()
    warmup: bool = True
    repeat: int | None = None


def _read_all(path: Path) -> tuple[float, str]:
    from slam2d.io import open_recording

    t0 = time.perf_counter()
    rec = open_recording(path)
    n = beams = 0
    for frame in rec.frames():
        n += 1
        beams += frame.scan.num_beams
    dt = time.perf_counter() - t0
    return dt, f"{n} scans, {beams} beams"


def read_fr079(_: Path) -> tuple[float, str]:
    return _read_all(DATA / "fr079" / "fr079.clf.gz")


def _reader_case(rel: str) -> Callable[[Path], tuple[float, str]]:
    def run(_: Path) -> tuple[float, str]:
        return _read_all(DATA / rel)

    return run


def _slam2d(*args: str) -> None:
    subprocess.run([str(Path(sys.executable).with_name("slam2d")), *args], check=True, capture_output=True)


def map_fr079(workdir: Path) -> tuple[None, str]:
    _slam2d(
        "map", str(DATA / "fr079" / "fr079.clf.gz"),
        "--poses", str(DATA / "fr079" / "reference.tum"),
        "--resolution", "0.05", "--out", str(workdir / "fr079-map"),
    )
    info = json.loads((workdir / "fr079-map" / "map.json").read_text())
    wt = info["wall_thickness_cells"]
    return None, f"{info['size_cells'][0]}x{info['size_cells'][1]} cells, wall thickness median {wt['median']:g} cells"


def compare_fr079(workdir: Path) -> tuple[None, str]:
    """The whole `slam2d compare` command with both baselines on fr079; the report's share noted."""
    import re

    out = workdir / "compare-fr079"
    proc = subprocess.run(
        [str(Path(sys.executable).with_name("slam2d")), "compare", str(DATA / "fr079" / "fr079.clf.gz"),
         "--methods", "odometry,known-poses", "--reference", str(DATA / "fr079" / "reference.tum"),
         "--out", str(out)],
        check=True, capture_output=True, text=True,
    )
    report = re.search(r"report written in ([0-9.]+) s", proc.stdout)
    size = (out / "report.html").stat().st_size / 1e6
    return None, f"report rendering {report.group(1) if report else '?'} s of it; report.html {size:.1f} MB"


def map_intel_kernel(_: Path) -> tuple[float, str]:
    """Mapping alone (reading excluded): the compiled ray caster's throughput."""
    from slam2d.grids.mapping import map_from_poses
    from slam2d.grids.occupancy import GridParams
    from slam2d.io import open_recording
    from slam2d.io.tum import read_tum

    frames = list(open_recording(DATA / "intel" / "intel.clf.gz").frames())
    t, poses = read_tum(DATA / "intel" / "reference.tum")
    t0 = time.perf_counter()
    grid, stats = map_from_poses(frames, t, poses, params=GridParams(resolution=0.05))
    dt = time.perf_counter() - t0
    rays = sum(int(f.scan.valid.sum()) for f in frames)
    return dt, f"{stats.scans_used} scans, {rays / dt / 1e6:.1f} M rays/s"


def numba_compile(_: Path) -> tuple[float, str]:
    """Cold compile of the grid kernels (numba's on-disk cache disabled for this process)."""
    import os

    os.environ["NUMBA_CACHE_DIR"] = str(Path(_) / "numba-cold-cache")
    import numpy as np

    t0 = time.perf_counter()
    from slam2d.grids.occupancy import GridParams, OccupancyGrid

    grid = OccupancyGrid(GridParams(resolution=0.05))
    from slam2d.core import make_scan

    scan = make_scan(0.0, np.full(360, 3.0), -np.pi / 2, np.pi / 359, 0.0, 80.0)
    grid.integrate(scan, np.zeros(3))
    return time.perf_counter() - t0, "first call of the ray caster, compile included"


def _write_fr079_bag(workdir: Path) -> Path:
    bag = workdir / "fr079-ros2"
    if not bag.exists():
        from slam2d.io import open_recording
        from slam2d.io.rosbag import write_rosbag

        write_rosbag(bag, open_recording(DATA / "fr079" / "fr079.clf.gz").frames())
    return bag


def read_ros2_fr079(workdir: Path) -> tuple[float, str]:
    return _read_all(_write_fr079_bag(workdir))


def simulate_office(workdir: Path) -> tuple[float, str]:
    """Ten minutes of driving in `office`, simulation and every output file."""
    from slam2d.sim.simulate import SimulationParams, simulate, write_outputs

    t0 = time.perf_counter()
    sim = simulate("office", SimulationParams(duration=600.0, seed=1))
    t1 = time.perf_counter()
    write_outputs(sim, workdir / "office")
    t2 = time.perf_counter()
    return t2 - t0, f"{len(sim.scans)} scans; simulate {t1 - t0:.2f} s, write outputs {t2 - t1:.2f} s"


def _hector_run(data: Path, out: Path, *settings: str) -> tuple[float, list[float]]:
    """`hector` on a recording in this process: (CPU seconds of the updates, per-scan CPU seconds).

    Reading is excluded; the run folder is written to ``out`` for evaluation.
    """
    from slam2d.io import open_recording
    from slam2d.io.tum import write_tum
    from slam2d.methods.runner import build_method

    frames = list(open_recording(data).frames())
    values = dict(kv.split("=", 1) for kv in settings)
    build_method("hector", settings=values).run(frames[:20])  # numba's cache load is not the method's cost
    slam = build_method("hector", settings=values)
    t0 = time.process_time()
    slam.run(frames)
    cpu = time.process_time() - t0
    out.mkdir(parents=True, exist_ok=True)
    times, poses = slam.trajectory()
    write_tum(out / "trajectory.tum", times, poses)
    return cpu, slam.diagnostics.series["cpu_s"]


def hector_mines_speed(workdir: Path) -> tuple[float, str]:
    """CPU time of `hector` over mines-exp1 (no odometry), and its per-scan latency."""
    import statistics

    cpu, per_scan = _hector_run(DATA / "mines-exp1" / "mines-exp1.clf.gz", workdir / "hector-mines")
    ms = sorted(v * 1e3 for v in per_scan)
    p95 = ms[int(0.95 * (len(ms) - 1))]
    return cpu, f"{len(ms)} scans of 682 beams; per scan median {statistics.median(ms):.2f} ms, p95 {p95:.2f} ms (CPU)"


def hector_long_corridor(workdir: Path) -> tuple[None, str]:
    """`long-corridor` simulated, `hector` with odometry: ATE against the truth, degeneracy flags."""
    import numpy as np

    sim = workdir / "long-corridor"
    if not (sim / "truth.tum").is_file():
        _slam2d("simulate", "long-corridor", "--out", str(sim), "--seed", "0")
    out = {}
    for name, extra in (("odometry", ["--set", "use_odometry=true"]), ("blind", [])):
        run = workdir / f"hector-corridor-{name}"
        _slam2d("run", "hector", str(sim / "recording.log.gz"), "--out", str(run), *extra)
        _slam2d("evaluate", str(run), "--truth", str(sim))
        ev = json.loads((run / "evaluation.json").read_text())
        diag = json.loads((run / "diagnostics.json").read_text())["series"]
        truth_x = np.loadtxt(sim / "truth.tum")[:, 1]
        flags = np.array([np.nan if v is None else v for v in diag["degenerate"]])
        # the featureless stretch: more than the laser's 5.6 m from both ends of the 30 m corridor
        middle = (truth_x[: len(flags)] > 6.0) & (truth_x[: len(flags)] < 24.0)
        out[name] = (ev["trajectory"]["ate"]["translation_m"]["rmse"], np.nanmean(flags[middle]),
                     np.nanmean(flags[~middle]))
    (ate, mid, ends), (ate_blind, mid_b, _) = out["odometry"], out["blind"]
    return None, (f"with odometry ATE {ate:.3f} m, degenerate flagged on {100 * mid:.0f} % of the featureless "
                  f"stretch, {100 * ends:.0f} % near the ends; without odometry ATE {ate_blind:.2f} m, "
                  f"flagged {100 * mid_b:.0f} %")


def hector_fr079_odometry(workdir: Path) -> tuple[None, str]:
    """`hector` with odometry on fr079: ATE against reference.tum (GMapping's, not ground truth)."""
    run = workdir / "hector-fr079"
    _slam2d("run", "hector", str(DATA / "fr079" / "fr079.clf.gz"), "--out", str(run), "--set", "use_odometry=true")
    _slam2d("evaluate", str(run), "--reference", str(DATA / "fr079" / "reference.tum"))
    ev = json.loads((run / "evaluation.json").read_text())
    ate = ev["trajectory"]["ate"]["translation_m"]["rmse"]
    cost = ev["cost"]
    return None, f"ATE {ate:.3f} m vs reference.tum; {1e3 * cost['cpu_s_per_scan']['median']:.2f} ms CPU per scan"


def hector_paper_arena(workdir: Path) -> tuple[None, str]:
    """`paper-arena` simulated, `hector` without odometry: ATE against the truth."""
    sim = workdir / "paper-arena"
    if not (sim / "truth.tum").is_file():
        _slam2d("simulate", "paper-arena", "--out", str(sim), "--seed", "0")
    run = workdir / "hector-arena"
    _slam2d("run", "hector", str(sim / "recording.log.gz"), "--out", str(run))
    _slam2d("evaluate", str(run), "--truth", str(sim))
    ev = json.loads((run / "evaluation.json").read_text())
    cpu_ms = 1e3 * ev["cost"]["cpu_s_per_scan"]["median"]
    return None, (f"ATE {ev['trajectory']['ate']['translation_m']['rmse']:.4f} m without odometry; "
                  f"{cpu_ms:.2f} ms CPU per scan (median, 682 beams, most with a return)")


def hector_mines_maps(workdir: Path) -> tuple[None, str]:
    """Filatov corner and enclosed-area counts of `hector` (no odometry) vs the odometry baseline, mines logs."""
    notes = []
    for ds in ("mines-exp1", "mines-exp2"):
        counts = {}
        for method in ("hector", "odometry"):
            run = workdir / f"{method}-{ds}"
            _slam2d("run", method, str(DATA / ds / f"{ds}.clf.gz"), "--out", str(run))
            _slam2d("evaluate", str(run))
            q = json.loads((run / "evaluation.json").read_text())["map_quality"]
            counts[method] = (q["corners"], q["enclosed_areas"])
        (hc, he), (oc, oe) = counts["hector"], counts["odometry"]
        notes.append(f"{ds}: corners {hc} vs {oc}, enclosed areas {he} vs {oe}")
    return None, "hector vs odometry; " + "; ".join(notes)


CASES: list[Case] = [
    Case("simulate-office", "10 min of youBot + URG-04LX at 10 Hz in `office`, with CARMEN, ROS 2 bag, truth",
         simulate_office, target="< 20 s, < 300 MB", max_seconds=20.0, max_peak_mb=300.0),
    Case("read-fr079", "read fr079.clf.gz end to end into frames (4791 scans x 360 beams)", read_fr079,
         target="< 2 s", max_seconds=2.0, needs=(SHARED,)),
    Case("map-fr079", "`slam2d map` fr079 with reference.tum at 0.05 m, whole command", map_fr079,
         target="< 5 s", max_seconds=5.0, needs=(SHARED,)),
    Case("compare-fr079", "`slam2d compare` fr079 with odometry and known-poses against reference.tum, "
         "report included, whole command", compare_fr079, target="< 20 s; report < 5 s", max_seconds=20.0,
         needs=(SHARED,)),
    Case("map-intel-kernel", "ray casting all intel scans into a 0.05 m grid (reading excluded)", map_intel_kernel,
         needs=(SHARED,)),
    Case("numba-compile", "cold numba compile of the grid kernels", numba_compile, warmup=False, repeat=1),
    Case("read-ros2-fr079", "read fr079 converted to a ROS 2 bag (sqlite3)", read_ros2_fr079, needs=(SHARED,)),
    Case("hector-mines-exp1", "`hector` over mines-exp1 (756 scans of 682 beams, 75 s), no odometry: CPU time of "
         "the updates, reading excluded", hector_mines_speed, target="< 3 s; < 2 ms median per scan",
         max_seconds=3.0, needs=(SHARED,)),
    Case("hector-long-corridor", "`long-corridor` simulated, `hector` with and without odometry (whole commands)",
         hector_long_corridor, target="with odometry ATE < 0.2 m; degeneracy flagged on the featureless stretch",
         repeat=1),
    Case("hector-paper-arena", "`paper-arena` simulated, `hector` without odometry (whole commands)",
         hector_paper_arena, target="ATE < 0.03 m", repeat=1),
    Case("hector-fr079-odometry", "`hector` with odometry on fr079, evaluated against reference.tum (whole commands)",
         hector_fr079_odometry, target="ATE < 0.3 m", needs=(SHARED,), repeat=1),
    Case("hector-mines-maps", "`hector` (no odometry) and `odometry` on mines-exp1/2: Filatov map counts",
         hector_mines_maps, target="corners and enclosed areas below the odometry baseline's", needs=(SHARED,),
         repeat=1),
] + [
    Case(f"memory-{Path(rel).name.split('.')[0]}",
         f"peak memory reading `{rel}`", _reader_case(rel), target="< 200 MB", max_peak_mb=200.0,
         needs=(SHARED,), repeat=1)
    for rel in (
        "intel/intel.clf.gz", "aces/aces.clf.gz", "fr101/fr101.clf.gz", "mines-exp1/mines-exp1.clf.gz",
        "mines-exp2/mines-exp2.clf.gz", "robustness/csail-robotlaser1-corrected.log",
        "robustness/laser_scan_matcher_demo.bag",
    )
]


if __name__ == "__main__":
    name, workdir = sys.argv[1], Path(sys.argv[2])
    (case,) = [c for c in CASES if c.name == name]
    seconds, extra = case.run(workdir)
    print(json.dumps({"seconds": seconds, "extra": extra} if seconds is not None else {"extra": extra}))
