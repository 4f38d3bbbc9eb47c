"""Odometry noise: GMapping's srr/srt/str/stt, systematic scale errors and wheel slip.

The model turns a true trajectory into the odometry a robot would report. Each
step between two samples is an increment ``(dx, dy, dtheta)`` in the frame of
the earlier true pose; odometry composes a corrupted copy of it onto its own
previous pose, so errors accumulate the way they do on a robot:

1. **Systematic scales** (per run, deterministic)::

       dx' = wheel_radius_scale * dx      dy' = wheel_radius_scale * dy
       dtheta' = dtheta / track_width_scale

2. **Slip**: with probability ``slip_probability`` a step slips, and the wheels
   turn further than the robot moved: the step's odometry is divided by
   ``1 - slip_fraction`` (all three components).

3. **Random noise**: independent zero-mean Gaussian noise on each component of
   the step, with variances (``D = reference_distance``, ``A = reference_rotation``,
   ``d = sqrt(dx**2 + dy**2)``, all magnitudes of the *true* increment)::

       var_x     = D * (srr**2 |dx| + (0.3 srr)**2 |dy|) + A * str**2 |dtheta|
       var_y     = D * (srr**2 |dy| + (0.3 srr)**2 |dx|) + A * str**2 |dtheta|
       var_theta = A * stt**2 |dtheta| + D * srt**2 d

How this mirrors GMapping. GMapping's motion model (``motionmodel.cpp``,
``drawFromMotion``) adds Gaussian noise to the odometry increment between two
filter updates with *standard deviations*
``sx = srr|dx| + str|dtheta| + 0.3 srr|dy|``, ``sy = srr|dy| + str|dtheta| + 0.3 srr|dx|``,
``stheta = stt|dtheta| + srt d``. Note the roles the code gives the names: ``str``
(m/rad) turns rotation into translation noise and ``srt`` (rad/m) turns
translation into rotation noise; we follow the code, not the ROS wiki wording
that swaps them. Applying GMapping's standard deviations to every 20 ms
odometry step would make the drift depend on the odometry rate (n steps of
length d/n give a spread of srr*d/sqrt(n)). So the variances above add up
over steps instead: the spread over any motion is independent of the rate, and
over one reference increment (``reference_distance`` straight, default 1 m =
GMapping's ``linearUpdate``, or ``reference_rotation`` in place, default
0.5 rad = its ``angularUpdate``) it equals GMapping's standard deviation
exactly. Over a longer motion the spread grows like a random walk: a straight
drive of ``L`` metres has ``std(x error) = srr * sqrt(L * reference_distance)``
and a turn in place by ``a`` radians has
``std(heading error) = stt * sqrt(|a| * reference_rotation)``. For a motion that
both translates and rotates, the terms add in variance (GMapping adds their
standard deviations, which is larger by at most a factor sqrt(2)).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray

from slam2d.core import se2
from slam2d.errors import InputError
from slam2d.params import param, validate

__all__ = [
    "OdometryNoise", "simulate_odometry", "step_variances", "odometry_increments", "gmapping_motion_std",
    "draw_from_motion",
]

# GMapping's coupling of lateral and forward translation noise (motionmodel.cpp: sxy = 0.3 * srr).
LATERAL_COUPLING = 0.3


@dataclass(frozen=True)
class OdometryNoise:
    """How simulated odometry departs from the truth. Defaults are GMapping's (noisy) defaults.

    See the module docstring and docs/robots.md for exactly how each field enters.
    """

    srr: float = param(0.1, unit="m/m", low=0.0, help="translation noise from translation (GMapping srr)")
    srt: float = param(
        0.2, unit="rad/m", low=0.0,
        help="rotation noise from translation (GMapping srt, as its motion model uses it)",
    )
    str: float = param(
        0.1, unit="m/rad", low=0.0,
        help="translation noise from rotation (GMapping str, as its motion model uses it)",
    )
    stt: float = param(0.2, unit="rad/rad", low=0.0, help="rotation noise from rotation (GMapping stt)")
    reference_distance: float = param(
        1.0, unit="m", low=1e-9,
        help="straight motion over which the translation spread is exactly srr times it (GMapping linearUpdate)",
    )
    reference_rotation: float = param(
        0.5, unit="rad", low=1e-9,
        help="rotation over which the heading spread is exactly stt times it (GMapping angularUpdate)",
    )
    wheel_radius_scale: float = param(
        1.0, low=1e-6, help="systematic: odometry translation = true translation x this"
    )
    track_width_scale: float = param(
        1.0, low=1e-6, help="systematic: odometry rotation = true rotation / this"
    )
    slip_probability: float = param(
        0.0, low=0.0, high=1.0, help="probability that an odometry step slips (the mean excess is rate independent)"
    )
    slip_fraction: float = param(
        0.0, low=0.0, high=0.99,
        help="fraction of the wheels' motion lost on a slipping step: odometry reports the step / (1 - this)",
    )

    def check(self) -> None:
        """Raise :class:`InputError` naming the first field that is out of range."""
        for name in (
            "srr", "srt", "str", "stt", "reference_distance", "reference_rotation",
            "wheel_radius_scale", "track_width_scale", "slip_probability", "slip_fraction",
        ):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or not math.isfinite(value):
                raise InputError(f"{value!r} is not a finite number", field=name)
        validate(self)


def odometry_increments(poses: ArrayLike) -> NDArray[np.float64]:
    """Increments ``(N-1, 3)`` between consecutive poses, each in the frame of the earlier pose."""
    p = se2.as_poses(poses)
    return se2.relative(p[:-1], p[1:])


def step_variances(increments: ArrayLike, noise: OdometryNoise) -> NDArray[np.float64]:
    """Variances ``(N, 3)`` (x, y, heading) of the noise :func:`simulate_odometry` adds to each increment.

    ``increments`` are true steps ``(dx, dy, dtheta)`` in the frame of the earlier pose. The one
    place the simulated odometry's noise model is written: the simulator draws from it and
    ``slam2d.eval.accuracy_bound`` counts it.
    """
    d = np.asarray(increments, dtype=np.float64).reshape(-1, 3)
    adx, ady, adt = np.abs(d[:, 0]), np.abs(d[:, 1]), np.abs(d[:, 2])
    dist = np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1])
    D, A = float(noise.reference_distance), float(noise.reference_rotation)
    srr2, sxy2 = float(noise.srr) * float(noise.srr), (LATERAL_COUPLING * float(noise.srr)) ** 2
    str_, stt, srt = float(noise.str), float(noise.stt), float(noise.srt)
    return np.stack([
        D * (srr2 * adx + sxy2 * ady) + A * str_ * str_ * adt,
        D * (srr2 * ady + sxy2 * adx) + A * str_ * str_ * adt,
        A * stt * stt * adt + D * srt * srt * dist,
    ], axis=1)


@njit(cache=True)
def _integrate_odometry(
    start: NDArray[np.float64],
    increments: NDArray[np.float64],
    variances: NDArray[np.float64],
    normals: NDArray[np.float64],
    uniforms: NDArray[np.float64],
    radius_scale: float, track_scale: float,
    slip_probability: float, slip_gain: float,
) -> NDArray[np.float64]:
    n = increments.shape[0]
    out = np.empty((n + 1, 3))
    out[0, 0], out[0, 1], out[0, 2] = start[0], start[1], start[2]
    for k in range(n):
        dx, dy, dth = increments[k, 0], increments[k, 1], increments[k, 2]
        var_x, var_y, var_t = variances[k, 0], variances[k, 1], variances[k, 2]
        gain = slip_gain if uniforms[k] < slip_probability else 1.0
        ox = dx * radius_scale * gain + math.sqrt(var_x) * normals[k, 0]
        oy = dy * radius_scale * gain + math.sqrt(var_y) * normals[k, 1]
        ot = dth / track_scale * gain + math.sqrt(var_t) * normals[k, 2]
        th = out[k, 2]
        c, s = math.cos(th), math.sin(th)
        out[k + 1, 0] = out[k, 0] + c * ox - s * oy
        out[k + 1, 1] = out[k, 1] + s * ox + c * oy
        # wrap to [-pi, pi) like slam2d.core.se2
        out[k + 1, 2] = (th + ot + math.pi) % (2.0 * math.pi) - math.pi
    return out


def simulate_odometry(
    times: ArrayLike, true_poses: ArrayLike, noise: OdometryNoise, rng: np.random.Generator
) -> NDArray[np.float64]:
    """Odometry poses ``(N, 3)`` for a true trajectory sampled at ``times``.

    The odometry frame coincides with the world at the first sample
    (``odom[0] == true_poses[0]``). Every random number comes from ``rng``:
    ``3 (N-1)`` standard normals, then ``N-1`` uniforms for slip, always drawn
    in that order whatever the parameters, so the same seed gives the same
    numbers and changing one parameter does not reshuffle the others' draws.
    ``times`` only fixes the sample count and must increase; the model depends
    on the motion, not on time.
    """
    noise.check()
    t = np.asarray(times, dtype=np.float64)
    try:
        poses = se2.as_poses(true_poses)
    except ValueError as exc:
        raise InputError(str(exc), field="true_poses") from None
    if poses.ndim != 2 or t.ndim != 1 or len(t) != len(poses):
        raise InputError(
            f"times {t.shape} and poses {poses.shape} must be (N,) and (N, 3)", field="true_poses"
        )
    if len(poses) == 0:
        return np.empty((0, 3))
    if not (np.all(np.isfinite(poses)) and np.all(np.isfinite(t))):
        raise InputError("times and poses must be finite", field="true_poses")
    if np.any(np.diff(t) <= 0.0):
        raise InputError("times must increase", field="times")
    increments = odometry_increments(poses)
    steps = len(increments)
    normals = rng.standard_normal((steps, 3))
    uniforms = rng.random(steps)
    return _integrate_odometry(
        np.ascontiguousarray(poses[0]), np.ascontiguousarray(increments), step_variances(increments, noise),
        normals, uniforms, float(noise.wheel_radius_scale), float(noise.track_width_scale),
        float(noise.slip_probability), 1.0 / (1.0 - float(noise.slip_fraction)),
    )


def gmapping_motion_std(delta: ArrayLike, srr: float, srt: float, str_: float, stt: float) -> NDArray[np.float64]:
    """GMapping's standard deviations ``(sx, sy, stheta)`` of the noise on an odometry increment.

    ``delta`` is ``(dx, dy, dtheta)`` in the frame of the earlier pose (``motionmodel.cpp``,
    ``drawFromMotion``; ``str`` turns rotation into translation noise, ``srt`` translation
    into rotation noise, as the code uses them). ``delta`` of shape (N, 3) gives (N, 3), one row per increment.
    """
    d = np.asarray(delta, dtype=np.float64)
    sxy = LATERAL_COUPLING * srr
    if d.ndim == 2:
        dx, dy, dth = np.abs(d).T
        return np.stack([srr * dx + str_ * dth + sxy * dy, srr * dy + str_ * dth + sxy * dx,
                         stt * dth + srt * np.hypot(dx, dy)], -1)
    # One increment (the filter's per-update call): Python floats, cheaper than numpy on three numbers.
    dx, dy, dth = (abs(float(v)) for v in d.reshape(3))
    return np.array([
        srr * dx + str_ * dth + sxy * dy,
        srr * dy + str_ * dth + sxy * dx,
        stt * dth + srt * math.hypot(dx, dy),
    ])


@njit(cache=True)
def _draw_from_motion(poses, delta, normals, sx, sy, st):
    for p in range(poses.shape[0]):
        ox = delta[0] + sx * normals[p, 0]
        oy = delta[1] + sy * normals[p, 1]
        ot = delta[2] + st * normals[p, 2]
        th = poses[p, 2]
        c, s = math.cos(th), math.sin(th)
        poses[p, 0] += c * ox - s * oy
        poses[p, 1] += s * ox + c * oy
        poses[p, 2] = (th + ot + math.pi) % (2.0 * math.pi) - math.pi


def draw_from_motion(
    poses: NDArray[np.float64], delta: ArrayLike, normals: NDArray[np.float64],
    srr: float, srt: float, str_: float, stt: float,
) -> None:
    """Move every particle pose ``(N, 3)`` in place by the odometry increment ``delta`` plus noise.

    GMapping's ``drawFromMotion`` for all particles at once: each gets
    ``delta + (sx, sy, stheta) * normals[p]`` (standard deviations from
    :func:`gmapping_motion_std`) composed onto its pose. ``normals`` is
    ``(N, 3)`` standard normals from the caller's seeded generator.
    """
    d = np.asarray(delta, dtype=np.float64).reshape(3)
    sx, sy, st = gmapping_motion_std(d, srr, srt, str_, stt)
    _draw_from_motion(poses, d, np.ascontiguousarray(normals, dtype=np.float64), sx, sy, st)
