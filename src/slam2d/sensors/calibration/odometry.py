"""Odometry noise by maximum likelihood: GMapping's srr, srt, str, stt and the systematic scales.

The model is exactly the simulator's (:mod:`slam2d.sensors.motion_noise`).
Between two consecutive odometry samples the odometry increment ``u`` (in the
frame of the earlier odometry pose) and the reference increment ``v = (dx, dy,
dtheta)`` (in the frame of the earlier reference pose) satisfy::

    u = (k dx, k dy, dtheta / t) + noise,   k = wheel_radius_scale, t = track_width_scale
    noise ~ N(0, diag(var_x, var_y, var_theta)),  d = sqrt(dx**2 + dy**2)
    var_x     = D (srr**2 |dx| + (0.3 srr)**2 |dy|) + A str**2 |dtheta| + q_xy
    var_y     = D (srr**2 |dy| + (0.3 srr)**2 |dx|) + A str**2 |dtheta| + q_xy
    var_theta = A stt**2 |dtheta| + D srt**2 d + q_theta

with ``D`` and ``A`` the reference increments (GMapping's ``linearUpdate`` and
``angularUpdate``; the simulator's defaults 1 m and 0.5 rad). The variances are
linear in the motion, so over an interval made of many small odometry steps
they add up to the same formula with the interval's increment: the estimate
does not depend on the odometry rate. ``q_xy`` and ``q_theta`` absorb the
reference's own error per interval (zero for a simulator's exact truth, not
for a SLAM trajectory used as the reference); they are estimated too, unless
the reference is declared exact. Motion at one constant speed cannot tell a
constant ``q`` from ``srr`` or ``srt`` (both add the same variance to every
interval): data with stops, speed changes and turns in place calibrate best.

The maximum of the Gaussian log-likelihood over all intervals is found in
``(k, 1/t, log srr**2, log str**2, log stt**2, log srt**2, log q_xy, log
q_theta)``; the 95 % intervals come from the observed information (the inverse
Hessian of the negative log-likelihood) in those coordinates, so a noise
parameter's interval is ``value * exp(+-1.96 se)`` and never goes below zero. A
parameter the motion does not excite (``str`` and ``stt`` without turning)
is reported as not identifiable instead of with a meaningless number.

Slip (:class:`~slam2d.sensors.motion_noise.OdometryNoise` ``slip_*``) is not
modelled here: slipping steps show up as heavier tails in the residual plot.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slam2d.core import se2
from slam2d.errors import InputError
from slam2d.sensors.motion_noise import LATERAL_COUPLING

__all__ = ["OdometryPairs", "OdometryCalibration", "Estimate", "load_odometry_pairs", "pairs_from_poses",
           "calibrate_odometry", "NOISE_NAMES"]

NOISE_NAMES = ("srr", "srt", "str", "stt")
_Z95 = 1.959963984540054
_LOG_VAR_BOUNDS = (math.log(1e-14), math.log(1e2))
_MIN_INTERVALS = 20


@dataclass
class OdometryPairs:
    """Matched increments: odometry ``u`` and reference ``v`` (both ``(N, 3)``), and where they came from."""

    u: NDArray[np.float64]
    v: NDArray[np.float64]
    times: NDArray[np.float64]  # start time of each interval
    odometry: NDArray[np.float64] = field(repr=False)  # the odometry poses used (M, 3)
    reference: NDArray[np.float64] = field(repr=False)  # the reference poses at the same times
    skipped: list[str] = field(default_factory=list)


def pairs_from_poses(
    times: NDArray[np.float64], odometry: NDArray[np.float64], reference: NDArray[np.float64],
    valid: NDArray[np.bool_] | None = None,
) -> OdometryPairs:
    """Increments between consecutive samples where odometry and reference both have a pose."""
    t = np.asarray(times, dtype=np.float64)
    odo = se2.as_poses(odometry).reshape(-1, 3)
    ref = se2.as_poses(reference).reshape(-1, 3)
    ok = np.ones(len(t), bool) if valid is None else np.asarray(valid, bool)
    ok &= np.all(np.isfinite(odo), axis=1) & np.all(np.isfinite(ref), axis=1)
    both = ok[:-1] & ok[1:]
    u = se2.relative(odo[:-1][both], odo[1:][both])
    v = se2.relative(ref[:-1][both], ref[1:][both])
    skipped = []
    if (~both).any():
        skipped.append(f"{int((~both).sum())} intervals without a reference or odometry pose at both ends")
    return OdometryPairs(u, v, t[:-1][both], odo[ok], ref[ok], skipped)


def load_odometry_pairs(data: str | Path, reference: str | Path, *, max_gap: float = 0.5) -> OdometryPairs:
    """Odometry from a recording (or a TUM file of odometry poses) matched to a TUM reference trajectory.

    The reference is interpolated at the odometry's timestamps (up to
    ``max_gap`` seconds between reference poses).
    """
    from slam2d.io.tum import interpolate_poses, read_tum

    data = Path(data)
    if not data.exists():
        raise InputError("no such file or folder", path=data)
    if data.suffix.lower() in (".tum", ".txt"):
        times, odo = read_tum(data)
    else:
        from slam2d.io import open_recording

        stamped = [(f.timestamp, f.odometry) for f in open_recording(data).frames() if f.odometry is not None]
        if not stamped:
            raise InputError("has no odometry to calibrate", path=data)
        times = np.array([s[0] for s in stamped], dtype=np.float64)
        odo = np.array([s[1] for s in stamped], dtype=np.float64).reshape(-1, 3)
    if len(times) < 2:
        raise InputError(f"{len(times)} odometry pose(s); at least two are needed", path=data)
    rt, rp = read_tum(reference)
    if len(rt) < 2:
        raise InputError(f"{len(rt)} pose(s); a reference trajectory needs at least two", path=reference)
    ref, valid = interpolate_poses(rt, rp, times, max_gap)
    if valid.sum() < 2:
        raise InputError(
            f"the reference ({rt.min():.3f}-{rt.max():.3f} s) does not overlap the odometry "
            f"({times.min():.3f}-{times.max():.3f} s)", path=reference, field="timestamp",
        )
    return pairs_from_poses(times, odo, ref, valid)


@dataclass(frozen=True)
class Estimate:
    """A parameter's maximum-likelihood value with a 95 % interval (NaN bounds: not identifiable)."""

    value: float
    low: float
    high: float
    identifiable: bool = True

    def as_dict(self) -> dict[str, Any]:
        return {"value": float(self.value), "ci95": [float(self.low), float(self.high)],
                "identifiable": bool(self.identifiable)}


@dataclass
class OdometryCalibration:
    """The estimates and what they were estimated from."""

    noise: dict[str, Estimate]  # srr, srt, str, stt
    wheel_radius_scale: Estimate
    track_width_scale: Estimate
    reference_noise: dict[str, float]  # q_xy (m), q_theta (rad): standard deviations per interval
    reference_distance: float
    reference_rotation: float
    intervals: int
    distance: float  # m travelled by the reference
    rotation: float  # rad turned by the reference
    log_likelihood: float
    residuals: NDArray[np.float64] = field(repr=False)  # standardised (N, 3)
    pairs: OdometryPairs | None = field(default=None, repr=False)
    notes: list[str] = field(default_factory=list)

    def gmapping_params(self) -> dict[str, float]:
        """The four GMapping parameters (a not-identifiable one is left out: GMapping keeps its default)."""
        return {k: float(e.value) for k, e in self.noise.items() if e.identifiable}

    def as_dict(self) -> dict[str, Any]:
        return {
            "noise": {k: e.as_dict() for k, e in self.noise.items()},
            "wheel_radius_scale": self.wheel_radius_scale.as_dict(),
            "track_width_scale": self.track_width_scale.as_dict(),
            "reference_noise_per_interval": self.reference_noise,
            "reference_distance_m": self.reference_distance,
            "reference_rotation_rad": self.reference_rotation,
            "intervals": self.intervals,
            "distance_m": self.distance,
            "rotation_rad": self.rotation,
            "log_likelihood": self.log_likelihood,
            "notes": self.notes,
        }


def _design(v: NDArray[np.float64], D: float, A: float) -> tuple[NDArray, NDArray, NDArray]:
    """Per interval, the coefficients of (srr^2, str^2, stt^2, srt^2) in var_x, var_y, var_theta."""
    adx, ady, adt = np.abs(v[:, 0]), np.abs(v[:, 1]), np.abs(v[:, 2])
    dist = np.hypot(v[:, 0], v[:, 1])
    c2 = LATERAL_COUPLING**2
    zero = np.zeros_like(adx)
    gx = np.stack([D * (adx + c2 * ady), A * adt, zero, zero], axis=1)
    gy = np.stack([D * (ady + c2 * adx), A * adt, zero, zero], axis=1)
    gt = np.stack([zero, zero, A * adt, D * dist], axis=1)
    return gx, gy, gt


def _nll_factory(u: NDArray, v: NDArray, D: float, A: float):
    gx, gy, gt = _design(v, D, A)

    def parts(theta: NDArray[np.float64]) -> tuple[NDArray, NDArray]:
        k, g = theta[0], theta[1]
        var = np.exp(theta[2:6])
        qxy, qt = math.exp(theta[6]), math.exp(theta[7])
        ex = u[:, 0] - k * v[:, 0]
        ey = u[:, 1] - k * v[:, 1]
        et = se2.wrap_angle(u[:, 2] - g * v[:, 2])
        vx, vy, vt = gx @ var + qxy, gy @ var + qxy, gt @ var + qt
        return np.stack([ex, ey, et], axis=1), np.stack([vx, vy, vt], axis=1)

    def nll(theta: NDArray[np.float64]) -> float:
        e, var = parts(theta)
        return float(0.5 * np.sum(np.log(var) + e**2 / var))

    def grad(theta: NDArray[np.float64]) -> NDArray[np.float64]:
        e, var = parts(theta)
        w = 0.5 * (1.0 / var - e**2 / var**2)  # d nll / d var
        out = np.empty(8)
        out[0] = -np.sum(e[:, 0] * v[:, 0] / var[:, 0] + e[:, 1] * v[:, 1] / var[:, 1])
        out[1] = -np.sum(e[:, 2] * v[:, 2] / var[:, 2])
        vv = np.exp(theta[2:6])
        out[2:6] = (w[:, 0] @ gx + w[:, 1] @ gy + w[:, 2] @ gt) * vv
        out[6] = (w[:, 0].sum() + w[:, 1].sum()) * math.exp(theta[6])
        out[7] = w[:, 2].sum() * math.exp(theta[7])
        return out

    return nll, grad, parts


def _hessian(grad, theta: NDArray[np.float64]) -> NDArray[np.float64]:
    """Central differences of the analytic gradient (8 parameters: 16 gradient calls)."""
    n = theta.shape[0]
    h = np.empty((n, n))
    for i in range(n):
        step = 1e-5 * max(1.0, abs(theta[i]))
        a, b = theta.copy(), theta.copy()
        a[i] += step
        b[i] -= step
        h[:, i] = (grad(a) - grad(b)) / (2 * step)
    return 0.5 * (h + h.T)


def calibrate_odometry(
    pairs: OdometryPairs, *, reference_distance: float = 1.0, reference_rotation: float = 0.5,
    exact_reference: bool = False,
) -> OdometryCalibration:
    """Maximum-likelihood srr, srt, str, stt, wheel_radius_scale and track_width_scale (see the module doc).

    ``exact_reference`` holds the reference's own noise (``q_xy``, ``q_theta``)
    at zero instead of estimating it: right for a simulator's truth, and it
    sharpens the estimates when the motion is so uniform (one speed
    throughout) that a constant term cannot be told from ``srr`` or ``srt``.
    """
    from scipy.optimize import minimize

    if not reference_distance > 0:
        raise InputError(f"{reference_distance} m must be positive", field="--linear-update")
    if not reference_rotation > 0:
        raise InputError(f"{reference_rotation} rad must be positive", field="--angular-update")
    u, v = pairs.u, pairs.v
    n = len(u)
    if n < _MIN_INTERVALS:
        raise InputError(f"{n} usable odometry intervals; at least {_MIN_INTERVALS} are needed", field="DATA")
    D, A = float(reference_distance), float(reference_rotation)
    distance = float(np.hypot(v[:, 0], v[:, 1]).sum())
    rotation = float(np.abs(v[:, 2]).sum())
    if distance < 1e-3 and rotation < 1e-3:
        raise InputError("the reference does not move: nothing to calibrate odometry against", field="--reference")
    nll, grad, parts = _nll_factory(u, v, D, A)
    # start: unit scales, each noise at GMapping's default magnitude, small reference noise
    theta0 = np.array([1.0, 1.0, *np.log([0.01, 0.01, 0.04, 0.04]), math.log(1e-8), math.log(1e-8)])
    dx = np.abs(v[:, 0]) + np.abs(v[:, 1])
    if np.sum(dx * dx) > 0:
        theta0[0] = float(np.sum(u[:, 0] * v[:, 0] + u[:, 1] * v[:, 1]) / np.sum(v[:, 0] ** 2 + v[:, 1] ** 2))
    if np.sum(v[:, 2] ** 2) > 0:
        theta0[1] = float(np.sum(u[:, 2] * v[:, 2]) / np.sum(v[:, 2] ** 2))
    bounds = [(1e-3, 1e3), (1e-3, 1e3)] + [_LOG_VAR_BOUNDS] * 6
    if exact_reference:
        theta0[6:] = _LOG_VAR_BOUNDS[0]
        bounds[6:] = [(_LOG_VAR_BOUNDS[0], _LOG_VAR_BOUNDS[0])] * 2
    best = None
    shifted = theta0.copy()
    shifted[2:6] += 2.0
    if not exact_reference:
        shifted[6:] += 2.0
    for start in (theta0, shifted):  # two starts: the surface is not convex
        res = minimize(nll, start, jac=grad, method="L-BFGS-B", bounds=bounds,
                       options={"maxiter": 2000, "ftol": 1e-13, "gtol": 1e-9})
        if best is None or res.fun < best.fun:
            best = res
    theta = best.x
    # Parameters that ended on a bound are held there; the information of the others gives their intervals.
    # So are parameters the motion does not excite at all (no rotation: str, stt and the track scale).
    gx, gy, gt = _design(v, D, A)
    excited = np.array([
        np.sum(v[:, 0] ** 2 + v[:, 1] ** 2), np.sum(v[:, 2] ** 2),
        gx[:, 0].sum(), gx[:, 1].sum(), gt[:, 2].sum(), gt[:, 3].sum(), 1.0, 1.0,
    ]) > 0
    free = excited & np.array([not (lo + 1e-6 >= t or t >= hi - 1e-6) for t, (lo, hi) in zip(theta, bounds, strict=True)])
    se = np.full(8, np.nan)
    try:
        h = _hessian(grad, theta)[np.ix_(free, free)]
        cov = np.linalg.inv(h)
        se[free] = np.sqrt(np.where(np.diag(cov) > 0, np.diag(cov), np.nan))
    except np.linalg.LinAlgError:
        pass
    notes = []
    noise = {}
    for name, j, power in zip(("srr", "str", "stt", "srt"), range(2, 6), excited[2:6], strict=True):
        value = math.exp(0.5 * theta[j])
        s = 0.5 * se[j]
        at_bound = theta[j] <= _LOG_VAR_BOUNDS[0] + 1.0
        ok = bool(power > 0 and math.isfinite(s) and s < 2.0 and not at_bound)
        if not ok:
            notes.append(f"{name} is not identifiable from this motion"
                         + (" (no " + ("rotation" if name in ("str", "stt") else "translation") + ")" if not power else ""))
        noise[name] = Estimate(value, value * math.exp(-_Z95 * s), value * math.exp(_Z95 * s), ok) if ok \
            else Estimate(value, math.nan, math.nan, False)
    noise = {k: noise[k] for k in NOISE_NAMES}
    k, sk = float(theta[0]), float(se[0])
    g, sg = float(theta[1]), float(se[1])
    radius = Estimate(k, k - _Z95 * sk, k + _Z95 * sk, bool(math.isfinite(sk) and distance > 0))
    if rotation > 0 and math.isfinite(sg) and g - _Z95 * sg > 0:
        track = Estimate(1.0 / g, 1.0 / (g + _Z95 * sg), 1.0 / (g - _Z95 * sg))
    else:
        track = Estimate(1.0 / g, math.nan, math.nan, False)
        notes.append("track_width_scale is not identifiable from this motion")
    e, var = parts(theta)
    z = e / np.sqrt(var)
    return OdometryCalibration(
        noise, radius, track,
        {"xy_m": math.exp(0.5 * theta[6]), "theta_rad": math.exp(0.5 * theta[7])},
        D, A, n, distance, rotation, -float(best.fun) - 1.5 * n * math.log(2 * math.pi), z, pairs, notes,
    )
