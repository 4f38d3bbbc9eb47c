"""Sparse pose adjustment (Konolige et al. 2010, Karto's optimiser): Levenberg-Marquardt on the pose graph.

Each iteration linearises every edge error at once in one compiled pass
(:func:`~slam2d.backends.linear.assemble_normal_equations`, the same local
Jacobians as :func:`~slam2d.backends.graph.edge_jacobians`), fills the fixed
sparsity pattern of ``H = J^T W J`` and solves ``(H + lambda D) dx = -g`` with
the compiled block Cholesky (or SuperLU / CHOLMOD), ``D = I`` by default or
``diag(H)`` as in Karto's ``SysSPA2d::doSPA``. A step that lowers the
objective is kept and lambda follows Nielsen's gain-ratio rule; otherwise
lambda grows and the step is retried. Poses are updated on the manifold,
``X <- X (+) dx``.

A robust kernel (Huber or Cauchy, on the Mahalanobis distance
``sqrt(e^T Omega e)``) is applied by iteratively reweighted least squares:
each edge's information is scaled by ``rho'(chi2)`` at the linearisation point.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from slam2d.backends.base import Backend, OptimizationResult
from slam2d.backends.graph import PoseGraph, edge_errors
from slam2d.backends.linear import KERNELS, SOLVERS, BlockPattern, LinearSolver, assemble_normal_equations
from slam2d.core import se2
from slam2d.params import param

__all__ = ["SpaParams", "SpaBackend", "robust_weights", "robust_objective"]

# damping never drops below this: keeps parts of a graph not tied to the fixed node solvable
_MIN_LAMBDA = 1e-12


@dataclass
class SpaParams:
    max_iterations: int = param(40, low=1, help="most Levenberg-Marquardt iterations (Karto: doSPA(40))")
    initial_lambda: float = param(1e-5, low=0.0, help="initial LM damping (GTSAM 1e-5; Karto's sba 1e-4 with diagonal damping)")
    damping: str = param(
        "identity", choices=("identity", "diagonal"),
        help="LM damping added to H: lambda*I (as GTSAM; does not hold back weakly constrained sub-graphs) or lambda*diag(H) (Marquardt, as Karto's sba)",
    )
    max_lambda: float = param(1e12, low=0.0, help="give up when the damping exceeds this (no descent step exists)")
    relative_tolerance: float = param(
        1e-6, low=0.0, help="converged when an accepted step lowers the objective by less than this fraction (Ceres' function_tolerance)"
    )
    step_tolerance: float = param(1e-9, low=0.0, help="converged when the largest step component is below this [m or rad]")
    robust_kernel: str = param("none", choices=("none", "huber", "cauchy"), help="robust kernel on the Mahalanobis distance of each edge")
    robust_delta: float = param(
        1.0, low=1e-12, help="kernel width in units of the Mahalanobis distance (Huber: quadratic below it; Cauchy: scale c)"
    )
    linear_solver: str = param(
        "auto", choices=SOLVERS,
        help="sparse solver: block (compiled block Cholesky; auto), splu (scipy SuperLU) or cholmod (needs scikit-sparse)",
    )


def robust_objective(chi2: NDArray, kernel: str, delta: float) -> NDArray[np.float64]:
    """Per-edge ``rho(chi2)``; equals ``chi2`` for no kernel."""
    if kernel == "huber":
        d2 = delta * delta
        return np.where(chi2 <= d2, chi2, 2.0 * delta * np.sqrt(chi2) - d2)
    if kernel == "cauchy":
        c2 = delta * delta
        return c2 * np.log1p(chi2 / c2)
    return chi2


def robust_weights(chi2: NDArray, kernel: str, delta: float) -> NDArray[np.float64]:
    """Per-edge ``rho'(chi2)``: the IRLS weight of each edge's information."""
    if kernel == "huber":
        root = np.sqrt(np.maximum(chi2, 1e-300))
        return np.where(chi2 <= delta * delta, 1.0, delta / root)
    if kernel == "cauchy":
        return 1.0 / (1.0 + chi2 / (delta * delta))
    return np.ones_like(chi2)


class SpaBackend(Backend):
    name: ClassVar[str] = "spa"
    needs_initial_guess: ClassVar[bool] = True

    def __init__(self, params: SpaParams | None = None) -> None:
        self.params = params or SpaParams()

    def optimize(self, graph: PoseGraph, poses: NDArray | None = None, *, solver: LinearSolver | None = None) -> OptimizationResult:
        """Optimise from the graph's poses (or ``poses``); the graph itself is not modified.

        ``solver``: a :class:`LinearSolver` already set up for this graph's 3x3 block
        pattern (LAGO hands over its own, so the ordering and symbolic analysis are reused).
        """
        t0, c0 = time.perf_counter(), time.process_time()
        graph.check_fixed()
        p = self.params
        x = np.array(graph.poses if poses is None else poses, dtype=np.float64)
        ei, ej, z, info = graph.edge_i, graph.edge_j, graph.measurements, graph.information
        n = graph.num_nodes
        kernel, delta = p.robust_kernel, p.robust_delta

        def objective(poses_: NDArray) -> tuple[float, float]:
            e = edge_errors(poses_, ei, ej, z)
            chi2 = np.einsum("ki,kij,kj->k", e, info, e)
            return float(robust_objective(chi2, kernel, delta).sum()), float(chi2.sum())

        obj, cost = objective(x)
        obj0, cost0 = obj, cost
        if n < 2 or graph.num_edges == 0:
            return OptimizationResult(
                poses=x, cost_before=cost, cost_after=cost, iterations=0, converged=True,
                wall_s=time.perf_counter() - t0, cpu_s=time.process_time() - c0,
                objective_before=obj, objective_after=obj, message="nothing to optimise",
            )
        if solver is None or solver.pattern.d != 3 or solver.pattern.slots.shape[0] != ei.size:
            solver = LinearSolver(p.linear_solver, BlockPattern(ei, ej, n, int(graph.fixed)))
        pattern = solver.pattern
        data = np.zeros(pattern.nnz)
        g = np.zeros(pattern.size)
        kcode = KERNELS[kernel]
        info = np.ascontiguousarray(info)
        lam = p.initial_lambda
        nu = 2.0
        converged = False
        message = "iteration limit"
        it = 0
        solves = 0
        rejected = 0
        history = [obj]
        while it < p.max_iterations:
            it += 1
            assemble_normal_equations(x, ei, ej, z, info, pattern.slots, pattern.gslots, kcode, delta, data, g)
            diag = data[pattern.diag_slot]
            if p.damping == "diagonal":
                # Marquardt scaling; the small absolute term keeps nodes without constraints solvable
                damp_base = np.maximum(diag, 1e-9 * max(float(diag.max()), 1.0))
            else:
                damp_base = np.ones_like(diag)
            accepted = False
            while lam <= p.max_lambda:
                solves += 1
                try:
                    d = solver.solve(data, lam * damp_base, -g)
                except np.linalg.LinAlgError:
                    lam, nu = max(lam, _MIN_LAMBDA) * nu, 2.0 * nu
                    continue
                if not np.all(np.isfinite(d)):
                    lam, nu = max(lam, _MIN_LAMBDA) * nu, 2.0 * nu
                    continue
                dx = pattern.expand(d)
                x_new = se2.compose(x, dx)
                obj_new, cost_new = objective(x_new)
                # decrease the quadratic model predicts, -(2 g.d + d^T H d), with (H + lambda D) d = -g
                predicted = -float(g @ d) + lam * float(damp_base @ (d * d))
                if np.isfinite(obj_new) and obj_new <= obj:
                    accepted = True
                    break
                rejected += 1
                lam, nu = max(lam, _MIN_LAMBDA) * nu, 2.0 * nu
            if not accepted:
                converged = True  # no descent direction at any damping: a (local) minimum
                message = "no further decrease at any damping"
                break
            decrease = obj - obj_new
            # Nielsen's damping update from the gain ratio (actual / predicted decrease)
            rho = decrease / predicted if predicted > 0 else 0.0
            lam = max(lam * max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3), _MIN_LAMBDA)
            nu = 2.0
            x, obj, cost = x_new, obj_new, cost_new
            history.append(obj)
            step = float(np.abs(dx).max())
            if decrease <= p.relative_tolerance * max(obj + decrease, 1e-300) or step < p.step_tolerance:
                converged = True
                message = "converged"
                break
        return OptimizationResult(
            poses=x, cost_before=cost0, cost_after=cost, iterations=it, converged=converged,
            wall_s=time.perf_counter() - t0, cpu_s=time.process_time() - c0,
            objective_before=obj0, objective_after=obj, message=message,
            extra={"objective_history": history, "linear_solves": solves, "rejected_steps": rejected, "final_lambda": lam, "linear_solver": solver.kind},
        )
