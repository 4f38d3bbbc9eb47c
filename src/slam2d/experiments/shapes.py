"""How well a map draws one known shape: thickness across it and distance to it, in metres.

The study judged its Figs. 8-10 by eye ("smoother and narrower obstacles", "the arched shape
of the can is more evident"). These measures put numbers on that, against the exact geometry
of the simulated world:

* **stations**: points along the true shape (every ``spacing`` metres, away from its ends and
  corners so a neighbouring wall does not count), each with the shape's normal there; for a
  circle only the arc facing the viewer (the robot sees one side of a can);
* **thickness** at a station: the length of the normal line, ``half_width`` either side of the
  true shape, that runs through occupied map cells (one clean wall of 5 cm cells: 0.05 m
  square to the grid, up to about 0.1 m for a diagonal staircase);
* **map -> shape**: distance from every occupied cell within ``half_width`` of the shape to the
  true shape (how far the drawn obstacle strays: smear and noise);
* **shape -> map**: distance from every station to the nearest occupied cell (how well the
  shape is drawn at all: a missing or misplaced piece);
* **coverage**: share of stations with any occupied cell on their normal line.

Whole-array numpy; the map is taken into the truth's frame by a transform ``[x, y, theta]``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from slam2d.core import se2
from slam2d.sim.world import segment_distances

__all__ = ["Shape", "stations", "shape_distance", "thickness_profile", "measure_shape"]


@dataclass(frozen=True)
class Shape:
    """Part of a world to measure: wall segments ``(M, 4)`` and circles ``(K, 3)``, truth frame."""

    name: str
    segments: NDArray[np.float64]
    circles: NDArray[np.float64]

    @classmethod
    def of(cls, name: str, segments: ArrayLike = (), circles: ArrayLike = ()) -> Shape:
        return cls(name, np.asarray(segments, dtype=np.float64).reshape(-1, 4),
                   np.asarray(circles, dtype=np.float64).reshape(-1, 3))


def stations(
    shape: Shape, *, spacing: float, end_margin: float, viewer: ArrayLike | None = None, arc_deg: float = 60.0
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Points ``(S, 2)`` along ``shape`` and the unit normals ``(S, 2)`` there.

    Segments: every ``spacing`` metres, at least ``end_margin`` from either end. Circles: every
    ``spacing`` metres of arc within ``arc_deg`` of the direction to ``viewer`` (all round if
    None).
    """
    pts, nrm = [np.zeros((0, 2))], [np.zeros((0, 2))]
    for x0, y0, x1, y1 in shape.segments:
        length = math.hypot(x1 - x0, y1 - y0)
        if length <= 2.0 * end_margin:
            continue
        s = np.arange(end_margin, length - end_margin + 1e-9, spacing)
        u = np.array([x1 - x0, y1 - y0]) / length
        pts.append(np.array([x0, y0]) + s[:, None] * u)
        nrm.append(np.repeat([[-u[1], u[0]]], s.size, axis=0))
    for cx, cy, r in shape.circles:
        centre = np.array([cx, cy])
        if viewer is None:
            mid, half = 0.0, math.pi
        else:
            v = np.asarray(viewer, dtype=np.float64)[:2] - centre
            mid, half = math.atan2(v[1], v[0]), math.radians(arc_deg)
        count = max(2, int(round(2.0 * half * r / spacing)) + 1)
        a = mid + np.linspace(-half, half, count)
        n = np.stack([np.cos(a), np.sin(a)], axis=-1)
        pts.append(centre + r * n)
        nrm.append(n)
    return np.concatenate(pts), np.concatenate(nrm)


def shape_distance(shape: Shape, points: ArrayLike) -> NDArray[np.float64]:
    """Distance (m) from each point ``(N, 2)`` to the nearest segment or circle outline of ``shape``."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    best = np.full(p.shape[0], np.inf)
    if shape.segments.shape[0]:
        best = np.minimum(best, segment_distances(shape.segments, p).min(axis=1))
    if shape.circles.shape[0]:
        c = shape.circles
        d = np.abs(np.hypot(p[:, None, 0] - c[None, :, 0], p[:, None, 1] - c[None, :, 1]) - c[None, :, 2])
        best = np.minimum(best, d.min(axis=1))
    return best


def _occupied_at(grid: Any, transform: NDArray[np.float64], points: NDArray[np.float64],
                 threshold: float) -> NDArray[np.bool_]:
    """Whether the map cell under each truth-frame point is occupied (False outside the map)."""
    local = se2.transform_points(se2.inverse(transform), points.reshape(-1, 2))
    cells = grid.world_to_cell(local)
    inside = grid.in_bounds(cells)
    occ = np.zeros(local.shape[0], dtype=np.bool_)
    occupied = grid.occupied(threshold)
    occ[inside] = occupied[cells[inside, 0], cells[inside, 1]]
    return occ.reshape(points.shape[:-1])


def thickness_profile(
    grid: Any, transform: ArrayLike, points: NDArray[np.float64], normals: NDArray[np.float64], *,
    half_width: float, step: float | None = None, threshold: float = 0.65,
) -> NDArray[np.float64]:
    """Occupied length (m) of the normal line ``points +- half_width * normals`` at every station."""
    step = float(grid.resolution) / 4.0 if step is None else float(step)
    t = np.arange(-half_width, half_width + 1e-12, step)
    line = points[:, None, :] + t[None, :, None] * normals[:, None, :]
    occ = _occupied_at(grid, np.asarray(transform, dtype=np.float64), line, threshold)
    return occ.sum(axis=1) * step


def measure_shape(
    grid: Any, transform: ArrayLike, shape: Shape, *, spacing: float = 0.025, half_width: float = 0.12,
    end_margin: float | None = None, viewer: ArrayLike | None = None, threshold: float = 0.65,
) -> dict[str, float]:
    """Thickness, distances and coverage of ``shape`` in ``grid`` (metres; see the module docstring)."""
    tr = np.asarray(transform, dtype=np.float64)
    margin = half_width + 2.0 * float(grid.resolution) if end_margin is None else end_margin
    pts, nrm = stations(shape, spacing=spacing, end_margin=margin, viewer=viewer)
    nan = float("nan")
    if pts.shape[0] == 0:
        return {"stations": 0, "thickness_median_m": nan, "thickness_p90_m": nan, "coverage": nan,
                "map_to_shape_mean_m": nan, "map_to_shape_p95_m": nan, "shape_to_map_mean_m": nan, "cells": 0}
    thick = thickness_profile(grid, tr, pts, nrm, half_width=half_width, threshold=threshold)
    seen = thick > 0
    rows, cols = np.nonzero(grid.occupied(threshold))
    cells = se2.transform_points(tr, grid.cell_to_world(np.stack([rows, cols], axis=-1)).reshape(-1, 2))
    near = shape_distance(shape, cells)
    # only cells beside the measured part of the shape (not past its ends, where other walls begin)
    beside = cKDTree(pts).query(cells, k=1)[0] <= half_width if cells.shape[0] else np.zeros(0, bool)
    mine = near[(near <= half_width) & beside]
    to_map = cKDTree(cells).query(pts, k=1)[0] if cells.shape[0] else np.full(pts.shape[0], np.inf)
    return {
        "stations": int(pts.shape[0]),
        "thickness_median_m": float(np.median(thick[seen])) if seen.any() else nan,
        "thickness_p90_m": float(np.percentile(thick[seen], 90)) if seen.any() else nan,
        "coverage": float(seen.mean()),
        "map_to_shape_mean_m": float(mine.mean()) if mine.size else nan,
        "map_to_shape_p95_m": float(np.percentile(mine, 95)) if mine.size else nan,
        "shape_to_map_mean_m": float(np.mean(to_map)),
        "cells": int(mine.size),
    }
