"""The improved proposal of Grisetti et al. 2007 as a product of two Gaussians (``proposal=laplace``).

Around each particle's scan-matching optimum ``x*`` the scan's log-likelihood
(:func:`slam2d.matching.hill_climb._evaluate`, GMapping's ``lsigma`` likelihood)
is evaluated on a small grid of offsets in the optimum's own frame
(``(forward, left, dtheta)``) and a quadratic is fitted to it by least squares:
``log p(z | m, x* + o) ~ c + g.o - o.H.o / 2``. ``H`` is the scan's information
about the pose; directions in which the fitted curvature is not negative (the
score is flat or rippled, as along a corridor longer than the laser's reach)
get none (``H``'s negative eigenvalues are set to 0). The odometry motion
model's Gaussian (mean the particle's pose at the last update moved by the
odometry, covariance GMapping's ``srr``... for the increment) is multiplied in
analytically:

    A = H + P^-1,   mu = A^-1 (g + P^-1 d),   Sigma = A^-1

``d`` the predicted pose in the optimum's frame, ``P^-1`` the prior's
information there. Along a corridor the product is the odometry's Gaussian,
across it and in heading the scan's. The particle is drawn from
``N(x* + mu, Sigma)`` and its weight factor is the normaliser
``log eta = log integral p(z | m, x) p(x | x_prev, u) dx``:

    log eta = c - d.P^-1.d / 2 + b.mu / 2 - log det A / 2 + log det P^-1 / 2   (b = g + P^-1 d)

(less a constant the same for every particle). Unlike sampling ``tau`` on a
grid as wide as the odometry (``proposal=gaussian`` with ``proposal_range``),
the likelihood is only evaluated within a few centimetres of the optimum, where
beams ending at the edge of the mapped area do not yet gain map points by
moving the pose back into it.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from slam2d.matching.hill_climb import _evaluate

__all__ = ["quadratic_design", "laplace_proposal"]


def quadratic_design(offsets: np.ndarray) -> np.ndarray:
    """The least-squares solver ``(10, K)`` of a full quadratic in 3 variables fitted at ``offsets`` ``(K, 3)``.

    Coefficients: ``c, g0, g1, g2, q00, q11, q22, q01, q02, q12`` of
    ``c + g.o + sum q_ii o_i^2 + sum_{i<j} q_ij o_i o_j``.
    """
    o = np.asarray(offsets, dtype=np.float64)
    design = np.column_stack([np.ones(len(o)), o, o**2, o[:, 0] * o[:, 1], o[:, 0] * o[:, 2], o[:, 1] * o[:, 2]])
    return np.ascontiguousarray(np.linalg.pinv(design))


@njit(cache=True, parallel=True)
def laplace_proposal(pool, occ, table, ox, oy, res, kernel, free_check, optima, predicted, prior_std, offsets, solver,
                     mount, ex, ey, ux, uy, div_s, div_l, normals, out_poses, out_logeta):
    """Draw every particle from the product of the scan's fitted Gaussian and the odometry's; weight by eta.

    ``offsets`` ``(K, 3)`` and ``solver`` (:func:`quadratic_design` of them)
    are shared by all particles; ``prior_std`` are the motion model's
    standard deviations ``(forward, left, heading)`` in the predicted pose's
    frame; ``normals[p]`` the particle's standard normals.
    """
    K = offsets.shape[0]
    for p in prange(optima.shape[0]):
        co, so = math.cos(optima[p, 2]), math.sin(optima[p, 2])
        values = np.empty(K)
        for k in range(K):
            x = optima[p, 0] + co * offsets[k, 0] - so * offsets[k, 1]
            y = optima[p, 1] + so * offsets[k, 0] + co * offsets[k, 1]
            values[k] = _evaluate(pool, occ, table, p, ox, oy, res, kernel, free_check, x, y,
                                  optima[p, 2] + offsets[k, 2], mount, ex, ey, ux, uy, div_s, div_l, True)[1]
        q = solver @ values
        c = q[0]
        g = q[1:4].copy()
        H = np.empty((3, 3))  # minus the Hessian of the fitted log-likelihood
        H[0, 0], H[1, 1], H[2, 2] = -2.0 * q[4], -2.0 * q[5], -2.0 * q[6]
        H[0, 1] = H[1, 0] = -q[7]
        H[0, 2] = H[2, 0] = -q[8]
        H[1, 2] = H[2, 1] = -q[9]
        lam, vec = np.linalg.eigh(H)
        for i in range(3):
            lam[i] = max(lam[i], 0.0)  # a flat or rippled direction carries no information
        H = (vec * lam) @ vec.T
        # the odometry prior in the optimum's frame: its mean d and information Pinv
        dx, dy = predicted[p, 0] - optima[p, 0], predicted[p, 1] - optima[p, 1]
        d = np.array([co * dx + so * dy, -so * dx + co * dy,
                      (predicted[p, 2] - optima[p, 2] + math.pi) % (2.0 * math.pi) - math.pi])
        phi = predicted[p, 2] - optima[p, 2]
        cp, sp = math.cos(phi), math.sin(phi)
        ia, ib = 1.0 / prior_std[0] ** 2, 1.0 / prior_std[1] ** 2
        Pinv = np.zeros((3, 3))
        Pinv[0, 0] = cp * cp * ia + sp * sp * ib
        Pinv[1, 1] = sp * sp * ia + cp * cp * ib
        Pinv[0, 1] = Pinv[1, 0] = cp * sp * (ia - ib)
        Pinv[2, 2] = 1.0 / prior_std[2] ** 2
        A = H + Pinv
        b = g + Pinv @ d
        Sigma = np.linalg.inv(A)
        Sigma = 0.5 * (Sigma + Sigma.T)
        mu = Sigma @ b
        L = np.linalg.cholesky(Sigma)
        v = mu + L @ normals[p]
        out_poses[p, 0] = optima[p, 0] + co * v[0] - so * v[1]
        out_poses[p, 1] = optima[p, 1] + so * v[0] + co * v[1]
        out_poses[p, 2] = (optima[p, 2] + v[2] + math.pi) % (2.0 * math.pi) - math.pi
        out_logeta[p] = (c - 0.5 * (d @ (Pinv @ d)) + 0.5 * (b @ mu) - 0.5 * math.log(np.linalg.det(A))
                         + 0.5 * math.log(np.linalg.det(Pinv)))
