#!/usr/bin/env python3
"""First run against second in a fresh clone: does any run still pay for compilation?

    .venv/bin/python benchmarks/first_run.py                    # the table on stdout
    .venv/bin/python benchmarks/first_run.py --write BENCHMARKS.md
    .venv/bin/python benchmarks/first_run.py --make-demo        # `make demo` in a fresh clone, timed

Clones this repository's HEAD into a temporary folder (so numba's on-disk cache
starts empty), runs ``slam2d compile`` there as ``make`` does after installing,
then runs ``slam2d run METHOD LOG`` twice per method (this venv's Python, the
clone's sources) and reports the whole command's wall time both times.
``--no-compile`` shows what the first run costs without it.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
SHARED = ROOT.parent / "shared" / "datasets"
sys.path.insert(0, str(HERE))

METHODS = ("karto", "lago", "gmapping", "hector", "coreslam", "crsm")
SECTION_BEGIN = "<!-- BEGIN first-run (benchmarks/first_run.py --write) -->"
SECTION_END = "<!-- END first-run -->"


def _timed(clone: Path, args: list[str]) -> float:
    env = {**os.environ, "PYTHONPATH": str(clone / "src")}
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "slam2d", *args], cwd=clone, env=env, capture_output=True, text=True)
    took = time.perf_counter() - start
    if done.returncode:
        raise SystemExit(f"slam2d {' '.join(args)} failed:\n{done.stderr[-2000:]}")
    return took


def _make_demo() -> int:
    """Wall time of `make demo` in a fresh clone, and of its three steps (install, compile, the paper)."""
    with tempfile.TemporaryDirectory(prefix="slam2d-make-demo-") as tmp:
        clone = Path(tmp) / "clone"
        subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True)
        env = {k: v for k, v in os.environ.items() if k not in ("VIRTUAL_ENV", "PYTHONPATH")}
        start = time.perf_counter()
        marks: dict[str, float] = {}
        proc = subprocess.Popen(["make", "demo"], cwd=clone, env=env, stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT, text=True)
        assert proc.stdout is not None
        for line in proc.stdout:
            for step in ("slam2d compile", "slam2d paper"):
                if step in line and step not in marks:
                    marks[step] = time.perf_counter() - start
        if proc.wait():
            raise SystemExit("make demo failed")
        total = time.perf_counter() - start
    install = marks.get("slam2d compile", float("nan"))
    compile_s = marks.get("slam2d paper", float("nan")) - install
    print(f"make demo in a fresh clone: {total:.0f} s (install {install:.0f} s, compile {compile_s:.0f} s, "
          f"paper --quick {total - install - compile_s:.0f} s)")
    return 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--methods", default=",".join(METHODS))
    parser.add_argument("--log", default="intel", help="a shared log (default: intel)")
    parser.add_argument("--no-compile", action="store_true", help="skip 'slam2d compile' (the cost without it)")
    parser.add_argument("--write", type=Path, metavar="BENCHMARKS.md")
    parser.add_argument("--make-demo", action="store_true",
                        help="instead: time `make demo` in a fresh clone (its own .venv; pip's cache is used)")
    args = parser.parse_args()
    if args.make_demo:
        return _make_demo()
    log = SHARED / args.log / f"{args.log}.clf.gz"
    if not log.is_file():
        raise SystemExit(f"{log}: not found (the shared datasets are beside the clone)")
    lines = ["| method | first run (s) | second run (s) | first / second |", "|---|---|---|---|"]
    with tempfile.TemporaryDirectory(prefix="slam2d-first-run-") as tmp:
        clone = Path(tmp) / "clone"
        subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True)
        compile_s = None if args.no_compile else _timed(clone, ["compile"])
        for method in args.methods.split(","):
            settings = ["--set", "use_odometry=true"] if method in ("hector", "coreslam") else []
            times = [_timed(clone, ["run", method, str(log), *settings, "--out", str(Path(tmp) / f"{method}-{i}")])
                     for i in (1, 2)]
            lines.append(f"| `{method}` | {times[0]:.1f} | {times[1]:.1f} | {times[0] / times[1]:.2f} |")
            print(lines[-1], file=sys.stderr, flush=True)
    from datetime import datetime, timezone

    when = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    head = (f"`slam2d run METHOD {args.log}` in a fresh clone, whole command's wall time, "
            + ("without `slam2d compile`" if compile_s is None else
               f"after `slam2d compile` ({compile_s:.0f} s, as `make` runs it after installing)")
            + f". Measured {when}; command: `.venv/bin/python benchmarks/first_run.py"
            + (" --no-compile" if compile_s is None else "") + " --write BENCHMARKS.md`.")
    from defaults import emit_section

    emit_section(SECTION_BEGIN, SECTION_END, "First run in a fresh clone", head, lines, args.write)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
