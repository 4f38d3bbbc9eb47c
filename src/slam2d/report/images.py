"""Map pictures: PNG previews drawn the way map viewers show occupancy maps."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from slam2d.io.atomic import atomic_path

__all__ = ["map_image", "save_map_png", "MATERIAL_COLOURS"]

#: One colour per surface material in every picture (dark for the dark surface).
MATERIAL_COLOURS = {
    "varnished-wood": "#a0522d",
    "white-textile": "#6a9fd4",
    "white-paper": "#808080",
    "cardboard": "#d4a017",
    "black-metal": "#000000",
}

UNKNOWN_GRAY = 205 / 255  # map_saver's colour for unknown cells
OCCUPIED_PERCENT = 65  # map_saver's thresholds: black at or above, white at or below free
FREE_PERCENT = 25
MIN_PREVIEW_PIXELS = 600  # small maps are enlarged so a wall is visible


def map_image(grid: Any) -> np.ndarray:
    """Grey levels in [0, 1] (rows x cols, row 0 at the top = highest y).

    Black where map_saver would write occupied, white where it would write
    free, its unknown grey where nothing was observed, and a grey ramp for the
    uncertain cells in between, which map_saver would flatten to unknown.
    """
    occ = np.asarray(grid.occupancy(), dtype=np.float64)
    img = 1.0 - (occ - FREE_PERCENT) / (OCCUPIED_PERCENT - FREE_PERCENT)
    img = np.clip(img, 0.0, 1.0)
    img[occ < 0] = UNKNOWN_GRAY
    return img[::-1]


def save_map_png(grid: Any, path: str | Path, *, scale: int | None = None) -> Path:
    """Write a PNG preview of an occupancy grid, atomically.

    ``scale`` pixels per cell; by default 1, or more for a small map so the
    picture is at least about 600 pixels across.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.image

    path = Path(path)
    img = map_image(grid)
    if scale is None:
        scale = max(1, int(np.ceil(MIN_PREVIEW_PIXELS / max(1, max(img.shape)))))
    if scale > 1:
        img = np.repeat(np.repeat(img, scale, axis=0), scale, axis=1)
    with atomic_path(path) as tmp:
        matplotlib.image.imsave(tmp, img, cmap="gray", vmin=0.0, vmax=1.0, format="png")
    return path
