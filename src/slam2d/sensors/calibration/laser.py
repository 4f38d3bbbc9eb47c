"""Laser range calibration: repeated measurements -> sigma table, fits of sigma(distance), a model file.

Two kinds of data (:func:`load_laser_data`):

* a tidy CSV of repeated readings, one row per reading, with the columns
  ``material, angle_deg, distance_m, repetition, range_m`` that
  ``slam2d repeatability`` writes (``angle_deg`` is the angle between the beam
  and the target surface, 90 = square to it, as in the source study; an empty
  ``range_m`` is a lost reading). Each (material, angle, distance) is a set-up;
* recordings (CARMEN log or ROS bag) of a laser standing still in front of a
  static scene. Every beam's readings over the scans give its own mean and
  spread; beams are grouped by their mean range (``range_bin`` wide bins) and
  by the incidence angle estimated from the neighbouring endpoints
  (:func:`~slam2d.sensors.beam_model.incidence_angles`, ``incidence_bin``
  wide bins centred on 0, 15, 30 ... degrees); each group is a set-up whose
  sigma pools the beams' variances. Beams at a depth jump (mixed returns
  between two surfaces) and beams that return in fewer than half the scans
  are left out.

:func:`calibrate_laser` then reduces the set-ups as the source study did, for
any sensor: sigma per set-up with its 95 % interval, the table of sigma per
surface and angle (Table I), polynomial fits of sigma against distance per
angle averaged over the surfaces (Figs. 6-7), one per surface and angle, and
one over everything (eq. 1), each with its degree chosen by cross-validation
(:mod:`~slam2d.sensors.calibration.fits`), and the sigma at a reference
distance (the study's 2.5 m). :meth:`LaserCalibration.model_document` is the
model file.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slam2d.errors import InputError
from slam2d.sensors.calibration.fits import PolyFit, choose_degree, fit_polynomial
from slam2d.sensors.calibration.model import model_document

__all__ = [
    "SetupStats",
    "LaserData",
    "CurveFit",
    "LaserCalibration",
    "VerifyRow",
    "Verification",
    "load_laser_data",
    "calibrate_laser",
    "verify_model",
]

CSV_SUFFIXES = (".csv",)
#: Fewest readings (per beam in a recording, per set-up in a CSV) that give a sigma.
MIN_READINGS = 10
_DEPTH_JUMP = 0.1  # m: neighbouring beams' mean ranges further apart than this are on different surfaces


@dataclass
class SetupStats:
    """One set-up: a surface at a distance and angle, measured many times."""

    material: str
    angle_deg: float  # between the beam and the surface; 90 = square to it (incidence 0)
    distance: float  # m, nominal (CSV) or the mean range of the group (recording)
    count: int  # readings attempted
    returns: int  # readings with a return
    mean: float  # m
    sigma: float  # m
    dof: int  # degrees of freedom of sigma
    residuals: NDArray[np.float64] = field(repr=False)  # readings minus their mean (per beam in a recording)
    beams: int = 1

    @property
    def incidence_deg(self) -> float:
        return 90.0 - self.angle_deg

    @property
    def se(self) -> float:
        """Standard error of sigma for Gaussian readings: sigma / sqrt(2 dof)."""
        return self.sigma / math.sqrt(2.0 * self.dof)

    def interval(self, level: float = 0.95) -> tuple[float, float]:
        """Confidence interval of sigma (chi-square, Gaussian readings)."""
        from scipy.stats import chi2

        a = 1.0 - level
        return (self.sigma * math.sqrt(self.dof / chi2.ppf(1 - a / 2, self.dof)),
                self.sigma * math.sqrt(self.dof / chi2.ppf(a / 2, self.dof)))

    def normality(self) -> float:
        """Correlation of the normal probability plot (1 = perfectly Gaussian)."""
        from scipy.stats import probplot

        if self.residuals.size < 3 or not np.ptp(self.residuals) > 0:
            return float("nan")
        (_, _), (_, _, r) = probplot(self.residuals)
        return float(r)


@dataclass
class LaserData:
    """Set-ups from one or more files."""

    setups: list[SetupStats]
    sources: list[str]
    kind: str  # "csv" or "recording"
    skipped: list[str] = field(default_factory=list)  # set-ups or beams left out, and why

    @property
    def materials(self) -> list[str]:
        return list(dict.fromkeys(s.material for s in self.setups))

    @property
    def angles(self) -> list[float]:
        return sorted({s.angle_deg for s in self.setups}, reverse=True)


def _stats(material: str, angle: float, distance: float, ranges: NDArray[np.float64]) -> SetupStats:
    ok = ranges[~np.isnan(ranges)]
    mean = float(ok.mean()) if ok.size else math.nan
    res = ok - mean
    dof = max(int(ok.size) - 1, 0)
    sigma = float(math.sqrt(np.sum(res**2) / dof)) if dof > 0 else math.nan
    return SetupStats(material, angle, distance, int(ranges.size), int(ok.size), mean, sigma, dof, res)


def _csv_setups(path: Path) -> tuple[list[SetupStats], list[str]]:
    from slam2d.sim.repeatability import read_repeatability_csv

    rows = read_repeatability_csv(path, any_material=True)
    if len(rows) == 0:
        raise InputError("has a header but no readings", path=path)
    for name, values in (("angle_deg", rows.angle_deg), ("distance_m", rows.distance)):
        bad = ~np.isfinite(values)
        if name == "angle_deg":
            bad |= (values <= 0) | (values > 90)
        else:
            bad |= values <= 0
        if bad.any():
            line = int(np.argmax(bad)) + 2  # rows start on line 2 (blank lines aside)
            raise InputError(
                f"{float(values[bad][0])!r} is not " + ("an angle in (0, 90] deg" if name == "angle_deg" else "a distance > 0 m"),
                path=path, where=f"reading {line - 1}", field=name,
            )
    key = np.stack([np.unique(rows.material, return_inverse=True)[1], rows.angle_deg, rows.distance], axis=1)
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    setups, skipped = [], []
    for g in np.argsort(first):  # in the order the set-ups first appear
        i = first[g]
        s = _stats(str(rows.material[i]), float(rows.angle_deg[i]), float(rows.distance[i]), rows.range[inverse == g])
        if s.returns < MIN_READINGS:
            skipped.append(f"{s.material} {s.angle_deg:g} deg {s.distance:g} m: {s.returns} readings "
                           f"(fewer than {MIN_READINGS})")
            continue
        setups.append(s)
    return setups, skipped


def _recording_setups(
    path: Path, range_bin: float, incidence_bin: float
) -> tuple[list[SetupStats], list[str]]:
    from slam2d.io import open_recording
    from slam2d.sensors.beam_model import incidence_angles

    recording = open_recording(path)
    rows, odometry = [], []
    angles = None
    for frame in recording.frames():
        scan = frame.scan
        if angles is None:
            angles = scan.angles
        elif scan.ranges.shape[0] != angles.shape[0]:
            raise InputError(
                f"scan {len(rows)} has {scan.ranges.shape[0]} beams, the first had {angles.shape[0]}: "
                "a static calibration needs one laser with a fixed beam count", path=path,
            )
        rows.append(scan.ranges)
        if frame.odometry is not None:
            odometry.append(frame.odometry)
    if len(rows) < MIN_READINGS:
        raise InputError(f"{len(rows)} scans; a static calibration needs at least {MIN_READINGS}", path=path)
    if odometry:
        odo = np.asarray(odometry)
        moved = float(np.hypot(*(odo[:, :2] - odo[0, :2]).T).max())
        turned = float(np.abs(np.angle(np.exp(1j * (odo[:, 2] - odo[0, 2])))).max())
        if moved > 0.02 or turned > 0.01:
            raise InputError(
                f"the robot moved ({moved:.3f} m, {math.degrees(turned):.2f} deg by its odometry): "
                "a static calibration needs a laser standing still", path=path,
            )
    r = np.vstack(rows)
    n = np.sum(~np.isnan(r), axis=0)
    mean = _nanmean(r, n)
    usable = n >= max(MIN_READINGS, r.shape[0] // 2)
    # a beam whose neighbours are on another surface mixes two depths: leave it out
    prev = np.concatenate([[np.nan], mean[:-1]])
    nxt = np.concatenate([mean[1:], [np.nan]])
    smooth = (np.abs(prev - mean) <= _DEPTH_JUMP) & (np.abs(nxt - mean) <= _DEPTH_JUMP)
    skipped = []
    if (usable & ~smooth).any():
        skipped.append(f"{int((usable & ~smooth).sum())} beams at a depth jump or next to a lost beam")
    if (~usable & (n > 0)).any():
        skipped.append(f"{int((~usable & (n > 0)).sum())} beams returning in fewer than half the scans")
    keep = usable & smooth
    if not keep.any():
        raise InputError("no beam returns steadily from a smooth surface in this recording", path=path)
    incidence = np.degrees(incidence_angles(mean, angles))
    setups = []
    idx = np.flatnonzero(keep)
    ib = np.round(incidence[idx] / incidence_bin).astype(np.int64)
    rb = np.floor(mean[idx] / range_bin).astype(np.int64)
    keys = np.stack([ib, rb], axis=1)
    groups, inverse = np.unique(keys, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    for g, (ibin, _) in enumerate(groups):
        beams = idx[inverse == g]
        block = r[:, beams]
        res = (block - mean[beams][None])[~np.isnan(block)]
        dof = int(np.sum(n[beams]) - beams.size)
        if dof < MIN_READINGS:
            continue
        sigma = float(math.sqrt(np.sum(res**2) / dof))
        angle = 90.0 - float(ibin) * incidence_bin
        setups.append(SetupStats(
            "scene", angle, float(np.mean(mean[beams])), int(block.size), int(res.size),
            float(np.mean(mean[beams])), sigma, dof, res, beams=int(beams.size),
        ))
    setups.sort(key=lambda s: (-s.angle_deg, s.distance))
    return setups, skipped


def _nanmean(r: NDArray[np.float64], n: NDArray[np.int64]) -> NDArray[np.float64]:
    total = np.nansum(r, axis=0)
    out = np.full(r.shape[1], np.nan)
    out[n > 0] = total[n > 0] / n[n > 0]
    return out


def load_laser_data(
    paths: Sequence[str | Path], *, range_bin: float = 0.25, incidence_bin: float = 15.0
) -> LaserData:
    """Set-ups from CSV files or static recordings (not both kinds at once); see the module doc."""
    if not paths:
        raise InputError("no data files given", field="DATA")
    if not (range_bin > 0):
        raise InputError(f"{range_bin} m must be positive", field="--range-bin")
    if not (0 < incidence_bin <= 90):
        raise InputError(f"{incidence_bin} deg must be in (0, 90]", field="--incidence-bin")
    setups: list[SetupStats] = []
    skipped: list[str] = []
    kinds = set()
    for p in map(Path, paths):
        if not p.exists():
            raise InputError("no such file or folder", path=p)
        if p.suffix.lower() in CSV_SUFFIXES:
            kinds.add("csv")
            s, k = _csv_setups(p)
        else:
            kinds.add("recording")
            s, k = _recording_setups(p, range_bin, incidence_bin)
            if len(paths) > 1:  # each recording is its own scene
                for item in s:
                    item.material = p.name.split(".")[0]
        setups += s
        skipped += [f"{p.name}: {line}" for line in k]
    if len(kinds) > 1:
        raise InputError("give either CSV files or recordings, not both", field="DATA")
    if not setups:
        raise InputError("no set-up has enough readings to estimate a sigma", path=paths[0])
    return LaserData(setups, [str(p) for p in paths], kinds.pop(), skipped)


# --------------------------------------------------------------------------- fits


@dataclass
class CurveFit:
    """sigma against distance for one surface and angle, or averaged over surfaces (and angles)."""

    label: str
    material: str | None  # None: averaged over the surfaces
    angle_deg: float | None  # None: averaged over the angles
    distance: NDArray[np.float64]  # the points fitted
    sigma: NDArray[np.float64]
    se: NDArray[np.float64]
    fit: PolyFit
    cv: dict[int, float]
    scatter: float  # relative spread of single surfaces about the curve beyond their sampling error
    members: list[SetupStats] = field(default_factory=list, repr=False)  # the set-ups averaged
    note: str = ""

    def document(self, distance_range: tuple[float, float] | None = None) -> dict[str, Any]:
        """This curve as a model file's fit entry (its own range when it differs from ``distance_range``)."""
        out: dict[str, Any] = {}
        if self.angle_deg is not None:
            out["incidence_deg"] = float(90.0 - self.angle_deg)
        if distance_range is not None and tuple(self.fit.distance_range) != tuple(distance_range):
            out["distance_range_m"] = [float(v) for v in self.fit.distance_range]
        out["degree"] = self.fit.degree
        out["coefficients"] = [float(c) for c in self.fit.coefficients]
        out["covariance"] = [[float(v) for v in row] for row in self.fit.covariance]
        out["scatter"] = float(self.scatter)
        return out


def _average(setups: list[SetupStats]) -> tuple[NDArray, NDArray, NDArray]:
    """Per distance: mean sigma over the set-ups and its standard error."""
    d = np.array([s.distance for s in setups])
    levels = np.unique(d)
    sig = np.array([np.mean([s.sigma for s, di in zip(setups, d, strict=True) if di == x]) for x in levels])
    se = np.array([
        math.sqrt(sum(s.se**2 for s, di in zip(setups, d, strict=True) if di == x)) / int(np.sum(d == x))
        for x in levels
    ])
    return levels, sig, se


def _fit_curve(
    label: str, material: str | None, angle: float | None, members: list[SetupStats],
    degree: int | None, max_degree: int,
) -> CurveFit | None:
    d, sig, se = _average(members)
    if len(d) < 1:
        return None
    note = ""
    if degree is None:
        chosen, scores = choose_degree(d, sig, se, max_degree)
    else:
        chosen, scores = min(degree, len(d) - 1), {}
        if chosen < degree:
            note = f"degree {degree} asked, {chosen} used: only {len(d)} distances"
    fit = fit_polynomial(d, sig, se, chosen)
    grid = np.linspace(d.min(), d.max(), 201)
    while chosen > 0 and fit(grid).min() <= 0:  # a model file must give a positive sigma everywhere
        chosen -= 1
        fit = fit_polynomial(d, sig, se, chosen)
        note = f"degree lowered to {chosen}: the higher fit went below zero"
    pd = np.array([s.distance for s in members])
    ps = np.array([s.sigma for s in members])
    pse = np.array([s.se for s in members])
    pred = fit(pd)
    rel = (ps - pred) / pred
    scatter = float(math.sqrt(max(0.0, float(np.mean(rel**2) - np.mean((pse / pred) ** 2)))))
    return CurveFit(label, material, angle, d, sig, se, fit, scores, scatter, members, note)


@dataclass
class LaserCalibration:
    """Everything ``slam2d calibrate laser`` reports and the model it writes."""

    data: LaserData
    per_angle: dict[float, CurveFit]  # averaged over surfaces, one per angle (Figs. 6-7)
    per_material: dict[tuple[str, float], CurveFit]
    overall: CurveFit  # every surface and angle (eq. 1)
    reference_distance: float
    degree: int | None
    max_degree: int

    def table(self) -> list[dict[str, Any]]:
        """Table I: per surface, per angle, the mean sigma over the distances measured (m)."""
        out = []
        for m in self.data.materials:
            row: dict[str, Any] = {"material": m}
            for a in self.data.angles:
                s = [x.sigma for x in self.data.setups if x.material == m and x.angle_deg == a]
                row[a] = float(np.mean(s)) if s else math.nan
            out.append(row)
        return out

    def sigma_at_reference(self) -> dict[str, float]:
        """sigma at the reference distance: overall, and per angle (m)."""
        x = np.array([self.reference_distance])
        out = {"all": float(self.overall.fit(x)[0])}
        for a, c in self.per_angle.items():
            out[f"{a:g} deg"] = float(c.fit(x)[0])
        return out

    def model_document(self, extra: dict[str, Any] | None = None) -> dict[str, Any]:
        """The model file's content: sigma(range) for one angle, sigma(range, incidence) for several."""
        d = np.array([s.distance for s in self.data.setups])
        rng = (float(d.min()), float(d.max()))
        if len(self.per_angle) == 1:
            kind = "range"
            fits = [next(iter(self.per_angle.values())).document(rng)]
            fits[0].pop("incidence_deg", None)
        else:
            kind = "range-incidence"
            fits = [c.document(rng) for c in sorted(self.per_angle.values(), key=lambda c: -c.angle_deg)]
        materials: dict[str, list[dict[str, Any]]] = {}
        if len(self.data.materials) > 1:
            for m in self.data.materials:
                curves = sorted((c for (mm, _), c in self.per_material.items() if mm == m), key=lambda c: -c.angle_deg)
                if not curves:
                    continue
                if kind == "range":
                    doc = curves[0].document(rng)
                    doc.pop("incidence_deg", None)
                    materials[m] = [doc]
                else:  # a surface measured at one angle only is held at it for every incidence
                    materials[m] = [c.document(rng) for c in curves]
        ref = self.sigma_at_reference()
        info = {
            "reference": {"distance_m": self.reference_distance, "sigma_m": ref["all"]},
            "calibration": {
                "data": self.data.sources,
                "kind": self.data.kind,
                "setups": len(self.data.setups),
                "materials": self.data.materials,
                "angles_deg": self.data.angles,
                "degree": "cross-validation" if self.degree is None else self.degree,
                "max_degree": self.max_degree,
                "overall_fit": self.overall.document(),
            },
        }
        info.update(extra or {})
        return model_document(kind, distance_range=rng, fits=fits, materials=materials, extra=info)


#: Highest degree cross-validation may choose by default. Leave-one-distance-out can only compare
#: degrees up to (distances - 2), so on the study's five distances this still means at most its
#: cubic; over 0.5-4 m every 0.25 m it lets the data ask for a quartic or quintic when a cubic
#: cannot follow the curve (the study model's tangent below 1 m: the best cubic is 4.3 % off there).
DEFAULT_MAX_DEGREE = 5


def calibrate_laser(
    data: LaserData, *, reference_distance: float = 2.5, degree: int | None = None,
    max_degree: int = DEFAULT_MAX_DEGREE,
) -> LaserCalibration:
    """Fits of sigma against distance from the set-ups (``degree`` None: chosen by cross-validation)."""
    if not (math.isfinite(reference_distance) and reference_distance > 0):
        raise InputError(f"{reference_distance} m must be positive", field="--reference-distance")
    if degree is not None and degree < 0:
        raise InputError(f"{degree} must be >= 0", field="--degree")
    if max_degree < 0:
        raise InputError(f"{max_degree} must be >= 0", field="--max-degree")
    distances = sorted({s.distance for s in data.setups})
    if len(distances) < 2:
        raise InputError(
            f"every set-up is at {distances[0]:g} m: a fit of sigma against distance needs set-ups at two "
            "distances or more", path=", ".join(data.sources), field="distance_m" if data.kind == "csv" else "range",
        )
    per_angle, per_material = {}, {}
    for a in data.angles:
        members = [s for s in data.setups if s.angle_deg == a]
        per_angle[a] = _fit_curve(f"all surfaces, {a:g} deg", None, a, members, degree, max_degree)
        for m in data.materials:
            own = [s for s in members if s.material == m]
            if own:
                per_material[(m, a)] = _fit_curve(f"{m}, {a:g} deg", m, a, own, degree, max_degree)
    overall = _fit_curve("all surfaces and angles", None, None, data.setups, degree, max_degree)
    return LaserCalibration(data, per_angle, per_material, overall, reference_distance, degree, max_degree)


# --------------------------------------------------------------------------- verification


@dataclass
class VerifyRow:
    setup: SetupStats
    predicted: float  # m
    half_width: float  # m, the band is predicted +- half_width
    inside: bool


@dataclass
class Verification:
    rows: list[VerifyRow]
    model_source: str
    z: float

    @property
    def share_inside(self) -> float:
        return float(np.mean([r.inside for r in self.rows])) if self.rows else math.nan


def _material_indices(name: str) -> list[int]:
    """The model's material index for a surface name; the study's four tabulated ones if it has none."""
    from slam2d.sensors.beam_model import TABULATED_MATERIALS
    from slam2d.sensors.range_noise import MATERIALS

    return [MATERIALS.index(name)] if name in MATERIALS else list(TABULATED_MATERIALS)


def verify_model(model: Any, data: LaserData, *, z: float = 1.959963984540054, source: str = "") -> Verification:
    """Each set-up's measured sigma against the model's prediction and its band.

    The band is ``predicted +- z * sqrt(model_band**2 + sampling**2)``: the
    model's own uncertainty (its fit's standard error and the spread of single
    surfaces about it, for a calibrated model; none for a constant or the
    study model) and the sampling error of a sigma estimated from the set-up's
    readings if the model were exact (``predicted / sqrt(2 dof)``). A surface
    the model has no index for gets the mean over the surfaces the study
    tabulated, as a SLAM method does.
    """
    if not (z > 0):
        raise InputError(f"{z} must be positive", field="--z")
    rows = []
    for s in data.setups:
        mats = np.array(_material_indices(s.material), dtype=np.int64)
        d = np.full(mats.shape, s.distance)
        a = np.full(mats.shape, math.radians(s.incidence_deg))
        pred = float(np.mean(model.sigma(d, a, mats)))
        band = float(np.mean(model.band(d, a, mats))) if hasattr(model, "band") else 0.0
        half = z * math.sqrt(band**2 + pred**2 / (2.0 * s.dof))
        rows.append(VerifyRow(s, pred, half, abs(s.sigma - pred) <= half))
    return Verification(rows, source, z)
