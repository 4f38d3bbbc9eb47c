"""Compiled inner loops of localization: scoring particles and matching a scan to a fixed map.

Both read a :class:`~slam2d.grids.likelihood_field.LikelihoodField` (distance to the nearest
occupied cell, capped at ``max_d``) through plain arrays, so numba sees only numbers.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from slam2d.grids.likelihood_field import bilinear_gradient_at

__all__ = ["particle_log_likelihoods", "traced_path_log_likelihood", "slide_cost", "scan_log_likelihood_grid",
           "refine_on_field", "fit_fraction"]


@njit(cache=True)
def particle_log_likelihoods(field, ox, oy, res, max_d, poses, bx, by, inv_two_sigma2, z_hit, z_rand, out):
    """Mean log-likelihood per beam of every particle pose ``(N, 3)``: the likelihood-field model.

    A beam ending ``d`` metres from the nearest wall scores ``z_hit exp(-d^2 / 2 sigma^2) + z_rand``
    (the cell the endpoint falls in; off the map ``d = max_d``). ``bx, by``: the endpoints in the base frame.
    """
    m = bx.shape[0]
    for p in range(poses.shape[0]):
        acc = _summed_log_likelihood(field, ox, oy, res, max_d, poses[p, 0], poses[p, 1], poses[p, 2], bx, by, 0, m,
                                     inv_two_sigma2, z_hit, z_rand)
        out[p] = acc / max(m, 1)


@njit(cache=True)
def _summed_log_likelihood(field, ox, oy, res, max_d, x, y, th, bx, by, lo, hi, inv_two_sigma2, z_hit, z_rand):
    """The summed beam log-likelihood of the endpoints ``bx[lo:hi], by[lo:hi]`` (base frame) at ``(x, y, th)``."""
    rows, cols = field.shape
    c, s = math.cos(th), math.sin(th)
    acc = 0.0
    for b in range(lo, hi):
        col = int(math.floor((x + c * bx[b] - s * by[b] - ox) / res))
        row = int(math.floor((y + s * bx[b] + c * by[b] - oy) / res))
        d = max_d
        if 0 <= row < rows and 0 <= col < cols:
            d = field[row, col]
        acc += math.log(z_hit * math.exp(-d * d * inv_two_sigma2) + z_rand)
    return acc


@njit(cache=True)
def fit_fraction(field, ox, oy, res, max_d, x, y, th, bx, by, near):
    """The fraction of endpoints within ``near`` metres of a wall of the map, the scan placed at ``(x, y, th)``."""
    c, s = math.cos(th), math.sin(th)
    hits = 0
    for b in range(bx.shape[0]):
        d, _, _ = bilinear_gradient_at(field, ox, oy, res, x + c * bx[b] - s * by[b], y + s * bx[b] + c * by[b], max_d)
        if d < near:
            hits += 1
    return hits / max(bx.shape[0], 1)


@njit(cache=True)
def refine_on_field(field, ox, oy, res, max_d, x, y, th, bx, by, iterations, huber, prior, prior_xy, prior_th):
    """Gauss-Newton on the distance field: the pose near ``(x, y, th)`` that brings the endpoints onto walls.

    Minimises the sum of squared distances (Huber-weighted beyond ``huber`` metres; endpoints at the cap
    carry no gradient and drop out) plus ``prior_xy |xy - prior xy|^2 + prior_th (th - prior th)^2``: along
    a corridor the walls say nothing, and the prior (the odometry's prediction) holds the pose there.
    Returns the pose and the number of endpoints that took part.
    """
    used = 0
    for _ in range(iterations):
        c, s = math.cos(th), math.sin(th)
        h = np.zeros((3, 3))
        g = np.zeros(3)
        used = 0
        for b in range(bx.shape[0]):
            wx = x + c * bx[b] - s * by[b]
            wy = y + s * bx[b] + c * by[b]
            d, gx, gy = bilinear_gradient_at(field, ox, oy, res, wx, wy, max_d)
            if d >= max_d:
                continue
            w = 1.0 if d <= huber else huber / d
            jt = gx * (-s * bx[b] - c * by[b]) + gy * (c * bx[b] - s * by[b])
            j0, j1 = gx, gy
            h[0, 0] += w * j0 * j0
            h[0, 1] += w * j0 * j1
            h[0, 2] += w * j0 * jt
            h[1, 1] += w * j1 * j1
            h[1, 2] += w * j1 * jt
            h[2, 2] += w * jt * jt
            g[0] += w * j0 * d
            g[1] += w * j1 * d
            g[2] += w * jt * d
            used += 1
        if used < 3:
            break
        h[1, 0], h[2, 0], h[2, 1] = h[0, 1], h[0, 2], h[1, 2]
        dth = (th - prior[2] + math.pi) % (2.0 * math.pi) - math.pi
        h[0, 0] += prior_xy
        h[1, 1] += prior_xy
        h[2, 2] += prior_th
        g[0] += prior_xy * (x - prior[0])
        g[1] += prior_xy * (y - prior[1])
        g[2] += prior_th * dth
        damping = 1e-3 * (h[0, 0] + h[1, 1] + h[2, 2]) / 3.0 + 1e-9
        for k in range(3):
            h[k, k] += damping
        step = np.linalg.solve(h, g)
        x -= step[0]
        y -= step[1]
        th -= step[2]
        if abs(step[0]) + abs(step[1]) < 1e-4 and abs(step[2]) < 1e-4:
            break
    th = (th + math.pi) % (2.0 * math.pi) - math.pi
    return x, y, th, used



@njit(cache=True)
def slide_cost(dx, dy, travel, slide_std, slide_per_m):
    """What a pose pays for lying ``(dx, dy)`` from the odometry's prediction over a step of ``travel`` metres: the
    negative log of a Gaussian of std ``slide_std + slide_per_m * travel`` on each axis (its constant left out)."""
    sigma = slide_std + slide_per_m * travel
    return 0.5 * (dx * dx + dy * dy) / (sigma * sigma)


@njit(cache=True)
def traced_path_log_likelihood(field, ox, oy, res, max_d, x, y, th, steps, bx, by, starts, iterations, huber,
                               prior_xy, prior_th, inv_two_sigma2, z_hit, z_rand, slide_std, slide_per_m, per_scan):
    """The summed mean log-likelihood per beam of scans ``0..n-1``, traced back from the last one at ``(x, y, th)``.

    Each earlier pose is the later one moved by ``steps[k]`` (scan ``k``'s pose in scan ``k + 1``'s frame, from the
    odometry) and matched to the map from there (:func:`refine_on_field`, the prediction as its prior), as a
    hypothesis is tracked forwards: odometry alone drifts a tenth of a radian in a second. Scan ``k``'s endpoints
    are ``bx[starts[k]:starts[k + 1]], by[...]`` (base frame). ``per_scan``: each scan's term, when it has ``n`` places.
    With ``slide_std > 0`` each matched pose also pays for how far matching moved it from the prediction (the
    odometry's likelihood: Gaussian, ``slide_std + slide_per_m`` x the step's travel metres per axis): a twin of the
    true place fits the scans by sliding along its corridors, the true path follows the odometry.
    """
    n = starts.shape[0] - 1
    total = 0.0
    prior = np.empty(3)
    for k in range(n - 1, -1, -1):
        lo, hi = starts[k], starts[k + 1]
        if k < n - 1:
            c, s = math.cos(th), math.sin(th)
            x, y, th = x + c * steps[k, 0] - s * steps[k, 1], y + s * steps[k, 0] + c * steps[k, 1], th + steps[k, 2]
            prior[0], prior[1], prior[2] = x, y, th
            x, y, th, _ = refine_on_field(field, ox, oy, res, max_d, x, y, th, bx[lo:hi], by[lo:hi], iterations,
                                          huber, prior, prior_xy, prior_th)
        term = _summed_log_likelihood(field, ox, oy, res, max_d, x, y, th, bx, by, lo, hi, inv_two_sigma2, z_hit,
                                      z_rand) / max(hi - lo, 1)
        if k < n - 1 and slide_std > 0.0:
            term -= slide_cost(x - prior[0], y - prior[1], math.hypot(steps[k, 0], steps[k, 1]), slide_std, slide_per_m)
        if per_scan.shape[0] == n:
            per_scan[k] = term
        total += term
    return total



@njit(cache=True)
def scan_log_likelihood_grid(log_likelihood, ox, oy, res, off_map, xy, headings, bx, by, out):
    """The mean log-likelihood per beam of one scan at every position ``xy (P, 2)`` and heading: ``out (P, H)``.

    ``log_likelihood``: each cell's beam log-likelihood (the model of :func:`particle_log_likelihoods` drawn once
    per map), ``off_map`` the value outside it.
    """
    rows, cols = log_likelihood.shape
    m = bx.shape[0]
    rx, ry = np.empty(m), np.empty(m)
    for h in range(headings.shape[0]):
        c, s = math.cos(headings[h]), math.sin(headings[h])
        for b in range(m):  # the scan turned once per heading
            rx[b] = c * bx[b] - s * by[b] - ox
            ry[b] = s * bx[b] + c * by[b] - oy
        for p in range(xy.shape[0]):
            acc = 0.0
            for b in range(m):
                col = int(math.floor((xy[p, 0] + rx[b]) / res))
                row = int(math.floor((xy[p, 1] + ry[b]) / res))
                if 0 <= row < rows and 0 <= col < cols:
                    acc += log_likelihood[row, col]
                else:
                    acc += off_map
            out[p, h] = acc / max(m, 1)
