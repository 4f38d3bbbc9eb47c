"""Sparse normal equations of a pose graph, assembled with whole-array numpy.

The sparsity pattern (which 3x3 blocks are non-zero) is fixed for a graph, so
it is computed once: every edge contributes the four blocks ii, ij, ji, jj;
their 36 entries are mapped once to positions in a CSC matrix, and each
Levenberg-Marquardt iteration only refills the values with ``np.bincount``.
The gauge node is removed from the unknowns (its columns and rows dropped).
"""

from __future__ import annotations

import numba
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from numpy.typing import NDArray

__all__ = ["BlockPattern", "LinearSolver", "SOLVERS", "cholmod_available", "node_ordering", "assemble_normal_equations"]


def cholmod_available() -> bool:
    try:
        import sksparse.cholmod  # noqa: F401
    except Exception:
        return False
    return True


def node_ordering(ei: NDArray, ej: NDArray, n: int, fixed: int) -> NDArray[np.int64]:
    """Elimination rank of every node (-1 for ``fixed``) from a minimum-degree ordering of the node graph.

    Ordering the N-node graph instead of the 3N-variable matrix is ~27x cheaper
    and as good, since every node is a dense 3x3 block. SuperLU's multiple
    minimum degree on A + A^T is used through a factorisation of the graph
    Laplacian (diagonally dominant, so it never pivots off the diagonal), incomplete so the factors stay small.
    """
    others = np.flatnonzero(np.arange(n) != fixed)
    m = n - 1
    if m <= 2:
        rank = np.full(n, -1, dtype=np.int64)
        rank[others] = np.arange(m)
        return rank
    red = np.full(n, -1, dtype=np.int64)
    red[others] = np.arange(m)
    keep = (ei != fixed) & (ej != fixed)
    a, b = red[ei[keep]], red[ej[keep]]
    adj = sp.coo_matrix((np.ones(2 * a.size), (np.r_[a, b], np.r_[b, a])), shape=(m, m)).tocsc()
    deg = np.asarray(adj.sum(axis=0)).ravel()
    lap = (sp.diags(deg + 1.0) - 0.5 * adj).tocsc()
    # Only the order is wanted: an incomplete factorization that drops every fill-in computes the same column
    # order (SuperLU orders and postorders from the pattern alone) without holding the complete factors, which
    # grew with the loop edges to 57 MB on intel driven 8 times (benchmarks/memory.py --times 8).
    lu = spla.spilu(lap, drop_tol=1e300, fill_factor=1.0, permc_spec="MMD_AT_PLUS_A", options={"SymmetricMode": True})
    rank = np.full(n, -1, dtype=np.int64)
    rank[others] = lu.perm_c.astype(np.int64)  # perm_c[k]: elimination position of node k
    return rank


class BlockPattern:
    """CSC layout of ``J^T Omega J`` for edges ``(ei, ej)`` over ``n`` nodes of dimension ``d``, node ``fixed`` removed.

    Built at node level (unique node pairs, then each pair expanded to a dense
    ``d x d`` block), so the work is over node pairs rather than scalar entries.
    ``slots[k, b, p, q]`` is where entry ``(p, q)`` of edge ``k``'s block ``b``
    (ii, ij, ji, jj) goes in ``data`` (-1 for the gauge node), ``gslots[k, b, p]``
    where its gradient part goes.
    """

    def __init__(self, ei: NDArray, ej: NDArray, n: int, fixed: int, d: int = 3, rank: NDArray | None = None) -> None:
        self.n = n
        self.d = d
        self.fixed = fixed
        # elimination rank of every node (-1 for the gauge node): the reduced system is
        # numbered in a fill-reducing order so no permutation is needed later. A caller
        # with several patterns over the same edges (LAGO) passes the one ordering in.
        rank = node_ordering(ei, ej, n, fixed) if rank is None else np.asarray(rank, dtype=np.int64)
        self.rank = rank
        self.base = np.where(rank >= 0, rank * d, -1)
        m = n - 1
        self.size = m * d
        ri, rj = rank[ei], rank[ej]
        ok = (ri >= 0) & (rj >= 0)
        # node-level pattern: every edge's (i, j) and (j, i) plus every diagonal, unique, column-major
        nodes = np.arange(m, dtype=np.int64)
        keys = np.concatenate([rj[ok] * m + ri[ok], ri[ok] * m + rj[ok], nodes * m + nodes])
        ukeys = np.unique(keys)
        ucol = ukeys // m
        deg = np.bincount(ucol, minlength=m)
        nodeptr = np.zeros(m + 1, dtype=np.int64)
        np.cumsum(deg, out=nodeptr[1:])
        pos = np.arange(ukeys.size, dtype=np.int64) - nodeptr[ucol]  # place of the row node in its column
        urow = ukeys % m
        # scalar CSC: column c*d+q holds, for each row node r of node column c, rows r*d .. r*d+d-1
        colstart = (d * d * nodeptr[:-1])[:, None] + (np.arange(d) * d)[None, :] * deg[:, None]  # (m, d)
        indptr = np.zeros(self.size + 1, dtype=np.int64)
        indptr[:-1] = colstart.ravel()
        indptr[-1] = d * d * nodeptr[-1]
        self.indptr = indptr.astype(np.int32)
        self.nnz = int(indptr[-1])
        indices = np.empty(self.nnz, dtype=np.int64)
        # entry (p, q) of node pair number u sits at colstart[col, q] + d*pos + p
        p_ = np.arange(d)
        slot_of_pair = colstart[ucol][:, None, :] + (d * pos)[:, None, None] + p_[None, :, None]  # (U, d(p), d(q))
        indices[slot_of_pair.ravel()] = (urow[:, None, None] * d + p_[None, :, None] + 0 * p_[None, None, :]).ravel()
        self.indices = indices.astype(np.int32)
        # node-level CSC for the block Cholesky: rows of node column c and the slots of each block
        self.node_colptr = nodeptr
        self.node_rows = urow
        self.pair_slots = np.ascontiguousarray(slot_of_pair)
        diag_pairs = np.searchsorted(ukeys, nodes * m + nodes)
        self.diag_slot = slot_of_pair[diag_pairs][:, p_, p_].ravel() if m else np.zeros(0, dtype=np.int64)
        # diag_slot is in node order; the scalar diagonal index of slot k is (node*d + p)
        # edge blocks ii, ij, ji, jj -> pair numbers (row node, column node)
        rows_node = np.stack([ri, ri, rj, rj], axis=1)
        cols_node = np.stack([ri, rj, ri, rj], axis=1)
        valid = (rows_node >= 0) & (cols_node >= 0)
        pk = np.searchsorted(ukeys, np.where(valid, cols_node * m + rows_node, 0))
        slots = slot_of_pair[pk]  # (M, 4, d, d)
        slots[~valid] = -1
        self.slots = slots
        gs = self.base[np.stack([ei, ej], axis=1)][:, :, None] + p_[None, None, :]
        gs[np.broadcast_to((self.base[np.stack([ei, ej], axis=1)] < 0)[:, :, None], gs.shape)] = -1
        self.gslots = gs

    def _csc(self, data: NDArray) -> sp.csc_matrix:
        return sp.csc_matrix((data, self.indices, self.indptr), shape=(self.size, self.size))

    def values(self, blocks: NDArray) -> NDArray[np.float64]:
        """``blocks`` ``(M, 4, d, d)`` (ii, ij, ji, jj) -> the summed CSC values."""
        keep = self.slots.ravel() >= 0
        return np.bincount(self.slots.ravel()[keep], weights=blocks.ravel()[keep], minlength=self.nnz)

    def matrix(self, blocks: NDArray) -> sp.csc_matrix:
        """``blocks`` ``(M, 4, d, d)`` (ii, ij, ji, jj) -> the summed sparse matrix."""
        return self._csc(self.values(blocks))

    def vector(self, parts: NDArray) -> NDArray[np.float64]:
        """``parts`` ``(M, 2, d)`` (contributions to node i, node j) -> the summed vector."""
        keep = self.gslots.ravel() >= 0
        return np.bincount(self.gslots.ravel()[keep], weights=parts.ravel()[keep], minlength=self.size)

    def expand(self, reduced: NDArray) -> NDArray[np.float64]:
        """Reduced solution -> ``(n, d)`` with zeros at the gauge node."""
        out = np.zeros((self.n, self.d))
        mask = self.base >= 0
        out[mask] = reduced.reshape(-1, self.d)[self.rank[mask]]
        return out


SOLVERS = ("auto", "block", "splu", "cholmod")


class LinearSolver:
    """Solve ``(H + diag(diag_add)) x = b`` for matrices with one :class:`BlockPattern`.

    ``block``: the compiled block Cholesky (:mod:`slam2d.backends.cholesky`),
    symbolic analysis once, the default. ``splu``: scipy's SuperLU without
    pivoting or reordering (the matrix is symmetric positive definite and
    already in fill-reducing order). ``cholmod``: scikit-sparse's supernodal
    Cholesky when installed. A matrix that is not positive definite raises
    ``numpy.linalg.LinAlgError``.
    """

    def __init__(self, kind: str, pattern: BlockPattern) -> None:
        if kind == "auto":
            kind = "block"
        if kind == "cholmod" and not cholmod_available():
            from slam2d.errors import InputError

            raise InputError("linear_solver 'cholmod' needs scikit-sparse (pip install scikit-sparse)", field="linear_solver")
        if kind not in SOLVERS:
            raise ValueError(kind)
        self.kind = kind
        self.pattern = pattern
        self._symbolic = None
        self._block = None
        if kind == "block":
            from slam2d.backends.cholesky import BlockCholesky

            self._block = BlockCholesky(pattern)

    def solve(self, data: NDArray, diag_add: NDArray, b: NDArray) -> NDArray[np.float64]:
        if self._block is not None:
            if not self._block.factor(data, diag_add):
                raise np.linalg.LinAlgError("matrix is not positive definite")
            return self._block.solve(b)
        values = data.copy()
        values[self.pattern.diag_slot] += diag_add
        A = self.pattern._csc(values)
        if self.kind == "cholmod":
            from sksparse.cholmod import CholmodNotPositiveDefiniteError, analyze

            if self._symbolic is None:
                self._symbolic = analyze(A, mode="supernodal")
            try:
                f = self._symbolic.cholesky(A)
            except CholmodNotPositiveDefiniteError as exc:
                raise np.linalg.LinAlgError(str(exc)) from None
            return f(b)
        try:
            lu = spla.splu(A, permc_spec="NATURAL", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
        except RuntimeError as exc:  # "Factor is exactly singular"
            raise np.linalg.LinAlgError(str(exc)) from None
        return lu.solve(b)


KERNELS = {"none": 0, "huber": 1, "cauchy": 2}


@numba.njit(cache=True)
def assemble_normal_equations(poses, ei, ej, z, info, slots, gslots, kernel, delta, data, grad):  # pragma: no cover - numba
    """Fill ``data`` (CSC values of ``H = J^T W J``) and ``grad`` (``J^T W e``) for all edges.

    Same errors and local Jacobians as :func:`slam2d.backends.graph.edge_jacobians`;
    ``W`` is the edge information scaled by the robust weight ``rho'(e^T Omega e)``
    (``kernel`` 0 none, 1 Huber, 2 Cauchy, width ``delta``). Returns the summed
    quadratic cost ``sum e^T Omega e`` and the robust objective ``sum rho``.
    """
    data[:] = 0.0
    grad[:] = 0.0
    two_pi = 2.0 * np.pi
    cost = 0.0
    objective = 0.0
    A = np.zeros((3, 3))
    B = np.zeros((3, 3))
    e = np.zeros(3)
    W = np.zeros((3, 3))
    WA = np.zeros((3, 3))
    WB = np.zeros((3, 3))
    We = np.zeros(3)
    for k in range(ei.shape[0]):
        i = ei[k]
        j = ej[k]
        ci = np.cos(poses[i, 2])
        si = np.sin(poses[i, 2])
        dx = poses[j, 0] - poses[i, 0]
        dy = poses[j, 1] - poses[i, 1]
        d0 = ci * dx + si * dy
        d1 = -si * dx + ci * dy
        cz = np.cos(z[k, 2])
        sz = np.sin(z[k, 2])
        u0 = d0 - z[k, 0]
        u1 = d1 - z[k, 1]
        e[0] = cz * u0 + sz * u1
        e[1] = -sz * u0 + cz * u1
        a = poses[j, 2] - poses[i, 2] - z[k, 2]
        e[2] = (a + np.pi) % two_pi - np.pi
        chi2 = 0.0
        for p in range(3):
            for q in range(3):
                chi2 += e[p] * info[k, p, q] * e[q]
        w = 1.0
        if kernel == 1:
            if chi2 <= delta * delta:
                objective += chi2
            else:
                r = np.sqrt(chi2)
                objective += 2.0 * delta * r - delta * delta
                w = delta / r
        elif kernel == 2:
            c2 = delta * delta
            objective += c2 * np.log1p(chi2 / c2)
            w = 1.0 / (1.0 + chi2 / c2)
        else:
            objective += chi2
        cost += chi2
        A[0, 0] = -cz
        A[0, 1] = -sz
        A[1, 0] = sz
        A[1, 1] = -cz
        A[0, 2] = cz * d1 - sz * d0
        A[1, 2] = -sz * d1 - cz * d0
        A[2, 2] = -1.0
        ce = np.cos(e[2])
        se = np.sin(e[2])
        B[0, 0] = ce
        B[0, 1] = -se
        B[1, 0] = se
        B[1, 1] = ce
        B[2, 2] = 1.0
        for p in range(3):
            for q in range(3):
                W[p, q] = w * info[k, p, q]
        for p in range(3):
            We[p] = W[p, 0] * e[0] + W[p, 1] * e[1] + W[p, 2] * e[2]
            for q in range(3):
                WA[p, q] = W[p, 0] * A[0, q] + W[p, 1] * A[1, q] + W[p, 2] * A[2, q]
                WB[p, q] = W[p, 0] * B[0, q] + W[p, 1] * B[1, q] + W[p, 2] * B[2, q]
        # blocks ii, ij, ji, jj = A^T W A, A^T W B, B^T W A, B^T W B
        for b in range(4):
            left = A if b < 2 else B
            right = WA if b % 2 == 0 else WB
            for p in range(3):
                for q in range(3):
                    s = slots[k, b, p, q]
                    if s >= 0:
                        data[s] += left[0, p] * right[0, q] + left[1, p] * right[1, q] + left[2, p] * right[2, q]
        for p in range(3):
            s = gslots[k, 0, p]
            if s >= 0:
                grad[s] += A[0, p] * We[0] + A[1, p] * We[1] + A[2, p] * We[2]
            s = gslots[k, 1, p]
            if s >= 0:
                grad[s] += B[0, p] * We[0] + B[1, p] * We[1] + B[2, p] * We[2]
    return cost, objective
