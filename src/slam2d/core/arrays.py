"""Growing arrays: per-node and per-sighting stores that gain rows as a run goes on."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["grown", "row_bands", "lookup_by_band"]

#: Cells a band of :func:`row_bands` holds: a float copy of it is 4-8 MB, where one of a 330 m map is 170 MB.
BAND_CELLS = 1 << 20


def grown(arr: NDArray, needed: int, *, fill: float = 0, minimum: int = 0) -> NDArray:
    """``arr`` if it has ``needed`` rows, else a copy with at least ``needed`` (doubling, at least ``minimum``) rows.

    The new rows hold ``fill``. Doubling keeps appending one row at a time linear in the rows added.
    """
    if needed <= arr.shape[0]:
        return arr
    out = np.full((max(needed, 2 * arr.shape[0], minimum),) + arr.shape[1:], fill, dtype=arr.dtype)
    out[: arr.shape[0]] = arr
    return out


def row_bands(shape: tuple[int, ...], cells: int = BAND_CELLS) -> list[slice]:
    """Slices of rows of an array of ``shape`` that hold about ``cells`` cells each (at least one row): work on a
    big map a band at a time instead of making whole-map copies."""
    rows = shape[0]
    cols = shape[1] if len(shape) > 1 else 1
    step = max(1, cells // max(1, cols))
    return [slice(r, r + step) for r in range(0, rows, step)]


def lookup_by_band(table: NDArray, index: NDArray) -> NDArray:
    """``table[index]`` for a big 2D integer ``index`` (a map), a band of rows at a time.

    numpy turns a fancy index into 8-byte integers first: for a whole 40-million-cell map that is a
    transient 350 MB where the answer (uint8) is 40 MB.
    """
    out = np.empty(index.shape, dtype=table.dtype)
    for rows in row_bands(index.shape):
        out[rows] = table[index[rows]]
    return out
