"""CRSM's critical-ray selection: the few beams of a scan worth matching.

From the ranges ``d`` (0 where no return) with ``density[i] = |d[i] - d[i+1]|``:

1. Keep the first and last beams with a return below ``laser_max - 0.05``
   and both beams of every discontinuity ``density > jump`` (CRSM's
   ``scan_density_lower_boundary``, 0.3 m).
2. Between two consecutive kept beams (unless the segment starts next to a
   near-max-range beam) walk the cumulative density and keep a beam each
   time it exceeds ``parameter * step / exp(3 d / sqrt(max range))``, where
   ``step`` is the segment's mean density: far beams have a lower
   threshold, so more far beams are kept (they pin rotation down).
3. ``parameter`` persists from scan to scan and is adapted so the walk keeps
   about ``desired`` beams: outside +-25 % it is moved by the excess in beams,
   as the original does. The walk keeps roughly ``1 / parameter`` beams, so
   when ``desired`` is in the hundreds this overshoots: ``parameter`` falls to
   or below 0 (every beam picked, ~400), jumps by ~280 (30-60 beams for
   several scans) and saws between the two. Scaling it by ``picked / desired``
   instead removed the sawtooth but not the heading errors, and was removed
   (docs/methods/what-was-tried.md).
4. Gaps of more than 25 beams are bisected until none is left, then beams
   with no return or at the maximum range are dropped.

Also returns the scan's mean density (mean ``|d[i] - d[i+1]|``), which sets
the map update's gain.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["critical_rays"]

_MAX_GAP = 25  # beams: larger gaps between picked beams are bisected


@njit(cache=True)
def critical_rays(d, laser_max, parameter, jump, desired):
    """``(selected indices, new parameter, mean density, rays picked by the walk)``."""
    n = d.shape[0]
    density = np.zeros(n)
    total = 0.0
    max_ray = 0.0
    for i in range(n):
        if d[i] > max_ray:
            max_ray = d[i]
        if i < n - 1:
            density[i] = abs(d[i] - d[i + 1])
            total += density[i]
    mean_density = total / (n - 1) if n > 1 else 0.0
    near = laser_max - 0.05
    big = np.zeros(n, dtype=np.bool_)
    for i in range(n):
        if d[i] < near:
            big[i] = True
            break
    i = 0
    while i < n:
        a = 0
        b = 0
        if density[i] > jump:
            if d[i] < near:
                big[i] = True
                a = 1
            if i + 1 < n and d[i + 1] < near:
                big[i + 1] = True
                b = 1
        i += max(1, a + b)
    for i in range(n - 1, 0, -1):
        if d[i] < near:
            big[i] = True
            break
    selected = big.copy()
    picked = 0
    if max_ray > 0.0:
        root = math.sqrt(max_ray)
        prev = -1
        for end in range(n):
            if not big[end]:
                continue
            start = prev
            prev = end
            if start < 0 or d[start + 1] > laser_max - 0.5:
                continue
            step = 0.0
            for k in range(start, end - 1):
                step += density[k]
            step /= end - start
            local = 0.0
            for k in range(start, end):
                local += density[k]
                if local > parameter * step / math.exp(d[k] / root * 3.0):
                    selected[k] = True
                    picked += 1
                    local = 0.0
    if picked > desired * 1.25:
        parameter += picked - desired
    elif picked < desired * 0.75:
        parameter -= desired - picked
    # bisect gaps wider than _MAX_GAP beams until none is left
    changed = True
    while changed:
        changed = False
        last = -1
        for k in range(n):
            if selected[k]:
                if last >= 0 and k - last > _MAX_GAP:
                    selected[(k + last) // 2] = True
                    changed = True
                last = k
    count = 0
    for k in range(n):
        if selected[k] and (d[k] == 0.0 or d[k] >= laser_max):
            selected[k] = False
        if selected[k]:
            count += 1
    out = np.empty(count, dtype=np.int64)
    j = 0
    for k in range(n):
        if selected[k]:
            out[j] = k
            j += 1
    return out, parameter, mean_density, picked
