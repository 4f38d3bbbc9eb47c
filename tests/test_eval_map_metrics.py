"""Map quality metrics: against a ground-truth map (k-NN distances, ICP) and without one."""

from __future__ import annotations

import math

import numpy as np
import pytest

from slam2d.core import se2
from slam2d.errors import InputError
from slam2d.eval.map_metrics import align_maps, map_quality, map_to_truth, obstacle_points
from slam2d.grids import OccupancyGrid

RES = 0.05
PAD = 5  # unknown cells around the test rooms
UNKNOWN, FREE, OCCUPIED = -1, 0, 100


def make_grid(values: np.ndarray, resolution: float = RES, origin=(0.0, 0.0)) -> OccupancyGrid:
    return OccupancyGrid.from_occupancy(values, resolution, origin)


def room_values(height: int = 40, width: int = 60, thickness: int = 1) -> np.ndarray:
    """A closed rectangular room: walls ``thickness`` cells thick, free inside, unknown around.

    The room's outer cells are rows PAD..PAD+height-1 and cols PAD..PAD+width-1.
    """
    values = np.full((height + 2 * PAD, width + 2 * PAD), UNKNOWN, dtype=np.int16)
    inner = values[PAD : PAD + height, PAD : PAD + width]
    inner[:] = OCCUPIED
    inner[thickness:-thickness, thickness:-thickness] = FREE
    return values


def polyline(corners, spacing: float = 0.002) -> np.ndarray:
    """Dense points along the segments between consecutive corners."""
    c = np.asarray(corners, dtype=np.float64)
    pieces = []
    for a, b in zip(c[:-1], c[1:]):
        n = max(2, int(math.ceil(np.hypot(*(b - a)) / spacing)) + 1)
        t = np.linspace(0.0, 1.0, n)[:, None]
        pieces.append(a + t * (b - a))
    return np.concatenate(pieces)


def rasterise(points: np.ndarray, shape, origin=(0.0, 0.0), resolution: float = RES) -> np.ndarray:
    """Occupancy values with every cell holding a point occupied, the rest unknown."""
    values = np.full(shape, UNKNOWN, dtype=np.int16)
    cols = np.floor((points[:, 0] - origin[0]) / resolution).astype(int)
    rows = np.floor((points[:, 1] - origin[1]) / resolution).astype(int)
    assert rows.min() >= 0 and cols.min() >= 0, "test geometry leaves the grid"
    assert rows.max() < shape[0] and cols.max() < shape[1], "test geometry leaves the grid"
    values[rows, cols] = OCCUPIED
    return values


# ----------------------------------------------------------------------------- obstacle points


def test_obstacle_points_are_cell_centres_with_row_zero_at_lowest_y():
    values = np.full((5, 6), FREE, dtype=np.int16)
    values[1, 4] = OCCUPIED
    values[3, 0] = OCCUPIED
    values[2, 2] = 50  # uncertain: not an obstacle
    grid = make_grid(values, 0.1, (1.0, -2.0))
    points = obstacle_points(grid)
    got = sorted(map(tuple, np.round(points, 12).tolist()))
    assert got == sorted([(1.45, -1.85), (1.05, -1.65)])
    # [1, 2, pi/2] maps (x, y) to (1 - y, 2 + x).
    moved = obstacle_points(grid, transform=[1.0, 2.0, math.pi / 2])
    expected = np.stack([1.0 - points[:, 1], 2.0 + points[:, 0]], axis=-1)
    np.testing.assert_allclose(moved, expected, atol=1e-12)


def test_obstacle_points_follow_the_threshold_and_an_empty_grid_gives_none():
    values = np.full((3, 3), FREE, dtype=np.int16)
    values[1, 1] = 70
    grid = make_grid(values)
    assert obstacle_points(grid).shape == (1, 2)
    assert obstacle_points(grid, occupied_threshold=0.8).shape == (0, 2)
    assert obstacle_points(OccupancyGrid()).shape == (0, 2)


# ----------------------------------------------------------------------------- map vs truth


@pytest.mark.parametrize("moved_by", ["cells", "origin"])
def test_a_wall_moved_by_20_cm_is_20_cm_away_both_ways(moved_by):
    truth_values = np.full((30, 50), UNKNOWN, dtype=np.int16)
    truth_values[10, 5:45] = OCCUPIED
    truth = make_grid(truth_values)
    if moved_by == "cells":
        map_values = np.full((30, 50), UNKNOWN, dtype=np.int16)
        map_values[14, 5:45] = OCCUPIED  # 4 cells of 0.05 m = 0.2 m in +y
        grid = make_grid(map_values)
    else:
        grid = make_grid(truth_values, origin=(0.0, 0.2))
    # Every cell's nearest counterpart is straight across (same x), 0.2 m away.
    result = map_to_truth(grid, truth, tolerance=0.1)
    for key in ("truth_to_map_m", "map_to_truth_m"):
        for stat in ("mean", "median", "p95", "max"):
            assert result[key][stat] == pytest.approx(0.2, abs=1e-9), (key, stat)
    assert result["precision"] == 0.0 and result["recall"] == 0.0 and result["f1"] == 0.0
    assert result["map_cells"] == result["truth_cells"] == 40
    assert result["tolerance_m"] == 0.1
    wide = map_to_truth(grid, truth, tolerance=0.25)
    assert wide["precision"] == 1.0 and wide["recall"] == 1.0 and wide["f1"] == 1.0
    # "Within the tolerance" includes the tolerance itself.
    edge = map_to_truth(grid, truth, tolerance=0.2)
    assert edge["precision"] == 1.0 and edge["recall"] == 1.0


def test_a_room_with_one_wall_moved_outward():
    height, width, shift = 40, 60, 4  # the right wall moves 4 cells = 0.2 m outward
    truth_values = room_values(height, width)
    map_values = room_values(height, width + shift)  # same origin: only the right wall moves
    truth, grid = make_grid(truth_values), make_grid(map_values)
    result = map_to_truth(grid, truth)

    # True wall cells: every cell on the bottom, top and left walls, and both
    # ends of the right wall, are still walls in the map (its top and bottom
    # walls run past them). A true right-wall cell i cells above the bottom
    # (0 < i < height - 1) is 4 cells from the moved wall, or i cells from the
    # map's bottom wall, or height - 1 - i from its top wall, whichever is least.
    n_truth = 2 * width + 2 * (height - 2)
    i = np.arange(1, height - 1)
    right_wall = RES * np.minimum(shift, np.minimum(i, height - 1 - i))
    expected_mean = right_wall.sum() / n_truth
    assert result["truth_cells"] == n_truth
    assert result["truth_to_map_m"]["mean"] == pytest.approx(expected_mean, abs=1e-9)
    # The plain estimate: the share of cells on the moved wall times 0.2 m,
    # within a cell (only the cells near its ends are closer).
    share = (height - 2) / n_truth
    assert abs(result["truth_to_map_m"]["mean"] - share * shift * RES) < RES
    assert result["truth_to_map_m"]["max"] == pytest.approx(shift * RES, abs=1e-9)
    assert result["truth_to_map_m"]["median"] == 0.0
    assert result["map_to_truth_m"]["max"] == pytest.approx(shift * RES, abs=1e-9)
    # Recall at 0.1 m: the right-wall cells within 2 cells of the map's walls
    # (its ends and their neighbours) count; the rest do not.
    n_far = int(np.count_nonzero(right_wall > 0.1 + 1e-9))
    assert result["recall"] == pytest.approx(1.0 - n_far / n_truth)


def test_identical_maps_score_zero_and_a_transform_undoes_a_known_motion():
    values = room_values()
    values[PAD + 10, PAD : PAD + 30] = OCCUPIED  # an inner wall makes the room asymmetric
    origin = (-0.7, 0.4)
    truth = make_grid(values, origin=origin)
    same = map_to_truth(make_grid(values, origin=origin), truth)
    for key in ("truth_to_map_m", "map_to_truth_m"):
        assert same[key] == {"mean": 0.0, "median": 0.0, "p95": 0.0, "max": 0.0}
    assert same["precision"] == same["recall"] == same["f1"] == 1.0

    # The same map in a frame where the world is rotated by +90 degrees and
    # moved by (dx, dy): cell (r, c) lands at cell (c, rows - 1 - r) of the
    # rotated array when the origin is chosen as below.
    dx, dy = 1.3, -0.45
    rows = values.shape[0]
    rotated = values.T[:, ::-1]
    map_origin = (-origin[1] - rows * RES + dx, origin[0] + dy)
    grid = make_grid(np.ascontiguousarray(rotated), origin=map_origin)
    truth_to_map_frame = np.array([dx, dy, math.pi / 2])
    np.testing.assert_allclose(
        np.sort(obstacle_points(grid), axis=0),
        np.sort(se2.transform_points(truth_to_map_frame, obstacle_points(truth)), axis=0),
        atol=1e-9,
    )
    unaligned = map_to_truth(grid, truth)
    assert unaligned["truth_to_map_m"]["mean"] > 0.1
    assert unaligned["recall"] < 0.5
    aligned = map_to_truth(grid, truth, transform=se2.inverse(truth_to_map_frame))
    for key in ("truth_to_map_m", "map_to_truth_m"):
        assert aligned[key]["max"] < 1e-9
    assert aligned["precision"] == aligned["recall"] == 1.0


def test_a_ghost_wall_raises_map_to_truth_but_not_truth_to_map():
    truth_values = room_values(40, 60)
    map_values = truth_values.copy()
    # 20 cells of wall in the middle of the room: 19 cells (0.95 m) below the
    # top wall, 20 above the bottom wall, 20 from the side walls.
    map_values[PAD + 20, PAD + 20 : PAD + 40] = OCCUPIED
    result = map_to_truth(make_grid(map_values), make_grid(truth_values))
    n_room = 2 * 60 + 2 * 38
    assert result["truth_to_map_m"]["max"] == 0.0
    assert result["recall"] == 1.0
    assert result["map_to_truth_m"]["max"] == pytest.approx(0.95, abs=1e-9)
    assert result["map_to_truth_m"]["median"] == 0.0
    assert result["precision"] == pytest.approx(n_room / (n_room + 20))
    assert result["map_cells"] == n_room + 20


def test_maps_of_different_resolutions_are_compared_in_metres():
    # The same wall: y in [1.0, 1.05) at 0.05 m cells, [1.0, 1.1) at 0.1 m
    # cells. Fine centres (0.025 + 0.05 k, 1.025), coarse (0.05 + 0.1 k, 1.05):
    # every fine centre is 0.025 m off in x and in y from a coarse one. A truth
    # coarser than the map is compared as it is, centre to centre.
    fine_values = np.full((40, 40), UNKNOWN, dtype=np.int16)
    fine_values[20, 0:40] = OCCUPIED
    coarse_values = np.full((20, 20), UNKNOWN, dtype=np.int16)
    coarse_values[10, 0:20] = OCCUPIED
    fine = make_grid(fine_values, 0.05)
    coarse = make_grid(coarse_values, 0.1)
    result = map_to_truth(fine, coarse, tolerance=0.05)
    diagonal = math.hypot(0.025, 0.025)
    for key in ("truth_to_map_m", "map_to_truth_m"):
        assert result[key]["mean"] == pytest.approx(diagonal, abs=1e-9)
        assert result[key]["max"] == pytest.approx(diagonal, abs=1e-9)
    assert result["precision"] == result["recall"] == 1.0
    assert (result["map_cells"], result["truth_cells"]) == (40, 20)
    assert map_to_truth(fine, coarse, tolerance=0.03)["recall"] == 0.0


def test_a_truth_finer_than_the_map_is_judged_on_the_maps_own_cells():
    # A perfect 0.1 m map of a wall the 0.05 m truth knows more precisely: its cells are
    # where a perfect map on its lattice puts the wall, so it scores 0, not the half
    # diagonal that the cell centres' offset would give.
    fine_values = np.full((40, 40), UNKNOWN, dtype=np.int16)
    fine_values[20, 0:40] = OCCUPIED
    coarse_values = np.full((20, 20), UNKNOWN, dtype=np.int16)
    coarse_values[10, 0:20] = OCCUPIED
    perfect = map_to_truth(make_grid(coarse_values, 0.1), make_grid(fine_values, 0.05), tolerance=0.05)
    for key in ("truth_to_map_m", "map_to_truth_m"):
        assert perfect[key]["max"] == pytest.approx(0.0, abs=1e-9)
    assert perfect["truth_cells"] == 20  # one per map cell the wall falls in
    # The wall one map cell off is 0.1 m off, whatever the lattices.
    shifted_values = np.full((20, 20), UNKNOWN, dtype=np.int16)
    shifted_values[11, 0:20] = OCCUPIED
    shifted = map_to_truth(make_grid(shifted_values, 0.1), make_grid(fine_values, 0.05), tolerance=0.05)
    assert shifted["truth_to_map_m"]["mean"] == pytest.approx(0.1, abs=1e-9)
    assert shifted["recall"] == 0.0


def test_a_map_without_obstacles_scores_as_documented():
    truth = make_grid(room_values())
    empty_values = room_values()
    empty_values[empty_values == OCCUPIED] = FREE
    for grid in (make_grid(empty_values), OccupancyGrid()):
        result = map_to_truth(grid, truth)
        assert result["truth_to_map_m"] == {k: math.inf for k in ("mean", "median", "p95", "max")}
        assert all(math.isnan(v) for v in result["map_to_truth_m"].values())
        assert math.isnan(result["precision"])
        assert result["recall"] == 0.0 and result["f1"] == 0.0
        assert result["map_cells"] == 0 and result["truth_cells"] == 2 * 60 + 2 * 38


def test_a_truth_without_obstacles_is_an_input_error():
    values = room_values()
    values[values == OCCUPIED] = FREE
    with pytest.raises(InputError, match="ground-truth map has no occupied cells") as err:
        map_to_truth(make_grid(room_values()), make_grid(values))
    assert err.value.field == "truth"
    with pytest.raises(InputError) as err:
        align_maps(make_grid(room_values()), make_grid(values))
    assert err.value.field == "truth"


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"tolerance": 0.0}, "tolerance"),
        ({"tolerance": float("nan")}, "tolerance"),
        ({"tolerance": "near"}, "tolerance"),
        ({"transform": [1.0, 2.0]}, "transform"),
        ({"transform": [0.0, float("inf"), 0.0]}, "transform"),
        ({"occupied_threshold": 1.5}, "occupied_threshold"),
        ({"occupied_threshold": None}, "occupied_threshold"),
    ],
)
def test_bad_arguments_are_input_errors(kwargs, field):
    grid = make_grid(room_values())
    with pytest.raises(InputError) as err:
        map_to_truth(grid, grid, **kwargs)
    assert err.value.field == field


# ----------------------------------------------------------------------------- ICP alignment


def office_walls() -> np.ndarray:
    """Wall points of a 10 m x 8 m floor: rooms, doors, a pillar; no symmetry to confuse ICP.

    The walls run through cell centres (x.x25 m at 5 cm cells), so the
    rasterised truth has no half-cell bias.
    """
    segments = [
        [[0, 0], [10, 0], [10, 8], [0, 8], [0, 0]],  # outer walls
        [[4, 0], [4, 3]],  # a wall with a door at y 3..4
        [[4, 4], [4, 8]],
        [[0, 5], [2.5, 5]],  # a room on the left, door at x 2.5..3.3
        [[3.3, 5], [4, 5]],
        [[4, 3.5], [7, 3.5]],  # corridor wall, door at x 7..8
        [[8, 3.5], [10, 3.5]],
        [[6.5, 5.5], [7.2, 5.5], [7.2, 6.4], [6.5, 6.4], [6.5, 5.5]],  # a pillar
        [[1, 1], [2.5, 1], [2.5, 1.6]],  # a cupboard
    ]
    return np.concatenate([polyline(s) for s in segments]) + 0.025


OFFICE_SHAPE, OFFICE_ORIGIN = (230, 260), (-1.5, -1.5)


@pytest.mark.parametrize(
    ("method", "max_error_m", "max_error_deg"),
    # Over 30 random offsets of up to 0.3 m and 5 deg on this floor, the
    # worst errors were 2.5 cm / 0.06 deg (point-to-plane) and 5.2 cm / 0.31
    # deg (point-to-point, whose centres snap to centres).
    [("point-to-plane", 0.03, 0.1), ("point-to-point", 0.06, 0.35)],
)
def test_align_maps_recovers_a_known_transform(method, max_error_m, max_error_deg):
    walls = office_walls()
    truth = make_grid(rasterise(walls, OFFICE_SHAPE, OFFICE_ORIGIN), origin=OFFICE_ORIGIN)
    map_to_truth_frame = np.array([0.3, -0.2, math.radians(5.0)])
    # The map was drawn in a frame where every wall point p of the truth is at
    # inverse(T) p, so T maps the map's frame back into the truth's.
    in_map_frame = se2.transform_points(se2.inverse(map_to_truth_frame), walls)
    grid = make_grid(rasterise(in_map_frame, OFFICE_SHAPE, OFFICE_ORIGIN), origin=OFFICE_ORIGIN)

    transform, info = align_maps(grid, truth, method=method)
    assert math.hypot(transform[0] - 0.3, transform[1] + 0.2) < max_error_m
    assert abs(se2.wrap_angle(transform[2] - math.radians(5.0))) < math.radians(max_error_deg)
    assert info["converged"] and 1 <= info["iterations"] <= 30
    # Both maps are rasterised: aligned centres are up to a cell apart.
    assert info["rmse_m"] < RES
    assert info["inliers"] > 0.95 * obstacle_points(grid).shape[0]

    before = map_to_truth(grid, truth)
    after = map_to_truth(grid, truth, transform=transform)
    assert before["truth_to_map_m"]["mean"] > 0.1
    assert after["truth_to_map_m"]["mean"] < RES
    assert after["recall"] > 0.95


def test_point_to_plane_slides_along_walls_where_point_to_point_locks():
    walls = office_walls()
    truth = make_grid(rasterise(walls, OFFICE_SHAPE, OFFICE_ORIGIN), origin=OFFICE_ORIGIN)
    # A shift of exactly 5 cells along x: the map is the truth moved by whole
    # cells, so the answer is exact. Walls along x match at once, and in
    # point-to-point their cells pair with the cell next door and pull back.
    in_map_frame = se2.transform_points([-0.25, 0.0, 0.0], walls)
    grid = make_grid(rasterise(in_map_frame, OFFICE_SHAPE, OFFICE_ORIGIN), origin=OFFICE_ORIGIN)
    plane, info = align_maps(grid, truth)
    np.testing.assert_allclose(plane, [0.25, 0.0, 0.0], atol=1e-9)
    assert info["rmse_m"] < 1e-9
    point, _ = align_maps(grid, truth, method="point-to-point")
    assert 0.5 * RES < 0.25 - point[0] < RES  # short by more than half a cell


def test_align_maps_is_not_pulled_by_a_ghost_wall_or_fooled_by_sliding_walls():
    walls = office_walls()
    truth = make_grid(rasterise(walls, OFFICE_SHAPE, OFFICE_ORIGIN), origin=OFFICE_ORIGIN)
    # A pure shift along x: every wall along x matches at once, only the walls
    # across x (a minority) tell how far to move.
    shift = np.array([0.25, 0.0, 0.0])
    in_map_frame = se2.transform_points(se2.inverse(shift), walls)
    # A ghost wall 1 m long, over 1 m from every true wall.
    ghost = polyline([[5.0, 1.5], [6.0, 1.5]]) + 0.025
    values = rasterise(np.concatenate([in_map_frame, ghost]), OFFICE_SHAPE, OFFICE_ORIGIN)
    grid = make_grid(values, origin=OFFICE_ORIGIN)
    transform, info = align_maps(grid, truth)
    np.testing.assert_allclose(transform, shift, atol=1e-9)
    assert info["inliers"] == obstacle_points(grid).shape[0] - 21  # the ghost's cells are dropped


def test_align_maps_from_a_good_initial_guess_stays_there_and_rejects_bad_input():
    truth = make_grid(rasterise(office_walls(), OFFICE_SHAPE, OFFICE_ORIGIN), origin=OFFICE_ORIGIN)
    transform, info = align_maps(truth, truth, initial=[0.0, 0.0, 0.0])
    np.testing.assert_allclose(transform, 0.0, atol=1e-9)
    assert info["converged"] and info["iterations"] == 1 and info["rmse_m"] < 1e-9
    with pytest.raises(InputError) as err:
        align_maps(make_grid(np.full((4, 4), FREE, dtype=np.int16)), truth)
    assert err.value.field == "grid"
    with pytest.raises(InputError) as err:
        align_maps(truth, truth, initial=[0.0, 0.0])
    assert err.value.field == "initial"
    with pytest.raises(InputError) as err:
        align_maps(truth, truth, iterations=0)
    assert err.value.field == "iterations"
    with pytest.raises(InputError) as err:
        align_maps(truth, truth, method="point-to-line")
    assert err.value.field == "method"


# ----------------------------------------------------------------------------- without ground truth


def test_a_clean_room_has_four_corners_one_area_and_exact_fractions():
    height, width = 40, 60
    result = map_quality(make_grid(room_values(height, width)))
    walls = 2 * width + 2 * (height - 2)
    assert result["corners"] == 4
    assert result["enclosed_areas"] == 1
    assert result["largest_area_fraction"] == 1.0
    assert result["occupied_fraction"] == pytest.approx(walls / (height * width))
    assert result["uncertain_fraction"] == 0.0
    assert result["observed_m2"] == pytest.approx(height * width * RES**2)


def test_a_map_as_read_measures_the_same_as_its_grid(tmp_path):
    """map_quality of a map_server image (one byte a cell, what `slam2d evaluate` reads) equals that of the
    OccupancyGrid made from it, on every value 0..100 and unknown, thresholds' edges included."""
    from slam2d.io.map_server import read_map, write_map

    rng = np.random.default_rng(4)
    values = room_values(50, 70)
    values[5:45, 5:65] = rng.integers(-1, 101, (40, 60))  # every value, -1 unknown among them
    values[20, 10:40] = 25  # exactly free_threshold * 100
    values[21, 10:40] = 65  # exactly occupied_threshold * 100
    write_map(tmp_path / "m.yaml", values, RES, (0.0, 0.0, 0.0), mode="raw")  # raw: every value as it is
    image = read_map(tmp_path / "m.yaml")
    assert np.array_equal(image.occupancy, values)
    for thresholds in ({}, {"free_threshold": 0.3, "occupied_threshold": 0.5}):
        assert map_quality(image, **thresholds) == map_quality(image.to_grid(), **thresholds)


def test_uncertain_cells_are_counted_apart():
    values = room_values(40, 60)
    values[PAD + 10 : PAD + 15, PAD + 10 : PAD + 15] = 50  # 25 cells neither free nor occupied
    result = map_quality(make_grid(values))
    walls = 2 * 60 + 2 * 38
    assert result["uncertain_fraction"] == pytest.approx(25 / (40 * 60))
    assert result["occupied_fraction"] == pytest.approx(walls / (40 * 60 - 25))
    # The thresholds decide: at free_threshold 0.5 those cells are free.
    assert map_quality(make_grid(values), free_threshold=0.5)["uncertain_fraction"] == 0.0


def test_thick_walls_raise_the_occupied_fraction_but_not_the_corners():
    thin = map_quality(make_grid(room_values(thickness=1)))
    thick = map_quality(make_grid(room_values(thickness=3)))
    assert thick["occupied_fraction"] > 2.5 * thin["occupied_fraction"]
    assert thick["occupied_fraction"] == pytest.approx(1.0 - (40 - 6) * (60 - 6) / (40 * 60))
    assert thick["corners"] == thin["corners"] == 4


def test_a_doubled_wall_adds_corners():
    values = np.pad(room_values(40, 60), ((0, 0), (0, 20)), constant_values=UNKNOWN)
    # A copy of the bottom wall shifted 1 m up and 0.75 m right, as a bad loop
    # closure would draw it: it starts inside the room, crosses the right wall
    # and ends outside.
    values[PAD + 20, PAD + 15 : PAD + 75] = OCCUPIED
    result = map_quality(make_grid(values))
    assert result["corners"] > 4
    # Its free end, the crossing and its far end, all at least 15 cells from
    # other features: three more.
    assert result["corners"] == 7


def test_a_door_gap_adds_its_two_jambs():
    values = room_values(40, 60)
    values[PAD, PAD + 25 : PAD + 35] = FREE
    assert map_quality(make_grid(values))["corners"] == 6


@pytest.mark.parametrize("degrees", [0.0, 5.0, 10.0, 25.0, 45.0])
def test_a_slanted_room_still_has_four_corners(degrees):
    # Drawn at an angle the walls become pixel staircases; smoothing keeps the
    # stairs from counting as corners.
    walls = polyline([[0, 0], [3, 0], [3, 2], [0, 2], [0, 0]])
    walls = se2.transform_points([2.5, 0.5, math.radians(degrees)], walls)
    values = rasterise(walls, (120, 120), (0.0, 0.0))
    assert map_quality(make_grid(values))["corners"] == 4


def test_an_inner_wall_splits_the_room_into_two_areas():
    values = room_values(40, 60)
    values[PAD : PAD + 40, PAD + 30] = OCCUPIED  # floor to ceiling
    result = map_quality(make_grid(values))
    assert result["enclosed_areas"] == 2
    # Free columns 1..29 and 31..58 of the room, 38 rows each.
    assert result["largest_area_fraction"] == pytest.approx(29 / (29 + 28))


def test_small_free_pockets_count_only_from_min_area_cells():
    values = room_values(40, 60)
    values[1, 1:3] = FREE  # a 2-cell free pocket in the unknown margin
    assert map_quality(make_grid(values))["enclosed_areas"] == 1
    assert map_quality(make_grid(values), min_area_cells=2)["enclosed_areas"] == 2
    # Free cells touching only diagonally are separate areas (4-connectivity).
    values[2, 3] = FREE
    assert map_quality(make_grid(values), min_area_cells=1)["enclosed_areas"] == 3


def test_map_quality_of_an_empty_map():
    result = map_quality(OccupancyGrid())
    assert result["corners"] == 0 and result["enclosed_areas"] == 0
    assert result["observed_m2"] == 0.0
    for key in ("occupied_fraction", "uncertain_fraction", "largest_area_fraction"):
        assert math.isnan(result[key])
    only_free = map_quality(make_grid(np.full((10, 10), FREE, dtype=np.int16)))
    assert only_free["corners"] == 0 and only_free["occupied_fraction"] == 0.0
    assert only_free["enclosed_areas"] == 1


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"free_threshold": 0.7}, "free_threshold"),
        ({"occupied_threshold": 0.0}, "occupied_threshold"),
        ({"min_area_cells": 0}, "min_area_cells"),
        ({"min_area_cells": 2.5}, "min_area_cells"),
    ],
)
def test_map_quality_rejects_bad_arguments(kwargs, field):
    with pytest.raises(InputError) as err:
        map_quality(make_grid(room_values()), **kwargs)
    assert err.value.field == field


def test_walls_the_laser_never_saw_do_not_count_when_a_visibility_mask_is_given():
    from slam2d.eval.map_metrics import visible_walls

    # two rooms side by side, 3 m x 2 m each, sharing a wall with no door
    values = np.zeros((40, 120), dtype=np.int8)
    values[0, :] = values[-1, :] = 100
    values[:, 0] = values[:, 59] = values[:, -1] = 100
    truth = make_grid(values)
    # the laser sits in the left room only and sees all around, 10 m
    angles = np.linspace(-np.pi, np.pi, 720, endpoint=False)
    seen = visible_walls(truth, [[1.5, 1.0, 0.0]], angles=angles, max_range=10.0)
    xs = truth.cell_to_world(np.argwhere(seen))[:, 0]
    assert seen.sum() > 100 and xs.max() < 3.0  # nothing of the right room's far walls
    # a map of exactly what was seen: perfect with the mask, "missing walls" without it
    seen_map = make_grid(np.where(seen, 100, 0).astype(np.int8))
    with_mask = map_to_truth(seen_map, truth, truth_visible=seen)
    without = map_to_truth(seen_map, truth)
    assert with_mask["truth_to_map_m"]["max"] == 0.0 and with_mask["recall"] == 1.0
    assert without["truth_to_map_m"]["mean"] > 0.5 and without["recall"] < 0.6
    assert with_mask["truth_cells"] == int(seen.sum()) < with_mask["truth_cells_total"]
    # the ghost-wall direction still uses every true wall: the map's walls all lie on true ones
    assert with_mask["map_to_truth_m"]["max"] == 0.0


# ----------------------------------------------------------------------------- walls on cell boundaries


def _boundary_wall_truth() -> OccupancyGrid:
    """A wall along y = 1.0 at 0.02 m, as slam2d.sim.world.rasterize draws it: true cells centred on it."""
    values = np.full((101, 151), UNKNOWN, dtype=np.int16)  # rows centred on 0.02 k, k = 0..100
    values[50, 10:141] = OCCUPIED  # y = 1.0, x from 0.2 to 2.8
    return make_grid(values, 0.02, origin=(-0.01, -0.01))


@pytest.mark.parametrize(("row", "expected"), [(19, 0.0), (20, 0.0), (18, 0.05), (21, 0.05)])
def test_a_wall_on_a_map_cell_boundary_may_be_drawn_on_either_side(row, expected):
    # y = 1.0 is the boundary between the 0.05 m cells [0.95, 1.0] (row 19) and [1.0, 1.05]
    # (row 20). A mapper marks the cell behind the wall as seen from the robot (the near
    # one is crossed by rays that end just behind the boundary): either is right, and
    # the next one out is a cell off. Before, the truth went to row 20 only (floor), so
    # a perfect map drawing row 19 scored 0.05 m.
    truth = _boundary_wall_truth()
    values = np.full((40, 60), UNKNOWN, dtype=np.int16)
    values[row, 4:56] = OCCUPIED  # x 0.2 .. 2.8
    result = map_to_truth(make_grid(values), truth, tolerance=0.04)
    assert result["truth_to_map_m"]["mean"] == pytest.approx(expected, abs=1e-9)
    assert result["map_to_truth_m"]["mean"] == pytest.approx(expected, abs=1e-9)
    assert result["recall"] == (1.0 if expected == 0.0 else 0.0)
    # one unit per map cell along the wall, not two (a cell's two choices are one wall cell)
    assert result["truth_cells"] == result["truth_cells_between"] == 52


def test_a_wall_drawn_on_both_sides_of_a_boundary_is_no_ghost():
    truth = _boundary_wall_truth()
    values = np.full((40, 60), UNKNOWN, dtype=np.int16)
    values[19:21, 4:56] = OCCUPIED
    result = map_to_truth(make_grid(values), truth)
    assert result["truth_to_map_m"]["max"] == result["map_to_truth_m"]["max"] == 0.0


def test_a_wall_inside_a_map_cell_still_has_one_right_cell():
    # y = 1.02: inside [1.0, 1.05] with its whole true cell [1.01, 1.03]; the next cell is wrong.
    values = np.full((101, 151), UNKNOWN, dtype=np.int16)
    values[51, 10:141] = OCCUPIED
    truth = make_grid(values, 0.02, origin=(-0.01, -0.01))
    for row, expected in ((20, 0.0), (19, 0.05), (21, 0.05)):
        grid_values = np.full((40, 60), UNKNOWN, dtype=np.int16)
        grid_values[row, 4:56] = OCCUPIED
        result = map_to_truth(make_grid(grid_values), truth)
        assert result["truth_to_map_m"]["mean"] == pytest.approx(expected, abs=1e-9)


@pytest.mark.parametrize("laser", ["rplidar-a1", "urg-04lx"])
def test_a_map_at_the_true_poses_scores_near_zero_on_a_simulated_floor(laser):
    # The RPLidar's known-poses map of corridor-loop scored 0.017 m (office: 0.019 m), as much
    # as karto's: the walls there lie at whole metres, on the 0.05 m map's cell boundaries,
    # and the RPLidar's long grazing rays erase the near cell, so the map draws each wall in
    # the cell behind it, and for the walls seen from above or from the right the truth
    # (floor) said the other one.
    from slam2d.core import se2
    from slam2d.eval.map_metrics import visible_walls
    from slam2d.grids.mapping import map_from_poses
    from slam2d.sim.laser import laser_preset
    from slam2d.sim.simulate import SimulationParams, simulate
    from slam2d.sim.world import rasterize

    sim = simulate("corridor-loop", SimulationParams(seed=0, laser=laser))
    truth = rasterize(sim.world, resolution=0.02)
    spec = laser_preset(laser)
    seen = visible_walls(truth, se2.compose(sim.scan_truth, sim.scans[0].mount), angles=spec.angles,
                         max_range=spec.range_max)
    grid, _ = map_from_poses(sim.frames(), sim.scan_times, sim.scan_truth)
    result = map_to_truth(grid, truth, truth_visible=seen)
    assert result["truth_to_map_m"]["mean"] < 0.003
    assert result["map_to_truth_m"]["mean"] < 0.003
    assert result["recall"] > 0.99


def test_corners_counted_in_bands_equal_the_whole_image_count():
    """The corner response is computed in overlapping bands of rows (memory); the count must not change."""
    from scipy import ndimage

    import slam2d.eval.map_metrics as mm

    def whole(occupied):
        rows = np.flatnonzero(occupied.any(axis=1))
        cols = np.flatnonzero(occupied.any(axis=0))
        pad = 2 + int(4.0 * mm._HARRIS_SMOOTHING + 0.5) + int(4.0 * mm._HARRIS_WINDOW + 0.5)
        image = np.pad(occupied[rows[0]: rows[-1] + 1, cols[0]: cols[-1] + 1].astype(np.float32), pad)
        response = mm._harris_response(image)
        strong = response > mm._HARRIS_RELATIVE_THRESHOLD * float(response.max())
        return ndimage.label(strong, structure=np.ones((3, 3), dtype=np.bool_))[1]

    rng = np.random.default_rng(1)
    occ = np.zeros((1300, 900), bool)  # three bands of 512 rows
    for _ in range(200):
        r, c = rng.integers(0, 1300), rng.integers(0, 900)
        occ[r: r + rng.integers(1, 80), c: c + 3] = True
        r, c = rng.integers(0, 1300), rng.integers(0, 900)
        occ[r: r + 2, c: c + rng.integers(1, 80)] = True
    assert mm._count_corners(occ) == whole(occ) > 100
    blobs = rng.random((300, 400)) > 0.7
    assert mm._count_blobs(blobs.copy()) == ndimage.label(blobs, structure=np.ones((3, 3)))[1]


def test_region_sizes_are_scipys_four_connected_labels_counted():
    from scipy import ndimage

    from slam2d.eval.map_metrics import region_sizes

    rng = np.random.default_rng(11)
    for _ in range(100):  # every density, empty and one-row masks among them
        m = rng.random((int(rng.integers(0, 30)), int(rng.integers(0, 30)))) < rng.random()
        labels, n = ndimage.label(m)
        expected = sorted(np.bincount(labels.ravel())[1:].tolist()) if n else []
        assert sorted(region_sizes(np.ascontiguousarray(m)).tolist()) == expected
    # a U: two arms joined only at the bottom row are one region
    u = np.zeros((5, 5), bool)
    u[:, 0] = u[:, 4] = u[4, :] = True
    assert region_sizes(u).tolist() == [13]
