"""The comparison report: report.html (self-contained) and report.md (with PNGs), from a real comparison."""

from __future__ import annotations

import base64
import copy
import dataclasses
import re
from html import escape
from pathlib import Path

import numpy as np
import pytest

from slam2d.eval.compare import Comparison, MethodOutcome, compare
from slam2d.eval.evaluate import METRIC_COLUMNS, load_reference, load_truth
from slam2d.grids.occupancy import OccupancyGrid
from slam2d.report.comparison import BEST_MARK, write_report
from slam2d.report.plots import common_canvas
from tests import browser

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


# --------------------------------------------------------------------------- fixtures


@pytest.fixture(scope="module")
def sim(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 15 s paper-arena recording with its truth trajectory and map."""
    from slam2d.cli import main

    out = tmp_path_factory.mktemp("sim")
    assert main(["simulate", "paper-arena", "--out", str(out), "--duration", "15"]) == 0
    return out


@pytest.fixture(scope="module")
def comparison(sim: Path, tmp_path_factory: pytest.TempPathFactory) -> Comparison:
    """odometry and known-poses really run and evaluated against the truth, plus one failed method."""
    out = tmp_path_factory.mktemp("compare")
    result = compare(sim / "recording.log.gz", ["odometry", "known-poses"], out, truth=load_truth(sim),
                     jobs=2, command="slam2d compare (test)")
    assert [o.status for o in result.outcomes] == ["ok", "ok"], [o.error for o in result.outcomes]
    result.outcomes.append(MethodOutcome(
        "gmapping", "failed", out / "runs" / "gmapping", params={"particles": 30},
        error="ValueError: scan 17 has 3 beams | expected 682",
        details='Traceback (most recent call last):\n  File "gmapping.py", line 1\nValueError: scan 17 has 3 beams',
    ))
    return result


@pytest.fixture(scope="module")
def report(comparison: Comparison, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("report")
    written = write_report(comparison, out)
    assert written[:2] == [out / "report.html", out / "report.md"]
    assert all(p.is_file() for p in written)
    return out


def _md_table(md: str) -> dict[str, list[str]]:
    """The metric table of report.md: header and one list of cells per method."""
    lines = [line for line in md.split("## Metrics", 1)[1].splitlines() if line.startswith("|")]
    split = [[c.strip() for c in re.split(r"(?<!\\)\|", line)[1:-1]] for line in lines]
    return {"header": split[0], **{row[0]: row[1:] for row in split[2:]}}


# --------------------------------------------------------------------------- content


def test_one_map_per_method_plus_truth(report: Path) -> None:
    html = (report / "report.html").read_text()
    md = (report / "report.md").read_text()
    assert html.count('class="map-panel"') == 3
    for map_id in ("map-truth", "map-odometry", "map-known-poses"):
        assert f'id="{map_id}"' in html
    assert re.findall(r"!\[map: ([^\]]+)\]", md) == ["truth map", "odometry", "known-poses"]
    # every map panel has the same pixel size: one canvas, one scale
    sizes = {(report / "images" / f"{m}.png").read_bytes()[16:24] for m in ("map-truth", "map-odometry", "map-known-poses")}
    assert len(sizes) == 1


def test_metric_columns_with_values_appear(report: Path, comparison: Comparison) -> None:
    html = (report / "report.html").read_text()
    header = _md_table((report / "report.md").read_text())["header"]
    evaluations = [o.evaluation for o in comparison.outcomes if o.ok]
    with_values = [c for c in METRIC_COLUMNS if any(c.value(ev) is not None for ev in evaluations)]
    without = [c for c in METRIC_COLUMNS if c not in with_values]
    assert len(with_values) >= 10 and any(c.key[0] == "relations" for c in without)  # no relations file given
    shown = [h.split(" [")[0] for h in header[1:]]
    assert shown == [c.label for c in with_values]
    for column in with_values:
        assert f'title="{escape(column.help)}' in html  # the column's tooltip
    for column in without:
        assert column.label not in shown


def test_real_runs_mark_the_truth_pose_map_better(report: Path, comparison: Comparison) -> None:
    # known-poses maps along the exact truth, odometry along drifting odometry: its ATE must be lower.
    table = _md_table((report / "report.md").read_text())
    ate = table["header"].index("ATE [m]") - 1
    assert BEST_MARK in table["known-poses"][ate]
    assert BEST_MARK not in table["odometry"][ate]


def _evaluation(ate: float, precision: float, corners: int, time_s: float, alignment: list[float]) -> dict:
    return {
        "alignment": alignment,
        "alignment_source": "trajectory",
        "trajectory": {"ate": {"translation_m": {"rmse": ate}}},
        "map_truth": {"precision": precision},
        "map_quality": {"corners": corners},
        "cost": {"wall_s_per_scan": {"median": time_s}},
    }


def test_best_value_marked_per_column(comparison: Comparison, tmp_path: Path) -> None:
    odo, known = (copy.deepcopy(o) for o in comparison.outcomes[:2])
    # odometry: lower ATE (better), lower precision (worse); corners have no better direction; times tie.
    odo.evaluation = _evaluation(0.10, 0.50, 40, 0.002, odo.alignment)
    known.evaluation = _evaluation(0.30, 0.90, 12, 0.002, known.alignment)
    c = dataclasses.replace(comparison, outcomes=[odo, known])
    write_report(c, tmp_path)
    table = _md_table((tmp_path / "report.md").read_text())
    by_key = {c.key: c for c in METRIC_COLUMNS}
    columns = [by_key[k] for k in (("trajectory", "ate", "translation_m", "rmse"), ("map_truth", "precision"),
                                   ("map_quality", "corners"), ("cost", "wall_s_per_scan", "median"))]
    assert [c.better for c in columns] == ["lower", "higher", None, "lower"]
    assert table["header"] == ["method"] + [f"{c.label} [{c.unit}]" if c.unit else c.label for c in columns]
    assert table["odometry"] == [f"**0.100 {BEST_MARK}**", "0.500", "40", f"**2.00 {BEST_MARK}**"]
    assert table["known-poses"] == ["0.300", f"**0.900 {BEST_MARK}**", "12", f"**2.00 {BEST_MARK}**"]
    html = (tmp_path / "report.html").read_text()
    assert html.count('class="num best"') == 4
    assert html.count(BEST_MARK) == 4 + html.count(f"{BEST_MARK} and bold")


def test_failed_method_reported_and_others_shown(report: Path) -> None:
    html = (report / "report.html").read_text()
    md = (report / "report.md").read_text()
    row = _md_table(md)["gmapping"]
    assert row[0] == r"**failed: ValueError: scan 17 has 3 beams \| expected 682**"
    assert "failed: ValueError: scan 17 has 3 beams | expected 682" in html
    assert re.search(r"<details><summary>details</summary><pre>Traceback.*ValueError: scan 17", html, re.S)
    assert "## Failed methods" in md and "Traceback (most recent call last)" in md
    assert 'id="map-gmapping"' not in html
    assert 'id="diagnostics-odometry"' in html and 'id="diagnostics-known-poses"' in html


def test_ok_run_with_unreadable_folder_does_not_break_the_report(comparison: Comparison, tmp_path: Path) -> None:
    broken = copy.deepcopy(comparison.outcomes[0])
    broken.method = "odometry-copy"
    broken.run_dir = tmp_path / "gone"
    c = dataclasses.replace(comparison, outcomes=[comparison.outcomes[1], broken])
    write_report(c, tmp_path / "out")
    html = (tmp_path / "out" / "report.html").read_text()
    assert "run folder unreadable" in html and str(tmp_path / "gone") in html
    assert html.count('class="map-panel"') == 2  # truth + known-poses


def test_diagnostics_and_parameters(report: Path) -> None:
    html = (report / "report.html").read_text()
    md = (report / "report.md").read_text()
    assert "![diagnostics: odometry](images/diagnostics-odometry.png)" in md
    assert "<details><summary>parameters (" in html
    assert re.search(r"<td>resolution</td><td class=\"num\">0.05</td>", html)
    assert "finish_wall_s" in html  # a summary value


def test_reference_is_not_called_ground_truth(comparison: Comparison, sim: Path, tmp_path: Path) -> None:
    c = dataclasses.replace(comparison, truth=load_reference(sim / "truth.tum"))
    write_report(c, tmp_path)
    for name in ("report.html", "report.md"):
        text = (tmp_path / name).read_text()
        assert "NOT independent ground truth" in text
    html = (tmp_path / "report.html").read_text()
    assert html.count('class="map-panel"') == 2  # no reference map given
    # every caption, title and fact says what the runs were aligned to: a reference, not the truth
    assert "aligned to the reference" in html and "Alignment to the reference" in html
    assert "to the truth" not in html and "truth's frame" not in html
    assert 'id="error-along-run"' in html


def test_the_error_along_the_run_is_drawn_only_against_a_trajectory(report: Path, comparison: Comparison,
                                                                    tmp_path: Path) -> None:
    html = (report / "report.html").read_text()
    assert 'id="error-along-run"' in html and "aligned to the truth" in html
    outcomes = [copy.deepcopy(o) for o in comparison.outcomes]
    for o in outcomes:
        if o.evaluation:
            o.evaluation = {k: v for k, v in o.evaluation.items() if k in ("map_quality", "cost")}
    write_report(dataclasses.replace(comparison, truth=None, outcomes=outcomes), tmp_path)
    assert 'id="error-along-run"' not in (tmp_path / "report.html").read_text()


def test_a_long_summary_list_is_counted_not_printed(comparison: Comparison, tmp_path: Path) -> None:
    # karto's loop_attempts: a list of dicts, 1070 characters in a cell made the page scroll sideways
    import json

    run = comparison.outcomes[0].run_dir
    diagnostics = json.loads((run / "diagnostics.json").read_text())
    diagnostics["summary"]["loop_attempts"] = [{"to": k, "response_coarse": 0.5, "chain": [0, 12]} for k in range(19)]
    copied = tmp_path / "run"
    import shutil

    shutil.copytree(run, copied)
    (copied / "diagnostics.json").write_text(json.dumps(diagnostics))
    outcomes = [dataclasses.replace(copy.deepcopy(comparison.outcomes[0]), run_dir=copied)]
    write_report(dataclasses.replace(comparison, outcomes=outcomes), tmp_path / "out")
    html = (tmp_path / "out" / "report.html").read_text()
    assert "19 entries (summary.loop_attempts in" in html and "response_coarse" not in html


def test_without_truth_maps_in_own_frames(comparison: Comparison, tmp_path: Path) -> None:
    outcomes = [copy.deepcopy(o) for o in comparison.outcomes]
    for o in outcomes:
        if o.evaluation:
            o.evaluation = {k: v for k, v in o.evaluation.items() if k in ("map_quality", "cost")}
    write_report(dataclasses.replace(comparison, truth=None, outcomes=outcomes), tmp_path)
    md = (tmp_path / "report.md").read_text()
    assert "No ground truth or reference was given" in md
    assert "each run's own frame" in md
    assert re.findall(r"!\[map: ([^\]]+)\]", md) == ["odometry", "known-poses"]
    assert "ATE" not in _md_table(md)["header"]


# --------------------------------------------------------------------------- files


def test_markdown_images_exist_and_are_png(report: Path) -> None:
    md = (report / "report.md").read_text()
    links = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", md)
    assert len(links) == 9  # 3 maps, self-disagreement along the run, trajectories, error along the run, time per scan, 2 diagnostics
    for link in links:
        assert not link.startswith(("/", "http")), link
        path = report / link
        assert path.is_file(), link
        assert path.read_bytes()[:8] == PNG_SIGNATURE
    assert not list(report.rglob("*.partial*"))  # atomic writes left nothing behind


def test_html_is_self_contained(report: Path) -> None:
    html = (report / "report.html").read_text()
    assert not re.search(r"""(src|href)\s*=\s*["']?(https?:|//)""", html, re.I)
    assert "<link" not in html and "@import" not in html and "url(" not in html
    sources = re.findall(r'<img [^>]*src="([^"]+)"', html)
    assert len(sources) == 9
    for src in sources:
        assert src.startswith("data:image/png;base64,")
        assert base64.b64decode(src.split(",", 1)[1])[:8] == PNG_SIGNATURE
    assert "dataset.imagesLoaded" in html and 'id="image-check"' in html


def test_browser_loads_every_image(report: Path) -> None:
    loaded, total = browser.images_loaded(report / "report.html")
    assert total == 9
    assert loaded == total


def test_browser_page_does_not_scroll_sideways_at_1280_px(report: Path) -> None:
    dom = browser.dump_dom(report / "report.html", width=1280)
    overflow = re.search(r'data-page-overflow="(-?\d+)"', dom)
    scale = re.search(r'data-smallest-figure-scale="(\d+)"', dom)
    assert overflow and scale, "the report's load script did not record the layout"
    assert int(overflow.group(1)) <= 0
    assert int(scale.group(1)) >= 50  # no figure shrunk below half its size: its type stays readable


def test_browser_flags_a_broken_image(report: Path, tmp_path: Path) -> None:
    # The check must be able to fail: corrupt one picture and it is counted as not loaded.
    html = (report / "report.html").read_text()
    broken = re.sub(r'(id="trajectories" class="plot" alt="[^"]*" src="data:image/png;base64,)[^"]{40}',
                    r"\1" + "A" * 40, html, count=1)
    assert broken != html
    (tmp_path / "broken.html").write_text(broken)
    loaded, total = browser.images_loaded(tmp_path / "broken.html")
    assert (loaded, total) == (8, 9)


# --------------------------------------------------------------------------- the common canvas


def test_canvas_puts_a_moved_map_where_its_transform_says() -> None:
    occ = np.zeros((20, 40), dtype=np.int8)  # 4 m x 2 m, free
    occ[:, 38:] = 100
    grid = OccupancyGrid.from_occupancy(occ, 0.1, (0.0, 0.0))
    # the wall at x in [3.8, 4.0]; turned by 90 deg and shifted by (10, 0): it lands at y in [3.8, 4.0], x in [8, 10]
    canvas = common_canvas([grid, grid], [None, [10.0, 0.0, np.pi / 2]])
    xmin, ymin, xmax, ymax = canvas.extent
    assert canvas.metres_per_pixel == pytest.approx(0.1)
    assert xmin <= 0.0 and ymin <= 0.0 and xmax >= 10.0 and ymax >= 4.0
    moved = canvas.images[1]

    def at(img, x, y):
        col = int((x - xmin) / canvas.metres_per_pixel)
        row = int((ymax - y) / canvas.metres_per_pixel)
        return img[row, col]

    assert at(moved, 9.0, 3.9) == 0.0  # wall: black
    assert at(moved, 9.0, 2.0) == 1.0  # free: white
    assert at(moved, 3.9, 1.0) == pytest.approx(205 / 255)  # only the unmoved map is here: unknown grey
    assert at(canvas.images[0], 3.9, 1.0) == 0.0
    assert canvas.images[0].shape == moved.shape


@pytest.mark.parametrize("max_pixels", [100, 70, 23])
def test_canvas_keeps_thin_walls_when_coarser_than_the_map(max_pixels: int) -> None:
    occ = np.zeros((400, 400), dtype=np.int8)
    occ[:, 201] = 100  # a wall one 1 cm cell thick in a 4 m map, drawn on a canvas of 4 cm or more per pixel
    occ[137, :] = 100
    grid = OccupancyGrid.from_occupancy(occ, 0.01, (0.0, 0.0))
    canvas = common_canvas([grid], [None], max_pixels=max_pixels)
    assert canvas.metres_per_pixel == pytest.approx(4.0 / max_pixels)
    image = canvas.images[0]
    assert (image.min(axis=1) == 0.0).all()  # the vertical wall shows on every row
    assert (image.min(axis=0) == 0.0).all()  # the horizontal one in every column
    assert (image == 1.0).mean() > 0.5  # and the free space stays free
