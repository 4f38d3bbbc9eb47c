"""Reports of the calibration commands: pictures (PNG), report.md and a self-contained report.html.

A report is a list of blocks (heading, paragraph, table, picture) rendered
twice: to Markdown, whose pictures are files next to it, and to HTML, whose
pictures are embedded so the one file can be mailed or archived.
"""

from __future__ import annotations

import base64
import html
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from slam2d.report.plots import _new_figure, _png, _style, method_colours
from slam2d.sensors.calibration.fits import Z95

__all__ = ["Report", "laser_report", "verify_report", "odometry_report"]

_CSS = (
    "body{font-family:system-ui,sans-serif;max-width:70rem;margin:2rem auto;padding:0 1rem;color:#222}"
    "table{border-collapse:collapse;margin:.5rem 0 1rem}td,th{border:1px solid #ccc;padding:.2rem .5rem}"
    "td.num{text-align:right;font-variant-numeric:tabular-nums}img{max-width:100%}"
    "code{background:#f3f3f3;padding:0 .2rem}.scroll{overflow-x:auto}"
    "#image-check{background:#c62828;color:white;font-weight:bold;padding:.8em 1em}"
)


@dataclass
class Report:
    title: str
    blocks: list[tuple[str, Any]] = field(default_factory=list)
    images: dict[str, bytes] = field(default_factory=dict)

    def heading(self, text: str) -> None:
        self.blocks.append(("h2", text))

    def text(self, text: str) -> None:
        self.blocks.append(("p", text))

    def table(self, head: Sequence[str], rows: Sequence[Sequence[Any]]) -> None:
        self.blocks.append(("table", (list(head), [[str(c) for c in r] for r in rows])))

    def image(self, name: str, png: bytes, alt: str) -> None:
        self.images[name] = png
        self.blocks.append(("img", (name, alt)))

    def markdown(self) -> str:
        out = [f"# {self.title}", ""]
        for kind, value in self.blocks:
            if kind == "h2":
                out += [f"## {value}", ""]
            elif kind == "p":
                out += [value, ""]
            elif kind == "table":
                head, rows = value
                out.append("| " + " | ".join(head) + " |")
                out.append("|" + "|".join("---" for _ in head) + "|")
                out += ["| " + " | ".join(r) + " |" for r in rows]
                out.append("")
            else:
                name, alt = value
                out += [f"![{alt}]({name})", ""]
        return "\n".join(out)

    def html(self) -> str:
        e = html.escape
        from slam2d.report.comparison import _SCRIPT  # image and layout checks the browser tests read

        out = ["<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
               '<meta name="viewport" content="width=device-width, initial-scale=1">',
               f"<title>{e(self.title)}</title><style>{_CSS}</style><script>{_SCRIPT}</script></head><body>",
               '<div id="image-check" role="alert" hidden></div>', f"<h1>{e(self.title)}</h1>"]
        for kind, value in self.blocks:
            if kind == "h2":
                out.append(f"<h2>{e(value)}</h2>")
            elif kind == "p":
                out.append(f"<p>{e(value)}</p>")
            elif kind == "table":
                head, rows = value
                out.append('<div class="scroll"><table><tr>' + "".join(f"<th>{e(h)}</th>" for h in head) + "</tr>")
                for r in rows:
                    out.append("<tr>" + "".join(
                        f'<td class="num">{e(c)}</td>' if _numeric(c) else f"<td>{e(c)}</td>" for c in r) + "</tr>")
                out.append("</table></div>")
            else:
                name, alt = value
                data = base64.b64encode(self.images[name]).decode("ascii")
                out.append(f'<p><img class="plot" alt="{e(alt, quote=True)}" src="data:image/png;base64,{data}"></p>')
        out.append("</body></html>")
        return "\n".join(out) + "\n"

    def write(self, out_dir: Path) -> list[Path]:
        from slam2d.io.atomic import write_bytes_atomic, write_text_atomic

        out_dir.mkdir(parents=True, exist_ok=True)
        written = []
        for name, png in self.images.items():
            (out_dir / name).parent.mkdir(parents=True, exist_ok=True)
            write_bytes_atomic(out_dir / name, png)
            written.append(out_dir / name)
        write_text_atomic(out_dir / "report.md", self.markdown())
        write_text_atomic(out_dir / "report.html", self.html())
        return [out_dir / "report.md", out_dir / "report.html", *written]


def _numeric(text: str) -> bool:
    try:
        float(text.split()[0])
        return True
    except (ValueError, IndexError):
        return False


def _mm(value: float, digits: int = 3) -> str:
    return "-" if not math.isfinite(value) else f"{1000 * value:.{digits}f}"


# --------------------------------------------------------------------------- laser


def _probability_png(setups: list[Any], title: str) -> bytes:
    """Fig. 5 form: normal probability plot of every set-up of one surface (angles x distances)."""
    from scipy.stats import norm

    angles = sorted({s.angle_deg for s in setups}, reverse=True)
    dists = sorted({s.distance for s in setups})
    with _style():
        w, h = 1.6 * len(dists) + 0.8, 1.6 * len(angles) + 0.9
        fig = _new_figure(w, h)  # fixed margins: a constrained layout of many panels is slow
        fig.subplots_adjust(left=0.6 / w, right=1 - 0.1 / w, bottom=0.5 / h, top=1 - 0.75 / h, wspace=0.15, hspace=0.55)
        axes = fig.subplots(len(angles), len(dists), squeeze=False, sharex=True, sharey=True)
        for ax in axes.flat:
            ax.set_visible(False)
        for s in setups:
            ax = axes[angles.index(s.angle_deg), dists.index(s.distance)]
            ax.set_visible(True)
            x = np.sort(s.residuals) / s.sigma
            if x.size > 400:  # plotted quantiles; the statistics use every reading
                x = x[np.linspace(0, x.size - 1, 400).round().astype(int)]
            q = norm.ppf((np.arange(1, x.size + 1) - 0.5) / x.size)
            ax.plot(q, x, ".", ms=2, color="#1f77b4", rasterized=True)
            ax.plot([-4, 4], [-4, 4], "-", lw=0.8, color="#d62728")
            ax.set_xlim(-4, 4)
            ax.set_ylim(-5, 5)
            ax.set_title(f"{s.distance:g} m, {s.angle_deg:g} deg\nsigma {1000 * s.sigma:.2f} mm, r {s.normality():.3f}",
                         fontsize=7)
        fig.suptitle(f"{title}: normal probability plots (readings / sigma against normal quantiles)")
        fig.supxlabel("normal quantile")
        fig.supylabel("standardised reading")
        return _png(fig)


def _fits_png(curves: list[Any], materials: list[str], reference: float) -> bytes:
    """Figs. 6-7 form: per curve, the set-ups, the averaged points, the fit and its 95 % band; residuals below."""
    colours = dict(zip(materials, method_colours(len(materials)), strict=True))
    with _style():
        fig = _new_figure(4.0 * len(curves), 5.0, layout="constrained")
        axes = fig.subplots(2, len(curves), squeeze=False, height_ratios=[3, 1], sharex="col")
        for j, c in enumerate(curves):
            ax, rax = axes[0, j], axes[1, j]
            lo, hi = c.fit.distance_range
            grid = np.linspace(lo, hi, 200)
            y, se = c.fit(grid), c.fit.standard_error(grid)
            for m in materials:
                pts = [s for s in c.members if s.material == m]
                if pts:
                    ax.plot([s.distance for s in pts], [1000 * s.sigma for s in pts], "o", ms=3,
                            color=colours[m], label=m, alpha=0.7)
            ax.errorbar(c.distance, 1000 * c.sigma, yerr=1000 * Z95 * c.se, fmt="s", ms=4, color="k",
                        label="mean over surfaces", capsize=2)
            ax.fill_between(grid, 1000 * (y - Z95 * se), 1000 * (y + Z95 * se), color="#999", alpha=0.35,
                            label="95 % band of the fit")
            ax.plot(grid, 1000 * y, "-", color="k", lw=1.2, label=f"degree {c.fit.degree} fit")
            if lo <= reference <= hi:
                ax.axvline(reference, color="#d62728", lw=0.8, ls="--")
            ax.set_title(c.label)
            ax.set_ylabel("sigma [mm]")
            if j == 0:
                ax.legend(loc="upper left", fontsize=6)
            res = c.sigma - c.fit(c.distance)
            rax.axhline(0, color="k", lw=0.8)
            rax.errorbar(c.distance, 1000 * res, yerr=1000 * Z95 * c.se, fmt="s", ms=3, color="k", capsize=2)
            rax.fill_between(grid, -1000 * Z95 * se, 1000 * Z95 * se, color="#999", alpha=0.35)
            rax.set_xlabel("distance [m]")
            rax.set_ylabel("residual [mm]")
        return _png(fig)


def laser_report(cal: Any, model_path: Path | None, command: str = "") -> Report:
    from slam2d.sensors.calibration.laser import LaserCalibration

    assert isinstance(cal, LaserCalibration)
    data = cal.data
    rep = Report("Laser range calibration")
    rep.text(f"Data: {', '.join(data.sources)} ({data.kind}); {len(data.setups)} set-ups, "
             f"{sum(s.returns for s in data.setups)} readings with a return."
             + (f" Command: `{command}`." if command else ""))
    if data.skipped:
        rep.text("Left out: " + "; ".join(data.skipped[:10]) + (" ..." if len(data.skipped) > 10 else ""))
    ref = cal.sigma_at_reference()
    rep.heading(f"Sigma at {cal.reference_distance:g} m")
    label = {"all": "all surfaces and angles (eq. 1 form)"}
    rep.table(["fit", "sigma [mm]", "sigma [m]"],
              [[label.get(k, f"all surfaces, {k}"), _mm(v), f"{v:.5f}"] for k, v in ref.items()])
    rep.text(f"The single value for a method that takes one constant sigma (the study's choice): "
             f"--sensor-model constant:{ref['all']:.5f}" + (f"; the whole model: --sensor-model {model_path}"
                                                               if model_path else "") + ".")
    rep.heading("Sigma per surface and angle (Table I form)")
    angles = data.angles
    rows = []
    for row in cal.table():
        rows.append([row["material"], *[_mm(row[a], 4) for a in angles]])
    rep.table(["surface", *[f"sigma at {a:g} deg [mm]" for a in angles]], rows)
    rep.text("Each value is the mean over the distances measured; angles are between the beam and the surface "
             "(90 deg = square to it).")
    rep.heading("Fits of sigma against distance")
    curves = [cal.per_angle[a] for a in angles] + ([cal.overall] if len(angles) > 1 else [])
    rep.image("figures/fits.png", _fits_png(curves, data.materials, cal.reference_distance),
              "sigma against distance per angle with fits, 95 % bands and residuals")
    frows = []
    for c in curves + [cal.per_material[k] for k in sorted(cal.per_material, key=lambda k: (-k[1], k[0]))]:
        coef = ", ".join(f"{v:.6g}" for v in c.fit.coefficients)
        cv = ", ".join(f"{k}: {v:.3g}" for k, v in c.cv.items()) or "too few distances"
        frows.append([c.label, str(c.fit.degree), coef, cv, f"{c.fit.chi2_reduced:.2f}", f"{100 * c.scatter:.1f}",
                      c.note or ""])
    rep.table(["curve", "degree", "coefficients c0, c1, ... (sigma = c0 + c1 d + ..., m)",
               "cross-validation score per degree", "reduced chi2", "surface scatter [%]", "note"], frows)
    rep.text("Cross-validation leaves one distance out at a time; the score is the mean squared prediction error "
             "in units of the points' standard errors (about 1 for a model that fits to within the sampling "
             "noise). The band is the 95 % confidence band of the fitted curve.")
    rep.heading("Set-ups")
    srows = []
    for s in data.setups:
        lo, hi = s.interval()
        srows.append([s.material, f"{s.angle_deg:g}", f"{s.distance:.3f}", str(s.returns), str(s.count - s.returns),
                      f"{s.mean:.4f}", _mm(s.sigma), f"{_mm(lo)}-{_mm(hi)}", f"{s.normality():.4f}"])
    rep.table(["surface", "angle [deg]", "distance [m]", "readings", "lost", "mean [m]", "sigma [mm]",
               "95 % interval [mm]", "probability-plot r"], srows)
    rep.heading("Gaussian probability plots (Fig. 5 form)")
    for m in data.materials:
        setups = [s for s in data.setups if s.material == m]
        rep.image(f"figures/probability-{_slug(m)}.png", _probability_png(setups, m),
                  f"normal probability plots for {m}")
    return rep


def _slug(text: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_" else "-" for ch in text)


# --------------------------------------------------------------------------- verify


def _verify_png(ver: Any, model: Any) -> bytes:
    from slam2d.sensors.calibration.laser import _material_indices

    """Fig. 11 form: measured sigma (95 % interval) and the model's prediction with its band, per angle."""
    rows = ver.rows
    angles = sorted({r.setup.angle_deg for r in rows}, reverse=True)
    materials = list(dict.fromkeys(r.setup.material for r in rows))
    colours = dict(zip(materials, method_colours(len(materials)), strict=True))
    with _style():
        fig = _new_figure(4.2 * len(angles), 3.6, layout="constrained")
        axes = fig.subplots(1, len(angles), squeeze=False)[0]
        for ax, a in zip(axes, angles, strict=True):
            for m in materials:
                sel = sorted((r for r in rows if r.setup.angle_deg == a and r.setup.material == m),
                             key=lambda r: r.setup.distance)
                if not sel:
                    continue
                d = np.array([r.setup.distance for r in sel])
                meas = np.array([r.setup.sigma for r in sel])
                ci = np.array([r.setup.interval() for r in sel])
                # the model as a curve between the distances measured, its band for the set-ups' sample size
                grid = np.linspace(d.min(), d.max(), 60) if d.size > 1 else d
                mats = np.array(_material_indices(m), dtype=np.int64)
                dd, mm = np.meshgrid(grid, mats, indexing="ij")
                inc = np.full(dd.shape, math.radians(90.0 - a))
                p = model.sigma(dd, inc, mm).mean(axis=1)
                band = model.band(dd, inc, mm).mean(axis=1) if hasattr(model, "band") else np.zeros_like(p)
                dof = float(np.mean([r.setup.dof for r in sel]))
                h = ver.z * np.sqrt(band**2 + p**2 / (2.0 * dof))
                c = colours[m]
                ax.fill_between(grid, 1000 * (p - h), 1000 * (p + h), color=c, alpha=0.15)
                ax.plot(grid, 1000 * p, "-", color=c, lw=1)
                ax.errorbar(d, 1000 * meas, yerr=[1000 * (meas - ci[:, 0]), 1000 * (ci[:, 1] - meas)], fmt="o",
                            ms=3, color=c, capsize=2, label=m)
            ax.set_title(f"{a:g} deg (incidence {90 - a:g} deg)")
            ax.set_xlabel("distance [m]")
            ax.set_ylabel("sigma [mm]")
        axes[0].legend(fontsize=6)
        fig.suptitle("measured sigma (points, 95 % interval) against the model (line, band)")
        return _png(fig)


def verify_report(ver: Any, model: Any, data_sources: list[str], command: str = "") -> Report:
    rep = Report("Sensor model verification")
    rep.text(f"Model: {ver.model_source}. Data: {', '.join(data_sources)}; {len(ver.rows)} set-ups."
             + (f" Command: `{command}`." if command else ""))
    inside = sum(r.inside for r in ver.rows)
    rep.text(f"{inside} of {len(ver.rows)} set-ups ({100 * ver.share_inside:.1f} %) have their measured sigma "
             f"inside the model's band (prediction +- {ver.z:.2f} x the combined standard deviation of the model's "
             "own uncertainty and the sampling error of the measured sigma).")
    rep.image("figures/verify.png", _verify_png(ver, model), "measured against predicted sigma")
    rows = []
    for r in ver.rows:
        s = r.setup
        lo, hi = s.interval()
        rows.append([s.material, f"{s.angle_deg:g}", f"{s.distance:.3f}", _mm(s.sigma), f"{_mm(lo)}-{_mm(hi)}",
                     _mm(r.predicted), f"{_mm(r.predicted - r.half_width)}-{_mm(r.predicted + r.half_width)}",
                     f"{100 * (s.sigma / r.predicted - 1):+.1f}", "yes" if r.inside else "no"])
    rep.table(["surface", "angle [deg]", "distance [m]", "measured [mm]", "95 % interval [mm]", "model [mm]",
               "band [mm]", "measured vs model [%]", "inside"], rows)
    return rep


# --------------------------------------------------------------------------- odometry


def _odometry_png(cal: Any) -> bytes:
    from scipy.stats import norm

    z = cal.residuals
    with _style():
        fig = _new_figure(11.0, 3.4, layout="constrained")
        axes = fig.subplots(1, 4)
        for ax, j, name in zip(axes[:3], range(3), ("x", "y", "heading"), strict=True):
            x = np.sort(z[:, j])
            if x.size > 1000:
                x = x[np.linspace(0, x.size - 1, 1000).round().astype(int)]
            q = norm.ppf((np.arange(1, x.size + 1) - 0.5) / x.size)
            ax.plot(q, x, ".", ms=2)
            ax.plot([-4, 4], [-4, 4], "-", color="#d62728", lw=0.8)
            ax.set_title(f"{name} residual / model sigma")
            ax.set_xlabel("normal quantile")
        ax = axes[3]
        pairs = cal.pairs
        if pairs is not None:
            ax.plot(pairs.reference[:, 0], pairs.reference[:, 1], "-", color="k", lw=1, label="reference")
            ax.plot(pairs.odometry[:, 0], pairs.odometry[:, 1], "-", color="#1f77b4", lw=0.8, label="odometry")
            ax.set_aspect("equal", adjustable="datalim")
            ax.legend(fontsize=6)
            ax.set_title("trajectories")
        return _png(fig)


def odometry_report(cal: Any, sources: list[str], command: str = "") -> Report:
    rep = Report("Odometry calibration")
    rep.text(f"Odometry: {sources[0]}; reference: {sources[1]}. {cal.intervals} intervals, "
             f"{cal.distance:.1f} m and {math.degrees(cal.rotation):.0f} deg of motion. "
             f"Reference increments: {cal.reference_distance:g} m (GMapping linearUpdate) and "
             f"{cal.reference_rotation:g} rad (angularUpdate)." + (f" Command: `{command}`." if command else ""))
    rows = []
    units = {"srr": "m/m", "srt": "rad/m", "str": "m/rad", "stt": "rad/rad"}
    for k, e in cal.noise.items():
        rows.append([k, units[k], f"{e.value:.4g}", f"{e.low:.4g}-{e.high:.4g}" if e.identifiable else "not identifiable"])
    for k in ("wheel_radius_scale", "track_width_scale"):
        e = getattr(cal, k)
        rows.append([k, "-", f"{e.value:.4f}", f"{e.low:.4f}-{e.high:.4f}" if e.identifiable else "not identifiable"])
    rep.table(["parameter", "unit", "maximum likelihood", "95 % interval"], rows)
    rep.text(f"Reference error absorbed per interval: {1000 * cal.reference_noise['xy_m']:.3f} mm, "
             f"{math.degrees(cal.reference_noise['theta_rad']):.4f} deg. Log-likelihood {cal.log_likelihood:.1f}.")
    for note in cal.notes:
        rep.text("Note: " + note)
    rep.image("figures/odometry.png", _odometry_png(cal),
              "standardised residuals against normal quantiles, and the trajectories")
    rep.text("If the model fits, the standardised residuals lie on the red line; heavy tails mean slip or "
             "a reference with errors of its own.")
    return rep
