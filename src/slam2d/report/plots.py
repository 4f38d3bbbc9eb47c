"""Figures of the comparison report, rendered to PNG bytes.

* :func:`common_canvas` resamples several occupancy grids, each moved into a
  common frame by its own SE(2) transform, onto one canvas: the union of
  their transformed extents at one metres-per-pixel, so the map pictures
  share scale, orientation and size.
* :func:`map_panel_png`, :func:`trajectories_png`, :func:`time_per_scan_png`
  and :func:`diagnostics_png` draw the report's pictures.

Figures are :class:`matplotlib.figure.Figure` objects drawn by the Agg
canvas directly, not through ``pyplot``: nothing is registered in pyplot's
global figure list (so nothing can leak), and the caller's matplotlib backend
is left alone.
"""

from __future__ import annotations

import io
import math
import re
import textwrap
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from slam2d.core import se2
from slam2d.core.arrays import row_bands
from slam2d.report.images import UNKNOWN_GRAY, by_occupancy, grey_levels

__all__ = [
    "DPI",
    "MapCanvas",
    "common_canvas",
    "method_colours",
    "split_meaning",
    "map_panel_png",
    "trajectories_png",
    "time_per_scan_png",
    "diagnostics_png",
]

DPI = 100
#: Longest side of the map canvas, pixels: about twice the displayed width, so
#: walls stay crisp while a 100 m building still renders in a fraction of a second.
MAX_CANVAS_PIXELS = 1000
TRUTH_COLOUR = "#000000"
_SCALE_BAR_LENGTHS = (0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0, 100.0, 200.0, 500.0, 1000.0)
_PALETTE = (
    "#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd",
    "#8c564b", "#e377c2", "#17becf", "#bcbd22", "#7f7f7f",
)  # matplotlib's tab10, reordered so the first two differ for colour-blind readers
# text as it is: a "$" in a file or dataset name ("lab_$A_$B.clf") is not the start of a formula
_BASE_STYLE = {"font.size": 8, "axes.titlesize": 9, "legend.fontsize": 8, "axes.grid": False, "text.parse_math": False}


#: the dots marking where a map disagrees with itself
DISAGREEMENT_COLOUR = "#ff00ff"  # magenta: none of the methods' colours


def method_colours(count: int) -> list[str]:
    """One colour per method, the same in every figure of a report (cycles after ten)."""
    return [_PALETTE[i % len(_PALETTE)] for i in range(count)]


def split_meaning(meaning: str) -> tuple[str, str]:
    """``"grid cells the scan changed [cells]"`` -> ``("grid cells the scan changed", "cells")``."""
    m = re.match(r"^(.*?)\s*\[([^\]]*)\]\s*$", meaning or "")
    if m:
        return m.group(1), m.group(2)
    return meaning or "", ""


# --------------------------------------------------------------------------- maps on one canvas


@dataclass
class MapCanvas:
    """Maps resampled onto one canvas.

    ``images[i]`` is grey levels in [0, 1] (rows x cols, row 0 at the top =
    highest y), the unknown grey where map ``i`` has no cell;
    ``extent`` = ``(xmin, ymin, xmax, ymax)`` in the common frame, metres.
    """

    extent: tuple[float, float, float, float]
    metres_per_pixel: float
    images: list[NDArray[np.float64]]

    @property
    def shape(self) -> tuple[int, int]:
        return self.images[0].shape if self.images else (0, 0)  # type: ignore[return-value]

    @property
    def width(self) -> float:
        return self.extent[2] - self.extent[0]

    @property
    def height(self) -> float:
        return self.extent[3] - self.extent[1]


@dataclass
class MapRaster:
    """A map as its occupancy values only (int8, -1 unknown, 0..100): a sixth of an OccupancyGrid's memory,
    all a picture needs (a report of seven methods held seven full grids at once)."""

    values: NDArray[np.int8]
    resolution: float
    origin: tuple[float, float]

    @classmethod
    def of(cls, grid: Any) -> MapRaster:
        """From an OccupancyGrid, or from a map as read (MapImage: its values as the file has them)."""
        values = grid.occupancy() if callable(grid.occupancy) else grid.occupancy
        return cls(values, float(grid.resolution), (float(grid.origin[0]), float(grid.origin[1])))

    @property
    def shape(self) -> tuple[int, int]:
        return self.values.shape  # type: ignore[return-value]

    def occupancy(self) -> NDArray[np.int8]:
        return self.values

    def extent(self) -> tuple[float, float, float, float]:
        ox, oy = self.origin
        rows, cols = self.shape
        return ox, oy, ox + cols * self.resolution, oy + rows * self.resolution


def _grid_corners(grid: Any) -> NDArray[np.float64]:
    xmin, ymin, xmax, ymax = grid.extent()
    return np.array([[xmin, ymin], [xmax, ymin], [xmax, ymax], [xmin, ymax]], dtype=np.float64)


def common_canvas(
    grids: Sequence[Any],
    transforms: Sequence[ArrayLike | None],
    *,
    max_pixels: int = MAX_CANVAS_PIXELS,
) -> MapCanvas:
    """Resample ``grids`` onto one canvas in a common frame.

    ``transforms[i]`` is the SE(2) pose ``[x, y, theta]`` taking grid ``i``'s
    frame into the common frame (None: the identity). The canvas covers the
    union of the transformed extents at the finest grid resolution, or coarser
    so that its longest side has at most ``max_pixels`` pixels. Each canvas
    pixel takes the value of the grid cell under it (nearest cell, found
    through the inverse transform). When the canvas is coarser than a grid,
    the grid is first reduced by keeping the darkest cell of each block, and
    the darkest of 2 x 2 samples across the pixel is kept, so walls one cell
    thick do not vanish.
    """
    if len(grids) != len(transforms):
        raise ValueError(f"transforms: {len(transforms)} given for {len(grids)} grids")
    poses = [np.zeros(3) if t is None else se2.as_poses(t).reshape(3) for t in transforms]
    usable = [i for i, g in enumerate(grids) if g.shape[0] > 0 and g.shape[1] > 0]
    if not usable:
        return MapCanvas((0.0, 0.0, 0.0, 0.0), 1.0, [])
    corners = np.concatenate([se2.transform_points(poses[i], _grid_corners(grids[i])) for i in usable])
    xmin, ymin = corners.min(axis=0)
    xmax, ymax = corners.max(axis=0)
    finest = min(float(grids[i].resolution) for i in usable)
    longest = max(xmax - xmin, ymax - ymin, finest)
    mpp = max(finest, longest / max_pixels)
    cols = max(1, math.ceil((xmax - xmin) / mpp - 1e-9))
    rows = max(1, math.ceil((ymax - ymin) / mpp - 1e-9))
    # Centre the pixel lattice on the union box.
    xmin = 0.5 * (xmin + xmax) - 0.5 * cols * mpp
    ymax = 0.5 * (ymin + ymax) + 0.5 * rows * mpp
    extent = (float(xmin), float(ymax - rows * mpp), float(xmin + cols * mpp), float(ymax))

    images = []
    for grid, pose in zip(grids, poses):
        image = np.full((rows, cols), UNKNOWN_GRAY, dtype=np.float64)
        if grid.shape[0] > 0 and grid.shape[1] > 0:
            grey, resolution = _pooled_grey(grid, mpp)
            origin = grid.origin
            # A pixel up to twice as wide as a pooled cell: the darkest of 2 x 2 samples.
            samples = max(1, math.ceil(mpp / resolution - 1e-9))
            inverse = se2.inverse(pose)
            for a in range(samples):
                for b in range(samples):
                    fx = (np.arange(cols) + (a + 0.5) / samples) * mpp + xmin
                    fy = ymax - (np.arange(rows) + (b + 0.5) / samples) * mpp
                    # a band of pixel rows at a time: a whole canvas's sample points are 16 bytes a pixel, twice
                    for band in row_bands((rows, cols), 1 << 16):
                        points = np.stack(np.broadcast_arrays(fx[None, :], fy[band, None]), axis=-1)
                        sample = _lookup(grey, origin, resolution, se2.transform_points(inverse, points))
                        image[band] = sample if (a, b) == (0, 0) else np.minimum(image[band], sample)
        images.append(image)
    return MapCanvas(extent, float(mpp), images)


def _pooled_grey(grid: Any, metres_per_pixel: float) -> tuple[NDArray[np.float64], float]:
    """The grid's grey levels (row 0 = lowest y) and cell size, pooled to at most one cell per canvas pixel.

    Pooling keeps the darkest cell of each block (occupied over unknown over
    free), so a wall one cell thick survives any reduction.
    """
    # Each occupancy value's grey, and its rank among the greys (0 = darkest): the darkest cell of a block is
    # the one of least rank, pooled as one byte a cell (float64 greys of a big map were 220 MB a copy).
    levels = grey_levels()
    rank = np.empty(levels.size, dtype=np.uint8)
    rank[np.argsort(levels, kind="stable")] = np.arange(levels.size, dtype=np.uint8)
    by_rank = np.sort(levels, kind="stable")
    occupancy = grid.occupancy()  # row 0 = lowest y
    factor = max(1, int(metres_per_pixel / float(grid.resolution) + 1e-9))
    if factor == 1:
        return by_rank[by_occupancy(rank, occupancy)], float(grid.resolution)
    rows, cols = occupancy.shape
    out_rows, out_cols = -(-rows // factor), -(-cols // factor)
    pooled = np.empty((out_rows, out_cols), dtype=np.uint8)
    # a band of pooled rows at a time: a diverged map of 40 M cells had three whole-map byte copies at once
    for band in row_bands((out_rows, out_cols * factor * factor)):
        r0, r1 = band.start, min(band.stop, out_rows)
        ranks = by_occupancy(rank, occupancy[r0 * factor : r1 * factor])
        padded = np.full(((r1 - r0) * factor, out_cols * factor), rank[0], dtype=np.uint8)
        padded[: ranks.shape[0], :cols] = ranks
        pooled[r0:r1] = padded.reshape(-1, factor, out_cols, factor).min(axis=(1, 3))
    return by_rank[pooled], float(grid.resolution) * factor


def _lookup(
    grey: NDArray[np.float64], origin: tuple[float, float], resolution: float, points: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Grey level of the cell under each point (unknown outside the grid)."""
    col = np.floor((points[..., 0] - origin[0]) / resolution).astype(np.int64)
    row = np.floor((points[..., 1] - origin[1]) / resolution).astype(np.int64)
    rows, cols = grey.shape
    inside = (row >= 0) & (row < rows) & (col >= 0) & (col < cols)
    out = np.full(points.shape[:-1], UNKNOWN_GRAY, dtype=np.float64)
    out[inside] = grey[row[inside], col[inside]]
    return out


# --------------------------------------------------------------------------- figures


def _new_figure(width_in: float, height_in: float, layout: str | None = None) -> Any:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_in, height_in), dpi=DPI, layout=layout)
    FigureCanvasAgg(fig)
    return fig


def _png(fig: Any) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, metadata={"Software": None})
    fig.clear()
    return buf.getvalue()


def _style() -> Any:
    import matplotlib

    return matplotlib.rc_context(_BASE_STYLE)


def log_scale(ax: Any, axis: str = "y") -> None:
    """A log axis whose ticks read 0.1, 1, 10: the report style turns mathtext off (a '$' in a file name must
    print as itself), and matplotlib's own log labels are mathtext ($10^{-1}$)."""
    from matplotlib import ticker

    getattr(ax, f"set_{axis}scale")("log")
    target = ax.yaxis if axis == "y" else ax.xaxis
    target.set_major_formatter(ticker.FuncFormatter(lambda v, _: f"{v:g}"))
    target.set_minor_formatter(ticker.NullFormatter())


def scale_bar_length(width_m: float) -> float:
    """A round length (1, 2, 5 x 10^k m) of at most a fifth of the width."""
    target = width_m / 5.0
    fitting = [v for v in _SCALE_BAR_LENGTHS if v <= target]
    return fitting[-1] if fitting else _SCALE_BAR_LENGTHS[0]


def map_panel_size(canvas: MapCanvas) -> tuple[float, float, tuple[float, float, float, float]]:
    """Figure width, height (inches) and axes box (figure fractions): the same for every panel of a canvas."""
    left, right, bottom, top = 0.6, 0.2, 0.45, 0.45
    fig_w = 8.0  # about 730 pixels of map: close to the canvas's own resolution
    axes_w = fig_w - left - right
    axes_h = axes_w * canvas.height / max(canvas.width, 1e-9)
    if axes_h > 9.0:  # a tall, thin building: cap the height and centre the axes
        axes_h = 9.0
        axes_w = axes_h * canvas.width / max(canvas.height, 1e-9)
        left = 0.5 * (fig_w - axes_w)
    axes_h = max(axes_h, 0.5)
    fig_h = axes_h + bottom + top
    return fig_w, fig_h, (left / fig_w, bottom / fig_h, axes_w / fig_w, axes_h / fig_h)


def map_panel_png(canvas: MapCanvas, index: int, title: str, *, colour: str = TRUTH_COLOUR,
                  track: NDArray[np.float64] | None = None, marks: NDArray[np.float64] | None = None) -> bytes:
    """One map of a canvas as a PNG: title, axes in metres, a scale bar; every panel of a canvas has one size.

    ``track`` (poses ``(N, 3)`` in the canvas frame) is drawn over the map in ``colour``, its start as a dot;
    ``marks`` (points ``(M, 2)``, the same frame) as small magenta dots: where the map disagrees with itself.
    """
    from matplotlib.font_manager import FontProperties
    from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar

    fig_w, fig_h, box = map_panel_size(canvas)
    xmin, ymin, xmax, ymax = canvas.extent
    with _style():
        fig = _new_figure(fig_w, fig_h)
        ax = fig.add_axes(box)
        ax.imshow(canvas.images[index], cmap="gray", vmin=0.0, vmax=1.0, extent=(xmin, xmax, ymin, ymax),
                  interpolation="antialiased", origin="upper")
        if track is not None and len(track):
            ax.plot(track[:, 0], track[:, 1], color=colour, lw=1.0, alpha=0.85)
            ax.plot(track[:1, 0], track[:1, 1], "o", color=colour, ms=4)
        if marks is not None and len(marks):
            ax.plot(marks[:, 0], marks[:, 1], ".", color=DISAGREEMENT_COLOUR, ms=1.5, alpha=0.8)
        ax.set_xlim(xmin, xmax)
        ax.set_ylim(ymin, ymax)
        # Panels are shown at about 80 % of their size, side by side: larger type than the other figures.
        ax.set_title(title, color=colour, fontweight="bold", fontsize=13)
        ax.tick_params(labelsize=10, length=3)
        length = scale_bar_length(canvas.width)
        bar = AnchoredSizeBar(
            ax.transData, length, f"{length:g} m", "lower left", pad=0.3, sep=3, color="black",
            frameon=True, size_vertical=max(canvas.height * 0.006, canvas.metres_per_pixel),
            fontproperties=FontProperties(size=11),
        )
        bar.patch.set_alpha(0.8)
        ax.add_artist(bar)
        return _png(fig)


def trajectories_png(
    tracks: Sequence[tuple[str, NDArray[np.float64], str]],
    truth: tuple[str, NDArray[np.float64]] | None,
    *,
    title: str,
) -> bytes:
    """Trajectories ``(label, poses (N, 3), colour)`` over the truth's ``(label, poses)``, equal axis scale."""
    with _style():
        fig = _new_figure(7.5, 6.0)
        ax = fig.add_axes((0.09, 0.08, 0.88, 0.85))
        if truth is not None and len(truth[1]):
            ax.plot(truth[1][:, 0], truth[1][:, 1], color=TRUTH_COLOUR, lw=3.0, alpha=0.3, label=truth[0])
        for k, (label, poses, colour) in enumerate(tracks):
            if len(poses) == 0:
                continue
            # Earlier methods drawn wider, so a trajectory hidden under an identical one still shows.
            width = max(1.0, 3.0 - 1.0 * k) if len(tracks) > 1 else 1.2
            ax.plot(poses[:, 0], poses[:, 1], color=colour, lw=width, label=label)
            ax.plot(poses[:1, 0], poses[:1, 1], "o", color=colour, ms=4)
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_title(title)
        ax.grid(True, lw=0.3, alpha=0.5)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(loc="best", framealpha=0.85)
        return _png(fig)


def error_along_run_png(series: Sequence[tuple[str, NDArray[np.float64], NDArray[np.float64], str]],
                        against: str) -> bytes:
    """Position error (m) against time in the recording, ``(label, t (s), error (m), colour)`` per method."""
    with _style():
        fig = _new_figure(7.5, 3.4)
        ax = fig.add_axes((0.09, 0.15, 0.88, 0.75))
        for label, t, err, colour in series:
            # a log axis: a diverged method (metres) and good ones (centimetres) stay readable on one plot
            ax.plot(t, np.maximum(err, 1e-3), color=colour, lw=1.0, label=f"{label} (max {np.nanmax(err):.3g} m)")
        ax.set_xlabel("time in the recording [s]")
        ax.set_ylabel("position error [m] (log)")
        ax.set_title(f"Distance from the {against} along the run, after the alignment")
        log_scale(ax)
        ax.grid(True, which="major", lw=0.3, alpha=0.5)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(loc="upper left", framealpha=0.85)
        return _png(fig)


def time_per_scan_png(series: Sequence[tuple[str, NDArray[np.float64], NDArray[np.float64], str]]) -> bytes:
    """Wall time per scan (ms) against time in the recording, ``(label, t (s), wall (s), colour)`` per method.

    The median of each method is a dashed line of its colour; the y axis is
    logarithmic when every time is positive.
    """
    with _style():
        fig = _new_figure(9.0, 3.6)
        ax = fig.add_axes((0.08, 0.14, 0.9, 0.78))
        positive = True
        for label, t, wall, colour in series:
            ms = np.asarray(wall, dtype=np.float64) * 1000.0
            finite = np.isfinite(ms) & np.isfinite(t)
            if not finite.any():
                continue
            positive &= bool((ms[finite] > 0).all())
            median = float(np.median(ms[finite]))
            ax.plot(t[finite], ms[finite], color=colour, lw=0.7, alpha=0.8, label=f"{label} (median {median:.3g} ms)")
            ax.axhline(median, color=colour, lw=1.2, ls="--")
        if positive and ax.lines:
            log_scale(ax)
        ax.set_xlabel("time in the recording [s]")
        ax.set_ylabel("wall time per scan [ms]")
        ax.set_title("Time per scan (dashed: median)")
        ax.grid(True, which="major", lw=0.3, alpha=0.5)
        if ax.lines:
            ax.legend(loc="upper right", framealpha=0.85)
        return _png(fig)


def diagnostics_png(
    t: NDArray[np.float64],
    panels: Sequence[tuple[str, NDArray[np.float64], str]],
    *,
    colour: str,
    title: str,
) -> bytes:
    """One small plot per method-specific series ``(name, values, meaning)`` against time in the recording."""
    n = len(panels)
    ncols = min(3, max(1, n))
    nrows = math.ceil(n / ncols)
    with _style():
        fig = _new_figure(3.3 * ncols, 2.3 * nrows + 0.3, layout="constrained")
        fig.suptitle(title, fontsize=9, fontweight="bold", color=colour)
        for k, (name, values, meaning) in enumerate(panels):
            ax = fig.add_subplot(nrows, ncols, k + 1)
            text, unit = split_meaning(meaning)
            finite = np.isfinite(values) & np.isfinite(t)
            if values.size and finite.sum() < 0.2 * values.size:
                # Sparse values (only some updates report them): dots, so isolated points show.
                ax.plot(t[finite], values[finite], ".", color=colour, ms=2.5)
            else:
                ax.plot(t, values, color=colour, lw=0.7)
            ax.set_title("\n".join(textwrap.wrap(text or name, 42)), fontsize=8)
            ax.set_ylabel(f"{name} [{unit}]" if unit else name, fontsize=7)
            ax.set_xlabel("time [s]", fontsize=7)
            ax.tick_params(labelsize=7)
            ax.grid(True, lw=0.3, alpha=0.5)
        return _png(fig)


def disagreement_along_run_png(series: Sequence[tuple[str, NDArray[np.float64], NDArray[np.float64], str]]) -> bytes:
    """Each run's self-disagreement (%) against the scan number, ``(label, scan, percent, colour)`` per method."""
    with _style():
        fig = _new_figure(7.5, 3.4)
        ax = fig.add_axes((0.09, 0.15, 0.88, 0.75))
        for label, scan, percent, colour in series:
            ax.plot(scan, percent, color=colour, lw=1.0, label=label)
        ax.set_xlabel("scan")
        ax.set_ylabel("beams contradicting [%]")
        ax.set_title("Where each map disagrees with itself (21-scan windows)")
        ax.set_ylim(bottom=0.0)
        ax.grid(True, which="major", lw=0.3, alpha=0.5)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(loc="upper left", framealpha=0.85)
        return _png(fig)
