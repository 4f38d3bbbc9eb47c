"""The matcher's threaded kernels give the serial kernels' results bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from slam2d.matching.correlative import (
    _score_all,
    _score_all_parallel,
    smear_in_row_bands,
    smear_in_row_order,
)


@pytest.mark.parametrize("step", [1, 2, 3])
def test_parallel_exhaustive_search_equals_the_serial_one(step):
    rng = np.random.default_rng(step)
    grid = rng.integers(0, 256, (300, 280)).astype(np.uint8)
    # Cells inside, across the edges and wholly outside the grid.
    rows = rng.integers(-60, 340, (21, 250))
    cols = rng.integers(-60, 320, (21, 250))
    serial = _score_all(grid, rows, cols, 17, step)
    assert serial.max() > 0
    assert np.array_equal(_score_all_parallel(grid, rows, cols, 17, step), serial)


@pytest.mark.parametrize("bands", [1, 2, 3, 8])
@pytest.mark.parametrize("skip_drawn", [False, True])
def test_smear_in_row_bands_draws_the_serial_grid(bands, skip_drawn):
    rng = np.random.default_rng(bands)
    n = 4000
    # Points inside and beyond every edge, clustered (many in one row) and spread.
    px = np.concatenate([rng.uniform(-0.3, 6.3, n), np.full(200, 2.0)])
    py = np.concatenate([rng.uniform(-0.3, 4.3, n), rng.uniform(1.0, 1.005, 200)])
    sigma = np.full(px.size, 0.03)
    if not skip_drawn:  # mixed sigmas (a sensor model) are never skipped
        sigma[::5] = 0.05
    serial = np.zeros((400, 600), np.uint8)
    banded = serial.copy()
    # Drawn in two goes, as a grid cache extends a grid.
    for part in (slice(0, 3000), slice(3000, None)):
        smear_in_row_order(serial, 0.0, 0.0, 0.01, px[part], py[part], sigma[part], skip_drawn)
        smear_in_row_bands(banded, 0.0, 0.0, 0.01, px[part], py[part], sigma[part], skip_drawn, bands)
    assert serial.max() == 255
    assert np.array_equal(banded, serial)


def test_smear_in_row_bands_of_nothing_draws_nothing():
    grid = np.zeros((50, 50), np.uint8)
    smear_in_row_bands(grid, 0.0, 0.0, 0.01, np.zeros(0), np.zeros(0), np.zeros(0), False, 2)
    assert not grid.any()


def test_threads_work_in_a_forked_child():
    """A process forked after the worker threads started gets its own (a stale pool would hang)."""
    import multiprocessing

    from slam2d.matching import correlative

    rng = np.random.default_rng(0)
    grid = rng.integers(0, 256, (200, 200)).astype(np.uint8)
    rows = rng.integers(0, 160, (8, 100))
    cols = rng.integers(0, 160, (8, 100))
    serial = _score_all(grid, rows, cols, 17, 2)
    if correlative._THREADS < 2:
        pytest.skip("threads are off (SLAM2D_THREADS=1 or one CPU)")
    # The parent's worker thread runs before the fork.
    assert np.array_equal(_score_all_parallel(grid, rows, cols, 17, 2), serial)
    ctx = multiprocessing.get_context("fork")
    with ctx.Pool(1) as pool:
        got = pool.apply_async(_score_all_parallel, (grid, rows, cols, 17, 2)).get(timeout=120)
    assert np.array_equal(got, serial)
