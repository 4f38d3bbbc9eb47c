#!/usr/bin/env python3
"""The original GMapping (OpenSLAM's C++, as slam_gmapping runs it) on the shared SICK logs: the peer of ``gmapping``.

    git clone https://github.com/ros-perception/openslam_gmapping /tmp/gmapping_src
    S=/tmp/gmapping_src B=/tmp/gmapping_build; mkdir -p $B/obj && cp -r $S/include $B/
    for d in utils sensor/sensor_base sensor/sensor_odometry sensor/sensor_range log configfile scanmatcher \\
        gridfastslam; do n=${d##*/}; echo "#define ${n^^}_EXPORT" > $B/include/gmapping/$d/${n}_export.h; done
    for f in utils/stat utils/movement sensor/sensor_base/sensor sensor/sensor_base/sensorreading \\
        sensor/sensor_range/rangesensor sensor/sensor_range/rangereading scanmatcher/smmap scanmatcher/scanmatcher \\
        gridfastslam/gridslamprocessor gridfastslam/gridslamprocessor_tree gridfastslam/motionmodel; do
        g++ -O2 -w -I$B/include -c $S/$f.cpp -o $B/obj/${f//\\//_}.o; done
    ar rcs $B/libgmapping.a $B/obj/*.o
    .venv/bin/python benchmarks/peer_gmapping.py --gmapping /tmp/gmapping_build [--logs aces,csail] [--seeds 0-4]

GMapping is not a dependency: it runs here only to show how the original behaves on
the logs of the "defaults on every real log" table, seed by seed, next to slam2d's
``gmapping``. The build above replaces catkin (the ``*_EXPORT`` headers it would
generate are empty on Linux). This script compiles ``peer_gmapping_driver.cpp``
(our own code, GMapping's public API only) against that folder into a temporary
folder, writes each log as text (the scans with odometry, read by slam2d's own
reader; no return as the scan's maximum range) and runs the driver once per (log,
seed), ``--jobs`` at a time. The driver does what slam_gmapping's node does: its
default parameters (30 particles, 5 cm cells, ``linearUpdate`` 1 m, ``angularUpdate``
0.5 rad, ``maxUrange`` = ``maxRange`` = the laser's maximum - 1 cm...), the odometry
of the laser's frame turned to the middle of its field of view with the beams at
``(i - n/2) * increment`` about it (half a beam off the scan's own angles, as the node
has them), readings below the minimum range replaced by the maximum, the seed set
once with ``GMapping::sampleGaussian(1, seed)`` (seed 0 leaves drand48 unseeded: its
fixed default state, so every seed's run is reproducible). The estimate at each scan
is the final best particle's tree path (its node at each scan GMapping processed;
the odometry composed onto the last node in between), as ``gmapping``'s trajectory
is. ATE as in ``benchmarks/defaults.py``, against ``reference.tum`` (a GMapping
result, not independent ground truth) after SE(2) alignment, over every scan;
"updates only" is over the processed scans alone. A run takes 0.5-2 min (fr079, its
4791 scans, about 2).
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
SHARED = ROOT.parent / "shared" / "datasets"
DRIVER = Path(__file__).resolve().parent / "peer_gmapping_driver.cpp"
LOGS = ("intel", "aces", "fr079", "fr101", "csail")


def _seeds(text: str) -> list[int]:
    """``0-4`` or ``1,3`` (or both, ``0-2,7``) as a list of seeds."""
    out = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        out.extend(range(int(lo), int(hi) + 1) if hi else [int(lo)])
    return out


def build_driver(gmapping: Path, workdir: Path) -> Path:
    """The driver compiled against ``gmapping`` (a folder with ``include/`` and ``libgmapping.a``), in ``workdir``."""
    exe = workdir / "peer_gmapping_driver"
    cmd = ["g++", "-O2", "-std=c++17", "-isystem", str(gmapping / "include"), str(DRIVER),
           str(gmapping / "libgmapping.a"), "-o", str(exe)]
    subprocess.run(cmd, check=True)
    return exe


def write_input(frames, path: Path) -> None:
    """The driver's input: the laser line, then one line per scan (time, odometry, ranges; no return = maximum)."""
    first = frames[0].scan
    values = [first.angle_min, first.angle_increment, first.range_min, first.range_max, *first.mount]
    with open(path, "w") as f:
        f.write(f"laser {first.num_beams} " + " ".join(repr(float(v)) for v in values) + "\n")
        for frame in frames:
            scan = frame.scan
            ranges = np.nan_to_num(scan.ranges, nan=first.range_max)
            x, y, theta = (float(v) for v in frame.odometry)
            f.write(f"scan {frame.timestamp:.6f} {x!r} {y!r} {theta!r} {scan.num_beams} "
                    + " ".join(f"{r:.4f}" for r in ranges) + "\n")


def run_peer(exe: Path, data: Path, seed: int, out: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """(times, base poses, processed-scan mask, wall seconds) of one run of the driver."""
    t0 = time.perf_counter()
    # GMapping writes its progress to stdout and stderr (as it does under slam_gmapping): dropped
    done = subprocess.run([str(exe), str(data), str(out), str(seed)], stdout=subprocess.DEVNULL,
                          stderr=subprocess.PIPE)
    wall = time.perf_counter() - t0
    if done.returncode != 0:
        tail = done.stderr.decode(errors="replace").strip().splitlines()[-3:]
        raise RuntimeError(f"driver failed on {data.name} seed {seed} (exit {done.returncode}): {tail}")
    rows = np.loadtxt(out, ndmin=2)
    return rows[:, 0], rows[:, 1:4], rows[:, 4] > 0, wall


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--gmapping", type=Path, required=True,
                        help="GMapping's build folder: include/ (with the *_export.h headers) and libgmapping.a")
    parser.add_argument("--logs", default=",".join(LOGS))
    parser.add_argument("--seeds", default="0-4", help="e.g. 0-4 or 1,3")
    parser.add_argument("--jobs", type=int, default=2, help="runs at a time (each is one process)")
    args = parser.parse_args()
    sys.path.insert(0, str(ROOT / "src"))
    from slam2d.eval.trajectory_metrics import absolute_trajectory_error, associate
    from slam2d.io import open_recording
    from slam2d.io.tum import read_tum

    seeds = _seeds(args.seeds)
    logs = args.logs.split(",")
    with tempfile.TemporaryDirectory(prefix="peer_gmapping_") as tmp:
        work = Path(tmp)
        exe = build_driver(args.gmapping, work)
        refs, odometry = {}, {}
        for log in logs:
            frames = [f for f in open_recording(SHARED / log / f"{log}.clf.gz").frames() if f.odometry is not None]
            write_input(frames, work / f"{log}.txt")
            refs[log] = read_tum(SHARED / log / "reference.tum")
            odometry[log] = (np.array([f.timestamp for f in frames]), np.array([f.odometry for f in frames], float))

        def ate(log, times, poses):
            rt, rp = refs[log]
            return absolute_trajectory_error(associate(times, poses, rt, rp))["translation_m"]["rmse"]

        def one(task):
            log, k, seed = task
            times, poses, updated, wall = run_peer(exe, work / f"{log}.txt", seed, work / f"{log}-{k}.out")
            return log, seed, ate(log, times, poses), ate(log, times[updated], poses[updated]), \
                int(updated.sum()), len(times), wall

        tasks = [(log, k, seed) for log in logs for k, seed in enumerate(seeds)]
        results = {log: [] for log in logs}
        with ThreadPoolExecutor(max_workers=max(1, args.jobs)) as pool:
            for log, seed, a, a_updates, n_updates, n, wall in pool.map(one, tasks):
                results[log].append((seed, a, a_updates, wall))
                print(f"{log} seed {seed}: ATE {a:.3f} m (updates only {a_updates:.3f} m, {n_updates} of {n} "
                      f"scans), {wall:.1f} s", flush=True)
    print(f"\n| log | GMapping (OpenSLAM) median / worst, seeds {args.seeds} | every seed | updates only, median "
          f"| odometry alone | s per run |\n|---|---|---|---|---|---|")
    for log in logs:
        ates = [r[1] for r in results[log]]
        every = ", ".join(f"{r[1]:.3f}" for r in results[log])
        print(f"| {log} | {statistics.median(ates):.3f} / {max(ates):.3f} | {every} | "
              f"{statistics.median(r[2] for r in results[log]):.3f} | {ate(log, *odometry[log]):.3f} | "
              f"{statistics.median(r[3] for r in results[log]):.0f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
