"""The hill climb's shortcuts (per-beam window cache, remembered poses) give the plain evaluation's numbers, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from slam2d.grids.tiled import TiledMaps
from slam2d.matching.hill_climb import _SLOTS, BeamSet, _evaluate, _score_cached, match_one, match_particles


def _cluttered_maps(n: int) -> tuple[TiledMaps, np.ndarray, np.ndarray]:
    """Maps of a room with pillars, seen from a few poses per map, spanning several tiles (windows cross tile edges)."""
    rng = np.random.default_rng(7)
    angles = np.linspace(-np.pi, np.pi, 540, endpoint=False)
    pillars = rng.uniform(-3.0, 3.0, (12, 2))

    def ranges_from(pose):
        a = angles + pose[2]
        c, s = np.cos(a), np.sin(a)
        with np.errstate(divide="ignore", invalid="ignore"):
            tx = np.where(c > 0, (4.1 - pose[0]) / c, np.where(c < 0, (-3.9 - pose[0]) / c, np.inf))
            ty = np.where(s > 0, (3.3 - pose[1]) / s, np.where(s < 0, (-3.7 - pose[1]) / s, np.inf))
        r = np.minimum(tx, ty)
        for px, py in pillars:  # 0.2 m radius discs
            dx, dy = px - pose[0], py - pose[1]
            along = dx * c + dy * s
            off2 = dx * dx + dy * dy - along * along
            hit = (along > 0) & (off2 < 0.04)
            r = np.where(hit, np.minimum(r, along - np.sqrt(np.maximum(0.04 - off2, 0.0))), r)
        return r + rng.normal(0.0, 0.01, r.shape)

    maps = TiledMaps(n, 0.05, (-5, -5, 5, 5))
    for p in range(n):
        for _ in range(4):
            pose = np.array([rng.normal(0, 0.3), rng.normal(0, 0.3), rng.normal(0, 0.05)])
            maps.register(np.array([p]), pose[None, :], ranges_from(pose)[None, :], angles, max_range=20.0,
                          usable_range=20.0, generate_map=False)
    ranges = ranges_from(np.zeros(3))
    return maps, ranges, angles


@pytest.mark.parametrize("kernel", [0, 1, 2])
def test_cached_score_equals_the_plain_evaluation_bit_for_bit(kernel):
    """A random walk of poses (steps from 0.1 mm to 10 cm, so beams keep or change cells): the same score exactly."""
    maps, ranges, angles = _cluttered_maps(2)
    beams = BeamSet(ranges, angles, np.isfinite(ranges), np.full(ranges.shape, 0.05), np.full(ranges.shape, 0.075))
    mount = np.array([0.1, 0.02, 0.01])
    rng = np.random.default_rng(kernel)
    b = len(beams)
    key = np.full((b * _SLOTS, 2), np.iinfo(np.int64).min, dtype=np.int64)
    count = np.zeros(b * _SLOTS, dtype=np.int64)
    pts = np.empty((b * _SLOTS, (2 * kernel + 1) ** 2, 2))
    pose = np.zeros(3)
    hits = 0
    for i in range(600):
        scale = 10.0 ** rng.uniform(-4, -1)
        pose = pose + rng.normal(0.0, scale, 3) * np.array([1.0, 1.0, 0.5])
        p = i % 2
        plain = _evaluate(maps.pool, maps.occ, maps.table, p, maps.origin[0], maps.origin[1], maps.resolution,
                          kernel, pose[0], pose[1], pose[2], mount, beams.ex, beams.ey,
                          beams.div_score, beams.div_like, False)[0]
        if p == 0:  # one cache follows map 0's walk; map 1 gets a fresh cache each time
            cached = _score_cached(maps.pool, maps.occ, maps.table, p, maps.origin[0], maps.origin[1],
                                   maps.resolution, kernel, pose[0], pose[1], pose[2], mount, beams.ex, beams.ey,
                                   beams.div_score, key, count, pts)
        else:
            fresh = np.full_like(key, np.iinfo(np.int64).min)
            cached = _score_cached(maps.pool, maps.occ, maps.table, p, maps.origin[0], maps.origin[1],
                                   maps.resolution, kernel, pose[0], pose[1], pose[2], mount, beams.ex, beams.ey,
                                   beams.div_score, fresh, np.zeros_like(count), np.empty_like(pts))
        assert cached == plain, (i, cached, plain)
        hits += plain > 0.0
    assert hits > 300  # the walk stays where the beams match the map


def test_match_one_climbs_as_match_particles_does():
    """The tracking climb (match_one) and the particles' (match_particles) share the climb: same poses and scores."""
    maps, ranges, angles = _cluttered_maps(3)
    beams = BeamSet(ranges, angles, np.isfinite(ranges), np.full(ranges.shape, 0.05), np.full(ranges.shape, 0.075))
    start = np.array([[0.08, -0.05, 0.04], [-0.06, 0.07, -0.03], [0.01, 0.0, 0.0]])
    out, score, like, ok = np.empty((3, 3)), np.empty(3), np.empty(3), np.empty(3, bool)
    args = (maps.pool, maps.occ, maps.table, maps.origin[0], maps.origin[1], 0.05, 1)
    match_particles(*args, start, np.zeros(3), beams.ex, beams.ey, beams.div_score,
                    beams.div_like, 0.05, 0.05, 5, 0.0, 0.0, np.zeros((3, 3)), 0.0, out, score, like, ok)
    assert ok.all() and np.all(np.hypot(out[:, 0], out[:, 1]) < 0.3)
    for p in range(3):
        x, y, th, sc, good = match_one(maps.pool, maps.occ, maps.table, p, *args[3:], start[p], np.zeros(3), beams.ex,
                                       beams.ey, beams.div_score, beams.div_like, 0.05, 0.05, 5,
                                       0.0, 0.0, np.zeros(3), 0.0)
        assert good and (x, y, th, sc) == (out[p, 0], out[p, 1], out[p, 2], score[p])
