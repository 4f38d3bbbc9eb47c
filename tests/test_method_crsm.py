"""crsm: the map update profile, critical rays, the fitness, the RRHC search, the method."""

from __future__ import annotations

import math

import numpy as np
import pytest

from slam2d.cli import main
from slam2d.core import se2
from slam2d.eval.trajectory_metrics import align_se2
from slam2d.core import make_scan
from slam2d.errors import InputError
from slam2d.grids.crsm_map import GAIN_TABLE, UNKNOWN, CrsmMap, first_beam_per_cell, marked_endpoints
from slam2d.matching.critical_rays import critical_rays
from slam2d.matching.random_numbers import new_state, next_u64, randint, skip
from slam2d.matching.rrhc import (
    HEADING_STEP, _cells_at, _fitness, _restart_table, near_known, paired_gain, refine_offset, rrhc_search,
)
from slam2d.methods import get_method
from slam2d.methods.crsm import Crsm, CrsmParams, ray_points
from slam2d.params import from_mapping
from tests._room import frame, room_scan
from tests.conftest import run_ate

# The URG-04LX's beams over 240 degrees: at the 2 cm cells CRSM uses, coarser scans leave gaps between beams.
URG_BEAMS = 682


def test_one_beam_update_profile():
    """Crossed cells rise, the cell before the end falls on balance, the end cell falls, beyond stays unknown."""
    m = CrsmMap(0.1)
    m.ensure_contains(-1, -1, 3, 1, margin=0)
    g = 0.2 * 40  # mean density 0.2 (the clamp's top) x density 40 = 8 levels on an unknown cell
    m.update(np.array([0.05, 0.05, 0.0]), np.array([1.0]), np.array([0.0]), np.array([True]),
             mean_density=0.2, density=40.0, obstacle_density=3.0, margin=0)
    ox, oy = m.origin
    row = m.values[int((0.05 - oy) / 0.1)]
    col0 = int((0.05 - ox) / 0.1)
    r = 10  # range in cells
    assert all(row[col0 + k] == 127 + int(g) for k in range(1, r - 1))
    after_rise = 127 + int(g)
    assert row[col0 + r - 1] == int(after_rise - g * 3.0)  # both, with the damping of the cell before the scan
    assert row[col0 + r] == int(127 - g * 3.0)
    assert row[col0 + r + 1] == UNKNOWN and row[col0 + r + 2] == UNKNOWN and row[col0 + r + 3] == UNKNOWN
    assert row[col0] == UNKNOWN  # the walk starts one cell out
    # a sure cell moves less: the certainty damping
    assert GAIN_TABLE[127] == 1.0 and GAIN_TABLE[250] < 0.1 and GAIN_TABLE[5] < 0.1


def test_occupancy_uses_the_originals_thresholds():
    m = CrsmMap(0.1)
    m.ensure_contains(0, 0, 0.25, 0.05, margin=0)
    m.values[0, :3] = [200, 127, 40]
    assert list(m.occupancy()[0, :3]) == [0, -1, 100]


def test_a_map_cropped_to_its_written_cells_keeps_every_cell_where_it_was():
    m = CrsmMap(0.1)
    m.ensure_contains(-5, -5, 5, 5, margin=0)
    m.values[40, 30], m.values[60, 70] = 200, 40  # two written cells inside a mostly unwritten map
    cropped = m.crop_to_observed()
    assert cropped.shape == (21 + 2, 41 + 2)  # the written box plus one unknown cell around it
    for grid in (m, cropped):  # the same world position for the same value, in both
        ox, oy = grid.origin
        assert grid.values[round((m.origin[1] + 40 * 0.1 - oy) / 0.1), round((m.origin[0] + 30 * 0.1 - ox) / 0.1)] == 200
    assert (cropped.occupancy() == 0).sum() == 1 and (cropped.occupancy() == 100).sum() == 1
    assert cropped.crop_to_observed() is cropped  # already cropped: no copy
    assert m.shape == (101, 101) and cropped.observed.sum() == 2
    grid = m.to_occupancy_grid()  # the float grid every method hands out: the same cells, known and occupied
    assert grid.shape == cropped.shape and grid.origin == pytest.approx(cropped.origin)
    assert np.array_equal(grid.observed, cropped.observed) and np.array_equal(grid.occupied(), cropped.occupied())
    # a written cell on the edge: the margin beyond the edge is unknown
    m.values[0, 0] = 40
    edge = m.crop_to_observed()
    assert edge.shape == (61 + 2, 71 + 2) and edge.values[0, 0] == UNKNOWN and edge.values[1, 1] == 40
    empty = CrsmMap(0.1)
    assert empty.crop_to_observed().shape == (0, 0)


def test_critical_rays_keep_discontinuities_and_adapt_their_count():
    d = np.full(300, 2.0) + 0.01 * np.sin(np.arange(300))  # texture for the density walk
    d[100:150] = 4.0  # two jumps of 2 m
    d[200:210] = 0.0  # no return
    sel, param, mean_density, picked = critical_rays(d, 5.6, 100.0, 0.3, 40)
    s = set(sel.tolist())
    assert {99, 100, 149, 150} <= s  # both rays of each discontinuity
    assert not s & set(range(200, 210))  # no-return rays never matched
    assert np.all(np.diff(sel)[np.diff(sel) > 0] <= 25 + 10)  # gaps bisected (the hole at 200-209 aside)
    assert mean_density == pytest.approx(np.mean(np.abs(np.diff(d))))
    # the walk's threshold factor moves towards the desired count, scan after scan
    counts = []
    p = 100.0
    for _ in range(30):
        sel, p, _, picked = critical_rays(d, 5.6, p, 0.3, 40)
        counts.append(picked)
    assert 0.75 * 40 <= counts[-1] <= 1.25 * 40 or abs(counts[-1] - 40) < abs(counts[0] - 40)


def _room_map(scans=5):
    m = CrsmMap(0.02)
    m.ensure_contains(-5, -5, 5, 5, margin=0)
    scan = room_scan(np.zeros(3), n=URG_BEAMS)
    d = np.nan_to_num(scan.ranges)
    for _ in range(scans):
        m.update(np.zeros(3), d, scan.angles, d > 0, mean_density=0.2, density=40.0, obstacle_density=3.0)
    return m, scan


def _rays(scan):
    d = np.nan_to_num(scan.ranges)
    sel, *_ = critical_rays(d, scan.range_max, 100.0, 0.3, 40)
    pts = ray_points(scan, d, sel, 0.02)
    return np.ascontiguousarray(pts[:, 0]), np.ascontiguousarray(pts[:, 1])


def test_fitness_of_rays_on_walls_is_higher_than_off():
    m, scan = _room_map()
    qx, qy = _rays(scan)
    ox, oy = m.origin
    inv = 1.0 / m.resolution
    n = len(qx)
    cache_r = np.empty((1, n), np.int64)
    cache_c = np.empty((1, n), np.int64)
    r_k, c_k = _cells_at(0, cache_r, cache_c, np.zeros(1, np.bool_), 0, -ox * inv, -oy * inv, 0.0, qx * inv, qy * inv,
                         np.empty(n, np.int64), np.empty(n, np.int64))
    on = _fitness(m.values, r_k, c_k, 0, 0)
    off = _fitness(m.values, r_k, c_k, 4, -3)
    assert on > 1.3 * off > 0


def test_paired_gain_needs_more_evidence_from_fewer_beams():
    """The paired z over the beams: positive for the true pose against a turned one, 0 against itself, and with the
    same beams thinned out the same mean gain is less significant."""
    m, scan = _room_map()
    d = np.nan_to_num(scan.ranges)
    every = np.flatnonzero(d > 0)
    pts = ray_points(scan, d, every, 0.02)
    qx, qy = np.ascontiguousarray(pts[:, 0]), np.ascontiguousarray(pts[:, 1])
    ox, oy = m.origin
    turn = math.radians(4)
    gain, z, n = paired_gain(m.values, ox, oy, 0.02, qx, qy, 0.0, 0.0, 0.0, 0.0, 0.0, turn)
    assert n == every.shape[0] and gain > 0 and z > 5
    back, z_back, _ = paired_gain(m.values, ox, oy, 0.02, qx, qy, 0.0, 0.0, turn, 0.0, 0.0, 0.0)
    assert back == pytest.approx(-gain) and z_back < 0
    assert paired_gain(m.values, ox, oy, 0.02, qx, qy, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)[:2] == (0.0, 0.0)
    few = slice(None, None, 16)
    z_few = paired_gain(m.values, ox, oy, 0.02, np.ascontiguousarray(qx[few]), np.ascontiguousarray(qy[few]),
                        0.0, 0.0, 0.0, 0.0, 0.0, turn)[1]
    assert 0 < z_few < z


def test_the_turn_test_rejects_an_unsupported_turn_and_keeps_a_supported_one():
    """turn_sigma: a match turned 15 degrees with no better fit is replaced by the prediction's fit (counted); the
    true pose, turned away from a wrong prediction, is kept because every beam bears it out."""
    m = Crsm(seed=0)
    m._map, scan = _room_map()
    d = np.nan_to_num(scan.ranges)
    pts = ray_points(scan, d, np.flatnonzero(d > 0), 0.02)
    qx, qy = np.ascontiguousarray(pts[:, 0]), np.ascontiguousarray(pts[:, 1])
    values: dict = {}
    wrong = np.array([0.0, 0.0, math.radians(15)])
    kept = m._check_turn(wrong, qx, qy, values)
    assert abs(kept[2]) < math.radians(1) and values["turn_rejected"] == 1.0
    assert m.diagnostics.counters["turns_rejected"] == 1
    # the robot was believed turned by 6 degrees; the true pose (0) must win against that prediction's fit
    m._pose = np.array([0.0, 0.0, math.radians(6)])
    values = {}
    kept = m._check_turn(np.zeros(3), qx, qy, values)
    assert np.array_equal(kept, np.zeros(3)) and values["turn_rejected"] == 0.0 and values["turn_z"] > 5


def _restart_search(m, qx, qy, pose, d):
    """What rrhc_search sets up around ``pose`` for disparity ``d``: the heading cache (``_cells_at``'s arguments
    after ``k``), the rays' cells at the restart headings, and the restart window ``(lo, width)``."""
    inv = 1.0 / m.resolution
    ox, oy = m.origin
    n = len(qx)
    kmax = 6 * d
    cache = (np.empty((2 * kmax + 1, n), np.int64), np.empty((2 * kmax + 1, n), np.int64),
             np.zeros(2 * kmax + 1, np.bool_), kmax, (pose[0] - ox) * inv, (pose[1] - oy) * inv, pose[2],
             qx * inv, qy * inv, np.empty(n, np.int64), np.empty(n, np.int64))
    cr = np.empty((d, n), np.int64)
    cc = np.empty((d, n), np.int64)
    for i in range(d):
        cr[i], cc[i] = _cells_at(4 * i - 2 * d, *cache)
    return cache, cr, cc, -(d // 4), (d - 1) // 2 + 1


def _assert_table_is_the_direct_fitness(values, cr, cc, lo, width):
    table = _restart_table(values, cr, cc, lo, width)
    for i in range(cr.shape[0]):
        for a in range(width):
            for b in range(width):
                assert table[i, a, b] == _fitness(values, cr[i], cc[i], b + lo, a + lo)
    return table


def test_the_restart_table_equals_the_direct_fitness():
    """The per-scan table of restart fitnesses holds exactly what scoring each candidate directly gives."""
    m, scan = _room_map()
    qx, qy = _rays(scan)
    _, cr, cc, lo, width = _restart_search(m, qx, qy, (0.3, -0.2, 0.1), 16)
    _assert_table_is_the_direct_fitness(m.values, cr, cc, lo, width)


def test_the_restart_table_equals_the_direct_fitness_where_rays_leave_the_map():
    """Windows reaching past the map's edge (and its border cells) score 0 there, as the direct score skips them."""
    m = CrsmMap(0.02)
    m.ensure_contains(-1.2, -0.8, 1.0, 0.9, margin=0)  # smaller than the room: many endpoints fall outside
    scan = room_scan(np.array([0.2, -0.1, 0.3]), n=URG_BEAMS)
    rng = np.random.default_rng(5)
    m.values[:] = rng.integers(0, 256, m.values.shape)  # known cells everywhere, up to the border
    m.values[rng.random(m.values.shape) < 0.3] = UNKNOWN
    qx, qy = _rays(scan)
    _, cr, cc, lo, width = _restart_search(m, qx, qy, (0.2, -0.1, 0.3), 12)
    rows, cols = m.values.shape
    assert ((cr < 1) | (cr >= rows - 1) | (cc < 1) | (cc >= cols - 1)).mean() > 0.2
    assert _assert_table_is_the_direct_fitness(m.values, cr, cc, lo, width).max() > 0
    for far in ((40.0, 0.0, 0.0), (-40.0, 0.0, 0.0), (0.0, 40.0, 0.0), (0.0, -40.0, 0.0)):  # every ray off the map
        _, cr, cc, lo, width = _restart_search(m, qx, qy, far, 12)
        assert not _restart_table(m.values, cr, cc, lo, width).any()


def test_marked_endpoints_equal_ray_points_bit_for_bit():
    """The per-scan kernel gives exactly the endpoints ray_points does (a mounted laser, beams without returns)."""
    rng = np.random.default_rng(3)
    r = rng.uniform(0.05, 5.0, URG_BEAMS)
    r[rng.random(URG_BEAMS) < 0.1] = np.nan
    scan = make_scan(0.0, r, -2.1, 4.2 / (URG_BEAMS - 1), 0.02, 5.6, mount=[0.12, -0.03, 0.2])
    d = np.nan_to_num(scan.ranges)
    m = scan.mount
    x, y = marked_endpoints(d, np.cos(scan.angles), np.sin(scan.angles), 0.02, m[0], m[1], np.cos(m[2]), np.sin(m[2]))
    ref = ray_points(scan, d, np.arange(URG_BEAMS), 0.02)
    assert np.array_equal(x, ref[:, 0]) and np.array_equal(y, ref[:, 1])


def test_first_beam_per_cell_keeps_each_endpoint_cells_first_beam():
    """As a set of laser-frame endpoint cells would: later beams ending in a cell already seen are not walked."""
    rng = np.random.default_rng(4)
    n = 500
    angles = np.linspace(-2.0, 2.0, n)
    d = np.where(rng.random(n) < 0.3, rng.uniform(0.01, 0.1, n), rng.uniform(0.5, 3.0, n))  # short: shared cells
    d[rng.random(n) < 0.1] = 0.0
    use = first_beam_per_cell(d, np.cos(angles), np.sin(angles), 0.02)
    seen = set()
    expected = np.zeros(n, bool)
    for i in range(n):
        cell = (int(np.trunc(d[i] * np.cos(angles[i]) / 0.02)), int(np.trunc(d[i] * np.sin(angles[i]) / 0.02)))
        if d[i] > 0 and cell not in seen:
            expected[i] = True
            seen.add(cell)
    assert expected.sum() < (d > 0).sum()  # the case has shared cells
    assert np.array_equal(use, expected)


@pytest.mark.parametrize("offset", [(0.1, -0.06, 0.06), (-0.08, 0.12, -0.1)])
def test_rrhc_recovers_a_known_offset(offset):
    m, scan = _room_map()
    qx, qy = _rays(scan)
    ox, oy = m.origin
    dx, dy, dk, fit, n, restarts, better = rrhc_search(
        m.values, ox, oy, m.resolution, qx, qy, *offset, 40, 40000, new_state(np.random.default_rng(2)))
    x = offset[0] + dx * m.resolution
    y = offset[1] + dy * m.resolution
    t = offset[2] + dk * HEADING_STEP
    assert math.hypot(x, y) <= 1.5 * m.resolution, (x, y)
    assert abs(t) <= 2.5 * HEADING_STEP, t
    assert n == 40002 and restarts + better == n and better >= 1 and 0 < fit <= 1


def test_skip_advances_the_generator_as_drawing_does():
    for steps in (0, 1, 2, 63, 64, 65, 1000, 120_006):
        drawn = new_state(np.random.default_rng(steps))
        skipped = drawn.copy()
        for _ in range(steps):
            next_u64(drawn)
        skip(skipped, steps)
        assert drawn[0] == skipped[0], steps


def _rrhc_without_early_stop(m, qx, qy, pose, disparity, max_iter, state):
    """rrhc_search's loop candidate by candidate (Python), with no early stop: the reference for the stop."""
    n = len(qx)
    values = m.values
    cache, cr, cc, lo, width = _restart_search(m, qx, qy, pose, disparity)
    table = _restart_table(values, cr, cc, lo, width)
    best = bdx = bdy = bk = dx = dy = k = 0
    restart_index, restarts, better, settled_at = -1, 0, 0, None
    for counter in range(max_iter + 2):
        if restart_index >= 0:
            f = table[restart_index, dy - lo, dx - lo]
            if settled_at is None and best >= table.max():
                settled_at = counter
        else:
            f = _fitness(values, *_cells_at(k, *cache), dx, dy)
        if f > best:
            best, bdx, bdy, bk = f, dx, dy, k
            better += 1
            dx += randint(state, disparity) // 4 - disparity // 8
            dy += randint(state, disparity) // 4 - disparity // 8
            k += 2 * randint(state, disparity) - disparity
            restart_index = -1
        else:
            dx = randint(state, disparity) // 2 - disparity // 4
            dy = randint(state, disparity) // 2 - disparity // 4
            restart_index = randint(state, disparity)
            k = 4 * restart_index - 2 * disparity
            restarts += 1
    return (bdx, bdy, bk, best / (255.0 * 14.0 * n), max_iter + 2, restarts, better), settled_at


@pytest.mark.parametrize("seed", [0, 1])
def test_rrhc_stops_early_with_the_same_result_counts_and_generator_state(seed):
    """Once no restart can beat the best, the search stops: the same result and counts, and the generator left where
    the full loop leaves it (the next scan's numbers depend on it)."""
    m, scan = _room_map()
    qx, qy = _rays(scan)
    ox, oy = m.origin
    start = (0.06, -0.04, 0.05)
    state = new_state(np.random.default_rng(seed))
    ref_state = state.copy()
    got = rrhc_search(m.values, ox, oy, m.resolution, qx, qy, *start, 16, 5000, state)
    ref, settled_at = _rrhc_without_early_stop(m, qx, qy, start, 16, 5000, ref_state)
    assert settled_at is not None and settled_at < 4000  # the case does stop early
    assert tuple(got) == ref
    assert state[0] == ref_state[0]


def test_the_dense_refinement_scores_every_beam_and_walks_to_the_fit():
    """refine_offset climbs with every beam's endpoint (not only critical rays) from a few cells off to the fit."""
    m, scan = _room_map()
    d = np.nan_to_num(scan.ranges)
    pts = ray_points(scan, d, np.flatnonzero(d > 0), 0.02)
    qx, qy = np.ascontiguousarray(pts[:, 0]), np.ascontiguousarray(pts[:, 1])
    ox, oy = m.origin
    start = (3 * m.resolution, -2 * m.resolution, 3 * HEADING_STEP)
    dx, dy, dk, fit, moved = refine_offset(m.values, ox, oy, m.resolution, qx, qy, *start, 0, 0, 0, 50)
    _, _, _, fit0, moved0 = refine_offset(m.values, ox, oy, m.resolution, qx, qy, *start, 0, 0, 0, 0)
    assert moved >= 2 and moved0 == 0 and fit > fit0
    x, y, t = start[0] + dx * m.resolution, start[1] + dy * m.resolution, start[2] + dk * HEADING_STEP
    assert math.hypot(x, y) <= 1.5 * m.resolution and abs(t) <= 1.5 * HEADING_STEP, (x, y, t)
    # from the fit itself it stays within a cell (the wall is two cells thick)
    ex, ey, ek = refine_offset(m.values, ox, oy, m.resolution, qx, qy, 0.0, 0.0, 0.0, 0, 0, 0, 50)[:3]
    assert max(abs(ex), abs(ey), abs(ek)) <= 1, (ex, ey, ek)


def test_near_known_flags_points_beyond_the_mapped_area():
    """A point is judged against the map only if a known cell lies within the margin of where it lands."""
    m = CrsmMap(0.02)
    m.ensure_contains(-2, -2, 2, 2, margin=0)
    ox, oy = m.origin
    m.values[:, : int((0.5 - ox) / 0.02)] = 200  # known (free) up to x = 0.5 m, unknown beyond
    qx = np.array([0.3, 0.49, 0.53, 0.6, 1.5])
    qy = np.zeros(5)
    assert near_known(m.values, ox, oy, 0.02, qx, qy, 0.0, 0.0, 0.0, 0).tolist() == [True, True, False, False, False]
    assert near_known(m.values, ox, oy, 0.02, qx, qy, 0.0, 0.0, 0.0, 2).tolist() == [True, True, True, False, False]
    # the pose moves the points: shifted back by 1 m, all but the last land on the known part
    assert near_known(m.values, ox, oy, 0.02, qx, qy, -1.0, 0.0, 0.0, 0).tolist() == [True, True, True, True, False]


def test_unknown_rays_drop_leaves_out_rays_on_new_space_and_still_tracks():
    """unknown_rays=drop (the default): driving on, rays beyond the mapped part are counted and left out; the drive is tracked."""
    frames, truth = _drive()
    m = Crsm(seed=3).run(frames)  # the default
    dropped = m.diagnostics.array("rays_on_unknown")
    assert np.nansum(dropped) > 0
    pa = m.trajectory()[1]
    aligned = se2.compose(align_se2(pa[:, :2], truth[:, :2]), pa)
    err = np.hypot(*(aligned[:, :2] - truth[:, :2]).T)
    assert np.sqrt(np.mean(err**2)) < 0.05, err
    # score (the original) counts every ray
    assert "rays_on_unknown" not in Crsm(CrsmParams(unknown_rays="score"), seed=3).run(frames[:5]).diagnostics.series


def test_error_code_readings_are_no_return():
    """URG-04LX error codes (a few mm) are not returns: counted, never critical rays, never on the map."""
    scan = room_scan(np.zeros(3), n=URG_BEAMS)
    r = scan.ranges.copy()
    r[100:140:3] = 0.007
    bad = make_scan(0.0, r, scan.angle_min, scan.angle_increment, 0.0, scan.range_max)
    m = Crsm(seed=1)
    for i in range(3):
        m.feed(frame(bad, index=i))
    assert m.diagnostics.counters["short_readings"] == 3 * 14
    assert np.hypot(*m.pose[:2]) < 0.03
    # the laser's own cell stays free: no beam ended there
    ox, oy = m._map.origin
    assert m._map.values[int(-oy / 0.02), int(-ox / 0.02)] > 127


def test_the_search_centre_is_the_last_pose(monkeypatch):
    """The random-restart search is centred on the last pose, as in the original (no motion model)."""
    import slam2d.methods.crsm as crsm_module

    centres = []
    real = crsm_module.rrhc_search

    def spy(values, ox, oy, res, qx, qy, x, y, theta, *rest):
        centres.append((x, y, theta))
        return real(values, ox, oy, res, qx, qy, x, y, theta, *rest)

    monkeypatch.setattr(crsm_module, "rrhc_search", spy)
    frames, _ = _drive(n=8, step=0.05, turn=0.02)
    m = Crsm(CrsmParams(warmup_scans=0), seed=3)
    poses = []
    for f in frames:
        m.feed(f)
        poses.append(m.pose.copy())
    for i in range(2, len(frames)):
        assert np.allclose(centres[i - 1], poses[i - 1]), i


def _drive(n=50, step=0.05, turn=0.015):
    poses = [np.array([i * step, 0.02 * i * step, i * turn]) for i in range(n)]
    return [frame(room_scan(p, n=URG_BEAMS, t=0.1 * i), index=i) for i, p in enumerate(poses)], np.stack(poses)


def test_velocity_prediction_scales_the_recent_motion_by_the_scan_interval():
    """turn_null=velocity: the prediction is the mean velocity of the last matched motions (from the scan timestamps)
    times this scan's interval; with no interval (first scan, a repeated stamp) it is no motion."""
    m = Crsm(CrsmParams(turn_null="velocity", velocity_scans=2), seed=0)
    assert np.array_equal(m._velocity_step(), np.zeros(3))
    m._recent = [(np.array([0.10, 0.0, 0.02]), 0.1), (np.array([0.30, 0.0, 0.06]), 0.1)]
    m._dt = 0.05
    assert np.allclose(m._velocity_step(), [0.10, 0.0, 0.02])  # 2 m/s, 0.4 rad/s over 0.05 s
    assert np.allclose(m._velocity_step(turn=False), [0.10, 0.0, 0.0])


def test_the_measured_turn_options_track_a_drive_and_are_deterministic():
    """turn_null=velocity and turn_starts=translations (not the defaults; measured on the mines logs in
    docs/methods/crsm.md) still track the simulated drive, and repeat bit for bit."""
    frames, truth = _drive()
    params = CrsmParams(turn_null="velocity", turn_starts="translations")
    a = Crsm(params, seed=3).run(frames)
    b = Crsm(params, seed=3).run(frames)
    pa = a.trajectory()[1]
    assert np.array_equal(pa, b.trajectory()[1])
    aligned = se2.compose(align_se2(pa[:, :2], truth[:, :2]), pa)
    err = np.hypot(*(aligned[:, :2] - truth[:, :2]).T)
    assert np.sqrt(np.mean(err**2)) < 0.05, err
    assert np.abs(se2.wrap_angle(aligned[:, 2] - truth[:, 2])).max() < math.radians(2)
    assert len(a._recent) == 3  # the drive's frames are 0.1 s apart: the velocity is kept


@pytest.mark.parametrize("motion", [(0.10, 0.02, 0.05), (0.15, -0.05, 0.22), (0.0, 0.0, -0.2)])
def test_scan_to_scan_registration_recovers_the_turn_between_two_scans(motion):
    """turn_null=scan_to_scan: the motion between two scans of a room, found from the scans alone (no map) and from
    a guess of no motion, including a 0.2 rad turn (far points leave a Gaussian's reach: the heading sweep)."""
    from slam2d.matching.scan_to_scan import consecutive_motion

    def points(pose):
        scan = room_scan(pose, n=URG_BEAMS)
        d = np.nan_to_num(scan.ranges)
        return np.ascontiguousarray(ray_points(scan, d, np.flatnonzero((d > 0) & (d < scan.range_max)), 0.02))

    truth = np.array(motion)
    found = consecutive_motion(points(np.zeros(3)), points(truth), np.zeros(3))
    assert abs(se2.wrap_angle(found[2] - truth[2])) < math.radians(0.5), found
    assert np.hypot(*(found[:2] - truth[:2])) < 0.05, found
    # too few points: the guess comes back
    assert np.array_equal(consecutive_motion(np.zeros((2, 2)), points(truth), truth), truth)


# a room with a lattice of small pillars: many wall segments end inside the scan, where a registration on the
# smeared previous scan pulled the points past a segment's end back along the wall, against the turn
_PILLARS = [(x, y, x + 0.2, y + 0.2) for x in np.arange(-2.5, 3.6, 0.9) for y in np.arange(-1.5, 3.1, 0.9)]


def _pillar_points(pose, n=URG_BEAMS, fov=math.radians(240)):
    from tests._room import ROOM, _box_hits

    a = -fov / 2 + fov * np.arange(n) / (n - 1)
    dx, dy = np.cos(pose[2] + a), np.sin(pose[2] + a)
    r = _box_hits(pose[0], pose[1], dx, dy, ROOM, True)
    for box in _PILLARS:
        r = np.fmin(r, _box_hits(pose[0], pose[1], dx, dy, box, False))
    scan = make_scan(0.0, np.where(r < 20.0, r, np.nan), -fov / 2, fov / (n - 1), 0.02, 20.0)
    d = np.nan_to_num(scan.ranges)
    return np.ascontiguousarray(ray_points(scan, d, np.flatnonzero(d > 0), 0.02))


@pytest.mark.parametrize("sign", [1, -1])
def test_scan_to_scan_recovers_a_3_degree_turn_without_shrinking_it(sign):
    """A 3 degree turn (and 5 cm forward) between two scans among pillars, from six poses: every estimate within 4 %
    of the turn. The Gauss-Newton on the smeared previous scan (before the point-to-line step) missed it by up to
    9 % (0.906 and 1.068 of it at two of these poses)."""
    from slam2d.matching.scan_to_scan import consecutive_motion

    rng = np.random.default_rng(0)
    motion = np.array([0.05, 0.0, sign * math.radians(3)])
    ratios = []
    for i in range(6):
        base = np.array([0.9 * i - 1.95, -1.05 + 0.9 * (i % 4), rng.uniform(-3, 3)])  # between the pillars
        found = consecutive_motion(_pillar_points(base), _pillar_points(se2.compose(base, motion)), motion * [1, 0, 0])
        ratios.append(found[2] / motion[2])
        assert np.hypot(*(found[:2] - motion[:2])) < 0.02, found
    assert np.all(np.abs(np.array(ratios) - 1.0) < 0.04), ratios
    assert abs(np.mean(ratios) - 1.0) < 0.01, ratios


def test_crsm_tracks_a_drive_and_is_deterministic():
    frames, truth = _drive()
    a = Crsm(seed=3).run(frames)
    b = Crsm(seed=3).run(frames)
    c = Crsm(seed=4).run(frames)
    pa = a.trajectory()[1]
    assert np.array_equal(pa, b.trajectory()[1])
    assert np.array_equal(a.diagnostics.array("restarts"), b.diagnostics.array("restarts"), equal_nan=True)
    # another seed searches differently (the final every-beam climb may still settle on the same poses)
    assert not np.array_equal(a.diagnostics.array("restarts"), c.diagnostics.array("restarts"), equal_nan=True)
    # the warm-up holds the first scans at the start while the robot already moves: judge the shape (as ATE does)
    aligned = se2.compose(align_se2(pa[:, :2], truth[:, :2]), pa)
    err = np.hypot(*(aligned[:, :2] - truth[:, :2]).T)
    assert np.sqrt(np.mean(err**2)) < 0.05 and err[10:].max() < 0.05, err
    assert np.abs(se2.wrap_angle(aligned[:, 2] - truth[:, 2])).max() < math.radians(2)
    d = a.diagnostics
    assert d.summary["warmup_ended_at_scan"] <= 5  # it moves from the start: the hold ends early
    assert np.all(d.array("iterations")[1:] == 40002)
    assert np.all(d.array("restarts")[1:] > 30000)
    assert np.all((d.array("score")[1:] > 0) & (d.array("score")[1:] <= 1))
    assert a.map().occupied().sum() > 100


def test_warm_up_holds_a_standing_robot_at_the_start():
    scan = room_scan(np.zeros(3), n=URG_BEAMS)
    m = Crsm(seed=1)
    for i in range(12):
        m.feed(frame(scan, index=i))
    assert np.array_equal(m.pose, np.zeros(3))
    assert "warmup_ended_at_scan" not in m.diagnostics.summary


def test_degenerate_scans_are_counted_not_fatal():
    empty = make_scan(0.0, np.full(100, np.nan), -1.0, 0.02, 0.02, 5.0)
    m = Crsm()
    for i in range(3):
        m.feed(frame(empty, index=i))
    assert m.diagnostics.counters["scans_without_returns"] == 3
    one = make_scan(0.0, np.r_[np.full(99, np.nan), 2.0], -1.0, 0.02, 0.02, 5.0)
    m.feed(frame(one, index=3))
    m.feed(frame(one, index=4))
    assert m.diagnostics.counters["scans_too_few_rays"] >= 1
    assert np.all(np.isfinite(m.pose))


@pytest.mark.parametrize("text", ["hill_climbing_disparity=2", "max_hill_climbing_iterations=0",
                                  "resolution=0", "map_update_density=-1", "desired_number_of_picked_rays=x"])
def test_bad_parameters_are_input_errors(text):
    name, _, value = text.partition("=")
    with pytest.raises(InputError) as err:
        from_mapping(get_method("crsm").Params, {name: value})
    assert name in str(err.value)


def test_crsm_on_the_simulated_arena(tmp_path, paper_arena):
    """The issue's target: paper-arena (no odometry used), ATE under 5 cm."""
    ate = run_ate("crsm", paper_arena, tmp_path / "run")
    assert ate < 0.05, ate


@pytest.mark.slow
@pytest.mark.datasets
def test_crsm_on_mines_exp1_beats_the_odometry_map(tmp_path):
    """mines-exp1 (URG-04LX, 756 scans) without odometry: crsm's trajectory makes a better map than the odometry's.

    Both maps are drawn by the same mapper (known-poses, 5 cm log-odds) so only the trajectories differ;
    Filatov et al.'s counts (corners, enclosed free areas) must both be lower than the odometry's.
    """
    import json

    from tests.conftest import dataset_file

    log = dataset_file("mines-exp1/mines-exp1.clf.gz")
    quality = {}
    for name in ("crsm", "odometry"):
        assert main(["run", name, str(log), "--out", str(tmp_path / name)]) == 0
        out = tmp_path / f"{name}-map"
        poses = f"poses={tmp_path / name / 'trajectory.tum'}"
        assert main(["run", "known-poses", str(log), "--out", str(out), "--set", poses]) == 0
        assert main(["evaluate", str(out), "--json"]) == 0
        quality[name] = json.loads((out / "evaluation.json").read_text())["map_quality"]
    crsm, odo = quality["crsm"], quality["odometry"]
    assert crsm["corners"] < odo["corners"] and crsm["enclosed_areas"] < odo["enclosed_areas"], quality
    # error codes would put rays on the laser's cell; the run must have seen and dropped them
    diag = json.loads((tmp_path / "crsm" / "diagnostics.json").read_text())
    assert diag["counters"]["short_readings"] > 10_000


def _mines_run(name: str, seed: int = 0, settings: dict | None = None, log: str = "mines-exp2"):
    """``name`` on a mines log (the SLAM methods use no odometry): ``(scan_consistency mean, times, poses)``."""
    from slam2d.eval import scan_consistency
    from slam2d.io import open_recording
    from slam2d.methods.runner import build_method
    from tests.conftest import dataset_file

    frames = list(open_recording(dataset_file(f"{log}/{log}.clf.gz")).frames())
    slam = build_method(name, settings=settings or {}, seed=seed)
    slam.run(frames)
    times, poses = slam.trajectory()
    return scan_consistency(frames, times, poses)["mean"], np.asarray(times), np.asarray(poses)


@pytest.fixture(scope="module")
def hector_mines_exp2():
    return _mines_run("hector")


@pytest.fixture(scope="module")
def hector_mines_exp1():
    return _mines_run("hector", log="mines-exp1")


@pytest.mark.slow
@pytest.mark.datasets
def test_scan_consistency_ranks_the_mines_exp2_trajectories(hector_mines_exp2):
    """On the real log the number orders what the pictures show: hector's map (consistent) above the odometry's.

    Measured: hector 0.66, odometry 0.55, crsm with the original's 40 rays (seed 0) 0.40 (rooms turned).
    """
    odometry = _mines_run("odometry")[0]
    assert hector_mines_exp2[0] > 0.6
    assert odometry < hector_mines_exp2[0] - 0.05


# How far (95th percentile over scans, degrees, after a rigid alignment) the headings of the other methods whose
# maps of the log look consistent (coreslam, gmapping, karto; scan_consistency 0.64-0.74) stray from hector's:
# at most 11.9 on mines-exp1 and 22.8 on mines-exp2 (hector turns 20 degrees more than all of them at scan 236).
# crsm must stay as close to hector as they do (docs/methods/crsm.md).
HEADING_BOUND_DEG = {"mines-exp1": 12.0, "mines-exp2": 23.0}


def _check_mines_target(log: str, hector) -> list:
    """Seeds 0-4 of crsm on ``log``: those whose scan_consistency is below 95 % of hector's or whose heading p95 exceeds
    ``HEADING_BOUND_DEG`` (as ``(log, seed, consistency, heading)``)."""
    from slam2d.eval.trajectory_metrics import heading_agreement

    failures = []
    for seed in (0, 1, 2, 3, 4):
        consistency, times, poses = _mines_run("crsm", seed, log=log)
        heading = heading_agreement(times, poses, hector[1], hector[2])["heading_p95_deg"]
        if consistency < 0.95 * hector[0] or heading > HEADING_BOUND_DEG[log]:
            failures.append((log, seed, round(consistency, 3), round(heading, 1)))
    return failures


@pytest.mark.slow
@pytest.mark.datasets
def test_crsm_mines_exp1_map_is_as_consistent_as_hector(hector_mines_exp1):
    """The target on mines-exp1, seeds 0-4: scan_consistency within 5 % of hector's, and the headings (aligned as ATE
    aligns) no further from hector's than the other consistent methods' are (``HEADING_BOUND_DEG``).

    The consistency alone is necessary, not sufficient: settings whose maps have rooms turned by 20-40 degrees
    pass it (docs/methods/crsm.md, "Unknown space and the lag"); a part turned against the rest shows in the
    headings for the rest of the run. Measured with the defaults (turn_null=scan_to_scan, its point-to-line step):
    consistency 0.730 / 0.720 / 0.716 / 0.727 / 0.724 (bar 0.650), heading p95 5.5 / 4.2 / 7.8 / 4.1 / 5.7 degrees
    (bound 12; with the smeared-field step that shrank turns, seed 4 failed at 12.4).
    """
    failures = _check_mines_target("mines-exp1", hector_mines_exp1)
    assert not failures, failures


@pytest.mark.slow
@pytest.mark.datasets
def test_crsm_mines_exp2_map_is_as_consistent_as_hector(hector_mines_exp2):
    """The target on mines-exp2, seeds 0-4 (as the mines-exp1 test). About 18 degrees of the bound are hector's own
    turn at scan 236: hector's trajectory with that turn taken out scores 18.3 against hector's. Measured with the
    defaults: heading p95 21.2 / 16.5 / 18.2 / 21.0 / 16.2 degrees (bound 23), consistency 0.730 / 0.733 / 0.743 /
    0.736 / 0.711 (bar 0.624). The runs are chaotic (a change anywhere moves which seed is worst); with the
    smeared-field scan-to-scan step, which shrank turns, seed 4 failed at 24.0: docs/methods/what-was-tried.md."""
    failures = _check_mines_target("mines-exp2", hector_mines_exp2)
    assert not failures, failures
