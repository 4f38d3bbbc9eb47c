"""Sparse normal equations of a pose graph, assembled with whole-array numpy.

The sparsity pattern (which 3x3 blocks are non-zero) is fixed for a graph, so
it is computed once: every edge contributes the four blocks ii, ij, ji, jj;
their 36 entries are mapped once to positions in a CSC matrix, and each
Levenberg-Marquardt iteration only refills the values with ``np.bincount``.
The gauge node is removed from the unknowns (its columns and rows dropped).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from numpy.typing import NDArray

__all__ = ["BlockPattern", "SparseSolver", "cholmod_available"]


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
    Laplacian (diagonally dominant, so it never pivots off the diagonal).
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
    lu = spla.splu(lap, permc_spec="MMD_AT_PLUS_A", options={"SymmetricMode": True})
    rank = np.full(n, -1, dtype=np.int64)
    rank[others] = lu.perm_c.astype(np.int64)  # perm_c[k]: elimination position of node k
    return rank


class BlockPattern:
    """CSC layout of ``J^T Omega J`` for edges ``(ei, ej)`` over ``n`` nodes of dimension ``d``, node ``fixed`` removed."""

    def __init__(self, ei: NDArray, ej: NDArray, n: int, fixed: int, d: int = 3) -> None:
        self.n = n
        self.d = d
        self.fixed = fixed
        # column of each node's first variable in the reduced system (-1 for the gauge node);
        # nodes are numbered in a fill-reducing elimination order so no permutation is needed later
        rank = node_ordering(ei, ej, n, fixed)
        base = np.full(n, -1, dtype=np.int64)
        base[rank >= 0] = rank[rank >= 0] * d
        self.base = base
        self.size = (n - 1) * d
        r = np.arange(d)
        # blocks in the order ii, ij, ji, jj; entry (a, b) of a block at flat index a*d+b
        rows_node = np.stack([ei, ei, ej, ej], axis=1)  # (M, 4)
        cols_node = np.stack([ei, ej, ei, ej], axis=1)
        rb = base[rows_node][:, :, None, None] + r[None, None, :, None]
        cb = base[cols_node][:, :, None, None] + r[None, None, None, :]
        rb, cb = np.broadcast_arrays(rb, cb)
        keep = ((base[rows_node] >= 0) & (base[cols_node] >= 0))[:, :, None, None]
        keep = np.broadcast_to(keep, rb.shape).ravel()
        rows = rb.ravel()[keep]
        cols = cb.ravel()[keep]
        # the diagonal is always present (damping, isolated nodes)
        diag = np.arange(self.size, dtype=np.int64)
        rows = np.concatenate([rows, diag])
        cols = np.concatenate([cols, diag])
        key = cols * self.size + rows  # column-major order = CSC order
        ukey, inv = np.unique(key, return_inverse=True)
        self.keep = keep
        self.slot = inv[: keep.sum()]
        self.nnz = ukey.size
        self.indices = (ukey % self.size).astype(np.int32)
        ucols = ukey // self.size
        self.indptr = np.zeros(self.size + 1, dtype=np.int32)
        np.cumsum(np.bincount(ucols, minlength=self.size), out=self.indptr[1:])
        # positions of the diagonal entries in data
        self.diag_slot = inv[-self.size :] if self.size else np.zeros(0, dtype=np.int64)
        # gradient scatter: variable index per (edge, block i/j, component)
        gi = base[np.stack([ei, ej], axis=1)][:, :, None] + r[None, None, :]
        self.gkeep = (base[np.stack([ei, ej], axis=1)] >= 0)[:, :, None].repeat(d, axis=2).ravel()
        self.gidx = gi.ravel()[self.gkeep]

    def matrix(self, blocks: NDArray) -> sp.csc_matrix:
        """``blocks`` ``(M, 4, d, d)`` (ii, ij, ji, jj) -> the summed sparse matrix."""
        data = np.bincount(self.slot, weights=blocks.ravel()[self.keep], minlength=self.nnz)
        return sp.csc_matrix((data, self.indices, self.indptr), shape=(self.size, self.size))

    def vector(self, parts: NDArray) -> NDArray[np.float64]:
        """``parts`` ``(M, 2, d)`` (contributions to node i, node j) -> the summed vector."""
        return np.bincount(self.gidx, weights=parts.ravel()[self.gkeep], minlength=self.size)

    def expand(self, reduced: NDArray) -> NDArray[np.float64]:
        """Reduced solution -> ``(n, d)`` with zeros at the gauge node."""
        out = np.zeros((self.n, self.d))
        mask = self.base >= 0
        out[mask] = reduced.reshape(-1, self.d)[self.base[mask] // self.d]
        return out


class SparseSolver:
    """Solve symmetric positive-definite sparse systems with one fixed pattern.

    ``cholmod``: scikit-sparse's supernodal Cholesky, symbolic analysis done once.
    ``splu``: scipy's SuperLU without pivoting or reordering: the matrix is
    symmetric positive definite and already in fill-reducing order
    (:func:`node_ordering`).
    """

    def __init__(self, kind: str = "auto") -> None:
        if kind == "auto":
            kind = "cholmod" if cholmod_available() else "splu"
        self.kind = kind
        self._symbolic = None

    def solve(self, A: sp.csc_matrix, b: NDArray) -> NDArray[np.float64]:
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
