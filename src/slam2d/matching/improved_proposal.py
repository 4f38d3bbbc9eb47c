"""The improved proposal of Grisetti et al. 2007 as a product of two Gaussians (``proposal=laplace``).

Around each particle's scan-matching optimum ``x*`` the scan's log-likelihood
(:func:`slam2d.matching.hill_climb._evaluate`, GMapping's ``lsigma`` likelihood)
is evaluated on a small grid of offsets in the optimum's own frame
(``(forward, left, dtheta)``, half-widths ``h``): the optimum, +-h on each
axis and the four corners of the forward-left square. Taking the optimum as
the likelihood's mode, its information ``H`` is minus the curvature of the
log-likelihood there by finite differences (heading's cross terms left out),
summed over the beams that find a map point at all 11 poses (a beam that
gains or loses one changes the log-likelihood by ``0.5 / lsigma``, far more
than the others' ``d^2`` differences);
negative eigenvalues of the translation block and a negative heading curvature
are set to 0: a flat or rippled direction (along a corridor longer than the
laser's reach) carries no information. Forward ``h`` is one cell: the cells'
ripple along a wall is periodic in it and cancels in the difference. The odometry motion
model's Gaussian (mean ``d``: the particle's pose at the last update moved by
the odometry; covariance ``P`` from ``srr``... for the increment, both in the
optimum's frame) is multiplied in analytically:

    A = H + P^-1,   Sigma = A^-1,   mu = Sigma P^-1 d

Along a corridor the product is the odometry's Gaussian, across it and in
heading the scan's. The particle is drawn from ``N(x* + mu, Sigma)``; its
weight factor is the normaliser ``log eta = log integral L(x) p(x | x_prev, u) dx``
with ``L(o) = exp(c - o.H.o / 2)``, ``c`` the log-likelihood at the optimum:

    log eta = c - d.(H - H Sigma H).d / 2 - log det(A) / 2 + log det(P^-1) / 2

(less a constant the same for every particle). Unlike sampling ``tau`` on a
grid as wide as the odometry (``proposal=gaussian`` with the former
``proposal_range``), the likelihood is only evaluated within a cell of the
optimum, where beams ending at the edge of the mapped area do not gain map
points by moving the pose back into it.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

# _evaluate compiles in grids.tiled.TILE_SHIFT; numba's cache only checks this file's
# timestamp, so touch this file too when the tile size changes
from slam2d.matching.hill_climb import _evaluate

__all__ = ["laplace_proposal"]


@njit(cache=True, parallel=True)
def laplace_proposal(pool, occ, table, ox, oy, res, kernel, free_check, optima, predicted, prior_std, half, mount,
                     ex, ey, ux, uy, div_s, div_l, normals, out_poses, out_logeta):
    """Draw every particle from the product of the scan's fitted Gaussian and the odometry's; weight by eta.

    ``half`` ``(3,)``: the finite differences' steps (forward, left in m;
    heading in rad); ``prior_std``: the motion model's standard
    deviations ``(forward, left, heading)`` in the predicted pose's frame;
    ``normals[p]``: the particle's standard normals.
    """
    # the optimum, +-each axis, and the four corners of the forward-left square (heading unchanged)
    offsets = np.zeros((11, 3))
    for i in range(3):
        offsets[1 + 2 * i, i] = half[i]
        offsets[2 + 2 * i, i] = -half[i]
    for k, (sf, sl) in enumerate(((1.0, 1.0), (-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0))):
        offsets[7 + k, 0], offsets[7 + k, 1] = sf * half[0], sl * half[1]
    for p in prange(optima.shape[0]):
        co, so = math.cos(optima[p, 2]), math.sin(optima[p, 2])
        c = _evaluate(pool, occ, table, p, ox, oy, res, kernel, free_check, optima[p, 0], optima[p, 1], optima[p, 2],
                      mount, ex, ey, ux, uy, div_s, div_l, True)[1]
        # the curvature from the beams that find a map point at all 11 poses: a beam gaining or losing its
        # map point (a step of 0.5 / lsigma) would swamp the differences of the others' d^2
        v = np.zeros(11)
        beam = np.empty(11)
        for j in range(ex.shape[0]):
            kept = True
            for k in range(11):
                x = optima[p, 0] + co * offsets[k, 0] - so * offsets[k, 1]
                y = optima[p, 1] + so * offsets[k, 0] + co * offsets[k, 1]
                _, lk, matched = _evaluate(pool, occ, table, p, ox, oy, res, kernel, free_check, x, y,
                                           optima[p, 2] + offsets[k, 2], mount, ex[j:j + 1], ey[j:j + 1],
                                           ux[j:j + 1], uy[j:j + 1], div_s[j:j + 1], div_l[j:j + 1], True)
                if matched == 0:
                    kept = False
                    break
                beam[k] = lk
            if kept:
                v += beam
        H = np.zeros((3, 3))  # the scan's information: minus the log-likelihood's curvature by finite differences
        for i in range(3):
            H[i, i] = (2.0 * v[0] - v[1 + 2 * i] - v[2 + 2 * i]) / half[i] ** 2
        H[0, 1] = H[1, 0] = -(v[7] + v[8] - v[9] - v[10]) / (4.0 * half[0] * half[1])
        # a flat or rippled direction carries no information (negative eigenvalues of the translation block
        # and a negative heading curvature are set to 0)
        lam, vec = np.linalg.eigh(H[:2, :2].copy())
        lam[0], lam[1] = max(lam[0], 0.0), max(lam[1], 0.0)
        H[:2, :2] = (vec * lam) @ vec.T
        H[2, 2] = max(H[2, 2], 0.0)
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
        Sigma = np.linalg.inv(A)
        Sigma = 0.5 * (Sigma + Sigma.T)
        mu = Sigma @ (Pinv @ d)
        L = np.linalg.cholesky(Sigma)
        w = mu + L @ normals[p]
        out_poses[p, 0] = optima[p, 0] + co * w[0] - so * w[1]
        out_poses[p, 1] = optima[p, 1] + so * w[0] + co * w[1]
        out_poses[p, 2] = (optima[p, 2] + w[2] + math.pi) % (2.0 * math.pi) - math.pi
        out_logeta[p] = (c - 0.5 * (d @ ((H - H @ Sigma @ H) @ d)) - 0.5 * math.log(np.linalg.det(A))
                         + 0.5 * math.log(np.linalg.det(Pinv)))
