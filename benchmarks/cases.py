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


def _gmapping(rel: str, particles: int = 30) -> Callable[[Path], tuple[float, str]]:
    """`gmapping` with default parameters on a shared log, in this process (so peak memory is its own).

    Time is the whole run (reading, filter, map, writing the run folder). The note gives the
    filter's per-update latency (median and p95 of the updates' wall time), its CPU time and
    the map tiles it held.
    """

    def run(workdir: Path) -> tuple[float, str]:
        import numpy as np

        from slam2d.methods.runner import run_method

        out = workdir / f"gmapping-{Path(rel).parent.name}-{particles}"
        t0 = time.perf_counter()
        run_method("gmapping", DATA / rel, out, settings={"particles": particles}, seed=0)
        dt = time.perf_counter() - t0
        diag = json.loads((out / "diagnostics.json").read_text())
        series = diag["series"]
        updated = np.array([u == 1 for u in series["updated"]])
        wall = np.array(series["wall_s"])[updated] * 1e3
        cpu = float(np.nansum(np.array(series["cpu_s"], dtype=float)))
        return dt, (f"{int(updated.sum())} updates of {updated.size} scans; per update median "
                    f"{np.median(wall):.1f} ms, p95 {np.percentile(wall, 95):.1f} ms; filter CPU {cpu:.1f} s; "
                    f"map tiles peak {diag['summary'].get('map_tiles_peak')}")

    return run


def gmapping_compile(workdir: Path) -> tuple[float, str]:
    """Cold numba compile of gmapping's kernels: 30 intel scans with an empty on-disk cache."""
    import itertools
    import os

    os.environ["NUMBA_CACHE_DIR"] = str(workdir / "numba-cold-cache-gmapping")
    from slam2d.io import open_recording
    from slam2d.methods.gmapping import GMapping

    frames = list(itertools.islice(open_recording(DATA / "intel" / "intel.clf.gz").frames(), 30))
    t0 = time.perf_counter()
    slam = GMapping(seed=0).run(frames)
    slam.map()
    first = time.perf_counter() - t0
    t1 = time.perf_counter()
    GMapping(seed=0).run(frames).map()
    again = time.perf_counter() - t1
    return first - again, f"first run {first:.1f} s minus a compiled rerun {again:.2f} s"


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
    Case("gmapping-intel", "`gmapping` defaults (30 particles) on intel, whole run; per-update latency in notes",
         _gmapping("intel/intel.clf.gz"), target="< 30 s (C++ original 46 s)", max_seconds=30.0,
         needs=(SHARED,), repeat=1),
    Case("gmapping-fr079", "`gmapping` defaults (30 particles) on fr079, whole run; per-update latency in notes",
         _gmapping("fr079/fr079.clf.gz"), target="< 40 s (C++ original 60 s)", max_seconds=40.0,
         needs=(SHARED,), repeat=1),
    Case("gmapping-memory-intel-100", "`gmapping` with 100 particles on intel: peak memory (copy-on-write tiles)",
         _gmapping("intel/intel.clf.gz", particles=100), target="< 1 GB", max_peak_mb=1000.0,
         needs=(SHARED,), repeat=1),
    Case("gmapping-compile", "cold numba compile of gmapping's kernels (filter and map rebuild)",
         gmapping_compile, warmup=False, repeat=1, needs=(SHARED,)),
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
