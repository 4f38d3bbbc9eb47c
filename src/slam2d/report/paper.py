"""The ``slam2d paper`` report: any list of :class:`~slam2d.experiments.ExperimentResult`, section by section.

``report.html`` is self-contained (pictures inline as ``data:`` URIs, CSS and script inline; it
opens from disk with no network). Its script records on load how many pictures decoded in
``<html data-images-loaded="L/T">`` and how many script errors happened in
``data-console-errors``. ``report.md`` shows the same content and links the pictures where the
experiments wrote them (paths relative to the report).

A section that did not run (its code is missing from this build, or it failed) is rendered as
such, in words: no table or figure is made up for it.
"""

from __future__ import annotations

import base64
import json
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from slam2d.experiments.result import ExperimentResult, Figure, Table
from slam2d.io.atomic import write_text_atomic
from slam2d.report.comparison import _CSS as _BASE_CSS
from slam2d.report.comparison import _SCRIPT as _BASE_SCRIPT
from slam2d.report.comparison import _e, _m

__all__ = ["SectionRun", "write_paper_report", "format_cell", "REPORT_HTML", "REPORT_MD"]

REPORT_HTML = "report.html"
REPORT_MD = "report.md"


@dataclass
class SectionRun:
    """One section of the study as it ran here: its results, or why there are none."""

    key: str  # "III", "IV", "V"
    title: str
    results: list[ExperimentResult] = field(default_factory=list)
    folder: Path | None = None  # figure paths of its results are relative to this folder
    status: str = "ok"  # "ok", "not run", "failed"
    note: str = ""  # what quick mode skipped, or why the section did not run
    details: str = ""  # a traceback for a failed section
    cpu_s: float | None = None
    wall_s: float | None = None


def format_cell(value: Any) -> str:
    """A table cell as text: numbers to four significant digits, None as a dash."""
    if value is None:
        return "–"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            return "n/a"
        if value == 0:
            return "0"
        if 1e-3 <= abs(value) < 1e5:
            text = f"{value:.4g}"
            return text if "e" not in text else f"{value:.1f}"
        return f"{value:.4g}"
    if isinstance(value, (list, tuple)):
        return ", ".join(format_cell(v) for v in value)
    if isinstance(value, dict):
        return json.dumps(value, default=str)
    return str(value)


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


_UNIT_SUFFIXES = {"m": "m", "mm": "mm", "s": "s", "ms": "ms", "deg": "deg", "pct": "%", "mb": "MB"}
_ACRONYMS = {"ate": "ATE", "rpe": "RPE", "cpu": "CPU", "rmse": "RMSE"}


def _header(table: Table, column: str) -> str:
    """A column's header as a reader wants it: ``can.map_to_shape_mean_m`` -> ``can: map to shape mean [m]``."""
    unit = table.units.get(column)
    *groups, name = column.split(".")
    words = name.split("_")
    if unit is None and len(words) > 1 and words[-1] in _UNIT_SUFFIXES:
        unit = _UNIT_SUFFIXES[words.pop()]
    text = " ".join(_ACRONYMS.get(w, w) for w in words)
    if groups:
        text = f"{'.'.join(groups)}: {text}"
    return f"{text} [{unit}]" if unit else text


def _flatten(doc: Any, prefix: str = "") -> list[tuple[str, str]]:
    if isinstance(doc, dict):
        out = []
        for k, v in doc.items():
            out += _flatten(v, f"{prefix}.{k}" if prefix else str(k))
        return out
    if isinstance(doc, (list, tuple)):
        return [(prefix, ", ".join(_exact(v) for v in doc))]
    return [(prefix, _exact(doc))]


def _exact(value: Any) -> str:
    """The study's published numbers as published (shortest round-trip form), not rounded."""
    if isinstance(value, float) and math.isfinite(value):
        return repr(value)
    return format_cell(value)


def _figure_file(section: SectionRun, result: ExperimentResult, figure: Figure) -> Path | None:
    """The figure's file: relative to the section's folder, or to a folder named after the experiment in it."""
    if section.folder is None:
        return None
    for base in (section.folder, section.folder / result.name):
        p = base / figure.path
        if p.is_file():
            return p
    return None


# --------------------------------------------------------------------------- entry point


def write_paper_report(
    sections: Sequence[SectionRun], out_dir: Path, *, title: str, facts: Sequence[tuple[str, str]] = (),
    intro: str = "",
) -> list[Path]:
    """Write ``out_dir/report.html`` and ``out_dir/report.md``; return their paths."""
    out_dir = Path(out_dir)
    md = _markdown(sections, out_dir, title, facts, intro)
    page = _html(sections, title, facts, intro)
    md_path, html_path = out_dir / REPORT_MD, out_dir / REPORT_HTML
    write_text_atomic(md_path, md)
    write_text_atomic(html_path, page)
    return [html_path, md_path]


def _brief(text: str, limit: int = 220) -> str:
    """A verdict's first sentence (or ``limit`` characters) for the summary table; the section has it whole."""
    end = text.find(". ", 40)
    short = text if end < 0 else text[: end + 1]
    if len(short) > limit:
        short = short[:limit].rsplit(" ", 1)[0] + " ..."
    return short + (" (more in its section)" if short != text else "")


def _verdict_rows(sections: Sequence[SectionRun]) -> list[tuple[str, str, str]]:
    rows = []
    for s in sections:
        if s.status != "ok":
            rows.append((f"Section {s.key}", s.title, f"NOT RUN: {s.note}" if s.status == "not run"
                         else f"FAILED: {s.note}"))
            continue
        for r in s.results:
            rows.append((f"Section {s.key}", r.title, _brief(r.verdict) if r.verdict else "(no verdict given)"))
    return rows


def _section_status(s: SectionRun) -> str:
    bits = []
    if s.wall_s is not None:
        bits.append(f"wall {s.wall_s:.1f} s")
    if s.cpu_s is not None:
        bits.append(f"CPU {s.cpu_s:.1f} s")
    return ", ".join(bits)


# --------------------------------------------------------------------------- HTML

_CSS = _BASE_CSS + """
.verdict { background: #eef6ee; border-left: 4px solid #2e7d32; padding: 0.5em 0.8em; max-width: 75em; }
.notrun { background: #fdecea; border-left: 4px solid #c62828; padding: 0.5em 0.8em; max-width: 75em; }
.figures { display: grid; grid-template-columns: repeat(auto-fill, minmax(420px, 1fr)); gap: 1em; }
.figures figure { margin: 0; } .figures img { width: 100%; height: auto; border: 1px solid #ddd; cursor: zoom-in; }
.figures.wide { grid-template-columns: 1fr; } .figures.wide img { max-width: 1100px; cursor: zoom-out; }
td.text { max-width: 40em; }
"""

# Counts script errors for the browser check; the comparison report's script then counts the pictures
# that decoded (data-images-loaded) and shows a red banner naming any that did not.
_SCRIPT = """
(function () {
  var errors = 0;
  function mark() { document.documentElement.dataset.consoleErrors = String(errors); }
  window.addEventListener("error", function () { errors += 1; mark(); });
  var original = console.error;
  console.error = function () { errors += 1; mark(); return original.apply(console, arguments); };
  mark();
})();
""" + _BASE_SCRIPT


def _table_html(table: Table) -> str:
    head = "".join(f"<th>{_e(_header(table, c))}</th>" for c in table.columns)
    body = []
    for row in table.rows:
        cells = []
        for v in row:
            cls = "num" if _is_number(v) else "text"
            cells.append(f'<td class="{cls}">{_e(format_cell(v))}</td>')
        body.append("<tr>" + "".join(cells) + "</tr>")
    return (f'<div class="scroll"><table class="metrics"><caption>{_e(table.caption)}</caption>'
            f"<tr>{head}</tr>{''.join(body)}</table></div>")


def _kv_html(rows: list[tuple[str, str]], head: tuple[str, str]) -> str:
    body = "".join(f"<tr><td>{_e(k)}</td><td>{_e(v)}</td></tr>" for k, v in rows)
    return f"<table><tr><th>{_e(head[0])}</th><th>{_e(head[1])}</th></tr>{body}</table>"


def _html(sections: Sequence[SectionRun], title: str, facts: Sequence[tuple[str, str]], intro: str) -> str:
    out = ["<!DOCTYPE html>", '<html lang="en">', "<head>", '<meta charset="utf-8">',
           '<meta name="viewport" content="width=device-width, initial-scale=1">', f"<title>{_e(title)}</title>",
           f"<style>{_CSS}</style>", f"<script>{_SCRIPT}</script>", "</head>", "<body>",
           '<div id="image-check" role="alert" hidden></div>', f"<h1>{_e(title)}</h1>"]
    out.append('<table class="facts">' + "".join(f"<tr><th>{_e(k)}</th><td>{_e(v)}</td></tr>" for k, v in facts)
               + "</table>")
    if intro:
        out.append(f'<p class="note">{_e(intro)}</p>')
    out.append('<h2 id="verdicts">Where the study holds</h2>')
    out.append('<div class="scroll"><table><tr><th>section</th><th>experiment</th><th>verdict</th></tr>'
               + "".join(f'<tr><td>{_e(a)}</td><td>{_e(b)}</td><td class="text">{_e(c)}</td></tr>'
                         for a, b, c in _verdict_rows(sections)) + "</table></div>")
    for s in sections:
        sid = f"section-{s.key.lower()}"
        out.append(f'<h2 id="{_e(sid)}">Section {_e(s.key)}: {_e(s.title)}</h2>')
        status = _section_status(s)
        if s.status != "ok":
            word = "was not run" if s.status == "not run" else "failed"
            out.append(f'<p class="notrun"><strong>Section {_e(s.key)} {word}.</strong> {_e(s.note)}</p>')
            if s.details:
                out.append(f"<details><summary>details</summary><pre>{_e(s.details)}</pre></details>")
            continue
        if s.note or status:
            out.append(f'<p class="note">{_e(" ".join(x for x in (s.note, f"({status})" if status else "") if x))}</p>')
        for r in s.results:
            out.append(_result_html(s, r))
    out += ["</body>", "</html>"]
    return "\n".join(out) + "\n"


def _result_html(section: SectionRun, r: ExperimentResult) -> str:
    out = [f'<h3 id="{_e(r.name)}">{_e(r.title)}</h3>', f'<p class="note">{_e(r.summary)}</p>']
    if r.verdict:
        out.append(f'<p class="verdict"><strong>Verdict:</strong> {_e(r.verdict)}</p>')
    for t in r.tables:
        out.append(_table_html(t))
    if r.figures:
        out.append('<div class="figures">')
        for f in r.figures:
            path = _figure_file(section, r, f)
            if path is None:
                out.append(f'<figure><p class="notrun">figure missing: {_e(f.path)}</p>'
                           f"<figcaption>{_e(f.caption)}</figcaption></figure>")
                continue
            data = base64.b64encode(path.read_bytes()).decode("ascii")
            out.append(f'<figure><img class="plot" alt="{_e(f.caption)}" src="data:image/png;base64,{data}">'
                       f"<figcaption>{_e(f.caption)}</figcaption></figure>")
        out.append("</div>")
    if r.study:
        out.append(f"<details open><summary>the study's values</summary>"
                   f"{_kv_html(_flatten(r.study), ('item', 'the study'))}</details>")
    if r.numbers:
        out.append(f"<details><summary>all numbers ({len(r.numbers)})</summary>"
                   f"{_kv_html([(k, format_cell(v)) for k, v in r.numbers.items()], ('name', 'value'))}</details>")
    return "\n".join(out)


# --------------------------------------------------------------------------- Markdown


def _md_table(table: Table) -> list[str]:
    head = [_m(_header(table, c)) for c in table.columns]
    align = ["---:" if table.rows and all(_is_number(r[i]) or r[i] is None for r in table.rows) else "---"
             for i in range(len(table.columns))]
    lines = [f"*{_m(table.caption)}*", "", "| " + " | ".join(head) + " |", "|" + "|".join(align) + "|"]
    lines += ["| " + " | ".join(_m(format_cell(v)) for v in row) + " |" for row in table.rows]
    return lines + [""]


def _markdown(sections: Sequence[SectionRun], out_dir: Path, title: str, facts: Sequence[tuple[str, str]],
              intro: str) -> str:
    out = [f"# {title}", ""]
    out += [f"- **{_m(k)}:** {_m(v)}" for k, v in facts]
    out.append("")
    if intro:
        out += [intro, ""]
    out += ["## Where the study holds", "", "| section | experiment | verdict |", "|---|---|---|"]
    out += [f"| {_m(a)} | {_m(b)} | {_m(c)} |" for a, b, c in _verdict_rows(sections)]
    out.append("")
    for s in sections:
        out += [f"## Section {s.key}: {s.title}", ""]
        if s.status != "ok":
            word = "was not run" if s.status == "not run" else "failed"
            out += [f"> **Section {s.key} {word}.** {_m(s.note)}", ""]
            continue
        status = _section_status(s)
        if s.note or status:
            out += [" ".join(x for x in (s.note, f"({status})" if status else "") if x), ""]
        for r in s.results:
            out += [f"### {r.title}", "", r.summary, ""]
            if r.verdict:
                out += [f"> **Verdict:** {_m(r.verdict)}", ""]
            for t in r.tables:
                out += _md_table(t)
            for f in r.figures:
                path = _figure_file(s, r, f)
                if path is None:
                    out += [f"*figure missing: {_m(f.path)}*", ""]
                else:
                    rel = Path(os.path.relpath(path, out_dir)).as_posix()
                    out += [f"![{_m(f.caption)}]({rel})", "", f"*{_m(f.caption)}*", ""]
            if r.study:
                out += ["<details open><summary>the study's values</summary>", "", "| item | the study |", "|---|---|"]
                out += [f"| {_m(k)} | {_m(v)} |" for k, v in _flatten(r.study)]
                out += ["", "</details>", ""]
            if r.numbers:
                out += [f"<details><summary>all numbers ({len(r.numbers)})</summary>", "", "| name | value |",
                        "|---|---:|"]
                out += [f"| {_m(k)} | {_m(format_cell(v))} |" for k, v in r.numbers.items()]
                out += ["", "</details>", ""]
    return "\n".join(out).rstrip() + "\n"
