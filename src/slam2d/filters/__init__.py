"""Particle-filter arithmetic shared by particle-based methods: weights, resampling, ancestry."""

from slam2d.filters.particles import (
    backtrack,
    normalized_weights,
    effective_sample_size,
    published_entropy,
    weight_entropy,
    systematic_resample,
)

__all__ = [
    "backtrack",
    "normalized_weights",
    "effective_sample_size",
    "published_entropy",
    "weight_entropy",
    "systematic_resample",
]
