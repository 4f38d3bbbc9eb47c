"""The matcher's threaded kernels give the serial kernels' results bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from slam2d.matching.correlative_grid import _split, smear_in_row_bands, smear_in_row_order
from slam2d.matching.correlative_search import _score_poses


def _search_sums(threaded, grid, q, half, step):
    """The exhaustive search's sums over 21 angles, serially or shared among threads as the matcher does."""
    angles = np.linspace(-0.35, 0.35, 21)
    sums = np.empty((angles.size, 2 * half + 1, 2 * half + 1))
    args = (grid, -0.5, -0.4, 0.01, q, 0.9, 1.1, 0.2, angles, half, step)
    if threaded:
        _split(lambda a0, a1: _score_poses(*args, a0, a1, sums), angles.size)
    else:
        _score_poses(*args, 0, angles.size, sums)
    return sums


@pytest.mark.parametrize("step", [1, 2, 3])
def test_parallel_exhaustive_search_equals_the_serial_one(step):
    rng = np.random.default_rng(step)
    grid = rng.integers(0, 256, (300, 280)).astype(np.uint8)
    # Points whose cells fall inside, across the edges and wholly outside the grid.
    q = rng.uniform(-1.5, 4.0, (250, 2))
    serial = _search_sums(False, grid, q, 8, step)
    assert serial.max() > 0
    assert np.array_equal(_search_sums(True, grid, q, 8, step), serial)


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

    from slam2d.matching import correlative_grid

    rng = np.random.default_rng(0)
    grid = rng.integers(0, 256, (200, 200)).astype(np.uint8)
    q = rng.uniform(-0.5, 1.5, (100, 2))
    serial = _search_sums(False, grid, q, 8, 2)
    assert serial.max() > 0
    if correlative_grid._THREADS < 2:
        pytest.skip("threads are off (SLAM2D_THREADS=1 or one CPU)")
    # The parent's worker thread runs before the fork.
    assert np.array_equal(_search_sums(True, grid, q, 8, 2), serial)
    ctx = multiprocessing.get_context("fork")
    with ctx.Pool(1) as pool:
        got = pool.apply_async(_search_sums, (True, grid, q, 8, 2)).get(timeout=120)
    assert np.array_equal(got, serial)


def test_shared_pieces_are_each_run_once_whichever_thread_takes_them():
    """_split with more pieces than threads: every piece runs once, the pieces cover [0, n) without overlap."""
    import threading

    done = []
    lock = threading.Lock()

    def work(a, b):
        with lock:
            done.append((a, b))

    _split(work, 20, pieces=7, threads=2)
    assert sorted(done) == [((k * 20) // 7, ((k + 1) * 20) // 7) for k in range(7)]
    done.clear()
    _split(work, 3, pieces=8, threads=2)  # never more pieces than items
    assert sorted(done) == [(0, 1), (1, 2), (2, 3)]


@pytest.mark.parametrize("bands", [2, 6, 9])
def test_bands_taken_in_turn_by_two_threads_draw_the_serial_grid(bands):
    rng = np.random.default_rng(10 + bands)
    px = rng.uniform(-0.3, 6.3, 5000)
    py = rng.uniform(-0.3, 4.3, 5000)
    sigma = rng.uniform(0.005, 0.1, px.size)
    serial = np.zeros((400, 600), np.uint8)
    banded = serial.copy()
    smear_in_row_order(serial, 0.0, 0.0, 0.01, px, py, sigma, False)
    smear_in_row_bands(banded, 0.0, 0.0, 0.01, px, py, sigma, False, bands, 2)
    assert serial.max() == 255
    assert np.array_equal(banded, serial)


def _serial_branch_and_bound(grid, rows, cols, order, flat, n_blocks, block, n_steps, step, band, norm, floor):
    """The one-thread branch and bound, written plainly: blocks in order until one's bound falls below the best less the band."""
    from slam2d.matching.correlative_search import _score_window

    out = np.full((rows.shape[0], n_steps, n_steps), -1.0)
    buf = np.zeros((block, block), np.int32)
    best, lookups = floor, 0
    for f in order:
        if flat[f] / norm < best - band:
            break
        a, rem = divmod(int(f), n_blocks * n_blocks)
        i0, j0 = (rem // n_blocks) * block, (rem % n_blocks) * block
        ni, nj = min(block, n_steps - i0), min(block, n_steps - j0)
        _score_window(grid, rows, cols, a, i0, j0, ni, nj, step, buf)
        out[a, i0:i0 + ni, j0:j0 + nj] = buf[:ni, :nj]
        best = max(best, float(buf[:ni, :nj].max()) / norm)
        lookups += ni * nj * rows.shape[1]
    return out, lookups


@pytest.mark.parametrize("seed", range(4))
def test_branch_and_bound_in_strides_scores_the_serial_blocks(seed):
    """Blocks scored in 1, 2 or 3 strides (threads), then trimmed: the serial search's sums and lookups exactly."""
    from slam2d.matching.correlative_search import (_block_bounds, _max_pool, _query_cells, _score_blocks_stride,
                                                    _serial_blocks)

    rng = np.random.default_rng(seed)
    half, step, block, res = 20, 2, 8, 0.05
    # The query's points drawn into a noisy grid at one offset: one clear peak, so the bound prunes.
    q = rng.uniform(-2.0, 2.0, (60, 2))
    grid = rng.integers(0, 60, (260, 260)).astype(np.uint8)
    true = np.array([6.5, 6.5]) + rng.integers(-half, half + 1, 2) * step * res
    cells = np.floor((q + true) / res).astype(int)
    grid[cells[:, 1], cells[:, 0]] = 255
    angles = np.linspace(-0.2, 0.2, 5)
    n_steps = 2 * half + 1
    rows, cols = _query_cells(q[:, 0], q[:, 1], angles, 6.5, 6.5, 0.0, 0.0, 0.0, res, -half * step)
    n_blocks = (n_steps + block - 1) // block
    width = (block - 1) * step + 1
    flat = _block_bounds(_max_pool(grid, width), rows, cols, n_blocks, block * step, width).reshape(-1)
    order = np.argsort(-flat, kind="stable")
    norm, band = 60 * 255.0, 0.1 + 1e-9
    extras = []
    for floor in (-1.0, 0.3):
        want, want_lookups = _serial_branch_and_bound(grid, rows, cols, order, flat, n_blocks, block, n_steps, step,
                                                      band, norm, floor)
        scored = int((want >= 0).sum())
        assert 0 < scored < want.size // 2, scored  # it pruned most poses, and scored some
        for strides in (1, 2, 3):
            sums = np.full_like(want, -1.0)
            for s in range(strides):
                _score_blocks_stride(grid, rows, cols, order, flat, n_blocks, block, n_steps, step, band, norm, floor,
                                     s, strides, sums)
            extra = int((sums >= 0).sum()) - scored  # blocks scored beyond the serial search's, trimmed below
            assert extra >= 0
            extras.append(extra)
            lookups = _serial_blocks(sums, rows.shape[1], order, flat, n_blocks, block, n_steps, band, norm, floor)
            np.testing.assert_array_equal(sums, want)
            assert lookups == want_lookups
    assert max(extras) > 0  # the trim had something to do
