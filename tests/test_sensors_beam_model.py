"""The shared per-beam sigma: incidence from neighbouring endpoints, models evaluated per beam."""

from __future__ import annotations

import math

import numpy as np
import pytest

from slam2d.core.scan import make_scan
from slam2d.sensors.beam_model import beam_sigmas, incidence_angles
from slam2d.sensors.range_noise import ConstantSigma, StudyModel, sigma_45, sigma_90


def _wall_ranges(angles, distance, tilt):
    """Ranges to an infinite wall at ``distance`` along x, its normal turned by ``tilt``."""
    n = np.array([math.cos(tilt), math.sin(tilt)])
    d = np.stack([np.cos(angles), np.sin(angles)], axis=-1)
    return distance / (d @ n)


@pytest.mark.parametrize("tilt_deg", [0.0, 20.0, 45.0, -30.0])
def test_incidence_on_a_flat_wall_matches_geometry(tilt_deg):
    tilt = math.radians(tilt_deg)
    angles = np.linspace(-0.3, 0.3, 61)
    r = _wall_ranges(angles, 2.0, tilt)
    inc = incidence_angles(r, angles)
    expected = np.abs(angles - tilt)
    np.testing.assert_allclose(inc, expected, atol=1e-9)


def test_missing_neighbours_and_depth_jumps():
    angles = np.linspace(-0.1, 0.1, 5)
    r = np.array([2.0, np.nan, 2.0, 5.0, 5.0])
    inc = incidence_angles(r, angles)
    assert np.isnan(inc[1])
    assert inc[0] == 0.0  # no usable neighbour: assumed square
    assert inc[2] == 0.0  # its neighbour at 5 m is another surface
    assert np.isfinite(inc[3]) and np.isfinite(inc[4])
    assert incidence_angles(np.zeros(0), np.zeros(0)).shape == (0,)


def test_beam_sigmas_default_constant_and_study_model():
    angles = np.linspace(-0.5, 0.5, 101)
    r = _wall_ranges(angles, 2.5, 0.0)
    r[10] = np.nan
    scan = make_scan(0.0, r, angle_min=-0.5, angle_increment=0.01, range_min=0.02, range_max=5.6)
    s = beam_sigmas(scan, None, 0.05)
    assert np.isnan(s[10]) and np.all(s[~np.isnan(scan.ranges)] == 0.05)
    s = beam_sigmas(scan, ConstantSigma(0.0041), 0.05)
    assert np.nanmax(np.abs(s - 0.0041)) < 1e-15
    s = beam_sigmas(scan, StudyModel(), 0.05)
    # the beam square to the wall gets the 90-degree fit, averaged over the tabulated materials
    assert s[50] == pytest.approx(float(sigma_90(2.5)), rel=1e-9)
    # an oblique beam is noisier than the square one, and below the 45-degree fit at this incidence
    assert s[0] > s[50]
    assert s[0] < float(sigma_45(float(r[0])))
