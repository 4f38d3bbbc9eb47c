"""A lower bound on the trajectory error any method can reach on a simulated recording.

For a simulated recording the truth is known exactly: the true trajectory, the
world's walls, the laser's range noise model and the odometry's noise model.
:func:`accuracy_bound` turns these into the Fisher information of everything the
robot measured about its poses and inverts it (the Cramer-Rao bound of a batch
smoother): the covariance below which no unbiased estimator of the trajectory can
go, whatever its front end, matcher or optimiser. From the per-pose covariances
it gives the expected ATE (RMS over the scans of the position error after the
best rigid alignment, as ``slam2d evaluate`` computes the ATE) and the heading
error.

What goes in (see docs/accuracy_bound.md for the assumptions and their effect):

* **Laser**: every beam that hits a surface within the laser's range and returns
  (weighted by ``1 - dropout probability``) measures its range with the
  simulated laser's sigma(distance, incidence, material); its information about
  the pose is ``g g^T / sigma^2`` with ``g`` the derivative of the true range
  with respect to the robot's pose, exact from the hit surface's normal. Beams
  with no return give none.
* **Edges**: where a wall ends in front of something farther (a door jamb, a
  corner of a box), the scan tells the edge's bearing only to within the gap
  between two beams; it is counted as a bearing measurement with the variance of
  a uniform error over that gap (``angle_increment**2 / 12``). The range
  derivative cannot see this information (the range jumps there), and without it
  the bound would not be one.
* **Odometry**: the increments between scans with the covariance
  :class:`~slam2d.sensors.motion_noise.OdometryNoise` gives them, propagated
  exactly (to first order) through the odometry steps between two scans.
* **The first pose** is known (every method starts from it).
* **The map**, either

  - ``map="known"``: the true world. This is the bound of localisation in a
    perfect map, the loosest (lowest) bound; revisits need no loop closure here
    because every scan is already compared with the true walls.
  - ``map="walls"``: walls (and round obstacles) of unknown position: every
    segment's two end points and every circle's centre and radius are nuisance
    parameters estimated with the trajectory. This is the SLAM bound: what the
    scans can tell when the map must be learnt from them too, for an estimator
    that at least knows the world is made of straight walls and round posts (a
    grid method knows less, so it cannot do better).

Both assume known data association (each beam's surface is known), Gaussian
range noise and a locally linear model; biased estimators (priors that pull to
the truth) are outside a Cramer-Rao bound. The error of one run fluctuates about
the expectation; the bound holds for the RMS over runs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from numba import njit
from numpy.typing import NDArray

from slam2d.core import se2
from slam2d.errors import InputError
from slam2d.sensors.motion_noise import OdometryNoise, step_variances
from slam2d.sensors.range_noise import RangeNoiseModel, dropout_probability

__all__ = [
    "BoundSetup",
    "setup_from_simulation",
    "laser_information",
    "odometry_covariances",
    "accuracy_bound",
    "chain_marginals",
    "joint_information",
    "oracle_smoother",
]

#: Sigma used where the range noise model says 0 (noise-free ranges would give infinite information).
SIGMA_FLOOR = 1e-4
#: Variance floor of an odometry increment (standing still is exact in the model; keep the matrix finite).
ODOMETRY_VARIANCE_FLOOR = 1e-12


@dataclass
class BoundSetup:
    """Everything the bound needs about one simulated recording.

    ``odometry_truth`` holds the true poses at the odometry rate and ``scan_indices``
    which of them had a scan; ``mount`` is the laser's pose on the robot.
    """

    world: Any
    odometry_truth: NDArray[np.float64]
    scan_indices: NDArray[np.int64]
    angles: NDArray[np.float64]
    angle_increment: float
    range_min: float
    range_max: float
    mount: NDArray[np.float64]
    range_noise: RangeNoiseModel
    dropouts: bool
    odometry_noise: OdometryNoise

    @property
    def scan_truth(self) -> NDArray[np.float64]:
        return self.odometry_truth[self.scan_indices]


def setup_from_simulation(sim: Any) -> BoundSetup:
    """A :class:`BoundSetup` for a :class:`slam2d.sim.simulate.Simulation`, with its laser and noise models."""
    from slam2d.sim.simulate import _range_noise

    if sim.params.distortion:
        raise InputError("the bound assumes scans taken at one pose; simulate without distortion", field="distortion")
    return BoundSetup(
        world=sim.world,
        odometry_truth=np.asarray(sim.truth, dtype=np.float64),
        scan_indices=np.asarray(sim.scan_indices, dtype=np.int64),
        angles=np.asarray(sim.laser.angles, dtype=np.float64),
        angle_increment=float(sim.laser.angle_increment),
        range_min=float(sim.laser.range_min),
        range_max=float(sim.laser.range_max),
        mount=np.asarray(sim.robot.laser_mount, dtype=np.float64),
        range_noise=_range_noise(sim.params),
        dropouts=bool(sim.params.dropouts),
        odometry_noise=sim.noise,
    )


# ---------------------------------------------------------------------------
# Laser


@njit(cache=True)
def _hit_surfaces(hx, hy, segments, circles, surface, along):
    """For each hit point, the surface it lies on: segment j (0..M-1) or circle M+k; -1 for none.

    ``along`` gets the hit's position along its segment (0 at the first end point, 1 at
    the second) or, for a circle, 0. The ray caster does not return which surface it
    hit, so it is found here as the nearest one (the hit lies on it up to rounding).
    """
    m = segments.shape[0]
    for i in range(hx.shape[0]):
        if not np.isfinite(hx[i]):
            surface[i] = -1
            continue
        best = np.inf
        best_j = -1
        best_t = 0.0
        for j in range(m):
            ex = segments[j, 2] - segments[j, 0]
            ey = segments[j, 3] - segments[j, 1]
            ll = ex * ex + ey * ey
            t = ((hx[i] - segments[j, 0]) * ex + (hy[i] - segments[j, 1]) * ey) / ll if ll > 0 else 0.0
            t = min(max(t, 0.0), 1.0)
            dx = segments[j, 0] + t * ex - hx[i]
            dy = segments[j, 1] + t * ey - hy[i]
            d = dx * dx + dy * dy
            if d < best:
                best, best_j, best_t = d, j, t
        for k in range(circles.shape[0]):
            d = math.hypot(hx[i] - circles[k, 0], hy[i] - circles[k, 1]) - circles[k, 2]
            d = d * d
            if d < best:
                best, best_j, best_t = d, m + k, 0.0
        surface[i] = best_j
        along[i] = best_t


@dataclass
class LaserInformation:
    """The laser's information, per scan and per map parameter.

    ``pose`` ``(N, 3, 3)``: information of each scan about its own pose (range
    and edge terms). ``rows``: one row per used measurement with its scan index,
    weight (1/variance), derivative with respect to the pose ``(3,)`` and, for
    the map parameters, up to four parameter indices with their derivatives
    (``-1``: none). ``n_params``: number of map parameters (4 per segment, 3 per
    circle). ``beams_used`` and ``edges_used`` count the terms (range rows first,
    then edge rows). For checks against a recording's actual readings: ``beam``,
    the flattened index (scan * beams + beam) of the row's beam (an edge's nearer
    beam); ``variance`` of the reading (without the dropout weighting); ``value``,
    the true range or the edge's true bearing in the laser frame; ``reading``, for
    edge rows the bearing a scan would report (the middle of the beam gap).
    """

    pose: NDArray[np.float64]
    scan: NDArray[np.int64]
    weight: NDArray[np.float64]
    d_pose: NDArray[np.float64]
    param_index: NDArray[np.int64]
    d_param: NDArray[np.float64]
    n_params: int
    beams_used: int
    edges_used: int
    beam: NDArray[np.int64]
    variance: NDArray[np.float64]
    value: NDArray[np.float64]
    reading: NDArray[np.float64]


def laser_information(setup: BoundSetup, *, edges: bool = True, edge_sigma: float = 0.0) -> LaserInformation:
    """Fisher information of every scan about its pose (and about the walls), whole-array.

    ``edge_sigma`` (m): locate a wall end no better than this across the beam (the bearing's
    standard deviation is at least ``edge_sigma / distance``); 0 keeps the beam gap's.
    """
    from slam2d.sim.laser import _Geometry

    geometry = _Geometry(setup.world)
    poses = setup.scan_truth
    n, b = poses.shape[0], setup.angles.shape[0]
    laser = se2.compose(poses, setup.mount)  # (N, 3)
    lx = np.repeat(laser[:, 0], b)
    ly = np.repeat(laser[:, 1], b)
    heading = (laser[:, 2][:, None] + setup.angles[None, :]).reshape(-1)
    r, incidence, material = geometry.cast(lx, ly, heading)
    dx, dy = np.cos(heading), np.sin(heading)
    r = np.where(np.isfinite(r), r, np.nan)  # nothing hit
    hx, hy = lx + r * dx, ly + r * dy
    surface = np.empty(r.shape[0], dtype=np.int64)
    along = np.zeros(r.shape[0])
    _hit_surfaces(hx, hy, geometry.segments, geometry.circles, surface, along)
    with np.errstate(invalid="ignore"):
        hit = (material >= 0) & (r >= setup.range_min) & (r < setup.range_max) & (surface >= 0)

    m_seg = geometry.segments.shape[0]
    seg = geometry.segments if m_seg else np.zeros((1, 4))
    # Unit normal of the hit surface: the segment's fixed normal, or the circle's outward one.
    sidx = np.where(hit & (surface < m_seg), surface, 0)
    ex, ey = seg[sidx, 2] - seg[sidx, 0], seg[sidx, 3] - seg[sidx, 1]
    el = np.hypot(ex, ey)
    el = np.where(el > 0, el, 1.0)
    nx, ny = -ey / el, ex / el
    cidx = np.where(hit & (surface >= m_seg), surface - m_seg, 0)
    on_circle = hit & (surface >= m_seg)
    if geometry.circles.shape[0]:
        c = geometry.circles[cidx]
        cx_n = (hx - c[:, 0]) / c[:, 2]
        cy_n = (hy - c[:, 1]) / c[:, 2]
        nx = np.where(on_circle, cx_n, nx)
        ny = np.where(on_circle, cy_n, ny)
    nd = nx * dx + ny * dy
    hit &= np.abs(nd) > 1e-9

    # Range derivatives: r = (n.(q - p)) / (n.d) locally, so dr/dp = -n/(n.d) and
    # dr/dphi = -r (n.d_perp)/(n.d); the laser's position moves with the heading by the mount.
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_nd = np.where(hit, 1.0 / nd, 0.0)
    drx, dry = -nx * inv_nd, -ny * inv_nd
    dphi = -np.where(hit, r, 0.0) * (-nx * dy + ny * dx) * inv_nd
    base_heading = np.repeat(poses[:, 2], b)
    mc, ms = np.cos(base_heading), np.sin(base_heading)
    mxw = mc * setup.mount[0] - ms * setup.mount[1]  # mount offset in the world
    myw = ms * setup.mount[0] + mc * setup.mount[1]
    dth = drx * (-myw) + dry * mxw + dphi
    g = np.stack([drx, dry, dth], axis=1)

    sigma = np.full(r.shape[0], np.nan)
    if hit.any():
        sigma[hit] = setup.range_noise.sigma(r[hit], incidence[hit], material[hit])
    sigma = np.where(np.isfinite(sigma), np.maximum(sigma, SIGMA_FLOOR), SIGMA_FLOOR)
    keep = np.ones(r.shape[0])
    if setup.dropouts and hit.any():
        keep[hit] = 1.0 - dropout_probability(incidence[hit], material[hit])
    w = np.where(hit, keep / sigma**2, 0.0)

    scan_of_beam = np.repeat(np.arange(n), b)
    rows_beam = np.flatnonzero(w > 0)
    # Map parameters: segment j -> 4 j .. 4 j + 3 (its end points), circle k -> 4 M + 3 k .. (cx, cy, r).
    # Moving an end point by delta moves the wall at the hit by (1 - t) delta (first end) or t delta (second).
    n_params = 4 * m_seg + 3 * geometry.circles.shape[0]
    pidx = np.full((rows_beam.shape[0], 4), -1, dtype=np.int64)
    dpar = np.zeros((rows_beam.shape[0], 4))
    sb = surface[rows_beam]
    t = along[rows_beam]
    base = nx[rows_beam] * inv_nd[rows_beam], ny[rows_beam] * inv_nd[rows_beam]
    is_seg = sb < m_seg
    pidx[is_seg] = 4 * sb[is_seg, None] + np.arange(4)[None, :]
    dpar[is_seg] = np.stack([(1 - t) * base[0], (1 - t) * base[1], t * base[0], t * base[1]], axis=1)[is_seg]
    is_c = ~is_seg
    pidx[is_c, :3] = 4 * m_seg + 3 * (sb[is_c, None] - m_seg) + np.arange(3)[None, :]
    dpar[is_c, :3] = np.stack([base[0], base[1], inv_nd[rows_beam]], axis=1)[is_c]

    scans = [scan_of_beam[rows_beam]]
    weights = [w[rows_beam]]
    d_pose = [g[rows_beam]]
    pidxs = [pidx]
    dpars = [dpar]
    beams = [rows_beam.astype(np.int64)]
    variances = [sigma[rows_beam] ** 2]
    values = [r[rows_beam]]
    readings = [np.full(rows_beam.shape[0], np.nan)]
    n_edges = 0
    if edges and b > 1:
        e = _edge_rows(setup, geometry, r.reshape(n, b), hit.reshape(n, b), surface.reshape(n, b),
                       along.reshape(n, b), hx.reshape(n, b), hy.reshape(n, b), incidence.reshape(n, b),
                       laser, poses, keep.reshape(n, b), edge_sigma)
        if e is not None:
            scans.append(e[0])
            weights.append(e[1])
            d_pose.append(e[2])
            pidxs.append(e[3])
            dpars.append(e[4])
            beams.append(e[5])
            variances.append(e[6])
            values.append(e[7])
            readings.append(e[8])
            n_edges = e[0].shape[0]
    scan = np.concatenate(scans)
    weight = np.concatenate(weights)
    d = np.concatenate(d_pose)
    info = np.zeros((n, 3, 3))
    np.add.at(info, scan, weight[:, None, None] * d[:, :, None] * d[:, None, :])
    return LaserInformation(info, scan, weight, d, np.concatenate(pidxs), np.concatenate(dpars),
                            n_params, int(rows_beam.shape[0]), n_edges, np.concatenate(beams),
                            np.concatenate(variances), np.concatenate(values), np.concatenate(readings))


def _edge_rows(setup, geometry, r, hit, surface, along, hx, hy, incidence, laser, poses, keep, edge_sigma):
    """Bearing measurements of wall ends seen against something farther (or nothing), per beam gap."""
    m_seg = geometry.segments.shape[0]
    da = setup.angle_increment
    rr = np.where(hit, r, np.inf)
    near_first = rr[:, :-1] <= rr[:, 1:]
    near_r = np.where(near_first, rr[:, :-1], rr[:, 1:])
    far_r = np.where(near_first, rr[:, 1:], rr[:, :-1])

    def pick(a: NDArray) -> NDArray:  # the nearer beam's value at each gap
        return np.where(near_first, a[:, :-1], a[:, 1:])

    def pick_far(a: NDArray) -> NDArray:
        return np.where(near_first, a[:, 1:], a[:, :-1])
    near_s, far_s = pick(surface), pick_far(surface)
    near_t = pick(along)
    near_inc = pick(np.nan_to_num(incidence, nan=0.0))
    far_inc = pick_far(np.nan_to_num(incidence, nan=0.0))
    cand = np.isfinite(near_r) & (near_s >= 0) & (near_s < m_seg) & (near_s != far_s)
    # The near beam must hit within one beam gap (on the wall, allowing for the incidence) of an end point.
    seg = geometry.segments
    s = np.where(cand, near_s, 0)
    end = np.where(near_t < 0.5, 0, 1)
    ex_ = np.where(end == 0, seg[s, 0], seg[s, 2])
    ey_ = np.where(end == 0, seg[s, 1], seg[s, 3])
    nhx, nhy = pick(hx), pick(hy)
    gap_near = near_r * da / np.maximum(np.cos(near_inc), 0.05)
    cand &= np.hypot(nhx - ex_, nhy - ey_) <= 1.5 * gap_near + 1e-6
    # The far beam must land away from that end point: a concave corner continues the surface.
    fhx, fhy = pick_far(hx), pick_far(hy)
    gap_far = np.where(np.isfinite(far_r), far_r, 0.0) * da / np.maximum(np.cos(far_inc), 0.05)
    far_away = ~np.isfinite(far_r) | (np.hypot(fhx - ex_, fhy - ey_) > 3.0 * gap_far + 0.02)
    cand &= far_away
    if not cand.any():
        return None
    scan_i, gap_i = np.nonzero(cand)
    ex_, ey_ = ex_[scan_i, gap_i], ey_[scan_i, gap_i]
    seg_i, end_i = s[scan_i, gap_i], end[scan_i, gap_i]
    lp = laser[scan_i]
    ux, uy = ex_ - lp[:, 0], ey_ - lp[:, 1]
    rho2 = ux * ux + uy * uy
    # bearing = atan2(u) - laser heading: d/dp_laser = (u_y, -u_x)/rho^2, d/dheading = -1
    gbx, gby = uy / rho2, -ux / rho2
    th = poses[scan_i, 2]
    mxw = np.cos(th) * setup.mount[0] - np.sin(th) * setup.mount[1]
    myw = np.sin(th) * setup.mount[0] + np.cos(th) * setup.mount[1]
    gth = gbx * (-myw) + gby * mxw - 1.0
    near_keep = pick(keep)[scan_i, gap_i]
    variance = np.maximum(da**2 / 12.0, edge_sigma**2 / rho2)
    weight = near_keep / variance
    nb = r.shape[1]
    near_beam = scan_i * nb + gap_i + np.where(near_first[scan_i, gap_i], 0, 1)
    bearing = np.arctan2(uy, ux) - lp[:, 2]
    reading = setup.angles[gap_i] + 0.5 * da
    bearing = reading + se2.wrap_angle(bearing - reading)
    pidx = np.full((scan_i.shape[0], 4), -1, dtype=np.int64)
    pidx[:, 0] = 4 * seg_i + 2 * end_i
    pidx[:, 1] = 4 * seg_i + 2 * end_i + 1
    dpar = np.zeros((scan_i.shape[0], 4))
    dpar[:, 0], dpar[:, 1] = -gbx, -gby  # moving the end point is moving the laser the other way
    return (scan_i.astype(np.int64), weight, np.stack([gbx, gby, gth], axis=1), pidx, dpar,
            near_beam.astype(np.int64), variance, bearing, reading)


# ---------------------------------------------------------------------------
# Odometry


def odometry_covariances(setup: BoundSetup) -> NDArray[np.float64]:
    """Covariance ``(N-1, 3, 3)`` of the odometry increment between consecutive scans.

    The noise of each odometry step is as :func:`slam2d.sensors.motion_noise.simulate_odometry`
    draws it (variances from the true step); the steps between two scans compose, and the
    composition is linearised (a heading error early in the interval turns later translation
    into cross-track error).
    """
    noise = setup.odometry_noise
    truth = setup.odometry_truth
    idx = setup.scan_indices
    steps = se2.relative(truth[:-1], truth[1:])
    var = step_variances(steps, noise)
    if np.any(idx[1:] - idx[:-1] <= 0):
        raise InputError("scan indices must increase", field="scan_indices")
    per = np.diff(idx)
    if not np.all(per == per[0]):
        raise InputError("the bound expects scans at a fixed number of odometry steps", field="scan_indices")
    k = int(per[0])
    n = idx.shape[0] - 1
    # Steps of interval i are idx[i] .. idx[i] + k - 1; compose them one at a time, all intervals at once.
    cov = np.zeros((n, 3, 3))
    acc = np.zeros((n, 3))  # the increment composed so far, in the frame of the interval's first pose
    for j in range(k):
        s = steps[idx[:-1] + j]
        v = var[idx[:-1] + j]
        c, sn = np.cos(acc[:, 2]), np.sin(acc[:, 2])
        rbx, rby = c * s[:, 0] - sn * s[:, 1], sn * s[:, 0] + c * s[:, 1]
        ja = np.zeros((n, 3, 3))
        ja[:, 0, 0] = ja[:, 1, 1] = ja[:, 2, 2] = 1.0
        ja[:, 0, 2], ja[:, 1, 2] = -rby, rbx
        jb = np.zeros((n, 3, 3))
        jb[:, 0, 0], jb[:, 0, 1], jb[:, 1, 0], jb[:, 1, 1], jb[:, 2, 2] = c, -sn, sn, c, 1.0
        cov = ja @ cov @ ja.transpose(0, 2, 1) + (jb * v[:, None, :]) @ jb.transpose(0, 2, 1)
        acc = np.stack([acc[:, 0] + rbx, acc[:, 1] + rby, acc[:, 2] + s[:, 2]], axis=1)
    return cov + ODOMETRY_VARIANCE_FLOOR * np.eye(3)


def _relative_jacobians(a: NDArray[np.float64], b: NDArray[np.float64]) -> tuple[NDArray, NDArray]:
    """Jacobians ``(N, 3, 3)`` of ``relative(a, b)`` with respect to ``a`` and ``b``."""
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    dx, dy = b[:, 0] - a[:, 0], b[:, 1] - a[:, 1]
    ja = np.zeros((a.shape[0], 3, 3))
    ja[:, 0, 0], ja[:, 0, 1], ja[:, 1, 0], ja[:, 1, 1] = -c, -s, s, -c
    ja[:, 0, 2] = -s * dx + c * dy
    ja[:, 1, 2] = -c * dx - s * dy
    ja[:, 2, 2] = -1.0
    jb = np.zeros((a.shape[0], 3, 3))
    jb[:, 0, 0], jb[:, 0, 1], jb[:, 1, 0], jb[:, 1, 1], jb[:, 2, 2] = c, s, -s, c, 1.0
    return ja, jb


# ---------------------------------------------------------------------------
# Solving


@njit(cache=True)
def chain_marginals(diag: NDArray[np.float64], off: NDArray[np.float64]) -> NDArray[np.float64]:
    """Diagonal blocks of the inverse of a symmetric block-tridiagonal matrix.

    ``diag`` ``(N, k, k)`` are the diagonal blocks, ``off[i]`` ``(N-1, k, k)`` the block
    at row ``i``, column ``i + 1``. A forward elimination then a backward pass (the
    Rauch-Tung-Striebel smoother's recursion): linear in ``N``.
    """
    n = diag.shape[0]
    schur = np.empty_like(diag)
    schur_inv = np.empty_like(diag)
    schur[0] = diag[0]
    schur_inv[0] = np.linalg.inv(schur[0])
    for i in range(1, n):
        schur[i] = diag[i] - off[i - 1].T @ schur_inv[i - 1] @ off[i - 1]
        schur_inv[i] = np.linalg.inv(schur[i])
    out = np.empty_like(diag)
    out[n - 1] = schur_inv[n - 1]
    for i in range(n - 2, -1, -1):
        gain = schur_inv[i] @ off[i]
        out[i] = schur_inv[i] + gain @ out[i + 1] @ gain.T
    return out


def _alignment_operator(positions: NDArray[np.float64]) -> tuple[NDArray, NDArray]:
    """``U`` ``(3N, 3)`` and ``K`` ``(3, 3N)``: the linearised best rigid alignment of the positions.

    A small rigid motion ``a = (tx, ty, w)`` moves pose i by ``U_i a``; the alignment that
    best fits the position errors ``e`` is ``a = K e`` (least squares on positions only,
    about the centroid as :func:`slam2d.eval.trajectory_metrics.align_se2` does).
    """
    n = positions.shape[0]
    p = positions - positions.mean(axis=0)
    u = np.zeros((n, 3, 3))
    u[:, 0, 0] = u[:, 1, 1] = u[:, 2, 2] = 1.0
    u[:, 0, 2], u[:, 1, 2] = -p[:, 1], p[:, 0]
    u = u.reshape(3 * n, 3)
    g = u.copy()
    g[2::3] = 0.0  # the fit uses positions only
    k = np.linalg.solve(g.T @ g, g.T)
    return u, k


def accuracy_bound(setup: BoundSetup | Any, *, map: str = "known", edges: bool = True,
                   edge_sigma: float = 0.0, align: bool = True) -> dict[str, Any]:
    """Cramer-Rao bound of the trajectory for a simulated recording (or a :class:`BoundSetup`).

    ``map``: ``"known"`` (localisation in the true map) or ``"walls"`` (walls of unknown
    position, estimated with the trajectory: the SLAM bound). ``edges``: count the bearing of
    wall ends (see the module docstring); ``edge_sigma`` (m) coarsens them to what a map of
    that precision could locate (then no longer a bound: a what-if). ``align``: remove the best rigid alignment first, as
    the ATE of ``slam2d evaluate`` does.

    Returns ``ate_m`` (expected ATE: RMS over scans of the position standard deviation),
    ``heading_deg`` (the same for the heading), per-scan ``position_std_m`` and
    ``heading_std_deg``, ``unaligned`` (the same without the alignment), ``covariance``
    ``(N, 3, 3)`` (each pose's marginal covariance, unaligned) and counts.
    """
    _check_map(map)
    if not isinstance(setup, BoundSetup):
        setup = setup_from_simulation(setup)
    poses = setup.scan_truth
    n = poses.shape[0]
    if n < 2:
        raise InputError("the bound needs at least two scans", field="scans")
    if not (math.isfinite(edge_sigma) and edge_sigma >= 0.0):
        raise InputError(f"{edge_sigma!r} must be a distance >= 0", field="edge_sigma")
    laser, d1, o1 = _pose_information(setup, edges, edge_sigma)
    m = n - 1
    pose_cov = np.zeros((n, 3, 3))
    pose_cov[1:] = chain_marginals(np.ascontiguousarray(d1), np.ascontiguousarray(o1))
    lu = spla.splu(_block_tridiagonal(d1, o1).tocsc())
    if map == "walls":
        # Schur complement on the map: Sigma_poses = A^-1 + X S^-1 X^T with X = A^-1 B, S = C - B^T X.
        b_mat, c_mat, used = _map_blocks(laser, n)
        x = lu.solve(b_mat)  # A^-1 B, (3m, P)
        schur = c_mat - b_mat.T @ x
        schur_inv = np.linalg.inv(schur)
        xr = x.reshape(m, 3, -1)
        pose_cov[1:] += np.einsum("nip,pq,njq->nij", xr, schur_inv, xr, optimize=True)

        def solve(v: NDArray) -> NDArray:
            y = lu.solve(v)
            return y + x @ (schur_inv @ (b_mat.T @ y))
    else:
        used = 0

        def solve(v: NDArray) -> NDArray:
            return lu.solve(v)

    var_pos = pose_cov[:, 0, 0] + pose_cov[:, 1, 1]
    var_head = pose_cov[:, 2, 2].copy()
    result: dict[str, Any] = {
        "map": map, "edges": edges, "scans": n, "beams_used": laser.beams_used, "edges_used": laser.edges_used,
        "map_parameters": used,
        "unaligned": {"ate_m": float(np.sqrt(var_pos.mean())), "heading_deg": float(np.degrees(np.sqrt(var_head.mean())))},
    }
    if align:
        u, k = _alignment_operator(poses[:, :2])
        v = k.T[3:]  # pose 0 is fixed: its rows drop out
        w = np.zeros((3 * n, 3))
        w[3:] = solve(np.ascontiguousarray(v))  # Sigma K^T
        # Var of row r after alignment: Sigma_rr - 2 U_r W_r + U_r (K Sigma K^T) U_r^T.
        kk = k @ w
        sd = pose_cov.reshape(n, 3, 3)[:, np.arange(3), np.arange(3)].reshape(-1)
        aligned = sd - 2.0 * np.einsum("rj,rj->r", u, w) + np.einsum("rj,jk,rk->r", u, kk, u)
        aligned = np.maximum(aligned.reshape(n, 3), 0.0)
        var_pos = aligned[:, 0] + aligned[:, 1]
        var_head = aligned[:, 2]
    result["covariance"] = pose_cov
    result["ate_m"] = float(np.sqrt(var_pos.mean()))
    result["heading_deg"] = float(np.degrees(np.sqrt(var_head.mean())))
    result["position_std_m"] = np.sqrt(var_pos)
    result["heading_std_deg"] = np.degrees(np.sqrt(var_head))
    return result


def _check_map(map: str) -> None:
    if map not in ("known", "walls"):
        raise InputError(f"{map!r} is not a map model (known, walls)", field="map")


def _pose_information(setup: BoundSetup, edges: bool, edge_sigma: float) -> tuple[LaserInformation, NDArray, NDArray]:
    """The laser's information and the poses' block-tridiagonal information (laser + odometry).

    The first pose is known, so it is left out: the blocks are those of poses 1..N-1.
    """
    poses = setup.scan_truth
    laser = laser_information(setup, edges=edges, edge_sigma=edge_sigma)
    omega = np.linalg.inv(odometry_covariances(setup))
    ja, jb = _relative_jacobians(poses[:-1], poses[1:])
    ta = ja.transpose(0, 2, 1)
    diag = laser.pose.copy()
    diag[:-1] += ta @ omega @ ja
    diag[1:] += jb.transpose(0, 2, 1) @ omega @ jb
    off = ta @ omega @ jb  # block (i, i + 1)
    return laser, diag[1:], off[1:]


def joint_information(setup: BoundSetup, *, map: str = "known", edges: bool = True,
                      edge_sigma: float = 0.0) -> sp.csr_matrix:
    """The whole information matrix: poses 1..N-1 (x, y, theta each), then the map parameters seen.

    What :func:`accuracy_bound` inverts, for checks on small cases (its inverse is the bound's
    joint covariance).
    """
    _check_map(map)
    laser, d1, o1 = _pose_information(setup, edges, edge_sigma)
    a = _block_tridiagonal(d1, o1)
    if map == "known":
        return a
    b, c, _ = _map_blocks(laser, setup.scan_truth.shape[0])
    return sp.bmat([[a, sp.csr_matrix(b)], [sp.csr_matrix(b.T), sp.csr_matrix(c)]]).tocsr()


def _block_tridiagonal(diag: NDArray, off: NDArray) -> sp.csr_matrix:
    n = diag.shape[0]
    k = diag.shape[1]
    rows, cols, vals = [], [], []
    base = np.arange(n) * k
    ii, jj = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
    rows.append((base[:, None, None] + ii).ravel())
    cols.append((base[:, None, None] + jj).ravel())
    vals.append(diag.ravel())
    rows.append((base[:-1, None, None] + ii).ravel())
    cols.append((base[1:, None, None] + jj).ravel())
    vals.append(off.ravel())
    rows.append((base[1:, None, None] + ii).ravel())
    cols.append((base[:-1, None, None] + jj).ravel())
    vals.append(off.transpose(0, 2, 1).ravel())
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n * k, n * k))


def _map_blocks(laser: LaserInformation, n: int) -> tuple[NDArray, NDArray, int]:
    """Pose-map block ``B`` ``(3(n-1), P)`` and map block ``C`` ``(P, P)`` over the map parameters seen.

    Parameters no measurement touches are left out (they would make ``C`` singular);
    the first pose is known, so its rows of ``B`` are dropped.
    """
    valid = laser.param_index >= 0
    seen = np.unique(laser.param_index[valid])
    col = np.full(laser.n_params, -1, dtype=np.int64)
    col[seen] = np.arange(seen.shape[0])
    p = seen.shape[0]
    w = laser.weight
    b = np.zeros(3 * n * p)
    c = np.zeros(p * p)
    for a in range(4):  # four parameter slots per measurement: a loop over slots, not over beams
        ia = laser.param_index[:, a]
        ok = ia >= 0
        ca = col[ia[ok]]
        for r in range(3):
            b += np.bincount((3 * laser.scan[ok] + r) * p + ca,
                             w[ok] * laser.d_pose[ok, r] * laser.d_param[ok, a], minlength=b.shape[0])
        for bb in range(4):
            ib = laser.param_index[:, bb]
            ok2 = ok & (ib >= 0)
            c += np.bincount(col[ia[ok2]] * p + col[ib[ok2]],
                             w[ok2] * laser.d_param[ok2, a] * laser.d_param[ok2, bb], minlength=c.shape[0])
    b = b.reshape(3 * n, p)
    c = c.reshape(p, p)
    # A wall end seen by no edge keeps its along-wall direction unobserved: a tiny prior keeps C invertible
    # without adding information anyone would notice (1 km standard deviation).
    c += np.eye(p) * 1e-6
    return b[3:], c, p


def oracle_smoother(sim: Any, *, map: str = "walls", edges: bool = True, beam_mask: NDArray[np.bool_] | None = None,
                    edge_mask: NDArray[np.bool_] | None = None) -> dict[str, Any]:
    """The maximum-likelihood smoother with the data association known, on the recording's actual readings.

    The estimator the bound is the bound of: every range reading (as the simulated laser
    reported it, dropouts included) against the surface it truly hit, every wall end's bearing
    read as the middle of its beam gap, and the odometry increments between scans, solved
    jointly for the poses (and, with ``map="walls"``, the walls) by one Gauss-Newton step
    linearised at the truth. The readings are millimetres off, so the step lands on the
    maximum-likelihood estimate to first order. No method can use this (it knows which surface
    each beam hit); it shows whether the bound can be reached at all. Returns ``ate_m`` and
    ``heading_deg`` as ``slam2d evaluate`` computes them (after alignment).

    ``beam_mask`` / ``edge_mask`` (optional, boolean ``(scans, beams)``): use only the range readings
    of the beams marked True / only the wall-end bearings whose nearer beam is marked True (e.g. the
    beams and wall ends a method actually uses: what its inputs are worth when solved this way).
    """
    from slam2d.eval.trajectory_metrics import absolute_trajectory_error, associate

    _check_map(map)
    setup = setup_from_simulation(sim)
    poses = setup.scan_truth
    n = poses.shape[0]
    laser = laser_information(setup, edges=edges)
    measured = np.concatenate([np.asarray(s.ranges, dtype=np.float64) for s in sim.scans])[laser.beam]
    is_edge = np.arange(laser.scan.shape[0]) >= laser.beams_used
    observed = np.isfinite(measured)
    shape = (n, setup.angles.shape[0])
    for mask, rows_of in ((beam_mask, ~is_edge), (edge_mask, is_edge)):
        if mask is not None:
            mask = np.asarray(mask, dtype=bool)
            if mask.shape != shape:
                raise InputError(f"a mask of shape {mask.shape} for {shape} (scans, beams)", field="mask")
            observed &= ~rows_of | mask.reshape(-1)[laser.beam]
    residual = np.where(is_edge, se2.wrap_angle(laser.reading - laser.value), measured - laser.value)
    root_w = np.where(observed, 1.0 / np.sqrt(laser.variance), 0.0)
    residual = np.where(observed, residual, 0.0)
    n_pose = 3 * (n - 1)
    if map == "walls":
        seen = np.unique(laser.param_index[laser.param_index >= 0])
        col = np.full(laser.n_params, -1, dtype=np.int64)
        col[seen] = n_pose + np.arange(seen.shape[0])
        n_var = n_pose + seen.shape[0]
    else:
        n_var = n_pose
    rows, cols, vals = [], [], []
    k = laser.scan.shape[0]
    row_id = np.arange(k)
    moving = laser.scan > 0  # pose 0 is known
    for a in range(3):
        rows.append(row_id[moving])
        cols.append(3 * (laser.scan[moving] - 1) + a)
        vals.append((root_w * laser.d_pose[:, a])[moving])
    if map == "walls":
        for a in range(4):
            ok = laser.param_index[:, a] >= 0
            rows.append(row_id[ok])
            cols.append(col[laser.param_index[ok, a]])
            vals.append((root_w * laser.d_param[:, a])[ok])
    rhs = [root_w * residual]
    # Odometry: whitened by the Cholesky factor of each increment's information.
    idx = setup.scan_indices
    odo = np.asarray(sim.odometry, dtype=np.float64)[idx]
    z = se2.relative(odo[:-1], odo[1:])
    pred = se2.relative(poses[:-1], poses[1:])
    res_o = z - pred
    res_o[:, 2] = se2.wrap_angle(res_o[:, 2])
    chol = np.linalg.cholesky(np.linalg.inv(odometry_covariances(setup)))  # Omega = L L^T
    lt = chol.transpose(0, 2, 1)
    ja, jb = _relative_jacobians(poses[:-1], poses[1:])
    wa, wb = lt @ ja, lt @ jb
    base_row = k + 3 * np.arange(n - 1)
    for i in range(3):
        for a in range(3):
            first = np.arange(n - 1) > 0
            rows.append(base_row[first] + i)
            cols.append(3 * (np.arange(n - 1)[first] - 1) + a)
            vals.append(wa[first, i, a])
            rows.append(base_row + i)
            cols.append(3 * np.arange(n - 1) + a)
            vals.append(wb[:, i, a])
    rhs.append(np.einsum("nij,nj->ni", lt, res_o).reshape(-1))
    h = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                      shape=(k + 3 * (n - 1), n_var))
    info = (h.T @ h).tocsc() + sp.identity(n_var, format="csc") * 1e-6  # same tiny prior as the bound
    step = spla.splu(info).solve(h.T @ np.concatenate(rhs))
    estimate = poses.copy()
    estimate[1:] += step[:n_pose].reshape(-1, 3)
    times = np.asarray(sim.scan_times, dtype=np.float64)
    ate = absolute_trajectory_error(associate(times, estimate, times, poses))
    return {"ate_m": float(ate["translation_m"]["rmse"]), "heading_deg": float(ate["rotation_deg"]["rmse"]),
            "estimate": estimate, "readings_used": int(observed.sum())}
