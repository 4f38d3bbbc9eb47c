"""Weights, Neff, entropy and low-variance resampling of a particle filter, as GMapping does them.

All functions are whole-array numpy over the particles (or compiled), so a
filter step never loops over particles in Python.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "normalized_weights",
    "effective_sample_size",
    "weight_entropy",
    "published_entropy",
    "systematic_resample",
    "backtrack",
]


def normalized_weights(log_weights: ArrayLike, gain: float = 1.0) -> NDArray[np.float64]:
    """``w_i = exp(gain (l_i - max l)) / sum``: GMapping's ``normalize()`` with ``gain = 1 / (ogain N)``.

    The gain flattens the log-likelihoods so a single scan does not collapse the
    particle set (GMapping's ``ogain`` smoothing).
    """
    lw = np.asarray(log_weights, dtype=np.float64)
    w = np.exp(gain * (lw - lw.max()))
    return w / w.sum()


def effective_sample_size(weights: ArrayLike) -> float:
    """Neff = 1 / sum(w_i^2) of normalised weights: N when equal, 1 when one particle has them all."""
    w = np.asarray(weights, dtype=np.float64)
    return float(1.0 / np.dot(w, w))


def weight_entropy(weights: ArrayLike) -> float:
    """``-sum w_i ln w_i`` of normalised weights; at most ``ln N`` (3.4012 for 30 particles)."""
    w = np.asarray(weights, dtype=np.float64)
    w = w[w > 0.0]
    return float(-np.sum(w * np.log(w)))


def published_entropy(particle_weights: ArrayLike) -> float:
    """The entropy ``slam_gmapping`` publishes on ``~entropy`` (``computePoseEntropy``).

    It normalises the particles' *raw* weights (their accumulated
    log-likelihoods since the last resampling, all <= 0) by their sum and returns
    ``-sum q_i ln q_i`` with ``q_i = weight_i / sum weight``. Its maximum is
    ``ln N`` (all weights equal). Right after a resampling every weight is 0,
    the ratio is undefined and the node publishes nothing: NaN here, as for any
    value the node would not publish (it publishes only values > 0).
    """
    lw = np.asarray(particle_weights, dtype=np.float64)
    total = lw.sum()
    with np.errstate(invalid="ignore", divide="ignore"):
        q = lw / total
        q = q[q > 0.0]
        h = float(-np.sum(q * np.log(q)))
    return h if h > 0.0 and math.isfinite(h) else math.nan


def systematic_resample(weights: ArrayLike, u: float) -> NDArray[np.int64]:
    """Low-variance resampling: indices of the parents of N new particles.

    One offset ``u`` in [0, 1) places N equally spaced pointers ``(u + k) / N``
    on the cumulative weights (GMapping's ``resampleIndexes``); a particle of
    weight w gets floor or ceil of ``N w`` children.
    """
    w = np.asarray(weights, dtype=np.float64)
    n = w.shape[0]
    cum = np.cumsum(w)
    cum /= cum[-1]
    targets = (u + np.arange(n)) / n
    return np.minimum(np.searchsorted(cum, targets, side="right"), n - 1).astype(np.int64)


@njit(cache=True)
def backtrack(history: NDArray[np.float64], parents: NDArray[np.int32], last: int) -> NDArray[np.float64]:
    """The path ``(F, 3)`` of particle ``last`` back through its ancestors.

    ``history[k]`` holds every particle's pose after step k and ``parents[k, i]``
    the index at step k - 1 of particle i's ancestor.
    """
    f = history.shape[0]
    out = np.empty((f, 3))
    i = last
    for k in range(f - 1, -1, -1):
        out[k] = history[k, i]
        i = parents[k, i]
    return out
