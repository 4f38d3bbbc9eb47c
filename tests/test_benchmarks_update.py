"""benchmarks/run.py --update: re-measured rows replace their own, the rest of BENCHMARKS.md stays."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _run_module():
    sys.path.insert(0, str(ROOT / "benchmarks"))
    spec = importlib.util.spec_from_file_location("bench_run", ROOT / "benchmarks" / "run.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_update_replaces_only_the_measured_rows_and_adds_new_ones_in_case_order(tmp_path):
    run = _run_module()
    names = [c.name for c in run.cases.CASES]
    a, b, c = names[0], names[1], names[2]
    path = tmp_path / "BENCHMARKS.md"
    path.write_text("\n".join([
        "# Benchmarks", "", "Measured 2026-01-01 00:00 UTC on: a machine.", "",
        "| case | what is measured | runs | time (s) | peak memory (MB) | target | met | notes |",
        "|---|---|---|---|---|---|---|---|",
        f"| `{a}` | old a | 1 | 1.00 | 10 | - | - | a notes |",
        f"| `{c}` | old c | 1 | 3.00 | 30 | - | - | c notes |",
        "", "## Methods x datasets", "", "kept table", ""]))
    by_name = {x.name: x for x in run.cases.CASES}
    rows = [dict(case=by_name[c], seconds=9.5, peak=99.0, extra="new c", verdict="-", runs=1),
            dict(case=by_name[b], seconds=0.05, peak=5.0, extra="new b", verdict="-", runs=1)]
    run._update_rows(path, rows)
    lines = path.read_text().splitlines()
    table = [line for line in lines if line.startswith("| `")]
    assert [line.split("`")[1] for line in table] == [a, b, c]
    assert table[0].endswith("| a notes |") and "new c" in table[2] and "9.50" in table[2] and "new b" in table[1]
    assert any(line.startswith("Rows ") and f"`{c}`" in line for line in lines)
    assert "kept table" in lines and "Measured 2026-01-01 00:00 UTC on: a machine." in lines


def test_update_keeps_one_stamp_per_row(tmp_path):
    """A row re-measured again leaves its older stamp line; a stamp line naming no row any more goes."""
    run = _run_module()
    names = [c.name for c in run.cases.CASES]
    a, b = names[0], names[1]
    by_name = {x.name: x for x in run.cases.CASES}
    path = tmp_path / "BENCHMARKS.md"
    path.write_text("\n".join([
        "# Benchmarks", "", "Measured 2026-01-01 00:00 UTC on: a machine.",
        f"Rows `{a}`, `{b}` re-measured 2026-01-02 00:00 UTC (`benchmarks/run.py --update`); the others as measured above.",
        f"Rows `{b}` re-measured 2026-01-03 00:00 UTC (`benchmarks/run.py --update`); the others as measured above.",
        "",
        "| case | what is measured | runs | time (s) | peak memory (MB) | target | met | notes |",
        "|---|---|---|---|---|---|---|---|",
        f"| `{a}` | old a | 1 | 1.00 | 10 | - | - | a notes |",
        f"| `{b}` | old b | 1 | 2.00 | 20 | - | - | b notes |", ""]))
    run._update_rows(path, [dict(case=by_name[b], seconds=0.05, peak=5.0, extra="new b", verdict="-", runs=1)])
    stamps = [line for line in path.read_text().splitlines() if line.startswith("Rows ")]
    assert len(stamps) == 2
    assert stamps[0].startswith(f"Rows `{b}` re-measured ") and "2026-01-0" not in stamps[0]
    assert stamps[1].startswith(f"Rows `{a}` re-measured 2026-01-02 00:00 UTC")


def test_update_refuses_an_unknown_case(tmp_path, monkeypatch, capsys):
    run = _run_module()
    (tmp_path / "B.md").write_text("# Benchmarks\n")
    monkeypatch.setattr(sys, "argv", ["run.py", "--update", "no-such-case", "--output", str(tmp_path / "B.md")])
    assert run.main() == 2
    assert "no-such-case" in capsys.readouterr().err
