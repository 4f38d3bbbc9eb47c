"""Weighted polynomial fits of sigma against distance, with the degree chosen by cross-validation.

A fit is a weighted least-squares polynomial (weights ``1 / se**2``, ``se`` the
standard error of each measured sigma). Its coefficient covariance is
``(X' W X)^-1``, inflated by the reduced chi-square when the points scatter
more than their standard errors say (materials that differ, a model that is
not quite a polynomial), so the confidence band is honest either way.

The degree is chosen by leave-one-distance-out cross-validation: every
distinct distance is left out in turn, the fit to the others predicts it, and
the degree with the smallest mean weighted squared prediction error wins
(ties go to the lower degree). The two end distances are not held out:
predicting them is extrapolation, which a model file never asks of a
polynomial. Cross-validation protects against too low a degree (a curve that
misses the shape); it may pick a degree higher than the truth's, which costs
a little variance, not bias. Leaving a whole distance out, not one point, keeps
points measured at the same distance (several materials) from vouching for
each other.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["PolyFit", "fit_polynomial", "choose_degree", "cv_scores", "Z95"]

#: Two-sided 95 % normal quantile: the confidence bands are +- this many standard errors.
Z95 = 1.959963984540054


@dataclass(frozen=True)
class PolyFit:
    """sigma(d) = c0 + c1 d + ... (lowest power first), fitted over ``distance_range``."""

    coefficients: NDArray[np.float64]
    covariance: NDArray[np.float64]
    distance_range: tuple[float, float]
    chi2_reduced: float  # weighted residual sum of squares / degrees of freedom (NaN: none)
    points: int

    @property
    def degree(self) -> int:
        return int(self.coefficients.shape[0]) - 1

    def __call__(self, distance: ArrayLike) -> NDArray[np.float64]:
        return _vander(np.asarray(distance, dtype=np.float64), self.degree) @ self.coefficients

    def standard_error(self, distance: ArrayLike) -> NDArray[np.float64]:
        """Standard error of the fitted curve at ``distance`` (from the coefficient covariance)."""
        x = _vander(np.asarray(distance, dtype=np.float64), self.degree)
        return np.sqrt(np.maximum(np.einsum("...i,ij,...j->...", x, self.covariance, x), 0.0))


def _vander(d: NDArray[np.float64], degree: int) -> NDArray[np.float64]:
    return d[..., None] ** np.arange(degree + 1)


def fit_polynomial(distance: ArrayLike, sigma: ArrayLike, se: ArrayLike, degree: int) -> PolyFit:
    """Weighted least-squares polynomial of ``degree`` through ``(distance, sigma)`` with standard errors ``se``."""
    d = np.asarray(distance, dtype=np.float64)
    y = np.asarray(sigma, dtype=np.float64)
    s = np.asarray(se, dtype=np.float64)
    if degree < 0 or len(np.unique(d)) < degree + 1:
        raise ValueError(f"degree {degree} needs at least {degree + 1} distinct distances, got {len(np.unique(d))}")
    w = 1.0 / np.maximum(s, 1e-12 * max(float(np.max(np.abs(y))), 1e-12))
    x = _vander(d, degree)
    coef, *_ = np.linalg.lstsq(x * w[:, None], y * w, rcond=None)
    info = (x * (w**2)[:, None]).T @ x
    cov = np.linalg.pinv(info)
    dof = len(d) - (degree + 1)
    chi2 = float(np.sum(((x @ coef - y) * w) ** 2))
    red = chi2 / dof if dof > 0 else float("nan")
    if dof > 0 and red > 1.0:
        cov = cov * red
    return PolyFit(coef, cov, (float(d.min()), float(d.max())), red, int(len(d)))


def cv_scores(distance: ArrayLike, sigma: ArrayLike, se: ArrayLike, max_degree: int) -> dict[int, float]:
    """Leave-one-distance-out score (mean weighted squared prediction error) per degree 0..max_degree.

    Degrees that leave too few distinct distances to fit when one is held out are absent.
    """
    return {k: float(np.mean(v)) for k, v in _cv_errors(distance, sigma, se, max_degree).items()}


def _cv_errors(
    distance: ArrayLike, sigma: ArrayLike, se: ArrayLike, max_degree: int
) -> dict[int, NDArray[np.float64]]:
    d = np.asarray(distance, dtype=np.float64)
    y = np.asarray(sigma, dtype=np.float64)
    s = np.asarray(se, dtype=np.float64)
    levels = np.unique(d)
    scores: dict[int, NDArray[np.float64]] = {}
    for degree in range(max_degree + 1):
        if len(levels) - 1 < degree + 1:
            break
        errors = []
        # The ends are not held out: predicting them would be extrapolation, which a model file never
        # does with its polynomial (it continues along the tangent), and one wild end would decide alone.
        for level in levels[1:-1] if len(levels) > 3 else levels:
            held = d == level
            fit = fit_polynomial(d[~held], y[~held], s[~held], degree)
            errors.append(((fit(d[held]) - y[held]) / s[held]) ** 2)
        scores[degree] = np.concatenate(errors)
    return scores


def choose_degree(distance: ArrayLike, sigma: ArrayLike, se: ArrayLike, max_degree: int = 3) -> tuple[int, dict[int, float]]:
    """The degree with the best cross-validation score, and every degree's score.

    With too few distinct distances to cross-validate (fewer than three) the
    degree is the highest the points allow, at most ``max_degree``.
    """
    errors = _cv_errors(distance, sigma, se, max_degree)
    if len(errors) < 2:  # nothing to choose between
        return min(max_degree, len(np.unique(np.asarray(distance))) - 1), {}
    scores = {k: float(np.mean(v)) for k, v in errors.items()}
    best = min(scores.values())
    return min(k for k, v in scores.items() if v <= best * (1 + 1e-9) + 1e-12), scores  # ties: the lower degree
