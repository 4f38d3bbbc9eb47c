"""Map quality measured without ground truth.

* :func:`wall_thickness`: a map built from a good trajectory has walls one or
  two cells thick, because every scan puts a wall in the same cells. It is a
  property of the map alone, and it catches moderate pose noise (walls smeared
  over a few parallel positions). It does *not* catch gross pose errors in a
  log-odds map: when scans disagree by metres, the free-space rays of one scan
  erase the walls another one drew, and what survives is scattered thin
  fragments (the Intel log mapped from raw odometry has median thickness 1).
* :func:`scan_agreement`: the fraction of beam endpoints that land on an
  occupied cell of the map when every scan is placed at its pose. It needs
  the scans again, but it separates good from bad trajectories on every real
  log (Intel: 0.78 with the reference trajectory, 0.11 with raw odometry).
* :func:`scan_consistency`: the same per scan, against a map rebuilt from the
  trajectory with the shared mapper: the mean over scans and the share of
  scans that mostly miss the map. It catches one part of a map turned or
  shifted against the rest (those scans' walls are erased by the others'
  free rays), which the counts of :func:`map_quality` do not.
* :func:`map_quality`: the ground-truth-free measures of Filatov et al. 2017
  (share of occupied among known cells, corners, enclosed free areas). They
  only rank maps *of the same place at the same resolution* against each
  other; on their own the numbers mean little.

Map quality against a ground-truth map:

* :func:`obstacle_points`: the occupied cells of a grid as world points.
* :func:`map_to_truth`: nearest-neighbour distances between the obstacle cells
  of a SLAM map and of a ground-truth map, both ways (truth -> map is Santos et
  al. 2013's normalised k-NN error, k = 1, in metres), with precision, recall
  and F1 at a distance tolerance.
* :func:`align_maps`: ICP (point-to-plane by default) of a map's obstacle cells
  onto the truth's, for when only a ground-truth map (no ground-truth
  trajectory) gives the frame.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray
from numba import njit

from slam2d.core import se2
from slam2d.core.frames import Frame
from slam2d.errors import InputError
from slam2d.grids.raycast import cast_rays
from slam2d.io.tum import poses_at_scans

if TYPE_CHECKING:
    from scipy.spatial import cKDTree

# scipy.ndimage and scipy.spatial are imported where they are used: `slam2d map` needs neither,
# and importing them costs it about 0.3 s.

__all__ = [
    "run_lengths",
    "wall_thickness",
    "scan_agreement",
    "scan_consistency",
    "obstacle_points",
    "map_to_truth",
    "visible_walls",
    "align_maps",
    "ICP_METHODS",
    "map_quality",
]


@njit(cache=True)
def _row_runs(m, out, cap):
    """``out[r, k]`` = the length (at most ``cap``) of the run of True cells along row ``r`` through ``m[r, k]``."""
    rows, cols = m.shape
    for r in range(rows):
        c = 0
        while c < cols:
            if not m[r, c]:
                c += 1
                continue
            end = c
            while end < cols and m[r, end]:
                end += 1
            for k in range(c, end):
                out[r, k] = min(end - c, cap)
            c = end


#: columns whose vertical runs are held at once by _thickness_of_occupied
_THICKNESS_BAND = 256


@njit(cache=True)
def _thickness_of_occupied(m):
    """min(run along the row, run along the column) for every True cell of ``m`` (in no particular order).

    Column bands of ``_THICKNESS_BAND`` columns at a time: only a band's column runs are held (uint16, capped at
    65535 cells), and each row's runs are walked where they cross the band. One whole-map uint16 array of
    column runs took 87 MB of crsm's 443 MB peak writing its 43-million-cell fr101 map.
    """
    rows, cols = m.shape
    out = np.empty(np.count_nonzero(m), np.int32)
    down = np.zeros((rows, min(cols, _THICKNESS_BAND)), np.uint16)
    n = 0
    for c0 in range(0, cols, _THICKNESS_BAND):
        c1 = min(c0 + _THICKNESS_BAND, cols)
        _row_runs(m[:, c0:c1].T, down[:, : c1 - c0].T, 65535)  # the band's column runs: rows of the transposed views
        for r in range(rows):  # each row's runs where they cross the band
            c = c0
            while c < c1:
                if not m[r, c]:
                    c += 1
                    continue
                start = c
                while start > 0 and m[r, start - 1]:
                    start -= 1
                end = c
                while end < cols and m[r, end]:
                    end += 1
                length = end - start
                for k in range(c, min(end, c1)):
                    out[n] = min(length, np.int32(down[r, k - c0]))
                    n += 1
                c = end
    return out


def run_lengths(mask: ArrayLike) -> NDArray[np.int32]:
    """For each True cell, the length of the run of consecutive True cells along its row.

    False cells get 0. Compiled, one pass, no array but the answer (the cumulative-sum version took five
    int64 copies of the map: 200 MB at once for fr101's odometry map).
    """
    m = np.asarray(mask, dtype=np.bool_)
    if m.ndim != 2:
        raise ValueError(f"expected a 2D mask, got shape {m.shape}")
    out = np.zeros(m.shape, dtype=np.int32)
    if m.size:
        _row_runs(m, out, np.iinfo(np.int32).max)
    return out


def wall_thickness(
    occupancy: Any, *, occupied_threshold: float = 0.65
) -> dict[str, float]:
    """How thick the walls of a map are, in cells.

    For every occupied cell, the runs of occupied cells through it along x and
    along y are measured and the shorter one is taken: a wall running along x
    counts its thickness in y and vice versa. A diagonal line one cell wide
    counts 1 if it is 8-connected and 2 if it is a 4-connected staircase (as
    ray-traced diagonal walls are), so "one or two cells" is the sharp range.

    ``occupancy`` is an :class:`~slam2d.grids.occupancy.OccupancyGrid`, an int8
    ``nav_msgs/OccupancyGrid``-style array (-1 unknown, 0..100; occupied when
    ``value >= 100 * occupied_threshold``) or a boolean occupied mask.

    Returns ``{"median", "p90", "mean", "occupied_cells"}`` (thickness in cells;
    NaN when nothing is occupied).
    """
    mask = _occupied_mask(occupancy, occupied_threshold)
    thickness = _thickness_of_occupied(np.ascontiguousarray(mask))
    if thickness.size == 0:
        nan = float("nan")
        return {"median": nan, "p90": nan, "mean": nan, "occupied_cells": 0}
    return {
        "median": float(np.median(thickness)),
        "p90": float(np.percentile(thickness, 90)),
        "mean": float(thickness.mean()),
        "occupied_cells": int(thickness.size),
    }


def _occupied_mask(occupancy: Any, threshold: float) -> NDArray[np.bool_]:
    if hasattr(occupancy, "occupied") and callable(occupancy.occupied):
        return np.asarray(occupancy.occupied(threshold), dtype=np.bool_)
    arr = np.asarray(occupancy)
    if arr.ndim != 2:
        raise ValueError(f"expected a 2D map, got shape {arr.shape}")
    if arr.dtype == np.bool_:
        return arr
    return (arr >= 100.0 * threshold) & (arr <= 100)


def scan_agreement(
    grid: Any,
    frames: Iterable[Frame],
    pose_times: ArrayLike,
    poses: ArrayLike,
    *,
    occupied_threshold: float = 0.65,
    max_pose_gap: float = 1.0,
) -> dict[str, float]:
    """How well the scans agree with a map: the fraction of endpoints on occupied cells.

    Every frame is placed at the trajectory's pose at its timestamp (as
    :func:`~slam2d.grids.mapping.map_from_poses` does; frames without a pose
    are skipped) and each beam endpoint with a return is looked up in
    ``grid`` (an :class:`~slam2d.grids.occupancy.OccupancyGrid`). Endpoints off
    the grid count as misses.

    Returns ``{"fraction", "endpoints", "scans"}``.
    """
    hits = _hits_per_scan(grid, frames, pose_times, poses, occupied_threshold, max_pose_gap)
    on_wall = int(hits[:, 0].sum())
    endpoints = int(hits[:, 1].sum())
    fraction = on_wall / endpoints if endpoints else float("nan")
    return {"fraction": float(fraction), "endpoints": endpoints, "scans": int(hits.shape[0])}


def _hits_per_scan(
    grid: Any, frames: Iterable[Frame], pose_times: ArrayLike, poses: ArrayLike, occupied_threshold: float,
    max_pose_gap: float,
) -> NDArray[np.int64]:
    """``(scans, 2)``: endpoints on occupied cells and endpoints with a return, per placed scan."""
    occupied = grid.occupied(occupied_threshold)
    rows = []
    for frame, pose in poses_at_scans(frames, pose_times, poses, max_pose_gap):
        if pose is None:
            continue
        laser = se2.compose(pose, frame.scan.mount)
        points = se2.transform_points(laser, frame.scan.points())
        cells = grid.hit_cells(laser[:2], points)  # the cells the mapper marks, boundaries included
        inside = grid.in_bounds(cells)
        rows.append((int(occupied[cells[inside, 0], cells[inside, 1]].sum()), int(points.shape[0])))
    return np.array(rows, dtype=np.int64).reshape(-1, 2)


def scan_consistency(
    frames: Iterable[Frame],
    pose_times: ArrayLike,
    poses: ArrayLike,
    *,
    resolution: float = 0.05,
    low: float = 0.3,
    occupied_threshold: float = 0.65,
    max_pose_gap: float = 1.0,
) -> dict[str, Any]:
    """How consistent a trajectory's map is, without ground truth: per-scan agreement with the common map.

    The scans (a sequence: it is read twice) are mapped at the trajectory
    with :func:`~slam2d.grids.mapping.map_from_poses` (log-odds, cells of
    ``resolution`` m), then each scan's share of endpoints on an occupied
    cell is taken. Where part of a map is turned or shifted against the rest,
    the scans of one version see through the other's walls, the log-odds
    erase them, and those scans land mostly on free cells: the ``mean``
    falls and the share of scans below ``low`` (``low_share``) rises. Scans
    with no return are left out. Comparable between trajectories of the same
    log (on mines-exp2: hector 0.66, raw odometry 0.55).

    Returns ``{"mean", "p10", "low_share", "scans", "per_scan"}`` (``per_scan`` a
    float array, one value per placed scan with a return).
    """
    from slam2d.grids.mapping import map_from_poses
    from slam2d.grids.occupancy import GridParams

    frames = list(frames)
    grid, _ = map_from_poses(frames, pose_times, poses, params=GridParams(resolution=resolution),
                             max_pose_gap=max_pose_gap)
    hits = _hits_per_scan(grid, frames, pose_times, poses, occupied_threshold, max_pose_gap)
    hits = hits[hits[:, 1] > 0]
    per_scan = hits[:, 0] / hits[:, 1] if hits.shape[0] else np.zeros(0)
    if per_scan.shape[0] == 0:
        nan = float("nan")
        return {"mean": nan, "p10": nan, "low_share": nan, "scans": 0, "per_scan": per_scan}
    return {
        "mean": float(per_scan.mean()),
        "p10": float(np.percentile(per_scan, 10)),
        "low_share": float(np.mean(per_scan < low)),
        "scans": int(per_scan.shape[0]),
        "per_scan": per_scan,
    }


# --------------------------------------------------------------------------- against a ground-truth map

# Slack on "within tolerance": cell centres computed from different origins
# differ from the exact distance by round-off of a few 1e-16 m.
_DISTANCE_SLACK = 1e-9


def _as_float(value: Any) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


def _check_probability(value: float, name: str) -> float:
    v = _as_float(value)
    if not 0.0 < v < 1.0:
        raise InputError(f"{value!r} is not a probability strictly between 0 and 1", field=name)
    return v


def _as_transform(transform: ArrayLike, name: str) -> NDArray[np.float64]:
    try:
        arr = np.asarray(transform, dtype=np.float64)
    except (TypeError, ValueError):
        arr = np.full(0, np.nan)
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise InputError(f"{transform!r} is not a finite transform [x, y, theta]", field=name)
    return arr


def obstacle_points(
    grid: Any, *, occupied_threshold: float = 0.65, transform: ArrayLike | None = None
) -> NDArray[np.float64]:
    """World ``[x, y]`` of the centres of a grid's occupied cells, ``(N, 2)``.

    A cell is occupied as :meth:`~slam2d.grids.occupancy.OccupancyGrid.occupied`
    says (observed, probability above ``occupied_threshold``). With
    ``transform`` ``[x, y, theta]`` the points are mapped by
    :func:`slam2d.core.se2.transform_points` (e.g. from a SLAM map's frame into
    the ground truth's frame).
    """
    _check_probability(occupied_threshold, "occupied_threshold")
    rows, cols = np.nonzero(grid.occupied(occupied_threshold))
    points = grid.cell_to_world(np.stack([rows, cols], axis=-1))
    if transform is not None:
        points = se2.transform_points(_as_transform(transform, "transform"), points)
    return np.asarray(points, dtype=np.float64).reshape(-1, 2)


def _distance_stats(distances: NDArray[np.float64]) -> dict[str, float]:
    return {
        "mean": float(distances.mean()),
        "median": float(np.median(distances)),
        "p95": float(np.percentile(distances, 95)),
        "max": float(distances.max()),
    }


def _truth_points(truth: Any, occupied_threshold: float) -> NDArray[np.float64]:
    points = obstacle_points(truth, occupied_threshold=occupied_threshold)
    if points.shape[0] == 0:
        raise InputError("the ground-truth map has no occupied cells", field="truth")
    return points


@njit(cache=True)
def _mark_first_hits(occupied, origin_x, origin_y, resolution, poses, angles, max_range, seen):
    rows, cols = occupied.shape
    for k in range(poses.shape[0]):
        x, y, theta = poses[k, 0], poses[k, 1], poses[k, 2]
        ranges = cast_rays(occupied, origin_x, origin_y, resolution, x, y, theta, angles, max_range)
        for i in range(angles.shape[0]):
            r = ranges[i]
            if r != r:  # NaN: nothing within range
                continue
            # half a cell past the entry point lies inside the hit cell
            a = theta + angles[i]
            px = x + (r + 0.5 * resolution) * math.cos(a)
            py = y + (r + 0.5 * resolution) * math.sin(a)
            col = int(math.floor((px - origin_x) / resolution))
            row = int(math.floor((py - origin_y) / resolution))
            if 0 <= row < rows and 0 <= col < cols and occupied[row, col]:
                seen[row, col] = True


def visible_walls(
    truth: Any,
    laser_poses: ArrayLike,
    *,
    angles: ArrayLike,
    max_range: float,
    occupied_threshold: float = 0.65,
) -> NDArray[np.bool_]:
    """The true obstacle cells a laser could have hit from the given poses (a mask over ``truth``).

    Rays are cast in the ground-truth map from every laser pose ``[x, y,
    theta]`` (truth frame) at ``angles`` (radians, relative to the laser) up
    to ``max_range``; the first obstacle cell of each ray is marked. Walls the
    robot never saw then do not count against a map (:func:`map_to_truth`'s
    ``truth_visible``).
    """
    occupied = np.ascontiguousarray(truth.occupied(occupied_threshold))
    poses = np.ascontiguousarray(np.asarray(laser_poses, dtype=np.float64).reshape(-1, 3))
    seen = np.zeros(occupied.shape, dtype=np.bool_)
    if poses.shape[0] == 0 or occupied.size == 0:
        return seen
    ox, oy = truth.origin
    _mark_first_hits(occupied, float(ox), float(oy), float(truth.resolution), poses,
                     np.ascontiguousarray(np.asarray(angles, dtype=np.float64)), float(max_range), seen)
    return seen


def map_to_truth(
    grid: Any,
    truth: Any,
    *,
    transform: ArrayLike | None = None,
    tolerance: float = 0.1,
    occupied_threshold: float = 0.65,
    truth_visible: NDArray[np.bool_] | None = None,
) -> dict[str, Any]:
    """Compare a SLAM map's obstacle cells with a ground-truth map's, in metres.

    ``grid`` is the SLAM map and ``truth`` the ground-truth map (both
    :class:`~slam2d.grids.occupancy.OccupancyGrid`, any resolutions and
    origins: cells are compared as points at their centres).
    ``transform`` ``[x, y, theta]`` maps the SLAM map's coordinates into the
    truth's frame (None: they share a frame; see :func:`align_maps`).

    Returns::

        {"truth_to_map_m": stats of the distance from each true obstacle cell to
                           the nearest map obstacle cell (Santos et al. 2013's
                           normalised k-NN error with k = 1, in metres: missing
                           or misplaced walls),
         "map_to_truth_m": the same from each map obstacle cell to the truth
                           (ghost walls, smeared walls),
         "precision": share of map obstacle cells within ``tolerance`` of a true one,
         "recall": share of true obstacle cells within ``tolerance`` of a map one,
         "f1": their harmonic mean, "tolerance_m": tolerance,
         "map_cells": map obstacle cells, "truth_cells": true obstacle cells,
         "truth_cells_total": every true obstacle cell, seen or not,
         "truth_cells_between": true cells on a map cell boundary (see below)}

    where stats are ``{"mean", "median", "p95", "max"}``. "Within" includes
    the tolerance itself.

    Every true obstacle cell counts, so walls the robot never saw count as
    missing (they raise ``truth_to_map_m`` and lower recall), unless
    ``truth_visible`` (a boolean mask over ``truth``, see
    :func:`visible_walls`) limits the true cells to those the laser could have
    hit; ``truth_cells_total`` then says how many there are in all. With different resolutions even identical walls are
    some fraction of a cell apart (cell centres do not coincide).

    When the truth is at least twice as fine as the map, the true cells are first put on
    the map's lattice: each becomes the map cells a perfect map could mark for it (one, or
    two or four when the true cell lies across a map cell boundary: a wall on the boundary
    belongs to either neighbour, and the mapper's side of it is luck), and is judged by the
    nearest of them; ``truth_cells`` then counts these units (one per map cell off
    boundaries) and ``truth_cells_between`` those with a choice. In the other direction a
    map cell on any of the choices lies on a true wall.

    A map with no obstacle cells gives ``truth_to_map_m`` all infinite,
    ``map_to_truth_m`` all NaN, precision NaN, recall 0 and F1 0. A truth with
    no obstacle cells raises :class:`~slam2d.errors.InputError`.
    """
    tol = _as_float(tolerance)
    if not (math.isfinite(tol) and tol > 0.0):
        raise InputError(f"{tolerance!r} is not a positive distance in metres", field="tolerance")
    truth_pts = all_truth_pts = _truth_points(truth, occupied_threshold)
    n_truth_total = int(truth_pts.shape[0])
    if truth_visible is not None:
        mask = np.asarray(truth_visible, dtype=np.bool_)
        if mask.shape != tuple(truth.shape):
            raise ValueError(f"truth_visible: shape {mask.shape} does not match the truth's {tuple(truth.shape)}")
        occupied = truth.occupied(occupied_threshold)
        rows, cols = np.nonzero(occupied & mask)
        if rows.size:
            truth_pts = truth.cell_to_world(np.stack([rows, cols], axis=1))
    map_pts = obstacle_points(grid, occupied_threshold=occupied_threshold, transform=transform)
    on_lattice = float(truth.resolution) <= 0.5 * float(grid.resolution)
    if on_lattice:
        # A map can only put a wall at its own cell centres: judged against the exact wall, a
        # perfect map would score up to half a diagonal cell depending on where its lattice
        # happens to fall. Judging it against the cells a perfect map on its own lattice
        # could mark takes that luck out (needs a truth finer than the map to know them).
        choices = _lattice_choices(truth_pts, float(truth.resolution), grid, transform)
        all_choices = _lattice_choices(all_truth_pts, float(truth.resolution), grid, transform)
        truth_pts = choices.centres
        all_truth_pts = all_choices.centres
    n_map = int(map_pts.shape[0])
    n_truth = int(choices.units.shape[0]) if on_lattice else int(truth_pts.shape[0])
    # True cells a perfect map could draw in two (or four) map cells: walls on cell boundaries.
    n_between = int(np.count_nonzero(np.any(choices.units != choices.units[:, :1], axis=1))) if on_lattice else 0
    if n_map == 0:
        inf, nan = float("inf"), float("nan")
        return {
            "truth_to_map_m": {"mean": inf, "median": inf, "p95": inf, "max": inf},
            "map_to_truth_m": {"mean": nan, "median": nan, "p95": nan, "max": nan},
            "precision": nan,
            "recall": 0.0,
            "f1": 0.0,  # the limit of 2PR / (P + R) as R -> 0, whatever P is
            "tolerance_m": tol,
            "map_cells": 0,
            "truth_cells": n_truth,
            "truth_cells_total": n_truth_total,
            "truth_cells_between": n_between,
        }
    from scipy.spatial import cKDTree

    truth_to_map = cKDTree(map_pts).query(truth_pts, k=1)[0]
    if on_lattice:
        # Each true cell is judged by the best of the map cells the wall could fall in.
        truth_to_map = truth_to_map[choices.units].min(axis=1)
    # A map wall on a true wall is no ghost, seen or not: the reverse direction uses every true cell.
    map_to_truth_d = cKDTree(all_truth_pts).query(map_pts, k=1)[0]
    within = tol + _DISTANCE_SLACK
    precision = float(np.mean(map_to_truth_d <= within))
    recall = float(np.mean(truth_to_map <= within))
    f1 = 2.0 * precision * recall / (precision + recall) if precision + recall > 0.0 else 0.0
    return {
        "truth_to_map_m": _distance_stats(truth_to_map),
        "map_to_truth_m": _distance_stats(map_to_truth_d),
        "precision": precision,
        "recall": recall,
        "f1": float(f1),
        "tolerance_m": tol,
        "map_cells": n_map,
        "truth_cells": n_truth,
        "truth_cells_total": n_truth_total,
        "truth_cells_between": n_between,
    }


class _LatticeChoices(NamedTuple):
    """True wall cells moved onto a map's lattice (see :func:`_lattice_choices`)."""

    centres: NDArray[np.float64]  # (C, 2) truth-frame centres of every map cell a true wall may fall in
    units: NDArray[np.int64]  # (U, 4) rows of ``centres``: the choices of one true cell (repeats allowed)


def _lattice_choices(
    points: NDArray[np.float64], truth_resolution: float, grid: Any, transform: ArrayLike | None
) -> _LatticeChoices:
    """The ``grid`` cells a perfect map could mark for true obstacle cells centred at ``points``.

    A true cell of side ``truth_resolution`` only says the wall passes somewhere inside it. The
    map cells it may fall in are those whose inside overlaps the true cell (taken along the
    map's axes, around its centre mapped into the map's frame): one cell, or two or four when
    the true cell lies across a map cell boundary. A wall exactly on a boundary, as walls at
    round coordinates are on a lattice anchored at 0, belongs to both neighbours; which of
    them a mapper marks is luck (the side it is seen from, range noise). Needs
    ``truth_resolution`` at most half the map's, so there are at most two per axis.

    Returns the centres (truth frame) of the distinct cells, and for each distinct set of
    choices (true cells with the same choices are one unit, so a wall counts once per map
    cell it falls in) the indices of its choices, padded by repeating one.
    """
    to_truth = None if transform is None else _as_transform(transform, "transform")
    in_map = points if to_truth is None else se2.transform_points(se2.inverse(to_truth), points)
    in_map = np.asarray(in_map, dtype=np.float64).reshape(-1, 2)
    res = float(grid.resolution)
    origin = np.asarray(grid.origin, dtype=np.float64)
    # The true cell, shrunk by a hair so that a map cell it only touches along an edge is out.
    half = 0.5 * truth_resolution - _DISTANCE_SLACK
    low = np.floor((in_map - half - origin) / res).astype(np.int64)  # [x, y] cells
    high = np.floor((in_map + half - origin) / res).astype(np.int64)
    # The four corners' cells: (low | high) in x times (low | high) in y, as [row, col].
    corners = np.stack(
        [
            np.stack([low[:, 1], low[:, 0]], axis=-1),
            np.stack([low[:, 1], high[:, 0]], axis=-1),
            np.stack([high[:, 1], low[:, 0]], axis=-1),
            np.stack([high[:, 1], high[:, 0]], axis=-1),
        ],
        axis=1,
    )  # (N, 4, 2)
    cells, index = np.unique(corners.reshape(-1, 2), axis=0, return_inverse=True)
    units = _minimal_sets(index.reshape(-1, 4))
    centres = grid.cell_to_world(cells)
    if to_truth is not None:
        centres = se2.transform_points(to_truth, centres)
    return _LatticeChoices(np.asarray(centres, dtype=np.float64).reshape(-1, 2), units)


# The 14 non-empty proper subsets of 4 slots, as masks.
_SUBSET_MASKS = np.array([[(m >> k) & 1 for k in range(4)] for m in range(1, 15)], dtype=np.bool_)


def _canonical_sets(rows: NDArray[np.int64]) -> NDArray[np.int64]:
    """Rows of up to 4 indices (repeats allowed, -1 = none) as sets: distinct values sorted, -1 first."""
    s = np.sort(rows, axis=1)
    repeat = np.zeros(s.shape, dtype=np.bool_)
    repeat[:, 1:] = s[:, 1:] == s[:, :-1]
    s[repeat] = -1
    return np.sort(s, axis=1)


def _minimal_sets(rows: NDArray[np.int64]) -> NDArray[np.int64]:
    """The distinct sets among ``rows`` ``(N, 4)`` that hold no other one, padded by repeating.

    A true cell whose choices include all of another's adds nothing (a wall cell lying on a
    boundary next to one inside a cell); without boundaries every set is one cell and this
    is one unit per map cell, as before choices existed.
    """
    units = np.unique(_canonical_sets(rows), axis=0)
    n = units.shape[0]
    size = np.count_nonzero(units >= 0, axis=1)
    subsets = np.where(_SUBSET_MASKS[None, :, :], units[:, None, :], -1).reshape(-1, 4)
    subsets = _canonical_sets(subsets)
    sub_size = np.count_nonzero(subsets >= 0, axis=1).reshape(n, -1)
    ids = np.unique(np.concatenate([units, subsets]), axis=0, return_inverse=True)[1].reshape(-1)
    is_unit = np.zeros(int(ids.max()) + 1, dtype=np.bool_)
    is_unit[ids[:n]] = True
    proper = (sub_size > 0) & (sub_size < size[:, None])
    redundant = np.any(proper & is_unit[ids[n:].reshape(n, -1)], axis=1)
    kept = units[~redundant]
    # Pad with the set's largest index (the last column, never -1).
    return np.where(kept >= 0, kept, kept[:, -1:]).astype(np.int64)


def _rigid_fit(source: NDArray[np.float64], target: NDArray[np.float64]) -> NDArray[np.float64]:
    """The rigid motion ``[x, y, theta]`` that best maps ``source`` onto ``target`` (least squares)."""
    src_mean = source.mean(axis=0)
    dst_mean = target.mean(axis=0)
    a = source - src_mean
    b = target - dst_mean
    # Maximising sum(b . R a) over the angle has this closed form in 2D.
    cos_part = float(np.sum(a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1]))
    sin_part = float(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]))
    theta = math.atan2(sin_part, cos_part)
    c, s = math.cos(theta), math.sin(theta)
    tx = dst_mean[0] - (c * src_mean[0] - s * src_mean[1])
    ty = dst_mean[1] - (s * src_mean[0] + c * src_mean[1])
    return np.array([tx, ty, theta])


#: the ways :func:`align_maps` can pair cells
ICP_METHODS = ("point-to-plane", "point-to-point")
_NORMAL_NEIGHBOURS = 7


def _wall_normals(points: NDArray[np.float64], tree: cKDTree) -> NDArray[np.float64]:
    """Unit normals ``(N, 2)`` of the walls through each point, from its 7 nearest neighbours.

    The wall runs along the direction in which the neighbours spread most
    (principal axis of their scatter); the normal is perpendicular to it.
    """
    k = min(_NORMAL_NEIGHBOURS, points.shape[0])
    nearest = tree.query(points, k=k)[1].reshape(points.shape[0], k)
    spread = points[nearest] - points[nearest].mean(axis=1, keepdims=True)
    sxx = np.sum(spread[..., 0] ** 2, axis=1)
    syy = np.sum(spread[..., 1] ** 2, axis=1)
    sxy = np.sum(spread[..., 0] * spread[..., 1], axis=1)
    along = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)
    return np.stack([-np.sin(along), np.cos(along)], axis=-1)


def _point_to_plane_step(
    source: NDArray[np.float64], target: NDArray[np.float64], normals: NDArray[np.float64]
) -> NDArray[np.float64]:
    """The rigid motion that best moves ``source`` onto the walls through ``target``.

    Minimises the squared distances along ``normals`` (linearised in the
    angle, about the source's centroid for good conditioning; the next
    iteration corrects the linearisation). A direction no wall constrains
    (all walls parallel) gets no motion.
    """
    centre = source.mean(axis=0)
    rel = source - centre
    residual = np.sum(normals * (source - target), axis=1)
    jacobian = np.stack(
        [normals[:, 0], normals[:, 1], normals[:, 1] * rel[:, 0] - normals[:, 0] * rel[:, 1]],
        axis=-1,
    )
    dx, dy, dtheta = np.linalg.lstsq(jacobian, -residual, rcond=None)[0]
    c, s = math.cos(dtheta), math.sin(dtheta)
    # Rotate by dtheta about the centre, then move by (dx, dy).
    return np.array(
        [
            centre[0] + dx - (c * centre[0] - s * centre[1]),
            centre[1] + dy - (s * centre[0] + c * centre[1]),
            dtheta,
        ]
    )


def align_maps(
    grid: Any,
    truth: Any,
    *,
    initial: ArrayLike | None = None,
    iterations: int = 30,
    occupied_threshold: float = 0.65,
    method: str = "point-to-plane",
) -> tuple[NDArray[np.float64], dict[str, Any]]:
    """The transform ``[x, y, theta]`` from a SLAM map's frame into a ground-truth map's.

    ICP of the map's obstacle cell centres onto the truth's, starting from
    ``initial`` (default: identity). Each iteration pairs every map point with
    its nearest true point (KD-tree), drops pairs farther apart than a gate,
    and solves the rigid motion of the kept pairs in closed form:

    * ``"point-to-plane"`` (default) minimises each pair's distance along the
      true wall's normal (estimated from the 7 nearest true cells), so map
      cells may slide along a wall;
    * ``"point-to-point"`` minimises the distance between the paired centres.
      It locks about half a cell short: when the maps are shifted along a
      wall, the cells on that wall pair with the cell next door and pull
      back. A 10 m floor shifted by 0.25 m along x came out 0.222 m
      (point-to-plane: 0.250); over 30 random offsets of up to 0.3 m and 5 deg
      the median error was 10 mm / 0.08 deg (point-to-plane: 1.3 mm / 0.004 deg).

    The gate starts open and shrinks to three times the 90th percentile of the
    pair distances whenever that is smaller (not the median: when most walls
    run along the offset, they match at once and the few across it are all
    far), but never below two cells of the coarser map, so ghost walls and
    unexplored parts (up to a tenth of the map) stop pulling once the maps are
    close. It stops when a step moves less than 1 um and 1e-8 rad, or after
    ``iterations`` steps.

    ICP only finds the nearest local optimum: start it within roughly a wall
    spacing and a few degrees of the answer (``initial``), and expect a
    symmetric place (a plain rectangle) to align as well the wrong way round.

    Returns ``(transform, {"iterations", "rmse_m", "inliers", "converged"})``:
    the steps taken, the RMS distance from the kept map cells to their nearest
    true cells after the last step (m; cell centres, so about a third of a
    cell for perfectly aligned maps drawn in different frames), how many map
    cells were kept, and whether it stopped by convergence. Pass
    ``transform`` to :func:`map_to_truth`.
    """
    if method not in ICP_METHODS:
        raise InputError(f"{method!r} is not one of {', '.join(ICP_METHODS)}", field="method")
    try:
        steps = int(iterations)
    except (TypeError, ValueError):
        steps = 0
    if steps < 1:
        raise InputError(f"{iterations!r}: need at least one iteration", field="iterations")
    transform = np.zeros(3) if initial is None else _as_transform(initial, "initial")
    target = _truth_points(truth, occupied_threshold)
    source = obstacle_points(grid, occupied_threshold=occupied_threshold)
    if source.shape[0] < 3:
        raise InputError(
            f"the map has {source.shape[0]} occupied cells; aligning needs at least 3",
            field="grid",
        )
    from scipy.spatial import cKDTree

    tree = cKDTree(target)
    normals = _wall_normals(target, tree) if method == "point-to-plane" else None
    min_gate = 2.0 * max(float(grid.resolution), float(truth.resolution))
    gate = math.inf
    converged = False
    done = 0
    for done in range(1, steps + 1):
        moved = se2.transform_points(transform, source)
        dist, nearest = tree.query(moved, k=1)
        gate = max(min_gate, min(gate, 3.0 * float(np.percentile(dist, 90))))
        # At least 90 % of the cells are within the gate, so never fewer than 3.
        keep = dist <= gate
        paired = nearest[keep]
        if normals is not None:
            step = _point_to_plane_step(moved[keep], target[paired], normals[paired])
        else:
            step = _rigid_fit(moved[keep], target[paired])
        transform = se2.compose(step, transform)
        if math.hypot(step[0], step[1]) < 1e-6 and abs(step[2]) < 1e-8:
            converged = True
            break
    dist = tree.query(se2.transform_points(transform, source), k=1)[0]
    keep = dist <= gate
    rmse = float(np.sqrt(np.mean(dist[keep] ** 2))) if keep.any() else float("nan")
    info = {"iterations": done, "rmse_m": rmse, "inliers": int(keep.sum()), "converged": converged}
    return np.asarray(transform, dtype=np.float64), info


# --------------------------------------------------------------------------- without ground truth

# Harris detector settings (cells): the image is smoothed by one Gaussian, the
# structure tensor summed over another, R = det - k * trace^2, and cells with R
# above a share of the map's strongest response are corner cells. Tuned on
# rasterised rooms: with a window of 1 cell or a threshold of 1 %, a third of
# a 3 m x 2 m room's orientations (0-90 deg in 1 deg steps) scored 5-14 corners
# instead of 4, from the staircases of slanted walls; with these, none did.
_HARRIS_SMOOTHING = 1.0
_HARRIS_WINDOW = 1.5
_HARRIS_K = 0.05
_HARRIS_RELATIVE_THRESHOLD = 0.05


@njit(cache=True)
def _find(parent, i):
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


@njit(cache=True)
def region_sizes(mask):
    """Cells of every 4-connected region of True cells, in no particular order.

    Row by row, each run of True cells is joined (union-find) to the runs of the row below it that share a
    column: memory for the runs, not for a label per cell.
    """
    rows, cols = mask.shape
    cap = 1024
    parent = np.empty(cap, np.int64)
    size = np.empty(cap, np.int64)
    prev_start = np.empty(cols, np.int64)
    prev_end = np.empty(cols, np.int64)
    prev_id = np.empty(cols, np.int64)
    cur_start = np.empty(cols, np.int64)
    cur_end = np.empty(cols, np.int64)
    cur_id = np.empty(cols, np.int64)
    n_prev = 0
    n = 0
    for r in range(rows):
        n_cur = 0
        c = 0
        while c < cols:
            if not mask[r, c]:
                c += 1
                continue
            start = c
            while c < cols and mask[r, c]:
                c += 1
            if n == cap:
                cap *= 2
                grown_parent = np.empty(cap, np.int64)
                grown_size = np.empty(cap, np.int64)
                grown_parent[:n] = parent[:n]
                grown_size[:n] = size[:n]
                parent, size = grown_parent, grown_size
            parent[n] = n
            size[n] = c - start
            cur_start[n_cur], cur_end[n_cur], cur_id[n_cur] = start, c, n
            n += 1
            n_cur += 1
        # join each run to the runs of the row before that overlap it (a two-pointer walk: both are sorted)
        i = j = 0
        while i < n_cur and j < n_prev:
            if cur_start[i] < prev_end[j] and prev_start[j] < cur_end[i]:
                a, b = _find(parent, cur_id[i]), _find(parent, prev_id[j])
                if a != b:
                    if size[a] < size[b]:
                        a, b = b, a
                    parent[b] = a
                    size[a] += size[b]
            if cur_end[i] < prev_end[j]:
                i += 1
            else:
                j += 1
        prev_start[:n_cur] = cur_start[:n_cur]
        prev_end[:n_cur] = cur_end[:n_cur]
        prev_id[:n_cur] = cur_id[:n_cur]
        n_prev = n_cur
    roots = 0
    for k in range(n):
        if parent[k] == k:
            roots += 1
    out = np.empty(roots, np.int64)
    m = 0
    for k in range(n):
        if parent[k] == k:
            out[m] = size[k]
            m += 1
    return out


_HARRIS_BAND = 128  # rows per band of the corner response (each band's filters hold about 8 float copies of it)


def _harris_response(image: NDArray[np.float32]) -> NDArray[np.float32]:
    from scipy import ndimage

    # Without smoothing, the staircase of a rasterised slanted wall is a row of
    # tiny corners (a room rotated by 10 degrees scored 30 corners instead of 4).
    image = ndimage.gaussian_filter(image, _HARRIS_SMOOTHING, mode="constant")
    grad_x = ndimage.sobel(image, axis=1, mode="constant")
    grad_y = ndimage.sobel(image, axis=0, mode="constant")
    sxx = ndimage.gaussian_filter(grad_x * grad_x, _HARRIS_WINDOW, mode="constant")
    syy = ndimage.gaussian_filter(grad_y * grad_y, _HARRIS_WINDOW, mode="constant")
    sxy = ndimage.gaussian_filter(grad_x * grad_y, _HARRIS_WINDOW, mode="constant")
    return sxx * syy - sxy * sxy - _HARRIS_K * (sxx + syy) ** 2


def _count_corners(occupied: NDArray[np.bool_]) -> int:
    """Harris corners of the occupied-cell image (1 occupied, 0 anything else)."""
    rows_any = np.flatnonzero(occupied.any(axis=1))
    if rows_any.size == 0:
        return 0
    cols_any = np.flatnonzero(occupied.any(axis=0))
    # Crop to the walls with enough empty margin that no filter sees the crop edge.
    pad = 2 + int(4.0 * _HARRIS_SMOOTHING + 0.5) + int(4.0 * _HARRIS_WINDOW + 0.5)
    crop = occupied[rows_any[0] : rows_any[-1] + 1, cols_any[0] : cols_any[-1] + 1]
    rows, cols = crop.shape[0] + 2 * pad, crop.shape[1] + 2 * pad

    def bands():
        """``(r0, r1, response of rows r0:r1)``: bands of rows that overlap by the filters' reach (pad), so each
        band's own rows come out exactly as from the whole image, with a few float copies of a band in memory
        instead of eight of the map."""
        for r0 in range(0, rows, _HARRIS_BAND):
            lo, hi = max(0, r0 - pad), min(rows, r0 + _HARRIS_BAND + pad)
            band = np.zeros((hi - lo, cols), dtype=np.float32)
            c_lo, c_hi = max(lo - pad, 0), min(hi - pad, crop.shape[0])  # the crop rows inside this band
            if c_hi > c_lo:
                band[c_lo + pad - lo : c_hi + pad - lo, pad : pad + crop.shape[1]] = crop[c_lo:c_hi]
            r1 = min(rows, r0 + _HARRIS_BAND)
            yield r0, r1, _harris_response(band)[r0 - lo : r1 - lo]

    peak = max(float(response.max()) for _, _, response in bands())
    if peak <= 0.0:
        return 0
    strong = np.zeros((rows, cols), dtype=np.bool_)
    for r0, r1, response in bands():  # computed again: cheaper than holding the whole response
        strong[r0:r1] = response > _HARRIS_RELATIVE_THRESHOLD * peak
    return _count_blobs(strong)


@njit(cache=True)
def _count_blobs(mask):
    """8-connected blobs of True cells, counted by flood fill (``mask`` is cleared; no label image)."""
    rows, cols = mask.shape
    n = 0
    for r in range(rows):
        for c in range(cols):
            if mask[r, c]:
                n += 1
    stack_r = np.empty(n, np.int64)
    stack_c = np.empty(n, np.int64)
    count = 0
    for r in range(rows):
        for c in range(cols):
            if not mask[r, c]:
                continue
            count += 1
            mask[r, c] = False
            top = 0
            stack_r[0], stack_c[0] = r, c
            top = 1
            while top > 0:
                top -= 1
                y, x = stack_r[top], stack_c[top]
                for dy in range(-1, 2):
                    for dx in range(-1, 2):
                        yy, xx = y + dy, x + dx
                        if 0 <= yy < rows and 0 <= xx < cols and mask[yy, xx]:
                            mask[yy, xx] = False  # cleared when pushed: each cell once on the stack
                            stack_r[top], stack_c[top] = yy, xx
                            top += 1
    return count


def _cell_classes(grid: Any, occ_p: float, free_p: float) -> tuple[int, NDArray[np.bool_], NDArray[np.bool_]]:
    """``(observed cells, occupied, free)`` of an OccupancyGrid, or of a map as read (MapImage, int8 values).

    Compared in log-odds, as the grid stores them, so a loaded value of exactly 100 * free_threshold counts as
    free. A MapImage's values are looked up in per-value tables that make the same float32 comparisons, a band
    of rows at a time: no six-byte-a-cell grid for a map that is only measured."""
    free_logodds = np.float32(math.log(free_p / (1.0 - free_p)))
    occupied_logodds = np.float32(math.log(occ_p / (1.0 - occ_p)))
    if callable(getattr(grid, "occupancy", None)):  # an OccupancyGrid
        observed = np.asarray(grid.observed, dtype=np.bool_)
        occupied = (grid.logodds > occupied_logodds) & observed
        return int(observed.sum()), occupied, observed & (grid.logodds <= free_logodds) & ~occupied
    from slam2d.core.arrays import row_bands
    from slam2d.grids.occupancy import occupancy_logodds

    table = occupancy_logodds()  # what MapImage.to_grid() stores
    occupied_table = np.append(table > occupied_logodds, False)  # index 101: unknown (-1, or over 100)
    free_table = np.append((table <= free_logodds) & ~(table > occupied_logodds), False)
    values = grid.occupancy
    occupied = np.empty(values.shape, dtype=np.bool_)
    free = np.empty_like(occupied)
    observed = 0
    for rows in row_bands(values.shape):
        band = values[rows]
        known = (band >= 0) & (band <= 100)
        observed += int(np.count_nonzero(known))
        index = np.where(known, band, 101).astype(np.intp)
        occupied[rows], free[rows] = occupied_table[index], free_table[index]
    return observed, occupied, free


def map_quality(
    grid: Any,
    *,
    occupied_threshold: float = 0.65,
    free_threshold: float = 0.25,
    min_area_cells: int = 4,
) -> dict[str, Any]:
    """Map quality without ground truth (Filatov et al. 2017's measures).

    ``grid`` is an :class:`~slam2d.grids.occupancy.OccupancyGrid` or a map as read
    (:class:`~slam2d.io.map_server.MapImage`: the same numbers, a sixth of the memory). Among
    observed cells, a cell is *occupied* when its probability is above
    ``occupied_threshold`` (as :meth:`OccupancyGrid.occupied` and map_server
    decide), *free* when it is at most ``free_threshold``, and *uncertain* in
    between. Returns::

        {"occupied_fraction": occupied / (occupied + free): higher than another
                              map of the same place means blurred or thick walls,
         "uncertain_fraction": uncertain / observed,
         "corners": Harris corners of the walls,
         "enclosed_areas": 4-connected regions of free cells with at least
                           min_area_cells cells (the explored space is one;
                           misaligned or double walls close off extra ones),
         "largest_area_fraction": cells of the largest free region / all free cells,
         "observed_m2": observed area, square metres}

    Corners: the image is 1 on occupied cells and 0 elsewhere (free, uncertain
    and unknown alike, so the edge of the explored region is not structure;
    only walls make corners). It is smoothed by a Gaussian of sigma 1 cell
    (so slanted walls drawn as pixel staircases do not count as rows of
    corners), Sobel gradients give the structure tensor, summed over a
    Gaussian window of sigma 1.5 cells, Harris's ``R = det - 0.05 trace^2``
    above 5 % of the map's strongest response marks corner cells, and each
    8-connected blob of them is one corner. A wall end (a door jamb) counts as
    a corner too; features closer than about 10 cells can merge into one. The direction of "better" is disputed: the paper's is fewer
    (double walls and misalignment add corners), while some tools read more
    corners as more detail. Counts depend on resolution.

    All of these only compare maps of the same place at the same resolution
    (e.g. two SLAM methods, or two settings, on one log); alone they mean
    little. Fractions are NaN when their denominator is 0.

    On real logs (Intel, FR079, FR101, ACES; 5 cm log-odds maps from the
    reference trajectory vs raw odometry) the odometry map always had many
    more enclosed areas (1093 vs 23 on Intel) and a larger uncertain
    fraction, but a *lower* occupied fraction (0.018 vs 0.065 on Intel: with
    poses metres off, the free-space rays of one scan erase the walls another
    drew, which is the reverse of the mild blurring the measure was made for),
    and fewer corners on three logs out of four.
    """
    occ_p = _check_probability(occupied_threshold, "occupied_threshold")
    free_p = _check_probability(free_threshold, "free_threshold")
    if not free_p < occ_p:
        raise InputError(
            f"{free_threshold!r} must be below occupied_threshold {occupied_threshold!r}",
            field="free_threshold",
        )
    try:
        min_area = int(min_area_cells)
    except (TypeError, ValueError):
        min_area = 0
    if min_area < 1 or min_area != min_area_cells:
        raise InputError(f"{min_area_cells!r} is not a positive whole number", field="min_area_cells")
    n_observed, occupied, free = _cell_classes(grid, occ_p, free_p)
    n_occupied = int(occupied.sum())
    n_free = int(free.sum())
    n_uncertain = n_observed - n_occupied - n_free
    nan = float("nan")
    # 4-connected free regions, sized from runs of free cells (no label image: 110 MB of int32 for a diverged
    # crsm map of 28 M cells)
    sizes = region_sizes(np.ascontiguousarray(free))
    del free  # before the corners: a map of 10^7 cells is 10 MB a copy
    if sizes.size:
        enclosed = int(np.count_nonzero(sizes >= min_area))
        largest = float(sizes.max()) / n_free
    else:
        enclosed, largest = 0, nan
    known = n_occupied + n_free
    return {
        "occupied_fraction": n_occupied / known if known else nan,
        "uncertain_fraction": n_uncertain / n_observed if n_observed else nan,
        "corners": _count_corners(occupied),
        "enclosed_areas": enclosed,
        "largest_area_fraction": largest,
        "observed_m2": n_observed * float(grid.resolution) ** 2,
    }
