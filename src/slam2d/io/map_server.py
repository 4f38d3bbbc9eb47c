"""ROS map_server maps: a YAML file plus an image (PGM, or PNG for ``scale`` maps).

Reading follows the map_server loaders exactly (ROS 1 ``map_server`` and ROS 2
``nav2_map_server``), pixel by pixel:

* the YAML keys are ``image`` (relative to the YAML's folder unless
  absolute), ``resolution`` (m/cell), ``origin: [x, y, yaw]`` (the lower-left
  pixel's corner), ``negate``, ``occupied_thresh``, ``free_thresh`` (all
  required, as map_server requires them) and ``mode`` (``trinary`` when absent,
  ``scale`` or ``raw``);
* a pixel's shade is the mean of its colour channels over 255 (trinary mode
  averages alpha in too); ``occ = 1 - shade`` (``shade`` when ``negate`` is 1);
* trinary: ``occ > occupied_thresh`` -> 100, ``occ < free_thresh`` -> 0, else -1;
* scale: the same two thresholds, a non-opaque pixel -> -1, and in between
  ``rint(100 * (occ - free) / (occupied - free))`` (nav2) or
  ``int(99 * (occ - free) / (occupied - free))`` (ROS 1: truncated, so at most
  99, and the alpha test comes after the thresholds);
* raw: nav2 takes the pixel value itself (0..100, anything else -1, ``negate``
  ignored); ROS 1 takes it after ``negate`` as a signed byte (255 -> -1);
* image row 0 is the top of the map: rows are flipped so that
  :attr:`MapImage.occupancy` row 0 is the lowest y, like
  ``nav_msgs/OccupancyGrid``.

Writing follows ROS 1 ``map_saver``: trinary maps are PGM with occupied cells
(value >= 65, ``--occ``) black (0), free cells (0..25, ``--free``) 254 and
the rest 205, and the YAML says ``occupied_thresh: 0.65``, ``free_thresh:
0.196``, which reads those three shades back as 100 / 0 / -1. ``scale`` maps
are written so that a map_server (nav2) loading them gets back every value
0..100 exactly (see :func:`write_map`), with unknown cells transparent in a
PNG. ``raw`` maps store the value as the pixel (unknown 255). The YAML stores
floats in shortest round-trip form, so origin and resolution come back exact.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import ArrayLike, NDArray

from slam2d.core.arrays import lookup_by_band, row_bands
from slam2d.errors import InputError
from slam2d.io.atomic import atomic_path

__all__ = [
    "MapImage",
    "read_map",
    "load_map_grid",
    "write_map",
    "save_grid",
    "read_pgm",
    "write_pgm",
    "occupancy_from_pixels",
    "MODES",
    "LOADERS",
    "UNKNOWN_SHADE",
    "FREE_SHADE",
    "OCCUPIED_SHADE",
]

MODES = ("trinary", "scale", "raw")
LOADERS = ("nav2", "ros1")

#: the three shades map_saver writes in trinary maps
OCCUPIED_SHADE = 0
FREE_SHADE = 254
UNKNOWN_SHADE = 205

_REQUIRED_KEYS = ("image", "resolution", "origin", "negate", "occupied_thresh", "free_thresh")


@dataclass(frozen=True, eq=False)
class MapImage:
    """A map as map_server would publish it.

    Attributes:
        occupancy: int8 ``(rows, cols)``, -1 unknown, 0..100; row 0 is the lowest y.
        resolution: metres per cell.
        origin: ``(x, y, yaw)`` of the lower-left corner of cell ``[0, 0]``.
        negate, occupied_thresh, free_thresh, mode: the YAML's values.
        image_path: the image file read.
        yaml_path: the YAML file read.
    """

    occupancy: NDArray[np.int8]
    resolution: float
    origin: tuple[float, float, float]
    negate: bool
    occupied_thresh: float
    free_thresh: float
    mode: str
    image_path: Path
    yaml_path: Path

    @property
    def shape(self) -> tuple[int, int]:
        return self.occupancy.shape  # type: ignore[return-value]

    def require_unrotated(self) -> None:
        """Raise :class:`InputError` (naming the YAML's ``origin``) when the map's origin yaw is not 0."""
        if abs(self.origin[2]) > 1e-9:
            raise InputError(
                f"yaw {self.origin[2]} rad: rotated maps are not supported by the grids",
                path=self.yaml_path,
                field="origin",
            )

    def to_grid(self, params: Any = None) -> Any:
        """This map as an :class:`~slam2d.grids.occupancy.OccupancyGrid` (origin yaw must be 0)."""
        from slam2d.grids.occupancy import OccupancyGrid

        self.require_unrotated()
        return OccupancyGrid.from_occupancy(
            self.occupancy, self.resolution, (self.origin[0], self.origin[1]), params
        )


# --------------------------------------------------------------------------- reading


def _key_lines(text: str) -> dict[str, int]:
    """Line number (1-based) of each top-level key, for error messages."""
    try:
        node = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError:
        return {}
    if not isinstance(node, yaml.MappingNode):
        return {}
    return {
        str(k.value): k.start_mark.line + 1 for k, _ in node.value if isinstance(k, yaml.ScalarNode)
    }


def _load_yaml(path: Path) -> tuple[dict[str, Any], dict[str, int]]:
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError("no such file", path=path) from None
    except UnicodeDecodeError:
        raise InputError("is not text (a map_server YAML file was expected; the image goes in its 'image' key)",
                         path=path) from None
    except OSError as exc:
        raise InputError(f"cannot be read: {exc.strerror or exc}", path=path) from None
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = mark.line + 1 if mark is not None else None
        problem = getattr(exc, "problem", None) or str(exc)
        raise InputError(f"not valid YAML: {problem}", path=path, where=line) from None
    if not isinstance(doc, dict):
        raise InputError(
            "expected a YAML mapping of map_server keys (image, resolution, ...)", path=path
        )
    return doc, _key_lines(text)


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _number(doc: dict[str, Any], key: str, path: Path, lines: dict[str, int]) -> float:
    value = doc[key]
    if not _is_number(value) or not math.isfinite(value):
        raise InputError(
            f"{value!r} is not a finite number", path=path, where=lines.get(key), field=key
        )
    return float(value)


def read_map(yaml_path: str | Path, *, loader: str = "nav2") -> MapImage:
    """Load a map_server map (YAML + PGM/PNG) exactly as map_server would.

    ``loader`` picks whose semantics apply where they differ (``scale`` and
    ``raw`` modes): ``"nav2"`` (ROS 2, default) or ``"ros1"``. Raises
    :class:`~slam2d.errors.InputError` naming the file, the line and the key
    for a missing or bad key, an image that is missing or unreadable.
    """
    if loader not in LOADERS:
        raise ValueError(f"loader: {loader!r} is not one of {LOADERS}")
    path = Path(yaml_path)
    doc, lines = _load_yaml(path)
    for key in _REQUIRED_KEYS:
        if key not in doc or doc[key] is None:
            raise InputError("required key is missing", path=path, field=key)

    image = doc["image"]
    if not isinstance(image, str) or not image.strip():
        raise InputError(
            f"{image!r} is not an image file name", path=path, where=lines.get("image"), field="image"
        )
    image_path = Path(image)
    if not image_path.is_absolute():
        image_path = path.parent / image_path

    resolution = _number(doc, "resolution", path, lines)
    if resolution <= 0.0:
        raise InputError(
            f"{resolution} must be > 0", path=path, where=lines.get("resolution"), field="resolution"
        )

    origin = doc["origin"]
    if (
        not isinstance(origin, (list, tuple))
        or len(origin) != 3
        or not all(_is_number(v) and math.isfinite(v) for v in origin)
    ):
        raise InputError(
            f"{origin!r} is not [x, y, yaw] (three finite numbers)",
            path=path,
            where=lines.get("origin"),
            field="origin",
        )

    negate_raw = doc["negate"]
    if negate_raw not in (0, 1) or isinstance(negate_raw, float):
        raise InputError(
            f"{negate_raw!r} must be 0 or 1", path=path, where=lines.get("negate"), field="negate"
        )
    negate = bool(negate_raw)

    occupied_thresh = _number(doc, "occupied_thresh", path, lines)
    free_thresh = _number(doc, "free_thresh", path, lines)
    for key, value in (("occupied_thresh", occupied_thresh), ("free_thresh", free_thresh)):
        if not 0.0 <= value <= 1.0:  # probabilities: 65 for 0.65 would mark nothing occupied
            raise InputError(f"{value:g} is not a probability in [0, 1]", path=path, where=lines.get(key), field=key)

    mode = doc.get("mode", "trinary")
    if mode is None:
        mode = "trinary"
    if not isinstance(mode, str) or mode not in MODES:
        raise InputError(
            f"{mode!r} is not a map mode (one of: {', '.join(MODES)})",
            path=path,
            where=lines.get("mode"),
            field="mode",
        )

    if not image_path.is_file():
        raise InputError(
            f"image file {image_path} not found", path=path, where=lines.get("image"), field="image"
        )
    color, alpha = _read_image(image_path, path)
    # rows flipped before the conversion (a view): map_server's row 0 is the image's last; a grey image's
    # lookup then makes the only copy
    occupancy = occupancy_from_pixels(
        color[::-1],
        None if alpha is None else alpha[::-1],
        mode=mode,
        negate=negate,
        occupied_thresh=occupied_thresh,
        free_thresh=free_thresh,
        loader=loader,
    )
    return MapImage(
        occupancy=np.ascontiguousarray(occupancy),
        resolution=resolution,
        origin=(float(origin[0]), float(origin[1]), float(origin[2])),
        negate=negate,
        occupied_thresh=occupied_thresh,
        free_thresh=free_thresh,
        mode=mode,
        image_path=image_path,
        yaml_path=path,
    )


def load_map_grid(source: str | Path) -> tuple[Any, Path]:
    """The map of a run folder (its ``map.yaml``) or of a map_server YAML, as an occupancy grid."""
    source = Path(source)
    yaml_path = source / "map.yaml" if source.is_dir() else source
    if source.is_dir() and not yaml_path.is_file():
        raise InputError("is a folder without map.yaml: give a run folder or a map_server YAML", path=source)
    if not yaml_path.exists():
        raise InputError("no such map (a run folder or a map_server YAML)", path=source)
    return read_map(yaml_path).to_grid(), yaml_path


def occupancy_from_pixels(
    channels: NDArray[np.uint8],
    alpha: NDArray[np.uint8] | None,
    *,
    mode: str,
    negate: bool,
    occupied_thresh: float,
    free_thresh: float,
    loader: str = "nav2",
) -> NDArray[np.int8]:
    """map_server's pixel-to-value rule, whole-array, in image row order (row 0 = top).

    ``channels`` is ``(rows, cols)`` for grey images or ``(rows, cols, 3)``
    for colour; ``alpha`` is ``(rows, cols)`` or None.
    """
    if alpha is None and np.ndim(channels) == 2 and np.asarray(channels).dtype == np.uint8 and np.size(channels) > 256:
        # a grey image has 256 values: the rule once per value, looked up (no float copies of a big map)
        levels = occupancy_from_pixels(np.arange(256, dtype=np.uint8)[None, :], None, mode=mode, negate=negate,
                                       occupied_thresh=occupied_thresh, free_thresh=free_thresh, loader=loader)
        return levels[0][channels]
    c = np.asarray(channels, dtype=np.float64)
    color_sum = c.sum(axis=-1) if c.ndim == 3 else c
    n_color = c.shape[-1] if c.ndim == 3 else 1
    if mode == "trinary" and alpha is not None:
        # Both loaders average alpha in with the colours in trinary mode.
        avg = (color_sum + alpha) / (n_color + 1)
    else:
        avg = color_sum / n_color

    if mode == "raw":
        if loader == "nav2":
            value = np.rint(avg)  # nav2 ignores negate in raw mode
            return np.where((value >= 0) & (value <= 100), value, -1).astype(np.int8)
        if negate:
            avg = 255.0 - avg
        return avg.astype(np.uint8).view(np.int8)  # C: unsigned char -> int8

    occ = avg / 255.0 if negate else (255.0 - avg) / 255.0
    out = np.full(occ.shape, -1, dtype=np.int8)
    occupied = occ > occupied_thresh
    free = occ < free_thresh
    out[occupied] = 100
    out[free & ~occupied] = 0
    if mode == "trinary":
        return out
    between = ~occupied & ~free
    band = occupied_thresh - free_thresh
    ratio = (occ - free_thresh) / band if band != 0.0 else np.zeros_like(occ)
    if loader == "nav2":
        value = np.rint(ratio * 100.0)
        out[between] = value[between].astype(np.int8)
        if alpha is not None:
            out[alpha != 255] = -1
    else:
        value = np.trunc(ratio * 99.0)
        out[between] = value[between].astype(np.int8)
        if alpha is not None:
            out[between & (alpha < 1)] = -1
    return out


def _read_image(
    image_path: Path, yaml_path: Path
) -> tuple[NDArray[np.uint8], NDArray[np.uint8] | None]:
    """Colour channels (grey ``(rows, cols)`` or ``(rows, cols, 3)``) and alpha or None, 8 bits."""
    try:
        with open(image_path, "rb") as f:
            head = f.read(8)
    except OSError as exc:
        raise InputError(f"cannot be read: {exc.strerror}", path=image_path) from None
    if head[:2] in (b"P5", b"P2"):
        pixels, maxval = read_pgm(image_path)
        return _to_8bit(pixels, maxval), None
    if head[:2] in (b"P1", b"P3", b"P4", b"P6"):
        raise InputError(
            f"netpbm type {head[:2].decode()} is not a greyscale map image; use PGM (P5 or P2)",
            path=image_path,
            field="header",
        )
    return _read_with_pillow(image_path, yaml_path)


def _to_8bit(pixels: NDArray[Any], maxval: int) -> NDArray[np.uint8]:
    if maxval == 255:
        return pixels.astype(np.uint8)
    return np.rint(pixels.astype(np.float64) * (255.0 / maxval)).astype(np.uint8)


def _read_with_pillow(
    image_path: Path, yaml_path: Path
) -> tuple[NDArray[np.uint8], NDArray[np.uint8] | None]:
    try:
        from PIL import Image, UnidentifiedImageError  # matplotlib's own image library
    except ImportError:  # pragma: no cover - Pillow ships with matplotlib
        raise InputError(
            "only PGM images can be read without Pillow", path=image_path, field="header"
        ) from None
    try:
        with Image.open(image_path) as img:
            img.load()
            if img.mode in ("I;16", "I;16B", "I", "F"):
                arr = np.asarray(img, dtype=np.float64)
                peak = 65535.0 if img.mode.startswith("I") else 1.0
                return np.clip(np.rint(arr * 255.0 / peak), 0, 255).astype(np.uint8), None
            if img.mode in ("1", "L"):
                return np.asarray(img.convert("L"), dtype=np.uint8), None
            if img.mode == "LA":
                la = np.asarray(img, dtype=np.uint8)
                grey = np.repeat(la[..., :1], 3, axis=-1)
                return grey, la[..., 1].copy()
            has_alpha = img.mode in ("RGBA", "PA") or "transparency" in img.info
            rgba = np.asarray(img.convert("RGBA" if has_alpha else "RGB"), dtype=np.uint8)
            if has_alpha:
                return rgba[..., :3].copy(), rgba[..., 3].copy()
            return rgba, None
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError) as exc:
        raise InputError(
            f"not a readable image ({exc}); map images are PGM or PNG (image of {yaml_path})",
            path=image_path,
            field="header",
        ) from None


_PGM_TOKEN = re.compile(rb"\s*(?:#[^\n]*\n\s*)*([^\s#]+)")


def read_pgm(path: str | Path) -> tuple[NDArray[np.uint16] | NDArray[np.uint8], int]:
    """Pixels ``(rows, cols)`` (row 0 = top) and maxval of a binary (P5) or plain (P2) PGM.

    Raises :class:`~slam2d.errors.InputError` with field ``header`` or
    ``raster`` when the file is not a well-formed PGM.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputError(f"cannot be read: {exc.strerror}", path=path) from None
    magic = data[:2]
    if magic not in (b"P5", b"P2"):
        raise InputError(
            f"not a PGM image: starts with {data[:8]!r}, expected P5 or P2", path=path, field="header"
        )
    pos = 2
    values = []
    for name in ("width", "height", "maxval"):
        m = _PGM_TOKEN.match(data, pos)
        if m is None:
            raise InputError(f"{name} is missing", path=path, field="header")
        token = m.group(1)
        if not token.isdigit():
            raise InputError(
                f"{name} {token[:20]!r} is not a positive integer", path=path, field="header"
            )
        values.append(int(token))
        pos = m.end()
    width, height, maxval = values
    if width <= 0 or height <= 0:
        raise InputError(f"image size {width} x {height} is empty", path=path, field="header")
    if not 0 < maxval < 65536:
        raise InputError(f"maxval {maxval} must be between 1 and 65535", path=path, field="header")
    count = width * height
    if magic == b"P5":
        if pos >= len(data) or not data[pos : pos + 1].isspace():
            raise InputError("no whitespace after maxval", path=path, field="header")
        pos += 1  # exactly one whitespace character precedes the raster
        dtype = np.dtype(np.uint8) if maxval < 256 else np.dtype(">u2")
        need = count * dtype.itemsize
        if len(data) - pos < need:
            raise InputError(
                f"raster is {len(data) - pos} bytes, {width} x {height} pixels need {need}",
                path=path,
                field="raster",
            )
        pixels = np.frombuffer(data, dtype=dtype, count=count, offset=pos).reshape(height, width)
    else:
        body = re.sub(rb"#[^\n]*", b" ", data[pos:])
        tokens = body.split()
        if len(tokens) < count:
            raise InputError(
                f"raster has {len(tokens)} values, {width} x {height} pixels need {count}",
                path=path,
                field="raster",
            )
        try:
            pixels = np.array(tokens[:count], dtype=np.int64).reshape(height, width)
        except ValueError:
            raise InputError(
                "raster holds a value that is not an integer", path=path, field="raster"
            ) from None
    if int(pixels.max()) > maxval or int(pixels.min()) < 0:
        raise InputError(f"a pixel value exceeds maxval {maxval}", path=path, field="raster")
    out_dtype = np.uint8 if maxval < 256 else np.uint16
    return pixels.astype(out_dtype), maxval


def write_pgm(path: str | Path, pixels: ArrayLike, *, comment: str = "") -> None:
    """Write 8-bit pixels ``(rows, cols)`` (row 0 = top) as binary PGM (P5, maxval 255), atomically."""
    arr = np.asarray(pixels, dtype=np.uint8)
    if arr.ndim != 2:
        raise ValueError(f"pixels: expected a 2D array, got shape {arr.shape}")
    rows, cols = arr.shape
    header = "P5\n" + (f"# {comment}\n" if comment else "") + f"{cols} {rows}\n255\n"
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(header.encode("ascii"))
            for band in row_bands(arr.shape):  # a band at a time: no whole copy of a flipped (strided) image
                f.write(np.ascontiguousarray(arr[band]).data)


# --------------------------------------------------------------------------- writing


def _scale_table(occupied_thresh: float, free_thresh: float) -> NDArray[np.uint8]:
    """For each value 0..100 the shade (negate 0) that nav2's scale loader reads back as it.

    Among the shades that load back exactly, the one nearest ``255 * (1 - v / 100)``
    is taken, so the image still looks like the map. When the thresholds are
    too close to leave a shade for every value, the nearest loadable value is used.
    """
    shades = np.arange(256, dtype=np.uint8)
    loaded = occupancy_from_pixels(
        shades, None, mode="scale", negate=False, occupied_thresh=occupied_thresh,
        free_thresh=free_thresh, loader="nav2",
    ).astype(np.int64)
    table = np.empty(101, dtype=np.uint8)
    natural = np.rint(255.0 * (1.0 - np.arange(101) / 100.0))
    for v in range(101):  # 101 values, not a per-cell loop
        cost = np.abs(loaded - v) * 1000.0 + np.abs(shades - natural[v])
        table[v] = shades[int(np.argmin(cost))]
    return table


def write_map(
    yaml_path: str | Path,
    occupancy: ArrayLike,
    resolution: float,
    origin: ArrayLike,
    *,
    mode: str = "trinary",
    occupied_thresh: float = 0.65,
    free_thresh: float = 0.196,
    negate: int = 0,
    occupied_percent: int = 65,
    free_percent: int = 25,
    image_format: str | None = None,
) -> tuple[Path, Path]:
    """Write a map as map_server files: ``yaml_path`` and an image next to it.

    ``occupancy`` is int ``(rows, cols)`` with ``nav_msgs/OccupancyGrid``
    values (-1 unknown, 0..100; anything else counts as unknown) and row 0 at
    the lowest y; ``origin`` is ``[x, y, yaw]`` (a 2-element origin gets yaw 0).

    * ``trinary`` (PGM): values >= ``occupied_percent`` -> 0, values
      ``0..free_percent`` -> 254, others -> 205, exactly as ROS 1 map_saver with
      ``--occ 65 --free 25``. The YAML thresholds must read those shades back as
      100 / 0 / -1 (the defaults 0.65 / 0.196 do); other thresholds are refused.
    * ``scale`` (PNG by default): each value v gets the shade that map_server
      (nav2 rule) reads back as v exactly, nearest to ``255 * (1 - v / 100)``;
      unknown cells are transparent (shade 205 underneath). A PGM has no alpha,
      so ``image_format="pgm"`` is refused when a cell is unknown. ROS 1's
      loader reads such a map back within 2 (it truncates to 99 levels).
    * ``raw`` (PGM): the value is the shade, unknown 255; read back exactly by
      both loaders. ``negate`` must be 0 (the loaders disagree about it).

    ``negate=1`` writes every shade as ``255 - shade``. Both files are written
    atomically; the YAML's ``image`` is the image's file name. Returns
    ``(yaml_path, image_path)``.
    """
    yaml_path = Path(yaml_path)
    occ = np.asarray(occupancy)
    if occ.ndim != 2 or occ.size == 0:
        raise ValueError(f"occupancy: expected a non-empty 2D array, got shape {occ.shape}")
    if not np.issubdtype(occ.dtype, np.integer):
        raise ValueError(f"occupancy: expected integer values, got {occ.dtype}")
    if mode not in MODES:
        raise InputError(f"{mode!r} is not a map mode (one of: {', '.join(MODES)})", field="mode")
    resolution = float(resolution)
    if not (math.isfinite(resolution) and resolution > 0.0):
        raise InputError(f"{resolution} must be a finite size > 0", field="resolution")
    org = [float(v) for v in np.asarray(origin, dtype=np.float64).reshape(-1)]
    if len(org) == 2:
        org.append(0.0)
    if len(org) != 3 or not all(math.isfinite(v) for v in org):
        raise InputError(f"{origin!r} is not [x, y, yaw]", field="origin")
    if negate not in (0, 1):
        raise InputError(f"{negate!r} must be 0 or 1", field="negate")
    if not 0.0 <= free_thresh < occupied_thresh <= 1.0:
        raise InputError(
            f"need 0 <= free_thresh < occupied_thresh <= 1, got {free_thresh}, {occupied_thresh}",
            field="free_thresh",
        )
    fmt = (image_format or ("png" if mode == "scale" else "pgm")).lower()
    if fmt not in ("pgm", "png"):
        raise InputError(f"{image_format!r} is not pgm or png", field="image_format")

    if occ.dtype != np.int8:  # anything outside 0..100 is unknown
        occ = np.where((occ >= 0) & (occ <= 100), occ, -1).astype(np.int8)
    # every shade is looked up by the cell's byte (0..100 the value, 101..255 unknown), a band at a time:
    # no mask or int16 copy of a big map
    by_byte = occ.view(np.uint8)
    value_of_byte = np.arange(256)
    known_byte = value_of_byte <= 100
    alpha = None
    if mode == "trinary":
        if not 0 <= free_percent < occupied_percent <= 100:
            raise InputError(
                "need 0 <= free_percent < occupied_percent <= 100, "
                f"got {free_percent}, {occupied_percent}",
                field="free_percent",
            )
        table = np.full(256, UNKNOWN_SHADE, dtype=np.uint8)
        table[known_byte & (value_of_byte <= free_percent)] = FREE_SHADE
        table[known_byte & (value_of_byte >= occupied_percent)] = OCCUPIED_SHADE
        check = np.array([OCCUPIED_SHADE, FREE_SHADE, UNKNOWN_SHADE], dtype=np.uint8)
        got = occupancy_from_pixels(
            check, None, mode="trinary", negate=False,
            occupied_thresh=occupied_thresh, free_thresh=free_thresh,
        )
        if got.tolist() != [100, 0, -1]:
            raise InputError(
                f"with occupied_thresh {occupied_thresh} and free_thresh {free_thresh} map_server "
                f"would read the shades 0 / 254 / 205 as {got.tolist()}, not 100 / 0 / -1 "
                "(free_thresh must lie in (1/255, 50/255], occupied_thresh in [50/255, 1))",
                field="free_thresh" if got[1] != 0 or got[2] != -1 else "occupied_thresh",
            )
    elif mode == "scale":
        table = np.full(256, UNKNOWN_SHADE, dtype=np.uint8)
        table[:101] = _scale_table(occupied_thresh, free_thresh)
        if (by_byte > 100).any():
            if fmt == "pgm":
                raise InputError(
                    "scale maps mark unknown cells transparent and PGM has no alpha channel; "
                    "write a PNG (image_format='png') or use mode 'trinary'",
                    field="image_format",
                )
            alpha = lookup_by_band(np.where(known_byte, 255, 0).astype(np.uint8), by_byte)
    else:
        if negate:
            raise InputError(
                "raw maps cannot be negated: ROS 1 and nav2 map_server read negated raw maps "
                "differently",
                field="negate",
            )
        table = np.where(known_byte, value_of_byte, 255).astype(np.uint8)
    if negate:
        table = (255 - table).astype(np.uint8)
    shade = lookup_by_band(table, by_byte)
    image_rows = shade[::-1]  # image row 0 is the top of the map

    image_path = yaml_path.with_name(yaml_path.stem + "." + fmt)
    text = (
        f"image: {image_path.name}\n"
        f"mode: {mode}\n"
        f"resolution: {resolution!r}\n"
        f"origin: [{org[0]!r}, {org[1]!r}, {org[2]!r}]\n"
        f"negate: {int(negate)}\n"
        f"occupied_thresh: {float(occupied_thresh)!r}\n"
        f"free_thresh: {float(free_thresh)!r}\n"
    )
    with atomic_path(yaml_path) as tmp_yaml:
        if fmt == "pgm":
            write_pgm(image_path, image_rows, comment=f"CREATOR: slam2d {resolution:.3f} m/pix")
        else:
            _write_png(image_path, image_rows, None if alpha is None else alpha[::-1])
        tmp_yaml.write_text(text, encoding="utf-8")
    return yaml_path, image_path


def _write_png(path: Path, grey: NDArray[np.uint8], alpha: NDArray[np.uint8] | None) -> None:
    from PIL import Image

    if alpha is None:
        img = Image.fromarray(np.ascontiguousarray(grey), mode="L")
    else:
        img = Image.fromarray(np.ascontiguousarray(np.stack([grey, alpha], axis=-1)), mode="LA")
    with atomic_path(path) as tmp:
        img.save(tmp, format="PNG")


def save_grid(
    grid: Any,
    yaml_path: str | Path,
    *,
    mode: str = "trinary",
    crop: bool = True,
    margin: int = 1,
    **options: Any,
) -> tuple[Path, Path]:
    """Write an :class:`~slam2d.grids.occupancy.OccupancyGrid` as map_server files.

    The grid is cropped to its observed cells plus ``margin`` cells unless
    ``crop`` is False. ``options`` go to :func:`write_map` (thresholds,
    ``negate``, ``image_format``). Returns ``(yaml_path, image_path)``.
    """
    g = grid.crop_to_observed(margin) if crop else grid
    if g.shape[0] == 0 or g.shape[1] == 0:
        raise InputError("the map is empty: no scan was integrated", path=yaml_path)
    ox, oy = g.origin
    return write_map(yaml_path, g.occupancy(), g.resolution, (ox, oy, 0.0), mode=mode, **options)
