"""What a recording says about itself, measured before a run: the inputs of the ``auto`` defaults.

A method's right settings depend on the data: how far the laser reaches, how
far the robot moves between scans, and how good its odometry is. None of the
original nodes looks (slam_gmapping ships one fixed set). This module measures
those from the frames, cheaply (a sample of scan pairs, compiled matching), so
every parameter declared with ``param(..., auto=...)`` can resolve from them.

The odometry's quality is measured against scan matching: for scan pairs about
an update apart (``_PAIR_TRAVEL`` m or ``_PAIR_TURN`` rad of odometry), the
motion registered from the two scans alone
(:func:`slam2d.matching.scan_to_scan.consecutive_motion`) is compared with the
odometry's increment. The heading error is modelled as GMapping's motion model
draws it, ``sigma = srt * distance + stt * |turn|``, and fitted robustly (pairs
whose error is far beyond the rest, such as a turn the odometry never reported,
are counted as gaps, not noise).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from slam2d.core import se2

__all__ = ["RecordingProfile", "measure_profile"]

_PAIR_TRAVEL = 0.5  # m of odometry travel between the two scans of a measured pair
_PAIR_TURN = 0.25  # rad of odometry turn, whichever comes first
_MAX_PAIRS = 120  # pairs measured at most (spread evenly over the recording)
_MIN_PAIRS = 12  # fewer and the odometry's quality is not measured
_GAP_TURN = math.radians(15.0)  # a pair whose registered turn differs from the odometry's by more: a gap
_GAP_SHIFT = 0.5  # m, or whose registered position differs by more


@dataclass
class RecordingProfile:
    """A recording's measured properties. ``None`` where the recording cannot tell."""

    scans: int
    beams: int
    field_of_view: float  # rad
    angular_resolution: float  # rad per beam
    range_max: float  # m, the stated maximum (inf when none)
    longest_return: float  # m, the 99th percentile of returns: how far the laser reaches in this place
    rate_hz: float | None  # median scans per second
    has_odometry: bool
    step_m: float | None  # median odometry travel between consecutive scans
    step_rad: float | None  # median |odometry turn| between consecutive scans
    pairs: int = 0  # scan pairs measured against the odometry
    odometry_heading_per_m: float | None = None  # srt-like: heading error per metre travelled [rad/m]
    odometry_heading_per_rad: float | None = None  # stt-like: heading error per radian turned [rad/rad]
    odometry_gaps: int = 0  # pairs where the odometry missed a turn or a shift the scans show
    notes: list[str] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in asdict(self).items()}

    def scans_per_travel(self, metres: float, radians: float) -> float | None:
        """Scans between two filter updates of ``metres`` or ``radians`` (None without odometry)."""
        if self.step_m is None or self.step_rad is None:
            return None
        per_scan = max(self.step_m / metres if metres > 0 else 0.0, self.step_rad / radians if radians > 0 else 0.0)
        return 1.0 / per_scan if per_scan > 0 else None


def _pairs(odom: np.ndarray) -> list[tuple[int, int]]:
    """Index pairs ``(i, j)``: j the first scan after i with ``_PAIR_TRAVEL`` or ``_PAIR_TURN`` of odometry."""
    out = []
    i = 0
    n = odom.shape[0]
    while i < n - 1:
        j = i + 1
        while j < n:
            d = se2.relative(odom[i], odom[j])
            if math.hypot(d[0], d[1]) >= _PAIR_TRAVEL or abs(d[2]) >= _PAIR_TURN:
                break
            j += 1
        if j >= n:
            break
        out.append((i, j))
        i = j
    return out


def _fit_heading_noise(dist: np.ndarray, turn: np.ndarray, err: np.ndarray) -> tuple[float, float]:
    """``(srt, stt)`` with ``|err| ~ sqrt(2/pi) (srt * dist + stt * |turn|)``, non-negative, least squares."""
    from scipy.optimize import nnls

    a = np.stack([dist, np.abs(turn)], axis=1) * math.sqrt(2.0 / math.pi)
    (srt, stt), _ = nnls(a, np.abs(err))
    return float(srt), float(stt)


def measure_profile(frames: Sequence[Any]) -> RecordingProfile | None:
    """The profile of a recording's frames; None when there is nothing to measure (no scan)."""
    from slam2d.matching.scan_to_scan import consecutive_motion

    if len(frames) == 0:
        return None
    scans = [f.scan for f in frames]
    beams = int(np.median([s.num_beams for s in scans]))
    fov = float(np.median([s.field_of_view for s in scans]))
    res = float(np.median([s.angle_increment for s in scans]))
    range_max = float(np.median([s.range_max for s in scans]))
    step = max(1, len(scans) // 200)
    returns = np.concatenate([s.ranges[s.valid] for s in scans[::step]])
    longest = float(np.percentile(returns, 99)) if returns.size else float("nan")
    times = np.array([s.timestamp for s in scans], dtype=np.float64)
    dt = np.diff(times)
    dt = dt[dt > 0]
    rate = float(1.0 / np.median(dt)) if dt.size else None
    notes: list[str] = []
    odom = [f.odometry for f in frames]
    with_odom = sum(o is not None and bool(np.all(np.isfinite(o))) for o in odom)
    has_odom = with_odom >= 1 and with_odom >= 0.9 * len(frames)
    profile = RecordingProfile(
        scans=len(frames), beams=beams, field_of_view=fov, angular_resolution=res, range_max=range_max,
        longest_return=longest, rate_hz=rate, has_odometry=has_odom, step_m=None, step_rad=None, notes=notes,
    )
    if not has_odom:
        notes.append("no odometry (or under 90 % of the scans have it): its quality is not measured")
        return profile
    keep = [i for i, o in enumerate(odom) if o is not None and bool(np.all(np.isfinite(o)))]
    poses = np.asarray([odom[i] for i in keep], dtype=np.float64)
    steps = se2.relative(poses[:-1], poses[1:]) if len(poses) > 1 else np.zeros((0, 3))
    if len(steps) == 0:
        notes.append("a single scan: no motion to measure")
        return profile
    profile.step_m = float(np.median(np.hypot(steps[:, 0], steps[:, 1])))
    profile.step_rad = float(np.median(np.abs(steps[:, 2])))
    pairs = _pairs(poses)
    if len(pairs) > _MAX_PAIRS:
        pick = np.linspace(0, len(pairs) - 1, _MAX_PAIRS).round().astype(int)
        pairs = [pairs[k] for k in pick]
    dist, turn, err = [], [], []
    gaps = 0
    for i, j in pairs:
        a, b = scans[keep[i]], scans[keep[j]]
        pa, pb = a.points_in_base(), b.points_in_base()
        if pa.shape[0] < 20 or pb.shape[0] < 20:
            continue
        guess = se2.relative(poses[i], poses[j])
        matched = consecutive_motion(pa, pb, guess, half_turn=0.6)
        e = se2.relative(guess, matched)
        if abs(float(e[2])) > _GAP_TURN or math.hypot(float(e[0]), float(e[1])) > _GAP_SHIFT:
            gaps += 1
            continue
        dist.append(math.hypot(float(guess[0]), float(guess[1])))
        turn.append(float(guess[2]))
        err.append(float(e[2]))
    profile.pairs = len(err)
    profile.odometry_gaps = gaps
    if len(err) < _MIN_PAIRS:
        notes.append(f"only {len(err)} scan pairs far enough apart to measure the odometry (need {_MIN_PAIRS}): "
                     "its quality is not measured")
        return profile
    d, t, e = np.asarray(dist), np.asarray(turn), np.asarray(err)
    # Trim pairs whose error is far beyond the rest (a wrong registration), then fit once more.
    srt, stt = _fit_heading_noise(d, t, e)
    expected = math.sqrt(2.0 / math.pi) * (srt * d + stt * np.abs(t)) + 0.005
    ok = np.abs(e) <= 4.0 * expected
    if ok.sum() >= _MIN_PAIRS:
        srt, stt = _fit_heading_noise(d[ok], t[ok], e[ok])
    profile.odometry_heading_per_m = srt
    profile.odometry_heading_per_rad = stt
    if gaps:
        notes.append(f"{gaps} of {len(pairs)} measured scan pairs show a turn or shift the odometry did not report")
    return profile
