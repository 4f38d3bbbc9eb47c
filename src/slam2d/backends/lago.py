"""LAGO: the linear approximation for pose-graph optimisation (Carlone, Aragues, Castellanos, Bona 2012).

Needs no initial guess. Three linear steps:

1. **Orientations.** A breadth-first spanning tree from the fixed node gives
   every node a heading by chaining relative rotations (no wrapping). Each
   edge's measured rotation ``delta_ij`` is regularised by ``2 pi k_ij`` with
   ``k_ij = round((theta_j^tree - theta_i^tree - delta_ij) / 2 pi)`` (tree edges
   get ``k = 0``), which makes the orientation problem linear:
   ``min sum w_ij (theta_j - theta_i - delta_ij^reg)^2``, ``w_ij`` the inverse
   marginal rotation variance of the edge. One sparse solve gives ``theta_hat``
   and its information ``A^T W A``.
2. **Positions and refined headings.** Each edge's translation, rotated into
   the world by ``theta_hat_i``, is linear in the positions; the rotation is
   linearised at ``theta_hat`` and ``theta_hat`` enters as a measurement with the
   information of step 1 (the information form of the paper's stacked
   ``z = [Delta^g; theta_hat]`` with its propagated covariance, which avoids the
   dense ``P_theta``). One sparse solve gives all positions and headings.
3. **Optional Gauss-Newton refinement** of the full non-linear cost, as the
   paper suggests (``refine_iterations``, default 1).

The result is in the frame of the fixed node, which keeps its current pose.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import ClassVar

import numba
import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.sparse.csgraph import breadth_first_order

from slam2d.backends.base import Backend, OptimizationResult
from slam2d.backends.graph import PoseGraph
from slam2d.backends.linear import SOLVERS, BlockPattern, LinearSolver, node_ordering
from slam2d.backends.spa import SpaBackend, SpaParams
from slam2d.core import se2
from slam2d.errors import InputError
from slam2d.params import param

__all__ = ["LagoParams", "LagoBackend", "lago_orientations"]

TWO_PI = 2.0 * np.pi


@dataclass
class LagoParams:
    refine_iterations: int = param(
        1, low=0, help="Gauss-Newton iterations of the full cost after the linear estimate (the paper's optional step; 0 = pure LAGO)"
    )
    linear_solver: str = param(
        "auto", choices=SOLVERS,
        help="sparse solver: block (compiled block Cholesky; auto), splu (scipy SuperLU) or cholmod (needs scikit-sparse)",
    )


@numba.njit(cache=True)
def _propagate_tree(order: NDArray, pred: NDArray, tree_edge: NDArray, sign: NDArray, delta: NDArray, theta: NDArray) -> None:
    # nodes in breadth-first order: each one's parent is already done
    for k in range(1, order.shape[0]):
        v = order[k]
        theta[v] = theta[pred[v]] + sign[v] * delta[tree_edge[v]]


def _edge_marginals(info: NDArray) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Rotation weights ``1/Sigma_thth`` ``(M,)`` and translation information ``inv(Sigma_tt)`` ``(M, 2, 2)``.

    Both are Schur complements of the information matrix, in closed form for the
    whole array; an edge whose information is singular (a direction it does not
    measure) goes through the pseudo-inverse of its covariance instead.
    """
    info = np.asarray(info, dtype=np.float64)
    i_tt = info[:, :2, :2]
    i_ta = info[:, :2, 2]
    i_aa = info[:, 2, 2]
    det = i_tt[:, 0, 0] * i_tt[:, 1, 1] - i_tt[:, 0, 1] * i_tt[:, 1, 0]
    scale = np.maximum(np.abs(info).max(axis=(1, 2)), 1e-300)
    ok = (i_aa > 1e-9 * scale) & (det > 1e-9 * scale * scale)
    safe_det = np.where(ok, det, 1.0)
    safe_aa = np.where(ok, i_aa, 1.0)
    # i_ta^T i_tt^-1 i_ta with the 2x2 inverse written out
    quad = (i_tt[:, 1, 1] * i_ta[:, 0] ** 2 - (i_tt[:, 0, 1] + i_tt[:, 1, 0]) * i_ta[:, 0] * i_ta[:, 1]
            + i_tt[:, 0, 0] * i_ta[:, 1] ** 2) / safe_det
    w_th = i_aa - quad
    info_t = i_tt - i_ta[:, :, None] * i_ta[:, None, :] / safe_aa[:, None, None]
    ok &= w_th > 1e-9 * scale
    bad = np.flatnonzero(~ok)
    if bad.size:
        cov = np.linalg.pinv(info[bad], hermitian=True)
        var_th = cov[:, 2, 2]
        w_th[bad] = np.where(var_th > 0, 1.0 / np.where(var_th > 0, var_th, 1.0), 0.0)
        info_t[bad] = np.linalg.pinv(cov[:, :2, :2], hermitian=True)
    return w_th, info_t


def lago_orientations(graph: PoseGraph, linear_solver: str = "auto", *, rank: NDArray | None = None,
                      w_th: NDArray | None = None) -> tuple[NDArray, NDArray]:
    """Step 1: headings relative to the fixed node (not wrapped) and the regularised edge rotations.

    ``rank`` (the node elimination order) and ``w_th`` (the edge rotation weights)
    may be passed in when the caller has them already.
    """
    n = graph.num_nodes
    fixed = int(graph.fixed)
    ei, ej, z = graph.edge_i, graph.edge_j, graph.measurements
    m = ei.size
    adj = sp.coo_matrix((np.ones(m), (ei, ej)), shape=(n, n)).tocsr()
    order, pred = breadth_first_order(adj, fixed, directed=False, return_predecessors=True)
    if order.size != n:
        raise InputError(
            f"pose graph is not connected: {n - order.size} of {n} nodes cannot be reached from node {fixed}",
            field="graph",
        )
    # the edge joining each node to its tree parent, found by sorted (min, max) keys
    lo, hi = np.minimum(ei, ej), np.maximum(ei, ej)
    keys = lo * n + hi
    srt = np.argsort(keys, kind="stable")
    child = order[1:]
    parent = pred[child]
    q = np.minimum(parent, child) * n + np.maximum(parent, child)
    tree_edge = np.zeros(n, dtype=np.int64)
    tree_edge[child] = srt[np.searchsorted(keys[srt], q)]
    sign = np.zeros(n)
    sign[child] = np.where(ei[tree_edge[child]] == parent, 1.0, -1.0)
    theta_tree = np.zeros(n)
    _propagate_tree(order.astype(np.int64), pred.astype(np.int64), tree_edge, sign, z[:, 2].copy(), theta_tree)
    delta = z[:, 2]
    k = np.round((theta_tree[ej] - theta_tree[ei] - delta) / TWO_PI)
    delta_reg = delta + TWO_PI * k
    if w_th is None:
        w_th, _ = _edge_marginals(graph.information)
    # weighted Laplacian over the headings (1x1 blocks), fixed node removed
    pat = BlockPattern(ei, ej, n, fixed, d=1, rank=rank)
    blocks = np.stack([w_th, -w_th, -w_th, w_th], axis=1)[:, :, None, None]
    values = pat.values(blocks)
    rhs = pat.vector(np.stack([-w_th * delta_reg, w_th * delta_reg], axis=1)[:, :, None])
    tiny = np.full(pat.size, 1e-12 * max(float(values[pat.diag_slot].max()), 1.0))
    theta = pat.expand(LinearSolver(linear_solver, pat).solve(values, tiny, rhs))[:, 0]
    return theta, delta_reg


class LagoBackend(Backend):
    name: ClassVar[str] = "lago"
    needs_initial_guess: ClassVar[bool] = False

    def __init__(self, params: LagoParams | None = None) -> None:
        self.params = params or LagoParams()

    def optimize(self, graph: PoseGraph) -> OptimizationResult:
        """Estimate all poses from the edges alone; the graph's poses are only used for the fixed node and ``cost_before``."""
        t0, c0 = time.perf_counter(), time.process_time()
        graph.check_fixed()
        n = graph.num_nodes
        cost0 = graph.cost() if graph.num_edges else 0.0
        if n < 2 or graph.num_edges == 0:
            if n >= 2:
                raise InputError(f"pose graph has {n} nodes and no edges: LAGO cannot place them", field="graph")
            x = np.array(graph.poses)
            return OptimizationResult(x, cost0, cost0, 0, True, time.perf_counter() - t0, time.process_time() - c0,
                                      cost0, cost0, "nothing to optimise")
        fixed = int(graph.fixed)
        ei, ej, z = graph.edge_i, graph.edge_j, graph.measurements
        # One node ordering and one set of edge marginals serve both linear steps and the
        # refinement (which also reuses step 2's factorisation pattern).
        w_th, info_t = _edge_marginals(graph.information)
        rank = node_ordering(ei, ej, n, fixed)
        theta_hat, _ = lago_orientations(graph, self.params.linear_solver, rank=rank, w_th=w_th)

        # step 2: unknowns (x, y, theta) per node, linear in x, y and in theta about theta_hat
        c, s = np.cos(theta_hat[ei]), np.sin(theta_hat[ei])
        m = ei.size
        Rt = np.zeros((m, 2, 2))
        Rt[:, 0, 0], Rt[:, 0, 1], Rt[:, 1, 0], Rt[:, 1, 1] = c, -s, s, c
        zg = np.einsum("kab,kb->ka", Rt, z[:, :2])  # translation in the world frame
        dzg = np.stack([-zg[:, 1], zg[:, 0]], axis=1)  # d(R(theta) z_t)/d theta
        info_g = Rt @ info_t @ np.swapaxes(Rt, 1, 2)  # translation information in the world frame
        # residual r_t = p_j - p_i - zg - dzg (theta_i - theta_hat_i): Jacobians over (x, y, theta)
        Ja = np.zeros((m, 2, 3))
        Ja[:, 0, 0] = Ja[:, 1, 1] = -1.0
        Ja[:, :, 2] = -dzg
        Jb = np.zeros((m, 2, 3))
        Jb[:, 0, 0] = Jb[:, 1, 1] = 1.0
        # constant part of the residual at (p, theta) = 0: -zg + dzg theta_hat_i
        r0 = -zg + dzg * theta_hat[ei][:, None]
        WJa, WJb = info_g @ Ja, info_g @ Jb
        Jat, Jbt = np.swapaxes(Ja, 1, 2), np.swapaxes(Jb, 1, 2)
        blocks = np.stack([Jat @ WJa, Jat @ WJb, Jbt @ WJa, Jbt @ WJb], axis=1)
        Wr = np.einsum("kab,kb->ka", info_g, r0)
        # heading prior (theta - theta_hat)^T L_theta (theta - theta_hat), written per edge
        blocks[:, 0, 2, 2] += w_th
        blocks[:, 1, 2, 2] -= w_th
        blocks[:, 2, 2, 2] -= w_th
        blocks[:, 3, 2, 2] += w_th
        dth = theta_hat[ej] - theta_hat[ei]
        gi = np.einsum("kab,ka->kb", Ja, Wr)
        gj = np.einsum("kab,ka->kb", Jb, Wr)
        gi[:, 2] += w_th * dth  # d/dtheta_i of w (theta_j - theta_i - dth)^2 / 2 at zero
        gj[:, 2] -= w_th * dth
        pat = BlockPattern(ei, ej, n, fixed, rank=rank)
        values = pat.values(blocks)
        g = pat.vector(np.stack([gi, gj], axis=1))
        tiny = np.full(pat.size, 1e-12 * max(float(values[pat.diag_slot].max()), 1.0))
        # frame of the fixed node, which sits at the origin
        solver = LinearSolver(self.params.linear_solver, pat)
        local = pat.expand(solver.solve(values, tiny, -g))
        anchor = graph.poses[fixed]
        x = se2.compose(anchor, local)
        iterations = 2
        message = "linear estimate"
        converged = True
        if self.params.refine_iterations > 0:
            spa = SpaBackend(SpaParams(max_iterations=self.params.refine_iterations, initial_lambda=0.0,
                                       linear_solver=self.params.linear_solver))
            ref = spa.optimize(graph, poses=x, solver=solver)
            x = ref.poses
            iterations += ref.iterations
            message = f"linear estimate + {ref.iterations} Gauss-Newton step(s)"
        cost = graph.cost(x)
        return OptimizationResult(
            poses=x, cost_before=cost0, cost_after=cost, iterations=iterations, converged=converged,
            wall_s=time.perf_counter() - t0, cpu_s=time.process_time() - c0,
            objective_before=cost0, objective_after=cost, message=message,
        )
