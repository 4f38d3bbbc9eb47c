"""Odometry that missed a turn or a shift, caught by the scans and corrected before a method sees it.

Real odometry streams drop messages: a turn in place that was never reported,
a push the wheels did not feel. Every method then starts its match from a
prediction tens of degrees or metres off, beyond any search window sized for
odometry noise, and follows the odometry into a doubled map (csail: six such
gaps; GMapping and Karto alike end metres off).

The guard checks each scan against the one before it. Where the scan does not
fit the previous one at the odometry's increment, it registers the two
(:func:`~slam2d.matching.scan_to_scan.consecutive_motion`) near the increment
(+-0.25 rad), and, where that fits poorly or lands far away, over every
heading; where both fit poorly it also searches positions ``search_window``
around. A registration that differs from the odometry by more than
``gap_turn`` or ``gap_shift`` and fits clearly better (``margin`` of the coarse
field's mean, 0..1) and well (``good_fit``) replaces the increment: the method
is fed corrected odometry from there on, and the recovery is counted.

Three exceptions keep it from correcting what the odometry had right: a shift
the scans do not pin down (the odometry's position with the registration's
heading fits about as well: a corridor) stays the odometry's; and a
correction the next scan shows was one scan out of place (a scan stamped late
in a turn: the uncorrected odometry fits the next scan clearly better) is
taken back there (csail has both); and a registration that fits clearly better
only one way round (the current scan on the previous one, not the previous on
the current) is a robot reversing with its laser looking forwards, not a gap.

Why scan by scan: a method that matches scans takes out the odometry's error as
it goes; a correction over a longer interval than one scan would take out again
what the method already did (on fr079 a check every half metre put hector at
2.0 m and gmapping at 1.1-3.3 m; scan by scan changes neither). So the guard
only puts back what one step missed; a turn spread thinly over many scans is
left to the method. Costs one field lookup per scan where the odometry fits,
a few hundred microseconds where it does not.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import NDArray

from slam2d.core import se2
from slam2d.matching.scan_to_scan import _COARSE, _field, _point_to_line, _score, consecutive_motion, registration_fit
from slam2d.params import param

__all__ = ["GapCheck", "OdometryGapGuard", "OdometryGapParams"]


@dataclass
class OdometryGapParams:
    """The guard's switch, shared by every method that reads odometry."""

    odometry_gap_check: bool = param(
        True, help="check each scan's odometry increment against the scans and replace one the scans show "
        "missed a turn or a shift (over 20 deg or 0.4 m, clearly better fit, searched over every heading and "
        "2.5 m) before the method sees it; counted as odometry_recoveries (not in the originals)")


@dataclass(frozen=True)
class GapCheck:
    """When and how the guard checks the odometry (see the module's text)."""

    gap_turn: float = math.radians(20.0)  # rad: a registration this far from the odometry's heading is a gap
    gap_shift: float = 0.4  # m: or this far from its position
    margin: float = 0.15  # how much better (coarse field mean, 0..1) the gap's registration must fit
    poor_fit: float = 0.5  # below this fit near the odometry and over every heading, positions are searched too
    good_fit: float = 0.6  # a correction's registration fits at least this
    search_window: float = 2.5  # m: half-width of that position search
    # take the scans' increment even without a gap (hector: its Gauss-Newton match has no search to find a 10 deg
    # heading error by itself): where the odometry fits poorly (under poor_fit) and the registration near it
    # clearly better, all of it; where the odometry fits fairly and the registration well, its heading only (along
    # a corridor the registration's position slides: aces)
    refine: bool = False


@njit(cache=True)
def _position_search(px, py, qx, qy, gx, gy, headings, half, step):
    """Best (x, y, theta) of the coarse field over positions ``(gx, gy) +- half`` at each of ``headings``."""
    field, ox, oy = _field(px, py, _COARSE[0], _COARSE[1])
    inv = 1.0 / _COARSE[0]
    n = int(round(half / step))
    best = -1.0
    bx, by, bt = gx, gy, headings[0]
    for h in range(headings.shape[0]):
        t = headings[h]
        for i in range(-n, n + 1):
            for j in range(-n, n + 1):
                s = _score(field, ox, oy, inv, qx, qy, gx + i * step, gy + j * step, t)
                if s > best:
                    best = s
                    bx, by, bt = gx + i * step, gy + j * step, t
    return _point_to_line(px, py, qx, qy, bx, by, bt)


class OdometryGapGuard:
    """Feed it each frame's scan points and raw odometry; it returns the odometry to use (see the module's text)."""

    def __init__(self, check: GapCheck | None = None) -> None:
        self.check = check or GapCheck()
        self.recoveries = 0  # increments replaced
        self.checks = 0
        self.refined = 0  # increments or headings taken from the scans (refine)
        self.reverted = 0  # corrections taken back at the next scan (the corrected scan alone was out of place)
        self.last_correction: NDArray[np.float64] | None = None  # the last recovery's change (robot frame)
        self._ref_points: NDArray[np.float64] | None = None
        self._ref_raw: NDArray[np.float64] | None = None  # raw odometry at the reference scan
        self._ref_fixed: NDArray[np.float64] | None = None  # corrected odometry there
        self._undo: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None  # (raw, fixed) before a recovery

    def correct(self, points: NDArray[np.float64], odometry: NDArray[np.float64]) -> tuple[NDArray[np.float64], bool]:
        """``(corrected odometry, recovered here)`` for a scan's base-frame points and its raw odometry pose."""
        raw = np.asarray(odometry, dtype=np.float64)
        if self._ref_raw is None:
            self._set_reference(points, raw, raw.copy())
            return raw.copy(), False
        increment = se2.relative(self._ref_raw, raw)
        if points.shape[0] < 20 or self._ref_points.shape[0] < 20:
            fixed = se2.compose(self._ref_fixed, increment)  # too few points to judge: the odometry as it is
            if points.shape[0] >= 20:
                self._set_reference(points, raw, fixed)
            return fixed, False
        self.checks += 1
        undo = None
        if self._undo is not None:
            # the scan before was corrected: perhaps it alone was out of place (a late scan), not the odometry
            before_raw, before_fixed = self._undo
            undo = se2.relative(self._ref_fixed, se2.compose(before_fixed, se2.relative(before_raw, raw)))
        chosen, recovered = self._check(points, increment, undo)
        fixed = se2.compose(self._ref_fixed, chosen)
        before = (self._ref_raw, self._ref_fixed)
        self._set_reference(points, raw, fixed)
        self._undo = before if recovered else None
        return fixed, recovered

    def _set_reference(self, points, raw, fixed) -> None:
        self._ref_points = np.ascontiguousarray(points, dtype=np.float64)
        self._ref_raw, self._ref_fixed = raw, fixed
        self._undo = None

    def _check(self, points: NDArray[np.float64], increment: NDArray[np.float64],
               undo: NDArray[np.float64] | None = None) -> tuple[NDArray[np.float64], bool]:
        c = self.check
        ref = self._ref_points
        if undo is None:
            fit_odometry = float(registration_fit(ref, points, increment)[0])
        else:  # both on one field of the previous scan
            fit_odometry, fit_undo = (float(f) for f in registration_fit(ref, points, np.stack([increment, undo])))
            if fit_undo >= fit_odometry + c.margin:
                self.reverted += 1
                increment, fit_odometry = undo, fit_undo
        if fit_odometry >= c.good_fit:
            return increment, False  # the scans fit where the odometry puts them: no gap, nothing to search
        local = consecutive_motion(ref, points, increment, half_turn=0.25)
        fit_local = float(registration_fit(ref, points, local)[0])
        off = se2.relative(increment, local)
        odometry_wrong = fit_odometry < c.poor_fit and fit_local >= max(c.poor_fit, fit_odometry + c.margin)
        if fit_local >= c.good_fit and abs(float(off[2])) <= c.gap_turn and math.hypot(off[0], off[1]) <= c.gap_shift:
            if c.refine and fit_local > fit_odometry:
                self.refined += 1
                return (local if odometry_wrong else np.array([increment[0], increment[1], local[2]])), False
            return increment, False  # the scans fit well near the odometry: no gap (and no wide search to pay)
        wide = consecutive_motion(ref, points, increment, half_turn=math.pi)
        fit_wide = float(registration_fit(ref, points, wide)[0])
        best, fit_best = (wide, fit_wide) if fit_wide > fit_local + c.margin else (local, fit_local)
        if max(fit_local, fit_wide) < c.poor_fit:
            q = np.ascontiguousarray(points[::2])
            headings = np.array([increment[2], wide[2], local[2]])
            found = _position_search(np.ascontiguousarray(ref[:, 0]), np.ascontiguousarray(ref[:, 1]),
                                     np.ascontiguousarray(q[:, 0]), np.ascontiguousarray(q[:, 1]),
                                     float(increment[0]), float(increment[1]), headings, c.search_window, 0.1)
            fit_found = float(registration_fit(ref, points, found)[0])
            if fit_found > fit_best + c.margin:
                best, fit_best = found, fit_found
        if math.hypot(*se2.relative(increment, best)[:2]) > c.gap_shift:
            # a shift the scans do not pin down (along a corridor) is the odometry's to say, not the registration's
            turned_only = np.array([increment[0], increment[1], best[2]])
            fit_turned = float(registration_fit(ref, points, turned_only)[0])
            if fit_turned + c.margin > fit_best:
                best, fit_best = turned_only, fit_turned
        off = se2.relative(increment, best)
        is_gap = abs(float(off[2])) > c.gap_turn or math.hypot(float(off[0]), float(off[1])) > c.gap_shift
        # a registration far from the odometry must fit clearly better than the odometry does, and fit well:
        # two scans of a symmetric corridor also fit turned half round, a little
        if is_gap and fit_best >= fit_odometry + c.margin and fit_best >= c.good_fit and not self._seen_reversing(
                ref, points, increment, best):
            self.recoveries += 1
            self.last_correction = off
            return best, True
        if c.refine and odometry_wrong:  # no gap, but the odometry is plainly off and the scans say by how much
            self.refined += 1
            return local, False
        return increment, False

    def _seen_reversing(self, ref, points, increment, best) -> bool:
        """Whether the registration does not also fit clearly better the other way round (the previous scan's
        points on the current scan): the fit above is one-sided, and a robot reversing with its laser looking
        forwards sees what the last scan saw and more beside it, which the last scan never saw; that one-sided
        misfit is no gap (intel played backwards: 60 false recoveries)."""
        back = registration_fit(points, ref, se2.inverse(np.stack([increment, best])))
        return bool(back[1] < back[0] + self.check.margin)
