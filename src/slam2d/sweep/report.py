"""What a sweep leaves besides its runs: the table, a plot of each metric against each swept value, a summary.

"Best settings" are judged on the spec's ``objective`` metric, per method and
dataset: the setting with the best mean over all its runs there (every method
seed times every simulation seed), reported with the spread of those runs
(standard deviation, min-max, count). Settings where a run failed are ranked
only when no setting of that method ran cleanly. With several datasets the
summary also names the setting with the best mean rank over the datasets.
"""

from __future__ import annotations

import base64
import html
import json
import math
import statistics
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from slam2d.sweep.spec import METRICS, SweepSpec

__all__ = ["SettingStats", "setting_stats", "best_settings", "write_outputs", "plot_metric"]


@dataclass
class SettingStats:
    """The objective over the runs of one method setting on one dataset."""

    method: str
    dataset: str
    setting: dict[str, Any]
    values: list[float]
    runs: int
    failed: int
    means: dict[str, float | None]  # every metric's mean over the ok runs

    @property
    def n(self) -> int:
        return len(self.values)

    @property
    def mean(self) -> float | None:
        return statistics.fmean(self.values) if self.values else None

    @property
    def std(self) -> float | None:
        return statistics.stdev(self.values) if len(self.values) > 1 else (0.0 if self.values else None)


def _key(setting: dict[str, Any]) -> str:
    return json.dumps(setting, sort_keys=True, default=str)


def setting_stats(rows: list[dict[str, Any]], spec: SweepSpec) -> list[SettingStats]:
    """One entry per (method, dataset, swept setting), in the order the settings first appear."""
    groups: dict[tuple[str, str, str], SettingStats] = {}
    metric_values: dict[tuple[str, str, str], dict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
    for r in rows:
        setting = {**r.get("swept", {}), **{f"data.{k}": v for k, v in r.get("data_settings", {}).items()}}
        k = (r["method"], r["dataset"], _key(setting))
        g = groups.setdefault(k, SettingStats(r["method"], r["dataset"], setting, [], 0, 0, {}))
        g.runs += 1
        if r["status"] != "ok":
            g.failed += 1
            continue
        for m, v in (r.get("metrics") or {}).items():
            if v is not None:
                metric_values[k][m].append(float(v))
        v = (r.get("metrics") or {}).get(spec.objective.name)
        if v is not None:
            g.values.append(float(v))
    for k, g in groups.items():
        g.means = {m.name: (statistics.fmean(metric_values[k][m.name]) if metric_values[k][m.name] else None)
                   for m in spec.metrics}
    return list(groups.values())


def best_settings(stats: list[SettingStats], spec: SweepSpec) -> dict[str, dict[str, Any]]:
    """Per method: ``{"per_dataset": {dataset: SettingStats}, "overall": (setting, mean rank) or None}``."""
    sign = 1.0 if spec.objective.better == "lower" else -1.0
    out: dict[str, dict[str, Any]] = {}
    by_method: dict[str, list[SettingStats]] = defaultdict(list)
    for s in stats:
        by_method[s.method].append(s)
    for method, items in by_method.items():
        per_dataset: dict[str, SettingStats] = {}
        ranks: dict[str, list[int]] = defaultdict(list)
        datasets = list(dict.fromkeys(s.dataset for s in items))
        for d in datasets:
            cands = [s for s in items if s.dataset == d and s.mean is not None]
            clean = [s for s in cands if s.failed == 0]
            pool = clean or cands
            if not pool:
                continue
            ordered = sorted(pool, key=lambda s: sign * s.mean)
            per_dataset[d] = ordered[0]
            for i, s in enumerate(ordered):
                ranks[_key(s.setting)].append(i + 1)
        overall = None
        if len(per_dataset) > 1:
            full = {k: v for k, v in ranks.items() if len(v) == len(per_dataset)}
            if full:
                k = min(full, key=lambda k: statistics.fmean(full[k]))
                overall = (json.loads(k), statistics.fmean(full[k]))
        out[method] = {"per_dataset": per_dataset, "overall": overall}
    return out


# --------------------------------------------------------------------------- plots

def _numeric(values: list[Any]) -> bool:
    return all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values if v is not None)


def plot_metric(rows: list[dict[str, Any]], metric: str, column: str, unit: str = "") -> bytes | None:
    """PNG of ``metric`` against one swept value (``param.NAME`` or ``data.NAME``): every ok run as a dot,
    a line through the median at each value, one colour per method and dataset. None if nothing to draw."""
    from slam2d.report.plots import _new_figure, _png, _style, log_scale, method_colours

    kind, name = column.split(".", 1)
    source = "swept" if kind == "param" else "data_settings"
    series: dict[str, tuple[list[Any], list[float]]] = defaultdict(lambda: ([], []))
    for r in rows:
        if r["status"] != "ok" or name not in r.get(source, {}):
            continue
        v = (r.get("metrics") or {}).get(metric)
        if v is None:
            continue
        xs, ys = series[f"{r['method']} on {r['dataset']}"]
        xs.append(r[source][name])
        ys.append(float(v))
    if not series:
        return None
    all_x = [x for xs, _ in series.values() for x in xs]
    numeric = _numeric(all_x)
    categories = sorted({str(x) for x in all_x}) if not numeric else []
    m = METRICS[metric]
    with _style():
        fig = _new_figure(5.0, 3.4, layout="constrained")
        ax = fig.add_subplot(1, 1, 1)
        colours = method_colours(len(series))
        for (label, (xs, ys)), colour in zip(series.items(), colours, strict=True):
            px = [float(x) for x in xs] if numeric else [categories.index(str(x)) for x in xs]
            ax.scatter(px, [y for y in ys], s=12, alpha=0.45, color=colour, linewidths=0)
            at: dict[float, list[float]] = defaultdict(list)
            for x, y in zip(px, ys, strict=True):
                at[x].append(y)
            xsorted = sorted(at)
            ax.plot(xsorted, [statistics.median(at[x]) for x in xsorted], "-o", ms=3, color=colour, label=label)
        if numeric:
            positive = [float(x) for x in all_x if x is not None and float(x) > 0]
            if positive and len(positive) == len(all_x) and max(positive) / min(positive) > 20:
                log_scale(ax, "x")
        else:
            ax.set_xticks(range(len(categories)), categories)
        xunit = f" [{unit}]" if unit else ""
        ax.set_xlabel((name if kind == "param" else f"{name} (simulation)") + xunit)
        ax.set_ylabel(f"{metric} [{m.unit}]" if m.unit else metric)
        direction = {"lower": "lower is better", "higher": "higher is better"}.get(m.better or "", "")
        ax.set_title(f"{metric} against {name}" + (f" ({direction})" if direction else ""))
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", frameon=False)
        return _png(fig)


def swept_columns(rows: list[dict[str, Any]]) -> list[str]:
    """The ``param.``/``data.`` values that take more than one value in the rows."""
    seen: dict[str, set[str]] = defaultdict(set)
    for r in rows:
        for k, v in r.get("swept", {}).items():
            seen[f"param.{k}"].add(repr(v))
        for k, v in r.get("data_settings", {}).items():
            seen[f"data.{k}"].add(repr(v))
    return [c for c, vals in seen.items() if len(vals) > 1]


def _units(spec: SweepSpec) -> dict[str, str]:
    """Unit of each swept column, from the methods' and the simulation's parameter declarations."""
    from slam2d.methods.registry import available
    from slam2d.params import describe
    from slam2d.sensors.motion_noise import OdometryNoise
    from slam2d.sim.simulate import SimulationParams

    units = {f"data.{p.name}": p.unit for cls in (SimulationParams, OdometryNoise) for p in describe(cls)}
    registered = available()
    for sweep in spec.methods:
        if sweep.method in registered:
            units.update({f"param.{p.name}": p.unit for p in describe(registered[sweep.method].Params)})
    return units


def write_plots(rows: list[dict[str, Any]], spec: SweepSpec, out_dir: Path) -> list[Path]:
    from slam2d.io.atomic import write_bytes_atomic

    written = []
    units = _units(spec)
    for metric in spec.metrics:
        for column in swept_columns(rows):
            png = plot_metric(rows, metric.name, column, units.get(column, ""))
            if png is None:
                continue
            path = out_dir / "plots" / f"{metric.name}-vs-{column.split('.', 1)[1]}.png"
            path.parent.mkdir(parents=True, exist_ok=True)
            write_bytes_atomic(path, png)
            written.append(path)
    return written


# --------------------------------------------------------------------------- summary

def _e(text: Any) -> str:
    return html.escape(str(text), quote=True)


def _fmt(v: float | None, digits: int = 4) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    return f"{v:.{digits}g}"


def _setting_text(setting: dict[str, Any]) -> str:
    return ", ".join(f"{k}={v}" for k, v in setting.items()) or "(defaults)"


_CSS = """
body { font-family: system-ui, -apple-system, "Segoe UI", Roboto, sans-serif; margin: 0 auto; max-width: 1200px;
       padding: 1em 2em 3em; color: #222; line-height: 1.4; }
h2 { border-bottom: 1px solid #ccc; margin-top: 1.6em; }
table { border-collapse: collapse; margin: 0.5em 0; font-size: 0.92em; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.6em; } th { background: #f3f3f3; }
td.num { text-align: right; font-variant-numeric: tabular-nums; white-space: nowrap; }
.plots { display: grid; grid-template-columns: repeat(auto-fill, minmax(480px, 1fr)); gap: 1em; }
.plots img { width: 100%; height: auto; border: 1px solid #ddd; }
.note { color: #444; } td.failed { color: #b00020; }
"""


def _unmeasured(rows: list[dict[str, Any]], spec: SweepSpec) -> dict[str, list[str]]:
    """Metric -> datasets on which no finished run has a value for it."""
    out: dict[str, list[str]] = {}
    for m in spec.metrics:
        for d in dict.fromkeys(r["dataset"] for r in rows):
            ok = [r for r in rows if r["dataset"] == d and r["status"] == "ok"]
            if ok and all((r.get("metrics") or {}).get(m.name) is None for r in ok):
                out.setdefault(m.name, []).append(d)
    return out


def summary_html(spec: SweepSpec, result: Any, plots: list[Path]) -> str:
    rows = result.rows
    stats = setting_stats(rows, spec)
    best = best_settings(stats, spec)
    obj = spec.objective
    unit = f" [{obj.unit}]" if obj.unit else ""
    ok = sum(r["status"] == "ok" for r in rows)
    parts = [
        "<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
        f"<title>sweep {_e(spec.name)}</title><style>{_CSS}</style></head><body>",
        f"<h1>Sweep <code>{_e(spec.name)}</code></h1>",
        f'<p class="note">{len(rows)} runs: {ok} finished, {len(rows) - ok} failed; {result.executed} run now, '
        f"{result.reused} reused from an earlier run of the sweep; {len(result.lost)} attempt(s) lost to a dead "
        f"worker. Spec: <code>{_e(spec.path)}</code>. Executor: {_e(result.executor or '-')}. Table: "
        "<code>results.parquet</code>, <code>results.csv</code>.</p>",
        f"<h2>Best settings per method</h2><p class=\"note\">Judged on <b>{_e(obj.name)}</b>{_e(unit)} "
        f"({_e(obj.better)} is better): the mean over every run of a setting on a dataset (all method seeds "
        "and simulation seeds), with its spread over those seeds.</p>",
    ]
    missing = _unmeasured(rows, spec)
    if missing:
        parts.append('<p class="note">No value in any finished run (the dataset lacks what the metric is judged '
                     "against, e.g. a truth map or a relations file): "
                     + "; ".join(f"{_e(m)} on {_e(', '.join(ds))}" for m, ds in missing.items()) + ".</p>")
    for method, b in best.items():
        parts.append(f"<h3>{_e(method)}</h3>")
        if b["overall"] is not None:
            setting, rank = b["overall"]
            parts.append(f"<p>Over all datasets: <b>{_e(_setting_text(setting))}</b> (mean rank {rank:.1f}).</p>")
        if not b["per_dataset"]:
            parts.append('<p class="note">no finished run with a value of the objective</p>')
            continue
        head = "".join(f"<th>{_e(m.name)}{_e(f' [{m.unit}]' if m.unit else '')}</th>"
                       for m in spec.metrics if m is not obj)
        parts.append(f"<table><tr><th>dataset</th><th>best setting</th><th>{_e(obj.name)} mean ± sd{_e(unit)}</th>"
                     f"<th>min - max</th><th>runs</th>{head}</tr>")
        for d, s in b["per_dataset"].items():
            ties = sum(1 for o in stats if o.method == method and o.dataset == d and o is not s and o.mean is not None
                       and o.failed == s.failed == 0 and math.isclose(o.mean, s.mean, rel_tol=1e-12, abs_tol=0.0))
            tie = f" (tied with {ties} other setting(s))" if ties else ""
            others = "".join(f'<td class="num">{_fmt(s.means.get(m.name))}</td>' for m in spec.metrics if m is not obj)
            failed = f', <span class="failed">{s.failed} failed</span>' if s.failed else ""
            parts.append(
                f"<tr><td>{_e(d)}</td><td>{_e(_setting_text(s.setting))}{_e(tie)}</td>"
                f'<td class="num">{_fmt(s.mean)} ± {_fmt(s.std, 2)}</td>'
                f'<td class="num">{_fmt(min(s.values))} - {_fmt(max(s.values))}</td>'
                f'<td class="num">{s.n}{failed}</td>{others}</tr>'
            )
        parts.append("</table>")
    if plots:
        parts.append("<h2>Metrics against the swept values</h2><p class=\"note\">Each dot is a run; the line "
                     "joins the medians at each value (over seeds and every other swept value).</p>"
                     '<div class="plots">')
        for p in plots:
            data = base64.b64encode(p.read_bytes()).decode("ascii")
            parts.append(f'<figure><img alt="{_e(p.stem)}" src="data:image/png;base64,{data}"></figure>')
        parts.append("</div>")
    failed = [r for r in rows if r["status"] != "ok"]
    if failed or result.lost:
        parts.append("<h2>Failures</h2>")
    if failed:
        parts.append("<table><tr><th>run</th><th>method</th><th>dataset</th><th>seed</th><th>setting</th>"
                     "<th>error</th></tr>")
        for r in failed:
            parts.append(f"<tr><td><code>{_e(r['run_id'])}</code></td><td>{_e(r['method'])}</td>"
                         f"<td>{_e(r['dataset'])}</td><td>{_e(r['seed'])}</td>"
                         f"<td>{_e(_setting_text(r.get('swept', {})))}</td>"
                         f'<td class="failed">{_e(r.get("error"))}</td></tr>')
        parts.append("</table>")
    if result.lost:
        parts.append("<p>Attempts lost to a dead worker (each retried once):</p><ul>")
        parts += [f"<li>{_e(line)}</li>" for line in result.lost]
        parts.append("</ul>")
    parts.append("</body></html>")
    return "\n".join(parts) + "\n"


def write_outputs(spec: SweepSpec, result: Any) -> list[Path]:
    """The table, the plots and ``summary.html``; returns the paths written."""
    from slam2d.io.atomic import write_text_atomic
    from slam2d.sweep.table import write_table

    out_dir = result.out_dir
    metrics = [m.name for m in spec.metrics]
    written = write_table(result.rows, metrics, out_dir)
    plots = write_plots(result.rows, spec, out_dir)
    written += plots
    summary = out_dir / "summary.html"
    write_text_atomic(summary, summary_html(spec, result, plots))
    written.append(summary)
    return written
