"""Map pictures: PNG previews drawn the way map viewers show occupancy maps."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from slam2d.core.arrays import lookup_by_band
from slam2d.io.atomic import atomic_path

__all__ = ["map_image", "gray_pixels", "save_map_png", "MATERIAL_COLOURS"]

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
    return _image_of(np.asarray(grid.occupancy(), dtype=np.float64))[::-1]


def grey_levels() -> np.ndarray:
    """The grey level of each occupancy value -1..100 (index = value + 1)."""
    return _image_of(np.arange(-1, 101, dtype=np.float64))


def by_occupancy(table: np.ndarray, occupancy: np.ndarray) -> np.ndarray:
    """``table[value + 1]`` for each occupancy value (-1..100) of a map: a lookup, no float copy of the map."""
    table = np.asarray(table)
    # by the int8 value's byte: -1 is 255, 0..100 themselves; 101..127 count as 100 and -128..-2 as -1, as a clip did
    by_byte = np.concatenate([table[1:], np.repeat(table[-1:], 27), np.repeat(table[:1], 128)])
    return lookup_by_band(by_byte, np.asarray(occupancy, dtype=np.int8).view(np.uint8))


def _image_of(occ: np.ndarray) -> np.ndarray:
    """Grey levels in [0, 1] of occupancy values (-1 unknown, 0..100)."""
    img = 1.0 - (occ - FREE_PERCENT) / (OCCUPIED_PERCENT - FREE_PERCENT)
    img = np.clip(img, 0.0, 1.0)
    img[occ < 0] = UNKNOWN_GRAY
    return img


# The grey levels matplotlib's "gray" colour map gives (its lookup table is i/255 rounded down
# after a float round trip, so 24 of the 256 levels are one lower): previews written without
# importing matplotlib (half a second of a `slam2d map` run) keep the pixels they always had.
_GRAY_LEVELS = ((255.0 * np.linspace(0.0, 1.0, 256)) / 255.0 * 255.0).astype(np.uint8)


def gray_pixels(img: np.ndarray) -> np.ndarray:
    """8-bit grey levels of an image in [0, 1], as matplotlib's ``imsave(cmap="gray", vmin=0, vmax=1)`` draws them."""
    with np.errstate(invalid="ignore"):
        index = np.clip(np.asarray(img, dtype=np.float64) * 256.0, -1.0, 256.0).astype(np.intp)
    return _GRAY_LEVELS[np.clip(index, 0, 255)]


def save_map_png(grid: Any, path: str | Path, *, scale: int | None = None) -> Path:
    """Write a PNG preview of an occupancy grid (8-bit grey), atomically.

    ``scale`` pixels per cell; by default 1, or more for a small map so the
    picture is at least about 600 pixels across.
    """
    from PIL import Image

    path = Path(path)
    # one grey per occupancy value (-1..100), looked up: the same pixels as gray_pixels(map_image(grid)),
    # without its float64 copies of the map (300 MB at once for fr101's odometry map)
    pixels = by_occupancy(gray_pixels(grey_levels()), grid.occupancy()[::-1])
    if scale is None:
        scale = max(1, int(np.ceil(MIN_PREVIEW_PIXELS / max(1, max(pixels.shape)))))
    if scale > 1:
        pixels = np.repeat(np.repeat(pixels, scale, axis=0), scale, axis=1)
    with atomic_path(path) as tmp:
        Image.fromarray(np.ascontiguousarray(pixels)).save(tmp, format="PNG")
    return path
