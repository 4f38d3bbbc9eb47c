#!/usr/bin/env python3
"""karto's CPU time, ATE and trajectory hash on the four real logs, with optional parameter overrides.

    SLAM2D_THREADS=1 NUMBA_NUM_THREADS=1 PYTHONPATH=src .venv/bin/python docs/measure_karto_speed.py \
        [--logs intel,aces,fr101,fr079] [--set NAME=VALUE ...]

CPU is user + system (``resource.getrusage``) around ``Karto.run`` (reading excluded); the hash is a
sha1 prefix of the trajectory's times and poses, so two runs with the same hash gave the same result.
"""

from __future__ import annotations

import argparse
import ast
import hashlib
import resource
import time
from pathlib import Path

import numpy as np

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "datasets"


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def main() -> None:
    from slam2d.eval.trajectory_metrics import absolute_trajectory_error, associate
    from slam2d.io import open_recording
    from slam2d.io.tum import read_tum
    from slam2d.methods import get_method

    ap = argparse.ArgumentParser()
    ap.add_argument("--logs", default="intel,aces,fr101,fr079")
    ap.add_argument("--set", action="append", default=[], help="NAME=VALUE parameter override")
    args = ap.parse_args()
    settings = {}
    for item in args.set:
        name, value = item.split("=", 1)
        try:
            settings[name] = ast.literal_eval(value)
        except (ValueError, SyntaxError):
            settings[name] = value
    method = get_method("karto")
    for log in args.logs.split(","):
        frames = list(open_recording(DATA / log / f"{log}.clf.gz").frames())
        slam = method(method.Params(**settings))
        c0, w0 = _cpu(), time.perf_counter()
        slam.run(frames)
        cpu, wall = _cpu() - c0, time.perf_counter() - w0
        t, p = slam.trajectory()
        rt, rp = read_tum(DATA / log / "reference.tum")
        ate = absolute_trajectory_error(associate(t, p, rt, rp))["translation_m"]["rmse"]
        digest = hashlib.sha1(np.ascontiguousarray(t).tobytes() + np.ascontiguousarray(p).tobytes()).hexdigest()[:16]
        closures = len(slam.diagnostics.summary["loop_closures"])
        print(f"{log}: cpu {cpu:.2f} s, wall {wall:.2f} s, ATE {ate:.4f} m, {closures} closures, hash {digest}", flush=True)


if __name__ == "__main__":
    main()
