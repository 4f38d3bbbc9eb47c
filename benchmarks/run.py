#!/usr/bin/env python3
"""Run slam2d's benchmarks and rewrite BENCHMARKS.md.

    .venv/bin/python benchmarks/run.py              # everything, rewrite BENCHMARKS.md
    .venv/bin/python benchmarks/run.py --only read  # cases whose name contains "read"; prints, no rewrite
    .venv/bin/python benchmarks/run.py --update NAME[,NAME]  # re-measure these cases, replace their rows

Each case runs in a fresh child process, so its peak memory (max RSS, read
with ``wait4``) is its own. A case reports the wall time of the work it
measures; cases that time a whole ``slam2d`` command report the command's
wall time as a user sees it, interpreter start-up included. Every case is run
``--repeat`` times and the median is reported; numba's compile time is kept
out of the timings by a warm-up run (``cache=True`` keeps compiled code on
disk), and measured on its own in the ``numba-compile`` case.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))

import cases  # noqa: E402  (benchmarks/cases.py)


def _run_child(name: str, workdir: Path) -> dict:
    """Run one case in a child process; return its JSON result plus peak RSS in MB."""
    cmd = [sys.executable, str(HERE / "cases.py"), name, str(workdir)]
    start = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=ROOT)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - start
    out = proc.stdout.read().decode()
    err = proc.stderr.read().decode()
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode != 0:
        raise RuntimeError(f"case {name} failed ({proc.returncode}):\n{err[-3000:]}")
    result = json.loads(out.strip().splitlines()[-1])
    result["peak_mb"] = usage.ru_maxrss / 1024.0  # Linux reports KiB
    result.setdefault("seconds", wall)
    result["process_seconds"] = wall
    return result


def _machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        mem_kb = int(Path("/proc/meminfo").read_text().split()[1])
        mem = f"{mem_kb / 1024 / 1024:.0f} GiB RAM"
    except (OSError, ValueError, IndexError):
        mem = "unknown RAM"
    import numba
    import numpy

    return (
        f"{cpu}, {os.cpu_count()} cores, {mem}; {platform.system()} {platform.release()}; "
        f"Python {platform.python_version()}, numpy {numpy.__version__}, numba {numba.__version__}"
    )


def _fmt(v: float | None, digits: int = 2) -> str:
    return "-" if v is None else f"{v:.{digits}f}"


def _fmt_seconds(v: float | None) -> str:
    """Seconds with two decimals, or three significant digits below 0.1 s (a per-scan median of 1.2 ms is not 0.00)."""
    if v is not None and 0 < v < 0.1:
        return f"{v:.3g}"
    return _fmt(v)


def _row_line(r: dict) -> str:
    c = r["case"]
    return (f"| `{c.name}` | {c.what} | {r['runs']} | {_fmt_seconds(r['seconds'])} | {_fmt(r['peak'], 0)} | "
            f"{c.target or '-'} | {r['verdict']} | {r['extra']} |")


def _restamp(line: str, measured_now: dict) -> str | None:
    """An older "Rows ... re-measured" line without the rows measured now (None when none is left)."""
    if not (line.startswith("Rows `") and " re-measured " in line):
        return line
    names, rest = line[len("Rows "):].split(" re-measured ", 1)
    keep = [n for n in names.split(", ") if n.strip("`") not in measured_now]
    return f"Rows {', '.join(keep)} re-measured {rest}" if keep else None


def _update_rows(path: Path, rows: list[dict]) -> None:
    """Replace the rows of ``rows``' cases in the case table of ``path`` (a new case goes where CASES puts it).

    A line under the header says which rows were re-measured when (a row re-measured again leaves the
    older line, which is dropped once it names no row); the file is written to a temporary
    name and renamed, so an interrupted update leaves the old file.
    """
    lines = path.read_text().splitlines()
    order = [c.name for c in cases.CASES]
    new = {r["case"].name: _row_line(r) for r in rows}

    def name_of(line: str) -> str | None:
        return line.split("`")[1] if line.startswith("| `") else None

    first = next(i for i, line in enumerate(lines) if name_of(line))
    last = first
    while last + 1 < len(lines) and name_of(lines[last + 1]):
        last += 1
    table = {name_of(line): line for line in lines[first:last + 1]}
    table.update(new)
    body = [table[n] for n in order if n in table] + [line for n, line in table.items() if n not in order]
    stamp = (f"Rows {', '.join(f'`{n}`' for n in new)} re-measured "
             f"{datetime.now(timezone.utc).strftime('%Y-%m-%d %H:%M UTC')} (`benchmarks/run.py --update`); "
             "the others as measured above.")
    head = [_restamp(line, new) for line in lines[:first]]
    head = [line for line in head if line is not None]
    at = next((i for i, line in enumerate(head) if line.startswith("Measured ")), 0) + 1
    head = head[:at] + [stamp] + head[at:]
    text = "\n".join(head + body + lines[last + 1:]) + "\n"
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    tmp.replace(path)
    print(f"updated {len(new)} rows of {path}", file=sys.stderr)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", help="run only cases whose name contains this text (no rewrite)")
    parser.add_argument("--repeat", type=int, default=None,
                        help="runs per case, the median reported (default: the case's own count, else 3)")
    parser.add_argument("--output", type=Path, default=ROOT / "BENCHMARKS.md")
    parser.add_argument("--no-methods", action="store_true",
                        help="skip the methods x datasets table (no rewrite)")
    parser.add_argument("--update", help="comma-separated case names: run them and replace (or add) their rows "
                        "in the existing --output, leaving the other rows as they were measured")
    args = parser.parse_args()

    if args.update:
        names = [n.strip() for n in args.update.split(",") if n.strip()]
        unknown = sorted(set(names) - {c.name for c in cases.CASES})
        if unknown:
            print(f"error: --update: no case named {', '.join(unknown)}", file=sys.stderr)
            return 2
        if not args.output.exists():
            print(f"error: --update: {args.output} does not exist (run the whole benchmark first)", file=sys.stderr)
            return 2
    selected = [c for c in cases.CASES if (not args.only or args.only in c.name)
                and (not args.update or c.name in names)]
    rows = []
    with tempfile.TemporaryDirectory(prefix="slam2d-bench-") as tmp:
        workdir = Path(tmp)
        for case in selected:
            if case.needs and not all((ROOT / p).exists() for p in case.needs):
                print(f"skip {case.name}: missing {case.needs}", file=sys.stderr)
                continue
            if case.warmup:
                _run_child(case.name, workdir)
            results = [_run_child(case.name, workdir) for _ in range(args.repeat or case.repeat or 3)]
            seconds = statistics.median(r["seconds"] for r in results)
            peak = max(r["peak_mb"] for r in results)
            extra = results[-1].get("extra", "")
            ok = []
            if case.max_seconds is not None:
                ok.append(seconds <= case.max_seconds)
            if case.max_peak_mb is not None:
                ok.append(peak <= case.max_peak_mb)
            verdict = "-" if not ok else ("yes" if all(ok) else "**no**")
            row = dict(case=case, seconds=seconds, peak=peak, extra=extra, verdict=verdict, runs=len(results))
            rows.append(row)
            print(f"{case.name}: {seconds:.3f} s, {peak:.0f} MB peak {extra} -> {verdict}", file=sys.stderr)

    if args.update:
        _update_rows(args.output, rows)
        return 0
    method_rows: list[dict] = []
    if not args.no_methods and not args.only:
        import methods as method_matrix  # benchmarks/methods.py

        from slam2d.methods import method_names

        with tempfile.TemporaryDirectory(prefix="slam2d-bench-methods-") as tmp:
            method_rows = method_matrix.run_matrix(method_names(), list(method_matrix.DATASETS), Path(tmp))
    if args.only or args.no_methods:
        return 0
    lines = [
        "# Benchmarks",
        "",
        "Written by `make bench` (`.venv/bin/python benchmarks/run.py`); do not edit by hand.",
        f"Measured {datetime.now(timezone.utc).strftime('%Y-%m-%d %H:%M UTC')} on: {_machine()}.",
        "",
        "Each case runs in a fresh process; time is the median of the runs, peak memory the largest "
        "max-RSS of them (the whole process: interpreter, numpy and numba included). "
        "Numba compile time is excluded by a warm-up run and shown in its own row. "
        "Reference trajectories of the real logs are GMapping results, not independent ground truth.",
        "",
        "| case | what is measured | runs | time (s) | peak memory (MB) | target | met | notes |",
        "|---|---|---|---|---|---|---|---|",
    ]
    lines += [_row_line(r) for r in rows]
    # the defaults-on-every-log section is written by benchmarks/defaults.py; kept as it is
    import defaults  # benchmarks/defaults.py

    old = args.output.read_text() if args.output.is_file() else ""
    if defaults.SECTION_BEGIN in old and defaults.SECTION_END in old:
        kept = old.split(defaults.SECTION_BEGIN, 1)[1].split(defaults.SECTION_END, 1)[0]
        lines += ["", defaults.SECTION_BEGIN + kept + defaults.SECTION_END]
    lines += [
        "",
        "## Methods x datasets",
        "",
        "Every registered method on every dataset through `slam2d compare` with `--jobs 1` (each method "
        "alone in its own process; peak memory is that process's max RSS). Simulated worlds "
        f"({method_matrix.describe_simulated()}; the lasers are slam2d.sim's presets; seed 0, one pass of each "
        "world's path unless a duration is given) are judged against their exact truth, trajectory and "
        "map; the real logs against their `reference.tum`, a GMapping result and not independent ground "
        "truth (so `known-poses` scores 0 there by construction, and no map error is computed); the "
        "Mines logs have no reference. Metrics are defined in [docs/evaluation.md](docs/evaluation.md).",
        "",
        *method_matrix.markdown(method_rows),
        "",
        "Command: `make bench` (`.venv/bin/python benchmarks/run.py`); the table alone: "
        "`.venv/bin/python benchmarks/methods.py`.",
        "",
    ]
    args.output.write_text("\n".join(lines))
    print(f"wrote {args.output}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
