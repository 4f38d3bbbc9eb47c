"""Occupancy grids, compiled ray casting, likelihood fields and mapping with known poses."""

from slam2d.grids.likelihood_field import (
    LikelihoodField,
    bilinear_at,
    bilinear_gradient_at,
    bilinear_lookup,
    distance_field,
    likelihood_field,
)
from slam2d.grids.mapping import MappingStats, map_from_poses
from slam2d.grids.occupancy import GridParams, OccupancyGrid, logit
from slam2d.grids.raycast import cast_rays, integrate_rays, trace_ray

__all__ = [
    "GridParams",
    "OccupancyGrid",
    "logit",
    "LikelihoodField",
    "likelihood_field",
    "distance_field",
    "bilinear_at",
    "bilinear_gradient_at",
    "bilinear_lookup",
    "MappingStats",
    "map_from_poses",
    "integrate_rays",
    "trace_ray",
    "cast_rays",
]
