"""Map quality wall by wall: how noisy and how complete each true wall is in a SLAM map.

The study judged its maps by eye, wall by wall ("noise on a long straight wall"). Here each
map obstacle cell, moved into the truth's frame, is given to the nearest true wall segment
within ``band``; per wall we report the RMS distance of its cells from the wall line (the
wall's thickness and waviness: noise) and the share of the wall's length that has a map
obstacle within ``tolerance`` (coverage; a part "that could not be mapped" lowers it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import cKDTree

from slam2d.sim.world import segment_distances

__all__ = ["WallStats", "wall_stats", "longest_walls"]


@dataclass(frozen=True)
class WallStats:
    """One true wall segment in one map."""

    index: int
    length: float  # m
    cells: int  # map obstacle cells given to this wall
    rms: float  # m, RMS distance of those cells from the wall (NaN without cells)
    spread: float  # m, standard deviation of their signed offsets across the wall: thickness and waviness
    coverage: float  # share of the wall's samples with a map obstacle within the tolerance


def longest_walls(segments: ArrayLike, rel: float = 0.99) -> list[int]:
    """Indices of the longest segments (within ``rel`` of the longest): the study's "long straight wall"."""
    s = np.asarray(segments, dtype=np.float64).reshape(-1, 4)
    lengths = np.hypot(s[:, 2] - s[:, 0], s[:, 3] - s[:, 1])
    return [int(i) for i in np.nonzero(lengths >= rel * lengths.max())[0]]


def wall_stats(
    points: ArrayLike, segments: ArrayLike, *, band: float = 0.3, tolerance: float = 0.1, spacing: float = 0.05
) -> list[WallStats]:
    """Per-wall noise and coverage of map obstacle ``points`` (already in the truth's frame)."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    s = np.asarray(segments, dtype=np.float64).reshape(-1, 4)
    out = []
    if p.shape[0]:
        dist = segment_distances(s, p)
        nearest = np.argmin(dist, axis=1)
        near_d = dist[np.arange(p.shape[0]), nearest]
    for k, (x0, y0, x1, y1) in enumerate(s):
        length = float(np.hypot(x1 - x0, y1 - y0))
        n = max(2, int(np.ceil(length / spacing)) + 1)
        t = np.linspace(0.0, 1.0, n)
        samples = np.stack([x0 + t * (x1 - x0), y0 + t * (y1 - y0)], axis=1)
        if p.shape[0] == 0:
            out.append(WallStats(k, length, 0, float("nan"), float("nan"), 0.0))
            continue
        mine = (nearest == k) & (near_d <= band)
        d = near_d[mine]
        rms = float(np.sqrt(np.mean(d**2))) if d.size else float("nan")
        # Signed offset across the wall line: its spread does not depend on where the map's cell
        # centres happen to fall relative to the wall (a constant offset of up to half a cell).
        normal = np.array([-(y1 - y0), x1 - x0]) / max(length, 1e-12)
        offset = (p[mine] - np.array([x0, y0])) @ normal
        spread = float(np.std(offset)) if d.size > 1 else float("nan")
        if d.size:
            gap, _ = cKDTree(p[mine]).query(samples, k=1)
            coverage = float(np.mean(gap <= tolerance))
        else:
            coverage = 0.0
        out.append(WallStats(k, length, int(d.size), rms, spread, coverage))
    return out
