"""The pose graph: nodes are poses, edges are relative-pose measurements with an information matrix.

Data lives in growing numpy arrays (amortised doubling), never in per-edge
Python objects, so a back end builds its sparse system with whole-array code.

Conventions (every back end follows them):

* a node is a world-frame pose ``[x, y, theta]``;
* an edge ``(i, j, z, Omega)`` says "node ``j`` seen from node ``i`` is ``z``",
  i.e. ``z`` is the measured ``slam2d.core.se2.relative(x_i, x_j)``; ``Omega`` is
  the 3x3 information matrix over ``(x, y, theta)`` of ``z``;
* the error of an edge is ``e = t2v(Z^-1 X_i^-1 X_j)`` with its angle wrapped to
  ``[-pi, pi)`` (``e = relative(z, relative(x_i, x_j))``);
* the cost of the graph is ``sum_k e_k^T Omega_k e_k`` (no factor 1/2), the
  chi-square of g2o;
* node ``fixed`` (default 0) is the gauge: optimisers do not move it.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from slam2d.core import se2
from slam2d.core.arrays import grown
from slam2d.errors import InputError

__all__ = ["PoseGraph", "edge_errors", "edge_jacobians", "graph_cost"]


def _plainly_valid(i, j, n: int, z: NDArray[np.float64], info: NDArray[np.float64]) -> bool:
    """Whether one edge passes every check of :meth:`PoseGraph.add_edges` by a margin (False: let it decide).

    Integer node indices in range and distinct, finite values, a symmetric information matrix
    and a positive definite one (leading minors well above rounding: then its eigenvalues are
    too, and the semi-definite test passes).
    """
    if not (isinstance(i, (int, np.integer)) and isinstance(j, (int, np.integer))) or isinstance(i, bool) or isinstance(j, bool):
        return False
    if not (0 <= i < n and 0 <= j < n and i != j):
        return False
    (a, b, c), (b2, d, e), (c2, e2, f) = info.tolist()
    vals = z.tolist() + [a, b, c, b2, d, e, c2, e2, f]
    if not all(math.isfinite(v) for v in vals):
        return False
    for u, v in ((b, b2), (c, c2), (e, e2)):
        if abs(u - v) > 1e-9 * (1.0 + abs(u)) or abs(v - u) > 1e-9 * (1.0 + abs(v)):
            return False
    top = max(abs(v) for v in vals[3:])
    minor2 = a * d - b * b
    det = a * (d * f - e * e) - b * (b * f - e * c) + c * (b * e - d * c)
    return a > 1e-12 * top and minor2 > 1e-12 * top * top and det > 1e-12 * top * top * top


class PoseGraph:
    """A 2D pose graph stored in growing numpy arrays.

    ``poses`` is a live ``(N, 3)`` view; assign ``g.poses = new`` to replace
    all node poses at once (shape must match). Edges are read through
    ``edge_i``, ``edge_j``, ``measurements`` ``(M, 3)`` and ``information``
    ``(M, 3, 3)``.
    """

    def __init__(self) -> None:
        self._poses = np.zeros((0, 3))
        self._n = 0
        self._ei = np.zeros(0, dtype=np.int64)
        self._ej = np.zeros(0, dtype=np.int64)
        self._z = np.zeros((0, 3))
        self._info = np.zeros((0, 3, 3))
        self._m = 0
        self.fixed = 0

    # ----------------------------------------------------------------- nodes
    @property
    def num_nodes(self) -> int:
        return self._n

    def __len__(self) -> int:
        return self._n

    @property
    def poses(self) -> NDArray[np.float64]:
        return self._poses[: self._n]

    @poses.setter
    def poses(self, value: ArrayLike) -> None:
        arr = np.asarray(value, dtype=np.float64)
        if arr.shape != (self._n, 3):
            raise InputError(f"expected poses of shape ({self._n}, 3), got {arr.shape}", field="poses")
        if not np.all(np.isfinite(arr)):
            raise InputError("poses must be finite", field="poses")
        self._poses[: self._n] = arr
        self._poses[: self._n, 2] = se2.wrap_angle(arr[:, 2])

    def add_node(self, pose: ArrayLike) -> int:
        """Append a node at world pose ``[x, y, theta]``; returns its index."""
        one = se2._one(pose)
        if one is not None and all(map(math.isfinite, one)):
            # One finite float64 pose (a front end's case): add_nodes' writes, its wrap on a float (same arithmetic).
            n = self._n
            self._poses = grown(self._poses, n + 1, minimum=16)
            self._poses[n] = pose
            self._poses[n, 2] = se2.wrap_scalar(one[2])
            self._n = n + 1
            return n
        return int(self.add_nodes(np.asarray(pose, dtype=np.float64).reshape(1, 3))[0])

    def add_nodes(self, poses: ArrayLike) -> NDArray[np.int64]:
        """Append many nodes ``(K, 3)`` at once; returns their indices."""
        arr = np.asarray(poses, dtype=np.float64)
        if arr.ndim != 2 or arr.shape[1] != 3:
            raise InputError(f"a node pose has 3 components (x, y, theta); got shape {arr.shape}", field="pose")
        if not np.all(np.isfinite(arr)):
            raise InputError("node pose must be finite", field="pose")
        k = arr.shape[0]
        self._poses = grown(self._poses, self._n + k, minimum=16)
        self._poses[self._n : self._n + k] = arr
        self._poses[self._n : self._n + k, 2] = se2.wrap_angle(arr[:, 2])
        idx = np.arange(self._n, self._n + k, dtype=np.int64)
        self._n += k
        return idx

    # ----------------------------------------------------------------- edges
    @property
    def num_edges(self) -> int:
        return self._m

    @property
    def edge_i(self) -> NDArray[np.int64]:
        return self._ei[: self._m]

    @property
    def edge_j(self) -> NDArray[np.int64]:
        return self._ej[: self._m]

    @property
    def measurements(self) -> NDArray[np.float64]:
        return self._z[: self._m]

    @property
    def information(self) -> NDArray[np.float64]:
        return self._info[: self._m]

    def add_edge(self, i: int, j: int, measurement: ArrayLike, information: ArrayLike) -> int:
        """Add the measurement ``relative(x_i, x_j) ~ measurement`` with 3x3 ``information``; returns the edge index."""
        info = np.asarray(information, dtype=np.float64)
        if info.shape != (3, 3):
            raise InputError(f"information must be 3x3, got shape {info.shape}", field="information")
        z = np.asarray(measurement, dtype=np.float64)
        if z.shape != (3,):
            raise InputError(f"measurement has 3 components (x, y, theta); got shape {z.shape}", field="measurement")
        if _plainly_valid(i, j, self._n, z, info):
            # A front end adds its edges one at a time: the checks add_edges makes, on Python floats.
            m = self._m
            self._ei = grown(self._ei, m + 1, minimum=16)
            self._ej = grown(self._ej, m + 1, minimum=16)
            self._z = grown(self._z, m + 1, minimum=16)
            self._info = grown(self._info, m + 1, minimum=16)
            self._ei[m] = i
            self._ej[m] = j
            self._z[m] = z
            self._z[m, 2] = se2.wrap_scalar(float(z[2]))  # wrap_angle's arithmetic on a float
            self._info[m] = info
            self._m += 1
            return m
        return int(self.add_edges([i], [j], z[None], info[None])[0])

    def add_edges(
        self, i: ArrayLike, j: ArrayLike, measurements: ArrayLike, information: ArrayLike
    ) -> NDArray[np.int64]:
        """Add many edges at once: ``i``, ``j`` ``(K,)``, measurements ``(K, 3)``, information ``(K, 3, 3)`` or ``(3, 3)``."""
        ii = np.atleast_1d(np.asarray(i))
        jj = np.atleast_1d(np.asarray(j))
        z = np.asarray(measurements, dtype=np.float64).reshape(-1, 3)
        info = np.asarray(information, dtype=np.float64)
        k = z.shape[0]
        if info.shape == (3, 3):
            info = np.broadcast_to(info, (k, 3, 3))
        if ii.shape != (k,) or jj.shape != (k,) or info.shape != (k, 3, 3):
            raise InputError(
                f"edge arrays disagree: i {ii.shape}, j {jj.shape}, measurements {z.shape}, information {info.shape}",
                field="edge",
            )
        if k and not (np.issubdtype(ii.dtype, np.integer) and np.issubdtype(jj.dtype, np.integer)):
            raise InputError("edge node indices must be integers", field="edge")
        ii = ii.astype(np.int64)
        jj = jj.astype(np.int64)
        bad = (ii < 0) | (ii >= self._n) | (jj < 0) | (jj >= self._n)
        if np.any(bad):
            b = int(np.argmax(bad))
            raise InputError(
                f"edge ({ii[b]}, {jj[b]}) refers to a node that does not exist (graph has {self._n} nodes)",
                field="edge",
            )
        if np.any(ii == jj):
            b = int(np.argmax(ii == jj))
            raise InputError(f"edge ({ii[b]}, {jj[b]}) connects a node to itself", field="edge")
        if not (np.all(np.isfinite(z)) and np.all(np.isfinite(info))):
            raise InputError("edge measurement and information must be finite", field="edge")
        if np.any(np.abs(info - np.swapaxes(info, 1, 2)) > 1e-9 * (1.0 + np.abs(info))):
            raise InputError("information matrix must be symmetric", field="information")
        if k and np.any(np.linalg.eigvalsh(info)[:, 0] < -1e-9 * np.abs(info).max(axis=(1, 2))):
            raise InputError("information matrix must be positive semi-definite", field="information")
        m = self._m
        self._ei = grown(self._ei, m + k, minimum=16)
        self._ej = grown(self._ej, m + k, minimum=16)
        self._z = grown(self._z, m + k, minimum=16)
        self._info = grown(self._info, m + k, minimum=16)
        self._ei[m : m + k] = ii
        self._ej[m : m + k] = jj
        self._z[m : m + k] = z
        self._z[m : m + k, 2] = se2.wrap_angle(z[:, 2])
        self._info[m : m + k] = info
        self._m += k
        return np.arange(m, m + k, dtype=np.int64)

    def truncate(self, num_nodes: int, num_edges: int) -> None:
        """Forget the nodes from ``num_nodes`` on and the edges from ``num_edges`` on (the last added).

        The edges kept must not touch a forgotten node.
        """
        if not (0 <= num_nodes <= self._n and 0 <= num_edges <= self._m):
            raise InputError(f"cannot truncate {self._n} nodes, {self._m} edges to {num_nodes}, {num_edges}")
        if num_edges and max(int(self._ei[:num_edges].max()), int(self._ej[:num_edges].max())) >= num_nodes:
            raise InputError("a kept edge touches a forgotten node")
        self._n, self._m = int(num_nodes), int(num_edges)

    # ------------------------------------------------------------- helpers
    def copy(self) -> PoseGraph:
        g = PoseGraph()
        g.add_nodes(self.poses)
        if self._m:
            g.add_edges(self.edge_i, self.edge_j, self.measurements, self.information)
        g.fixed = self.fixed
        return g

    def errors(self, poses: ArrayLike | None = None) -> NDArray[np.float64]:
        """Edge errors ``(M, 3)`` at ``poses`` (default: the graph's own)."""
        p = self.poses if poses is None else np.asarray(poses, dtype=np.float64)
        return edge_errors(p, self.edge_i, self.edge_j, self.measurements)

    def cost(self, poses: ArrayLike | None = None) -> float:
        """``sum_k e_k^T Omega_k e_k`` at ``poses`` (default: the graph's own)."""
        p = self.poses if poses is None else np.asarray(poses, dtype=np.float64)
        return graph_cost(p, self.edge_i, self.edge_j, self.measurements, self.information)

    def check_fixed(self) -> None:
        if self._n and not (0 <= int(self.fixed) < self._n):
            raise InputError(f"fixed node {self.fixed} does not exist (graph has {self._n} nodes)", field="fixed")

    def __repr__(self) -> str:
        return f"PoseGraph({self._n} nodes, {self._m} edges, fixed={self.fixed})"


def edge_errors(poses: NDArray, ei: NDArray, ej: NDArray, z: NDArray) -> NDArray[np.float64]:
    """``t2v(Z^-1 X_i^-1 X_j)`` for every edge, angle wrapped."""
    return se2.relative(z, se2.relative(poses[ei], poses[ej]))


def graph_cost(poses: NDArray, ei: NDArray, ej: NDArray, z: NDArray, info: NDArray) -> float:
    e = edge_errors(poses, ei, ej, z)
    return float(np.einsum("ki,kij,kj->", e, info, e))


def edge_jacobians(
    poses: NDArray, ei: NDArray, ej: NDArray, z: NDArray
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Errors ``(M, 3)`` and Jacobians ``A = de/d delta_i``, ``B = de/d delta_j`` ``(M, 3, 3)``.

    The perturbation of a node is local (right-multiplied): ``X <- X (+) delta``,
    i.e. ``se2.compose(x, delta)``, as GTSAM and g2o retract on SE(2). With
    ``D = X_i^-1 X_j`` and ``e = t2v(Z^-1 D)``:
    ``de_t/d delta_i = [-R_z^T | R_z^T (t_Dy, -t_Dx)]``, ``de_t/d delta_j = [R_z^T R_D | 0]``,
    ``de_theta/d delta = -1, +1``. This converges in far fewer iterations than
    adding ``delta`` to world coordinates, whose linearisation of a rotated
    sub-chain is poor.
    """
    d = se2.relative(poses[ei], poses[ej])
    e = se2.relative(z, d)
    cz, sz = np.cos(z[:, 2]), np.sin(z[:, 2])
    m = z.shape[0]
    A = np.zeros((m, 3, 3))
    A[:, 0, 0] = -cz
    A[:, 0, 1] = -sz
    A[:, 1, 0] = sz
    A[:, 1, 1] = -cz
    A[:, 0, 2] = cz * d[:, 1] - sz * d[:, 0]
    A[:, 1, 2] = -sz * d[:, 1] - cz * d[:, 0]
    A[:, 2, 2] = -1.0
    # R_z^T R_D = R(theta_D - theta_z) = R(e_theta)
    ce, se_ = np.cos(e[:, 2]), np.sin(e[:, 2])
    B = np.zeros((m, 3, 3))
    B[:, 0, 0] = ce
    B[:, 0, 1] = -se_
    B[:, 1, 0] = se_
    B[:, 1, 1] = ce
    B[:, 2, 2] = 1.0
    return e, A, B
