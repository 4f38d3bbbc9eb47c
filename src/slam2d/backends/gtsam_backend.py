"""GTSAM's Levenberg-Marquardt as a back end, only when the optional ``gtsam`` package imports.

GTSAM's ``BetweenFactor<Pose2>`` error is ``Log(Z^-1 X_i^-1 X_j)``, which
agrees with slam2d's ``t2v`` error to first order; the reported costs are
always slam2d's (:meth:`PoseGraph.cost`). Building the factor graph loops over
edges in Python because that is GTSAM's API; it is a comparison back end,
not the default.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from slam2d.backends.base import Backend, OptimizationResult
from slam2d.backends.graph import PoseGraph
from slam2d.params import param

__all__ = ["GtsamParams", "GtsamBackend"]


@dataclass
class GtsamParams:
    max_iterations: int = param(100, low=1, help="most Levenberg-Marquardt iterations")
    relative_tolerance: float = param(1e-5, low=0.0, help="GTSAM relativeErrorTol")
    robust_kernel: str = param("none", choices=("none", "huber", "cauchy"), help="robust kernel on the whitened error")
    robust_delta: float = param(1.0, low=1e-12, help="kernel width in units of the Mahalanobis distance")


def _gtsam():
    try:
        import gtsam
    except Exception:
        return None
    return gtsam


class GtsamBackend(Backend):
    name: ClassVar[str] = "gtsam"
    needs_initial_guess: ClassVar[bool] = True

    @staticmethod
    def available() -> bool:
        return _gtsam() is not None

    @staticmethod
    def unavailable_reason() -> str:
        return "back end 'gtsam' needs the optional gtsam package (pip install gtsam); use 'spa' or 'lago'"

    def __init__(self, params: GtsamParams | None = None) -> None:
        self.params = params or GtsamParams()

    def optimize(self, graph: PoseGraph) -> OptimizationResult:
        gtsam = _gtsam()
        t0, c0 = time.perf_counter(), time.process_time()
        graph.check_fixed()
        p = self.params
        cost0 = graph.cost()
        fg = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        for k, pose in enumerate(graph.poses):
            values.insert(k, gtsam.Pose2(*pose))
        if graph.num_nodes:
            f = int(graph.fixed)
            fg.add(gtsam.NonlinearEqualityPose2(f, gtsam.Pose2(*graph.poses[f])))
        for i, j, z, info in zip(graph.edge_i, graph.edge_j, graph.measurements, graph.information):
            noise = gtsam.noiseModel.Gaussian.Information(info)
            if p.robust_kernel == "huber":
                noise = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(p.robust_delta), noise)
            elif p.robust_kernel == "cauchy":
                noise = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Cauchy.Create(p.robust_delta), noise)
            fg.add(gtsam.BetweenFactorPose2(int(i), int(j), gtsam.Pose2(*z), noise))
        lm = gtsam.LevenbergMarquardtParams()
        lm.setMaxIterations(p.max_iterations)
        lm.setRelativeErrorTol(p.relative_tolerance)
        opt = gtsam.LevenbergMarquardtOptimizer(fg, values, lm)
        result = opt.optimize()
        x = np.array([[q.x(), q.y(), q.theta()] for q in (result.atPose2(k) for k in range(graph.num_nodes))]).reshape(-1, 3)
        its = int(opt.iterations())
        return OptimizationResult(
            poses=x, cost_before=cost0, cost_after=graph.cost(x), iterations=its, converged=its < p.max_iterations,
            wall_s=time.perf_counter() - t0, cpu_s=time.process_time() - c0,
            objective_before=float("nan"), objective_after=2.0 * float(fg.error(result)),
            message="gtsam Levenberg-Marquardt",
        )
