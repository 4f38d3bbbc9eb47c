"""The generated parts of docs/ match the code (run `make docs` to refresh them)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_generated_docs_are_current():
    proc = subprocess.run(
        [sys.executable, str(ROOT / "docs" / "generate.py"), "--check"], capture_output=True, text=True, cwd=ROOT
    )
    assert proc.returncode == 0, f"docs are stale, run `make docs`:\n{proc.stderr}"


def test_every_command_has_a_page():
    from slam2d.cli import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    for name in sub.choices:
        page = ROOT / "docs" / "commands" / f"{name}.md"
        assert page.is_file(), f"no docs page for `slam2d {name}`"
        assert f"<!-- BEGIN GENERATED: help:{name} -->" in page.read_text()


def test_every_method_has_a_page():
    from slam2d.methods import available

    for name in available():
        page = ROOT / "docs" / "methods" / f"{name}.md"
        assert page.is_file(), f"no docs page for method {name}"
        text = page.read_text()
        assert f"<!-- BEGIN GENERATED: method:{name} -->" in text
        for section in ("## When to choose it", "## How it fails"):
            assert section in text, f"docs/methods/{name}.md has no '{section}' section"


def test_readme_opens_with_the_two_commands():
    head = "\n".join((ROOT / "README.md").read_text().splitlines()[:20])
    assert "make demo" in head and "make test" in head
    assert "make test" in (ROOT / ".ci" / "run").read_text()


def test_the_readme_python_examples_run_as_written(tmp_path, monkeypatch):
    """Every ```python block of README.md runs (from the repository root, as the paths in it assume)."""
    import re

    from tests.conftest import dataset_file

    dataset_file("intel/intel.clf.gz")  # the examples read the shared logs: skip without them
    dataset_file("mines-exp1/mines-exp1.clf.gz")
    blocks = re.findall(r"```python\n(.*?)```", (ROOT / "README.md").read_text(), re.S)
    assert len(blocks) >= 2
    monkeypatch.chdir(ROOT)
    for block in blocks:
        # the files an example writes go to the test's folder, not the repository
        namespace: dict = {}
        exec(compile(block.replace('"intel-karto.yaml"', repr(str(tmp_path / "intel-karto.yaml"))), "README", "exec"),
             namespace)
    assert (tmp_path / "intel-karto.yaml").is_file() and len(namespace["times"]) == 910


@pytest.mark.slow
def test_the_readme_usage_lines_run_as_written(tmp_path):
    """Every line of README.md's Usage block, in order, from a folder laid out like the clone's (../shared beside
    it, params/ in it), but the hour-long sweep and the `<command> --help` template."""
    import os
    import re
    import shlex

    from tests.conftest import DATASETS

    if not DATASETS.is_dir():
        pytest.skip(f"real datasets not found at {DATASETS}")
    text = (ROOT / "README.md").read_text()
    block = re.search(r"## Usage\n\n```bash\n(.*?)```", text, re.S).group(1).replace("\\\n", " ")
    lines = [shlex.split(ln, comments=True) for ln in block.splitlines() if "<command>" not in ln]
    lines = [argv for argv in lines if argv and argv[:2] != ["slam2d", "sweep"]]
    assert len(lines) >= 19
    work = tmp_path / "clone"
    work.mkdir()
    (tmp_path / "shared").symlink_to(DATASETS.parent)
    (work / "params").symlink_to(ROOT / "params")
    import time

    took = []
    for argv in lines:
        line = " ".join(argv)
        assert argv[0] == "slam2d", line
        t0 = time.perf_counter()
        proc = subprocess.run([sys.executable, "-m", "slam2d", *argv[1:]], cwd=work, capture_output=True, text=True,
                              env={**os.environ, "PYTHONPATH": str(ROOT / "src")})
        took.append((round(time.perf_counter() - t0, 1), line))
        assert proc.returncode == 0, f"{line}\n{proc.stderr[-2000:]}"
    print("\n".join(f"{t:7.1f} s  {line}" for t, line in took))  # (pytest -s): which lines cost the time


def test_every_method_page_is_under_25_kb():
    """A method page is what a user needs (issue 35); the advanced parameters' tables are on a generated page of
    their own (docs/methods/parameters/NAME.md), the history of experiments in docs/methods/what-was-tried.md."""
    from slam2d.methods import available

    for name in available():
        page = ROOT / "docs" / "methods" / f"{name}.md"
        assert page.stat().st_size < 25_000, f"docs/methods/{name}.md is {page.stat().st_size} bytes"
        if (ROOT / "docs" / "methods" / "parameters" / f"{name}.md").is_file():
            assert f"(parameters/{name}.md)" in page.read_text(), f"docs/methods/{name}.md does not link its parameters"
    # the history of experiments is a line each; its lab notebooks are in git history
    tried = ROOT / "docs" / "methods" / "what-was-tried.md"
    assert tried.stat().st_size < 40_000, f"docs/methods/what-was-tried.md is {tried.stat().st_size} bytes"


def _anchor(heading: str) -> str:
    import re

    return re.sub(r"[^\w\- ]", "", heading.replace("`", "").strip().lower()).replace(" ", "-")


def test_relative_links_in_the_docs_lead_somewhere():
    """Every relative link of README.md and docs/ names a file that exists, and a #fragment into a Markdown page
    names one of its headings."""
    import re

    link = re.compile(r"\[(?:[^\]\[]|\[[^\]]*\])*\]\(([^)\s]+)\)")
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    anchors: dict[Path, set[str]] = {}
    dead = []
    for page in pages:
        text = re.sub(r"`[^`\n]*`", "", re.sub(r"```.*?```", "", page.read_text(), flags=re.S))
        for url in link.findall(text):
            if re.match(r"^[a-z][a-z0-9+.-]*:", url):
                continue
            path, _, fragment = url.partition("#")
            target = (page.parent / path).resolve() if path else page
            if not target.exists():
                dead.append(f"{page.relative_to(ROOT)}: {url}")
            elif fragment and target.suffix == ".md":
                if target not in anchors:
                    body = re.sub(r"```.*?```", "", target.read_text(), flags=re.S)
                    anchors[target] = {_anchor(h) for h in re.findall(r"^#{1,6}\s+(.*)$", body, re.M)}
                if fragment not in anchors[target]:
                    dead.append(f"{page.relative_to(ROOT)}: {url}")
    assert not dead, "dead links:\n" + "\n".join(dead)
