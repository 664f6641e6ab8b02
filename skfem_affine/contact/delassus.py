r"""The Delassus operator W = J A^-1 J^T of a frame's contacts (paper sec. 3.3).

The Jacobian J (3 rows n, t1, t2 per contact) maps free-DOF velocities to the relative
velocity of each contact vertex against its closest point. W is applied through the frame's
factorisation and, for a reduced frame, through G: ``A^-1 ~ G (G^T A G)^-1 G^T``, so
``W = (J G) A_r^-1 (J G)^T`` costs solves of the small reduced system
(:class:`Resolvent`). What it needs of the frame comes in the reducer's
:class:`~skfem_affine.integrators.problem.Operator`.
"""
from contextlib import nullcontext as _nothing

import numpy as np
import scipy.sparse as sp
from scipy.linalg import cho_solve, cholesky, solve_triangular
from scipy.sparse.csgraph import connected_components

from skfem_affine.threads import serial_blas
from skfem_affine.solvers import SuperLU, direct_solver

# Blocks (bodies) of the Delassus operator: up to BLOCK_DENSE_MAX unknowns a dense Cholesky
# factor L gives W_b = X^T X, X = L^-1 J_b^T (one triangular solve); below BLOCK_DIRECT_MIN
# SuperLU, else the direct solver (measurements in docs/contact.md).
BLOCK_DENSE_MAX = 800
BLOCK_DIRECT_MIN = 2000


def jacobian(contacts, n_vertices, free):
    """J (3k x n_free): row 3i + r is frame row r of contact i on w_a v_a - sum_k w_k v_k (w_a the
    contact's ``own`` weight, 1 for a vertex; fixed DOFs dropped)."""
    k = contacts.size
    frames = contacts.frames()                                        # (k, 3, 3)
    verts = np.column_stack([contacts.vertex, contacts.others])       # (k, 4)
    own = np.ones(k) if contacts.own is None else contacts.own
    coef = np.column_stack([own, -contacts.weights])                  # (k, 4)
    vals = coef[:, None, :, None] * frames[:, :, None, :]             # (k, 3 rows, 4 verts, 3 comps)
    rows = np.broadcast_to((3 * np.arange(k)[:, None] + np.arange(3))[:, :, None, None], vals.shape)
    cols = np.broadcast_to((3 * verts[:, :, None] + np.arange(3))[:, None, :, :], vals.shape)
    dof_map = np.full(3 * n_vertices, -1, dtype=np.int64)
    dof_map[free] = np.arange(free.size)
    c = dof_map[cols.ravel()]
    keep = (c >= 0) & (vals.ravel() != 0)
    J = sp.csr_matrix((vals.ravel()[keep], (rows.ravel()[keep], c[keep])), shape=(3 * k, free.size))
    J.sum_duplicates()
    return J


def block_solver(size):
    """The solver of one body's block of ``size`` unknowns: SuperLU below :data:`BLOCK_DIRECT_MIN`,
    else the fastest direct solver."""
    return SuperLU() if size < BLOCK_DIRECT_MIN else direct_solver()


class Resolvent:
    """A^-1 applied to the columns of J^T with the frame's system, through G when reduced (sec. 3.3).

    ``operator`` (:class:`~skfem_affine.integrators.problem.Operator`) holds the frame's
    system matrix (full A, or A_r = G^T A G of a reducer), the solver that has factorised it,
    and the reducer's mapping G (n_free x r), or None in full space, so that
    ``W = (J G) A_r^-1 (J G)^T``. Bodies are not coupled by A, so
    when A has several connected components (several bodies), W is built per
    component from a factorization of that block alone (dense Cholesky up to
    :data:`BLOCK_DENSE_MAX` unknowns, SuperLU below :data:`BLOCK_DIRECT_MIN`, else the
    fastest direct solver), solving only the columns of contacts that touch it;
    components without contacts cost nothing. ``cache`` (a dict kept across frames) holds the
    block solvers by (size, first unknown); after each frame it holds only that frame's.
    """

    def __init__(self, operator, block=64, cache=None):
        self.solver, self.A, self.G, self.block = operator.solver, operator.matrix, operator.G, int(block)
        self.iterative = operator.iterative
        n_comp, labels = connected_components(self.A, directed=False)
        self.parts = None
        if n_comp > 1:  # renumber component by component, so that blocks are contiguous slices
            self.order = np.argsort(labels, kind="stable")
            self.bounds = np.concatenate([[0], np.cumsum(np.bincount(labels, minlength=n_comp))])
            self.parts = range(n_comp)
        self.cache = {} if cache is None else cache
        self.used = set()

    def _solve(self, solver, R, iterative=False):
        if iterative:  # CG takes one right-hand side at a time
            return np.column_stack([solver.solve(np.ascontiguousarray(R[:, j])) for j in range(R.shape[1])])
        return np.asarray(solver.solve(R)).reshape(R.shape)

    def _blocks(self, solver, JrT, iterative=False):
        """A^-1 JrT (dense), ``block`` columns at a time."""
        Y = np.empty(JrT.shape)
        for s in range(0, JrT.shape[1], self.block):
            cols = slice(s, min(s + self.block, JrT.shape[1]))
            Y[:, cols] = self._solve(solver, JrT[:, cols].toarray(), iterative)
        return Y

    def _block_solver(self, idx):
        key = (idx.size, int(idx[0]))  # components keep their unknowns while the pattern is fixed
        if key not in self.cache:
            self.cache[key] = block_solver(idx.size)
        self.used.add(key)
        return self.cache[key]

    def _evict(self):
        """Drop the cached block solvers this frame did not use: a reduced frame's components change
        with its clusters, so the keys met over a run are unbounded; the cache holds one frame's."""
        for key in [key for key in self.cache if key not in self.used]:
            del self.cache[key]

    def delassus(self, J):
        """W = J A^-1 J^T (dense, symmetric), A^-1 ~ G A_r^-1 G^T in a reduced frame."""
        Jr = sp.csr_matrix(J @ self.G) if self.G is not None else sp.csr_matrix(J)
        self.Jr = Jr
        k = J.shape[0]
        if self.parts is None:
            self._evict()
            W = Jr @ self._blocks(self.solver, Jr.T.tocsc(), self.iterative)
            return 0.5 * (W + W.T)
        W = np.zeros((k, k))
        Jc = Jr[:, self.order].tocsc()
        Ap = sp.csr_matrix(self.A)[self.order][:, self.order].tocsr()
        self.local = []
        for c in self.parts:
            s, e = self.bounds[c], self.bounds[c + 1]
            Jb = Jc[:, s:e].tocsr()
            rows = np.flatnonzero(np.diff(Jb.indptr))
            if not rows.size:
                continue
            Jb = Jb[rows]
            idx = self.order[s:e]
            if idx.size <= BLOCK_DENSE_MAX:  # W_b = X^T X with X = L^-1 J_b^T, A_b = L L^T dense
                with serial_blas():
                    L = cholesky(Ap[s:e, s:e].toarray(), lower=True)
                    X = solve_triangular(L, Jb.T.toarray(), lower=True)
                    W[np.ix_(rows, rows)] += X.T @ X
                self.local.append((idx, rows, Jb, L))
                continue
            solver = self._block_solver(idx)
            with serial_blas() if idx.size < BLOCK_DIRECT_MIN else _nothing():
                solver.factorize(Ap[s:e, s:e])
                W[np.ix_(rows, rows)] += Jb @ self._blocks(solver, Jb.T.tocsc())
            self.local.append((idx, rows, Jb, solver))
        self._evict()
        return 0.5 * (W + W.T)

    def apply(self, lam):
        """dv = A^-1 J^T lambda on the free DOFs (through G when reduced)."""
        if self.parts is None:
            y = self._solve(self.solver, (self.Jr.T @ lam)[:, None], self.iterative)[:, 0]
        else:
            y = np.zeros(self.Jr.shape[1])
            for idx, rows, Jb, solver in self.local:
                r = Jb.T @ lam[rows]
                if isinstance(solver, np.ndarray):  # a dense Cholesky factor
                    y[idx] = cho_solve((solver, True), r)
                    continue
                with serial_blas() if idx.size < BLOCK_DIRECT_MIN else _nothing():
                    y[idx] = self._solve(solver, r[:, None])[:, 0]
        return self.G @ y if self.G is not None else y
