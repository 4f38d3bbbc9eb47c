"""Simulated planar lasers: exact ray casting against a world, then the range noise model.

A world is anything with the attributes of :class:`slam2d.sim.world.World`:
``segments`` ``(M, 4)`` as ``x0, y0, x1, y1``, ``segment_material`` ``(M,)``,
``circles`` ``(K, 3)`` as ``cx, cy, r`` and ``circle_material`` ``(K,)``
(material indices into :data:`slam2d.sensors.range_noise.MATERIALS`).

:func:`cast_rays` finds, for every beam, the nearest wall or circle in closed
form (no grid, no marching), with the incidence angle between the beam and the
surface normal, which the noise model needs. :class:`LaserSimulator` turns
that into one sweep of readings: Gaussian range noise with the model's sigma,
dropouts, no-returns beyond the range limits, and optionally the distortion of
a sweep taken while the robot moves.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray

from slam2d.core import se2
from slam2d.errors import InputError
from slam2d.params import param
from slam2d.sensors.range_noise import RangeNoiseModel, StudyModel, dropout_probability

__all__ = ["LaserSpec", "LASER_PRESETS", "laser_preset", "cast_rays", "LaserSimulator"]

#: URG-04LX angular step: its mirror is divided into 1024 steps per revolution.
_URG_STEP = 2.0 * math.pi / 1024.0


@dataclass
class LaserSpec:
    """A planar scanning laser: beam layout, range limits and scan rate.

    Beam ``i`` points at ``angle_min + i * angle_increment`` in the laser frame
    (counter-clockwise from the laser's x axis). A reading below ``range_min``
    or at or beyond ``range_max`` is no return. Bad values raise
    :class:`~slam2d.errors.InputError` naming the field.
    """

    name: str = param("custom", help="name of the laser model")
    beams: int = param(682, low=1, help="number of beams in one scan")
    angle_min: float = param(-340 * _URG_STEP, unit="rad", help="direction of the first beam in the laser frame")
    angle_increment: float = param(_URG_STEP, unit="rad", help="angle between neighbouring beams (> 0)")
    range_min: float = param(0.02, unit="m", low=0.0, help="shortest distance the laser reports")
    range_max: float = param(5.6, unit="m", help="longest distance the laser reports")
    rate: float = param(10.0, unit="Hz", help="scans per second")

    def __post_init__(self) -> None:
        def bad(field: str, why: str) -> InputError:
            return InputError(why, where=f"laser {self.name!r}", field=field)

        if isinstance(self.beams, bool) or not isinstance(self.beams, (int, np.integer)) or self.beams < 1:
            raise bad("beams", f"{self.beams!r} must be a whole number of beams >= 1")
        for name in ("angle_min", "angle_increment", "range_min", "range_max", "rate"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
                raise bad(name, f"{value!r} is not a number")
        if not math.isfinite(self.angle_min):
            raise bad("angle_min", f"{self.angle_min} is not a finite angle")
        if not (math.isfinite(self.angle_increment) and self.angle_increment > 0.0):
            raise bad("angle_increment", f"{self.angle_increment} rad must be a finite angle > 0")
        if self.angle_increment * self.beams > 2.0 * math.pi * (1.0 + 1e-9):
            raise bad("beams", f"{self.beams} beams of {self.angle_increment} rad cover more than a full turn")
        if not (math.isfinite(self.range_min) and self.range_min >= 0.0):
            raise bad("range_min", f"{self.range_min} m must be a finite distance >= 0")
        if not (math.isfinite(self.range_max) and self.range_max > self.range_min):
            raise bad("range_max", f"{self.range_max} m must be finite and greater than range_min ({self.range_min} m)")
        if not (math.isfinite(self.rate) and self.rate > 0.0):
            raise bad("rate", f"{self.rate} Hz must be a finite rate > 0")

    @property
    def angles(self) -> NDArray[np.float64]:
        """Beam directions in the laser frame, radians, ``(beams,)``."""
        return self.angle_min + self.angle_increment * np.arange(self.beams, dtype=np.float64)

    @property
    def field_of_view(self) -> float:
        """Angle from the first to the last beam, radians."""
        return self.angle_increment * (self.beams - 1)

    @property
    def sweep_duration(self) -> float:
        """Seconds from the first to the last beam, for a mirror turning once per scan."""
        return self.field_of_view / (2.0 * math.pi) / self.rate

    @property
    def central_beam(self) -> int:
        """Index of the beam closest to the laser's x axis (straight ahead)."""
        return int(np.argmin(np.abs(self.angles)))


#: Preset lasers. Sources: Hokuyo URG-04LX-UG01 specification (20-5600 mm, 240 deg,
#: 0.352 deg = 360/1024 deg steps, 100 ms per scan; the driver reports steps 44-725,
#: 682 beams, the front at step 384); SICK LMS 200 technical description (180 deg at
#: 0.5 deg by interlacing two 75 Hz turns: 37.5 scans/s, 80 m); Slamtec RPLIDAR A1
#: datasheet (360 deg, 0.15-12 m, 5.5 Hz typical, about 1 deg resolution).
LASER_PRESETS: dict[str, LaserSpec] = {
    "urg-04lx": LaserSpec("urg-04lx", 682, -340 * _URG_STEP, _URG_STEP, 0.02, 5.6, 10.0),
    "urg-04lx-ug01": LaserSpec("urg-04lx-ug01", 682, -340 * _URG_STEP, _URG_STEP, 0.02, 5.6, 10.0),
    "sick-lms": LaserSpec("sick-lms", 361, -math.pi / 2, math.radians(0.5), 0.0, 80.0, 37.5),
    "rplidar-a1": LaserSpec("rplidar-a1", 360, -math.pi, math.radians(1.0), 0.15, 12.0, 5.5),
}


def laser_preset(name: str) -> LaserSpec:
    """A fresh copy of the preset laser ``name`` (case-insensitive).

    Raises :class:`~slam2d.errors.InputError` (field ``laser``) listing the presets.
    """
    key = str(name).strip().lower()
    if key not in LASER_PRESETS:
        raise InputError(f"unknown laser {name!r}; presets: {', '.join(LASER_PRESETS)}", field="laser")
    return dataclasses.replace(LASER_PRESETS[key])


# ---------------------------------------------------------------------------
# Ray casting


@njit(cache=True)
def _cast_kernel(ox, oy, heading, segments, segment_material, circles, circle_material, ranges, incidence, material):
    """Nearest hit along each ray ``(ox[i], oy[i])`` + t (cos heading[i], sin heading[i]), t > 0.

    Writes ``ranges`` (inf: no hit), ``incidence`` (radians from the surface
    normal, NaN: no hit) and ``material`` (-1: no hit). A ray parallel to a wall
    does not hit it; a ray through a segment's end point does.
    """
    n = ox.shape[0]
    m = segments.shape[0]
    k = circles.shape[0]
    ex = np.empty(m)
    ey = np.empty(m)
    for j in range(m):
        ex[j] = segments[j, 2] - segments[j, 0]
        ey[j] = segments[j, 3] - segments[j, 1]
    for i in range(n):
        dx = math.cos(heading[i])
        dy = math.sin(heading[i])
        px = ox[i]
        py = oy[i]
        best = np.inf
        best_inc = np.nan
        best_mat = -1
        for j in range(m):
            denom = dx * ey[j] - dy * ex[j]  # d x e
            if denom == 0.0:
                continue
            ax = segments[j, 0] - px
            ay = segments[j, 1] - py
            t = (ax * ey[j] - ay * ex[j]) / denom
            if t <= 0.0 or t >= best:
                continue
            u = (ax * dy - ay * dx) / denom
            if u < 0.0 or u > 1.0:
                continue
            best = t
            # atan2 keeps the angle exact near 0 and 90 degrees, where acos is not
            best_inc = math.atan2(abs(dx * ex[j] + dy * ey[j]), abs(denom))
            best_mat = segment_material[j]
        for j in range(k):
            fx = px - circles[j, 0]
            fy = py - circles[j, 1]
            r = circles[j, 2]
            b = fx * dx + fy * dy
            c = fx * fx + fy * fy - r * r
            disc = b * b - c
            if disc < 0.0:
                continue
            root = math.sqrt(disc)
            t = -b - root
            if t <= 0.0:
                t = -b + root  # the ray starts inside the circle: its far side
            if t <= 0.0 or t >= best:
                continue
            best = t
            nx = fx + t * dx
            ny = fy + t * dy
            best_inc = math.atan2(abs(dx * ny - dy * nx), abs(dx * nx + dy * ny))
            best_mat = circle_material[j]
        ranges[i] = best
        incidence[i] = best_inc
        material[i] = best_mat


class _Geometry:
    """A world's shapes as contiguous arrays for the kernel (made once per simulator)."""

    __slots__ = ("segments", "segment_material", "circles", "circle_material")

    def __init__(self, world: Any) -> None:
        self.segments = np.ascontiguousarray(np.asarray(world.segments, dtype=np.float64).reshape(-1, 4))
        self.segment_material = np.ascontiguousarray(np.asarray(world.segment_material, dtype=np.int64).reshape(-1))
        self.circles = np.ascontiguousarray(np.asarray(world.circles, dtype=np.float64).reshape(-1, 3))
        self.circle_material = np.ascontiguousarray(np.asarray(world.circle_material, dtype=np.int64).reshape(-1))
        if self.segment_material.shape[0] != self.segments.shape[0]:
            raise ValueError("world: segment_material needs one material per segment")
        if self.circle_material.shape[0] != self.circles.shape[0]:
            raise ValueError("world: circle_material needs one material per circle")

    def cast(
        self, ox: NDArray, oy: NDArray, heading: NDArray
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64]]:
        n = heading.shape[0]
        ranges = np.empty(n)
        incidence = np.empty(n)
        material = np.empty(n, dtype=np.int64)
        _cast_kernel(
            np.ascontiguousarray(ox, dtype=np.float64),
            np.ascontiguousarray(oy, dtype=np.float64),
            np.ascontiguousarray(heading, dtype=np.float64),
            self.segments,
            self.segment_material,
            self.circles,
            self.circle_material,
            ranges,
            incidence,
            material,
        )
        return ranges, incidence, material


def cast_rays(
    world: Any, laser_pose: ArrayLike, angles: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64]]:
    """Exact nearest intersection of each beam with the world's walls and circles.

    ``laser_pose`` is the laser's ``[x, y, theta]`` in the world and ``angles``
    ``(N,)`` the beam directions in the laser frame. Returns ``ranges`` (m, inf
    where nothing is hit), ``incidence`` (radians between the beam and the
    surface normal, in [0, pi/2]; NaN where nothing is hit) and ``material``
    (index into MATERIALS; -1 where nothing is hit).
    """
    pose = se2.as_poses(laser_pose).reshape(3)
    a = np.asarray(angles, dtype=np.float64).reshape(-1)
    n = a.shape[0]
    return _Geometry(world).cast(np.full(n, pose[0]), np.full(n, pose[1]), pose[2] + a)


class LaserSimulator:
    """One laser in one world: true ranges by exact ray casting, then noise and dropouts.

    ``noise`` defaults to the study's model (:class:`StudyModel`); use
    ``ConstantSigma(0.0)`` for noise-free ranges. ``dropouts`` loses returns
    with :func:`dropout_probability`. ``distortion`` casts each beam from
    where the laser was when that beam was measured (see :meth:`measure`).
    """

    def __init__(
        self,
        spec: LaserSpec,
        world: Any,
        noise: RangeNoiseModel | None = None,
        *,
        dropouts: bool = True,
        distortion: bool = False,
    ) -> None:
        self.spec = spec
        self.world = world
        self.noise: RangeNoiseModel = StudyModel() if noise is None else noise
        self.dropouts = bool(dropouts)
        self.distortion = bool(distortion)
        self.angles = spec.angles
        n = spec.beams
        # Fraction of the sweep at which each beam is measured.
        self._sweep_fraction = np.arange(n, dtype=np.float64) / (n - 1) if n > 1 else np.zeros(1)
        self._geometry = _Geometry(world)

    def beam_poses(self, pose_start: ArrayLike, pose_end: ArrayLike | None = None) -> NDArray[np.float64]:
        """The laser pose in the world at each beam ``(N, 3)``, heading including the beam angle.

        Without distortion (or without ``pose_end``) every beam starts at
        ``pose_start``; with it, beam ``i`` starts at the pose interpolated
        ``i / (N - 1)`` of the way from ``pose_start`` to ``pose_end``.
        """
        start = se2.as_poses(pose_start).reshape(3)
        n = self.spec.beams
        if self.distortion and pose_end is not None:
            poses = se2.interpolate(start, se2.as_poses(pose_end).reshape(3), self._sweep_fraction)
        else:
            poses = np.broadcast_to(start, (n, 3)).copy()
        poses[:, 2] = poses[:, 2] + self.angles
        return poses

    def cast(
        self, pose_start: ArrayLike, pose_end: ArrayLike | None = None
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64]]:
        """True ranges, incidences and materials of one sweep (as :func:`cast_rays`), no noise."""
        poses = self.beam_poses(pose_start, pose_end)
        return self._geometry.cast(poses[:, 0], poses[:, 1], poses[:, 2])

    def measure(
        self, pose_start: ArrayLike, pose_end: ArrayLike | None, rng: np.random.Generator
    ) -> NDArray[np.float64]:
        """The ranges ``(N,)`` of one sweep, as the laser reports them (NaN: no return).

        ``pose_start`` and ``pose_end`` are the laser's poses in the world at
        the first and the last beam of the sweep. Each hit gets Gaussian noise
        with the model's sigma; a dropout, nothing hit, or a reading outside
        ``[range_min, range_max)`` is NaN. The random draws are the same
        number per sweep whatever is hit, so a seed fixes every sweep.
        """
        true_range, incidence, material = self.cast(pose_start, pose_end)
        n = true_range.shape[0]
        gauss = rng.standard_normal(n)
        uniform = rng.random(n)
        hit = material >= 0
        sigma = np.zeros(n)
        sigma[hit] = self.noise.sigma(true_range[hit], incidence[hit], material[hit])
        ranges = np.where(hit, true_range + sigma * gauss, np.nan)
        if self.dropouts:
            p = np.zeros(n)
            p[hit] = dropout_probability(incidence[hit], material[hit])
            ranges[uniform < p] = np.nan
        with np.errstate(invalid="ignore"):
            outside = ~((ranges >= self.spec.range_min) & (ranges < self.spec.range_max) & (ranges > 0.0))
        ranges[outside] = np.nan
        return ranges
