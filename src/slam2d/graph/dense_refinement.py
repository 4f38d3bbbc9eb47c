"""Dense multi-scan alignment after the wall bundle adjustment (``dense_refinement``).

The wall refinement (:mod:`slam2d.graph.wall_refinement`) uses the beams of straight segments and the wall
ends; the beams on round posts, short faces, clutter and corners are dropped. This stage uses every
return: after the wall refinement, the poses are refined again by the same Levenberg-Marquardt solve
(:func:`slam2d.graph.wall_refinement.refine_walls`, its odometry / graph edges and, with
``dense_refinement_walls``, its walls and wall ends) with one more block of residuals, each return
against the surface of *another* frame's scan:

1. **Points and normals** (once, pose-free; :func:`scan_normals`, compiled): every
   ``dense_refinement_beam_step``-th return of every scan, in its frame, and the normal of the total
   least-squares line through the returns within ``dense_refinement_normal_beams`` beams on either side
   of it (a run cut where neighbours are more than ``dense_refinement_break_distance`` apart); a normal
   whose line fits with an RMS over ``dense_refinement_normal_rms`` (a corner, clutter) is not used as a
   target.
2. **Association** (:meth:`DenseTerm.associate`, every round at the current poses): all points placed in
   the world, one ``scipy.spatial.cKDTree`` (whole-array queries); each point's nearest
   ``dense_refinement_neighbours`` within ``dense_refinement_max_distance``, the nearest of them whose frame is at
   least ``dense_refinement_frame_gap`` frames away and whose normal is usable is its target.
3. **Residual**: the point-to-line distance ``n_b . (p_a - p_b)`` over ``dense_refinement_sigma`` (the
   target's normal held in the world frame for the round), Huber at ``dense_refinement_robust_delta``;
   it moves both poses (Jacobians through the local perturbations, as the wall beams').
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numba import njit
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from slam2d.backends.spa import robust_objective, robust_weights
from slam2d.graph.wall_geometry import floored_sigmas, place_points, tls_line, usable_returns
from slam2d.params import param

__all__ = ["DenseRefinementParams", "DenseTerm", "scan_normals"]


# a feature most runs leave off: its parameters are listed after the method's own, under its name
_ADVANCED = {"advanced": True, "group": "dense refinement"}


@dataclass
class DenseRefinementParams:
    """The dense multi-scan alignment after the wall refinement (not in Karto)."""

    dense_refinement: bool = param(
        False,
        help="after the wall refinement (wall_refinement), refine the poses again with every return of every scan "
        "against the nearest surface of another frame's scan (point to line), jointly with the same odometry / "
        "graph edges (and walls, dense_refinement_walls): uses the returns the line model drops, round posts and "
        "short faces; only with wall_refinement (not in Karto; docs/methods/what-was-tried.md, karto: URG-04LX wall "
        "ends and the wall refinement)",
        **_ADVANCED,
    )
    dense_refinement_iterations: int = param(
        3, unit="rounds", low=1, help="rounds of association then Levenberg-Marquardt steps (dense_refinement)",
        **_ADVANCED,
    )
    dense_refinement_steps: int = param(
        3, unit="steps", low=1, help="Levenberg-Marquardt steps per association round (dense_refinement)", **_ADVANCED
    )
    dense_refinement_beam_step: int = param(
        2, unit="beams", low=1, help="every this-many-th return of a scan is used (dense_refinement)", **_ADVANCED
    )
    dense_refinement_normal_beams: int = param(
        4, unit="beams", low=1,
        help="a return's normal is that of the line through the returns this many beams either side (dense_refinement)",
        **_ADVANCED,
    )
    dense_refinement_break_distance: float = param(
        0.2, unit="m", low=0.0,
        help="neighbouring returns farther apart than this are not on one surface for a normal (dense_refinement)",
        **_ADVANCED,
    )
    dense_refinement_normal_rms: float = param(
        0.01, unit="m", low=0.0,
        help="a normal whose line fits its returns with a larger RMS is not a target (dense_refinement)",
        **_ADVANCED,
    )
    dense_refinement_max_distance: float = param(
        0.1, unit="m", low=0.0, help="largest distance from a return to its target return (dense_refinement)",
        **_ADVANCED,
    )
    dense_refinement_neighbours: int = param(
        16, unit="points", low=1,
        help="nearest returns looked at for a target (the nearest usable one wins) (dense_refinement)",
        **_ADVANCED,
    )
    dense_refinement_frame_gap: int = param(
        20, unit="frames", low=1,
        help="a target is in a frame at least this many frames away from the return's (dense_refinement)",
        **_ADVANCED,
    )
    dense_refinement_sigma: float = param(
        0.05, unit="m", low=1e-6, help="sigma of a return's distance from its target's line (dense_refinement)",
        **_ADVANCED,
    )
    dense_refinement_robust_delta: float = param(
        2.0, unit="sigma", low=1e-6, help="Huber kernel width of the point-to-line residual (dense_refinement)",
        **_ADVANCED,
    )
    dense_refinement_walls: bool = param(
        True,
        help="keep the wall refinement's walls and wall ends in the dense solve (off: the returns and the "
        "odometry / graph edges only) (dense_refinement)",
        **_ADVANCED,
    )


@njit(cache=True)
def _normals(x, y, half, break_distance):
    """Per point (scan order) the normal of the TLS line through its run's neighbours within ``half`` points."""
    n = x.shape[0]
    run = np.empty(n, np.int64)  # the run each point is on (cut at gaps)
    cut = 0
    for k in range(n):
        if k > 0 and math.hypot(x[k] - x[k - 1], y[k] - y[k - 1]) > break_distance:
            cut += 1
        run[k] = cut
    nx = np.zeros(n)
    ny = np.zeros(n)
    rms = np.full(n, np.inf)
    for k in range(n):
        s = max(k - half, 0)
        e = min(k + half, n - 1)
        while run[s] != run[k]:
            s += 1
        while run[e] != run[k]:
            e -= 1
        if e - s + 1 < 3:
            continue
        a, _, _, r = tls_line(x, y, s, e)
        nx[k] = math.cos(a)
        ny[k] = math.sin(a)
        rms[k] = r
    return nx, ny, rms


def scan_normals(points: NDArray[np.float64], half: int, break_distance: float):
    """Unit normals (K, 2) and line-fit RMS (K,) of points in scan order (:class:`DenseTerm`)."""
    points = np.ascontiguousarray(points, dtype=np.float64)
    if points.shape[0] == 0:
        return np.zeros((0, 2)), np.zeros(0)
    nx, ny, rms = _normals(points[:, 0].copy(), points[:, 1].copy(), int(half), float(break_distance))
    return np.stack([nx, ny], -1), rms


class DenseTerm:
    """The point-to-line residuals of every return against other frames' returns, an extra block of
    :func:`slam2d.graph.wall_refinement.refine_walls` (``associate`` per round, ``objective``, ``rows``)."""

    def __init__(self, scans: list[Any], sigmas: list[NDArray[np.float64] | None], p: Any,
                 range_limit: float = math.inf) -> None:
        self.p = p
        frame_l, q_l, n_l, ok_l, s_l = [], [], [], [], []
        step = int(p.dense_refinement_beam_step)
        for i, scan in enumerate(scans):
            beams, _, pts = usable_returns(scan, range_limit)
            if beams.size < 3:
                continue
            normal, rms = scan_normals(pts, p.dense_refinement_normal_beams, p.dense_refinement_break_distance)
            keep = slice(None, None, step)
            frame_l.append(np.full(pts[keep].shape[0], i, np.int64))
            q_l.append(pts[keep])
            n_l.append(normal[keep])
            ok_l.append(rms[keep] <= p.dense_refinement_normal_rms)
            s_l.append(floored_sigmas(sigmas[i], beams, p.dense_refinement_sigma)[keep])
        if frame_l:
            self.frame, self.q, self.normal = np.concatenate(frame_l), np.concatenate(q_l), np.concatenate(n_l)
            self.usable, self.sigma = np.concatenate(ok_l), np.concatenate(s_l)
        else:
            self.frame, self.q, self.normal = np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((0, 2))
            self.usable, self.sigma = np.zeros(0, bool), np.zeros(0)
        self.a = self.b = np.zeros(0, np.int64)
        self.n = np.zeros((0, 2))

    def __len__(self) -> int:
        return int(self.a.size)

    def associate(self, x: NDArray[np.float64]) -> int:
        """Each return's target at poses ``x`` (see the module); returns the number of pairs."""
        p = self.p
        m = self.frame.size
        self.a = self.b = np.zeros(0, np.int64)
        self.n = np.zeros((0, 2))
        if m < 2:
            return 0
        world = place_points(x[self.frame], self.q)
        k = min(int(p.dense_refinement_neighbours) + 1, m)
        _, idx = cKDTree(world).query(world, k=k, distance_upper_bound=p.dense_refinement_max_distance)
        idx = idx.reshape(m, k)
        found = idx < m
        j = np.where(found, idx, 0)
        ok = found & self.usable[j] & (np.abs(self.frame[j] - self.frame[:, None]) >= p.dense_refinement_frame_gap)
        has = ok.any(1)
        a = np.flatnonzero(has)
        b = j[a, np.argmax(ok[a], axis=1)]
        th = x[self.frame[b], 2]
        c, s = np.cos(th), np.sin(th)
        nb = self.normal[b]
        self.a, self.b = a, b
        self.n = np.stack([c * nb[:, 0] - s * nb[:, 1], s * nb[:, 0] + c * nb[:, 1]], -1)
        return int(a.size)

    def _residuals(self, x: NDArray[np.float64]):
        fa, fb = self.frame[self.a], self.frame[self.b]
        pa = place_points(x[fa], self.q[self.a])
        pb = place_points(x[fb], self.q[self.b])
        sig = np.hypot(self.sigma[self.a], self.sigma[self.b]) / math.sqrt(2.0)
        return fa, fb, ((self.n * (pa - pb)).sum(1)) / sig, sig

    def objective(self, x: NDArray[np.float64]) -> float:
        if self.a.size == 0:
            return 0.0
        r = self._residuals(x)[2]
        return float(robust_objective(r * r, "huber", self.p.dense_refinement_robust_delta).sum())

    def rows(self, x: NDArray[np.float64], row0: int):
        """(rows, columns, values, weighted residuals) of the block from row ``row0``: 6 entries per pair."""
        fa, fb, r, sig = self._residuals(x)
        m = r.size
        sw = np.sqrt(robust_weights(r * r, "huber", self.p.dense_refinement_robust_delta)) / sig
        cols, vals = [], []
        for f, q, sign in ((fa, self.q[self.a], 1.0), (fb, self.q[self.b], -1.0)):
            c, s = np.cos(x[f, 2]), np.sin(x[f, 2])
            nr0 = self.n[:, 0] * c + self.n[:, 1] * s  # R^T n
            nr1 = -self.n[:, 0] * s + self.n[:, 1] * c
            jt = nr0 * (-q[:, 1]) + nr1 * q[:, 0]
            cols.append(np.stack([3 * f, 3 * f + 1, 3 * f + 2], 1))
            vals.append(np.stack([nr0, nr1, jt], 1) * (sign * sw)[:, None])
        rows = np.repeat(row0 + np.arange(m), 6)
        return (rows, np.concatenate(cols, 1).ravel(), np.concatenate(vals, 1).ravel(), r * sig * sw)
