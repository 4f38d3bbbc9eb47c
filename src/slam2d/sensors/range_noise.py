"""Range noise of a planar laser: sigma(distance, incidence angle, material) and dropouts.

The default model, :class:`StudyModel`, is built from the source study's
repeatability experiment with a Hokuyo URG-04LX-UG01 (50 set-ups of 500
repeated readings: five materials at 1, 2, 3, 3.5 and 4 m, the target
perpendicular to the beam or turned by 45 degrees):

* Fig. 6 and Fig. 7 give sigma against distance as cubic fits, one for the
  perpendicular ("90 deg") set-up and one for the 45-degree set-up, averaged
  over the materials;
* Table I gives sigma per material at each angle, averaged over the distances;
  the model uses only its *ratios* (a material's sigma over the mean of the
  four tabulated materials at that angle) to scale the fits per material;
* eq. (1) is the study's single fit over both angles; at 2.5 m it gives the
  0.0041 m that the study configured GMapping with (:class:`ConstantSigma`).

Everything the study does not give is an assumption of this module, named as
such below and in docs/sensor-model.md: the black metal plate's sigma, the
behaviour between and beyond the two measured angles, the behaviour outside
1-4 m, and the dropout probabilities.

Angles here are *incidence* angles: the angle between the beam and the surface
normal, in radians. The study's "90 deg" set-up (target square to the beam) is
incidence 0; its "45 deg" set-up is incidence pi/4.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from slam2d.errors import InputError
from slam2d.params import param

__all__ = [
    "MATERIALS",
    "material_index",
    "RangeNoiseModel",
    "ConstantSigma",
    "StudyModel",
    "dropout_probability",
    "sigma_90",
    "sigma_45",
    "sigma_eq1",
    "TABLE_I_MM",
    "STUDY_GMAPPING_SIGMA",
]

#: Surface materials, in this order everywhere (worlds store an index into it).
MATERIALS: tuple[str, ...] = ("varnished-wood", "white-textile", "white-paper", "cardboard", "black-metal")

#: Table I of the study: sigma in millimetres at the 90-degree and 45-degree set-ups,
#: each the mean over the measured distances. The study gives no number for the
#: black metal plate (only that it was the worst), so it is absent here.
TABLE_I_MM: dict[str, tuple[float, float]] = {
    "varnished-wood": (4.3872, 5.5417),
    "white-textile": (4.5669, 5.7235),
    "white-paper": (5.3563, 7.4447),
    "cardboard": (6.0059, 8.5790),
}

#: The single sigma the study configured GMapping with: eq. (1) at 2.5 m, metres.
STUDY_GMAPPING_SIGMA = 0.0041

# Cubic fits, highest power first; x and sigma in metres.
_FIT_90 = (0.000037032, 0.000037966, -0.001034868, 0.00479271)  # Fig. 6, target square to the beam
_FIT_45 = (0.000424014, -0.002317497, 0.004646225, 0.001744066)  # Fig. 7, target turned 45 deg
_FIT_EQ1 = (0.0002500, -0.0012220, 0.0018264, 0.0032760)  # eq. (1), both angles together
_MEASURED_NEAR = 1.0  # m, nearest distance the study measured
_MEASURED_FAR = 4.0  # m, farthest distance the study measured


def material_index(name: str) -> int:
    """Index of ``name`` in :data:`MATERIALS`; ``ValueError`` listing the valid names otherwise."""
    try:
        return MATERIALS.index(name)
    except ValueError:
        raise ValueError(f"unknown material {name!r}; valid materials: {', '.join(MATERIALS)}") from None


@runtime_checkable
class RangeNoiseModel(Protocol):
    """Standard deviation of a range reading, per beam."""

    def sigma(self, distance: NDArray, incidence: NDArray, material: NDArray) -> NDArray:
        """Sigma in metres for true ``distance`` (m), ``incidence`` (rad from the surface
        normal) and ``material`` (int index into :data:`MATERIALS`); arrays broadcast."""
        ...


class _ExtendedCubic:
    """A cubic fit measured over 1-4 m, continued outside it.

    Outside the measured distances the cubic is not trusted (the 45-degree fit
    would grow like x**3): it is continued by its tangent at the nearer end,
    and never drops below the smallest value the fit takes over 1-4 m.
    """

    def __init__(self, coefficients: tuple[float, float, float, float]) -> None:
        self.poly = np.poly1d(coefficients)
        slope = self.poly.deriv()
        lo, hi = _MEASURED_NEAR, _MEASURED_FAR
        candidates = [lo, hi] + [float(r.real) for r in slope.roots if abs(r.imag) < 1e-12 and lo < r.real < hi]
        self.floor = float(min(self.poly(c) for c in candidates))
        self.near_slope = float(slope(lo))
        self.far_slope = float(slope(hi))

    def __call__(self, distance: ArrayLike) -> NDArray[np.float64]:
        d = np.asarray(distance, dtype=np.float64)
        c3, c2, c1, c0 = self.poly.coeffs
        x = np.minimum(np.maximum(d, _MEASURED_NEAR), _MEASURED_FAR)
        s = ((c3 * x + c2) * x + c1) * x + c0  # the fit, held at its end values outside 1-4 m
        s += self.near_slope * np.minimum(d - _MEASURED_NEAR, 0.0)  # tangent below 1 m
        s += self.far_slope * np.maximum(d - _MEASURED_FAR, 0.0)  # tangent beyond 4 m
        return np.maximum(s, self.floor)


_SIGMA_90 = _ExtendedCubic(_FIT_90)
_SIGMA_45 = _ExtendedCubic(_FIT_45)
_SIGMA_EQ1 = _ExtendedCubic(_FIT_EQ1)


def sigma_90(distance: ArrayLike) -> NDArray[np.float64]:
    """Fig. 6: sigma (m) at ``distance`` (m) with the target square to the beam, all materials averaged."""
    return _SIGMA_90(distance)


def sigma_45(distance: ArrayLike) -> NDArray[np.float64]:
    """Fig. 7: sigma (m) at ``distance`` (m) with the target turned 45 degrees, all materials averaged."""
    return _SIGMA_45(distance)


def sigma_eq1(distance: ArrayLike) -> NDArray[np.float64]:
    """Eq. (1): the study's one fit over both angles and all materials; 0.0041 m at 2.5 m."""
    return _SIGMA_EQ1(distance)


def _material_array(material: ArrayLike) -> NDArray[np.int64]:
    m = np.asarray(material)
    if m.size and not np.issubdtype(m.dtype, np.integer):
        raise ValueError(f"material: expected integer indices into MATERIALS, got dtype {m.dtype}")
    m = m.astype(np.int64, copy=False)
    if m.size and (m.min() < 0 or m.max() >= len(MATERIALS)):
        bad = m[(m < 0) | (m >= len(MATERIALS))].flat[0]
        raise ValueError(f"material: index {bad} is not in 0..{len(MATERIALS) - 1} ({', '.join(MATERIALS)})")
    return m


@dataclass(frozen=True)
class ConstantSigma:
    """The same sigma for every beam: what GMapping's ``sigma`` parameter assumes.

    The study's choice was 0.0041 m (eq. (1) at 2.5 m). ``ConstantSigma(0.0)``
    gives noise-free ranges. (The field is ``value`` because ``sigma`` is the
    method every :class:`RangeNoiseModel` has.)
    """

    value: float = param(STUDY_GMAPPING_SIGMA, unit="m", low=0.0, help="standard deviation of every range reading")

    def __post_init__(self) -> None:
        if not (math.isfinite(self.value) and self.value >= 0.0):
            raise InputError(f"{self.value} must be a finite distance >= 0", field="range_sigma")

    def sigma(self, distance: NDArray, incidence: NDArray, material: NDArray) -> NDArray:
        """``value`` for every beam, in the broadcast shape of the arguments."""
        shape = np.broadcast_shapes(np.shape(distance), np.shape(incidence), np.shape(material))
        return np.full(shape, self.value, dtype=np.float64)


def _table_ratios(column: int, black_metal_factor: float) -> NDArray[np.float64]:
    """Each material's Table I sigma over the mean of the four tabulated materials at one angle."""
    values = np.array([TABLE_I_MM[m][column] for m in MATERIALS if m in TABLE_I_MM])
    ratios = [TABLE_I_MM[m][column] / values.mean() for m in MATERIALS if m in TABLE_I_MM]
    cardboard = TABLE_I_MM["cardboard"][column] / values.mean()
    return np.array(ratios + [black_metal_factor * cardboard], dtype=np.float64)


@dataclass(frozen=True)
class StudyModel:
    """The study's URG-04LX repeatability model: sigma(distance, incidence, material).

    For a material ``m``, distance ``d`` and incidence ``a`` (radians from the
    surface normal)::

        s0(d)  = sigma_90(d) * TableI[m, 90] / mean(TableI[:, 90])     # square to the beam
        s45(d) = sigma_45(d) * TableI[m, 45] / mean(TableI[:, 45])     # turned 45 degrees
        sigma  = s0 + (s45 - s0) * min(a, max_incidence) / (pi / 4)

    so the four tabulated materials average exactly to the study's fits.
    Assumptions (the study gives no data for them):

    * black metal plate: ``black_metal_factor`` (1.5) times cardboard's sigma at
      each angle; the study only says it was the worst surface;
    * incidence between 0 and 45 degrees is interpolated linearly, beyond 45
      degrees extrapolated linearly in the angle, and held constant beyond
      ``max_incidence`` (80 degrees), where beams mostly drop out anyway
      (:func:`dropout_probability`);
    * distances outside the measured 1-4 m continue each fit along its tangent
      at the nearer end, never below the fit's smallest value over 1-4 m. The
      fits describe the URG-04LX (5.6 m range); for long-range lasers use
      :class:`ConstantSigma`.
    """

    black_metal_factor: float = param(
        1.5, low=0.0, help="black metal plate's sigma as a multiple of cardboard's (an assumption: "
        "the study reports it only as the worst surface)"
    )
    max_incidence: float = param(
        math.radians(80.0), unit="rad", low=0.0, high=math.pi / 2,
        help="incidence beyond which sigma stops growing (an assumption; the study measured 0 and 45 deg)",
    )

    def __post_init__(self) -> None:
        if not (math.isfinite(self.black_metal_factor) and self.black_metal_factor > 0.0):
            raise InputError(f"{self.black_metal_factor} must be a positive factor", field="black_metal_factor")
        if not (0.0 <= self.max_incidence <= math.pi / 2):
            raise InputError(f"{self.max_incidence} rad is not in [0, pi/2]", field="max_incidence")
        object.__setattr__(self, "_ratio_90", _table_ratios(0, self.black_metal_factor))
        object.__setattr__(self, "_ratio_45", _table_ratios(1, self.black_metal_factor))

    def material_ratios(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Per-material multipliers of the 90- and 45-degree fits, in :data:`MATERIALS` order."""
        return self._ratio_90.copy(), self._ratio_45.copy()  # type: ignore[attr-defined]

    def sigma(self, distance: NDArray, incidence: NDArray, material: NDArray) -> NDArray:
        """Sigma (m) per beam; see the class docstring for the formula."""
        m = _material_array(material)
        d = np.asarray(distance, dtype=np.float64)
        a = np.minimum(np.abs(np.asarray(incidence, dtype=np.float64)), self.max_incidence)
        square = sigma_90(d) * self._ratio_90[m]  # type: ignore[attr-defined]
        turned = sigma_45(d) * self._ratio_45[m]  # type: ignore[attr-defined]
        return np.maximum(square + (turned - square) * (a / (math.pi / 4)), 0.0)


# Dropout assumptions (the study reports none): a small floor per material, and
# beyond an onset incidence the returned light falls off until nothing comes back
# at grazing incidence. Dark surfaces return less light, so they start earlier
# and have the higher floor.
_DROPOUT_FLOOR = np.array([0.001, 0.001, 0.001, 0.002, 0.02])
_DROPOUT_ONSET = np.radians([70.0, 70.0, 70.0, 70.0, 55.0])


def dropout_probability(incidence: ArrayLike, material: ArrayLike) -> NDArray[np.float64]:
    """Probability (per beam, per scan) that a beam hitting this surface returns nothing.

    An assumption, not a measurement (the study reports none)::

        grazing = clip((incidence - onset) / (pi/2 - onset), 0, 1) ** 2
        p = 1 - (1 - floor) * (1 - grazing)

    with ``floor`` 0.1 % for the bright materials, 0.2 % for cardboard and 2 %
    for the black metal plate, and ``onset`` 70 degrees (55 degrees for black
    metal, which returns less light). So a beam square to a bright wall almost
    always returns, and a beam grazing a wall (incidence -> 90 deg) never does.
    """
    m = _material_array(material)
    a = np.abs(np.asarray(incidence, dtype=np.float64))
    onset = _DROPOUT_ONSET[m]
    grazing = np.clip((a - onset) / (math.pi / 2 - onset), 0.0, 1.0) ** 2
    return 1.0 - (1.0 - _DROPOUT_FLOOR[m]) * (1.0 - grazing)
