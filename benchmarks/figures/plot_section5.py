#!/usr/bin/env python3
"""Copy the Section V experiments' pictures into docs/images (experiment-*.png).

Runs ``slam2d experiment`` in full mode, seed 0, for the experiments pictured on
docs/commands/experiment.md (several CPU minutes), or takes the folders of an
earlier run with ``--from DIR`` (DIR/NAME for each experiment, as ``slam2d experiment
NAME --out DIR/NAME`` writes them):

    .venv/bin/python benchmarks/figures/plot_section5.py [--from DIR]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from slam2d.experiments.section5 import run_experiment
from slam2d.io.atomic import write_bytes_atomic

IMAGES = Path(__file__).resolve().parents[2] / "docs" / "images"
#: experiment -> the figure shown on the page
PICTURES = {
    "can": "figures/maps.png",
    "broken-wall": "figures/maps.png",
    "rebound": "figures/maps.png",
    "entropy": "figures/entropy.png",
    "new-conditions": "figures/new-conditions.png",
    "held-out": "figures/ate.png",
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--from", dest="source", type=Path, help="folder of earlier full runs (DIR/NAME)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        for name, rel in PICTURES.items():
            folder = (args.source or Path(tmp)) / name
            if args.source is None:
                run_experiment(name, folder, quick=False, seed=0)
            target = IMAGES / f"experiment-{name}.png"
            write_bytes_atomic(target, (folder / rel).read_bytes())
            print(f"wrote {target}")


if __name__ == "__main__":
    main()
