"""Laser scans and their one clean-up step.

Every reader and the simulator build scans through :func:`make_scan`, so the
rules live in one place:

* a reading that is NaN, infinite, zero or negative, below ``range_min`` or at
  or beyond ``range_max`` becomes "no return", stored as NaN;
* a negative angle increment (a laser mounted reversed) is normalised by
  reversing the beam order, so ``angle_increment`` is always positive and beam
  angles always increase counter-clockwise;
* an upside-down laser (its z axis pointing down) has its beam angles
  mirrored, so the scan is expressed in a right-handed frame with z up;
* any number of beams is allowed (tested with 10,000).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from slam2d.core import se2

__all__ = ["LaserScan", "make_scan"]

_ZERO_POSE = np.zeros(3)
_ZERO_POSE.setflags(write=False)


@dataclass(frozen=True, slots=True, eq=False)
class LaserScan:
    """One sweep of a planar laser, already cleaned by :func:`make_scan`.

    Attributes:
        timestamp: time of the scan in seconds (the first beam, as ROS stamps it).
        ranges: metres, one per beam; NaN means no return.
        angle_min: radians, direction of the first beam in the laser frame.
        angle_increment: radians between beams, always positive.
        range_min: metres, shortest valid reading.
        range_max: metres, readings at or beyond it are no return.
        mount: the laser's pose ``[x, y, theta]`` on the robot (base frame).
        intensities: optional per-beam intensities or remissions.
        frame_id: the laser's frame name when the source has one.
    """

    timestamp: float
    ranges: NDArray[np.float64]
    angle_min: float
    angle_increment: float
    range_min: float
    range_max: float
    mount: NDArray[np.float64] = field(default_factory=lambda: _ZERO_POSE)
    intensities: NDArray[np.float64] | None = None
    frame_id: str = ""

    @property
    def num_beams(self) -> int:
        return int(self.ranges.shape[0])

    @property
    def angles(self) -> NDArray[np.float64]:
        """Beam directions in the laser frame, radians."""
        return self.angle_min + self.angle_increment * np.arange(self.num_beams, dtype=np.float64)

    @property
    def angle_max(self) -> float:
        return self.angle_min + self.angle_increment * (self.num_beams - 1)

    @property
    def field_of_view(self) -> float:
        """Angle covered from the first to the last beam, radians."""
        return self.angle_increment * (self.num_beams - 1)

    @property
    def valid(self) -> NDArray[np.bool_]:
        """True for beams with a return."""
        return ~np.isnan(self.ranges)

    def points(self) -> NDArray[np.float64]:
        """Endpoints of the beams with a return, ``(N, 2)`` in the laser frame."""
        ok = self.valid
        r = self.ranges[ok]
        a = self.angles[ok]
        return np.stack([r * np.cos(a), r * np.sin(a)], axis=-1)

    def points_in_base(self) -> NDArray[np.float64]:
        """Endpoints of the beams with a return, ``(N, 2)`` in the robot base frame."""
        return se2.transform_points(self.mount, self.points())


def make_scan(
    timestamp: float,
    ranges: ArrayLike,
    angle_min: float,
    angle_increment: float,
    range_min: float = 0.0,
    range_max: float = np.inf,
    *,
    mount: ArrayLike | None = None,
    intensities: ArrayLike | None = None,
    upside_down: bool = False,
    frame_id: str = "",
) -> LaserScan:
    """Build a cleaned :class:`LaserScan`.

    Raises ``ValueError`` with the offending field named when the scan cannot
    be made sense of; readers turn it into an :class:`~slam2d.errors.InputError`
    that also names the file and the line.
    """
    r = np.array(ranges, dtype=np.float64, copy=True).reshape(-1)
    n = r.shape[0]
    if n == 0:
        raise ValueError("ranges: a scan needs at least one beam")
    angle_min = float(angle_min)
    angle_increment = float(angle_increment)
    range_min = float(range_min)
    range_max = float(range_max)
    if not np.isfinite(angle_min):
        raise ValueError(f"angle_min: {angle_min} is not a finite angle")
    if not np.isfinite(angle_increment) or (angle_increment == 0.0 and n > 1):
        raise ValueError(f"angle_increment: {angle_increment} must be finite and non-zero")
    if not (np.isfinite(range_min) and range_min >= 0.0):
        raise ValueError(f"range_min: {range_min} must be a finite distance >= 0")
    if not (range_max > range_min):
        raise ValueError(f"range_max: {range_max} must be greater than range_min ({range_min})")
    inten = None
    if intensities is not None:
        inten = np.array(intensities, dtype=np.float64, copy=True).reshape(-1)
        if inten.shape[0] == 0:
            inten = None
        elif inten.shape[0] != n:
            raise ValueError(f"intensities: {inten.shape[0]} values for {n} beams")

    with np.errstate(invalid="ignore"):
        no_return = ~np.isfinite(r) | (r <= 0.0) | (r < range_min) | (r >= range_max)
    r[no_return] = np.nan

    if upside_down:
        # Seen from above, an upside-down laser sweeps clockwise: mirror the angles.
        angle_min = -angle_min
        angle_increment = -angle_increment
    if angle_increment < 0.0:
        angle_min = angle_min + angle_increment * (n - 1)
        angle_increment = -angle_increment
        r = r[::-1].copy()
        if inten is not None:
            inten = inten[::-1].copy()

    m = _ZERO_POSE if mount is None else np.array(mount, dtype=np.float64)
    if m.shape != (3,) or not np.all(np.isfinite(m)):
        raise ValueError(f"mount: {m!r} is not a finite pose [x, y, theta]")
    return LaserScan(
        timestamp=float(timestamp),
        ranges=r,
        angle_min=angle_min,
        angle_increment=angle_increment,
        range_min=range_min,
        range_max=range_max,
        mount=m,
        intensities=inten,
        frame_id=frame_id,
    )
