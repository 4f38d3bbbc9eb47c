"""Per-beam range sigma for the SLAM methods: the one place a sensor model meets a scan.

Every method that weighs beams by their range noise (GMapping's likelihood,
Karto's smear, Hector's residual weights, CoreSLAM's hole width) calls
:func:`beam_sigmas` once per scan and uses the result for all of its
hypotheses, so a calibrated model plugs into every method the same way.

A model is anything with ``sigma(distance, incidence, material)`` (the
:class:`~slam2d.sensors.range_noise.RangeNoiseModel` protocol): a constant
(the study's 0.0041 m), sigma(range) or sigma(range, incidence).

The incidence angle of a beam (between the beam and the surface normal) is
estimated from its neighbouring endpoints: the surface through the endpoints
of beams ``i - 1`` and ``i + 1`` is the local wall, and the beam's angle to its
normal follows. Where a neighbour is missing or lies across a depth jump (a
different surface), the one-sided difference is used; a beam with no usable
neighbour gets incidence 0 (square to the surface, the smallest sigma).

A SLAM method does not know what material a beam hit, so by default the sigma
is the mean over the surfaces the study tabulated (its fits are that mean).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from slam2d.core.scan import LaserScan
from slam2d.sensors.range_noise import TABLE_I_MM, RangeNoiseModel, material_index

__all__ = ["incidence_angles", "beam_sigmas", "TABULATED_MATERIALS"]

#: Indices of the materials the study measured (Table I); the default material mix.
TABULATED_MATERIALS: tuple[int, ...] = tuple(material_index(m) for m in TABLE_I_MM)

# Two endpoints belong to the same surface when they are closer than this many
# times the spacing a surface square to both beams would give, and never closer
# than the absolute floor (noise alone spreads neighbours by a few sigma).
_SAME_SURFACE_FACTOR = 5.0
_SAME_SURFACE_FLOOR = 0.05  # m


def incidence_angles(ranges: NDArray[np.float64], angles: NDArray[np.float64]) -> NDArray[np.float64]:
    """Incidence angle (rad, 0 = square to the surface, < pi/2) of every beam, NaN where no return.

    Whole-array numpy: central differences of the endpoints where both
    neighbours are on the same surface, one-sided where only one is, 0 where
    neither is.
    """
    r = np.asarray(ranges, dtype=np.float64)
    a = np.asarray(angles, dtype=np.float64)
    n = r.shape[0]
    out = np.full(n, np.nan)
    if n == 0:
        return out
    c, s = np.cos(a), np.sin(a)
    x, y = r * c, r * s
    ok = ~np.isnan(r)
    step = np.abs(np.diff(a)) if n > 1 else np.zeros(0)
    # link k joins beam k and k + 1
    dx, dy = np.diff(x), np.diff(y)
    gap = np.hypot(dx, dy)
    near = np.fmin(r[:-1], r[1:])
    limit = np.maximum(_SAME_SURFACE_FACTOR * near * step, _SAME_SURFACE_FLOOR)
    link = ok[:-1] & ok[1:] & (gap <= limit)
    link = np.where(np.isnan(gap), False, link)
    has_prev = np.zeros(n, bool)
    has_next = np.zeros(n, bool)
    has_prev[1:] = link
    has_next[:-1] = link
    # tangent: next - prev endpoint where both links hold, else the one link that does
    ip = np.clip(np.arange(n) - 1, 0, n - 1)
    inx = np.clip(np.arange(n) + 1, 0, n - 1)
    tx0 = np.where(has_prev, x[ip], x)
    ty0 = np.where(has_prev, y[ip], y)
    tx1 = np.where(has_next, x[inx], x)
    ty1 = np.where(has_next, y[inx], y)
    tx, ty = tx1 - tx0, ty1 - ty0
    norm = np.hypot(tx, ty)
    usable = ok & (has_prev | has_next) & (norm > 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        # |beam x tangent| / |tangent| = cos(incidence)
        cos_inc = np.abs(c * ty - s * tx) / norm
    inc = np.arccos(np.clip(cos_inc, 0.0, 1.0))
    out[ok] = 0.0
    out[usable] = inc[usable]
    return out


def beam_sigmas(
    scan: LaserScan,
    model: RangeNoiseModel | None,
    default: float,
    *,
    materials: tuple[int, ...] = TABULATED_MATERIALS,
) -> NDArray[np.float64]:
    """Range sigma (m) of every beam of ``scan``; NaN where the beam has no return.

    ``model`` None gives ``default`` for every beam with a return (the method's
    own constant, e.g. GMapping's ``sigma``). Otherwise the model is evaluated
    at each beam's measured range and estimated incidence, averaged over
    ``materials`` (indices into :data:`~slam2d.sensors.range_noise.MATERIALS`).
    """
    r = scan.ranges
    ok = ~np.isnan(r)
    out = np.full(r.shape[0], np.nan)
    if model is None:
        out[ok] = float(default)
        return out
    inc = incidence_angles(r, scan.angles)[ok]
    d = r[ok]
    total = np.zeros(d.shape[0])
    for m in materials:
        total += np.asarray(model.sigma(d, inc, np.full(d.shape[0], m, dtype=np.int64)), dtype=np.float64)
    out[ok] = total / len(materials)
    return out
