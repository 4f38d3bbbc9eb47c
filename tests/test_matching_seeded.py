"""The seeded search (CorrelativeMatcher.match_near) is the whole search's match, or gives up.

karto's sequential matches search first only the part of the coarse lattice near the last
scan's pose plus the odometry since it (``seeded_search_window``). Where that part holds the
whole surface's best and its covariance band, the match must be :meth:`match`'s bit for bit;
where a better pose may lie outside it (the band runs into its edge, a corridor) it must say so.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from slam2d.matching.correlative import CorrelativeMatcher
from tests.test_matching_fused import _grid, _scene


def _same(a, b):
    return (np.array_equal(a.pose, b.pose) and np.array_equal(a.covariance, b.covariance)
            and a.response == b.response and a.raw_response == b.raw_response
            and a.heading_variance_coarse == b.heading_variance_coarse)


@pytest.mark.parametrize("penalize", [True, False])
def test_seeded_part_gives_the_whole_search_or_none(penalize):
    kept = 0
    for seed in range(12):
        world, q, prior = _scene(seed)
        m = CorrelativeMatcher()
        m.fine_recentre = 3
        grid = _grid(m, world, q, prior)
        full = m.match(None, None, q, prior, grid=grid, penalize=penalize)
        rng = np.random.default_rng(seed)
        for _ in range(3):
            # Seeds a cell or two and a degree from the answer, as the last scan's pose plus odometry is.
            s = full.pose + np.array([rng.uniform(-0.03, 0.03), rng.uniform(-0.03, 0.03), rng.uniform(-0.02, 0.02)])
            near = m.match_near(q, prior, s, grid, half_steps=5, angle_steps=3, penalize=penalize)
            if near is None:
                continue
            kept += 1
            assert _same(near, full), (seed, near, full)
    assert kept >= 12  # the part does stand for the window in most scenes


def test_corridor_gives_up():
    """Along a corridor the good responses run through the part's edge: the whole window must be searched."""
    world, q, prior = _scene(0)  # seeds 0, 3, 6, 9 are the corridor
    m = CorrelativeMatcher()
    grid = _grid(m, world, q, prior)
    full = m.match(None, None, q, prior, grid=grid)
    assert m.match_near(q, prior, full.pose, grid, half_steps=3, angle_steps=3) is None


@pytest.mark.parametrize("seed", [1, 2, 4, 5])
def test_a_seed_off_the_answer_gives_up_or_responds_worse(seed):
    """A seed 10 deg off puts the answer's heading outside the part: it gives up, or its best fits
    clearly worse (which the front end's response-drop test then rejects)."""
    world, q, prior = _scene(seed)
    m = CorrelativeMatcher()
    grid = _grid(m, world, q, prior)
    full = m.match(None, None, q, prior, grid=grid)
    off = full.pose + np.array([0.0, 0.0, math.radians(10.0)])
    near = m.match_near(q, prior, off, grid, half_steps=5, angle_steps=2)
    assert near is None or near.raw_response < full.raw_response - 0.05, (near, full)


def test_part_is_clipped_to_the_window():
    """A seed outside the window searches the window's edge part; a part as big as the window is the whole search."""
    world, q, prior = _scene(1)
    m = CorrelativeMatcher()
    grid = _grid(m, world, q, prior)
    full = m.match(None, None, q, prior, grid=grid)
    whole = m.match_near(q, prior, prior + np.array([5.0, -5.0, 3.0]), grid, half_steps=100, angle_steps=100)
    assert whole is not None and _same(whole, full)
    assert m.match_near(np.zeros((0, 2)), prior, prior, grid, half_steps=5, angle_steps=3) is None
