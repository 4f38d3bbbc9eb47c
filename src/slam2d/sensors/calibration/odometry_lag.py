"""How far a recording's odometry leads (or lags) its scans in time, from the recording alone.

Why: a robot that stamps its laser late (or its odometry early) hands every
scan an odometry pose taken some time after the scan. A method that predicts
or de-skews with the odometry then turns too early; coreslam's
``odometry_delay`` reads the odometry that long before each scan's stamp, but
a user cannot guess the number (the mines logs' is ~0.15 s).

How: the heading increment from each scan to the next is measured twice, by
registering the two scans on each other (:func:`slam2d.matching.scan_to_scan.
consecutive_motion`, no map, no odometry) and from the odometry heading
read ``D`` seconds before each of the two stamps (the readings joined by lines
and smoothed over one reading period: see :func:`_smoothed_heading`). Over a grid of
``D`` the odometry increments are fitted to the scan increments with a free
scale (scan-to-scan under-turns by a few percent, and a wheel-base error
scales the odometry's turns: the lag is about timing, not size), and the ``D``
with the smallest rms residual wins, refined between grid points by a
parabola. Turns that start and stop are what fix ``D``: a recording that never
turns, or turns at one constant rate, has no timing in it, and is refused
rather than given a number. Scan pairs the registration got wrong (residual
beyond 5 robust sigmas and 2 degrees at a first estimate) are left out of the
second pass.

The 95 % interval is where ``n log(rms(D)^2 / rms_min^2)`` stays below 3.84
(the likelihood-ratio profile for Gaussian residuals, ``n`` the scan pairs
used), widened to take in the lags found with the odometry's smoothing halved
and doubled; neighbouring residuals are not independent, so read it as a lower
bound on the uncertainty. The estimate is *confident* when the interval
is narrower than 0.1 s, the lag moves by at most 0.02 s with the smoothing,
the minimum is not at the edge of the grid, and the
scale is near one (0.7-1.4: else the registration failed wholesale, e.g. on
scans seconds apart, or the odometry's noise per scan swamps the turns).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Iterable

import numpy as np
from numpy.typing import NDArray

from slam2d.core.frames import Frame
from slam2d.errors import InputError
from slam2d.matching.scan_to_scan import consecutive_motion

__all__ = ["OdometryLag", "scan_turns", "estimate_odometry_lag", "odometry_lag"]

_MIN_PAIRS = 20  # scan pairs with odometry at both read-back times
_MIN_TURN = 1.0  # rad: the scans must turn at least this much in all over the pairs used...
_MIN_TURN_RATE = math.radians(5.0)  # rad/s: ...counting pairs that turn faster than this
_MIN_POINTS = 20  # endpoints a scan needs to be registered
_CHI2_95 = 3.841458820694124  # one degree of freedom
_CONFIDENT_WIDTH = 0.1  # s
_OUTLIER_FLOOR = math.radians(2.0)  # a scan pair is only a registration failure beyond this residual
_SCALE_RANGE = (0.7, 1.4)
_MAX_SPREAD = 0.02  # s: how far the lag may move when the odometry's smoothing is halved or doubled
_MIN_IMPROVEMENT = 1.05  # rms at D = 0 / rms at the lag below which the odometry counts as on time  # scan turn / odometry turn that a working registration gives


@dataclass
class OdometryLag:
    """The estimate: ``lag`` > 0 when the odometry leads the scans (use ``odometry_delay=lag``)."""

    lag: float  # s
    interval: tuple[float, float]  # 95 % (s), from the rms profile
    rms_at_zero: float  # deg per scan pair: odometry read at the stamps
    rms_at_lag: float  # deg per scan pair: odometry read back by ``lag``
    scale: float  # scan turn / odometry turn at ``lag``
    pairs: int  # scan pairs used
    outliers: int  # scan pairs left out (registration failures)
    turn: float  # rad the scans turned (faster than 5 deg/s) over the pairs used
    confident: bool
    delays: NDArray[np.float64] = field(repr=False)
    rms: NDArray[np.float64] = field(repr=False)  # deg, per delay
    notes: list[str] = field(default_factory=list)

    @property
    def improvement(self) -> float:
        """How many times smaller the rms is at the lag than at ``D = 0``."""
        return self.rms_at_zero / self.rms_at_lag if self.rms_at_lag > 0 else math.inf

    def setting(self) -> str | None:
        """The ``--set`` for coreslam, or None when there is nothing to set: not confident, the odometry late, or
        on time (reading it back improves the rms by less than 5 %)."""
        if not self.confident or self.lag <= 0.0 or self.improvement < _MIN_IMPROVEMENT:
            return None
        return f"odometry_delay={self.lag:.2f}"

    def as_dict(self) -> dict[str, Any]:
        return {"lag_s": self.lag, "ci95_s": list(self.interval), "rms_at_zero_deg": self.rms_at_zero,
                "rms_at_lag_deg": self.rms_at_lag, "improvement": self.improvement, "scale": self.scale,
                "pairs": self.pairs, "outliers": self.outliers, "turn_rad": self.turn,
                "confident": self.confident, "setting": self.setting(), "notes": self.notes}


def scan_turns(frames: Iterable[Frame]) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """``(stamps (N,), odometry heading (N,) NaN where none, scan turn (N - 1,) NaN where not registered)``.

    The scan turn ``k`` is the heading of scan ``k + 1`` in scan ``k``'s frame from registering the two scans
    alone, each started from the last pair's motion.
    """
    stamps, heading, turns = [], [], []
    previous = None
    guess = np.zeros(3)
    for f in frames:
        stamps.append(float(f.timestamp))
        odom = f.odometry
        heading.append(float(odom[2]) if odom is not None and np.all(np.isfinite(odom)) else math.nan)
        points = f.scan.points_in_base()
        points = points if points.shape[0] >= _MIN_POINTS else None
        if len(stamps) > 1:
            if previous is None or points is None:
                turns.append(math.nan)
                guess = np.zeros(3)
            else:
                guess = consecutive_motion(previous, points, guess)
                turns.append(float(guess[2]))
        previous = points
    return np.array(stamps), np.array(heading), np.array(turns)


def _smoothed_heading(query: NDArray[np.float64], ts: NDArray[np.float64], th: NDArray[np.float64],
                      sigma: float) -> NDArray[np.float64]:
    """The odometry heading at ``query`` times: the readings joined by straight lines, smoothed by a Gaussian of
    ``sigma`` s (quadrature over +-3 sigma).

    Why not the straight lines alone: between two noisy readings they average the readings' noise, so an
    increment read half way between readings is quieter than one read at them, and the rms profile dips at every
    half reading period (a simulated lag of 0 came out as 0.05 s at 10 Hz). A Gaussian one reading period wide
    evens that out. Why not a Gaussian over the readings themselves (kernel regression): where the readings come
    unevenly (fr079: 0.1-0.5 s apart) it leans toward the denser side, which moves turns in time; the lines do
    not, and the symmetric smoothing of them moves no turn either.
    """
    u = np.linspace(-3.0, 3.0, 25)
    w = np.exp(-0.5 * u * u)
    w /= w.sum()
    out = np.zeros(query.shape)
    for uk, wk in zip(u * sigma, w, strict=True):  # 25 whole-array interpolations
        out += wk * np.interp(query - uk, ts, th)
    return out


def _rms_profile(s, t0, t1, ts, th, delays, sigma):
    """Per delay: rms of the scan turns ``s`` about the best scaled odometry turns, and that scale."""
    rms, scale, res = np.empty(len(delays)), np.empty(len(delays)), np.empty((len(delays), len(s)))
    for j, d in enumerate(delays):  # one whole-array pass per delay (a few hundred delays at most)
        o = _smoothed_heading(t1 - d, ts, th, sigma) - _smoothed_heading(t0 - d, ts, th, sigma)
        oo = float(o @ o)
        scale[j] = float(o @ s) / oo if oo > 0 else 0.0
        res[j] = s - scale[j] * o
        rms[j] = math.sqrt(float(np.mean(res[j] ** 2)))
    return rms, scale, res


def _best_delay(s, t0, t1, ts, th, delays, sigma):
    """``(rms per delay, best grid index, lag, rms at it, scale at it, 95 % interval)`` for one smoothing."""
    rms, _, _ = _rms_profile(s, t0, t1, ts, th, delays, sigma)
    n = len(s)
    best = int(np.argmin(rms))

    def excess(profile: NDArray[np.float64]) -> NDArray[np.float64]:
        # the likelihood-ratio statistic above its 95 % level (<= 0: inside the interval)
        return n * np.log(np.maximum(profile, 1e-300) ** 2 / max(float(profile.min()), 1e-300) ** 2) - _CHI2_95

    inside = excess(rms) <= 0
    lo, hi = best, best
    while lo > 0 and inside[lo - 1]:
        lo -= 1
    while hi < len(delays) - 1 and inside[hi + 1]:
        hi += 1
    # the grid's step is coarse next to the interval on a clear recording: the same profile a tenth as fine there
    fine = np.linspace(delays[max(lo - 1, 0)], delays[min(hi + 1, len(delays) - 1)],
                       10 * (min(hi + 1, len(delays) - 1) - max(lo - 1, 0)) + 1)
    rms_fine, k_fine, _ = _rms_profile(s, t0, t1, ts, th, fine, sigma)
    j = int(np.argmin(rms_fine))
    within = fine[excess(rms_fine) <= 0]
    return (rms, best, float(fine[j]), float(rms_fine[j]), float(k_fine[j]),
            (float(within.min()), float(within.max())))


# Lags tried on each side of zero at most (0.5 s in steps of 0.01 s is 50).
_MAX_GRID = 100_000


def estimate_odometry_lag(
    stamps: NDArray[np.float64], odometry_heading: NDArray[np.float64], scan_turn: NDArray[np.float64], *,
    max_lag: float = 0.5, step: float = 0.01,
) -> OdometryLag:
    """The lag from :func:`scan_turns`' output (see the module doc); raises InputError when it cannot be told."""
    if not (max_lag > 0 and 0 < step <= max_lag):
        raise InputError(f"max lag {max_lag} s and step {step} s: both must be positive, the step the smaller",
                         field="--max-lag")
    if max_lag / step > _MAX_GRID:
        raise InputError(f"{step} s over +-{max_lag} s is {2 * max_lag / step:.3g} lags to try, more than "
                         f"{2 * _MAX_GRID}", field="--step")
    stamps = np.asarray(stamps, dtype=np.float64)
    heading = np.asarray(odometry_heading, dtype=np.float64)
    scan_turn = np.asarray(scan_turn, dtype=np.float64)
    has = np.isfinite(heading)
    if has.sum() < _MIN_PAIRS:
        raise InputError(f"{int(has.sum())} scans with odometry: no odometry to time "
                         f"(at least {_MIN_PAIRS} are needed)", field="odometry")
    ts, th = stamps[has], np.unwrap(heading[has])
    if np.any(np.diff(ts) <= 0):
        order = np.argsort(ts, kind="stable")
        ts, th = ts[order], th[order]
        keep = np.concatenate([[True], np.diff(ts) > 0])
        ts, th = ts[keep], th[keep]
    t0, t1 = stamps[:-1], stamps[1:]
    dt = t1 - t0
    ok = np.isfinite(scan_turn) & (dt > 0)
    if ok.any():
        ok &= dt <= 3.0 * np.median(dt[ok])  # a gap: the scans are too far apart to register reliably
    # odometry on both sides of every read-back time (no extrapolation), the same pairs for every delay
    sigma = max(float(np.median(np.diff(ts))), 1e-6)  # the smoothing of the odometry heading (s)
    ok &= (t0 - max_lag - 6 * sigma >= ts[0]) & (t1 + max_lag + 6 * sigma <= ts[-1])  # 3 sigma of the doubled smoothing
    # and no odometry gap inside the pair's window
    gap = 3.0 * float(np.median(np.diff(ts))) if len(ts) > 1 else math.inf
    i0 = np.searchsorted(ts, t0 - max_lag, side="right") - 1
    i1 = np.searchsorted(ts, t1 + max_lag, side="left")
    big = np.concatenate([[0], np.cumsum(np.diff(ts) > max(gap, 2.0 * max_lag))])
    ok &= big[np.clip(i1, 0, len(ts) - 1)] == big[np.clip(i0, 0, len(ts) - 1)]
    if ok.sum() < _MIN_PAIRS:
        raise InputError(f"{int(ok.sum())} consecutive scan pairs with odometry around them and a registration; "
                         f"at least {_MIN_PAIRS} are needed", field="odometry")
    s, t0, t1 = scan_turn[ok], t0[ok], t1[ok]
    n_grid = int(round(max_lag / step))
    delays = step * np.arange(-n_grid, n_grid + 1)
    # turning as the scans see it (the odometry's noise would add up to turns on a straight drive), and only at
    # more than 5 deg/s (the registration's own noise stays below that)
    turning = np.abs(s) > _MIN_TURN_RATE * (t1 - t0)
    turn = float(np.abs(s[turning]).sum())
    if turn < _MIN_TURN:
        raise InputError(f"the scans turn {math.degrees(turn):.0f} deg in all (at more than "
                         f"{math.degrees(_MIN_TURN_RATE):.0f} deg/s) over {len(s)} scan pairs: no turning, so no "
                         f"timing to measure (at least {math.degrees(_MIN_TURN):.0f} deg of turns that start and stop "
                         "are needed)", field="odometry")
    o = np.interp(t1, ts, th) - np.interp(t0, ts, th)
    odometry_turn = float(np.abs(o[np.abs(o) > _MIN_TURN_RATE * (t1 - t0)]).sum())
    if odometry_turn < _MIN_TURN:
        raise InputError(f"the odometry turns {math.degrees(odometry_turn):.0f} deg in all (at more than "
                         f"{math.degrees(_MIN_TURN_RATE):.0f} deg/s) while the scans turn {math.degrees(turn):.0f} "
                         "deg: no turning in the odometry, so no timing to measure", field="odometry")
    rms, _, r = _rms_profile(s, t0, t1, ts, th, delays, sigma)
    first = int(np.argmin(rms))
    dev = np.abs(r[first] - np.median(r[first]))
    mad = 1.4826 * float(np.median(dev))
    # the floor: on a drive mostly straight the MAD is the straight stretches' and would cut every turn
    inlier = dev <= max(5.0 * mad, _OUTLIER_FLOOR)
    s, t0, t1 = s[inlier], t0[inlier], t1[inlier]
    n = len(s)
    rms, best, lag, rms_best, scale, interval = _best_delay(s, t0, t1, ts, th, delays, sigma)
    # the same with the odometry's smoothing halved and doubled: a lag that is in the data stays put; one that
    # comes from how the readings are joined moves (fr079: 0.09 / 0.118 / 0.118 s, the mines logs within 0.004 s)
    others = [_best_delay(s, t0, t1, ts, th, delays, f * sigma)[2] for f in (0.5, 2.0)]
    spread = max(others + [lag]) - min(others + [lag])
    interval = (min([interval[0], *others]), max([interval[1], *others]))
    zero = int(np.argmin(np.abs(delays)))
    notes = []
    at_edge = best in (0, len(delays) - 1)
    if at_edge:
        notes.append(f"the best delay is at the edge of the searched range (+-{max_lag:g} s): widen it")
    wide = interval[1] - interval[0] > _CONFIDENT_WIDTH
    if wide:
        notes.append(f"the 95 % interval is {interval[1] - interval[0]:.2f} s wide: the turns do not fix the timing")
    # scan-to-scan under-turns by a few percent; a scale far from 1 means the registration failed wholesale
    # (scans too far apart, turns beyond its reach) or odometry noise swamps the turns per scan (it pulls the
    # fitted scale down): either way the profile is mostly noise
    off_scale = not (_SCALE_RANGE[0] <= scale <= _SCALE_RANGE[1])
    if off_scale:
        notes.append(f"the scans turn {scale:.2f} x the odometry's: the scan-to-scan registration failed (median "
                     f"{float(np.median(t1 - t0)):.2f} s and {math.degrees(float(np.median(np.abs(s)))):.1f} deg "
                     "between scans) or the odometry is too noisy per scan; the estimate is not usable")
    unstable = spread > _MAX_SPREAD
    if unstable:
        notes.append(f"the lag moves by {spread:.3f} s when the odometry's smoothing is halved or doubled: it "
                     "depends on how the readings are joined: the data do not fix it")
    confident = not at_edge and not wide and not off_scale and not unstable
    if confident and interval[0] <= 0.0 <= interval[1]:
        notes.append("no lag measurable: D = 0 is inside the 95 % interval")
    elif confident and float(rms[zero]) < _MIN_IMPROVEMENT * rms_best:
        notes.append(f"the odometry is on time: reading it back by {lag:.3f} s improves the rms by less than "
                     f"{100 * (_MIN_IMPROVEMENT - 1):.0f} %")
    elif confident and lag < 0:
        notes.append("the odometry lags the scans; odometry_delay reads the past only and cannot take it")
    out_count = int((~inlier).sum())
    if out_count:
        notes.append(f"{out_count} scan pairs left out as registration failures (residual beyond 5 robust sigmas and 2 deg)")
    return OdometryLag(lag, interval, float(np.degrees(rms[zero])), float(np.degrees(rms_best)), scale, n,
                       out_count, turn, confident, delays, np.degrees(rms), notes)


def odometry_lag(frames: Iterable[Frame], *, max_lag: float = 0.5, step: float = 0.01) -> OdometryLag:
    """The odometry's lead over the scans of a recording's frames (registration of every scan pair, then
    :func:`estimate_odometry_lag`)."""
    stamps, heading, turns = scan_turns(frames)
    if len(stamps) < 2:
        raise InputError(f"{len(stamps)} scan(s): at least two are needed", field="scans")
    return estimate_odometry_lag(stamps, heading, turns, max_lag=max_lag, step=step)
