"""Wall ends in one laser scan: door jambs and box corners, as points with a covariance.

Along a corridor longer than the laser's reach the beams on the two walls say nothing about
where along it the robot is; the few beams where a wall *ends* in front of something farther
do (docs/accuracy_bound.md: with a URG-04LX in the simulated office the bound is 1.3 cm with
the wall ends' bearings and 16 cm without). A correlative score over hundreds of wall points
draws little of that out, so the graph front end can take the ends as landmarks
(:mod:`slam2d.graph.wall_end_landmarks`).

A wall end is the *nearer* beam at a range jump: beam k hits a surface, the next beam (and the
one after it, so a single dropout or a noisy reading is not taken for a doorway) returns more
than ``jump`` farther or nothing. The surface's true end lies somewhere between beam k's and
beam k+1's bearings. Checks that it really ends there:

* the near surface is one run of ``run`` beams without a jump (a lone point is clutter); its
  line is their least-squares fit, and the end beam's range continues those before it (a
  real laser's beam at an edge can return a mix of both surfaces);
* (a wall seen at a grazing angle has points ever further apart, and past some range the step
  between two beams on the *same* wall exceeds the jump: the wall occluding nothing but itself,
  which the test below refuses);
* the line meets the next beam's ray in front of the laser and within its range less half a
  jump: otherwise the wall may simply run out of range (no return) rather than end;
* the first beam after the end with a return (at most two lost returns later: dark and grazing
  walls lose returns) passes *behind* the line carried on: a reading on it is the same wall at a
  grazing angle, one in front of it something hiding the wall's continuation;
* the beam meets the surface at less than ``max_incidence`` from its normal: near grazing
  the end's position along the wall is ill-defined (and a round post's silhouette, which
  moves with the viewer, is always seen grazing).

The point is where the near line meets the ray half-way between the two bearings; its
covariance is a uniform error along the line over the gap between the two rays
(``gap^2 / 12``) and the range sigma across it. Everything is whole-array numpy over the
beams; both sides (the wall ending at increasing and at decreasing beam index) are the same
test on the reversed arrays.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from slam2d.core import se2

__all__ = ["WallEnds", "detect_wall_ends"]


@dataclass(frozen=True)
class WallEnds:
    """Wall ends of one scan, in the robot (base) frame.

    ``points`` (K, 2) m; ``covariances`` (K, 2, 2) m^2; ``beams`` (K,) index of the nearer beam;
    ``side`` (K,) +1 when the wall ends towards increasing beam index, -1 towards decreasing;
    ``direction`` (K, 2) unit vector along the wall, from the end into the wall.
    """

    points: NDArray[np.float64]
    covariances: NDArray[np.float64]
    beams: NDArray[np.int64]
    side: NDArray[np.int64]
    direction: NDArray[np.float64]

    def __len__(self) -> int:
        return int(self.points.shape[0])


def _one_side(r: NDArray[np.float64], ang: NDArray[np.float64], sig: NDArray[np.float64], *, jump: float,
              run: int, continuation: float, max_incidence: float, open_incidence: float, range_max: float,
              bearing_sigma: float):
    """Ends of walls towards increasing index: (beam k, end point, along-wall sigma, across sigma, wall direction)."""
    n = r.shape[0]
    empty = (np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.zeros((0, 2)))
    if n < run + 2:
        return empty
    ok = ~np.isnan(r)
    rr = np.where(ok, r, np.inf)  # no return counts as farther than anything
    k = np.arange(run - 1, n - 2)  # beam k needs run-1 beams before it and two after
    near = ok[k] & (rr[k + 1] > rr[k] + jump) & (rr[k + 2] > rr[k] + jump)
    for j in range(1, run):  # the near surface: a run of beams without a jump (run is a handful)
        a, b = k - j, k - j + 1
        with np.errstate(invalid="ignore"):
            near &= ok[a] & ok[b] & (np.abs(rr[a] - rr[b]) <= jump)
    k = k[near]
    if k.size == 0:
        return empty
    c, s = np.cos(ang), np.sin(ang)
    pk = np.stack([r[k] * c[k], r[k] * s[k]], axis=-1)
    # The near wall's direction: the principal axis of the run's points (a least-squares line),
    # pointing from the run's first point towards its end.
    idx = k[:, None] - np.arange(run)[None, :]
    pts = np.stack([r[idx] * c[idx], r[idx] * s[idx]], axis=-1)
    q = pts - pts.mean(axis=1, keepdims=True)
    sxx, syy, sxy = (q[..., 0] ** 2).sum(1), (q[..., 1] ** 2).sum(1), (q[..., 0] * q[..., 1]).sum(1)
    phi = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)
    u = np.stack([np.cos(phi), np.sin(phi)], axis=-1)
    d = pk - pts[:, -1]
    u = np.where(((u * d).sum(axis=1) < 0)[:, None], -u, u)  # along the wall, towards its end
    good = (sxx + syy) > 1e-12
    # The end beam itself must continue the ranges of the beams before it (a straight-line fit of
    # range over beam index, extrapolated one beam, within three sigmas of the prediction): a real
    # laser's beam at an edge can return a mix of the near and far surface, between them.
    m = run - 1
    x = np.arange(m, dtype=np.float64) - 0.5 * (m - 1)
    prev = r[idx[:, :0:-1]]  # beams k-run+1 .. k-1, in index order
    slope = (prev * x).sum(axis=1) / (x * x).sum()
    guess = prev.mean(axis=1) + slope * (0.5 * (m - 1) + 1.0)
    spread = math.sqrt(1.0 + 1.0 / m + (0.5 * (m - 1) + 1.0) ** 2 / (x * x).sum())
    good &= np.abs(r[k] - guess) <= 3.0 * spread * np.maximum(sig[k], 0.003)

    def hit(bearing):
        """Where the ray at ``bearing`` meets the near line: distance along the ray (inf if never in front)."""
        ray = np.stack([np.cos(bearing), np.sin(bearing)], axis=-1)
        # t * ray = pk + s * u  ->  t = cross(pk, u) / cross(ray, u)
        den = ray[:, 0] * u[:, 1] - ray[:, 1] * u[:, 0]
        num = pk[:, 0] * u[:, 1] - pk[:, 1] * u[:, 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = num / den
        return np.where(np.abs(den) > 1e-12, t, np.inf), ray

    # The evidence that the wall ends: the first beam after k with a return (j; at most two lost
    # returns between, since a dark or grazing wall loses returns too) must pass *behind* the wall
    # carried on. A far reading on that line is the same wall seen at a grazing angle (occluding only
    # itself); one in front of it is something occluding the wall's continuation: either way the
    # wall need not end here.
    nxt = np.where(ok, np.arange(n), n)
    nxt = np.minimum.accumulate(nxt[::-1])[::-1]
    j = nxt[k + 1]
    # No return for more than two beams (an open door into a room beyond the reach, or a grazing
    # wall losing its returns): taken only where a wall carried on would be seen at no more than
    # open_incidence and well within the reach three beams on; the end is then placed between beam
    # k and k + 1.
    gone = j > k + 3
    j = np.where(gone, k + 1, np.minimum(j, n - 1))
    t_next, ray_next = hit(ang[k + 1])
    t_j, ray_j = hit(ang[j])
    t_mid, ray_mid = hit(0.5 * (ang[k] + ang[j]))
    # Incidence at the end: the angle between beam k and the wall's normal.
    beam = np.stack([c[k], s[k]], axis=-1)
    cos_inc = np.abs(beam[:, 0] * u[:, 1] - beam[:, 1] * u[:, 0])
    good &= cos_inc >= math.cos(max_incidence)
    t_far, _ = hit(ang[np.minimum(k + 3, n - 1)])
    good &= ~gone | ((cos_inc >= math.cos(open_incidence)) & np.isfinite(t_far) & (t_far > 0)
                     & (t_far < range_max - jump))
    # The wall, carried on, must meet the next ray in front of the laser and within its reach (less
    # half a jump: noise must not let a wall running out of range pass).
    good &= np.isfinite(t_next) & (t_next > 0) & (t_next < range_max - 0.5 * jump) & np.isfinite(t_mid) & (t_mid > 0)
    far = np.where(gone, np.inf, r[j])
    in_front = np.isfinite(t_j) & (t_j > 0)
    with np.errstate(invalid="ignore"):
        good &= ~in_front | gone | (far > t_j + continuation + 0.05 * far)
    # The end lies between beam k and beam j (a lost return between may have been the wall).
    k, u, t_end, t_mid, ray_end, ray_mid, pk, sig_k, cos_inc = (
        k[good], u[good], t_j[good], t_mid[good], ray_j[good], ray_mid[good], pk[good], sig[k[good]], cos_inc[good])
    t_end = np.where(np.isfinite(t_end) & (t_end > 0), t_end, 2.0 * t_mid - np.hypot(pk[:, 0], pk[:, 1]))
    point = t_mid[:, None] * ray_mid
    gap = np.hypot(*(t_end[:, None] * ray_end - pk).T)  # along the wall, between the two rays
    # A real beam is not a ray: where it covers the edge only in part it can still return the near
    # surface, so the end seen from here can be off by a share of its width (bearing_sigma).
    along = gap / math.sqrt(12.0)
    if bearing_sigma > 0:
        along = np.hypot(along, np.hypot(pk[:, 0], pk[:, 1]) * bearing_sigma / np.maximum(cos_inc, 1e-3))
    return k, point, along, sig_k, -u


def detect_wall_ends(scan, sigmas: NDArray[np.float64] | float, *, jump: float = 0.3, run: int = 5,
                     continuation: float = 0.05, max_incidence: float = math.radians(80.0),
                     open_incidence: float = math.radians(70.0), max_range: float = math.inf,
                     bearing_sigma: float = 0.0) -> WallEnds:
    """The wall ends of ``scan`` (a :class:`~slam2d.core.scan.LaserScan`) in the robot frame.

    ``sigmas``: per-beam range sigma (m, NaN for no return, e.g. from
    :func:`~slam2d.sensors.beam_model.beam_sigmas`) or one value. ``jump`` (m): least range
    step from the near beam to the next two; ``run`` (beams): length of the near surface
    without a jump; ``continuation`` (m, plus 5 % of the range): a far reading this close to the
    near wall carried on is the same wall; ``max_incidence`` (rad), ``open_incidence`` (rad) where
    no return follows for three beams; ``bearing_sigma`` (rad): a bearing error added in quadrature
    to the beam gap's (a real beam's width); ``max_range`` (m): nearer
    beams beyond it are not used (a far end is located coarsely and is rarely needed).
    """
    r = np.array(scan.ranges, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        r[r > max_range] = np.nan
    ang = np.asarray(scan.angles, dtype=np.float64)
    sig = np.broadcast_to(np.asarray(sigmas, dtype=np.float64), r.shape)
    sig = np.where(np.isfinite(sig), sig, 0.0)
    kw = dict(jump=jump, run=max(int(run), 2), continuation=continuation, max_incidence=max_incidence,
              open_incidence=min(open_incidence, max_incidence), bearing_sigma=float(bearing_sigma),
              range_max=float(min(scan.range_max, max_range)))
    k1, p1, a1, s1, u1 = _one_side(r, ang, sig, **kw)
    k2, p2, a2, s2, u2 = _one_side(r[::-1].copy(), ang[::-1].copy(), sig[::-1].copy(), **kw)
    k2 = r.shape[0] - 1 - k2
    k = np.concatenate([k1, k2])
    pts = np.concatenate([p1, p2])
    along = np.concatenate([a1, a2])
    across = np.concatenate([s1, s2])
    u = np.concatenate([u1, u2])
    side = np.concatenate([np.ones(k1.size, np.int64), -np.ones(k2.size, np.int64)])
    # Covariance: along the wall a uniform error over the gap, across it the range sigma
    # (a floor of a millimetre keeps it invertible when no sigma is known).
    across = np.maximum(across, 1e-3)
    nrm = np.stack([-u[:, 1], u[:, 0]], axis=-1)
    cov = (along**2)[:, None, None] * u[:, :, None] * u[:, None, :] + (across**2)[:, None, None] * nrm[:, :, None] * nrm[:, None, :]
    # Laser frame -> robot frame.
    m = np.asarray(scan.mount, dtype=np.float64)
    if np.any(m != 0):
        pts = se2.transform_points(m, pts) if pts.size else pts
        c, s = math.cos(m[2]), math.sin(m[2])
        rot = np.array([[c, -s], [s, c]])
        cov = rot @ cov @ rot.T
        u = u @ rot.T
    return WallEnds(points=pts.reshape(-1, 2), covariances=cov.reshape(-1, 2, 2), beams=k.astype(np.int64),
                    side=side, direction=u.reshape(-1, 2))
