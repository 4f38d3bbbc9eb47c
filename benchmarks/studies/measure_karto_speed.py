#!/usr/bin/env python3
"""karto's CPU time, ATE and trajectory hash on the four real logs, with optional parameter overrides.

    SLAM2D_THREADS=1 NUMBA_NUM_THREADS=1 PYTHONPATH=src .venv/bin/python benchmarks/studies/measure_karto_speed.py \
        [--logs intel,aces,fr101,fr079] [--set NAME=VALUE ...]

CPU is user + system (``resource.getrusage``) around ``Karto.run`` (reading excluded); the hash is a
sha1 prefix of the trajectory's times and poses, so two runs with the same hash gave the same result.
``--lookups`` also prints the correlation-grid lookups (``MatchResult.evaluated``, coarse and fine) and
the CPU of the 1 cm matches by kind (seeded sequential, whole sequential, near chain, loop, recovery);
``--near-headings`` the heading corrections of the near-chain matches that link (response above 0.8);
``--steps`` the CPU (``time.process_time``, inclusive) of the front end's main steps; ``--kernels`` (after a
first whole run that loads every compiled function, so without the loading) the wall
time spent in compiled (numba) calls, on the main thread and on the worker threads, and per kind of frame
(kept scan or between nodes) the wall time of ``GraphFrontend.process`` and its main-thread share in
compiled calls (the rest is Python and numpy), with the worker threads' start after each hand-over
(``_split``); ``--thread-cpu`` (with ``--kernels``) times each
thread's own CPU (``time.thread_time``) instead of wall time, so the split is not inflated while the
host runs other work; ``--profile`` the
functions taking most CPU by cProfile (timed by ``process_time``; the profiler slows Python, not the
compiled kernels, so their share is understated).
"""

from __future__ import annotations

import argparse
import ast
import collections
import cProfile
import hashlib
import io
import math
import pstats
import sys
import resource
import time
from pathlib import Path

import numpy as np

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "datasets"


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
    ap.add_argument("--steps", action="store_true", help="CPU of the front end's main steps")
    ap.add_argument("--profile", action="store_true", help="cProfile's top functions by own time")
    ap.add_argument("--kernels", action="store_true",
                    help="wall time in compiled calls (main thread, workers) and per kind of frame")
    ap.add_argument("--thread-cpu", action="store_true",
                    help="with --kernels: each thread's own CPU time (time.thread_time) instead of wall time")
    args = ap.parse_args()
    kernel_times = None
    steps = collections.defaultdict(lambda: [0, 0.0])
    if args.steps:
        _time_steps(steps)
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
        if args.kernels and kernel_times is None:
            # Every compiled function loaded (or compiled) first, by a whole run: numba cannot compile a
            # function whose callee is the timing wrapper. So this mode's cpu and wall exclude loading.
            get_method("karto")(get_method("karto").Params(**settings)).run(frames)
            kernel_times = _time_kernels(time.thread_time if args.thread_cpu else time.perf_counter)
        slam = method(method.Params(**settings))
        profiler = cProfile.Profile(time.process_time) if args.profile else None
        c0, w0 = _cpu(), time.perf_counter()
        if profiler is not None:
            profiler.enable()
        slam.run(frames)
        if profiler is not None:
            profiler.disable()
        cpu, wall = _cpu() - c0, time.perf_counter() - w0
        t, p = slam.trajectory()
        rt, rp = read_tum(DATA / log / "reference.tum")
        ate = absolute_trajectory_error(associate(t, p, rt, rp))["translation_m"]["rmse"]
        digest = hashlib.sha1(np.ascontiguousarray(t).tobytes() + np.ascontiguousarray(p).tobytes()).hexdigest()[:16]
        closures = len(slam.diagnostics.summary["loop_closures"])
        counters = slam.diagnostics.counters
        between = f", between nodes {counters.get('frames_matched_between_nodes', 0)} matched"
        print(f"{log}: cpu {cpu:.2f} s, wall {wall:.2f} s, ATE {ate:.4f} m, {closures} closures{between}, "
              f"hash {digest}", flush=True)
        for kind, (n, lookups, seconds) in sorted(kinds.items(), key=lambda kv: -kv[1][1]):
            print(f"  {kind}: {n} matches, {lookups / 1e6:.0f} M lookups, {seconds:.2f} s")
        kinds.clear()
        if kernel_times is not None:
            _print_kernels(kernel_times)
        for step, (n, seconds) in sorted(steps.items(), key=lambda kv: -kv[1][1]):
            print(f"  {step}: {n} calls, {seconds:.2f} s")
        steps.clear()
        if profiler is not None:
            out = io.StringIO()
            pstats.Stats(profiler, stream=out).sort_stats("tottime").print_stats(15)
            print(out.getvalue())
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
            if frame.f_code.co_filename.endswith("scan_matcher.py"):
                frame = frame.f_back  # a ScanMatcher's method: its caller tells the kind
            kind = f"{_name} <- {frame.f_code.co_name}"
            if frame.f_code.co_name == "_seeded_match":
                kind += f" <- {frame.f_back.f_code.co_name}"
            c0 = time.process_time()
            result = _original(self, *a, **k)
            entry = kinds[kind]
            entry[0] += 1
            entry[1] += 0 if result is None else result.evaluated
            entry[2] += time.process_time() - c0
            return result

        setattr(CorrelativeMatcher, name, wrapped)


def _time_steps(steps) -> None:
    """Wrap the front end's and the grid cache's main steps to add their inclusive CPU to ``steps``."""
    from slam2d.graph.frontend import GraphFrontend
    from slam2d.matching.grid_cache import GridCache

    names = [(GraphFrontend, n) for n in ("_link_near_chains", "_near_outcome", "_sequential_estimate",
                                          "_seeded_match", "_try_close_loop", "optimize")]
    names += [(GridCache, n) for n in ("bound", "materialize", "get", "reserve")]
    for cls, name in names:
        original = getattr(cls, name)

        def wrapped(*a, _original=original, _key=f"{cls.__name__}.{name}", **k):
            c0 = time.process_time()
            try:
                return _original(*a, **k)
            finally:
                entry = steps[_key]
                entry[0] += 1
                entry[1] += time.process_time() - c0

        setattr(cls, name, wrapped)


def _time_kernels(clock=time.perf_counter) -> dict:
    """Wrap every compiled function the front end and the matcher call from Python, and their process step.

    Compiled functions calling each other are not affected (the wrappers sit on the module names
    Python code looks up), so each compiled call from Python is timed once.
    """
    import threading

    from numba.core.registry import CPUDispatcher

    import slam2d.graph.frontend as frontend
    import slam2d.graph.kernels as kernels
    import slam2d.graph.loop_closing as loop_closing
    import slam2d.graph.near_chains as near_chains
    import slam2d.graph.nodes as nodes
    import slam2d.graph.sequential as sequential
    import slam2d.matching.correlative as correlative
    import slam2d.matching.correlative_grid as correlative_grid
    import slam2d.matching.correlative_search as correlative_search
    import slam2d.matching.grid_cache as grid_cache

    main = threading.get_ident()
    times = {"main": 0.0, "workers": 0.0, "frames": collections.defaultdict(lambda: [0, 0.0, 0.0]),
             "by_name": collections.defaultdict(float), "starts": [],
             "clock": "wall" if clock is time.perf_counter else "thread CPU"}
    current = [0.0]
    # Each front-end module holds the names of the kernels it calls (kernels: those its wrappers call).
    for module in (correlative, correlative_grid, correlative_search, grid_cache, frontend, kernels, nodes,
                   sequential, near_chains, loop_closing):
        for name, obj in list(vars(module).items()):
            if not isinstance(obj, CPUDispatcher):
                continue

            def wrapped(*a, _obj=obj, _name=name, **k):
                t0 = clock()
                try:
                    return _obj(*a, **k)
                finally:
                    dt = clock() - t0
                    times["by_name"][_name] += dt
                    if threading.get_ident() == main:
                        times["main"] += dt
                        current[0] += dt
                    else:
                        times["workers"] += dt

            setattr(module, name, wrapped)
    split = correlative._split

    def timed_split(work, n, *a, **k):
        t0 = time.perf_counter()
        first = []

        def marked(i0, i1):
            if threading.get_ident() != main and not first:
                first.append(time.perf_counter() - t0)
            work(i0, i1)

        split(marked, n, *a, **k)
        times["starts"].append(first[0] if first else math.nan)  # NaN: this thread ran every piece

    correlative._split = correlative_grid._split = timed_split  # the matcher's calls and the smear's
    process = frontend.GraphFrontend.process

    def timed_process(self, frame):
        before = current[0]
        t0 = clock()
        out = process(self, frame)
        entry = times["frames"]["kept scan" if out is not None else "between nodes"]
        entry[0] += 1
        entry[1] += clock() - t0
        entry[2] += current[0] - before
        return out

    frontend.GraphFrontend.process = timed_process
    return times


def _print_kernels(times: dict) -> None:
    print(f"  compiled calls: main thread {times['main']:.2f} s, worker threads {times['workers']:.2f} s ({times['clock']})")
    for name, seconds in sorted(times["by_name"].items(), key=lambda kv: -kv[1])[:8]:
        print(f"    {name}: {seconds:.2f} s")
    for kind, (n, total, compiled) in sorted(times["frames"].items()):
        print(f"  {kind}: {n} frames, process {total:.2f} s, compiled {compiled:.2f} s, Python and numpy "
              f"{total - compiled:.2f} s ({1e6 * (total - compiled) / max(n, 1):.0f} us per frame)")
    if times["starts"]:
        d = np.array(times["starts"])
        took = d[np.isfinite(d)]
        print(f"  hand-overs: {d.size}, a worker took a piece in {took.size}, its first began after median "
              f"{1e6 * np.median(took) if took.size else math.nan:.0f} us, mean "
              f"{1e6 * took.mean() if took.size else math.nan:.0f} us")
    for key in ("main", "workers"):
        times[key] = 0.0
    for key in ("frames", "by_name"):
        times[key].clear()
    times["starts"].clear()


def _record_near_links(headings) -> None:
    from slam2d.graph.frontend import GraphFrontend

    original = GraphFrontend._near_outcome

    def wrapped(self, grid, points, pose, hot):
        out = original(self, grid, points, pose, hot)
        if not (out is None or isinstance(out, str)) and out.response > self.params.link_match_minimum_response_fine:
            headings.append(math.degrees(math.remainder(float(out.pose[2] - pose[2]), 2.0 * math.pi)))
        return out

    GraphFrontend._near_outcome = wrapped


if __name__ == "__main__":
    main()
