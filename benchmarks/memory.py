#!/usr/bin/env python3
"""Peak memory of every method on every shared real log, and on one log driven 1x, 2x and 4x.

    .venv/bin/python benchmarks/memory.py                          # the table (markdown on stdout)
    .venv/bin/python benchmarks/memory.py --methods karto --logs fr101
    .venv/bin/python benchmarks/memory.py --write BENCHMARKS.md     # into its section there

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

from defaults import SHARED, replace_section  # noqa: E402

LOGS = ("intel", "aces", "fr079", "fr101", "csail", "mines-exp1", "mines-exp2")
SICK = {"intel", "aces", "fr079", "fr101", "csail"}
METHODS = ("odometry", "gmapping", "karto", "lago", "hector", "coreslam", "crsm")
ODOMETRY_ON_SICK = {"hector", "coreslam"}
SECTION_BEGIN = "<!-- BEGIN memory (benchmarks/memory.py --write) -->"
SECTION_END = "<!-- END memory -->"


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
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, cwd=ROOT)
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    err = proc.stderr.read().decode(errors="replace").strip()
    proc.stderr.close()
    if proc.returncode != 0:
        print(f"{method} on {data.name}: failed: {err.splitlines()[-1] if err else proc.returncode}", file=sys.stderr)
        return None
    return usage.ru_maxrss / 1024.0  # KiB on Linux


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--methods", default=",".join(METHODS))
    parser.add_argument("--logs", default=",".join(LOGS))
    parser.add_argument("--repeat-log", default="intel", help="the log driven 1x, 2x and 4x ('' for none)")
    parser.add_argument("--write", type=Path, metavar="BENCHMARKS.md")
    args = parser.parse_args()
    methods = args.methods.split(",")
    logs = [log for log in args.logs.split(",") if (SHARED / log / f"{log}.clf.gz").is_file()]
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
            for times in (2, 4):
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


if __name__ == "__main__":
    raise SystemExit(main())
