#!/usr/bin/env python3
"""Regenerate the generated parts of docs/ from the code (run by ``make docs``).

Pages are written by hand; the parts between ``<!-- BEGIN GENERATED: key -->``
and ``<!-- END GENERATED: key -->`` come from the code, so option lists and
parameter tables cannot drift from what the program does:

* ``help:COMMAND`` — the output of ``slam2d COMMAND --help`` (``help:calibrate.laser``:
  of ``slam2d calibrate laser --help``);
* ``params:module:Class`` — the parameter table of a parameter dataclass (``params:module:Class:settings``:
  names as settings, ``name``, not flags);
* ``method:NAME`` — a registered method's parameter table (the parameters most runs set; the advanced ones
  by group on its reference page, linked) and the values it logs;
* ``ros-params:ORIGIN:METHOD`` — how a slam_toolbox or slam_gmapping YAML is read for METHOD;
* ``example:NAME`` — the output of an example command on a shared dataset
  (left as it is when ``../shared/datasets`` is absent).

Whole pages: ``methods/parameters/NAME.md``, a method's advanced parameters (a table per group),
for every registered method that has any; the folder holds nothing else.

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


PARAMETERS = DOCS / "methods" / "parameters"


def _anchor(heading: str) -> str:
    """The fragment GitHub gives a Markdown heading: lower case, punctuation dropped, spaces as dashes."""
    return re.sub(r"[^\w\- ]", "", heading.lower()).replace(" ", "-")


def _same_advanced_as(name: str) -> str | None:
    """The first registered method (by name) before ``name`` with the same advanced parameters (names, defaults,
    groups), whose page then serves both (lago's 95 are karto's); None when there is none, or when they are few
    enough (under 20) that a copy costs less than a detour."""
    from slam2d.methods import available
    from slam2d.params import describe

    def key(params):
        return [(i.name, repr(i.default), i.group) for i in describe(params) if i.advanced]

    methods = available()
    own = methods[name].Params
    for other in sorted(methods):
        if other < name and len(key(own)) >= 20 and key(own) == key(methods[other].Params):
            return other
    return None


def _method(name: str) -> str:
    from slam2d.methods import get_method
    from slam2d.params import advanced_groups, markdown_table

    cls = get_method(name)
    role = {"required": "needs odometry.", "optional": "odometry optional (see its parameters).",
            "ignored": "ignores the odometry."}[cls.odometry_role()]
    text = f"`slam2d run {cls.name} DATA --out DIR --set NAME=VALUE`; " + role + (" Stochastic: `--seed` picks the random stream." if cls.stochastic else "") + "\n\n"
    text += markdown_table(cls.Params, names="settings", advanced="omit")
    groups = advanced_groups(cls.Params)
    if groups:
        page = f"parameters/{_same_advanced_as(cls.name) or cls.name}.md"
        count = sum(map(len, groups.values()))
        text += (f"\n**Advanced**: {count} more parameters, most runs leave them at their defaults; their tables are on "
                 f"[{page}]({page}), by the feature they belong to: "
                 + ", ".join(f"[{g}]({page}#{_anchor(g)}) ({len(m)})" for g, m in groups.items())
                 + ". `run.json` records an advanced parameter only where it differs from its default.\n")
    if cls.DIAGNOSTICS:
        text += "\nLogged per update in `diagnostics.json` (besides `timestamp`, `wall_s`, `cpu_s`):\n\n"
        text += "| name | meaning |\n|---|---|\n"
        text += "".join(f"| `{k}` | {v} |\n" for k, v in cls.DIAGNOSTICS.items())
    return text


def parameter_pages() -> dict[Path, str]:
    """methods/parameters/NAME.md for every registered method with advanced parameters: a table per group."""
    from slam2d.methods import available
    from slam2d.params import advanced_groups, markdown_table

    pages = {}
    for name, cls in available().items():
        groups = advanced_groups(cls.Params)
        if not groups:
            continue
        count = sum(map(len, groups.values()))
        shared = _same_advanced_as(name)
        if shared is not None:  # one table for both, not a copy
            pages[PARAMETERS / f"{name}.md"] = (
                f"# `{name}`: advanced parameters\n\n"
                f"<!-- Written by docs/generate.py (`make docs`) from the method's parameter dataclass; do not edit. -->"
                f"\n\n[`{name}`](../{name}.md) takes the same {count} advanced parameters as `{shared}` (names, "
                f"defaults and groups): their tables are on [{shared}.md]({shared}.md) (where a help line names "
                f"`{shared}`, read `{name}`). `slam2d methods {name} --all` lists them in the terminal.\n\n"
                + "".join(f"- [{g}]({shared}.md#{_anchor(g)}) ({len(m)})\n" for g, m in groups.items()))
            continue
        pages[PARAMETERS / f"{name}.md"] = (
            f"# `{name}`: advanced parameters\n\n"
            f"<!-- Written by docs/generate.py (`make docs`) from the method's parameter dataclass; do not edit. -->\n\n"
            f"The {count} parameters of [`{name}`](../{name}.md) that most runs leave at their defaults, by the feature "
            f"they belong to; the ones most runs set are on the method page. Set any with `--set NAME=VALUE` or a "
            f"`--params` file; `slam2d methods {name} --all` lists them in the terminal. `run.json` records one only "
            f"where it differs from its default.\n\n"
            + "".join(f"- [{g}](#{_anchor(g)}) ({len(m)})\n" for g, m in groups.items()) + "\n"
            + markdown_table(cls.Params, names="settings", advanced="sections")
        )
    return pages


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
    pages = parameter_pages()
    for page in sorted(set(pages) | set(PARAMETERS.glob("*.md"))):
        new = pages.get(page)
        old = page.read_text() if page.is_file() else None
        if new != old:
            stale.append(page)
            if not args.check:
                if new is None:
                    page.unlink()
                else:
                    page.parent.mkdir(exist_ok=True)
                    page.write_text(new)
    for page in sorted(DOCS.rglob("*.md")):
        if page in pages:
            continue
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
