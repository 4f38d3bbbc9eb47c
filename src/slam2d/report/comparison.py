"""The comparison report: ``report.html`` (self-contained) and ``report.md`` (with PNGs) from a :class:`Comparison`.

What it shows, for an engineer choosing a method: the data and what the runs
were judged against; the metric table with the best value in each column
marked; every map side by side at one scale and orientation, in the truth's
frame when the runs were aligned to it; the trajectories over the truth; the
time each method took per scan; each method's own diagnostics, counters and
parameters; and why any method failed.

``report.html`` carries every picture inline (``data:`` URIs) and its CSS and a
small script inline, so it opens from disk with no network; the script checks
on load that every picture decoded, records ``"<loaded>/<total>"`` in
``<html data-images-loaded>``, and shows a red banner naming any that did not.
``report.md`` links the same pictures, written as PNG files in ``images/``.
"""

from __future__ import annotations

import base64
import html
import json
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slam2d.core import se2
from slam2d.errors import InputError, one_line
from slam2d.eval.compare import Comparison, MethodOutcome
from slam2d.eval.evaluate import ATE, METRIC_COLUMNS, MetricColumn, RunFiles, load_run
from slam2d.eval.self_consistency import AREA_TOLERANCE, SCALE_TOLERANCE, ConsistencyParams
from slam2d.io.atomic import write_bytes_atomic, write_text_atomic
from slam2d.report import plots

__all__ = ["write_report", "REPORT_HTML", "REPORT_MD", "IMAGES_DIR", "BEST_MARK"]

REPORT_HTML = "report.html"
REPORT_MD = "report.md"
IMAGES_DIR = "images"
BEST_MARK = "★"
_BUILT_IN_SERIES = ("timestamp", "wall_s", "cpu_s")


# --------------------------------------------------------------------------- what the report is made of


@dataclass
class _Entry:
    """One method of the comparison, with what its run folder holds."""

    outcome: MethodOutcome
    label: str  # unique name in this report
    slug: str  # for file names and HTML ids
    colour: str
    run: RunFiles | None = None
    run_error: str | None = None  # an ok outcome whose folder could not be read

    @property
    def shown(self) -> bool:
        """Whether the run has files to draw."""
        return self.outcome.ok and self.run is not None


@dataclass
class _Image:
    name: str  # file name under images/, and the HTML id without ".png"
    alt: str
    png: bytes
    caption: str = ""

    @property
    def id(self) -> str:
        return self.name.removesuffix(".png")


@dataclass
class _Cell:
    text: str
    best: bool = False


@dataclass
class _Row:
    entry: _Entry
    cells: list[_Cell] = field(default_factory=list)
    failed: str | None = None  # the one-line reason, for a row with no values


@dataclass
class _MethodSection:
    entry: _Entry
    facts: list[tuple[str, str]]
    figure: _Image | None
    no_series: str  # why there is no figure
    counters: list[tuple[str, str]]
    summary: list[tuple[str, str]]
    params: list[tuple[str, str]]


@dataclass
class _Report:
    title: str
    facts: list[tuple[str, str]]
    verdict: str | None  # the reference-free verdict in one sentence
    evidence: list[list[str]]  # its table: one row per judged run, best first
    disagreement: _Image | None  # the per-scan curves
    judged: str  # one paragraph: what the runs were judged against
    judged_warning: bool  # a reference (not ground truth) or nothing: shown as a warning
    columns: list[MetricColumn]
    rows: list[_Row]
    table_notes: list[str]
    maps: list[_Image]
    maps_note: str
    trajectories: _Image | None
    trajectories_note: str
    error: _Image | None
    timing: _Image | None
    sections: list[_MethodSection]
    failures: list[_Entry]


# --------------------------------------------------------------------------- public entry point


def write_report(comparison: Comparison, out_dir: Path) -> list[Path]:
    """Write ``out_dir/report.html``, ``out_dir/report.md`` and its PNGs in ``out_dir/images/``; return their paths.

    Every file is written atomically. A failed method, or an ok method whose
    run folder cannot be read, is reported as such and does not stop the
    report.
    """
    out_dir = Path(out_dir)
    report = _build(comparison)
    images = [*report.maps, report.disagreement, report.trajectories, report.error, report.timing,
              *(s.figure for s in report.sections)]
    images = [im for im in images if im is not None]
    written: list[Path] = []
    for image in images:
        path = out_dir / IMAGES_DIR / image.name
        write_bytes_atomic(path, image.png)
        written.append(path)
    md_path = out_dir / REPORT_MD
    write_text_atomic(md_path, _markdown(report))
    html_path = out_dir / REPORT_HTML
    write_text_atomic(html_path, _html(report))
    return [html_path, md_path, *written]


# --------------------------------------------------------------------------- gathering


def _slug(text: str) -> str:
    return re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-") or "method"


def _entries(outcomes: Sequence[MethodOutcome]) -> list[_Entry]:
    colours = plots.method_colours(len(outcomes))
    seen: dict[str, int] = {}
    entries = []
    for outcome, colour in zip(outcomes, colours):
        seen[outcome.method] = seen.get(outcome.method, 0) + 1
        label = outcome.method if seen[outcome.method] == 1 else f"{outcome.method} #{seen[outcome.method]}"
        entry = _Entry(outcome, label, _slug(label), colour)
        if outcome.ok:
            try:
                entry.run = load_run(outcome.run_dir)
                if entry.run.map_image is not None:  # the picture is all the report needs of a map
                    entry.run.map = plots.MapRaster.of(entry.run.map_image)
            except (InputError, OSError) as exc:
                entry.run_error = f"run folder unreadable: {exc}"
        entries.append(entry)
    # Labels like "a #2" could collide with a method literally named so; make slugs unique anyway.
    used: set[str] = set()
    for entry in entries:
        base, k = entry.slug, 2
        while entry.slug in used or entry.slug == "truth":
            entry.slug = f"{base}-{k}"
            k += 1
        used.add(entry.slug)
    return entries


def _alignment(entry: _Entry) -> NDArray[np.float64] | None:
    a = entry.outcome.alignment
    if a is None:
        return None
    try:
        pose = np.asarray(a, dtype=np.float64).reshape(3)
    except ValueError:
        return None
    return pose if np.isfinite(pose).all() else None


def _drawn_poses(entry: _Entry) -> NDArray[np.float64]:
    """The run's poses as the report draws them: moved by its alignment into the truth's frame when it has one."""
    alignment = _alignment(entry)
    return entry.run.poses if alignment is None else se2.compose(alignment, entry.run.poses)


def _drawn_marks(entry: _Entry) -> NDArray[np.float64] | None:
    """The beam ends where the run's map disagrees with itself, moved as its poses are drawn."""
    sc = (entry.outcome.evaluation or {}).get("self_consistency") or {}
    points = np.asarray(sc.get("disagreements") or [], dtype=np.float64).reshape(-1, 2)
    if not len(points):
        return None
    alignment = _alignment(entry)
    return points if alignment is None else se2.transform_points(alignment, points)


def _fmt_number(value: Any) -> str:
    if isinstance(value, bool) or value is None:
        return str(value)
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            return "n/a"
        return f"{value:.4g}"
    if isinstance(value, (list, tuple, dict)):
        return json.dumps(value, default=str)
    return str(value)


def _summary_value(value: Any, entry: _Entry, key: str) -> str:
    """A summary value for a table cell: a long list or mapping (karto's loop attempts) is counted, not printed."""
    text = _fmt_number(value)
    if isinstance(value, (list, tuple, dict)) and len(text) > 80:
        kind = "entries" if isinstance(value, (list, tuple)) else "keys"
        return f"{len(value)} {kind} (summary.{key} in {entry.outcome.run_dir}/diagnostics.json)"
    return text


def _build(comparison: Comparison) -> _Report:
    import slam2d

    entries = _entries(comparison.outcomes)
    truth = comparison.truth
    rec = comparison.recording or {}

    data_text = str(comparison.data)
    bits = []
    if rec.get("scans") is not None:
        bits.append(f"{rec['scans']} scans")
    if isinstance(rec.get("duration_s"), (int, float)) and math.isfinite(rec["duration_s"]):
        bits.append(f"{rec['duration_s']:.1f} s")
    if rec.get("format"):
        bits.append(str(rec["format"]))
    if bits:
        data_text += f" ({', '.join(bits)})"
    facts = [("Data", data_text)]
    if rec.get("sha256"):
        facts.append(("SHA-256", str(rec["sha256"])))
    facts.append(("Judged against", _judged_short(truth)))
    if comparison.relations is not None:
        facts.append(("Relations", str(comparison.relations)))
    ok = sum(e.outcome.ok for e in entries)
    facts.append(("Methods", f"{len(entries)} ({ok} finished, {len(entries) - ok} failed): "
                             + ", ".join(e.label for e in entries)))
    facts.append(("slam2d", slam2d.__version__))
    facts.append(("Date", datetime.now().astimezone().isoformat(timespec="seconds")))
    if comparison.command:
        facts.append(("Command", comparison.command))
    facts.append(("Total wall time", f"{comparison.wall_s:.1f} s (runs in parallel processes, and evaluation)"))

    columns, rows = _metric_rows(entries)
    notes = []
    if any(e.outcome.ok and e.outcome.method == "known-poses" for e in entries):
        notes.append("known-poses is not SLAM: it places the scans at the trajectory it was given (by default "
                     "the truth or reference), so its trajectory errors are near zero by construction. It shows "
                     "the best map these scans can make, the bound the other methods' maps are measured against.")
    maps, maps_note = _map_images(entries, truth)
    trajectories, trajectories_note = _trajectory_image(entries, truth)
    t0 = _time_origin(entries)
    judged = comparison.verdict or {}
    return _Report(
        title=f"slam2d comparison: {Path(str(comparison.data)).name}",
        facts=facts,
        verdict=judged.get("sentence"),
        evidence=_evidence_rows(judged, entries),
        disagreement=_disagreement_image(entries),
        judged=_judged_long(truth, comparison.relations),
        judged_warning=truth is None or truth.kind != "truth",
        columns=columns,
        rows=rows,
        table_notes=notes,
        maps=maps,
        maps_note=maps_note,
        trajectories=trajectories,
        trajectories_note=trajectories_note,
        error=_error_image(entries, truth, t0),
        timing=_timing_image(entries, t0),
        sections=[_method_section(e, t0, truth) for e in entries if e.outcome.ok],
        failures=[e for e in entries if not e.outcome.ok],
    )


EVIDENCE_HEAD = ["rank", "method", "disagreement", "beams contradicting", "travel / odometry", "map area",
                 "scans judged", "ATE (not used)"]
_JUDGING = ConsistencyParams()
VERDICT_NOTE = (
    f"Reference-free: every run's scans are mapped again at its poses by one mapper ({_JUDGING.resolution:g} m "
    f"cells, beams cut at {_JUDGING.max_range:g} m), and each scan is judged against the map of the scans taken "
    f"more than {_JUDGING.exclude:g} m of travel away. Disagreement = the share of judged beams that contradict "
    "that map (an end where the other visits saw free space, or a beam through their wall), plus a run's "
    f"difference from the other runs' median travel per metre of odometry (over {100 * SCALE_TOLERANCE:g} %: its "
    "map shrank or stretched) and its map area's excess over the smallest of the runs in scale (over "
    f"{100 * AREA_TOLERANCE:g} %: places drawn twice). Magenta dots on the maps below mark the contradicting "
    "beam ends. See docs/evaluation.md.")


def _evidence_rows(judged: dict[str, Any], entries: list[_Entry]) -> list[list[str]]:
    ranked = judged.get("reference_free") or {}
    evaluations = {e.outcome.method: e.outcome.evaluation or {} for e in entries if e.outcome.ok}
    rows = []
    for k, name in enumerate(ranked.get("ranking", []), start=1):
        sc = evaluations.get(name, {}).get("self_consistency") or {}
        scale, area = ranked.get("scale_off", {}).get(name), ranked.get("area_off", {}).get(name)
        ate = ATE.value(evaluations.get(name))
        rows.append([
            str(k), name, f"{100 * ranked['score'][name]:.2f} %", f"{100 * sc.get('inconsistency', math.nan):.2f} %",
            (f"{sc['travel_scale']:.3f}" if sc.get("travel_scale") else "n/a")
            + (f" ({100 * scale:+.1f} % off the median)" if scale is not None else ""),
            (f"{sc['area_m2']:.0f} m2" if sc.get("area_m2") else "n/a")
            + (f" ({100 * area:+.1f} % over the smallest)" if area is not None else ""),
            f"{sc.get('scans_judged', 0)} of {sc.get('scans', 0)}",
            f"{ate:.3f} m" if ate is not None else "-",
        ])
    for name in ranked.get("not_judged", []):
        rows.append(["-", name, "not judged", "", "", "", "0", ""])
    return rows


def _disagreement_image(entries: list[_Entry]) -> _Image | None:
    series = []
    for entry in entries:
        sc = (entry.outcome.evaluation or {}).get("self_consistency") if entry.outcome.ok else None
        if not sc or not sc.get("per_scan", {}).get("frame"):
            continue
        per = sc["per_scan"]
        judged = np.convolve(np.asarray(per["judged"], dtype=np.float64), np.ones(21), mode="same")
        bad = np.convolve(np.asarray(per["disagreeing"], dtype=np.float64), np.ones(21), mode="same")
        with np.errstate(invalid="ignore", divide="ignore"):
            percent = np.where(judged > 0, 100.0 * bad / judged, np.nan)
        series.append((entry.label, np.asarray(per["frame"]), percent, entry.colour))
    if not series:
        return None
    return _Image("disagreement-along-run.png", "self-disagreement along the run",
                  plots.disagreement_along_run_png(series),
                  "Where in the run each map disagrees with itself: the share of beams contradicting the map of the "
                  "run's other visits, over 21-scan windows. A rise that stays is where a method went wrong.")


def _judged_short(truth: Any) -> str:
    if truth is None:
        return "nothing (no ground truth or reference given)"
    what = "exact simulated ground truth" if truth.kind == "truth" else "a reference trajectory, NOT independent ground truth"
    text = f"{truth.source} ({what})"
    if truth.map_path is not None:
        text += f"; map {truth.map_path}"
    return text


def _word(truth: Any) -> str:
    """What the runs are judged against, in one word: a reference (a method's result) is not the truth."""
    return "truth" if truth is not None and truth.kind == "truth" else "reference"


def _judged_long(truth: Any, relations: Path | None) -> str:
    parts = []
    if truth is None:
        parts.append("No ground truth or reference was given: the table has map-quality and cost metrics only, "
                     "and each map and trajectory is shown in its own frame.")
    elif truth.kind == "truth":
        parts.append(f"The runs were judged against exact simulated ground truth ({truth.source}).")
    else:
        parts.append(
            f"The runs were judged against a reference trajectory ({truth.source}). It is NOT independent ground "
            "truth: trajectory errors measure agreement with the reference (for the datasets' reference.tum, "
            "GMapping's corrected poses), and a method more accurate than the reference would score worse."
        )
    if truth is not None and (truth.has_trajectory or truth.map is not None):
        w = _word(truth)
        parts.append(f"Each run is brought into the {w}'s frame by the SE(2) alignment of its trajectory to the "
                     f"{w}'s (ATE alignment), or, without a {w} trajectory, by aligning its map to the {w} map.")
    if relations is not None:
        parts.append(f"Relation errors use {relations} (Kümmerle et al. 2009).")
    return " ".join(parts)


def _metric_rows(entries: list[_Entry]) -> tuple[list[MetricColumn], list[_Row]]:
    """The columns with a value for at least one method, and one row per method with the best values marked.

    Values are compared as shown (rounded to the column's digits), so two
    values that print the same are both marked. A column with fewer than two
    values marks none: there is nothing to compare.
    """
    evaluations = [e.outcome.evaluation if e.outcome.ok else None for e in entries]
    columns = [c for c in METRIC_COLUMNS if any(c.value(ev) is not None for ev in evaluations)]
    shown: list[list[float | None]] = []
    for column in columns:
        vals = [column.value(ev) for ev in evaluations]
        shown.append([None if v is None else round(v, column.digits) for v in vals])
    best = []
    for column, vals in zip(columns, shown):
        present = [v for v in vals if v is not None]
        best.append(column.best(vals) if len(present) >= 2 else None)
    rows = []
    for i, entry in enumerate(entries):
        row = _Row(entry)
        if not entry.outcome.ok:
            row.failed = f"failed: {one_line(entry.outcome.error or 'no error message')}"
        else:
            for k, column in enumerate(columns):
                v = shown[k][i]
                if v is None:
                    row.cells.append(_Cell("–"))
                else:
                    row.cells.append(_Cell(f"{v:.{column.digits}f}", best[k] is not None and v == best[k]))
        rows.append(row)
    return columns, rows


def _column_header(column: MetricColumn) -> str:
    return f"{column.label} [{column.unit}]" if column.unit else column.label


def _direction(column: MetricColumn) -> str:
    return {"lower": "lower is better", "higher": "higher is better"}.get(column.better or "", "no better direction")


def _map_images(entries: list[_Entry], truth: Any) -> tuple[list[_Image], str]:
    grids: list[Any] = []
    transforms: list[Any] = []
    titles: list[tuple[str, str, str, str]] = []  # name, title, colour, caption
    tracks: list[NDArray[np.float64] | None] = []  # each map's trajectory, drawn on it
    marks: list[NDArray[np.float64] | None] = []  # where each map disagrees with itself
    word = _word(truth)
    if truth is not None and truth.map is not None:
        grids.append(truth.map)
        transforms.append(None)
        titles.append(("map-truth.png", f"{word} map", plots.TRUTH_COLOUR, f"{word} map"
                       + (f" and the {word} trajectory" if truth.has_trajectory else "")))
        tracks.append(np.asarray(truth.poses) if truth.has_trajectory else None)
        marks.append(None)
    aligned_any = unaligned_any = False
    have_truth = truth is not None
    for entry in entries:
        if not entry.shown or entry.run.map is None:
            continue
        alignment = _alignment(entry)
        grids.append(entry.run.map)
        transforms.append(alignment)
        poses = _drawn_poses(entry)
        tracks.append(poses if len(poses) else None)
        marks.append(_drawn_marks(entry))
        if alignment is not None:
            aligned_any = True
            caption = f"{entry.label} with its trajectory, aligned to the {word}"
        else:
            unaligned_any = True
            caption = (f"{entry.label} with its trajectory, in its own frame"
                       + (f" (no alignment to the {word})" if have_truth else ""))
        titles.append((f"map-{entry.slug}.png", entry.label, entry.colour, caption))
    if not grids:
        return [], "No map to show."
    canvas = plots.common_canvas(grids, transforms)
    # the canvas holds what the panels draw: the maps themselves go now, before matplotlib's own copies (a
    # diverged run's map is 40 million cells)
    grids.clear()
    for entry in entries:
        if entry.run is not None:
            entry.run.map = entry.run.map_image = None
    if not canvas.images:
        return [], "Every map is empty."
    images = [
        _Image(name, f"map: {title}", plots.map_panel_png(canvas, k, title, colour=colour, track=tracks[k],
                                                         marks=marks[k]), caption)
        for k, (name, title, colour, caption) in enumerate(titles)
    ]
    if len(images) == 1 and titles[0][0] == "map-truth.png":
        return images, f"No run produced a map: only the {word}'s is shown."
    frame = f"the {word}'s frame" if aligned_any else "each run's own frame"
    note = (f"All maps are drawn on one canvas in {frame}, at the same scale and orientation "
            f"({canvas.metres_per_pixel:.3g} m per pixel, {canvas.width:.1f} m x {canvas.height:.1f} m).")
    if aligned_any and unaligned_any:
        note += " Maps without an alignment are in their own frame and need not line up."
    return images, note


def _trajectory_image(entries: list[_Entry], truth: Any) -> tuple[_Image | None, str]:
    tracks = []
    for entry in entries:
        if not entry.shown or len(entry.run.poses) == 0:
            continue
        tracks.append((entry.label, _drawn_poses(entry), entry.colour))
    truth_track = None
    if truth is not None and truth.has_trajectory:
        word = "truth" if truth.kind == "truth" else "reference (not ground truth)"
        truth_track = (word, np.asarray(truth.poses))
    if not tracks and truth_track is None:
        return None, "No trajectory to show."
    if not tracks:
        png = plots.trajectories_png([], truth_track, title=f"{truth_track[0]} trajectory")
        return (_Image("trajectories.png", "trajectories", png),
                f"No run produced a trajectory: only the {_word(truth)}'s is shown.")
    aligned = truth_track is not None and any(_alignment(e) is not None for e in entries if e.shown)
    title = f"Trajectories aligned to the {_word(truth)}" if aligned else "Trajectories, each in its own frame"
    png = plots.trajectories_png(tracks, truth_track, title=title)
    note = (f"Each trajectory moved into the {_word(truth)}'s frame by its alignment; the wide grey line is the "
            + ("truth." if truth is not None and truth.kind == "truth" else "reference, which is not ground truth.")
            if aligned else "No alignment: each trajectory is drawn in its own frame, starting where its odometry starts.")
    return _Image("trajectories.png", "trajectories", png, title), note


def _series(run: RunFiles, name: str) -> NDArray[np.float64]:
    values = run.diagnostics.get("series", {}).get(name, [])
    return np.array([np.nan if v is None else v for v in values], dtype=np.float64)


def _time_origin(entries: list[_Entry]) -> float:
    starts = []
    for entry in entries:
        if entry.shown:
            t = _series(entry.run, "timestamp")
            if np.isfinite(t).any():
                starts.append(float(np.nanmin(t)))
    return min(starts) if starts else 0.0


def _error_image(entries: list[_Entry], truth: Any, t0: float) -> _Image | None:
    """Each aligned run's distance from the truth (or reference) pose at the same time, along the run."""
    from slam2d.eval.trajectory_metrics import associate

    if truth is None or not truth.has_trajectory:
        return None
    series = []
    for entry in entries:
        if not entry.shown or _alignment(entry) is None or len(entry.run.poses) < 2:
            continue
        try:
            pairs = associate(entry.run.times, _drawn_poses(entry), truth.times, truth.poses)
        except (InputError, ValueError):  # no overlap in time: nothing to draw
            continue
        error = np.hypot(*(pairs.estimate[:, :2] - pairs.reference[:, :2]).T)
        series.append((entry.label, pairs.times - t0, error, entry.colour))
    if not series:
        return None
    word = _word(truth)
    return _Image("error-along-run.png", f"position error along the run against the {word}",
                  plots.error_along_run_png(series, word),
                  f"Where in the run each method's error arises: the distance between its aligned pose and the "
                  f"{word}'s at the same time.")


def _timing_image(entries: list[_Entry], t0: float) -> _Image | None:
    series = []
    for entry in entries:
        if not entry.shown:
            continue
        t, wall = _series(entry.run, "timestamp"), _series(entry.run, "wall_s")
        if t.size and t.size == wall.size:
            series.append((entry.label, t - t0, wall, entry.colour))
    if not series:
        return None
    return _Image("time-per-scan.png", "wall time per scan", plots.time_per_scan_png(series),
                  "Wall time of each update against time in the recording; dashed: each method's median.")


def _descriptions(entry: _Entry) -> dict[str, str]:
    """The method's DIAGNOSTICS (name -> "meaning [unit]"), else what the run folder recorded."""
    from slam2d.methods import get_method

    recorded = entry.run.diagnostics.get("descriptions", {}) if entry.run is not None else {}
    try:
        return {**recorded, **get_method(entry.outcome.method).DIAGNOSTICS}
    except (InputError, ImportError):  # a method this installation does not have (an old run)
        return dict(recorded)


def _method_section(entry: _Entry, t0: float, truth: Any) -> _MethodSection:
    outcome = entry.outcome
    facts = [("Run folder", str(outcome.run_dir)), ("Seed", str(outcome.seed))]
    params = outcome.params or (entry.run.run.get("params", {}) if entry.run is not None else {})
    param_rows = [(str(k), _fmt_number(v)) for k, v in params.items()]
    if entry.run is None:
        facts.append(("Problem", entry.run_error or "no run folder"))
        return _MethodSection(entry, facts, None, "no diagnostics: the run folder could not be read", [], [], param_rows)

    evaluation = outcome.evaluation or {}
    alignment = _alignment(entry)
    if alignment is not None:
        source = evaluation.get("alignment_source", "")
        facts.append((f"Alignment to the {_word(truth)}",
                      f"x {alignment[0]:+.3f} m, y {alignment[1]:+.3f} m, θ {math.degrees(alignment[2]):+.2f}°"
                      + (f" (from the {source})" if source else "")))
    traj = evaluation.get("trajectory")
    if isinstance(traj, dict) and "pairs" in traj:
        facts.append((f"Poses matched to the {_word(truth)}", f"{traj.get('pairs')} ({traj.get('unmatched', 0)} unmatched)"))
    cost = evaluation.get("cost")
    if isinstance(cost, dict) and isinstance(cost.get("total_wall_s"), (int, float)):
        facts.append(("Processing time",
                      f"{cost['total_wall_s']:.2f} s wall, {cost.get('total_cpu_s', math.nan):.2f} s CPU "
                      f"for {cost.get('scans', '?')} scans (final step {cost.get('finish_wall_s', 0.0):.2f} s)"))
    problems = entry.run.run.get("input_problems") or []
    if problems:
        facts.append(("Input problems", "; ".join(str(p) for p in problems)))

    diag = entry.run.diagnostics
    descriptions = _descriptions(entry)
    names = [n for n in diag.get("series", {}) if n not in _BUILT_IN_SERIES]
    figure, no_series = None, ""
    t = _series(entry.run, "timestamp") - t0
    panels = []
    for name in names:
        values = _series(entry.run, name)
        if values.size == t.size and np.isfinite(values).any():
            panels.append((name, values, descriptions.get(name, name)))
    if panels:
        png = plots.diagnostics_png(t, panels, colour=entry.colour, title=f"{entry.label}: diagnostics per update")
        figure = _Image(f"diagnostics-{entry.slug}.png", f"diagnostics: {entry.label}", png)
    else:
        no_series = "This method reports no series of its own (only the time per update)."
    counters = [(str(k), _fmt_number(v)) for k, v in sorted(diag.get("counters", {}).items())]
    summary = [(str(k), _summary_value(v, entry, str(k))) for k, v in diag.get("summary", {}).items()]
    return _MethodSection(entry, facts, figure, no_series, counters, summary, param_rows)


# --------------------------------------------------------------------------- HTML

_CSS = """
body { font-family: system-ui, -apple-system, "Segoe UI", Roboto, sans-serif; margin: 0 auto; max-width: 1500px;
       padding: 1em 2em 3em; color: #222; line-height: 1.4; }
h1 { font-size: 1.5em; margin-bottom: 0.3em; } h2 { border-bottom: 1px solid #ccc; margin-top: 1.8em; }
h3 { margin-bottom: 0.3em; }
table { border-collapse: collapse; margin: 0.5em 0; font-size: 0.92em; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.6em; }
th { background: #f3f3f3; } td.num { text-align: right; font-variant-numeric: tabular-nums; white-space: nowrap; }
.scroll { overflow-x: auto; } table.metrics th { font-size: 0.85em; padding: 0.2em 0.4em; }
table.metrics td { padding: 0.2em 0.45em; } table.metrics td:first-child { white-space: nowrap; }
th[title] { cursor: help; text-decoration: underline dotted; }
table.facts th { text-align: left; vertical-align: top; background: none; border: none; padding-right: 1em; }
table.facts td { border: none; word-break: break-all; }
td.best { font-weight: bold; background: #e6f4e6; }
td.failed { color: #b00020; font-weight: bold; }
.swatch { display: inline-block; width: 0.9em; height: 0.9em; border-radius: 2px; margin-right: 0.4em;
          vertical-align: -0.1em; }
.note { color: #444; max-width: 75em; }
.warning { background: #fff4e5; border-left: 4px solid #e08a00; padding: 0.5em 0.8em; max-width: 75em; }
.maps { display: grid; grid-template-columns: repeat(auto-fill, minmax(440px, 1fr)); gap: 1em; }
.maps.wide { grid-template-columns: 1fr; } .maps.wide img { max-width: 900px; }
.maps img { cursor: zoom-in; } .maps.wide img { cursor: zoom-out; }
.maps figure { margin: 0; } .maps img { width: 100%; height: auto; border: 1px solid #ddd; }
figure { margin: 0.5em 0; } figcaption { font-size: 0.85em; color: #555; }
img.plot { max-width: 100%; height: auto; }
details { margin: 0.5em 0; } summary { cursor: pointer; color: #0550ae; }
pre { background: #f6f6f6; padding: 0.6em; overflow-x: auto; font-size: 0.85em; }
#image-check { background: #c62828; color: white; font-weight: bold; padding: 0.8em 1em; margin: 0 0 1em; }
dl.legend dt { font-weight: bold; float: left; clear: left; margin-right: 0.5em; }
dl.legend dd { margin: 0 0 0.2em 0; }
"""

_SCRIPT = """
document.addEventListener("click", function (event) {
  // a map or a figure of a grid: click for one per row, larger; click again to go back
  var box = event.target.tagName === "IMG" ? event.target.closest(".maps, .figures") : null;
  if (box) { box.classList.toggle("wide"); }
});
window.addEventListener("load", function () {
  var root = document.documentElement;
  // for the browser check: how far the page scrolls sideways, and the most shrunken figure (shown width as a
  // percentage of its own; its type was drawn to be read at its own size)
  root.dataset.pageOverflow = String(root.scrollWidth - root.clientWidth);
  var scales = Array.prototype.slice.call(document.querySelectorAll("img.plot, .maps img, .figures img"))
    .filter(function (img) { return img.naturalWidth > 0; })
    .map(function (img) { return Math.round(100 * img.getBoundingClientRect().width / img.naturalWidth); });
  root.dataset.smallestFigureScale = String(scales.length ? Math.min.apply(null, scales) : 0);
  var images = Array.prototype.slice.call(document.images);
  var failed = images.filter(function (img) { return !(img.complete && img.naturalWidth > 0); });
  document.documentElement.dataset.imagesLoaded = (images.length - failed.length) + "/" + images.length;
  if (failed.length) {
    var banner = document.getElementById("image-check");
    banner.textContent = failed.length + " of " + images.length + " images failed to load: " +
      failed.map(function (img) { return img.alt || img.id || "(unnamed)"; }).join(", ");
    banner.hidden = false;
  }
});
"""


def _e(text: Any) -> str:
    return html.escape(str(text), quote=True)


def _swatch(colour: str) -> str:
    return f'<span class="swatch" style="background:{_e(colour)}"></span>'


def _img_html(image: _Image, css_class: str = "plot") -> str:
    data = base64.b64encode(image.png).decode("ascii")
    return f'<img id="{_e(image.id)}" class="{css_class}" alt="{_e(image.alt)}" src="data:image/png;base64,{data}">'


def _facts_html(facts: list[tuple[str, str]]) -> str:
    rows = "".join(f"<tr><th>{_e(k)}</th><td>{_e(v)}</td></tr>" for k, v in facts)
    return f'<table class="facts">{rows}</table>'


def _kv_table_html(rows: list[tuple[str, str]], head: tuple[str, str]) -> str:
    body = "".join(f'<tr><td>{_e(k)}</td><td class="num">{_e(v)}</td></tr>' for k, v in rows)
    return f"<table><tr><th>{_e(head[0])}</th><th>{_e(head[1])}</th></tr>{body}</table>"


def _html(report: _Report) -> str:
    out = [
        "<!DOCTYPE html>",
        '<html lang="en">',
        "<head>",
        '<meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        f"<title>{_e(report.title)}</title>",
        f"<style>{_CSS}</style>",
        f"<script>{_SCRIPT}</script>",
        "</head>",
        "<body>",
        '<div id="image-check" role="alert" hidden></div>',
        f"<h1>{_e(report.title)}</h1>",
    ]
    if report.verdict:
        out.append('<h2 id="verdict">Which map to trust</h2>')
        out.append(f'<p class="verdict"><strong>{_e(report.verdict)}</strong></p>')
        if report.evidence:
            head = "".join(f"<th>{_e(h)}</th>" for h in EVIDENCE_HEAD)
            out.append(f'<div class="scroll"><table class="metrics"><tr>{head}</tr>')
            for row in report.evidence:
                out.append("<tr>" + "".join(f'<td class="num">{_e(c)}</td>' if k != 1 else f"<td>{_e(c)}</td>"
                                            for k, c in enumerate(row)) + "</tr>")
            out.append("</table></div>")
        out.append(f'<p class="note">{_e(VERDICT_NOTE)}</p>')
        if report.disagreement is not None:
            out.append(f"<figure>{_img_html(report.disagreement)}"
                       f"<figcaption>{_e(report.disagreement.caption)}</figcaption></figure>")

    out.append(_facts_html(report.facts))
    cls = "warning" if report.judged_warning else "note"
    out.append(f'<p class="{cls}">{_e(report.judged)}</p>')
    out.append('<h2 id="metrics">Metrics</h2>')
    if report.columns or report.rows:
        head = "".join(
            f'<th title="{_e(c.help + " (" + _direction(c) + ")")}">{_e(_column_header(c))}</th>'
            for c in report.columns
        ) or "<th>result</th>"
        out.append(f'<div class="scroll"><table class="metrics"><tr><th>method</th>{head}</tr>')
        for row in report.rows:
            name = f"<td>{_swatch(row.entry.colour)}{_e(row.entry.label)}</td>"
            if row.failed is not None:
                span = max(1, len(report.columns))
                out.append(f'<tr class="failed">{name}<td class="failed" colspan="{span}">{_e(row.failed)}</td></tr>')
                continue
            cells = "".join(
                f'<td class="num best">{_e(c.text)} {BEST_MARK}</td>' if c.best else f'<td class="num">{_e(c.text)}</td>'
                for c in row.cells
            )
            out.append(f"<tr>{name}{cells}</tr>")
        out.append("</table></div>")
    if report.columns:
        out.append(f'<p class="note">{BEST_MARK} and bold: the best value of the column (ties all marked; values are '
                   "compared as shown; no mark where the better direction is disputed or fewer than two methods have "
                   "a value). Hover a column header for what it measures.</p>")
        out += [f'<p class="note">{_e(note)}</p>' for note in report.table_notes]
    if not report.columns:
        out.append('<p class="note">No metric could be computed for any method.</p>')

    out.append('<h2 id="maps-heading">Maps</h2>')
    out.append(f'<p class="note">{_e(report.maps_note)}</p>')
    if report.maps:
        out.append('<p class="note">Click a map to show the maps one per row, larger; click again to go back.</p>')
        out.append('<div class="maps" id="maps">')
        for image in report.maps:
            out.append(f'<figure class="map-panel">{_img_html(image, "map")}'
                       f"<figcaption>{_e(image.caption)}</figcaption></figure>")
        out.append("</div>")

    out.append('<h2 id="trajectories">Trajectories</h2>')
    out.append(f'<p class="note">{_e(report.trajectories_note)}</p>')
    if report.trajectories is not None:
        out.append(f"<figure>{_img_html(report.trajectories)}</figure>")
    if report.error is not None:
        out.append(f"<figure>{_img_html(report.error)}<figcaption>{_e(report.error.caption)}</figcaption></figure>")

    out.append('<h2 id="timing">Time per scan</h2>')
    if report.timing is not None:
        out.append(f"<figure>{_img_html(report.timing)}<figcaption>{_e(report.timing.caption)}</figcaption></figure>")
    else:
        out.append('<p class="note">No timing recorded.</p>')

    if report.sections:
        out.append('<h2 id="methods">Methods</h2>')
    for section in report.sections:
        out.append(_section_html(section))
    if report.failures:
        out.append('<h2 id="failures">Failed methods</h2>')
        for entry in report.failures:
            o = entry.outcome
            out.append(f'<h3 id="failed-{_e(entry.slug)}">{_swatch(entry.colour)}{_e(entry.label)}</h3>')
            out.append(f'<p class="failed-error"><strong>failed:</strong> {_e(one_line(o.error or "no error message"))}</p>')
            if o.details:
                out.append(f"<details><summary>details</summary><pre>{_e(o.details)}</pre></details>")
            if o.params:
                rows = [(str(k), _fmt_number(v)) for k, v in o.params.items()]
                out.append(f"<details><summary>parameters</summary>{_kv_table_html(rows, ('parameter', 'value'))}"
                           "</details>")
    out.append("</body>")
    out.append("</html>")
    return "\n".join(out) + "\n"


def _section_html(section: _MethodSection) -> str:
    entry = section.entry
    out = [f'<h3 id="method-{_e(entry.slug)}">{_swatch(entry.colour)}{_e(entry.label)}</h3>', _facts_html(section.facts)]
    if section.figure is not None:
        out.append(f"<figure>{_img_html(section.figure)}</figure>")
    elif section.no_series:
        out.append(f'<p class="note">{_e(section.no_series)}</p>')
    if section.counters:
        out.append(_kv_table_html(section.counters, ("counter", "count")))
    if section.summary:
        out.append(_kv_table_html(section.summary, ("summary", "value")))
    if section.params:
        out.append(f"<details><summary>parameters ({len(section.params)})</summary>"
                   f"{_kv_table_html(section.params, ('parameter', 'value'))}</details>")
    return "\n".join(out)


# --------------------------------------------------------------------------- Markdown


def _m(text: Any) -> str:
    """Text for a Markdown table cell: one line, pipes escaped."""
    return one_line(str(text)).replace("|", "\\|")


def _md_table(head: Sequence[str], rows: Sequence[Sequence[str]], align_right_from: int = 1) -> list[str]:
    lines = ["| " + " | ".join(_m(h) for h in head) + " |"]
    lines.append("|" + "|".join("---" if i < align_right_from else "---:" for i in range(len(head))) + "|")
    lines += ["| " + " | ".join(rows_cell for rows_cell in row) + " |" for row in rows]
    return lines


def _md_image(image: _Image) -> str:
    return f"![{_m(image.alt)}]({IMAGES_DIR}/{image.name})"


def _markdown(report: _Report) -> str:
    out = [f"# {report.title}", ""]
    if report.verdict:
        out += ["## Which map to trust", "", f"**{_m(report.verdict)}**", ""]
        if report.evidence:
            out += _md_table(EVIDENCE_HEAD, [[_m(c) for c in row] for row in report.evidence]) + [""]
        out += [VERDICT_NOTE, ""]
        if report.disagreement is not None:
            out += [_md_image(report.disagreement), "", report.disagreement.caption, ""]
    for k, v in report.facts:
        out.append(f"- **{_m(k)}:** {_m(v)}")
    out += ["", f"> {one_line(report.judged)}", "", "## Metrics", ""]
    if report.columns or report.rows:
        head = ["method"] + ([_column_header(c) for c in report.columns] or ["result"])
        rows = []
        for row in report.rows:
            if row.failed is not None:
                rows.append([_m(row.entry.label), f"**{_m(row.failed)}**"] + [""] * max(0, len(report.columns) - 1))
            else:
                rows.append([_m(row.entry.label)]
                            + [f"**{c.text} {BEST_MARK}**" if c.best else c.text for c in row.cells])
        out += _md_table(head, rows)
    if report.columns:
        out += ["", f"{BEST_MARK} and bold: the best value of the column (ties all marked; values compared as shown; "
                "no mark where the better direction is disputed or fewer than two methods have a value).", ""]
        for c in report.columns:
            out.append(f"- **{_m(_column_header(c))}**: {_m(c.help)} ({_direction(c)}).")
        for note in report.table_notes:
            out += ["", note]
    if not report.columns:
        out += ["", "No metric could be computed for any method."]
    out += ["", "## Maps", "", report.maps_note, ""]
    for image in report.maps:
        out += [_md_image(image), "", f"*{_m(image.caption)}*", ""]
    out += ["## Trajectories", "", report.trajectories_note, ""]
    if report.trajectories is not None:
        out += [_md_image(report.trajectories), ""]
    if report.error is not None:
        out += [_md_image(report.error), "", report.error.caption, ""]
    out += ["## Time per scan", ""]
    out += [_md_image(report.timing), "", report.timing.caption, ""] if report.timing is not None else ["No timing recorded.", ""]
    out += ["## Methods", ""] if report.sections else []
    for section in report.sections:
        out += _section_md(section)
    if report.failures:
        out += ["## Failed methods", ""]
        for entry in report.failures:
            o = entry.outcome
            out += [f"### {entry.label}", "", f"**failed:** {_m(o.error or 'no error message')}", ""]
            if o.details:
                out += ["<details><summary>details</summary>", "", "```", o.details.rstrip().replace("```", "'''"),
                        "```", "", "</details>", ""]
    return "\n".join(out).rstrip() + "\n"


def _section_md(section: _MethodSection) -> list[str]:
    out = [f"### {section.entry.label}", ""]
    out += [f"- **{_m(k)}:** {_m(v)}" for k, v in section.facts]
    out.append("")
    if section.figure is not None:
        out += [_md_image(section.figure), ""]
    elif section.no_series:
        out += [section.no_series, ""]
    if section.counters:
        out += _md_table(["counter", "count"], [[_m(k), _m(v)] for k, v in section.counters]) + [""]
    if section.summary:
        out += _md_table(["summary", "value"], [[_m(k), _m(v)] for k, v in section.summary]) + [""]
    if section.params:
        out += [f"<details><summary>parameters ({len(section.params)})</summary>", ""]
        out += _md_table(["parameter", "value"], [[_m(k), _m(v)] for k, v in section.params])
        out += ["", "</details>", ""]
    return out
