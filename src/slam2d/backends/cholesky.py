"""Sparse block Cholesky for pose graphs, compiled with numba.

The normal equations of a pose graph are a sparse matrix of dense ``d x d``
node blocks (``d = 3`` for SE(2)). Factoring at the block level keeps the
symbolic work to the node graph and lets the numeric work run on small dense
blocks: a left-looking block Cholesky ``H = L L^T``, the nodes already in a
fill-reducing order (:func:`slam2d.backends.linear.node_ordering`).

The symbolic analysis (elimination tree and the block structure of ``L``) is
done once per pattern; each Levenberg-Marquardt trial refactors the values
only. Compared with SuperLU this does half the work (Cholesky, not LU) and no
pivoting, which the matrix, symmetric positive definite, does not need.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

__all__ = ["BlockCholesky"]


@numba.njit(cache=True)
def _symbolic(m, colptr, rows):  # pragma: no cover - numba
    """Block structure of L from the lower node pattern of A (column ``j``: rows ``>= j``, sorted, ``j`` first)."""
    parent = np.full(m, -1, dtype=np.int64)
    ancestor = np.full(m, -1, dtype=np.int64)
    # elimination tree (Liu), reading A's upper triangle as A's lower one transposed:
    # for column k, every i < k with A[k, i] != 0 is in column i at row k; iterate by rows via columns
    # -> build the transpose (row lists of the lower part) first
    cnt = np.zeros(m + 1, dtype=np.int64)
    for j in range(m):
        for t in range(colptr[j], colptr[j + 1]):
            cnt[rows[t] + 1] += 1
    for i in range(m):
        cnt[i + 1] += cnt[i]
    rowcols = np.empty(cnt[m], dtype=np.int64)
    fill = cnt[:-1].copy()
    for j in range(m):
        for t in range(colptr[j], colptr[j + 1]):
            r = rows[t]
            rowcols[fill[r]] = j
            fill[r] += 1
    for k in range(m):
        for t in range(cnt[k], cnt[k + 1]):
            i = rowcols[t]  # A[k, i] != 0 with i <= k
            while i != -1 and i < k:
                nxt = ancestor[i]
                ancestor[i] = k
                if nxt == -1:
                    parent[i] = k
                i = nxt
    # structure of each column: own rows of A plus the children's rows, minus the child itself
    head = np.full(m, -1, dtype=np.int64)
    nxt_child = np.full(m, -1, dtype=np.int64)
    for j in range(m - 1, -1, -1):
        p = parent[j]
        if p != -1:
            nxt_child[j] = head[p]
            head[p] = j
    mark = np.full(m, -1, dtype=np.int64)
    lptr = np.zeros(m + 1, dtype=np.int64)
    cap = max(16, 2 * colptr[m])
    lrows = np.empty(cap, dtype=np.int64)
    buf = np.empty(m, dtype=np.int64)
    for j in range(m):
        n = 0
        mark[j] = j
        buf[n] = j
        n += 1
        for t in range(colptr[j], colptr[j + 1]):
            r = rows[t]
            if r > j and mark[r] != j:
                mark[r] = j
                buf[n] = r
                n += 1
        c = head[j]
        while c != -1:
            for t in range(lptr[c] + 1, lptr[c + 1]):  # skip the child's diagonal
                r = lrows[t]
                if r > j and mark[r] != j:
                    mark[r] = j
                    buf[n] = r
                    n += 1
            c = nxt_child[c]
        srt = np.sort(buf[1:n])
        if lptr[j] + n > cap:
            while lptr[j] + n > cap:
                cap *= 2
            grown = np.empty(cap, dtype=np.int64)
            grown[: lptr[j]] = lrows[: lptr[j]]
            lrows = grown
        lrows[lptr[j]] = j
        lrows[lptr[j] + 1 : lptr[j] + n] = srt
        lptr[j + 1] = lptr[j] + n
    return lptr, lrows[: lptr[m]].copy()


@numba.njit(cache=True)
def _numeric(m, d, lptr, lrows, aptr, arows, aslots, data, diag_add, L):  # pragma: no cover - numba
    """Left-looking block Cholesky into ``L`` (blocks in ``lrows`` order). Returns False if not positive definite."""
    X = np.zeros((m, d, d))
    nextpos = np.empty(m, dtype=np.int64)  # per finished column: its next block row to use
    link = np.full(m, -1, dtype=np.int64)  # columns waiting to update column j, chained by row
    linknext = np.full(m, -1, dtype=np.int64)
    Ljk = np.zeros((d, d))
    for j in range(m):
        # scatter A's column j (rows >= j) into X
        for t in range(lptr[j], lptr[j + 1]):
            X[lrows[t]] = 0.0
        for t in range(aptr[j], aptr[j + 1]):
            r = arows[t]
            if r >= j:
                for p in range(d):
                    for q in range(d):
                        X[r, p, q] = data[aslots[t, p, q]]
        for p in range(d):
            X[j, p, p] += diag_add[j * d + p]
        # updates from every column k with L[j, k] != 0
        k = link[j]
        while k != -1:
            knext = linknext[k]
            pos = nextpos[k]
            for p in range(d):
                for q in range(d):
                    Ljk[p, q] = L[pos, p, q]
            for t in range(pos, lptr[k + 1]):
                i = lrows[t]
                # X[i] -= L[t] @ Ljk^T
                for p in range(d):
                    for q in range(d):
                        acc = 0.0
                        for r in range(d):
                            acc += L[t, p, r] * Ljk[q, r]
                        X[i, p, q] -= acc
            # move column k on to its next row
            pos += 1
            nextpos[k] = pos
            if pos < lptr[k + 1]:
                i = lrows[pos]
                linknext[k] = link[i]
                link[i] = k
            k = knext
        link[j] = -1
        # dense Cholesky of the diagonal block
        dpos = lptr[j]
        D = L[dpos]
        for p in range(d):
            for q in range(d):
                D[p, q] = 0.0
        for q in range(d):
            s = X[j, q, q]
            for r in range(q):
                s -= D[q, r] * D[q, r]
            if not (s > 0.0):
                return False
            D[q, q] = np.sqrt(s)
            for p in range(q + 1, d):
                s = X[j, p, q]
                for r in range(q):
                    s -= D[p, r] * D[q, r]
                D[p, q] = s / D[q, q]
        # off-diagonal blocks: L[i, j] = X[i] D^-T (solve each row against D)
        for t in range(dpos + 1, lptr[j + 1]):
            i = lrows[t]
            for p in range(d):
                for q in range(d):
                    s = X[i, p, q]
                    for r in range(q):
                        s -= L[t, p, r] * D[q, r]
                    L[t, p, q] = s / D[q, q]
        if dpos + 1 < lptr[j + 1]:
            nextpos[j] = dpos + 1
            i = lrows[dpos + 1]
            linknext[j] = link[i]
            link[i] = j
    return True


@numba.njit(cache=True)
def _solve(m, d, lptr, lrows, L, b):  # pragma: no cover - numba
    x = b.copy().reshape(m, d)
    # forward: L y = b
    for j in range(m):
        dpos = lptr[j]
        for p in range(d):
            s = x[j, p]
            for r in range(p):
                s -= L[dpos, p, r] * x[j, r]
            x[j, p] = s / L[dpos, p, p]
        for t in range(dpos + 1, lptr[j + 1]):
            i = lrows[t]
            for p in range(d):
                acc = 0.0
                for r in range(d):
                    acc += L[t, p, r] * x[j, r]
                x[i, p] -= acc
    # backward: L^T x = y
    for j in range(m - 1, -1, -1):
        dpos = lptr[j]
        for t in range(dpos + 1, lptr[j + 1]):
            i = lrows[t]
            for p in range(d):
                acc = 0.0
                for r in range(d):
                    acc += L[t, r, p] * x[i, r]
                x[j, p] -= acc
        for p in range(d - 1, -1, -1):
            s = x[j, p]
            for r in range(p + 1, d):
                s -= L[dpos, r, p] * x[j, r]
            x[j, p] = s / L[dpos, p, p]
    return x.reshape(m * d)


class BlockCholesky:
    """``H = L L^T`` over the block pattern of a :class:`~slam2d.backends.linear.BlockPattern`."""

    def __init__(self, pattern) -> None:
        self.m = pattern.size // pattern.d
        self.d = pattern.d
        self.aptr = pattern.node_colptr
        self.arows = pattern.node_rows
        self.aslots = pattern.pair_slots
        self.lptr, self.lrows = _symbolic(self.m, self.aptr, self.arows)
        self.L = np.zeros((self.lrows.size, self.d, self.d))

    @property
    def nnz_blocks(self) -> int:
        return int(self.lrows.size)

    def factor(self, data: NDArray, diag_add: NDArray) -> bool:
        """Factor the matrix with CSC values ``data`` plus ``diag_add`` on the diagonal; False if not positive definite."""
        return bool(_numeric(self.m, self.d, self.lptr, self.lrows, self.aptr, self.arows, self.aslots,
                             data, diag_add, self.L))

    def solve(self, b: NDArray) -> NDArray[np.float64]:
        return _solve(self.m, self.d, self.lptr, self.lrows, self.L, np.ascontiguousarray(b, dtype=np.float64))
