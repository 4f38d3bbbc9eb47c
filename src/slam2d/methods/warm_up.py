"""Compile every method's kernels before the first real run (``slam2d compile``; ``make`` runs it).

numba compiles a kernel the first time it is called and keeps the machine code
on disk (``cache=True``). Without this, a fresh install pays for it in the
first run of each method (karto on intel: 49 s the first time, 4 s the
second), and a user who times that run times the compiler.

How: simulate one lap of ``corridor-loop`` (a loop, so the graph methods close
it), make its odometry miss a 60 deg turn half-way and a 1.5 m shift later (so
the recovery searches run too), and run every method on that with its defaults, the odometry-optional ones
also with ``use_odometry=true``, each as ``slam2d run`` runs it, in its own
process (``jobs`` at a time); then evaluate one run against the truth. The
simulated recording has the same array types as a recording read from disk,
so the kernels compiled here are the ones a real run calls.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from slam2d.errors import Slam2dError

__all__ = ["warm_up_commands", "warm_up"]

_WORLD = "corridor-loop"
# the longest compilations first, so that two jobs end together; lago last: it shares karto's front end,
# whose kernels are cached by then (two processes compiling the same kernel both pay for it)
_FIRST = ("karto", "gmapping", "crsm")
_LAST = ("lago",)
_EXTRA = {"gmapping": {"particles": 10}}  # the same kernels as 30 particles, a third of the run


def _paths(folder: Path) -> tuple[Path, Path]:
    """The simulator's output folder and the recording with the missed turn."""
    return folder / "recording", folder / "missed-turn.log.gz"


def warm_up_commands(folder: Path) -> tuple[list[str], list[list[str]], list[str]]:
    """``(simulate, runs, evaluate)``: the ``slam2d`` argument lists the warm-up runs in ``folder``."""
    from slam2d.methods import get_method, method_names

    sim, log = _paths(folder)
    runs = []
    for name in method_names():
        settings = {"poses": sim / "truth.tum"} if name == "known-poses" else _EXTRA.get(name, {})  # replays one
        extra = [a for k, v in settings.items() for a in ("--set", f"{k}={v}")]
        runs.append(["run", name, str(log), *extra, "--out", str(folder / name)])
        if get_method(name).optional_odometry:
            runs.append(["run", name, str(log), "--set", "use_odometry=true", "--out", str(folder / f"{name}-odometry")])
    runs.sort(key=lambda a: (a[1] in _LAST, a[1] not in _FIRST, _FIRST.index(a[1]) if a[1] in _FIRST else 0))
    evaluate = ["evaluate", str(folder / "karto"), "--truth", str(sim)]
    return ["simulate", _WORLD, "--out", str(sim), "--seed", "0"], runs, evaluate


def _write_missed_turn(sim: Path, log: Path) -> None:
    import numpy as np

    from slam2d.io import open_recording
    from slam2d.io.carmen import write_carmen
    from slam2d.sim.faults import frames_with_odometry_missing

    frames = list(open_recording(sim / "recording.log.gz").frames())
    frames = frames_with_odometry_missing(frames, len(frames) // 2, np.array([0.0, 0.0, np.radians(60.0)]))
    write_carmen(log, frames_with_odometry_missing(frames, 3 * len(frames) // 4, np.array([1.5, 0.0, 0.0])))


def _slam2d(args: list[str]) -> tuple[list[str], float, subprocess.CompletedProcess]:
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "slam2d", *args], capture_output=True, text=True,
                          env={**os.environ, "PYTHONUNBUFFERED": "1"})
    return args, time.perf_counter() - start, done


def _check(args: list[str], done: subprocess.CompletedProcess) -> None:
    if done.returncode:
        tail = "\n".join((done.stderr or done.stdout).strip().splitlines()[-5:])
        raise Slam2dError(f"compiling: 'slam2d {' '.join(args)}' failed (exit {done.returncode}):\n{tail}")


def warm_up(jobs: int | None = None, say: Callable[[str], None] = print) -> float:
    """Run the warm-up; returns its wall seconds. ``say`` gets one line per step."""
    jobs = max(1, jobs or min(os.cpu_count() or 1, 4))
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="slam2d-compile-") as tmp:
        simulate, runs, evaluate = warm_up_commands(Path(tmp))
        args, took, done = _slam2d(simulate)
        _check(args, done)
        _write_missed_turn(*_paths(Path(tmp)))
        say(f"compiled the simulator ({took:.0f} s)")
        with ThreadPoolExecutor(jobs) as pool:
            for args, took, done in pool.map(_slam2d, runs):
                _check(args, done)
                what = args[1] + (" with odometry" if "use_odometry=true" in args else "")
                say(f"compiled {what} ({took:.0f} s)")
        args, took, done = _slam2d(evaluate)
        _check(args, done)
        say(f"compiled the evaluation ({took:.0f} s)")
    return time.perf_counter() - start
