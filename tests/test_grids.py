"""Occupancy grids: exact ray casting, update rules, growth, conversions, likelihood fields."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from slam2d.core.frames import Frame
from slam2d.core.scan import make_scan
from slam2d.errors import InputError
from slam2d.grids import (
    GridParams,
    OccupancyGrid,
    bilinear_at,
    bilinear_gradient_at,
    cast_rays,
    distance_field,
    likelihood_field,
    logit,
    trace_ray,
)
from slam2d.grids.crsm_map import CrsmMap

FREE = round(100 * 0.4)  # one miss from unknown with the default p_miss
HIT = round(100 * 0.7)  # one hit from unknown with the default p_hit


def unit_grid(**changes) -> OccupancyGrid:
    """A 1 m grid covering [0, 10) x [0, 10) so cell (r, c) spans [c, c+1) x [r, r+1)."""
    return OccupancyGrid.covering(0.0, 0.0, 9.5, 9.5, GridParams(resolution=1.0, **changes))


def observed_cells(grid: OccupancyGrid) -> dict[tuple[int, int], int]:
    occ = grid.occupancy()
    rows, cols = np.nonzero(occ >= 0)
    return {(int(r), int(c)): int(occ[r, c]) for r, c in zip(rows, cols)}


def trace(x0, y0, x1, y1, origin=(0.0, 0.0), resolution=1.0) -> list[tuple[int, int]]:
    n = abs(math.floor((x1 - origin[0]) / resolution) - math.floor((x0 - origin[0]) / resolution))
    n += abs(math.floor((y1 - origin[1]) / resolution) - math.floor((y0 - origin[1]) / resolution))
    rows = np.zeros(n + 1, dtype=np.int64)
    cols = np.zeros(n + 1, dtype=np.int64)
    k = trace_ray(x0, y0, x1, y1, origin[0], origin[1], resolution, rows, cols)
    return list(zip(rows[:k].tolist(), cols[:k].tolist()))


# ----------------------------------------------------------------------------- ray casting


def test_beam_along_x_marks_exactly_its_cells():
    grid = unit_grid()
    grid.integrate_scan([0.5, 2.5, 0.0], [4.0], [0.0])  # ends at x = 4.5 in cell (2, 4)
    assert observed_cells(grid) == {(2, 0): FREE, (2, 1): FREE, (2, 2): FREE, (2, 3): FREE, (2, 4): HIT}


def test_beam_along_negative_y_marks_exactly_its_cells():
    grid = unit_grid()
    grid.integrate_scan([3.5, 6.5, 0.0], [3.0], [-math.pi / 2])  # ends at y = 3.5 in cell (3, 3)
    assert observed_cells(grid) == {(6, 3): FREE, (5, 3): FREE, (4, 3): FREE, (3, 3): HIT}


def test_diagonal_beam_through_corners_stays_one_cell_wide():
    grid = unit_grid()
    grid.integrate_scan([0.5, 0.5, math.pi / 4], [3.0 * math.sqrt(2.0)], [0.0])
    assert observed_cells(grid) == {(0, 0): FREE, (1, 1): FREE, (2, 2): FREE, (3, 3): HIT}


def test_shallow_beam_visits_every_cell_it_crosses():
    # From (0.5, 0.2) to (6.5, 2.7): crosses y = 1 at x = 2.42 and y = 2 at x = 4.82.
    cells = trace(0.5, 0.2, 6.5, 2.7)
    assert cells == [(0, 0), (0, 1), (0, 2), (1, 2), (1, 3), (1, 4), (2, 4), (2, 5), (2, 6)]
    # Ending at y = 2.6 instead, the segment passes exactly through the corner (5, 2):
    # it steps diagonally from cell (1, 4) to (2, 5), touching neither (2, 4) nor (1, 5).
    assert trace(0.5, 0.2, 6.5, 2.6) == [(0, 0), (0, 1), (0, 2), (1, 2), (1, 3), (1, 4), (2, 5), (2, 6)]
    grid = unit_grid()
    grid.integrate_points([0.5, 0.2], [[6.5, 2.7]])
    expected = {cell: FREE for cell in cells[:-1]} | {cells[-1]: HIT}
    assert observed_cells(grid) == expected


@settings(max_examples=200, deadline=None)
@given(
    x0=st.floats(-20, 20),
    y0=st.floats(-20, 20),
    x1=st.floats(-20, 20),
    y1=st.floats(-20, 20),
    resolution=st.sampled_from([0.05, 0.1, 0.37, 1.0]),
)
def test_traversal_is_exact(x0, y0, x1, y1, resolution):
    """Every cell the segment passes through is visited, in order, each step to a neighbour."""
    origin = (-3.3, 1.7)
    cells = trace(x0, y0, x1, y1, origin, resolution)
    start = (math.floor((y0 - origin[1]) / resolution), math.floor((x0 - origin[0]) / resolution))
    end = (math.floor((y1 - origin[1]) / resolution), math.floor((x1 - origin[0]) / resolution))
    assert cells[0] == start and cells[-1] == end
    if len(cells) > 1:
        steps = np.abs(np.diff(np.array(cells), axis=0))
        assert np.all(steps.max(axis=1) == 1)  # to a 4- or (at exact corners) 8-neighbour
    assert len(set(cells)) == len(cells)
    # Dense samples along the segment (away from cell borders) all fall in visited cells.
    t = np.linspace(0.0, 1.0, 4001)
    u = (x0 + t * (x1 - x0) - origin[0]) / resolution
    v = (y0 + t * (y1 - y0) - origin[1]) / resolution
    clear = (np.abs(u - np.rint(u)) > 1e-6) & (np.abs(v - np.rint(v)) > 1e-6)
    sampled = set(zip(np.floor(v[clear]).astype(int).tolist(), np.floor(u[clear]).astype(int).tolist()))
    assert sampled <= set(cells)


@settings(max_examples=150, deadline=None)
@given(
    x=st.floats(-30, 30),
    y=st.floats(-30, 30),
    theta=st.floats(-math.pi, math.pi),
    beam=st.floats(-math.pi, math.pi),
    r=st.floats(0.01, 25.0),
)
def test_endpoint_occupied_and_laser_cell_free(x, y, theta, beam, r):
    grid = OccupancyGrid(GridParams(resolution=0.05))
    grid.integrate_scan([x, y, theta], [r], [beam])
    end = np.array([x + r * math.cos(theta + beam), y + r * math.sin(theta + beam)])
    laser_cell = tuple(grid.world_to_cell([x, y]))
    # A hit on a cell boundary belongs to the cell beyond it along the beam.
    onward = end + 1e-6 * 0.05 * (end - np.array([x, y])) / np.hypot(*(end - np.array([x, y])))
    end_cell = tuple(grid.world_to_cell(onward))
    occ = grid.occupancy()
    assert occ[end_cell] == HIT
    if laser_cell != end_cell:
        assert occ[laser_cell] == FREE
    # Nothing but the ray was touched: at most one cell per crossed row/column, plus the start.
    span = abs(end_cell[0] - laser_cell[0]) + abs(end_cell[1] - laser_cell[1]) + 1
    assert 1 <= int((occ >= 0).sum()) <= span


@pytest.mark.parametrize(("start", "end", "hit_cell", "free_cell"), [
    ((2.5, 5.5), (2.5, 2.0), (1, 2), (2, 2)),  # down onto y = 2: the wall is in row 1
    ((2.5, 0.5), (2.5, 2.0), (2, 2), (1, 2)),  # up onto it: row 2
    ((5.5, 2.5), (3.0, 2.5), (2, 2), (2, 3)),  # left onto x = 3: column 2
    ((0.5, 2.5), (3.0, 2.5), (2, 3), (2, 2)),  # right onto it: column 3
])
def test_a_hit_on_a_cell_boundary_marks_the_cell_beyond_it(start, end, hit_cell, free_cell):
    # A noise-free beam ending exactly on a wall at a round coordinate ends on a cell boundary.
    # floor() put the hit in the upper (right) cell whichever way the beam came, so beams from
    # above marked the free cell in front of the wall, and the next beams' free space erased it
    # (a simulated RPLidar floor without range noise lost a fifth of its walls).
    grid = unit_grid()
    grid.integrate_points(list(start), [list(end)])
    occ = grid.occupancy()
    assert occ[hit_cell] == HIT
    assert occ[free_cell] == FREE


def test_one_update_per_cell_per_scan_and_hits_win():
    grid = unit_grid()
    # Three beams from the same cell: two overlap all the way, one crosses the third's endpoint.
    grid.integrate_points(
        [0.5, 0.5],
        [[5.5, 0.5], [5.5, 0.6], [2.5, 0.5]],
    )
    occ = grid.occupancy()
    assert occ[0, 0] == FREE and occ[0, 1] == FREE and occ[0, 4] == FREE  # one miss, not two or three
    assert occ[0, 2] == HIT  # a hit, although two beams pass through it in the same scan
    assert occ[0, 5] == HIT  # two endpoints in one cell: one hit


def test_updates_accumulate_across_scans_and_clamp():
    grid = unit_grid()
    for _ in range(3):
        grid.integrate_scan([0.5, 0.5, 0.0], [2.0], [0.0])
    p = grid.probability()
    expected_free = 1.0 / (1.0 + math.exp(-3 * logit(0.4)))
    expected_hit = 1.0 / (1.0 + math.exp(-3 * logit(0.7)))
    assert p[0, 1] == pytest.approx(expected_free, rel=1e-5)
    assert p[0, 2] == pytest.approx(expected_hit, rel=1e-5)
    for _ in range(30):
        grid.integrate_scan([0.5, 0.5, 0.0], [2.0], [0.0])
    p = grid.probability()
    assert p[0, 1] == pytest.approx(0.12, rel=1e-5)
    assert p[0, 2] == pytest.approx(0.97, rel=1e-5)


def test_scan_counter_wraparound_keeps_observed_cells_and_per_scan_rule():
    grid = unit_grid()
    grid.integrate_scan([0.5, 0.5, 0.0], [2.0], [0.0])
    grid._scan_stamp = 65534  # near the end of the 16-bit scan counter
    for _ in range(3):  # crosses the wrap
        grid.integrate_points([0.5, 5.5], [[3.5, 5.5], [3.5, 5.6]])
    occ = grid.occupancy()
    assert occ[0, 2] == HIT and occ[0, 1] == FREE  # observed before the wrap, untouched
    p_free = 1.0 / (1.0 + math.exp(-3 * logit(0.4)))  # one miss per scan, not two
    assert grid.probability()[5, 1] == pytest.approx(p_free, rel=1e-5)
    assert int(grid.observed.sum()) == 3 + 4


def test_free_only_beams_clear_their_endpoint_cell():
    grid = unit_grid()
    grid.integrate_points([0.5, 0.5], [[3.5, 0.5], [0.5, 2.5]], hits=[False, True])
    assert observed_cells(grid) == {
        (0, 0): FREE, (0, 1): FREE, (0, 2): FREE, (0, 3): FREE, (1, 0): FREE, (2, 0): HIT
    }


def test_no_return_beams_are_skipped_unless_a_clearing_range_is_set():
    grid = unit_grid()
    grid.integrate_scan([0.5, 0.5, 0.0], [np.nan, np.inf, 0.0], [0.0, 0.5, 1.0])
    assert observed_cells(grid) == {}

    clearing = unit_grid(max_range=3.0)
    clearing.integrate_scan([0.5, 0.5, 0.0], [np.nan], [0.0])  # cleared to x = 3.5, no hit
    assert observed_cells(clearing) == {(0, 0): FREE, (0, 1): FREE, (0, 2): FREE, (0, 3): FREE}

    long_return = unit_grid()
    long_return.integrate_scan([0.5, 0.5, 0.0], [7.0], [0.0], max_range=3.0)  # truncated, no hit
    assert observed_cells(long_return) == {(0, 0): FREE, (0, 1): FREE, (0, 2): FREE, (0, 3): FREE}


def test_integrate_frame_uses_the_laser_mount():
    grid = OccupancyGrid(GridParams(resolution=0.1))
    scan = make_scan(1.0, [1.0], 0.0, 0.01, 0.0, 30.0, mount=[0.23, 0.0, 0.0])
    grid.integrate(Frame(0, scan, None), [0.05, 0.05, math.pi / 2])  # laser at (0.05, 0.28) facing +y
    occ = grid.occupancy()
    assert occ[tuple(grid.world_to_cell([0.05, 1.28]))] == HIT
    assert occ[tuple(grid.world_to_cell([0.05, 0.25]))] == FREE  # the laser's cell
    assert occ[tuple(grid.world_to_cell([0.05, 0.15]))] == -1  # robot centre, behind the laser
    assert occ[tuple(grid.world_to_cell([0.05, 1.35]))] == -1  # beyond the endpoint
    assert int((occ >= 0).sum()) == 11


# ----------------------------------------------------------------------------- growth, size


def test_growing_keeps_data_at_the_same_world_positions():
    grid = OccupancyGrid(GridParams(resolution=0.05))
    grid.integrate_scan([0.3, -0.2, 0.4], np.linspace(1.0, 3.0, 90), np.linspace(-1.5, 1.5, 90))
    occ_before = grid.occupancy()
    cells = np.argwhere(occ_before >= 0)
    centres = grid.cell_to_world(cells)
    values = occ_before[cells[:, 0], cells[:, 1]]
    origin_before = np.array(grid.origin)
    shape_before = grid.shape

    assert grid.ensure_contains(-40.0, -7.0, 55.0, 30.0)
    assert not grid.ensure_contains(-39.0, -6.0, 54.0, 29.0)  # already inside: no change
    xmin, ymin, xmax, ymax = grid.extent()
    assert xmin <= -40.0 and ymin <= -7.0 and xmax > 55.0 and ymax > 30.0
    shift = (np.array(grid.origin) - origin_before) / grid.resolution
    np.testing.assert_allclose(shift, np.rint(shift), atol=1e-6)  # whole cells only
    after = grid.occupancy()
    moved = grid.world_to_cell(centres)
    np.testing.assert_array_equal(after[moved[:, 0], moved[:, 1]], values)
    assert int((after >= 0).sum()) == len(values)
    assert grid.shape[0] > shape_before[0] and grid.shape[1] > shape_before[1]


def test_growth_is_amortised():
    grid = OccupancyGrid(GridParams(resolution=0.05, grow_margin=64))
    grid.ensure_contains(0.0, 0.0, 10.0, 10.0)
    rows, cols = grid.shape
    grid.ensure_contains(0.0, 0.0, grid.extent()[2] + 0.01, 1.0)  # one cell past the right edge
    assert grid.shape[1] >= cols + max(64, cols // 2)
    assert grid.shape[0] == rows
    reallocations = 0
    for x in np.arange(10.0, 200.0, 0.1):  # a robot driving 190 m to the right
        reallocations += grid.ensure_contains(x, 0.0, x + 5.0, 1.0)
    assert reallocations <= 16  # 10 m steps, then an eighth of the grid: not one per cell or per metre


@pytest.mark.parametrize("kind", ["occupancy", "values"])
def test_a_big_map_pushed_on_both_sides_grows_by_an_eighth(kind):
    # A drifting run pushes one edge and then the opposite one: each side gains at most
    # max(GROWTH_CAP_M, an eighth of the grid) here,
    # not half the grid (which made 5x the cells observed).
    if kind == "occupancy":
        grid = OccupancyGrid(GridParams(resolution=0.05, grow_margin=64))
    else:
        grid = CrsmMap(0.05, grow_margin=64)
    grid.ensure_contains(0.0, 0.0, 100.0, 1.0)

    def edges():
        return grid.origin[0], grid.origin[0] + grid.shape[1] * 0.05

    first = edges()[1] - edges()[0]
    grid.ensure_contains(edges()[0] - 1.0, 0.0, 1.0, 1.0)  # a metre past the left edge
    grid.ensure_contains(0.0, 0.0, edges()[1] + 1.0, 1.0)  # then a metre past the right one
    grown = grid.shape[1] * 0.05 - first
    assert 2.0 < grown <= 2.0 + 2 * 15.0  # an eighth of 100-115 m a side (half the grid a side: 100 m)


def test_a_200_m_square_grid_at_5_cm():
    grid = OccupancyGrid.covering(-100.0, -100.0, 99.99, 99.99, GridParams(resolution=0.05))
    assert grid.shape == (4000, 4000)
    assert grid.logodds.dtype == np.float32 and grid.logodds.nbytes == 64_000_000
    angles = np.linspace(-math.pi, math.pi, 720, endpoint=False)
    grid.integrate_scan([99.0, 99.0, 0.0], np.full(720, 0.9), angles)
    grid.integrate_scan([-99.0, -99.0, 0.0], np.full(720, 0.9), angles)
    assert grid.shape == (4000, 4000)  # both scans fit without growing
    occ = grid.occupancy()
    assert occ[tuple(grid.world_to_cell([99.0 + 0.9, 99.0]))] == HIT
    assert occ[tuple(grid.world_to_cell([-99.0 - 0.9, -99.0]))] == HIT
    assert occ[2000, 2000] == -1


def test_absurd_growth_is_an_input_error():
    grid = OccupancyGrid(GridParams(resolution=0.05, max_extent=500.0))
    with pytest.raises(InputError, match="max_extent"):
        grid.integrate_scan([0.0, 0.0, 0.0], [1e6], [0.0])
    with pytest.raises(ValueError, match="not finite"):
        grid.ensure_contains(0.0, 0.0, np.nan, 1.0)


def test_inconsistent_probabilities_are_refused():
    with pytest.raises(InputError, match="p_hit"):
        OccupancyGrid(GridParams(p_hit=0.3))
    with pytest.raises(InputError, match="p_miss"):
        OccupancyGrid(GridParams(p_miss=0.1, p_min=0.2))


# ----------------------------------------------------------------------------- conversions


def test_conversion_semantics():
    grid = unit_grid()
    assert np.all(grid.occupancy() == -1) and np.all(grid.probability() == 0.5)
    grid.integrate_scan([0.5, 0.5, 0.0], [2.0], [0.0])  # cell (0, 2) hit
    grid.integrate_scan([0.5, 0.5, 0.0], [4.0], [0.0])  # ... then crossed: 0.7 -> ~0.61
    occ = grid.occupancy()
    assert occ.dtype == np.int8
    p_cell = 1.0 / (1.0 + math.exp(-(logit(0.7) + logit(0.4))))
    assert occ[0, 2] == round(100 * p_cell)
    assert occ[5, 5] == -1 and not grid.observed[5, 5]
    assert grid.observed[0, 2] and grid.observed[0, 4]
    assert set(np.unique(occ[grid.observed]).tolist()) <= set(range(101))
    assert np.all(occ[~grid.observed] == -1)
    assert grid.occupied(0.65)[0, 4] and not grid.occupied(0.65)[0, 1]
    assert not grid.occupied(0.3)[5, 5]  # unknown is never occupied, whatever the threshold


def test_world_cell_conversions_are_vectorised_and_consistent():
    grid = OccupancyGrid.covering(-3.0, -2.0, 4.0, 5.0, GridParams(resolution=0.05))
    rng = np.random.default_rng(1)
    pts = rng.uniform([-3, -2], [4, 5], size=(500, 2))
    cells = grid.world_to_cell(pts)
    assert cells.shape == (500, 2) and cells.dtype == np.int64
    assert grid.in_bounds(cells).all()
    centres = grid.cell_to_world(cells)
    assert np.all(np.abs(centres - pts) <= 0.025 + 1e-9)
    np.testing.assert_array_equal(grid.world_to_cell(centres), cells)
    assert grid.world_to_cell(np.zeros((4, 7, 2))).shape == (4, 7, 2)
    assert not grid.in_bounds(grid.world_to_cell([[100.0, 0.0]]))[0]
    xmin, ymin, xmax, ymax = grid.extent()
    assert xmin <= -3.0 < xmin + 0.05 and ymax > 5.0


def test_crop_to_observed_keeps_cells_in_place():
    grid = OccupancyGrid(GridParams(resolution=0.1))
    grid.integrate_scan([2.0, 3.0, 0.0], [1.0, 1.5], [0.0, 1.0])
    cropped = grid.crop_to_observed(margin=2)
    cells = np.argwhere(grid.observed)
    rows = cells[:, 0].max() - cells[:, 0].min() + 1
    cols = cells[:, 1].max() - cells[:, 1].min() + 1
    assert cropped.shape == (rows + 4, cols + 4)
    centres = grid.cell_to_world(cells)
    moved = cropped.world_to_cell(centres)
    np.testing.assert_array_equal(
        cropped.occupancy()[moved[:, 0], moved[:, 1]], grid.occupancy()[cells[:, 0], cells[:, 1]]
    )
    assert int(cropped.observed.sum()) == len(cells)
    assert not cropped.observed[:2].any() and not cropped.observed[:, -2:].any()
    assert OccupancyGrid(GridParams()).crop_to_observed().shape == (0, 0)
    # The copy is independent.
    cropped.integrate_scan([2.0, 3.0, 0.0], [1.0], [0.0])
    assert grid.occupancy()[tuple(grid.world_to_cell([3.0, 3.0]))] == HIT


def test_from_occupancy_round_trips_map_values():
    occ = np.array([[-1, 0, 50], [100, 97, 12]], dtype=np.int8)
    grid = OccupancyGrid.from_occupancy(occ, 0.1, (1.0, -2.0))
    assert grid.origin == (1.0, -2.0) and grid.resolution == 0.1
    np.testing.assert_array_equal(grid.occupancy(), [[-1, 12, 50], [97, 97, 12]])  # clamped


# ----------------------------------------------------------------------------- likelihood field, simulation


def test_distance_field_matches_brute_force():
    occ = np.zeros((30, 40), dtype=bool)
    occ[[3, 17, 25], [5, 30, 12]] = True
    dist = distance_field(occ, 0.05, 0.6)
    rr, cc = np.mgrid[0:30, 0:40]
    brute = np.min(
        [np.hypot(rr - r, cc - c) * 0.05 for r, c in [(3, 5), (17, 30), (25, 12)]], axis=0
    )
    np.testing.assert_allclose(dist, np.minimum(brute, 0.6), atol=1e-6)
    assert np.all(distance_field(np.zeros((5, 5), bool), 0.05, 0.6) == np.float32(0.6))


def test_likelihood_field_lookups():
    grid = unit_grid()
    grid.integrate_scan([0.5, 4.5, 0.0], [6.0], [0.0])  # occupied cell (4, 6), centre (6.5, 4.5)
    field = likelihood_field(grid, 3.0)
    assert field.distance.shape == grid.shape
    got = field.lookup([[6.5, 4.5], [4.5, 4.5], [5.5, 4.5], [6.5, 6.5], [50.0, 50.0], [np.nan, 1.0]])
    np.testing.assert_allclose(got, [0.0, 2.0, 1.0, 2.0, 3.0, 3.0], atol=1e-6)
    # Bilinear between centres: halfway between distance 2 and 1 is 1.5.
    assert field.lookup([[5.0, 4.5]])[0] == pytest.approx(1.5)
    # The gradient points away from the obstacle and matches finite differences.
    x, y = 4.2, 5.3
    value, gx, gy = field.gradient(x, y)
    h = 1e-4

    def at(px, py):
        return bilinear_at(field.distance, 0.0, 0.0, 1.0, px, py, 3.0)

    num_x = (at(x + h, y) - at(x - h, y)) / (2 * h)
    num_y = (at(x, y + h) - at(x, y - h)) / (2 * h)
    assert gx == pytest.approx(num_x, abs=1e-6) and gy == pytest.approx(num_y, abs=1e-6)
    assert gx < 0.0  # the obstacle is at larger x
    assert bilinear_gradient_at(field.distance, 0.0, 0.0, 1.0, -5.0, 1.0, 3.0) == (3.0, 0.0, 0.0)


def test_cast_rays_in_a_box():
    occ = np.zeros((50, 80), dtype=bool)  # 0.1 m cells: 8 m x 5 m
    occ[0, :] = occ[-1, :] = True
    occ[:, 0] = occ[:, -1] = True
    occ[20:30, 79] = False  # a door in the right wall
    angles = np.array([0.0, math.pi / 2, math.pi, -math.pi / 2, math.atan2(1.0, 2.0)])
    got = cast_rays(occ, 0.0, 0.0, 0.1, 2.0, 1.0, 0.0, angles, 20.0)
    np.testing.assert_allclose(got[:4], [5.9, 3.9, 1.9, 0.9], atol=1e-9)
    # Slope 1/2: reaches the right wall (x = 7.9) at y = 3.95, above the door.
    assert got[4] == pytest.approx(math.hypot(5.9, 2.95), abs=1e-9)
    through_door = cast_rays(occ, 0.0, 0.0, 0.1, 2.0, 2.5, 0.0, np.array([0.0]), 20.0)
    assert np.isnan(through_door[0])
    short = cast_rays(occ, 0.0, 0.0, 0.1, 2.0, 1.0, 0.0, np.array([0.0]), 3.0)
    assert np.isnan(short[0])  # wall beyond max_range
