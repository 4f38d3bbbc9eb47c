"""Sensor model files: a calibrated sigma(distance, incidence, material) as YAML, and its loader.

A model file says how noisy a laser's ranges are, in one of three forms
(``kind``):

* ``constant``: one sigma for every beam (``sigma: 0.0041``, the study's choice);
* ``range``: sigma as a polynomial of the distance (one entry in ``fits``);
* ``range-incidence``: one polynomial per measured incidence angle (the angle
  between the beam and the surface normal; 0 = square to the surface),
  interpolated linearly in the incidence between them.

Example (what ``slam2d calibrate laser`` writes, shortened)::

    format: slam2d-sensor-model
    version: 1
    kind: range-incidence
    distance_range_m: [1.0, 4.0]
    beyond_measured_incidence: hold      # or: extend (linear, up to max_incidence_deg)
    fits:                                # averaged over the surfaces measured
      - incidence_deg: 0.0
        coefficients: [0.0048, -0.0010, 4e-05, 4e-05]   # sigma = c0 + c1 d + c2 d^2 + ... (m, d in m)
        distance_range_m: [1.0, 4.0]     # optional: this fit's own range, if narrower than the file's
        covariance: [[...], ...]         # of the coefficients (optional: the confidence band)
        scatter: 0.12                    # relative spread of single surfaces about this fit (optional)
      - incidence_deg: 45.0
        coefficients: [...]
    materials:                           # optional: one surface's own fits, same form
      cardboard:
        fits: [...]

Between the measured incidences sigma is interpolated linearly; beyond them it
is held at the nearest measured one (``hold``) or extended along the last
segment up to ``max_incidence_deg`` (``extend``, what the study model assumes).
Outside ``distance_range_m`` a polynomial is continued along its tangent at
the nearer end and never drops below its smallest value over the range: a
polynomial is not trusted outside its data.

A material the model has its own fits for (by name, one of
:data:`~slam2d.sensors.range_noise.MATERIALS`) uses them; every other
material, and a SLAM method that does not know what it hit, uses the
averaged ``fits``.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from slam2d.errors import InputError
from slam2d.sensors.range_noise import MATERIALS, ConstantSigma, RangeNoiseModel, StudyModel

__all__ = [
    "FORMAT",
    "KINDS",
    "DistanceCurve",
    "IncidenceCurves",
    "CalibratedModel",
    "load_sensor_model",
    "read_sensor_model",
    "sensor_model_from_spec",
    "describe_sensor_model",
    "model_document",
    "dump_model_yaml",
]

FORMAT = "slam2d-sensor-model"
VERSION = 1
KINDS = ("constant", "range", "range-incidence")
_DEFAULT_MAX_INCIDENCE_DEG = 80.0
_FLOOR = 1e-6  # m: no sigma below a micrometre, whatever a fit does


@dataclass(frozen=True)
class DistanceCurve:
    """One polynomial sigma(d) valid over ``distance_range``, continued outside it (see the module doc)."""

    coefficients: NDArray[np.float64]  # lowest power first
    distance_range: tuple[float, float]
    covariance: NDArray[np.float64] | None = None
    scatter: float = 0.0  # relative extra spread of single surfaces about the curve

    def __post_init__(self) -> None:
        lo, hi = self.distance_range
        grid = np.linspace(lo, hi, 201)
        values = self._poly(grid)
        slope = self._slope(np.array([lo, hi]))
        object.__setattr__(self, "_floor", max(float(values.min()), _FLOOR))
        object.__setattr__(self, "_slopes", slope)
        object.__setattr__(self, "_ends", self._poly(np.array([lo, hi])))

    def _poly(self, d: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.polynomial.polynomial.polyval(d, self.coefficients)

    def _slope(self, d: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.polynomial.polynomial.polyval(d, np.polynomial.polynomial.polyder(self.coefficients))

    def minimum(self) -> float:
        lo, hi = self.distance_range
        return float(self._poly(np.linspace(lo, hi, 201)).min())

    def __call__(self, distance: ArrayLike) -> NDArray[np.float64]:
        d = np.asarray(distance, dtype=np.float64)
        lo, hi = self.distance_range
        s = self._poly(np.clip(d, lo, hi))
        s = s + self._slopes[0] * np.minimum(d - lo, 0.0) + self._slopes[1] * np.maximum(d - hi, 0.0)  # type: ignore[attr-defined]
        return np.maximum(s, self._floor)  # type: ignore[attr-defined]

    def standard_error(self, distance: ArrayLike) -> NDArray[np.float64]:
        """Standard error of the curve itself (zero without a covariance); clamped to the fitted range."""
        d = np.clip(np.asarray(distance, dtype=np.float64), *self.distance_range)
        if self.covariance is None:
            return np.zeros_like(d)
        x = d[..., None] ** np.arange(self.coefficients.shape[0])
        return np.sqrt(np.maximum(np.einsum("...i,ij,...j->...", x, self.covariance, x), 0.0))


@dataclass(frozen=True)
class IncidenceCurves:
    """Curves at measured incidences (radians, increasing), interpolated linearly between them."""

    incidences: NDArray[np.float64]
    curves: tuple[DistanceCurve, ...]
    extend: bool = False
    max_incidence: float = math.radians(_DEFAULT_MAX_INCIDENCE_DEG)

    def _weights(self, incidence: NDArray[np.float64]) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """Index of the lower curve and the weight of the upper one, per element."""
        inc = self.incidences
        a = np.abs(incidence)
        if self.extend:
            a = np.minimum(a, max(self.max_incidence, float(inc[-1])))
        else:
            a = np.clip(a, inc[0], inc[-1])
        i = np.clip(np.searchsorted(inc, a, side="right") - 1, 0, len(inc) - 2)
        t = (a - inc[i]) / (inc[i + 1] - inc[i])
        if not self.extend:
            t = np.clip(t, 0.0, 1.0)
        else:
            t = np.maximum(t, 0.0)  # below the first measured incidence: hold
        return i, t

    def _combine(self, values: NDArray[np.float64], incidence: NDArray[np.float64]) -> NDArray[np.float64]:
        if len(self.curves) == 1:
            return values[0]
        i, t = self._weights(incidence)
        lower = np.take_along_axis(values, i[None], axis=0)[0]
        upper = np.take_along_axis(values, (i + 1)[None], axis=0)[0]
        return lower + (upper - lower) * t

    def sigma(self, distance: NDArray[np.float64], incidence: NDArray[np.float64]) -> NDArray[np.float64]:
        values = np.stack([c(distance) for c in self.curves])
        return np.maximum(self._combine(values, incidence), _FLOOR)

    def band(self, distance: NDArray[np.float64], incidence: NDArray[np.float64]) -> NDArray[np.float64]:
        """Standard deviation of a single surface's sigma about the curve: fit error and surface scatter."""
        se = np.stack([c.standard_error(distance) for c in self.curves])
        spread = np.stack([c.scatter * c(distance) for c in self.curves])
        return np.sqrt(np.maximum(self._combine(se**2 + spread**2, incidence), 0.0))


@dataclass(frozen=True)
class CalibratedModel:
    """A range noise model read from a model file: sigma(distance, incidence, material).

    Satisfies :class:`~slam2d.sensors.range_noise.RangeNoiseModel`; hand it to
    a method as ``sensor_model=`` (per beam through
    :func:`slam2d.sensors.beam_model.beam_sigmas`) or to the simulator.
    """

    kind: str
    average: IncidenceCurves | None  # None for a constant
    constant: float = math.nan
    materials: dict[int, IncidenceCurves] = field(default_factory=dict)
    source: str = ""
    document: dict[str, Any] = field(default_factory=dict, repr=False, compare=False)

    def _each(self, distance: ArrayLike, incidence: ArrayLike, material: ArrayLike, what: str) -> NDArray[np.float64]:
        d, a, m = np.broadcast_arrays(
            np.asarray(distance, dtype=np.float64), np.asarray(incidence, dtype=np.float64), np.asarray(material)
        )
        if self.average is None:
            return np.full(d.shape, self.constant if what == "sigma" else 0.0)
        out = getattr(self.average, what)(d, a)
        for index, curves in self.materials.items():  # a handful of surfaces at most
            mask = m == index
            if mask.any():
                out = np.where(mask, getattr(curves, what)(d, a), out)
        return out

    def sigma(self, distance: ArrayLike, incidence: ArrayLike, material: ArrayLike) -> NDArray[np.float64]:
        """Sigma (m) per beam for ``distance`` (m), ``incidence`` (rad) and ``material`` (index)."""
        return self._each(distance, incidence, material, "sigma")

    def band(self, distance: ArrayLike, incidence: ArrayLike, material: ArrayLike) -> NDArray[np.float64]:
        """One standard deviation of the model's own uncertainty about sigma (fit error + surface scatter), m."""
        return self._each(distance, incidence, material, "band")


# --------------------------------------------------------------------------- reading


def _number(value: Any, path: Path, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(float(value)):
        raise InputError(f"{value!r} is not a finite number", path=path, field=name)
    return float(value)


def _numbers(value: Any, path: Path, name: str, count: int | None = None) -> NDArray[np.float64]:
    if not isinstance(value, list) or not value:
        raise InputError(f"expected a non-empty list of numbers, got {value!r}", path=path, field=name)
    if count is not None and len(value) != count:
        raise InputError(f"expected {count} numbers, got {len(value)}", path=path, field=name)
    return np.array([_number(v, path, f"{name}[{i}]") for i, v in enumerate(value)], dtype=np.float64)


def _curve(entry: Any, path: Path, name: str, distance_range: tuple[float, float]) -> tuple[float | None, DistanceCurve]:
    if not isinstance(entry, dict):
        raise InputError(f"expected a mapping with 'coefficients', got {entry!r}", path=path, field=name)
    coef = _numbers(entry.get("coefficients"), path, f"{name}.coefficients")
    cov = None
    if entry.get("covariance") is not None:
        rows = entry["covariance"]
        if not isinstance(rows, list) or len(rows) != len(coef):
            raise InputError(f"expected a {len(coef)} x {len(coef)} matrix", path=path, field=f"{name}.covariance")
        cov = np.array([_numbers(r, path, f"{name}.covariance[{i}]", len(coef)) for i, r in enumerate(rows)])
    if entry.get("distance_range_m") is not None:  # a fit measured over fewer distances than the file's range
        lo, hi = _numbers(entry["distance_range_m"], path, f"{name}.distance_range_m", 2)
        if not 0 <= lo <= hi:
            raise InputError(f"[{lo}, {hi}] is not a range 0 <= near <= far", path=path,
                             field=f"{name}.distance_range_m")
        distance_range = (lo, hi)
    scatter = _number(entry.get("scatter", 0.0), path, f"{name}.scatter")
    if scatter < 0:
        raise InputError(f"{scatter} must be >= 0", path=path, field=f"{name}.scatter")
    inc = entry.get("incidence_deg")
    if inc is not None:
        inc = _number(inc, path, f"{name}.incidence_deg")
        if not 0.0 <= inc < 90.0:
            raise InputError(f"{inc} deg is not an incidence in [0, 90)", path=path, field=f"{name}.incidence_deg")
    curve = DistanceCurve(coef, distance_range, cov, scatter)
    if curve.minimum() <= 0.0:
        raise InputError(
            f"the polynomial is not positive over {distance_range[0]:g}-{distance_range[1]:g} m "
            f"(minimum {curve.minimum():.3g} m)", path=path, field=f"{name}.coefficients",
        )
    return inc, curve


def _curves(
    fits: Any, path: Path, name: str, kind: str, distance_range: tuple[float, float], extend: bool, max_inc: float
) -> IncidenceCurves:
    if not isinstance(fits, list) or not fits:
        raise InputError("expected a non-empty list of fits", path=path, field=name)
    parsed = [_curve(e, path, f"{name}[{i}]", distance_range) for i, e in enumerate(fits)]
    if kind == "range":
        if len(parsed) != 1:
            raise InputError(f"kind 'range' takes exactly one fit, got {len(parsed)}", path=path, field=name)
        return IncidenceCurves(np.zeros(1), (parsed[0][1],))
    for i, (inc, _) in enumerate(parsed):
        if inc is None:
            raise InputError("missing (kind 'range-incidence' needs one per fit)", path=path,
                             field=f"{name}[{i}].incidence_deg")
    incs = np.array([p[0] for p in parsed], dtype=np.float64)
    if len(np.unique(incs)) != len(incs):
        raise InputError(f"incidence angles repeat: {incs.tolist()}", path=path, field=name)
    order = np.argsort(incs)
    return IncidenceCurves(np.radians(incs[order]), tuple(parsed[i][1] for i in order), extend, max_inc)


def model_from_document(doc: Any, path: str | Path = "<model>") -> CalibratedModel:
    """Build a :class:`CalibratedModel` from a parsed model document; InputError naming the field otherwise."""
    path = Path(path)
    if not isinstance(doc, dict):
        raise InputError(f"expected a mapping (a sensor model file), got {type(doc).__name__}", path=path)
    if doc.get("format") != FORMAT:
        raise InputError(f"expected {FORMAT!r}, got {doc.get('format')!r}", path=path, field="format")
    version = doc.get("version")
    if version != VERSION:
        raise InputError(f"version {version!r} is not supported (this slam2d reads {VERSION})", path=path,
                         field="version")
    kind = doc.get("kind")
    if kind not in KINDS:
        raise InputError(f"{kind!r} is not one of {', '.join(KINDS)}", path=path, field="kind")
    if kind == "constant":
        sigma = _number(doc.get("sigma"), path, "sigma")
        if sigma < 0:
            raise InputError(f"{sigma} m must be >= 0", path=path, field="sigma")
        return CalibratedModel("constant", None, sigma, source=str(path), document=doc)
    lo, hi = _numbers(doc.get("distance_range_m"), path, "distance_range_m", 2)
    if not 0 <= lo < hi:
        raise InputError(f"[{lo}, {hi}] is not a range 0 <= near < far", path=path, field="distance_range_m")
    beyond = doc.get("beyond_measured_incidence", "hold")
    if beyond not in ("hold", "extend"):
        raise InputError(f"{beyond!r} is not 'hold' or 'extend'", path=path, field="beyond_measured_incidence")
    max_inc = _number(doc.get("max_incidence_deg", _DEFAULT_MAX_INCIDENCE_DEG), path, "max_incidence_deg")
    if not 0 <= max_inc <= 90:
        raise InputError(f"{max_inc} deg is not in [0, 90]", path=path, field="max_incidence_deg")
    args = (kind, (lo, hi), beyond == "extend", math.radians(max_inc))
    average = _curves(doc.get("fits"), path, "fits", *args)
    materials: dict[int, IncidenceCurves] = {}
    section = doc.get("materials") or {}
    if not isinstance(section, dict):
        raise InputError("expected a mapping of material names to {fits: [...]}", path=path, field="materials")
    for name, entry in section.items():
        where = f"materials.{name}"
        if not isinstance(entry, dict):
            raise InputError("expected a mapping with 'fits'", path=path, field=where)
        curves = _curves(entry.get("fits"), path, f"{where}.fits", *args)
        if name in MATERIALS:  # other surfaces are documented in the file but have no index to be asked by
            materials[MATERIALS.index(name)] = curves
    return CalibratedModel(kind, average, materials=materials, source=str(path), document=doc)


def read_sensor_model(path: str | Path) -> CalibratedModel:
    """Read a model file (YAML); :class:`InputError` naming the file and the field if it is wrong."""
    from slam2d.io.yaml_file import read_yaml

    return model_from_document(read_yaml(path, "sensor model file"), path)


def load_sensor_model(path: str | Path) -> CalibratedModel:
    """The model in a sensor model file: an object with ``sigma(distance, incidence, material)``."""
    return read_sensor_model(path)


def sensor_model_from_spec(spec: str) -> RangeNoiseModel:
    """``--sensor-model`` text: a model file, ``study`` (:class:`StudyModel`) or ``constant:SIGMA`` (m)."""
    text = spec.strip()
    if text == "study":
        return StudyModel()
    if text.startswith("constant:"):
        value = text.split(":", 1)[1].strip().removesuffix("m")
        try:
            sigma = float(value)
        except ValueError:
            raise InputError(f"{value!r} is not a number of metres", field="--sensor-model") from None
        if not (math.isfinite(sigma) and sigma >= 0):
            raise InputError(f"{sigma} must be a finite sigma >= 0 m", field="--sensor-model")
        return ConstantSigma(sigma)
    path = Path(text)
    if not path.exists():
        raise InputError(
            f"{spec!r} is neither a sensor model file, 'study' nor 'constant:SIGMA'", field="--sensor-model"
        )
    return read_sensor_model(path)


def describe_sensor_model(model: Any) -> dict[str, Any] | None:
    """What run.json records about a sensor model (None without one).

    ``spec`` is the ``--sensor-model`` text that gives the same model again
    (absent for a model built in code that has none).
    """
    if model is None:
        return None
    if isinstance(model, CalibratedModel):
        path = Path(model.source).resolve()
        out: dict[str, Any] = {"type": "file", "spec": str(path), "kind": model.kind, "path": str(path)}
        try:
            out["sha256"] = hashlib.sha256(path.read_bytes()).hexdigest()
        except OSError:
            pass
        return out
    if isinstance(model, ConstantSigma):
        return {"type": "constant", "spec": f"constant:{model.value!r}", "sigma_m": model.value}
    if isinstance(model, StudyModel):
        out = {"type": "study", "black_metal_factor": model.black_metal_factor, "max_incidence_rad": model.max_incidence}
        if model == StudyModel():
            out["spec"] = "study"
        return out
    return {"type": type(model).__name__}


def model_document(
    kind: str,
    *,
    sigma: float | None = None,
    distance_range: tuple[float, float] | None = None,
    fits: list[dict[str, Any]] | None = None,
    materials: dict[str, list[dict[str, Any]]] | None = None,
    extra: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """A model document ready for YAML (the inverse of :func:`model_from_document`)."""
    doc: dict[str, Any] = {"format": FORMAT, "version": VERSION, "kind": kind}
    if kind == "constant":
        doc["sigma"] = float(sigma)  # type: ignore[arg-type]
    else:
        doc["distance_range_m"] = [float(distance_range[0]), float(distance_range[1])]  # type: ignore[index]
        doc["beyond_measured_incidence"] = "hold"
        doc["max_incidence_deg"] = _DEFAULT_MAX_INCIDENCE_DEG
        doc["fits"] = fits
        if materials:
            doc["materials"] = {name: {"fits": f} for name, f in materials.items()}
    if extra:
        doc.update(extra)
    return doc


def dump_model_yaml(doc: dict[str, Any], header: str = "") -> str:
    """A model document as YAML text, lists of numbers on one line each (a covariance row per line)."""
    import yaml

    class _Dumper(yaml.SafeDumper):
        pass

    def _list(dumper: yaml.SafeDumper, data: list[Any]) -> Any:
        flat = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in data)
        return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=flat or None)

    _Dumper.add_representer(list, _list)
    text = yaml.dump(doc, Dumper=_Dumper, sort_keys=False, width=200)
    return "".join(f"# {line}\n" for line in header.splitlines()) + text
