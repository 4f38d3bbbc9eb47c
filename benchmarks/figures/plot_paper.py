"""Draw docs/images/paper-report.png: the top of the report `slam2d paper --quick` writes.

Run from the repository: `.venv/bin/python benchmarks/figures/plot_paper.py` (about half a minute; needs Chromium).
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

DOCS = Path(__file__).resolve().parents[2] / "docs"
sys.path.insert(0, str(DOCS))

from generate import _screenshot  # noqa: E402  (one way of taking screenshots for every docs picture)


def main() -> int:
    from slam2d.cli import main as slam2d

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "paper"
        args = ["paper", "--out", str(out), "--quick"]
        sys.argv = ["slam2d", *args]  # the report records the command line it was given
        status = slam2d(args)
        if status not in (0, 1):
            return status
        _screenshot(out / "report.html", DOCS / "images" / "paper-report.png", Path(tmp) / "browser")
    print(f"wrote {DOCS / 'images' / 'paper-report.png'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
