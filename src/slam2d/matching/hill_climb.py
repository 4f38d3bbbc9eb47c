"""GMapping's scan matcher: greedy hill climbing on a hit-point score, for all particles at once.

Every function takes all particles' maps (a :class:`~slam2d.grids.tiled.TiledMaps`
pool and table) and poses, and runs over the particles in parallel
(``numba.prange``; each particle writes only its own outputs, so the result
does not depend on the thread count).

**Score of a pose** (GMapping ``ScanMatcher::score``). For each beam, search
the ``(2 kernel_size + 1)^2`` cells around its end point for an *occupied*
cell (``hits / visits > 0.1``); ``d`` is the distance from the end point to
the nearest such cell's mean hit point.
The beam adds ``exp(-d^2 / sigma_j)`` to the score. The original's ``sigma``
is that divisor (m^2, not a standard deviation): it equals ``2 s^2`` for a
Gaussian of standard deviation ``s``, so the default 0.05 is ``s = 0.158 m``.

**Log-likelihood** (``likelihoodAndScore``): a matched beam adds
``-d^2 / lsigma_j``, an unmatched one ``-0.5 / lsigma_j`` (GMapping's
``nullLikelihood``), so a beam further than ``sqrt(0.5 lsigma)`` from the map
(0.19 m at the default 0.075) counts as a miss.

**Hill climb** (``ScanMatcher::optimize``): from the start pose, try the six
moves +-x, +-y (world frame, step ``lstep``) and +-theta (``astep``); take the
best that improves the score; when none does, halve both steps. Stop when
nothing improves and the steps have been halved ``iterations`` times.

The "free neighbour" test. GMapping's code also means to reject a cell whose
neighbour one ``sqrt(2)`` cell step back along the beam is occupied, but it
computes the neighbour's offset by passing a displacement through its
point-to-cell conversion, which adds the map's centre offset: with the default
map the "neighbour" lands thousands of cells away, almost always in unknown
space, so the test never rejects anything. slam2d reproduces that by not
testing it (the test as meant, ``free_cell_check``, was tried and removed:
docs/methods/what-was-tried.md).

**Speed, same numbers.** A climb scores ~80 poses a few millimetres to a
few centimetres apart. A beam's candidate map
points depend only on the cell it ends in, so each beam keeps the windows of
the last cells it ended in (:func:`_score_cached`, four slots: a 2 x 2 block
of cells) and looks the map up again only on a new cell (about a quarter of
the beams per pose); and a candidate that is bit for bit a pose the climb
already scored (a step back to where it came from) reuses that score. Both
do the same arithmetic in the same order as :func:`_evaluate`: the scores,
the climbs and so the filter are unchanged, bit for bit
(``tests/test_hill_climb_cache.py``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from slam2d.grids.tiled import HITS, SUM_X, SUM_Y, TILE_SHIFT, cell_tile

__all__ = ["BeamSet", "match_particles", "match_one", "score_particles", "gaussian_proposal", "hold_flat_direction",
           "along_terms", "wall_ends", "wall_end_terms"]

# TILE_SHIFT is compiled in as a constant, and numba's cache only checks this file's timestamp:
# touch this file when tiled.py changes it
_MASK = (1 << TILE_SHIFT) - 1
_SEEN = 256  # poses a climb remembers the score of
_SLOTS = 4  # cached windows per beam in a climb: a 2 x 2 block of cells (by row and column parity)
NULL_LIKELIHOOD = -0.5  # GMapping nullLikelihood: an unmatched beam's log-likelihood x lsigma


class BeamSet:
    """The beams of one scan a matcher uses, in the laser frame, with their divisors.

    ``ex, ey``: end points (m); ``div_score`` and
    ``div_like``: per-beam ``sigma`` and ``lsigma`` (m^2) of the score and the
    log-likelihood; ``var``: the sensor model's range variance per beam (m^2; zeros
    without a model). ``use`` selects the beams; every other argument has one
    entry per beam of the scan.
    """

    __slots__ = ("ex", "ey", "div_score", "div_like", "var", "ends")

    def __init__(self, ranges, angles, use, div_score, div_like, var=None, ends=None) -> None:
        r = np.asarray(ranges, dtype=np.float64)[use]
        a = np.asarray(angles, dtype=np.float64)[use]
        self.ex, self.ey = r * np.cos(a), r * np.sin(a)
        self.div_score = np.ascontiguousarray(np.asarray(div_score, dtype=np.float64)[use])
        self.div_like = np.ascontiguousarray(np.asarray(div_like, dtype=np.float64)[use])
        self.var = np.zeros(self.ex.shape[0]) if var is None else np.ascontiguousarray(
            np.asarray(var, dtype=np.float64)[use])
        self.ends = np.zeros((0, 5)) if ends is None else ends  # see wall_ends()

    def __len__(self) -> int:
        return int(self.ex.shape[0])


def wall_ends(ranges, angles, use, limit, jump=0.5, back=4, max_gap=0.15):
    """The scan's wall ends: where a beam still hits a straight wall and its neighbour passes the wall's end.

    A beam ``n`` (in ``use``) whose neighbour ``f`` and the next one beyond are invalid or more than
    ``jump`` m farther, while beams ``n-1 .. n-back`` on the other side lie on a line with it (the wall),
    marks a wall end: it lies on that wall line between ``n``'s end point ``a`` and where the line
    crosses ray ``f``. Returned ``(K, 5)``, laser frame: ``a`` (x, y), the wall's unit direction
    toward the end (x, y) and half the distance from ``a`` to ray ``f`` along it (m), for walls that
    cross ``f`` within ``max_gap`` (not those nearly along the beams) and nearer than ``limit`` (m, the
    farthest range used) less 5 cm: a wall that runs on out of the laser's reach is not a wall end.
    Whole-array numpy.
    """
    r = np.asarray(ranges, dtype=np.float64)
    a = np.asarray(angles, dtype=np.float64)
    n = r.shape[0]
    ok = np.asarray(use, dtype=bool) & np.isfinite(r)
    rr = np.where(ok, r, np.inf)
    out = []
    idx = np.arange(n)
    for d in (1, -1):  # the end's side: beams beyond it have higher (1) or lower (-1) indices
        near = idx[(idx + 2 * d >= 0) & (idx + 2 * d < n) & (idx - back * d >= 0) & (idx - back * d < n)]
        if near.size == 0:
            continue
        f1, f2, b = near + d, near + 2 * d, near - back * d
        cand = ok[near] & ok[b] & (rr[f1] > r[near] + jump) & (rr[f2] > r[near] + jump)
        for k in range(1, back + 1):  # the wall behind: every beam valid
            cand &= ok[near - k * d]
        near, f1, b = near[cand], f1[cand], b[cand]
        if near.size == 0:
            continue
        ax, ay = r[near] * np.cos(a[near]), r[near] * np.sin(a[near])
        bx, by = r[b] * np.cos(a[b]), r[b] * np.sin(a[b])
        wx, wy = ax - bx, ay - by
        length = np.hypot(wx, wy)
        wx, wy = wx / np.maximum(length, 1e-9), wy / np.maximum(length, 1e-9)
        mid = near - (back // 2) * d  # straight: the middle beam within 2 cm of the line
        mx, my = r[mid] * np.cos(a[mid]) - bx, r[mid] * np.sin(a[mid]) - by
        straight = np.abs(mx * wy - my * wx) < 0.02
        # where the wall line a + lam w crosses ray f: cross(a + lam w, u_f) = 0
        ufx, ufy = np.cos(a[f1]), np.sin(a[f1])
        den = wx * ufy - wy * ufx
        with np.errstate(divide="ignore", invalid="ignore"):
            lam = -(ax * ufy - ay * ufx) / den
        reach = np.hypot(ax + lam * wx, ay + lam * wy)  # where ray f would have met the wall had it gone on
        # not at grazing incidence (over 60 deg): there returns drop out in mid-wall and look like ends
        facing = np.abs(np.cos(a[near]) * wy - np.sin(a[near]) * wx) > 0.5
        good = (straight & facing & (length > 0.02) & np.isfinite(lam) & (lam > 0.0) & (lam < max_gap)
                & (reach < limit - 0.05))
        out.append(np.stack([ax, ay, wx, wy, 0.5 * lam], axis=1)[good])
    return np.ascontiguousarray(np.concatenate(out)) if out else np.zeros((0, 5))


@njit(cache=True, inline="always")
def _occupied(occ, t, row, col):
    return t >= 0 and occ[t, row & _MASK, col & _MASK]


@njit(cache=True, inline="always")
def _window_points(pool, occ, table, p, t0, row, col, kernel, ox, oy, res, pts, j):
    """The usable map points around cell ``(row, col)``: written to ``pts[j, :k]``, returns ``k``.

    A usable point is the mean hit point of an occupied cell in the window.
    ``t0`` is the tile of ``(row, col)`` when the whole window lies in it (the
    common case: one table lookup), else -1.
    """
    k = 0
    for dr in range(-kernel, kernel + 1):
        for dc in range(-kernel, kernel + 1):
            rr = row + dr
            cc = col + dc
            t = t0 if t0 >= 0 else cell_tile(table, p, rr, cc)
            if t < 0:
                continue
            a = rr & _MASK
            b = cc & _MASK
            if not occ[t, a, b]:
                continue
            n = pool[t, a, b, HITS]
            pts[j, k, 0] = ox + (cc + 0.5) * res + pool[t, a, b, SUM_X] / n
            pts[j, k, 1] = oy + (rr + 0.5) * res + pool[t, a, b, SUM_Y] / n
            k += 1
    return k


@njit(cache=True, inline="always")
def _nearest(pts, j, k, wx, wy):
    """Squared distance from ``(wx, wy)`` to the nearest of ``pts[j, :k]`` (the first on a tie), or -1."""
    best = -1.0
    for i in range(k):
        mx = pts[j, i, 0]
        my = pts[j, i, 1]
        d2 = (wx - mx) * (wx - mx) + (wy - my) * (wy - my)
        if best < 0.0 or d2 < best:
            best = d2
    return best


@njit(cache=True, inline="always")
def _laser_in_world(x, y, th, mount):
    """The laser's position and heading (cos, sin) in the world for robot pose ``(x, y, th)``."""
    c, s = math.cos(th), math.sin(th)
    lth = th + mount[2]
    return x + c * mount[0] - s * mount[1], y + s * mount[0] + c * mount[1], math.cos(lth), math.sin(lth)


@njit(cache=True, fastmath=True)
def _evaluate(pool, occ, table, p, ox, oy, res, kernel, x, y, th, mount, ex, ey, div_s, div_l, want_like):
    """``(score, log-likelihood, matched beams)`` of robot pose ``(x, y, th)`` on map ``p``."""
    lx, ly, lc, ls = _laser_in_world(x, y, th, mount)
    inv = 1.0 / res
    score = 0.0
    like = 0.0
    matched = 0
    pts = np.empty((1, (2 * kernel + 1) * (2 * kernel + 1), 2))
    for j in range(ex.shape[0]):
        wx = lx + lc * ex[j] - ls * ey[j]
        wy = ly + ls * ex[j] + lc * ey[j]
        col = int(math.floor((wx - ox) * inv))
        row = int(math.floor((wy - oy) * inv))
        a = row & _MASK
        b = col & _MASK
        t0 = -1
        if kernel <= a <= _MASK - kernel and kernel <= b <= _MASK - kernel:
            t0 = cell_tile(table, p, row, col)
            if t0 < 0:  # the whole window is unknown
                if want_like:
                    like += NULL_LIKELIHOOD / div_l[j]
                continue
        k = _window_points(pool, occ, table, p, t0, row, col, kernel, ox, oy, res, pts, 0)
        best = _nearest(pts, 0, k, wx, wy)
        if best >= 0.0:
            score += math.exp(-best / div_s[j])
            matched += 1
            if want_like:
                like -= best / div_l[j]
        elif want_like:
            like += NULL_LIKELIHOOD / div_l[j]
    return score, like, matched


@njit(cache=True, fastmath=True)
def _score_cached(pool, occ, table, p, ox, oy, res, kernel, x, y, th, mount, ex, ey, div_s, key, count, pts):
    """The score of :func:`_evaluate`, reusing each beam's window points.

    A climb evaluates ~90 poses a few millimetres apart, so most beams end in
    the cell they ended in at the previous pose: ``key[j]`` is that cell and
    ``pts[j, :count[j]]`` its window's map points, looked up again only when
    the beam changes cell. Same arithmetic, same order: the same score, bit
    for bit.
    """
    lx, ly, lc, ls = _laser_in_world(x, y, th, mount)
    inv = 1.0 / res
    score = 0.0
    for j in range(ex.shape[0]):
        wx = lx + lc * ex[j] - ls * ey[j]
        wy = ly + ls * ex[j] + lc * ey[j]
        col = int(math.floor((wx - ox) * inv))
        row = int(math.floor((wy - oy) * inv))
        slot = j * _SLOTS + (row & 1) * 2 + (col & 1)
        if row != key[slot, 0] or col != key[slot, 1]:
            key[slot, 0] = row
            key[slot, 1] = col
            a = row & _MASK
            b = col & _MASK
            inside = kernel <= a <= _MASK - kernel and kernel <= b <= _MASK - kernel  # the window in one tile
            t0 = cell_tile(table, p, row, col) if inside else -1
            if inside and t0 < 0:
                count[slot] = 0  # the whole window is unknown
            else:
                count[slot] = _window_points(pool, occ, table, p, t0, row, col, kernel, ox, oy, res, pts, slot)
        best = _nearest(pts, slot, count[slot], wx, wy)
        if best >= 0.0:
            score += math.exp(-best / div_s[j])
    return score


@njit(cache=True, inline="always")
def _score(pool, occ, table, p, ox, oy, res, kernel, x, y, th, mount, ex, ey, div_s, div_l,
           key, count, pts):
    """The score of a pose in a climb (cached windows)."""
    return _score_cached(pool, occ, table, p, ox, oy, res, kernel, x, y, th, mount, ex, ey, div_s, key, count, pts)


@njit(cache=True)
def _climb(pool, occ, table, p, ox, oy, res, kernel, start, mount, ex, ey, div_s, div_l,
           lstep, astep, iterations, lin_rel, ang_rel, prior_info):
    """GMapping's ``optimize`` for one particle: ``(x, y, th, best score)``.

    ``lin_rel`` (1/m^2) and ``ang_rel`` (1/rad^2) are GMapping's odometry
    reliabilities (``m_linearOdometryReliability``, ``m_angularOdometryReliability``,
    0 in GMapping): a candidate's score is multiplied by
    ``exp(-lin_rel d^2 - ang_rel dtheta^2)``, ``d`` and ``dtheta`` its distance
    from the start pose, so the climb does not wander where the scan does not
    constrain it (along a corridor).

    ``prior_info`` (not in GMapping; zeros: off): the information ``(1/sx^2,
    1/sy^2, 1/stheta^2)`` of the odometry prior around ``start`` (x, y in
    ``start``'s own frame). The climb then maximises ``score - prior``, ``prior``
    half the squared Mahalanobis distance from ``start``: near its optimum the
    score falls like a log-likelihood (``sum d^2 / sigma``), so this is the mode
    of likelihood times motion prior, the centre of Grisetti et al.'s improved
    proposal. Where the scan constrains the pose the score's curvature is far
    larger and the prior changes nothing; where it does not (along a corridor
    longer than the laser's range) the prior keeps the climb from sliding on
    the score's lattice ripple. The returned score is the plain score.
    """
    x, y, th = start[0], start[1], start[2]
    c0, s0 = math.cos(start[2]), math.sin(start[2])
    # each beam's last cell and its window's map points (see _score_cached)
    key = np.full((ex.shape[0] * _SLOTS, 2), np.iinfo(np.int64).min, dtype=np.int64)
    count = np.zeros(ex.shape[0] * _SLOTS, dtype=np.int64)
    pts = np.empty((ex.shape[0] * _SLOTS, (2 * kernel + 1) * (2 * kernel + 1), 2))
    # the poses scored so far and their scores: a step back to where the climb was (or a lattice point
    # it already tried) is often the very same pose, bit for bit, and its score is not computed again
    seen = np.empty((_SEEN, 3))
    seen_score = np.empty(_SEEN)
    n_seen = 0
    use_prior = prior_info[0] > 0.0 or prior_info[1] > 0.0 or prior_info[2] > 0.0
    current = _score(pool, occ, table, p, ox, oy, res, kernel, x, y, th, mount, ex, ey, div_s, div_l,
                     key, count, pts)
    seen[0, 0], seen[0, 1], seen[0, 2] = x, y, th
    seen_score[0] = current
    n_seen = 1
    raw = current
    best_score = -1.0
    cand_raw = raw
    ldelta, adelta = lstep, astep
    refinement = 0
    while True:
        if best_score >= current:
            refinement += 1
            ldelta *= 0.5
            adelta *= 0.5
        best_score = current
        bx, by, bth = x, y, th
        for move in range(6):
            cx, cy, cth = x, y, th
            if move == 0:
                cx += ldelta
            elif move == 1:
                cx -= ldelta
            elif move == 2:
                cy -= ldelta
            elif move == 3:
                cy += ldelta
            elif move == 4:
                cth += adelta
            else:
                cth -= adelta
            sc = -1.0
            for i in range(n_seen):
                if seen[i, 0] == cx and seen[i, 1] == cy and seen[i, 2] == cth:
                    sc = seen_score[i]
                    break
            if sc < 0.0:
                sc = _score(pool, occ, table, p, ox, oy, res, kernel, cx, cy, cth, mount, ex, ey,
                            div_s, div_l, key, count, pts)
                if n_seen < _SEEN:
                    seen[n_seen, 0], seen[n_seen, 1], seen[n_seen, 2] = cx, cy, cth
                    seen_score[n_seen] = sc
                    n_seen += 1
            if lin_rel > 0.0 or ang_rel > 0.0:
                ddx, ddy = cx - start[0], cy - start[1]
                dth = (cth - start[2] + math.pi) % (2.0 * math.pi) - math.pi
                sc *= math.exp(-lin_rel * (ddx * ddx + ddy * ddy) - ang_rel * dth * dth)
            obj = sc
            if use_prior:
                ddx, ddy = cx - start[0], cy - start[1]
                fx = c0 * ddx + s0 * ddy
                fy = -s0 * ddx + c0 * ddy
                dth = (cth - start[2] + math.pi) % (2.0 * math.pi) - math.pi
                obj = sc - 0.5 * (prior_info[0] * fx * fx + prior_info[1] * fy * fy + prior_info[2] * dth * dth)
            if obj > current:
                current = obj
                cand_raw = sc
                bx, by, bth = cx, cy, cth
        if bx != x or by != y or bth != th:
            raw = cand_raw
        x, y, th = bx, by, bth
        if not (current > best_score or refinement < iterations):
            break
    return x, y, th, (raw if use_prior else best_score)


@njit(cache=True, parallel=True)
def match_particles(pool, occ, table, ox, oy, res, kernel, poses, mount, ex, ey, div_s, div_l,
                    lstep, astep, iterations, lin_rel, ang_rel, prior_info, minimum_score,
                    out_poses, out_score, out_like, out_ok):
    """Hill-climb every particle from ``poses`` on its own map (GMapping ``scanMatch``).

    A particle whose best score is not above ``minimum_score`` keeps its pose
    (``out_ok`` False: the match failed, odometry is used). ``out_like`` is the
    log-likelihood at the pose kept. ``prior_info``: see :func:`_climb`, one
    row per particle (``(N, 3)``; zeros: GMapping's climb).
    """
    for p in prange(poses.shape[0]):
        x, y, th, sc = _climb(pool, occ, table, p, ox, oy, res, kernel, poses[p], mount, ex, ey,
                              div_s, div_l, lstep, astep, iterations, lin_rel, ang_rel, prior_info[p])
        ok = sc > minimum_score
        if not ok:
            x, y, th = poses[p, 0], poses[p, 1], poses[p, 2]
        out_poses[p, 0], out_poses[p, 1] = x, y
        out_poses[p, 2] = (th + math.pi) % (2.0 * math.pi) - math.pi
        out_score[p] = sc
        out_ok[p] = ok
        out_like[p] = _evaluate(pool, occ, table, p, ox, oy, res, kernel, x, y, th, mount, ex, ey,
                                div_s, div_l, True)[1]


@njit(cache=True)
def match_one(pool, occ, table, p, ox, oy, res, kernel, pose, mount, ex, ey, div_s, div_l,
              lstep, astep, iterations, lin_rel, ang_rel, prior_info, minimum_score):
    """Hill-climb one pose on map ``p`` (GMapping's climb): ``(x, y, theta, score, ok)``.

    ``ok`` False (score not above ``minimum_score``): the pose returned is ``pose``.
    """
    x, y, th, sc = _climb(pool, occ, table, p, ox, oy, res, kernel, pose, mount, ex, ey,
                          div_s, div_l, lstep, astep, iterations, lin_rel, ang_rel, prior_info)
    if not sc > minimum_score:
        return pose[0], pose[1], pose[2], sc, False
    return x, y, (th + math.pi) % (2.0 * math.pi) - math.pi, sc, True


@njit(cache=True, parallel=True)
def score_particles(pool, occ, table, ox, oy, res, kernel, poses, mount, ex, ey, div_s, div_l,
                    out_score, out_like, out_matched):
    """Score and log-likelihood of every particle at its pose, no search."""
    for p in prange(poses.shape[0]):
        sc, lk, m = _evaluate(pool, occ, table, p, ox, oy, res, kernel, poses[p, 0], poses[p, 1], poses[p, 2],
                              mount, ex, ey, div_s, div_l, True)
        out_score[p] = sc
        out_like[p] = lk
        out_matched[p] = m


@njit(cache=True, parallel=True)
def gaussian_proposal(pool, occ, table, ox, oy, res, kernel, optima, predicted, prior_std, offsets, mount,
                      ex, ey, div_s, div_l, normals, out_poses, out_logeta):
    """Grisetti et al. 2007's improved proposal around each particle's scan-matching optimum.

    For each particle, ``tau(x) = p(z | m, x) p(x | x_prev, u)`` is evaluated
    at the optimum moved by ``offsets[k]`` (``(forward, left, dtheta)`` in the
    optimum's own frame, so a grid stretched along the robot's heading follows
    a corridor it drives along). ``p(z | m, x)`` is the log-likelihood above;
    the odometry prior is a Gaussian around ``predicted`` (the particle's pose
    at the last update moved by the odometry) with standard deviations
    ``prior_std`` in the predicted pose's frame. A Gaussian is fitted to the
    samples (mean and covariance weighted by tau): where the scan pins the
    pose it is the likelihood's, where the scan is flat (along a corridor
    longer than the laser's reach) it is the odometry's. The new pose is drawn
    from it with the standard normals ``normals[p]``, and ``out_logeta`` is
    ``log sum tau``, the particle's weight factor (the grid's cell volume is
    the same for every particle and cancels in the normalised weights).
    """
    K = offsets.shape[0]
    for p in prange(optima.shape[0]):
        logt = np.empty(K)
        c, s = math.cos(predicted[p, 2]), math.sin(predicted[p, 2])
        co, so = math.cos(optima[p, 2]), math.sin(optima[p, 2])
        for k in range(K):
            x = optima[p, 0] + co * offsets[k, 0] - so * offsets[k, 1]
            y = optima[p, 1] + so * offsets[k, 0] + co * offsets[k, 1]
            th = optima[p, 2] + offsets[k, 2]
            lk = _evaluate(pool, occ, table, p, ox, oy, res, kernel, x, y, th, mount, ex, ey,
                           div_s, div_l, True)[1]
            dx, dy = x - predicted[p, 0], y - predicted[p, 1]
            fx = (c * dx + s * dy) / prior_std[0]
            fy = (-s * dx + c * dy) / prior_std[1]
            dth = (th - predicted[p, 2] + math.pi) % (2.0 * math.pi) - math.pi
            ft = dth / prior_std[2]
            logt[k] = lk - 0.5 * (fx * fx + fy * fy + ft * ft)
        top = logt.max()
        w = np.exp(logt - top)
        eta = w.sum()
        w /= eta
        mu = np.zeros(3)
        for k in range(K):
            for i in range(3):
                mu[i] += w[k] * offsets[k, i]
        cov = np.zeros((3, 3))
        for k in range(K):
            for i in range(3):
                for j in range(3):
                    cov[i, j] += w[k] * (offsets[k, i] - mu[i]) * (offsets[k, j] - mu[j])
        for i in range(3):
            cov[i, i] += 1e-12  # keeps the Cholesky factor defined when one sample dominates
        L = np.linalg.cholesky(cov)
        v = np.empty(3)
        for i in range(3):
            v[i] = mu[i]
            for j in range(i + 1):
                v[i] += L[i, j] * normals[p, j]
        out_poses[p, 0] = optima[p, 0] + co * v[0] - so * v[1]
        out_poses[p, 1] = optima[p, 1] + so * v[0] + co * v[1]
        out_poses[p, 2] = (optima[p, 2] + v[2] + math.pi) % (2.0 * math.pi) - math.pi
        out_logeta[p] = top + math.log(eta)


@njit(cache=True)
def along_terms(pool, occ, table, p, ox, oy, res, kernel, x, y, th, vx, vy, step, mount, ex, ey, end_w, reach):
    """The beams' point-distance term along ``(vx, vy)``, smoothed over one cell: ``(gradient, curvature, beams)``.

    For each beam the squared distance ``d2`` from its end point to the nearest map point in its
    window (as the score finds it) is taken at the pose moved by ``-step``, 0 and ``+step`` along
    the unit vector ``(vx, vy)``; a beam counts only when it has a map point at all three (a beam
    that finds one only when the pose moves back into the mapped area is no evidence). With
    ``step`` one cell, a beam along a wall parallel to the direction sees the same lattice of
    cells' mean hit points one period on, so its ripple cancels in both central differences
    and what remains is the pull of the beams on surfaces across the direction: the door jambs
    and box corners at a corridor's wall ends. ``end_w[j]`` weighs beam j's ``d2`` (``1 / (2 s^2)``
    for an end-point standard deviation ``s``), so the sums are the gradient and curvature of
    ``sum d2 / (2 s^2)``, a negative log-likelihood.

    ``reach`` ``(x, y, r)``: only beams ending within ``r`` of ``(x, y)`` count (r <= 0: all). The
    map ends where the last update's scan reached, and a wall cut off there looks like a wall
    end to a beam near the cut (moving the pose back gains it map points); with the last
    update's laser position and its usable range less a window, those beams are left out.
    """
    lx, ly, lc, ls = _laser_in_world(x, y, th, mount)
    inv = 1.0 / res
    pts = np.empty((1, (2 * kernel + 1) * (2 * kernel + 1), 2))
    grad = 0.0
    curv = 0.0
    used = 0
    d2 = np.empty(3)
    for j in range(ex.shape[0]):
        wx0 = lx + lc * ex[j] - ls * ey[j]
        wy0 = ly + ls * ex[j] + lc * ey[j]
        if reach[2] > 0.0 and (wx0 - reach[0]) ** 2 + (wy0 - reach[1]) ** 2 > reach[2] * reach[2]:
            continue
        for k in range(3):
            wx = wx0 + (k - 1) * step * vx
            wy = wy0 + (k - 1) * step * vy
            col = int(math.floor((wx - ox) * inv))
            row = int(math.floor((wy - oy) * inv))
            n = _window_points(pool, occ, table, p, -1, row, col, kernel, ox, oy, res, pts, 0)
            d2[k] = _nearest(pts, 0, n, wx, wy)
            if d2[k] < 0.0:
                break
        if d2[0] < 0.0 or d2[1] < 0.0 or d2[2] < 0.0:
            continue
        grad += end_w[j] * (d2[2] - d2[0]) / (2.0 * step)
        curv += end_w[j] * (d2[2] + d2[0] - 2.0 * d2[1]) / (step * step)
        used += 1
    return grad, curv, used


_END_SAMPLES = 6  # half-cell samples either side of a wall end's last hit: the search reaches 15 cm at 5 cm cells


@njit(cache=True)
def wall_end_terms(pool, occ, table, p, ox, oy, res, x, y, th, vx, vy, mount, ends, reach):
    """The scan's wall ends against the map's, along ``(vx, vy)``: ``(r J sum, J^2 sum, used)``.

    For each wall end of :func:`wall_ends` (laser frame) at robot pose ``(x, y, th)``: the map's
    wall is followed from the last hit ``a`` along the wall's direction ``w`` in half-cell steps,
    and its end estimated from the last occupied cell on it: the wall's hits fill that cell from
    where the line enters it to the end, so the end is twice their mean (along ``w``) less the
    entry, kept within the cell. The residual is that end's distance from ``a`` along ``w`` less
    the scan's (half the way to the beam that passed it): two-sided, unlike the end points'
    distances, where a pose behind the truth puts the wall end's beams on the mapped wall and
    costs nothing. Moving the pose by ``s`` along ``v`` moves ``a``, so ``J = -(v . w)``. A wall
    end whose mapped wall is not found near ``a``, or runs on to the search's end (a lost return
    in mid-wall, or a pose farther off than the search), is left out, as are those beyond
    ``reach`` (see :func:`along_terms`). A sixth column of ``ends``, when there is one, weighs
    each end's terms (its information relative to the caller's common one).
    """
    lx, ly, lc, ls = _laser_in_world(x, y, th, mount)
    inv = 1.0 / res
    half_step = 0.5 * res
    grad = 0.0
    curv = 0.0
    used = 0
    for e in range(ends.shape[0]):
        axw = lx + lc * ends[e, 0] - ls * ends[e, 1]
        ayw = ly + ls * ends[e, 0] + lc * ends[e, 1]
        if reach[2] > 0.0 and (axw - reach[0]) ** 2 + (ayw - reach[1]) ** 2 > reach[2] * reach[2]:
            continue
        wxw = lc * ends[e, 2] - ls * ends[e, 3]
        wyw = ls * ends[e, 2] + lc * ends[e, 3]
        # the occupied sample nearest a (behind first), then the run on from it along w
        start = -_END_SAMPLES - 1
        for k in range(_END_SAMPLES + 1):
            for kk in (-k, k):
                px = axw + kk * half_step * wxw
                py = ayw + kk * half_step * wyw
                col = int(math.floor((px - ox) * inv))
                row = int(math.floor((py - oy) * inv))
                if _occupied(occ, cell_tile(table, p, row, col), row, col):
                    start = kk
                    break
            if start >= -_END_SAMPLES:
                break
        if start < -_END_SAMPLES:
            continue
        last = start
        while last < _END_SAMPLES:
            px = axw + (last + 1) * half_step * wxw
            py = ayw + (last + 1) * half_step * wyw
            col = int(math.floor((px - ox) * inv))
            row = int(math.floor((py - oy) * inv))
            if not _occupied(occ, cell_tile(table, p, row, col), row, col):
                break
            last += 1
        if last >= _END_SAMPLES:
            continue  # the mapped wall runs on past the search
        px = axw + last * half_step * wxw
        py = ayw + last * half_step * wyw
        col = int(math.floor((px - ox) * inv))
        row = int(math.floor((py - oy) * inv))
        t = cell_tile(table, p, row, col)
        a_ = row & _MASK
        b_ = col & _MASK
        hits = pool[t, a_, b_, HITS]
        if hits <= 0.0:
            continue
        cx = ox + (col + 0.5) * res
        cy = oy + (row + 0.5) * res
        mean = (cx + pool[t, a_, b_, SUM_X] / hits - axw) * wxw + (cy + pool[t, a_, b_, SUM_Y] / hits - ayw) * wyw
        # where the line a + l w enters and leaves the cell (slab intersection), in l
        l_in = -1e9
        l_out = 1e9
        for dim in range(2):
            o = (axw - (cx - 0.5 * res)) if dim == 0 else (ayw - (cy - 0.5 * res))
            dv = wxw if dim == 0 else wyw
            if abs(dv) < 1e-12:
                continue
            t1 = -o / dv
            t2 = (res - o) / dv
            lo = min(t1, t2)
            hi = max(t1, t2)
            l_in = max(l_in, lo)
            l_out = min(l_out, hi)
        end = 2.0 * mean - l_in
        if end < mean:
            end = mean
        elif end > l_out:
            end = l_out
        resid = end - ends[e, 4]
        jac = -(vx * wxw + vy * wyw)
        grad += resid * jac
        curv += jac * jac
        used += 1
    return grad, curv, used


@njit(cache=True, inline="always")
def _wall_end_step(pool, occ, table, p, ox, oy, res, kernel, x, y, th, vx, vy, step, mount, ex, ey, end_w, reach,
                   prior, iterations, ends, end_info):
    """From a held pose, how far along ``(vx, vy)`` the beams' smoothed distance term and the prior put it.

    Newton steps (at most one cell each) on the data term plus ``prior s^2 / 2``, ``s`` the offset
    from the held pose (which is the odometry's along the direction, so the prior is centred
    there); stops when the curvature is not positive. The data term: with ``end_info`` > 0 the
    wall ends ``ends`` (:func:`wall_end_terms`, each residual squared times ``end_info / 2``),
    else the end points' distances (:func:`along_terms`, weights ``end_w``: one-sided at a wall
    end, kept for measuring, benchmarks/studies/measure_gmapping_wall_ends.py).
    """
    off = 0.0
    for _ in range(iterations):
        if end_info > 0.0:  # the wall ends, two-sided
            g, h, used = wall_end_terms(pool, occ, table, p, ox, oy, res, x + off * vx, y + off * vy, th, vx, vy,
                                        mount, ends, reach)
            g *= end_info
            h *= end_info
        else:  # the end points' distances
            g, h, used = along_terms(pool, occ, table, p, ox, oy, res, kernel, x + off * vx, y + off * vy, th, vx,
                                     vy, step, mount, ex, ey, end_w, reach)
        g += prior * off
        h += prior
        if used == 0 or h <= 0.0:
            break
        move = -g / h
        if move > step:
            move = step
        elif move < -step:
            move = -step
        off += move
        if abs(move) < 1e-4:
            break
    return off


@njit(cache=True, inline="always")
def _hold_one(pool, occ, table, p, ox, oy, res, kernel, start, x, y, th, mount, ex, ey, div_s,
              div_l, step, ratio, end_w, ends, end_info, reach, prior_info):
    """:func:`hold_flat_direction` for one pose: ``(x, y, flat)``, ``flat`` 0 (kept), 1 (one axis held) or 2 (both)."""
    s0 = _evaluate(pool, occ, table, p, ox, oy, res, kernel, x, y, th, mount, ex, ey, div_s, div_l,
                   False)[0]
    sxp = _evaluate(pool, occ, table, p, ox, oy, res, kernel, x + step, y, th, mount, ex, ey,
                    div_s, div_l, False)[0]
    sxm = _evaluate(pool, occ, table, p, ox, oy, res, kernel, x - step, y, th, mount, ex, ey,
                    div_s, div_l, False)[0]
    syp = _evaluate(pool, occ, table, p, ox, oy, res, kernel, x, y + step, th, mount, ex, ey,
                    div_s, div_l, False)[0]
    sym = _evaluate(pool, occ, table, p, ox, oy, res, kernel, x, y - step, th, mount, ex, ey,
                    div_s, div_l, False)[0]
    spp = _evaluate(pool, occ, table, p, ox, oy, res, kernel, x + step, y + step, th, mount, ex, ey,
                    div_s, div_l, False)[0]
    smm = _evaluate(pool, occ, table, p, ox, oy, res, kernel, x - step, y - step, th, mount, ex, ey,
                    div_s, div_l, False)[0]
    spm = _evaluate(pool, occ, table, p, ox, oy, res, kernel, x + step, y - step, th, mount, ex, ey,
                    div_s, div_l, False)[0]
    smp = _evaluate(pool, occ, table, p, ox, oy, res, kernel, x - step, y + step, th, mount, ex, ey,
                    div_s, div_l, False)[0]
    h2 = step * step
    # the score's information (minus its curvature) in x, y by central differences: a slope cancels
    a = -(sxp + sxm - 2.0 * s0) / h2
    c = -(syp + sym - 2.0 * s0) / h2
    b = -(spp + smm - spm - smp) / (4.0 * h2)
    mean = 0.5 * (a + c)
    rad = math.sqrt(0.25 * (a - c) * (a - c) + b * b)
    big, small = mean + rad, mean - rad
    if big <= 0.0:  # no curvature at all: the scan fixes no translation, the odometry's is kept
        return start[0], start[1], 2
    if small >= ratio * big:
        return x, y, 0
    # the eigenvector of the smallest eigenvalue: the direction the scan does not constrain
    if abs(b) > 1e-300:
        vx, vy = small - c, b
    elif a <= c:
        vx, vy = 1.0, 0.0
    else:
        vx, vy = 0.0, 1.0
    n = math.hypot(vx, vy)
    vx, vy = vx / n, vy / n
    along = (x - start[0]) * vx + (y - start[1]) * vy  # how far the climb moved along it: undone
    hx, hy = x - along * vx, y - along * vy
    if end_w.shape[0] > 0 or end_info > 0.0:  # flat_sigma: the wall ends' pull along it, against the prior
        c0, s0 = math.cos(start[2]), math.sin(start[2])
        vf = c0 * vx + s0 * vy  # the direction in the start's frame (the prior is forward / left)
        vl = -s0 * vx + c0 * vy
        prior = prior_info[0] * vf * vf + prior_info[1] * vl * vl
        # a window two cells wider than the score's: the wall end's beams stay matched one cell either side of a
        # pose a few centimetres off (the walls' ripple cancels in any window: their lattice is the same one cell on)
        off = _wall_end_step(pool, occ, table, p, ox, oy, res, kernel + 2, hx, hy, th, vx, vy, step, mount, ex, ey,
                             end_w, reach, prior, 4, ends, end_info)
        hx += off * vx
        hy += off * vy
    return hx, hy, 1


@njit(cache=True, parallel=True)
def hold_flat_direction(pool, occ, table, ox, oy, res, kernel, which, starts, poses, ok, mount, ex, ey,
                        div_s, div_l, step, ratio, end_w, ends, end_info, reach, prior_info, out_like,
                        out_flat):
    """Undo a climb's move along the direction its score does not constrain (not in GMapping).

    For each pose ``poses[i]`` matched on map ``which[i]`` from ``starts[i]``
    (``ok[i]`` False: left alone), the score's 2 x 2 translation information at the
    pose is taken by central differences of ``step`` (m; one cell: the cells' ripple
    along a wall is periodic in it); a linear slope, such as beams that gain map
    points by moving back into the mapped area, cancels in them. When its smaller
    eigenvalue is below ``ratio`` times the larger (a corridor whose ends are out of
    the laser's reach), the pose's component along that eigenvector is set back to
    the start's, the odometry's: the climb only slid there, on the lattice's ripple
    or toward the edge of the map. With no curvature at all the start's translation
    is kept. The heading stays the climb's. ``poses`` is changed in place,
    ``out_like[i]`` is the log-likelihood at the pose kept (as ``match_particles``
    computes it) and ``out_flat[i]`` 0 (unchanged), 1 (one direction held) or 2 (both).

    ``end_w`` (per beam, empty: off; gmapping ``flat_sigma``): a held pose is then not left at
    the start's along the flat direction but moved to the minimum of the beams' one-cell-smoothed
    distance term (:func:`along_terms`, weights ``end_w``) plus the odometry prior, whose
    information ``prior_info[i]`` (forward, left, heading in the start's frame; 1/m^2) is the
    motion model's: the few beams on wall ends, whose pull the whole score's curvature ratio
    cannot tell from the ripple, place the pose along the corridor as far as they say.
    ``end_info`` > 0 (1/m^2): the scan's wall ends ``ends`` (:func:`wall_ends`) matched to the
    map's (:func:`wall_end_terms`), each with this information, instead of the end points'
    distances. ``reach[i]``: see :func:`along_terms`.
    """
    for i in prange(poses.shape[0]):
        out_flat[i] = 0
        if not ok[i]:
            continue
        p = which[i]
        x, y, flat = _hold_one(pool, occ, table, p, ox, oy, res, kernel, starts[i], poses[i, 0],
                               poses[i, 1], poses[i, 2], mount, ex, ey, div_s, div_l, step, ratio, end_w,
                               ends, end_info, reach[i], prior_info[i])
        out_flat[i] = flat
        if flat:
            poses[i, 0], poses[i, 1] = x, y
            out_like[i] = _evaluate(pool, occ, table, p, ox, oy, res, kernel, x, y, poses[i, 2], mount,
                                    ex, ey, div_s, div_l, True)[1]
