#!/usr/bin/env python3
"""karto's CPU time, ATE and trajectory hash on the four real logs, with optional parameter overrides.

    SLAM2D_THREADS=1 NUMBA_NUM_THREADS=1 PYTHONPATH=src .venv/bin/python docs/measure_karto_speed.py \
        [--logs intel,aces,fr101,fr079] [--set NAME=VALUE ...]

CPU is user + system (``resource.getrusage``) around ``Karto.run`` (reading excluded); the hash is a
sha1 prefix of the trajectory's times and poses, so two runs with the same hash gave the same result.
``--lookups`` also prints the correlation-grid lookups (``MatchResult.evaluated``, coarse and fine) and
the CPU of the 1 cm matches by kind (seeded sequential, whole sequential, near chain, loop, recovery);
``--near-headings`` the heading corrections of the near-chain matches that link (response above 0.8).
"""

from __future__ import annotations

import argparse
import ast
import collections
import hashlib
import math
import sys
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
    ap.add_argument("--lookups", action="store_true", help="count lookups and CPU of the matches by kind")
    ap.add_argument("--near-headings", action="store_true", help="heading corrections of the near-chain links")
    args = ap.parse_args()
    kinds = collections.defaultdict(lambda: [0, 0, 0.0])
    headings = []
    if args.lookups:
        _count_matches(kinds)
    if args.near_headings:
        _record_near_links(headings)
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
        for kind, (n, lookups, seconds) in sorted(kinds.items(), key=lambda kv: -kv[1][1]):
            print(f"  {kind}: {n} matches, {lookups / 1e6:.0f} M lookups, {seconds:.2f} s")
        kinds.clear()
        if headings:
            d = np.abs(np.array(headings))
            print("  near-chain links: %d, |heading correction| deg 50/90/99 %%, max: %s"
                  % (d.size, np.round(np.percentile(d, [50, 90, 99, 100]), 2)))
            headings.clear()


def _count_matches(kinds) -> None:
    """Wrap the matcher's two entry points to add each call's lookups and CPU to its kind (the caller chain)."""
    from slam2d.matching.correlative import CorrelativeMatcher

    for name in ("match", "match_near"):
        original = getattr(CorrelativeMatcher, name)

        def wrapped(self, *a, _original=original, _name=name, **k):
            frame = sys._getframe(1)
            kind = f"{_name} <- {frame.f_code.co_name}"
            if frame.f_code.co_name in ("_match", "_seeded_match"):
                kind += f" <- {frame.f_back.f_code.co_name}"
            c0 = time.process_time()
            result = _original(self, *a, **k)
            entry = kinds[kind]
            entry[0] += 1
            entry[1] += 0 if result is None else result.evaluated
            entry[2] += time.process_time() - c0
            return result

        setattr(CorrelativeMatcher, name, wrapped)


def _record_near_links(headings) -> None:
    from slam2d.graph.frontend import GraphFrontend

    original = GraphFrontend._near_outcome

    def wrapped(self, entry, points, pose, lo, hi, hot):
        out = original(self, entry, points, pose, lo, hi, hot)
        if not (out is None or isinstance(out, str)) and out.response > self.params.link_match_minimum_response_fine:
            headings.append(math.degrees(math.remainder(float(out.pose[2] - pose[2]), 2.0 * math.pi)))
        return out

    GraphFrontend._near_outcome = wrapped


if __name__ == "__main__":
    main()
