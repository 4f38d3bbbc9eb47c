"""A synthetic rectangular room and exact laser scans of it, for the matcher tests."""

from __future__ import annotations

import numpy as np

from slam2d.core import make_scan
from slam2d.core.frames import Frame

ROOM = (-3.0, -2.0, 4.0, 3.5)  # xmin, ymin, xmax, ymax of the walls, metres
# A pillar breaks the room's symmetry so a scan has one best fit.
PILLAR = (1.0, 1.0, 1.6, 1.4)


def _box_hits(px, py, dx, dy, box, inside):
    xmin, ymin, xmax, ymax = box
    with np.errstate(divide="ignore", invalid="ignore"):
        tx1, tx2 = (xmin - px) / dx, (xmax - px) / dx
        ty1, ty2 = (ymin - py) / dy, (ymax - py) / dy
    if inside:  # leaving the box: the nearest positive exit (a ray parallel to two walls never meets them)
        t = np.fmin(np.where(dx > 0, tx2, np.where(dx < 0, tx1, np.inf)),
                    np.where(dy > 0, ty2, np.where(dy < 0, ty1, np.inf)))
        return np.where(np.isfinite(t) & (t > 0), t, np.inf)
    tmin = np.fmax(np.fmin(tx1, tx2), np.fmin(ty1, ty2))
    tmax = np.fmin(np.fmax(tx1, tx2), np.fmax(ty1, ty2))
    return np.where((tmax >= tmin) & (tmin > 0), tmin, np.inf)


def box_ranges(angles, box, origin=(0.0, 0.0)):
    """Exact ranges along world bearings ``angles`` from ``origin`` to the walls of ``box`` (xmin, ymin, xmax, ymax)."""
    return _box_hits(origin[0], origin[1], np.cos(angles), np.sin(angles), box, True)


def room_scan(pose, n=361, fov=np.radians(240), max_range=20.0, t=0.0):
    """An exact scan of the room (and pillar) from laser pose ``[x, y, theta]``."""
    a = -fov / 2 + fov * np.arange(n) / (n - 1)
    d = pose[2] + a
    dx, dy = np.cos(d), np.sin(d)
    r = np.fmin(_box_hits(pose[0], pose[1], dx, dy, ROOM, True), _box_hits(pose[0], pose[1], dx, dy, PILLAR, False))
    r = np.where(r < max_range, r, np.nan)
    return make_scan(t, r, -fov / 2, fov / (n - 1), 0.02, max_range)


def frame(scan, odometry=None, index=0):
    return Frame(index=index, scan=scan, odometry=None if odometry is None else np.asarray(odometry, dtype=np.float64))


def boxes_grid(shape, origin, resolution, boxes):
    """A boolean occupancy grid ``shape`` (rows, cols) with lower-left corner ``origin`` and cells of
    ``resolution`` m, occupied inside each box ``(x0, y0, x1, y1)`` (metres, rounded to cells)."""
    occ = np.zeros(shape, dtype=bool)
    for x0, y0, x1, y1 in boxes:
        occ[round((y0 - origin[1]) / resolution): round((y1 - origin[1]) / resolution),
            round((x0 - origin[0]) / resolution): round((x1 - origin[0]) / resolution)] = True
    return occ
