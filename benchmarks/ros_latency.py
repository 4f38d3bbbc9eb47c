#!/usr/bin/env python3
"""The live node: latency from a scan's arrival to its pose, scans dropped, and the offline run repeated.

    .venv/bin/python benchmarks/ros_latency.py                      # the table on stdout
    .venv/bin/python benchmarks/ros_latency.py --methods karto,hector --rates 1,4
    .venv/bin/python benchmarks/ros_latency.py --write BENCHMARKS.md

Needs ROS 1 (roscore, rosbag; see docs/commands/ros.md). Simulates 60 s of the office with the
URG-04LX at 10 Hz (``slam2d simulate office --ros1``), starts a roscore on a free port with
``use_sim_time``, and per method and rate starts ``slam2d ros METHOD --out DIR``, plays the bag with
``rosbag play --clock -r RATE``, stops the node with SIGINT and reads its run folder: the latency
median and p95 (arrival in the callback to the pose, queueing included), the scans dropped, and
the largest distance between its trajectory and ``slam2d run METHOD BAG --params DIR/run.json``
(the same method offline with the parameters the node ran with; same seed).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))

METHODS = ("karto", "hector", "gmapping", "lago", "coreslam", "crsm")
SECTION_BEGIN = "<!-- BEGIN live-node (benchmarks/ros_latency.py --write) -->"
SECTION_END = "<!-- END live-node -->"


def _slam2d(*args: str, env: dict[str, str], **kwargs) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "slam2d", *args], env=env, **kwargs)


def _one(method: str, rate: float, bag: Path, env: dict[str, str], work: Path) -> dict:
    import numpy as np

    from slam2d.io.tum import read_tum

    out = work / f"{method}-{rate:g}"
    node = _slam2d("ros", method, "--out", str(out), "--overwrite", env=env, stdout=subprocess.DEVNULL,
                   stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.monotonic() + 60
    while "/slam2d/save" not in subprocess.run(["rosservice", "list"], env=env, capture_output=True,
                                                text=True).stdout:
        if time.monotonic() > deadline:
            raise SystemExit(f"{method}: the node did not come up")
        time.sleep(0.5)
    subprocess.run(["rosbag", "play", "--clock", "-q", "-d", "2", "-r", str(rate), str(bag)], env=env, check=True,
                   capture_output=True)
    time.sleep(1.0)
    os.killpg(node.pid, signal.SIGINT)
    node.wait(timeout=300)
    summary = json.loads((out / "diagnostics.json").read_text())["summary"]
    offline = work / f"{method}-{rate:g}-offline"
    subprocess.run([sys.executable, "-m", "slam2d", "run", method, str(bag), "--params", str(out / "run.json"),
                    "--out", str(offline), "--overwrite"], env=env, check=True, capture_output=True)
    t_live, p_live = read_tum(out / "trajectory.tum")
    t_off, p_off = read_tum(offline / "trajectory.tum")
    same = len(t_live) == len(t_off)
    diff = float(np.abs(p_live[:, :2] - p_off[:, :2]).max()) if same else float("nan")
    return {"method": method, "rate": rate, "median_ms": 1000 * summary["live_latency_median_s"],
            "p95_ms": 1000 * summary["live_latency_p95_s"], "dropped": summary["live_scans_dropped"],
            "scans": len(t_live), "offline_scans": len(t_off), "offline_diff_m": diff}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--methods", default=",".join(METHODS))
    parser.add_argument("--rates", default="1,4", help="rosbag play rates (1 = real time)")
    parser.add_argument("--duration", type=float, default=60.0, help="seconds of the simulated office")
    parser.add_argument("--write", type=Path, metavar="BENCHMARKS.md")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="slam2d-ros-latency-") as tmp:
        work = Path(tmp)
        with socket.socket() as s:
            s.bind(("localhost", 0))
            port = s.getsockname()[1]
        env = {**os.environ, "ROS_MASTER_URI": f"http://localhost:{port}", "ROS_HOME": str(work / "ros"),
               "ROS_LOG_DIR": str(work / "ros" / "log")}
        subprocess.run([sys.executable, "-m", "slam2d", "simulate", "office", "--ros1", "--duration",
                        str(args.duration), "--out", str(work / "office")], env=env, check=True, capture_output=True)
        bag = work / "office" / "recording.bag"
        core = subprocess.Popen(["roscore", "-p", str(port)], env=env, stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL, start_new_session=True)
        try:
            while subprocess.run(["rosparam", "set", "/use_sim_time", "true"], env=env,
                                 capture_output=True).returncode:
                time.sleep(0.5)
            rows = []
            for method in args.methods.split(","):
                for rate in (float(r) for r in args.rates.split(",")):
                    r = _one(method, rate, bag, env, work)
                    rows.append(r)
                    print(f"{method} at {rate:g}x: median {r['median_ms']:.1f} ms, p95 {r['p95_ms']:.1f} ms, "
                          f"dropped {r['dropped']}, offline diff {r['offline_diff_m']:.2g} m", file=sys.stderr,
                          flush=True)
        finally:
            os.killpg(core.pid, signal.SIGINT)
            core.wait(timeout=30)
    from datetime import datetime, timezone

    when = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    lines = ["| method | rate | latency median (ms) | latency p95 (ms) | scans dropped | scans | "
             "largest distance to the offline run (m) |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        diff = "different scan count" if r["scans"] != r["offline_scans"] else f"{r['offline_diff_m']:.2g}"
        lines.append(f"| `{r['method']}` | {r['rate']:g}x | {r['median_ms']:.1f} | {r['p95_ms']:.1f} | "
                     f"{r['dropped']} | {r['scans']} | {diff} |")
    head = (f"`slam2d ros METHOD` fed {args.duration:g} s of the simulated office (URG-04LX, 10 Hz) by "
            "`rosbag play --clock -r RATE` against a real roscore: latency from a scan's arrival in the "
            "callback to its pose (queueing included), scans dropped, and the largest distance between the "
            "node's trajectory and `slam2d run` of the same method with the node's run.json. Measured "
            f"{when}; command: `.venv/bin/python benchmarks/ros_latency.py --write BENCHMARKS.md`.")
    from defaults import emit_section

    emit_section(SECTION_BEGIN, SECTION_END, "Live node", head, lines, args.write)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
