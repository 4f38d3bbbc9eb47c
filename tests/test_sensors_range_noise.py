"""The range noise model: the study's numbers, the documented assumptions, the edge cases."""

from __future__ import annotations

import math

import numpy as np
import pytest

from slam2d.errors import InputError
from slam2d.sensors.range_noise import (
    MATERIALS,
    STUDY_GMAPPING_SIGMA,
    ConstantSigma,
    RangeNoiseModel,
    StudyModel,
    dropout_probability,
    material_index,
    sigma_45,
    sigma_90,
    sigma_eq1,
)

# The study's numbers, typed in again here so the tests check the module against the paper.
FIG6 = (0.000037032, 0.000037966, -0.001034868, 0.00479271)
FIG7 = (0.000424014, -0.002317497, 0.004646225, 0.001744066)
TABLE_I = {  # mm at 90 / 45 deg
    "varnished-wood": (4.3872, 5.5417),
    "white-textile": (4.5669, 5.7235),
    "white-paper": (5.3563, 7.4447),
    "cardboard": (6.0059, 8.5790),
}
STUDY_DISTANCES = np.array([1.0, 2.0, 3.0, 3.5, 4.0])
DEG45 = math.pi / 4


def cubic(c, x):
    return c[0] * x**3 + c[1] * x**2 + c[2] * x + c[3]


def expected_sigma(material: str, distance: float, incidence: float) -> float:
    """sigma from the paper's numbers, as docs/sensor-model.md states the model."""
    if material == "black-metal":
        s0, s45 = 1.5 * TABLE_I["cardboard"][0], 1.5 * TABLE_I["cardboard"][1]
    else:
        s0, s45 = TABLE_I[material]
    mean0 = np.mean([v[0] for v in TABLE_I.values()])
    mean45 = np.mean([v[1] for v in TABLE_I.values()])
    square = cubic(FIG6, distance) * s0 / mean0
    turned = cubic(FIG7, distance) * s45 / mean45
    return square + (turned - square) * incidence / DEG45


def test_material_names_and_index():
    assert MATERIALS == ("varnished-wood", "white-textile", "white-paper", "cardboard", "black-metal")
    assert [material_index(m) for m in MATERIALS] == [0, 1, 2, 3, 4]
    with pytest.raises(ValueError, match="unknown material 'steel'.*varnished-wood.*black-metal"):
        material_index("steel")


def test_eq1_gives_the_studys_gmapping_sigma_at_2_5_m():
    assert STUDY_GMAPPING_SIGMA == 0.0041
    assert sigma_eq1(2.5) == pytest.approx(0.0041, abs=5e-5)


@pytest.mark.parametrize("d", [1.0, 1.7, 2.0, 2.5, 3.0, 3.5, 4.0])
def test_fits_are_the_papers_cubics_inside_the_measured_range(d):
    assert sigma_90(d) == pytest.approx(cubic(FIG6, d), rel=1e-12)
    assert sigma_45(d) == pytest.approx(cubic(FIG7, d), rel=1e-12)


@pytest.mark.parametrize("incidence", [0.0, DEG45])
def test_the_four_tabulated_materials_average_to_the_fit(incidence):
    model = StudyModel()
    d = np.linspace(0.05, 5.6, 57)
    per_material = np.stack([model.sigma(d, incidence, k) for k in range(4)])
    fit = sigma_90(d) if incidence == 0.0 else sigma_45(d)
    np.testing.assert_allclose(per_material.mean(axis=0), fit, rtol=1e-12)


@pytest.mark.parametrize("material", MATERIALS)
@pytest.mark.parametrize("d", list(STUDY_DISTANCES) + [2.5])
@pytest.mark.parametrize("incidence_deg", [0.0, 10.0, 22.5, 45.0])
def test_model_matches_the_paper_inside_the_measured_range(material, d, incidence_deg):
    inc = math.radians(incidence_deg)
    got = StudyModel().sigma(np.array([d]), np.array([inc]), np.array([material_index(material)]))[0]
    assert got == pytest.approx(expected_sigma(material, d, inc), rel=1e-9)


def test_material_ratios_follow_table_i_and_black_metal_is_the_worst():
    model = StudyModel()
    d = np.linspace(0.1, 5.6, 30)
    for inc, col in ((0.0, 0), (DEG45, 1)):
        wood = model.sigma(d, inc, 0)
        cardboard = model.sigma(d, inc, 3)
        np.testing.assert_allclose(cardboard / wood, TABLE_I["cardboard"][col] / TABLE_I["varnished-wood"][col])
        black = model.sigma(d, inc, 4)
        np.testing.assert_allclose(black, 1.5 * cardboard)
        for k in range(4):
            assert np.all(black > model.sigma(d, inc, k))
    # the factor is a documented, changeable assumption
    np.testing.assert_allclose(
        StudyModel(black_metal_factor=2.0).sigma(d, 0.0, 4), 2.0 * model.sigma(d, 0.0, 3)
    )


def test_incidence_interpolates_extrapolates_and_is_capped():
    model = StudyModel()
    d = np.array([1.0, 2.5, 4.0])
    s0 = model.sigma(d, 0.0, 2)
    s45 = model.sigma(d, DEG45, 2)
    np.testing.assert_allclose(model.sigma(d, DEG45 / 2, 2), 0.5 * (s0 + s45))
    sixty = model.sigma(d, math.radians(60), 2)
    np.testing.assert_allclose(sixty, s0 + (s45 - s0) * 60 / 45)
    cap = model.sigma(d, math.radians(80), 2)
    np.testing.assert_allclose(model.sigma(d, math.radians(89.9), 2), cap)
    np.testing.assert_allclose(model.sigma(d, math.pi / 2, 2), cap)
    # negative incidence (a beam from the other side) is the same angle
    np.testing.assert_allclose(model.sigma(d, -math.radians(30), 2), model.sigma(d, math.radians(30), 2))


@pytest.mark.parametrize("fit", [sigma_90, sigma_45])
def test_distance_extension_is_continuous_floored_and_positive(fit):
    eps = 1e-7
    for end in (1.0, 4.0):
        assert fit(end - eps) == pytest.approx(fit(end + eps), abs=1e-8)  # slope < 0.01 m/m
    d_in = np.linspace(1.0, 4.0, 30001)
    floor = fit(d_in).min()
    d = np.linspace(0.0, 80.0, 8001)
    s = fit(d)
    assert np.all(s >= floor - 1e-15) and np.all(s > 0)
    # beyond 4 m: the tangent at 4 m, both fits rising there
    slope4 = (fit(4.0) - fit(4.0 - 1e-6)) / 1e-6
    assert slope4 > 0
    assert fit(5.6) == pytest.approx(fit(4.0) + slope4 * 1.6, rel=1e-5)
    # below 1 m: the tangent at 1 m unless that would go under the floor
    slope1 = (fit(1.0 + 1e-6) - fit(1.0)) / 1e-6
    assert fit(0.5) == pytest.approx(max(fit(1.0) - 0.5 * slope1, floor), rel=1e-5)


def test_constant_sigma():
    model = ConstantSigma(0.0041)
    out = model.sigma(np.ones((3, 4)), 0.2, np.zeros(4, dtype=int))
    assert out.shape == (3, 4) and np.all(out == 0.0041)
    assert ConstantSigma().value == 0.0041
    assert np.all(ConstantSigma(0.0).sigma(np.ones(5), np.zeros(5), np.zeros(5, dtype=int)) == 0.0)
    with pytest.raises(InputError, match="range_sigma: -0.1 must be a finite distance >= 0"):
        ConstantSigma(-0.1)
    with pytest.raises(InputError):
        ConstantSigma(math.nan)


def test_models_follow_the_protocol():
    assert isinstance(StudyModel(), RangeNoiseModel)
    assert isinstance(ConstantSigma(), RangeNoiseModel)


def test_bad_model_parameters_name_the_field():
    with pytest.raises(InputError, match="black_metal_factor"):
        StudyModel(black_metal_factor=-1.0)
    with pytest.raises(InputError, match="max_incidence"):
        StudyModel(max_incidence=2.0)


def test_bad_material_index_is_named():
    with pytest.raises(ValueError, match="material: index 7"):
        StudyModel().sigma(np.ones(2), np.zeros(2), np.array([0, 7]))
    with pytest.raises(ValueError, match="material: expected integer"):
        StudyModel().sigma(np.ones(2), np.zeros(2), np.array([0.5, 1.0]))


def test_dropout_probability_shape_and_assumptions():
    inc = np.radians(np.linspace(0.0, 90.0, 181))
    for k in range(len(MATERIALS)):
        p = dropout_probability(inc, k)
        assert np.all((p >= 0) & (p <= 1))
        assert np.all(np.diff(p) >= 0), "grazing beams drop out more"
        assert p[-1] == pytest.approx(1.0), "a beam along the surface never returns"
        assert p[0] < 0.05
    bright = dropout_probability(inc, material_index("white-paper"))
    dark = dropout_probability(inc, material_index("black-metal"))
    assert np.all(dark >= bright) and dark[0] > bright[0]
    # the documented formula at one point: white paper at 80 deg
    graze = ((80 - 70) / (90 - 70)) ** 2
    assert dropout_probability(math.radians(80), 2) == pytest.approx(1 - (1 - 0.001) * (1 - graze))
