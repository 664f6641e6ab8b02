r"""Incomplete Cholesky factorisation of a sparse SPD matrix, compiled with numba.

The oracle's preconditioner (paper eq. 14) needs z = (L L^T)^{-1} r with L L^T ~ S; scipy has
no incomplete Cholesky, so this module provides one. Two kinds of factor, both left-looking
(column j of L from A's column j minus the columns k < j with L[j, k] != 0) on the matrix
scaled to unit diagonal, ``D^{-1/2} A D^{-1/2}``, with the scaling folded back into L:

* **threshold** (Lin & More 1999, "Incomplete Cholesky factorizations with limited
  memory"): column j keeps its ``n_j + fill`` entries of largest magnitude, n_j being
  the number of entries below the diagonal in column j of A, after dropping those below
  ``drop`` (relative to the unit diagonal, i.e. ``|l_ij| < drop``). With ``fill = 0``
  and ``drop = 0`` it keeps A's *number* of entries per column, not their positions.
* **IC(0)** (``fill=None``): L has exactly the pattern of A's lower triangle, and
  ``(L L^T)_ij = A_ij`` on that pattern.

A pivot that is not positive (or not finite) is a *breakdown*: the factorisation stops
and reports the column. :func:`incomplete_cholesky` then retries on ``A + s diag(A)`` for
the next shift s (Lin & More's remedy), and raises :class:`IncompleteCholeskyBreakdown`
when every shift fails. Without fill limits (``fill >= n``, ``drop = 0``) the
factor is the exact Cholesky factor; so it is, for any variant, when no fill arises
(a tree-shaped pattern, e.g. tridiagonal, eliminated leaves first).
"""
import numpy as np
import scipy.sparse as sp
from numba import njit

from skfem_affine import _compile_notice  # noqa: F401 (one stderr line when the cached kernels compile)

SHIFTS = (0.0, 1e-3, 1e-2, 1e-1, 1.0)


class IncompleteCholeskyBreakdown(ValueError):
    """The incomplete Cholesky factorisation met a non-positive pivot for every diagonal shift."""


@njit(cache=True)
def _factor(indptr, indices, data, n, fill, drop, ic0, shift):
    """Left-looking incomplete Cholesky of the unit-diagonal lower triangle (CSC) given.

    Returns (Lp, Li, Lx, failed): L in CSC with rows sorted and the diagonal first in each
    column, and failed = -1, or the column whose pivot was not positive (L is then partial).
    """
    cap = indptr[n] + n + (0 if ic0 else n * max(fill, 0))
    Lp = np.zeros(n + 1, np.int64)
    Li = np.empty(cap, np.int64)
    Lx = np.empty(cap)
    w = np.zeros(n)                   # the column being computed, dense
    seen = np.zeros(n, np.bool_)      # rows present in w
    inA = np.zeros(n, np.bool_)       # rows of A's column j (IC(0) keeps only these)
    rows = np.empty(n, np.int64)      # rows present in w, unordered
    head = np.full(n, -1, np.int64)   # head[r]: first finished column whose next entry is in row r
    link = np.full(n, -1, np.int64)   # next column in the same list
    nxt = np.zeros(n, np.int64)       # position in Li of that next entry, per finished column
    cand = np.empty(n, np.int64)      # rows kept below the diagonal, before the count limit
    mag = np.empty(n)                 # minus their magnitudes (argsort puts the largest first)
    top = 0
    for j in range(n):
        count = 0
        n_j = 0
        for p in range(indptr[j], indptr[j + 1]):
            i = indices[p]
            if i < j:
                continue
            if not seen[i]:
                seen[i] = True
                rows[count] = i
                count += 1
            w[i] += data[p]
            if i > j:
                inA[i] = True
                n_j += 1
        if not seen[j]:
            seen[j] = True
            rows[count] = j
            count += 1
        w[j] += shift
        k = head[j]                   # every finished column k with L[j, k] != 0
        head[j] = -1
        while k != -1:
            k_next = link[k]
            p0 = nxt[k]
            ljk = Lx[p0]
            for p in range(p0, Lp[k + 1]):
                i = Li[p]
                if not seen[i]:
                    seen[i] = True
                    rows[count] = i
                    count += 1
                w[i] -= Lx[p] * ljk
            if p0 + 1 < Lp[k + 1]:    # k's next entry is in a later row: file it there
                nxt[k] = p0 + 1
                r = Li[p0 + 1]
                link[k] = head[r]
                head[r] = k
            k = k_next
        d = w[j]
        if not (d > 0.0 and np.isfinite(d)):
            return Lp, Li, Lx, j
        ljj = np.sqrt(d)
        c = 0
        for a in range(count):
            i = rows[a]
            if i == j:
                continue
            v = w[i] / ljj
            keep = inA[i] if ic0 else (v != 0.0 and abs(v) >= drop)
            if keep:
                cand[c] = i
                mag[c] = -abs(v)
                c += 1
        if not ic0 and c > n_j + fill:
            order = np.argsort(mag[:c], kind="mergesort")[:n_j + fill]
            kept = np.sort(cand[:c][order])
        else:
            kept = np.sort(cand[:c])
        Li[top] = j
        Lx[top] = ljj
        top += 1
        for i in kept:
            Li[top] = i
            Lx[top] = w[i] / ljj
            top += 1
        Lp[j + 1] = top
        if kept.size:
            nxt[j] = Lp[j] + 1
            r = kept[0]
            link[j] = head[r]
            head[r] = j
        for a in range(count):        # clear the work arrays for the next column
            i = rows[a]
            w[i] = 0.0
            seen[i] = False
            inA[i] = False
    return Lp, Li[:top], Lx[:top], -1


@njit(cache=True, nogil=True)
def _solve(Lp, Li, Lx, X):
    """X <- (L L^T)^{-1} X in place, X (n, k), L in CSC with the diagonal first in each column."""
    n, k = X.shape
    for j in range(n):                # L y = x
        d = Lx[Lp[j]]
        for c in range(k):
            X[j, c] /= d
        for p in range(Lp[j] + 1, Lp[j + 1]):
            i, l = Li[p], Lx[p]
            for c in range(k):
                X[i, c] -= l * X[j, c]
    for j in range(n - 1, -1, -1):    # L^T z = y
        for p in range(Lp[j] + 1, Lp[j + 1]):
            i, l = Li[p], Lx[p]
            for c in range(k):
                X[j, c] -= l * X[i, c]
        d = Lx[Lp[j]]
        for c in range(k):
            X[j, c] /= d


class IncompleteCholesky:
    """A factor L with L L^T ~ A (lower triangular CSC, :attr:`L`) and its solve.

    Build it with :func:`incomplete_cholesky`.
    """

    def __init__(self, Lp, Li, Lx, shift):
        n = Lp.size - 1
        self.L = sp.csc_matrix((Lx, Li, Lp), shape=(n, n))
        self.shift = shift
        self._arrays = (Lp, Li, Lx)

    @property
    def shape(self):
        return self.L.shape

    def solve(self, b):
        """(L L^T)^{-1} b for b of shape (n,) or (n, k); b is not modified."""
        b = np.asarray(b, dtype=float)
        if b.shape[:1] != (self.L.shape[0],) or b.ndim > 2:
            raise ValueError(f"b must have shape ({self.L.shape[0]},) or ({self.L.shape[0]}, k), got {b.shape}")
        X = np.array(b.reshape(b.shape[0], -1), order="C")
        _solve(*self._arrays, X)
        return X.reshape(b.shape)

    __call__ = solve


def incomplete_cholesky(A, fill=0, drop=0.0, shifts=SHIFTS):
    """Incomplete Cholesky L L^T ~ A + s diag(A) of a sparse SPD matrix (module docstring).

    Parameters
    ----------
    A : sparse matrix, (n, n)
        Symmetric with a positive diagonal; only its lower triangle is read.
    fill : int or None
        Extra entries per column of L beyond A's count (threshold variant), or None for IC(0).
    drop : float
        Relative drop tolerance of the threshold variant (ignored by IC(0)).
    shifts : sequence of float
        Diagonal shifts s tried in turn; the first that factorises without breakdown is used.

    Returns
    -------
    IncompleteCholesky
        With ``.L``, ``.shift`` and ``.solve(b)``.

    Raises
    ------
    IncompleteCholeskyBreakdown
        When a pivot is not positive for every shift (A is then far from SPD).

    Examples
    --------
    A tridiagonal matrix has no fill: the factor is exact.

    >>> import numpy as np, scipy.sparse as sp
    >>> A = sp.diags([-1.0, 2.0, -1.0], [-1, 0, 1], shape=(5, 5))
    >>> ic = incomplete_cholesky(A, fill=None)
    >>> bool(np.allclose((ic.L @ ic.L.T).toarray(), A.toarray()))
    True
    """
    if not sp.issparse(A) or A.ndim != 2 or A.shape[0] != A.shape[1]:
        raise TypeError(f"A must be a square scipy sparse matrix, got {type(A).__name__} "
                        f"of shape {getattr(A, 'shape', None)}")
    if fill is not None and (int(fill) != fill or fill < 0):
        raise ValueError(f"fill must be a non-negative integer or None, got {fill!r}")
    if not (np.isfinite(drop) and drop >= 0):
        raise ValueError(f"drop must be a finite non-negative number, got {drop!r}")
    if len(shifts) == 0 or any(not (np.isfinite(s) and s >= 0) for s in shifts):
        raise ValueError(f"shifts must be finite non-negative numbers, got {shifts!r}")
    n = A.shape[0]
    A = sp.csc_matrix(A, dtype=float)
    if not np.all(np.isfinite(A.data)):
        raise ValueError("A has non-finite entries")
    d = A.diagonal()
    if not np.all(d > 0):
        raise ValueError(f"A must have a positive diagonal (an SPD matrix); entry {int(np.argmin(d))} is {d.min():g}")
    s = 1.0 / np.sqrt(d)
    T = sp.csc_matrix(sp.tril(sp.diags(s) @ A @ sp.diags(s)), dtype=float)  # unit diagonal
    T.sort_indices()
    ic0 = fill is None
    f = 0 if ic0 else min(int(fill), n)  # a column cannot hold more than n entries
    failed = []
    for shift in shifts:
        Lp, Li, Lx, col = _factor(T.indptr.astype(np.int64), T.indices.astype(np.int64), T.data,
                                  n, f, float(drop), ic0, float(shift))
        if col < 0:
            # L = D^{1/2} L_hat: L L^T = D^{1/2} (T + s I) D^{1/2} = A + s diag(A) (approximately)
            return IncompleteCholesky(Lp, Li, Lx * np.sqrt(d)[Li], float(shift))
        failed.append(f"shift {shift:g}: column {col}")
    raise IncompleteCholeskyBreakdown(
        "incomplete Cholesky broke down (non-positive pivot) for every diagonal shift s of "
        f"A + s diag(A) ({'; '.join(failed)}); is A symmetric positive definite?")
