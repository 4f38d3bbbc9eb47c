"""Pose-graph optimisers behind one small interface.

::

    from slam2d.backends import PoseGraph, get_backend
    g = PoseGraph()
    a = g.add_node([0, 0, 0]); b = g.add_node([1, 0, 0])
    g.add_edge(a, b, measurement=[1.0, 0.0, 0.0], information=np.eye(3))
    res = get_backend("spa").optimize(g)
    g.poses = res.poses

Back ends: ``spa`` (sparse pose adjustment, Levenberg-Marquardt), ``lago``
(Carlone et al.'s linear approximation, no initial guess needed) and
``gtsam`` (only when the ``gtsam`` package is installed).
"""

from __future__ import annotations

from slam2d.backends.base import Backend, OptimizationResult
from slam2d.backends.graph import PoseGraph, edge_errors, edge_jacobians, graph_cost
from slam2d.backends.registry import available_backends, backend_params, get_backend

__all__ = [
    "PoseGraph",
    "OptimizationResult",
    "Backend",
    "get_backend",
    "available_backends",
    "backend_params",
    "edge_errors",
    "edge_jacobians",
    "graph_cost",
]
