"""Map pictures: PNG previews drawn the way map viewers show occupancy maps."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from slam2d.io.atomic import atomic_path

__all__ = ["map_image", "save_map_png"]

UNKNOWN_GRAY = 205 / 255  # map_saver's colour for unknown cells


def map_image(grid: Any) -> np.ndarray:
    """Grey levels (rows x cols, row 0 at the top = highest y): black occupied, white free."""
    p = np.asarray(grid.probability(), dtype=np.float64)
    img = 1.0 - p
    img[~np.asarray(grid.observed)] = UNKNOWN_GRAY
    return img[::-1]


def save_map_png(grid: Any, path: str | Path) -> Path:
    """Write a PNG preview of an occupancy grid, atomically; one pixel per cell."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.image

    path = Path(path)
    img = map_image(grid)
    with atomic_path(path) as tmp:
        matplotlib.image.imsave(tmp, img, cmap="gray", vmin=0.0, vmax=1.0, format="png")
    return path
