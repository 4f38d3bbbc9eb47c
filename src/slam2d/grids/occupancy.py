"""Log-odds occupancy grids that grow as the robot explores.

Layout: ``grid.logodds[row, col]`` (float32), ``row`` along world y and ``col``
along world x; ``grid.origin`` is the world ``(x, y)`` of the lower-left corner
of cell ``[0, 0]``; cells are ``grid.resolution`` metres wide. Row 0 is the
lowest y, as in ``nav_msgs/OccupancyGrid`` (map images flip it on writing).

Update model: each scan adds ``log(p_hit / (1 - p_hit))`` to the cell where a
beam ends and ``log(p_miss / (1 - p_miss))`` to the cells the beam crosses
before it, clamped to the log-odds of ``[p_min, p_max]``. Within one scan a cell
is updated at most once and hits win over misses (see
:func:`slam2d.grids.raycast.integrate_rays`), so the result does not depend on
how many beams overlap near the laser.

Defaults (``p_hit`` 0.7, ``p_miss`` 0.4, clamps 0.12 / 0.97): one hit makes an
unknown cell 0.70 (occupied in a map_server map, threshold 0.65); one miss
makes it 0.40, three make it 0.22 (free below 0.25, as map_saver writes);
the clamps (Cartographer's) keep any cell able to change its mind within a few
scans when the world changes.

The grid grows on demand (:meth:`OccupancyGrid.ensure_contains`): its origin
always moves by whole cells from its first position, so a cell never shifts by
a fraction and old data keeps its world position.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from slam2d.core import se2
from slam2d.core.arrays import row_bands
from slam2d.core.memory import check_allocation
from slam2d.core.scan import LaserScan
from slam2d.errors import InputError
from slam2d.grids.raycast import HIT_NUDGE, integrate_rays
from slam2d.params import param, validate

__all__ = ["GridParams", "OccupancyGrid", "logit", "occupancy_logodds"]

_STAMP_DTYPE = np.uint16
_STAMP_LIMIT = int(np.iinfo(_STAMP_DTYPE).max)
# A side that must grow gains half the grid's size while that is under GROWTH_CAP_M, then the cap or an
# eighth of the grid, whichever is more (still geometric: few copies on a long drive). Half of an already
# big map on one side and then on the other left a drifting run with 5x the cells it observed (crsm on
# intel driven 4x: 121 M cells allocated, 25 M written).
GROWTH_CAP_M = 10.0


def growth_step(size: int, margin: int, resolution: float) -> int:
    """Cells a side that must grow gains beyond the cell it must hold (see ``GROWTH_CAP_M``), at least ``margin``."""
    return max(margin, min(size // 2, max(int(GROWTH_CAP_M / resolution), size // 8)))


def _probability(logodds: NDArray[np.float32]) -> NDArray[np.float32]:
    """Occupancy probability of log-odds, as float32."""
    return (1.0 / (1.0 + np.exp(-logodds))).astype(np.float32)


def logit(p: ArrayLike) -> NDArray[np.float64]:
    """Log-odds ``log(p / (1 - p))`` of probabilities."""
    p = np.asarray(p, dtype=np.float64)
    return np.log(p / (1.0 - p))


def occupancy_logodds(params: GridParams | None = None) -> NDArray[np.float32]:
    """The log-odds a grid stores for each ``nav_msgs/OccupancyGrid`` value 0..100 (index = value), clamped to
    ``[p_min, p_max]``."""
    params = params if params is not None else GridParams()
    return logit(np.clip(np.arange(101, dtype=np.float64) / 100.0, params.p_min, params.p_max)).astype(np.float32)


@dataclass
class GridParams:
    """How an occupancy grid is laid out and updated."""

    resolution: float = param(0.05, unit="m", low=0.001, high=10.0, help="cell size")
    p_hit: float = param(
        0.7,
        low=0.501,
        high=0.999,
        help="occupancy probability a cell gets from one beam ending in it "
        "(log-odds increment log(p/(1-p)) per scan)",
    )
    p_miss: float = param(
        0.4,
        low=0.001,
        high=0.499,
        help="occupancy probability a cell gets from one beam passing through it",
    )
    p_min: float = param(
        0.12,
        low=0.001,
        high=0.499,
        help="lower clamp of a cell's probability (keeps maps updatable)",
        advanced=True, group="occupancy grid",
    )
    p_max: float = param(
        0.97, low=0.501, high=0.999, help="upper clamp of a cell's probability", advanced=True, group="occupancy grid"
    )
    max_range: float | None = param(
        None,
        unit="m",
        low=0.0,
        help="usable range: longer returns only clear free space up to it (no hit), and beams "
        "with no return clear free space up to it; unset: every return is used in full and "
        "beams with no return are skipped",
    )
    grow_margin: int = param(
        64, unit="cells", low=1, help="the least a grid grows by on a side when it must grow", advanced=True,
        group="map growth",
    )
    max_extent: float = param(
        2000.0,
        unit="m",
        low=1.0,
        help="largest width or height a grid may grow to; a larger request is an error "
        "(it means corrupt poses or ranges)",
        advanced=True, group="map growth",
    )


class OccupancyGrid:
    """A growing log-odds occupancy grid.

    Attributes:
        logodds: float32 ``(rows, cols)`` log-odds of occupancy; 0 = unknown.
        resolution: cell size in metres.
        params: the :class:`GridParams` it was made with.

    Create an empty grid with ``OccupancyGrid(params)`` (it grows as scans
    arrive), a fixed area with :meth:`covering`, or load values with
    :meth:`from_occupancy`.
    """

    def __init__(
        self,
        params: GridParams | None = None,
        *,
        origin: tuple[float, float] = (0.0, 0.0),
        shape: tuple[int, int] = (0, 0),
    ) -> None:
        self.params = params if params is not None else GridParams()
        validate(self.params)
        p = self.params
        if not p.p_min < p.p_miss < 0.5 < p.p_hit < p.p_max:
            raise InputError(
                f"need p_min < p_miss < 0.5 < p_hit < p_max; got {p.p_min}, {p.p_miss}, "
                f"{p.p_hit}, {p.p_max}",
                field="p_miss" if not p.p_min < p.p_miss else "p_hit",
            )
        self.resolution = float(p.resolution)
        ox, oy = (float(v) for v in origin)
        if not (math.isfinite(ox) and math.isfinite(oy)):
            raise ValueError(f"origin: {origin!r} is not a finite position")
        rows, cols = (int(v) for v in shape)
        if rows < 0 or cols < 0:
            raise ValueError(f"shape: {shape!r} has a negative size")
        # Lattice anchor: the origin is always anchor + whole cells.
        self._anchor = (ox, oy)
        self._row0 = 0  # origin's offset from the anchor, in cells
        self._col0 = 0
        self.logodds = np.zeros((rows, cols), dtype=np.float32)
        # Last scan that touched each cell; 0 = never observed.
        self._stamp = np.zeros((rows, cols), dtype=_STAMP_DTYPE)
        self._scan_stamp = 1
        self.l_hit = float(logit(p.p_hit))
        self.l_miss = float(logit(p.p_miss))
        self.l_min = float(logit(p.p_min))
        self.l_max = float(logit(p.p_max))

    # ----------------------------------------------------------------- construction

    @classmethod
    def covering(
        cls, xmin: float, ymin: float, xmax: float, ymax: float, params: GridParams | None = None
    ) -> OccupancyGrid:
        """An unknown grid covering exactly the cells that contain the box (lattice at world 0)."""
        grid = cls(params)
        grid._grow_to(*grid._cell_box(xmin, ymin, xmax, ymax), margin=0)
        return grid

    @classmethod
    def from_occupancy(
        cls,
        occupancy: ArrayLike,
        resolution: float,
        origin: tuple[float, float],
        params: GridParams | None = None,
    ) -> OccupancyGrid:
        """A grid holding ``nav_msgs/OccupancyGrid``-style values (-1 unknown, 0..100).

        Values are turned into log-odds clamped to ``[p_min, p_max]``; -1 (and
        anything outside 0..100) stays unobserved. ``params.resolution`` is
        replaced by ``resolution``.
        """
        occ = np.asarray(occupancy)
        if occ.ndim != 2:
            raise ValueError(f"occupancy: expected a 2D array, got shape {occ.shape}")
        params = params if params is not None else GridParams()
        params = _replace(params, resolution=float(resolution))
        grid = cls(params, origin=origin, shape=occ.shape)
        if np.issubdtype(occ.dtype, np.integer):
            # one log-odds per value 0..100, looked up a band of rows at a time (no float64 copy of a big map)
            table = occupancy_logodds(params)
            for rows in row_bands(occ.shape):
                band = occ[rows]
                known = (band >= 0) & (band <= 100)
                grid.logodds[rows][known] = table[band[known]]
                grid._stamp[rows][known] = 1
        else:
            known = (occ >= 0) & (occ <= 100)
            prob = np.clip(occ[known].astype(np.float64) / 100.0, params.p_min, params.p_max)
            grid.logodds[known] = logit(prob).astype(np.float32)
            grid._stamp[known] = 1
        grid._scan_stamp = 2
        return grid

    def copy(self) -> OccupancyGrid:
        """An independent copy (particle filters keep one per particle)."""
        return self._with_arrays(self.logodds.copy(), self._stamp.copy(), self._row0, self._col0)

    def _with_arrays(
        self, logodds: NDArray[np.float32], stamp: NDArray[np.uint16], row0: int, col0: int
    ) -> OccupancyGrid:
        """A grid sharing this one's parameters and lattice, holding the given arrays."""
        other = object.__new__(OccupancyGrid)
        other.__dict__.update(self.__dict__)
        other.logodds = logodds
        other._stamp = stamp
        other._row0 = row0
        other._col0 = col0
        return other

    # ----------------------------------------------------------------- geometry

    @property
    def shape(self) -> tuple[int, int]:
        """``(rows, cols)``."""
        return self.logodds.shape  # type: ignore[return-value]

    @property
    def origin(self) -> tuple[float, float]:
        """World ``(x, y)`` of the lower-left corner of cell ``[0, 0]``, metres."""
        return (
            self._anchor[0] + self._col0 * self.resolution,
            self._anchor[1] + self._row0 * self.resolution,
        )

    def extent(self) -> tuple[float, float, float, float]:
        """World bounds ``(xmin, ymin, xmax, ymax)`` of the whole grid, metres."""
        ox, oy = self.origin
        rows, cols = self.shape
        return ox, oy, ox + cols * self.resolution, oy + rows * self.resolution

    def world_to_cell(self, points: ArrayLike) -> NDArray[np.int64]:
        """Cells ``[row, col]`` (int64, ``(..., 2)``) containing world points ``[x, y]``.

        Cells outside the grid are returned as computed (negative or too large);
        check with :meth:`in_bounds`.
        """
        pts = np.asarray(points, dtype=np.float64)
        ox, oy = self.origin
        col = np.floor((pts[..., 0] - ox) / self.resolution)
        row = np.floor((pts[..., 1] - oy) / self.resolution)
        return np.stack([row, col], axis=-1).astype(np.int64)

    def hit_cells(self, laser_xy: ArrayLike, points: ArrayLike) -> NDArray[np.int64]:
        """Cells ``[row, col]`` ``(N, 2)`` a scan's hits at world ``points`` ``(N, 2)`` mark from ``laser_xy``.

        As :meth:`world_to_cell`, except that a point on a cell boundary belongs to the cell
        beyond it along its beam, as the mapper decides (:func:`~slam2d.grids.raycast.integrate_rays`):
        look endpoints up with this to agree with the map about exact hits.
        """
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        start = np.asarray(laser_xy, dtype=np.float64).reshape(-1)[:2]
        along = pts - start
        length = np.hypot(along[:, 0], along[:, 1])[:, None]
        unit = np.divide(along, length, out=np.zeros_like(along), where=length > 0.0)
        return self.world_to_cell(pts + (HIT_NUDGE * self.resolution) * unit)

    def cell_to_world(self, cells: ArrayLike) -> NDArray[np.float64]:
        """World ``[x, y]`` of the centres of cells ``[row, col]``, ``(..., 2)``."""
        c = np.asarray(cells, dtype=np.float64)
        ox, oy = self.origin
        x = ox + (c[..., 1] + 0.5) * self.resolution
        y = oy + (c[..., 0] + 0.5) * self.resolution
        return np.stack([x, y], axis=-1)

    def in_bounds(self, cells: ArrayLike) -> NDArray[np.bool_]:
        """True for cells ``[row, col]`` inside the grid."""
        c = np.asarray(cells)
        rows, cols = self.shape
        return (c[..., 0] >= 0) & (c[..., 0] < rows) & (c[..., 1] >= 0) & (c[..., 1] < cols)

    def _cell_box(
        self, xmin: float, ymin: float, xmax: float, ymax: float
    ) -> tuple[int, int, int, int]:
        """Cells (relative to the anchor, inclusive) containing a world box."""
        vals = (xmin, ymin, xmax, ymax)
        if not all(math.isfinite(v) for v in vals):
            raise ValueError(f"bounds {vals!r} are not finite")
        if xmax < xmin or ymax < ymin:
            raise ValueError(f"bounds {vals!r} are empty (max < min)")
        ax, ay = self._anchor
        r = self.resolution
        return (
            math.floor((ymin - ay) / r),
            math.floor((xmin - ax) / r),
            math.floor((ymax - ay) / r),
            math.floor((xmax - ax) / r),
        )

    def ensure_contains(self, xmin: float, ymin: float, xmax: float, ymax: float) -> bool:
        """Grow the grid so the world box lies inside it; True if it had to grow.

        A side that must grow grows by :func:`growth_step` (at least
        ``params.grow_margin`` cells, half the grid's size up to ``GROWTH_CAP_M``),
        so a robot driving off an edge causes few reallocations. Data keeps its
        world position.
        """
        r0, c0, r1, c1 = self._cell_box(xmin, ymin, xmax, ymax)
        rows, cols = self.shape
        have_r0, have_c0 = self._row0, self._col0
        have_r1, have_c1 = have_r0 + rows - 1, have_c0 + cols - 1
        if rows and cols and r0 >= have_r0 and c0 >= have_c0 and r1 <= have_r1 and c1 <= have_c1:
            return False
        self._grow_to(r0, c0, r1, c1, margin=self.params.grow_margin)
        return True

    def _grow_to(self, r0: int, c0: int, r1: int, c1: int, *, margin: int) -> None:
        rows, cols = self.shape
        if rows and cols:
            have_r0, have_c0 = self._row0, self._col0
            have_r1, have_c1 = have_r0 + rows - 1, have_c0 + cols - 1
            grow_r = growth_step(rows, margin, self.resolution) if margin else 0
            grow_c = growth_step(cols, margin, self.resolution) if margin else 0
            new_r0 = min(have_r0, r0 - grow_r) if r0 < have_r0 else have_r0
            new_c0 = min(have_c0, c0 - grow_c) if c0 < have_c0 else have_c0
            new_r1 = max(have_r1, r1 + grow_r) if r1 > have_r1 else have_r1
            new_c1 = max(have_c1, c1 + grow_c) if c1 > have_c1 else have_c1
        else:
            new_r0, new_c0, new_r1, new_c1 = r0 - margin, c0 - margin, r1 + margin, c1 + margin
        new_rows = new_r1 - new_r0 + 1
        new_cols = new_c1 - new_c0 + 1
        limit = self.params.max_extent
        if max(new_rows, new_cols) * self.resolution > limit:
            raise InputError(
                f"the map would grow to {new_cols * self.resolution:.6g} m x "
                f"{new_rows * self.resolution:.6g} m, beyond the limit of {limit:g} m "
                "(poses or ranges are probably corrupt; raise max_extent if they are not)",
                field="max_extent",
            )
        check_allocation(new_rows * new_cols * (4 + np.dtype(_STAMP_DTYPE).itemsize),
                         f"a map of {new_cols * self.resolution:.4g} m x {new_rows * self.resolution:.4g} m in "
                         f"{self.resolution:g} m cells", "resolution")
        logodds = np.zeros((new_rows, new_cols), dtype=np.float32)
        stamp = np.zeros((new_rows, new_cols), dtype=_STAMP_DTYPE)
        if rows and cols:
            dr = self._row0 - new_r0
            dc = self._col0 - new_c0
            logodds[dr : dr + rows, dc : dc + cols] = self.logodds
            stamp[dr : dr + rows, dc : dc + cols] = self._stamp
        self.logodds = logodds
        self._stamp = stamp
        self._row0 = new_r0
        self._col0 = new_c0

    # ----------------------------------------------------------------- updates

    def integrate_scan(
        self,
        laser_pose: ArrayLike,
        ranges: ArrayLike,
        angles: ArrayLike,
        *,
        max_range: float | None = None,
    ) -> int:
        """Add one scan taken from ``laser_pose`` (world ``[x, y, theta]``) to the map.

        ``ranges`` (metres, NaN/inf/<=0 = no return) and ``angles`` (radians,
        laser frame) have one entry per beam. ``max_range`` overrides
        ``params.max_range`` (see :class:`GridParams`). The grid grows to hold
        the whole scan. Returns the number of cells updated.
        """
        pose = se2.as_poses(laser_pose)
        if pose.shape != (3,) or not np.all(np.isfinite(pose)):
            raise ValueError(f"laser_pose: {laser_pose!r} is not a finite pose [x, y, theta]")
        r = np.asarray(ranges, dtype=np.float64).reshape(-1)
        a = np.asarray(angles, dtype=np.float64).reshape(-1)
        if r.shape != a.shape:
            raise ValueError(f"ranges ({r.shape[0]}) and angles ({a.shape[0]}) differ in length")
        limit = self.params.max_range if max_range is None else max_range
        with np.errstate(invalid="ignore"):
            hit = np.isfinite(r) & (r > 0.0)
        if limit is not None:
            # Long returns and no-returns: free space up to the usable range, no hit.
            hit &= r <= limit
            r = np.where(hit, r, limit)
        elif not hit.all():
            r = r[hit]
            a = a[hit]
            hit = hit[hit]
        direction = pose[2] + a
        end_x = pose[0] + r * np.cos(direction)
        end_y = pose[1] + r * np.sin(direction)
        return self._integrate(pose[0], pose[1], end_x, end_y, hit)

    def integrate_points(
        self, laser_xy: ArrayLike, points: ArrayLike, *, hits: ArrayLike | None = None
    ) -> int:
        """Add beams from the world point ``laser_xy`` to world endpoints ``points`` ``(N, 2)``.

        ``hits[i]`` False makes beam ``i`` clear free space only (its endpoint
        cell included). Returns the number of cells updated.
        """
        start = np.asarray(laser_xy, dtype=np.float64).reshape(-1)
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        if start.shape != (2,) or not np.all(np.isfinite(start)):
            raise ValueError(f"laser_xy: {laser_xy!r} is not a finite point [x, y]")
        if hits is None:
            hit = np.ones(pts.shape[0], dtype=np.bool_)
        else:
            hit = np.asarray(hits, dtype=np.bool_).reshape(-1)
            if hit.shape[0] != pts.shape[0]:
                raise ValueError(f"hits: {hit.shape[0]} flags for {pts.shape[0]} points")
        ok = np.isfinite(pts).all(axis=1)
        if not ok.all():
            pts, hit = pts[ok], hit[ok]
        return self._integrate(start[0], start[1], pts[:, 0].copy(), pts[:, 1].copy(), hit)

    def integrate(self, scan: LaserScan | Any, robot_pose: ArrayLike) -> int:
        """Add a scan (or a frame: anything with ``.scan``) seen from the robot at ``robot_pose``.

        The laser's pose is ``robot_pose ⊕ scan.mount``.
        """
        if not isinstance(scan, LaserScan):
            scan = scan.scan
        laser_pose = se2.compose(np.asarray(robot_pose, dtype=np.float64), scan.mount)
        return self.integrate_scan(laser_pose, scan.ranges, scan.angles)

    def _integrate(
        self,
        start_x: float,
        start_y: float,
        end_x: NDArray[np.float64],
        end_y: NDArray[np.float64],
        hit: NDArray[np.bool_],
    ) -> int:
        if end_x.shape[0] == 0:
            xmin = xmax = start_x
            ymin = ymax = start_y
        else:
            xmin = min(start_x, float(end_x.min()))
            xmax = max(start_x, float(end_x.max()))
            ymin = min(start_y, float(end_y.min()))
            ymax = max(start_y, float(end_y.max()))
        self.ensure_contains(xmin, ymin, xmax, ymax)
        if self._scan_stamp >= _STAMP_LIMIT:
            # Stamps wrap: keep "observed" (non-zero) and restart the count.
            self._stamp[self._stamp != 0] = 1
            self._scan_stamp = 2
        ox, oy = self.origin
        updated = integrate_rays(
            self.logodds,
            self._stamp,
            self._scan_stamp,
            ox,
            oy,
            self.resolution,
            float(start_x),
            float(start_y),
            np.ascontiguousarray(end_x, dtype=np.float64),
            np.ascontiguousarray(end_y, dtype=np.float64),
            np.ascontiguousarray(hit, dtype=np.bool_),
            self.l_hit,
            self.l_miss,
            self.l_min,
            self.l_max,
        )
        self._scan_stamp += 1
        return int(updated)

    # ----------------------------------------------------------------- views

    @property
    def observed(self) -> NDArray[np.bool_]:
        """True for cells some beam has touched (or loaded with a known value)."""
        return self._stamp != 0

    def probability(self) -> NDArray[np.float32]:
        """Occupancy probability per cell in ``[0, 1]``; 0.5 where unknown."""
        return _probability(self.logodds)

    def occupancy(self) -> NDArray[np.int8]:
        """``nav_msgs/OccupancyGrid`` values: -1 never observed, else ``round(100 * p)``."""
        occ = np.empty(self.shape, dtype=np.int8)
        for rows in row_bands(self.shape):  # a band of rows at a time: no float copy of a whole big map
            occ[rows] = np.rint(_probability(self.logodds[rows]) * 100.0).astype(np.int8)
        occ[self._stamp == 0] = -1
        return occ

    def occupied(self, threshold: float = 0.65) -> NDArray[np.bool_]:
        """True for observed cells whose occupancy probability is above ``threshold``."""
        return (self.logodds > np.float32(logit(threshold))) & (self._stamp != 0)

    def crop_to_observed(self, margin: int = 1) -> OccupancyGrid:
        """A new grid trimmed to the observed cells plus ``margin`` unknown cells around them.

        It keeps this grid's lattice, so cells line up exactly. A grid with
        nothing observed crops to an empty grid; a grid already cropped is
        returned itself (read the result, do not change it).
        """
        seen = self.observed
        rows_any = np.flatnonzero(seen.any(axis=1))
        rows, cols = self.shape
        cols_any = np.flatnonzero(seen.any(axis=0))
        if rows_any.size == 0:
            empty = np.zeros((0, 0), dtype=np.float32)
            return self._with_arrays(empty, np.zeros((0, 0), _STAMP_DTYPE), self._row0, self._col0)
        r0 = int(rows_any[0]) - margin
        r1 = int(rows_any[-1]) + margin + 1
        c0 = int(cols_any[0]) - margin
        c1 = int(cols_any[-1]) + margin + 1
        if (r0, r1, c0, c1) == (0, rows, 0, cols):
            return self  # already cropped: no copy of a big map
        logodds = np.zeros((r1 - r0, c1 - c0), dtype=np.float32)
        stamp = np.zeros((r1 - r0, c1 - c0), dtype=_STAMP_DTYPE)
        sr0, sr1 = max(r0, 0), min(r1, rows)
        sc0, sc1 = max(c0, 0), min(c1, cols)
        logodds[sr0 - r0 : sr1 - r0, sc0 - c0 : sc1 - c0] = self.logodds[sr0:sr1, sc0:sc1]
        stamp[sr0 - r0 : sr1 - r0, sc0 - c0 : sc1 - c0] = self._stamp[sr0:sr1, sc0:sc1]
        return self._with_arrays(logodds, stamp, self._row0 + r0, self._col0 + c0)

    def __repr__(self) -> str:
        rows, cols = self.shape
        ox, oy = self.origin
        return (
            f"OccupancyGrid({rows} x {cols} cells of {self.resolution:g} m, "
            f"origin ({ox:.3f}, {oy:.3f}), {int(self.observed.sum())} observed)"
        )


def _replace(params: GridParams, **changes: Any) -> GridParams:
    from dataclasses import replace

    return replace(params, **changes)
