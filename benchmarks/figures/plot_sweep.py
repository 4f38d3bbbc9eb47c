#!/usr/bin/env python3
"""Run sweeps/odometry-noise.yaml and copy two of its plots into docs/images/sweep-*.png.

    .venv/bin/python benchmarks/figures/plot_sweep.py [--workers N]
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
from pathlib import Path

from slam2d.sweep import load_spec, run_sweep

DOCS = Path(__file__).resolve().parents[2] / "docs"
SPEC = DOCS.parent / "sweeps" / "odometry-noise.yaml"
PICTURES = {"ate-vs-srr.png": "sweep-ate-vs-srr.png", "map_error-vs-resolution.png": "sweep-map-error-vs-resolution.png"}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--workers", type=int, default=None)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        result = run_sweep(load_spec(SPEC), Path(tmp), workers=args.workers)
        if result.failed:
            raise SystemExit(f"{len(result.failed)} runs failed: {result.failed[0]['error']}")
        for name, target in PICTURES.items():
            shutil.copy(Path(tmp) / "plots" / name, DOCS / "images" / target)
            print(f"wrote {DOCS / 'images' / target}")


if __name__ == "__main__":
    main()
