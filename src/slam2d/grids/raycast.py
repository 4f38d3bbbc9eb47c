"""Compiled ray casting on a regular grid: the hot loops of mapping and simulation.

Conventions shared by every kernel here: a grid is a 2D array indexed
``[row, col]``; ``row`` counts cells along world y and ``col`` along world x;
``(origin_x, origin_y)`` is the world position of the lower-left corner of cell
``[0, 0]`` and ``resolution`` the cell size in metres. A world point falls in
cell ``(floor((y - origin_y) / resolution), floor((x - origin_x) / resolution))``.

Rays are traversed exactly (Amanatides & Woo, "A fast voxel traversal
algorithm", 1987): a ray visits every cell whose interior the segment crosses,
in order, one cell per step. A segment passing exactly through a cell corner
(within 1e-9 of a cell) steps diagonally, so the two cells it only touches are
not visited; this keeps a 45-degree beam one cell wide. The number of steps is
fixed in advance (``|dcol| + |drow|`` at most), so a traversal always ends on
the endpoint's cell, whatever the rounding.

All kernels are ``@njit(cache=True)``: the first call in a fresh environment
compiles them (a few seconds, cached on disk afterwards).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = [
    "integrate_rays",
    "trace_ray",
    "cast_rays",
    "world_to_cell",
    "first_crossings",
    "step",
    "end_coords",
]

# Corner crossings closer than this (in cells) count as exact: step diagonally.
_CORNER_EPS = 1e-9
# A hit is moved this far along its beam (in cells) before its cell is found, so that a beam
# ending exactly on a cell boundary (a noise-free wall at round coordinates) marks the cell
# beyond it, where the wall's material is, not the free cell in front that it crossed.
HIT_NUDGE = 1e-6


@njit(cache=True, inline="always")
def world_to_cell(x, y, origin_x, origin_y, resolution):
    """``(row, col)`` of the cell containing world point ``(x, y)`` (may be outside the grid)."""
    col = int(math.floor((x - origin_x) / resolution))
    row = int(math.floor((y - origin_y) / resolution))
    return row, col


@njit(cache=True)
def first_crossings(u0, v0, du, dv, col, row):
    """Ray parameters (0..1 along the segment) of the first x and y cell-boundary crossings."""
    if du > 0.0:
        t_max_x = (col + 1.0 - u0) / du
        t_delta_x = 1.0 / du
    elif du < 0.0:
        t_max_x = (u0 - col) / -du
        t_delta_x = -1.0 / du
    else:
        t_max_x = np.inf
        t_delta_x = np.inf
    if dv > 0.0:
        t_max_y = (row + 1.0 - v0) / dv
        t_delta_y = 1.0 / dv
    elif dv < 0.0:
        t_max_y = (v0 - row) / -dv
        t_delta_y = -1.0 / dv
    else:
        t_max_y = np.inf
        t_delta_y = np.inf
    return t_max_x, t_delta_x, t_max_y, t_delta_y


@njit(cache=True, inline="always")
def step(col, row, end_col, end_row, step_c, step_r, t_max_x, t_delta_x, t_max_y, t_delta_y):
    """One traversal step to the next cell: ``(col, row, t_max_x, t_max_y)`` after it.

    Once the ray is in the end cell's column (row) it only moves along the
    other axis, so rounding can never carry it past the end cell.
    """
    if col == end_col:
        return col, row + step_r, t_max_x, t_max_y + t_delta_y
    if row == end_row:
        return col + step_c, row, t_max_x + t_delta_x, t_max_y
    if t_max_x < t_max_y - _CORNER_EPS:
        return col + step_c, row, t_max_x + t_delta_x, t_max_y
    if t_max_y < t_max_x - _CORNER_EPS:
        return col, row + step_r, t_max_x, t_max_y + t_delta_y
    # exactly through a corner: step diagonally
    return col + step_c, row + step_r, t_max_x + t_delta_x, t_max_y + t_delta_y


@njit(cache=True)
def trace_ray(x0, y0, x1, y1, origin_x, origin_y, resolution, out_rows, out_cols):
    """Cells crossed by the segment ``(x0, y0) -> (x1, y1)``, start and end cells included.

    Writes them in order into ``out_rows`` / ``out_cols`` (int arrays, at least
    ``|dcol| + |drow| + 1`` long; extra cells are dropped) and returns how many
    were written. Cells may lie outside any particular grid: callers check.
    """
    u0 = (x0 - origin_x) / resolution
    v0 = (y0 - origin_y) / resolution
    u1 = (x1 - origin_x) / resolution
    v1 = (y1 - origin_y) / resolution
    col = int(math.floor(u0))
    row = int(math.floor(v0))
    end_col = int(math.floor(u1))
    end_row = int(math.floor(v1))
    du = u1 - u0
    dv = v1 - v0
    step_c = 1 if du > 0.0 else -1
    step_r = 1 if dv > 0.0 else -1
    t_max_x, t_delta_x, t_max_y, t_delta_y = first_crossings(u0, v0, du, dv, col, row)
    capacity = out_rows.shape[0]
    count = 0
    max_steps = abs(end_col - col) + abs(end_row - row)
    for _ in range(max_steps + 1):
        if count < capacity:
            out_rows[count] = row
            out_cols[count] = col
            count += 1
        if col == end_col and row == end_row:
            break
        col, row, t_max_x, t_max_y = step(
            col, row, end_col, end_row, step_c, step_r, t_max_x, t_delta_x, t_max_y, t_delta_y
        )
    return count


@njit(cache=True, inline="always")
def end_coords(u0, v0, x, y, origin_x, origin_y, resolution, is_hit):
    """A beam's end in cell units; a hit moved ``HIT_NUDGE`` cells on along the beam."""
    u1 = (x - origin_x) / resolution
    v1 = (y - origin_y) / resolution
    if is_hit:
        length = math.hypot(u1 - u0, v1 - v0)
        if length > 0.0:
            u1 += HIT_NUDGE * (u1 - u0) / length
            v1 += HIT_NUDGE * (v1 - v0) / length
    return u1, v1


@njit(cache=True)
def integrate_rays(
    logodds,
    stamp,
    scan_stamp,
    origin_x,
    origin_y,
    resolution,
    start_x,
    start_y,
    end_x,
    end_y,
    is_hit,
    l_hit,
    l_miss,
    l_min,
    l_max,
):
    """Apply one scan's beams to a log-odds grid, each cell updated at most once.

    Every beam starts at ``(start_x, start_y)`` (the laser) and ends at
    ``(end_x[i], end_y[i])``. Beams with ``is_hit[i]`` add ``l_hit`` to their
    endpoint cell (a hit exactly on a cell boundary belongs to the cell beyond it,
    along the beam: the wall's side); then every beam adds ``l_miss`` to the cells it crosses
    before its endpoint cell (a beam without a hit clears its endpoint cell
    too). Hits are applied first and a cell takes one update per scan
    (``stamp[r, c] == scan_stamp`` marks it done), so a wall cell grazed by a
    neighbouring beam stays occupied and the many beams that overlap near the
    laser count once. Results are clamped to ``[l_min, l_max]``. Cells outside
    the array are skipped. ``stamp != 0`` doubles as the "observed" mask.

    Returns the number of cells updated.
    """
    rows, cols = logodds.shape
    n = end_x.shape[0]
    updated = 0
    u0 = (start_x - origin_x) / resolution
    v0 = (start_y - origin_y) / resolution
    for i in range(n):
        if not is_hit[i]:
            continue
        u1, v1 = end_coords(u0, v0, end_x[i], end_y[i], origin_x, origin_y, resolution, True)
        col = int(math.floor(u1))
        row = int(math.floor(v1))
        if 0 <= row < rows and 0 <= col < cols and stamp[row, col] != scan_stamp:
            stamp[row, col] = scan_stamp
            logodds[row, col] = min(l_max, logodds[row, col] + l_hit)
            updated += 1

    start_col = int(math.floor(u0))
    start_row = int(math.floor(v0))
    for i in range(n):
        u1, v1 = end_coords(u0, v0, end_x[i], end_y[i], origin_x, origin_y, resolution, is_hit[i])
        end_col = int(math.floor(u1))
        end_row = int(math.floor(v1))
        du = u1 - u0
        dv = v1 - v0
        step_c = 1 if du > 0.0 else -1
        step_r = 1 if dv > 0.0 else -1
        t_max_x, t_delta_x, t_max_y, t_delta_y = first_crossings(
            u0, v0, du, dv, start_col, start_row
        )
        col = start_col
        row = start_row
        hit = is_hit[i]
        max_steps = abs(end_col - col) + abs(end_row - row)
        for _ in range(max_steps + 1):
            at_end = col == end_col and row == end_row
            if at_end and hit:
                break
            if 0 <= row < rows and 0 <= col < cols and stamp[row, col] != scan_stamp:
                stamp[row, col] = scan_stamp
                logodds[row, col] = max(l_min, logodds[row, col] + l_miss)
                updated += 1
            if at_end:
                break
            col, row, t_max_x, t_max_y = step(
                col, row, end_col, end_row, step_c, step_r, t_max_x, t_delta_x, t_max_y, t_delta_y
            )
    return updated


@njit(cache=True)
def cast_rays(occupied, origin_x, origin_y, resolution, x, y, theta, angles, max_range):
    """Simulated ranges: from ``(x, y)`` along ``theta + angles[i]`` to the first occupied cell.

    ``occupied`` is a boolean grid. The range is measured to where the ray
    enters the first occupied cell (0 if the start cell is occupied); NaN when
    no occupied cell lies within ``max_range`` metres or inside the grid. Used by
    simulators and beam-model likelihoods.
    """
    rows, cols = occupied.shape
    n = angles.shape[0]
    out = np.full(n, np.nan)
    u0 = (x - origin_x) / resolution
    v0 = (y - origin_y) / resolution
    start_col = int(math.floor(u0))
    start_row = int(math.floor(v0))
    length = max_range / resolution  # in cells
    for i in range(n):
        a = theta + angles[i]
        du = math.cos(a) * length
        dv = math.sin(a) * length
        end_col = int(math.floor(u0 + du))
        end_row = int(math.floor(v0 + dv))
        step_c = 1 if du > 0.0 else -1
        step_r = 1 if dv > 0.0 else -1
        t_max_x, t_delta_x, t_max_y, t_delta_y = first_crossings(
            u0, v0, du, dv, start_col, start_row
        )
        col = start_col
        row = start_row
        t_entry = 0.0
        max_steps = abs(end_col - col) + abs(end_row - row)
        for _ in range(max_steps + 1):
            if 0 <= row < rows and 0 <= col < cols:
                if occupied[row, col]:
                    out[i] = t_entry * max_range
                    break
            elif (
                (col >= cols and du >= 0.0)
                or (col < 0 and du <= 0.0)
                or (row >= rows and dv >= 0.0)
                or (row < 0 and dv <= 0.0)
            ):
                break  # outside and not heading back in
            if col == end_col and row == end_row:
                break
            previous_x, previous_y = t_max_x, t_max_y
            col, row, t_max_x, t_max_y = step(
                col, row, end_col, end_row, step_c, step_r, t_max_x, t_delta_x, t_max_y, t_delta_y
            )
            # the ray enters the new cell where it crossed the boundary it stepped over
            t_entry = previous_x if t_max_x != previous_x else previous_y
    return out
