"""Gauss-Newton scan-to-map matching on bilinearly interpolated occupancy (Hector SLAM's matcher).

The pose ``xi = [x, y, theta]`` of the robot minimises

    F(xi) = sum_i w_i (1 - M(S_i(xi)))^2  [+ s^2 (xi - xi_p)^T Lambda (xi - xi_p)]

where ``S_i(xi)`` is scan point ``i`` (robot frame) moved to the world by
``xi``, ``M`` the bilinear interpolation of the map's occupancy probability
(:func:`slam2d.grids.likelihood_field.bilinear_gradient_at`, analytic
gradient), ``w_i`` a per-beam weight from the range sigma, and the optional
second term a prior (odometry's prediction ``xi_p`` with information
``Lambda``; ``s^2`` is the residual variance, so both terms are in the same
units). Each iteration solves ``(H + s^2 Lambda) d = b + s^2 Lambda (xi_p - xi)``
with ``H = sum w J^T J``, ``b = sum w J^T (1 - M)``, ``J = dM/dxi``.

It runs coarse to fine over a :class:`~slam2d.grids.pyramid.MapPyramid`, with
an iteration cap per level and a convergence test (a step below a tolerance,
or a step that raised the cost: the pose before it is kept), where the
original runs a fixed 3 (coarse) / 5 (finest) iterations.

What the match reports beyond the pose:

* a covariance: ``inverse(H / s^2 + Lambda)`` at the final pose, with
  ``s^2 = sum w r^2 / (sum w - 3)`` the a-posteriori residual variance (the
  original publishes ``H`` itself);
* degeneracy: the eigenvalues of an information matrix with the heading
  scaled by the scan's RMS point distance (so a radian and a metre weigh
  alike); the inverse condition ``lambda_min / lambda_max`` below a threshold
  flags an under-constrained match (a featureless corridor), and the
  directions below the threshold are taken from the prior (odometry) when
  there is one. Given surface normals the test uses the scan's point-to-line
  information ``sum w [n, p x n]^T [n, p x n]``, otherwise ``H``: ``H`` sees
  map texture (a noisy wall's rough edge, the edge of the explored map) as
  information along a featureless corridor, the normals do not. The
  scan's information along a degenerate direction is dropped from the
  covariance.

The inner loop over points is compiled (numba); Python only loops over levels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import NDArray

from slam2d.grids.likelihood_field import bilinear_gradient_at
from slam2d.grids.pyramid import MapPyramid

__all__ = ["MatchSettings", "MatchResult", "GaussNewtonMatcher", "accumulate", "gauss_newton_level"]

# Off-map lookups return this sentinel so they are skipped (no gradient, no residual).
_OUTSIDE = -1.0


@njit(cache=True)
def accumulate(prob, origin_x, origin_y, resolution, points, weights, pose):
    """Normal equations at ``pose``: ``(H (3, 3), b (3,), sum w r^2, sum w, sum w M, points on the map)``.

    ``r = 1 - M`` per point; ``J = [dM/dx, dM/dy, dM/dtheta]``.
    """
    c = math.cos(pose[2])
    s = math.sin(pose[2])
    h = np.zeros((3, 3))
    b = np.zeros(3)
    ss = 0.0
    wsum = 0.0
    msum = 0.0
    used = 0
    for i in range(points.shape[0]):
        px = points[i, 0]
        py = points[i, 1]
        x = pose[0] + c * px - s * py
        y = pose[1] + s * px + c * py
        m, gx, gy = bilinear_gradient_at(prob, origin_x, origin_y, resolution, x, y, _OUTSIDE)
        if m < 0.0:
            continue
        w = weights[i]
        r = 1.0 - m
        j0 = gx
        j1 = gy
        j2 = gx * (-s * px - c * py) + gy * (c * px - s * py)
        b[0] += w * j0 * r
        b[1] += w * j1 * r
        b[2] += w * j2 * r
        h[0, 0] += w * j0 * j0
        h[0, 1] += w * j0 * j1
        h[0, 2] += w * j0 * j2
        h[1, 1] += w * j1 * j1
        h[1, 2] += w * j1 * j2
        h[2, 2] += w * j2 * j2
        ss += w * r * r
        wsum += w
        msum += w * m
        used += 1
    h[1, 0] = h[0, 1]
    h[2, 0] = h[0, 2]
    h[2, 1] = h[1, 2]
    return h, b, ss, wsum, msum, used


@njit(cache=True, inline="always")
def _wrap(a):
    return (a + math.pi) % (2.0 * math.pi) - math.pi


@njit(cache=True)
def _solve3(a, b):
    """``a^-1 b`` for a 3x3 matrix by cofactors; ``(ok, x)``, ok False when ``a`` is singular."""
    c00 = a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1]
    c01 = a[1, 2] * a[2, 0] - a[1, 0] * a[2, 2]
    c02 = a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0]
    det = a[0, 0] * c00 + a[0, 1] * c01 + a[0, 2] * c02
    scale = abs(a[0, 0] * a[1, 1] * a[2, 2]) + 1e-300
    x = np.zeros(3)
    if not (abs(det) > 1e-14 * scale) or not math.isfinite(det):
        return False, x
    inv = np.empty((3, 3))
    inv[0, 0] = c00
    inv[1, 0] = c01
    inv[2, 0] = c02
    inv[0, 1] = a[0, 2] * a[2, 1] - a[0, 1] * a[2, 2]
    inv[1, 1] = a[0, 0] * a[2, 2] - a[0, 2] * a[2, 0]
    inv[2, 1] = a[0, 1] * a[2, 0] - a[0, 0] * a[2, 1]
    inv[0, 2] = a[0, 1] * a[1, 2] - a[0, 2] * a[1, 1]
    inv[1, 2] = a[0, 2] * a[1, 0] - a[0, 0] * a[1, 2]
    inv[2, 2] = a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0]
    for k in range(3):
        x[k] = (inv[k, 0] * b[0] + inv[k, 1] * b[1] + inv[k, 2] * b[2]) / det
    return True, x


@njit(cache=True)
def gauss_newton_level(
    prob, origin_x, origin_y, resolution, points, weights, pose, max_iterations,
    tol_xy, tol_theta, max_angle_step, max_step, prior_pose, prior_info,
):
    """Gauss-Newton on one map level from ``pose``.

    A step is at most ``max_step`` (m) long and turns at most ``max_angle_step`` (rad).
    ``prior_info`` (3, 3) all zero means no prior. Stops after ``max_iterations``
    steps, when a step is below ``tol_xy`` (m) and ``tol_theta`` (rad), or when a
    step raised the cost (then the pose before it is kept). The normal equations
    are re-evaluated at the final pose.

    Returns ``(pose, H, b, sum w r^2, sum w, sum w M, used, steps)``.
    """
    xi = pose.copy()
    has_prior = prior_info[0, 0] > 0.0 or prior_info[1, 1] > 0.0 or prior_info[2, 2] > 0.0
    steps = 0
    s2_ref = -1.0
    best_cost = np.inf
    best = xi.copy()
    while True:
        h, b, ss, wsum, msum, used = accumulate(prob, origin_x, origin_y, resolution, points, weights, xi)
        d = np.empty(3)
        d[0] = prior_pose[0] - xi[0]
        d[1] = prior_pose[1] - xi[1]
        d[2] = _wrap(prior_pose[2] - xi[2])
        if s2_ref < 0.0:
            s2_ref = ss / max(wsum - 3.0, 1.0)
        cost = ss
        if has_prior:
            for r in range(3):
                for k in range(3):
                    cost += s2_ref * d[r] * prior_info[r, k] * d[k]
        if cost > best_cost:
            # The step made it worse (the interpolated map is only piecewise smooth): keep the last
            # pose and stop, instead of oscillating until the iteration cap.
            xi = best
            h, b, ss, wsum, msum, used = accumulate(prob, origin_x, origin_y, resolution, points, weights, xi)
            break
        best_cost = cost
        best = xi.copy()
        if steps >= max_iterations or used < 3:
            break
        a = h.copy()
        rhs = b.copy()
        if has_prior:
            s2 = ss / max(wsum - 3.0, 1.0)
            for r in range(3):
                for k in range(3):
                    a[r, k] += s2 * prior_info[r, k]
                    rhs[r] += s2 * prior_info[r, k] * d[k]
        elif h[0, 0] == 0.0 or h[1, 1] == 0.0:
            break  # nothing to match against (the original's test)
        ok, delta = _solve3(a, rhs)
        if not ok or not (math.isfinite(delta[0]) and math.isfinite(delta[1]) and math.isfinite(delta[2])):
            break
        # Trust region: the map's gradient reaches about a cell from a wall, so a step much longer
        # than that comes from a nearly singular H (few points near walls), not from the data.
        length = math.hypot(delta[0], delta[1])
        if length > max_step:
            delta[0] *= max_step / length
            delta[1] *= max_step / length
        if delta[2] > max_angle_step:
            delta[2] = max_angle_step
        elif delta[2] < -max_angle_step:
            delta[2] = -max_angle_step
        xi[0] += delta[0]
        xi[1] += delta[1]
        xi[2] = _wrap(xi[2] + delta[2])
        steps += 1
        if math.hypot(delta[0], delta[1]) < tol_xy and abs(delta[2]) < tol_theta:
            h, b, ss, wsum, msum, used = accumulate(prob, origin_x, origin_y, resolution, points, weights, xi)
            break
    return xi, h, b, ss, wsum, msum, used, steps


@dataclass(frozen=True)
class MatchSettings:
    """How a match runs (the method's parameters feed it)."""

    iterations_coarse: int = 10
    iterations_fine: int = 10
    tolerance_xy: float = 1e-4
    tolerance_theta: float = 1e-4
    max_angle_step: float = 0.2
    max_step_cells: float = 2.0
    degeneracy_threshold: float = 0.01


@dataclass
class MatchResult:
    """The outcome of :meth:`GaussNewtonMatcher.match`."""

    pose: NDArray[np.float64]
    covariance: NDArray[np.float64]  # (3, 3), m^2 / rad^2
    hessian: NDArray[np.float64]  # H = sum w J^T J at the final pose, finest level
    residual_variance: float  # s^2
    score: float  # weighted mean occupancy probability at the scan points (1 = every point on a wall)
    inverse_condition: float  # lambda_min / lambda_max of the heading-scaled H (0 = degenerate)
    geometric_condition: float  # the same for the scan's point-to-line information (NaN without normals)
    degenerate: bool
    degenerate_directions: NDArray[np.float64]  # (k, 3) unit directions in (x, y, L theta)
    used: int  # points that landed on the map (finest level)
    iterations: int  # Gauss-Newton steps over all levels
    prior_used_along_degeneracy: bool = False


def _weak_directions(
    hn: NDArray[np.float64], usable: bool, threshold: float
) -> tuple[float, NDArray[np.bool_], NDArray[np.float64]]:
    """``(lambda_min / lambda_max, weak eigenvalue mask, eigenvectors)`` of a 3x3 information matrix."""
    evals, evecs = np.linalg.eigh(hn)
    top = float(evals[-1])
    if not usable or not top > 0.0:
        return 0.0, np.ones(3, dtype=bool), evecs
    return float(max(evals[0], 0.0) / top), evals <= threshold * top, evecs


def _geometric_information(
    points: NDArray[np.float64], normals: NDArray[np.float64], weights: NDArray[np.float64], theta: float
) -> NDArray[np.float64]:
    """Point-to-line information ``sum w J^T J``, ``J = [n_x, n_y, p x n]`` in the world frame.

    A translation along a wall moves no point off it, so in a corridor the
    axis direction gets no information, whatever the map's texture.
    """
    ok = np.isfinite(normals).all(axis=1)
    p, n, w = points[ok], normals[ok], weights[ok]
    length = np.hypot(n[:, 0], n[:, 1])
    good = length > 0
    p, n, w = p[good], n[good] / length[good, None], w[good]
    c, s = math.cos(theta), math.sin(theta)
    j = np.stack([c * n[:, 0] - s * n[:, 1], s * n[:, 0] + c * n[:, 1], p[:, 0] * n[:, 1] - p[:, 1] * n[:, 0]], axis=1)
    return (j * w[:, None]).T @ j


class GaussNewtonMatcher:
    """Coarse-to-fine Gauss-Newton matcher over a :class:`MapPyramid`."""

    def __init__(self, settings: MatchSettings | None = None) -> None:
        self.settings = settings if settings is not None else MatchSettings()

    def match(
        self,
        pyramid: MapPyramid,
        points: NDArray[np.float64],
        weights: NDArray[np.float64],
        initial: NDArray[np.float64],
        *,
        prior: NDArray[np.float64] | None = None,
        prior_information: NDArray[np.float64] | None = None,
        normals: NDArray[np.float64] | None = None,
    ) -> MatchResult:
        """Match scan ``points`` (robot frame, ``(N, 2)``) with per-point ``weights`` from ``initial``.

        ``prior`` / ``prior_information`` (3,) and (3, 3): a pose prediction and
        its information (odometry); it enters the optimisation and replaces the
        match along degenerate directions. ``normals`` ``(N, 2)`` (robot frame,
        NaN where unknown): the surface normal at each point, for the geometric
        degeneracy test.
        """
        st = self.settings
        pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 2)
        w = np.ascontiguousarray(weights, dtype=np.float64).reshape(-1)
        if w.shape[0] != pts.shape[0]:
            raise ValueError(f"weights: {w.shape[0]} for {pts.shape[0]} points")
        xi = np.array(initial, dtype=np.float64).reshape(3)
        has_prior = prior is not None and prior_information is not None
        p_pose = np.array(prior, dtype=np.float64).reshape(3) if has_prior else np.zeros(3)
        p_info = (
            np.ascontiguousarray(prior_information, dtype=np.float64).reshape(3, 3) if has_prior else np.zeros((3, 3))
        )
        steps_total = 0
        out = None
        for i in range(len(pyramid) - 1, -1, -1):
            level = pyramid[i]
            ox, oy = level.origin
            iterations = st.iterations_fine if i == 0 else st.iterations_coarse
            # A coarse level only has to bring the pose within the next level's reach.
            loosen = level.resolution / pyramid[0].resolution
            out = gauss_newton_level(
                level.probability, ox, oy, level.resolution, pts, w, xi, iterations,
                st.tolerance_xy * loosen, st.tolerance_theta * loosen, st.max_angle_step, st.max_step_cells * level.resolution,
                p_pose, p_info,
            )
            xi = out[0]
            steps_total += int(out[7])
        assert out is not None
        _, h, _b, ss, wsum, msum, used, _ = out
        s2 = float(ss / max(wsum - 3.0, 1.0))
        s2 = max(s2, 1e-12)
        # Heading scaled by the RMS point distance: a rotation then moves points about as far as a translation.
        length = float(np.sqrt(np.mean(np.sum(pts * pts, axis=1)))) if pts.shape[0] else 1.0
        length = max(length, 1e-3)
        scale = np.array([1.0, 1.0, 1.0 / length])
        # Degeneracy from the map Hessian, or, given the surface normals, from the scan's
        # geometry: map texture (a noisy wall's rough edge, the edge of the explored map)
        # gives the Hessian information along a featureless corridor that the world does not.
        hn = h * scale[:, None] * scale[None, :]
        inv_cond, weak_map, evecs_map = _weak_directions(hn, used >= 3, st.degeneracy_threshold)
        geo_cond = math.nan
        weak_dirs = evecs_map[:, weak_map]
        if normals is not None:
            gn = _geometric_information(pts, np.asarray(normals, dtype=np.float64).reshape(-1, 2), w, xi[2])
            gn = gn * scale[:, None] * scale[None, :]
            geo_cond, weak_geo, evecs_geo = _weak_directions(gn, True, st.degeneracy_threshold)
            weak_dirs = evecs_geo[:, weak_geo]
        degenerate = weak_dirs.shape[1] > 0
        used_prior = False
        if degenerate and has_prior:
            # Along the unobservable directions the scan says nothing: take the prediction there.
            d = p_pose - xi
            d[2] = (d[2] + np.pi) % (2 * np.pi) - np.pi
            xi = xi + (weak_dirs @ (weak_dirs.T @ (d / scale))) * scale
            xi[2] = (xi[2] + np.pi) % (2 * np.pi) - np.pi
            used_prior = True
        # Covariance: the scan's information without its degenerate directions, plus the prior's.
        keep = np.eye(3) - weak_dirs @ weak_dirs.T
        info_n = keep @ hn @ keep / s2 + p_info * scale[:, None] * scale[None, :]
        ie, iv = np.linalg.eigh(info_n)
        # Information too small to invert is floored: an unobservable direction gets a huge, finite variance.
        floor = max(float(ie[-1]) * 1e-12, 1e-30)
        cov_n = (iv / np.maximum(ie, floor)) @ iv.T
        cov = cov_n * scale[:, None] * scale[None, :]
        return MatchResult(
            pose=xi,
            covariance=cov,
            hessian=h,
            residual_variance=s2,
            score=float(msum / wsum) if wsum > 0 else 0.0,
            inverse_condition=inv_cond,
            geometric_condition=geo_cond,
            degenerate=degenerate,
            degenerate_directions=weak_dirs.T.copy(),
            used=int(used),
            iterations=steps_total,
            prior_used_along_degeneracy=used_prior,
        )
