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

__all__ = ["surface_tangents", "incidence_angles", "beam_sigmas", "TABULATED_MATERIALS"]

#: Indices of the materials the study measured (Table I); the default material mix.
TABULATED_MATERIALS: tuple[int, ...] = tuple(material_index(m) for m in TABLE_I_MM)

# Two endpoints belong to the same surface when they are closer than this many
# times the spacing a surface square to both beams would give, and never closer
# than the absolute floor (noise alone spreads neighbours by a few sigma).
_SAME_SURFACE_FACTOR = 5.0
_SAME_SURFACE_FLOOR = 0.05  # m


def surface_tangents(
    ranges: NDArray[np.float64], angles: NDArray[np.float64], baseline: float = 0.0
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """Direction of the surface at every beam's endpoint, laser frame: ``(tx, ty, usable)``.

    The tangent is the difference of the endpoints ``k`` beams either side on
    the same surface (a run of beams without a depth jump), cut at the
    surface's ends; ``k`` is 1, or with ``baseline`` (m) > 0 the number of beams
    spanning about ``baseline`` at the beam's range, so range noise tilts the
    tangent less. ``usable`` is False where the beam has no return or no
    neighbour on its surface. Tangents are not normalised. Whole-array numpy.
    """
    r = np.asarray(ranges, dtype=np.float64)
    a = np.asarray(angles, dtype=np.float64)
    n = r.shape[0]
    if n == 0:
        return np.zeros(0), np.zeros(0), np.zeros(0, dtype=bool)
    x, y = r * np.cos(a), r * np.sin(a)
    ok = ~np.isnan(r)
    step = np.abs(np.diff(a)) if n > 1 else np.zeros(0)
    # link k joins beam k and k + 1
    gap = np.hypot(np.diff(x), np.diff(y))
    near = np.fmin(r[:-1], r[1:])
    limit = np.maximum(_SAME_SURFACE_FACTOR * near * step, _SAME_SURFACE_FLOOR)
    link = ok[:-1] & ok[1:] & (gap <= limit)
    link = np.where(np.isnan(gap), False, link)
    # surfaces: runs of linked beams; first and last beam of each beam's run
    index = np.arange(n)
    breaks = np.ones(n, dtype=bool)
    breaks[1:] = ~link
    first = np.maximum.accumulate(np.where(breaks, index, 0))
    ends = np.ones(n, dtype=bool)
    ends[:-1] = ~link
    last = np.minimum.accumulate(np.where(ends, index, n - 1)[::-1])[::-1]
    if baseline > 0.0 and n > 1:
        spacing = np.fmax(np.nan_to_num(r, nan=1.0) * float(np.median(step)), 1e-9)
        k = np.clip(np.ceil(baseline / spacing), 1, n).astype(np.int64)
    else:
        k = np.ones(n, dtype=np.int64)
    lo = np.maximum(index - k, first)
    hi = np.minimum(index + k, last)
    tx, ty = x[hi] - x[lo], y[hi] - y[lo]
    usable = ok & (hi > lo) & (np.hypot(tx, ty) > 0)
    return tx, ty, usable


def incidence_angles(ranges: NDArray[np.float64], angles: NDArray[np.float64]) -> NDArray[np.float64]:
    """Incidence angle (rad, 0 = square to the surface, < pi/2) of every beam, NaN where no return.

    Whole-array numpy: from :func:`surface_tangents`; 0 where a beam has no
    neighbour on its surface.
    """
    r = np.asarray(ranges, dtype=np.float64)
    a = np.asarray(angles, dtype=np.float64)
    out = np.full(r.shape[0], np.nan)
    if r.shape[0] == 0:
        return out
    tx, ty, usable = surface_tangents(r, a)
    c, s = np.cos(a), np.sin(a)
    norm = np.hypot(tx, ty)
    with np.errstate(invalid="ignore", divide="ignore"):
        # |beam x tangent| / |tangent| = cos(incidence)
        cos_inc = np.abs(c * ty - s * tx) / norm
    inc = np.arccos(np.clip(cos_inc, 0.0, 1.0))
    out[~np.isnan(r)] = 0.0
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
