#!/usr/bin/env python3
"""Regenerate the generated parts of docs/ from the code (run by ``make docs``).

Pages are written by hand; the parts between ``<!-- BEGIN GENERATED: key -->``
and ``<!-- END GENERATED: key -->`` come from the code, so option lists and
parameter tables cannot drift from what the program does:

* ``help:COMMAND`` — the output of ``slam2d COMMAND --help`` (``help:calibrate.laser``:
  of ``slam2d calibrate laser --help``);
* ``params:module:Class`` — the parameter table of a parameter dataclass (``params:module:Class:settings``:
  names as settings, ``name``, not flags);
* ``method:NAME`` — a registered method's parameter table (the advanced parameters folded, by group) and the
  values it logs;
* ``ros-params:ORIGIN:METHOD`` — how a slam_toolbox or slam_gmapping YAML is read for METHOD;
* ``example:NAME`` — the output of an example command on a shared dataset
  (left as it is when ``../shared/datasets`` is absent).

``--pictures`` also redraws the pictures in docs/images (needs the datasets).

With ``--check`` nothing is written and the exit status says whether the pages
are up to date (a test runs this).
"""

from __future__ import annotations

import argparse
import importlib
import os
import re
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
BLOCK = re.compile(
    r"(<!-- BEGIN GENERATED: (?P<key>[^ ]+) -->\n)(?P<body>.*?)(<!-- END GENERATED: (?P=key) -->)", re.S
)


def _help(command: str) -> str:
    from slam2d.cli import build_parser

    os.environ["COLUMNS"] = "100"  # argparse wraps to the terminal; fix it so output is stable
    parser = build_parser()
    for name in command.split("."):  # "calibrate.laser": a subcommand's subcommand
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        parser = sub.choices[name]
    text = parser.format_help()
    return "```text\n" + text.rstrip() + "\n```\n"


def _params(spec: str) -> str:
    from slam2d.params import markdown_table

    names = "flags"
    if spec.count(":") == 2:  # params:module:Class:settings names the parameters as settings, not flags
        spec, names = spec.rsplit(":", 1)
    module, cls = spec.rsplit(":", 1)
    return markdown_table(getattr(importlib.import_module(module), cls), names=names)


def _method(name: str) -> str:
    from slam2d.methods import get_method
    from slam2d.params import describe, markdown_table

    cls = get_method(name)
    role = {"required": "needs odometry.", "optional": "odometry optional (see its parameters).",
            "ignored": "ignores the odometry."}[cls.odometry_role()]
    text = f"`slam2d run {cls.name} DATA --out DIR --set NAME=VALUE`; " + role + (" Stochastic: `--seed` picks the random stream." if cls.stochastic else "") + "\n\n"
    text += markdown_table(cls.Params, names="settings")
    if any(p.advanced for p in describe(cls.Params)):
        text += "\n`run.json` records an advanced parameter only where it differs from its default.\n"
    if cls.DIAGNOSTICS:
        text += "\nLogged per update in `diagnostics.json` (besides `timestamp`, `wall_s`, `cpu_s`):\n\n"
        text += "| name | meaning |\n|---|---|\n"
        text += "".join(f"| `{k}` | {v} |\n" for k, v in cls.DIAGNOSTICS.items())
    return text


DATASETS = DOCS.parent.parent / "shared" / "datasets"

EXAMPLES = {
    "info-intel": ["info", "../shared/datasets/intel/intel.clf.gz"],
}


def _example(name: str) -> str | None:
    import contextlib
    import io

    from slam2d.cli import main

    if not DATASETS.is_dir():
        return None
    os.environ["COLUMNS"] = "100"
    buf = io.StringIO()
    cwd = os.getcwd()
    os.chdir(DOCS.parent)
    try:
        with contextlib.redirect_stdout(buf):
            main(EXAMPLES[name])
    finally:
        os.chdir(cwd)
    return "```text\n" + buf.getvalue().rstrip() + "\n```\n"


def render(key: str, old: str) -> str:
    kind, _, arg = key.partition(":")
    if kind == "help":
        return _help(arg)
    if kind == "params":
        return _params(arg)
    if kind == "method":
        return _method(arg)
    if kind == "ros-params":  # ros-params:slam_toolbox:karto
        from slam2d.io.ros_params import mapping_table
        from slam2d.methods import get_method

        origin, _, method = arg.partition(":")
        return mapping_table(origin, get_method(method).Params)
    if kind == "example":
        new = _example(arg)
        return old if new is None else new
    raise SystemExit(f"unknown generated block {key!r}")


def regenerate(text: str) -> str:
    return BLOCK.sub(lambda m: m.group(1) + render(m.group("key"), m.group("body")) + m.group(4), text)


def pictures() -> None:
    """Redraw docs/images from the shared datasets and the built-in demo."""
    import shutil
    import tempfile

    from slam2d.cli import main

    images = DOCS / "images"
    images.mkdir(exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        t = Path(tmp)
        intel = DATASETS / "intel"
        main(["map", str(intel / "intel.clf.gz"), "--poses", str(intel / "reference.tum"), "--out", str(t / "ref")])
        main(["map", str(intel / "intel.clf.gz"), "--out", str(t / "odom")])
        main(["demo", "--out", str(t / "demo")])
        shutil.copy(t / "ref" / "preview.png", images / "intel-reference.png")
        shutil.copy(t / "odom" / "preview.png", images / "intel-odometry.png")
        runs = t / "demo" / "compare" / "runs"
        shutil.copy(runs / "known-poses" / "preview.png", images / "demo-truth.png")
        shutil.copy(runs / "odometry" / "preview.png", images / "demo-odometry.png")
        _screenshot(t / "demo" / "compare" / "report.html", images / "compare-report.png", t / "browser")


def _screenshot(html: Path, png: Path, profile: Path) -> None:
    """A picture of the top of a report, rendered by headless Chromium (skipped without one)."""
    import shutil
    import subprocess

    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    if browser is None:
        print("no chromium: compare-report.png not redrawn", file=sys.stderr)
        return
    subprocess.run(
        [browser, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync", "--hide-scrollbars",
         f"--user-data-dir={profile}", "--window-size=1400,1500", f"--screenshot={png}", html.as_uri()],
        check=True, capture_output=True, timeout=120,
    )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="report stale pages, write nothing")
    parser.add_argument("--pictures", action="store_true", help="also redraw docs/images (needs datasets)")
    args = parser.parse_args()
    if args.pictures:
        pictures()
    stale = []
    for page in sorted(DOCS.rglob("*.md")):
        old = page.read_text()
        new = regenerate(old)
        if new != old:
            stale.append(page)
            if not args.check:
                page.write_text(new)
    for page in stale:
        print(f"{'stale' if args.check else 'updated'}: {page.relative_to(DOCS.parent)}", file=sys.stderr)
    return 1 if (args.check and stale) else 0


if __name__ == "__main__":
    raise SystemExit(main())
