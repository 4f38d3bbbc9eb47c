#!/usr/bin/env python3
"""Peak memory of every method on every shared real log, and on one log driven 1x, 2x and 4x.

    .venv/bin/python benchmarks/memory.py                          # the table (markdown on stdout)
    .venv/bin/python benchmarks/memory.py --methods karto --logs fr101
    .venv/bin/python benchmarks/memory.py --write BENCHMARKS.md     # into its section there
    .venv/bin/python benchmarks/memory.py --evaluate --write BENCHMARKS.md  # slam2d evaluate of each run instead

Each run is ``slam2d run METHOD LOG`` in its own process with the method's defaults
(hector and coreslam with ``use_odometry=true`` on the SICK logs, as the defaults table runs them);
the number is that process's peak resident memory (``wait4``'s ``ru_maxrss``): reading, the run and
writing the outputs. The repeated log plays the recording forwards, backwards, forwards... (the robot
retraces its path: the same explored area with 2x and 4x the scans), so a method whose memory grows
with the scans rather than with the area shows it.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))

from defaults import SHARED, emit_section, replace_section  # noqa: E402

LOGS = ("intel", "aces", "fr079", "fr101", "csail", "mines-exp1", "mines-exp2")
SICK = {"intel", "aces", "fr079", "fr101", "csail"}
METHODS = ("odometry", "gmapping", "karto", "lago", "hector", "coreslam", "crsm")
ODOMETRY_ON_SICK = {"hector", "coreslam"}
SECTION_BEGIN = "<!-- BEGIN memory (benchmarks/memory.py --write) -->"
SECTION_END = "<!-- END memory -->"
EVALUATE_SECTION = ("<!-- BEGIN evaluate-memory (benchmarks/memory.py --evaluate --write) -->",
                    "<!-- END evaluate-memory -->")


def repeated(log: Path, times: int, out: Path) -> Path:
    """``log`` played forwards, backwards, forwards... ``times`` passes in all, as one CARMEN log."""
    sys.path.insert(0, str(ROOT / "src"))
    from dataclasses import replace

    from slam2d.core.frames import Frame
    from slam2d.io import open_recording
    from slam2d.io.carmen import write_carmen

    frames = list(open_recording(log).frames())
    t = [f.timestamp for f in frames]
    step = max(1e-3, (t[-1] - t[0]) / max(1, len(t) - 1))
    out_frames, clock = [], t[0]
    for k in range(times):
        seq = frames if k % 2 == 0 else frames[::-1]
        stamps = [f.timestamp for f in seq]
        for i, f in enumerate(seq):
            # the time since the pass began, the same spacing backwards as forwards
            when = clock + abs(stamps[i] - stamps[0])
            out_frames.append(Frame(len(out_frames), replace(f.scan, timestamp=when), f.odometry))
        clock = out_frames[-1].timestamp + step
    return write_carmen(out, out_frames)


def peak_mb(method: str, data: Path, sick: bool, work: Path) -> float | None:
    cmd = [sys.executable, "-m", "slam2d", "run", method, str(data), "--out", str(work / "run"), "--overwrite"]
    if sick and method in ODOMETRY_ON_SICK:
        cmd += ["--set", "use_odometry=true"]
    return command_peak_mb(cmd, f"{method} on {data.name}")


def command_peak_mb(cmd: list[str], what: str) -> float | None:
    """Peak resident memory (MB) of one ``slam2d`` command in its own process; None (said) when it failed."""
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, cwd=ROOT)
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    err = proc.stderr.read().decode(errors="replace").strip()
    proc.stderr.close()
    if proc.returncode != 0:
        print(f"{what}: failed: {err.splitlines()[-1] if err else proc.returncode}", file=sys.stderr)
        return None
    return usage.ru_maxrss / 1024.0  # KiB on Linux


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--methods", default=",".join(METHODS))
    parser.add_argument("--logs", default=",".join(LOGS))
    parser.add_argument("--repeat-log", default="intel", help="the log driven 1x, 2x and 4x ('' for none)")
    parser.add_argument("--times", default="2,4", help="how many times the repeated log is driven, e.g. 8 alone "
                        "(with --logs none: only those columns)")
    parser.add_argument("--write", type=Path, metavar="BENCHMARKS.md")
    parser.add_argument("--evaluate", action="store_true",
                        help="measure `slam2d evaluate RUN --reference` of each method's run on each SICK log instead")
    args = parser.parse_args()
    methods = args.methods.split(",")
    logs = [log for log in args.logs.split(",") if (SHARED / log / f"{log}.clf.gz").is_file()]
    if args.evaluate:
        return evaluate_table(methods, [log for log in logs if (SHARED / log / "reference.tum").is_file()], args.write)
    rows: dict[str, dict[str, float | None]] = {m: {} for m in methods}
    with tempfile.TemporaryDirectory(prefix="slam2d-memory-") as tmp:
        work = Path(tmp)
        columns = list(logs)
        for log in logs:
            for m in methods:
                rows[m][log] = peak_mb(m, SHARED / log / f"{log}.clf.gz", log in SICK, work)
                print(f"{m:9s} {log:11s} {rows[m][log] or float('nan'):7.0f} MB", file=sys.stderr, flush=True)
        if args.repeat_log and (SHARED / args.repeat_log / f"{args.repeat_log}.clf.gz").is_file():
            base = SHARED / args.repeat_log / f"{args.repeat_log}.clf.gz"
            for times in (int(v) for v in args.times.split(",")):
                data = repeated(base, times, work / f"{args.repeat_log}-x{times}.log.gz")
                col = f"{args.repeat_log} x{times}"
                columns.append(col)
                for m in methods:
                    rows[m][col] = peak_mb(m, data, args.repeat_log in SICK, work)
                    print(f"{m:9s} {col:11s} {rows[m][col] or float('nan'):7.0f} MB", file=sys.stderr, flush=True)
    table = ["| method | " + " | ".join(columns) + " |", "|---" * (len(columns) + 1) + "|"]
    for m in methods:
        cells = ["failed" if rows[m].get(c) is None else f"{rows[m][c]:.0f}" for c in columns]
        table.append(f"| `{m}` | " + " | ".join(cells) + " |")
    print("\n".join(table))
    if args.write:
        from datetime import datetime, timezone

        block = "\n".join([
            SECTION_BEGIN, "## Peak memory", "",
            "Peak resident memory (MB) of one `slam2d run METHOD LOG` process with the defaults (reading, the run "
            "and writing the outputs; `hector` and `coreslam` with `use_odometry=true` on the SICK logs). The "
            f"`{args.repeat_log} xN` columns drive that log N times (forwards, backwards, ...: the same area, N "
            "times the scans). The interpreter with numpy and numba's compiled code is about 155 MB of every "
            f"number. Measured {datetime.now(timezone.utc).strftime('%Y-%m-%d %H:%M UTC')}; command: "
            "`.venv/bin/python benchmarks/memory.py --write BENCHMARKS.md`.", "", *table, "", SECTION_END])
        replace_section(args.write, SECTION_BEGIN, SECTION_END, block)
    return 0


def evaluate_table(methods: list[str], logs: list[str], write: Path | None) -> int:
    """Peak memory of ``slam2d evaluate`` (map quality measures and ATE) of each method's default run."""
    rows = ["| method | " + " | ".join(logs) + " |", "|---" * (len(logs) + 1) + "|"]
    with tempfile.TemporaryDirectory(prefix="slam2d-memory-") as tmp:
        work = Path(tmp)
        for m in methods:
            cells = []
            for log in logs:
                ran = peak_mb(m, SHARED / log / f"{log}.clf.gz", log in SICK, work)
                peak = None if ran is None else command_peak_mb(
                    [sys.executable, "-m", "slam2d", "evaluate", str(work / "run"),
                     "--reference", str(SHARED / log / "reference.tum")], f"evaluate {m} on {log}")
                cells.append("failed" if peak is None else f"{peak:.0f}")
                print(f"{m:9s} {log:11s} evaluate {cells[-1]} MB", file=sys.stderr, flush=True)
            rows.append(f"| `{m}` | " + " | ".join(cells) + " |")
    from datetime import datetime, timezone

    emit_section(*EVALUATE_SECTION, "Peak memory of an evaluation",
                 "Peak resident memory (MB) of `slam2d evaluate RUN --reference reference.tum` of each method's "
                 "default run (as the peak memory table runs them): reading the run, the ATE and the map quality "
                 "measures. Target (issue 31): under 400 MB for a map under 200 m across. Measured "
                 f"{datetime.now(timezone.utc).strftime('%Y-%m-%d %H:%M UTC')}; command: "
                 "`.venv/bin/python benchmarks/memory.py --evaluate --write BENCHMARKS.md`.", rows, write)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
