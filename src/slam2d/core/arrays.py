"""Growing arrays: per-node and per-sighting stores that gain rows as a run goes on."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["grown"]


def grown(arr: NDArray, needed: int, *, fill: float = 0, minimum: int = 0) -> NDArray:
    """``arr`` if it has ``needed`` rows, else a copy with at least ``needed`` (doubling, at least ``minimum``) rows.

    The new rows hold ``fill``. Doubling keeps appending one row at a time linear in the rows added.
    """
    if needed <= arr.shape[0]:
        return arr
    out = np.full((max(needed, 2 * arr.shape[0], minimum),) + arr.shape[1:], fill, dtype=arr.dtype)
    out[: arr.shape[0]] = arr
    return out
