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


def _manhattan(initial: str):
    from slam2d.backends import get_backend
    from slam2d.backends.synthetic import manhattan_graph

    # load the compiled kernels from numba's disk cache first, so the timing is the solve alone
    small = manhattan_graph(30, 60, seed=1)[0]
    get_backend("spa").optimize(small)
    get_backend("lago").optimize(small)
    return manhattan_graph(5000, 10000, seed=0, initial=initial)[0]


def spa_5000(_: Path) -> tuple[float, str]:
    """One SPA optimisation of a 5000-node, 10,000-edge Manhattan graph from its odometry guess."""
    from slam2d.backends import get_backend

    g = _manhattan("odometry")
    res = get_backend("spa").optimize(g)
    return res.wall_s, (f"{res.iterations} LM iterations, cpu {res.cpu_s:.3f} s, cost {res.cost_before:.4g} -> "
                        f"{res.cost_after:.6g}, converged {res.converged}")


def lago_5000(_: Path) -> tuple[float, str]:
    """LAGO (+1 Gauss-Newton step) on the same graph with every pose at the origin; cost compared to SPA's."""
    from slam2d.backends import get_backend

    g = _manhattan("zero")
    res = get_backend("lago").optimize(g)
    spa = get_backend("spa").optimize(_manhattan("odometry"))
    return res.wall_s, (f"cpu {res.cpu_s:.3f} s, cost {res.cost_after:.6g} = {res.cost_after / spa.cost_after:.6f} x SPA's "
                        f"{spa.cost_after:.6g} (SPA {spa.wall_s:.3f} s wall, {spa.cpu_s:.3f} s cpu)")


def _karto_on(log: str, reference: str | None) -> tuple[float, str]:
    """karto over a whole log (reading excluded): wall and CPU seconds, ATE against the reference."""
    from slam2d.eval.trajectory_metrics import absolute_trajectory_error, associate
    from slam2d.io import open_recording
    from slam2d.io.tum import read_tum
    from slam2d.methods import get_method

    frames = list(open_recording(DATA / log).frames())
    slam = get_method("karto")()
    t0, c0 = time.perf_counter(), time.process_time()
    slam.run(frames)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    summary = slam.diagnostics.summary
    note = f"cpu {cpu:.2f} s, {summary['nodes']} nodes, {len(summary['loop_closures'])} loop closures"
    if reference is not None:
        rt, rp = read_tum(DATA / reference)
        t, p = slam.trajectory()
        ate = absolute_trajectory_error(associate(t, p, rt, rp))["translation_m"]["rmse"]
        note += f", ATE {ate:.3f} m vs reference.tum"
    return wall, note


def karto_intel(_: Path) -> tuple[float, str]:
    return _karto_on("intel/intel.clf.gz", "intel/reference.tum")


def karto_fr079(_: Path) -> tuple[float, str]:
    return _karto_on("fr079/fr079.clf.gz", "fr079/reference.tum")


def karto_loop_precision(_: Path) -> tuple[float, str]:
    """Loop-closure precision of karto in simulation: closures within 0.2 m and 1 deg of the truth."""
    from slam2d.eval.trajectory_metrics import absolute_trajectory_error, associate
    from slam2d.graph.evaluation import loop_closure_precision
    from slam2d.methods import get_method
    from slam2d.sim.simulate import SimulationParams, simulate

    t0 = time.perf_counter()
    total = correct = 0
    notes = []
    for world, duration in (("corridor-loop", 125.0), ("office", 170.0)):
        for seed in (1, 2, 3):
            sim = simulate(world, SimulationParams(duration=duration, seed=seed))
            slam = get_method("karto")().run(sim.frames())
            prec = loop_closure_precision(slam.diagnostics.summary["loop_closures"], sim.scan_times, sim.scan_truth)
            t, p = slam.trajectory()
            ate = absolute_trajectory_error(associate(t, p, sim.scan_times, sim.scan_truth))["translation_m"]["rmse"]
            total += prec["closures"]
            correct += prec["correct"]
            notes.append(f"{world}/{seed}: {prec['correct']}/{prec['closures']}, ATE {ate:.3f} m")
    share = correct / total if total else float("nan")
    return time.perf_counter() - t0, f"precision {correct}/{total} = {share:.1%}; " + "; ".join(notes)

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
    Case("spa-5000", "SPA (LM, sparse Cholesky/LU) on a synthetic 5000-node, 10,000-edge Manhattan graph from odometry",
         spa_5000, target="< 0.3 s", max_seconds=0.3),
    Case("lago-5000", "LAGO + 1 Gauss-Newton step on the same graph from no initial guess (all poses at 0)",
         lago_5000, target="cost within 10% of SPA, faster than spa-5000"),
    Case("karto-intel", "`karto` over intel (910 scans, reading excluded); ATE vs reference.tum in the notes",
         karto_intel, target="< 4 s wall, ATE < 0.10 m", max_seconds=4.0, needs=(SHARED,), repeat=1),
    Case("karto-fr079", "`karto` over fr079 (4791 scans, reading excluded); ATE vs reference.tum in the notes",
         karto_fr079, target="< 6 s wall, ATE < 0.20 m", max_seconds=6.0, needs=(SHARED,), warmup=False,
         repeat=1),
    Case("karto-loop-precision", "`karto` loop closures vs truth in corridor-loop and office (3 seeds each, "
         "GMapping's odometry noise)", karto_loop_precision, target="precision >= 98 %", warmup=False, repeat=1),
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
