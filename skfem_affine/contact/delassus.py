r"""The Delassus operator W = J A^-1 J^T of a frame's contacts (paper sec. 3.3).

The Jacobian J (3 rows n, t1, t2 per contact) maps free-DOF velocities to the relative
velocity of each contact vertex against its closest point. W is applied through the frame's
factorisation and, for a reduced frame, through G: ``A^-1 ~ G (G^T A G)^-1 G^T``, so
``W = (J G) A_r^-1 (J G)^T`` costs solves of the small reduced system, one per unknown
that the contacts touch (12 per affine body, 6 per rigid one) or per row of J, whichever is
fewer (:class:`Resolvent`). What it needs of the frame comes in the reducer's
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
# factor L gives R^T A_b^-1 R = X^T X, X = L^-1 R (one triangular solve; R = J_b^T, or the unit
# columns of the unknowns its contacts touch); below BLOCK_DIRECT_MIN
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


class DenseCholesky:
    """A body's small block A_b = L L^T, factorised densely (up to :data:`BLOCK_DENSE_MAX` unknowns)."""

    def factorize(self, A):
        self.L = cholesky(sp.csr_matrix(A).toarray(), lower=True)

    def solve(self, R):
        return cho_solve((self.L, True), R)

    def gram(self, R):
        """R^T A^-1 R = X^T X with X = L^-1 R: one triangular solve."""
        X = solve_triangular(self.L, R, lower=True)
        return X.T @ X


def _solve(solver, R, iterative=False):
    if iterative:  # CG takes one right-hand side at a time
        return np.column_stack([solver.solve(np.ascontiguousarray(R[:, j])) for j in range(R.shape[1])])
    return np.asarray(solver.solve(R)).reshape(R.shape)


def gram(solver, R, block=64, iterative=False):
    """R^T A^-1 R (dense, m x m) for the matrix A that ``solver`` has factorised and R (n x m, sparse).

    A^-1 R is solved ``block`` columns at a time; a :class:`DenseCholesky` takes X = L^-1 R at once."""
    R = sp.csc_matrix(R)
    if isinstance(solver, DenseCholesky):
        return solver.gram(R.toarray())
    out = np.empty((R.shape[1], R.shape[1]))
    for s in range(0, R.shape[1], block):
        cols = slice(s, min(s + block, R.shape[1]))
        out[:, cols] = R.T @ _solve(solver, R[:, cols].toarray(), iterative)
    return out


class Resolvent:
    """A^-1 applied to the columns of J^T with the frame's system, through G when reduced (sec. 3.3).

    ``operator`` (:class:`~skfem_affine.integrators.problem.Operator`) holds the frame's
    system matrix (full A, or A_r = G^T A G of a reducer), the solver that has factorised it,
    and the reducer's mapping G (n_free x r), or None in full space, so that
    ``W = Jr A^-1 Jr^T`` with ``Jr = J G`` (``J`` in full space).

    W needs A^-1 only on the unknowns T that the contacts touch (the columns of Jr with a
    nonzero): ``W = Jr_T Z Jr_T^T`` with ``Z = (A^-1)_TT`` (:meth:`inverse_on`), from solves of
    the unit columns e_T. That costs ``|T|`` solves instead of one per row of Jr (3 per contact),
    and is taken when ``|T|`` is the smaller: the contacts on an affine (rigid) body touch its 12
    (6) reduced unknowns however many they are, and a vertex with several contacts is solved
    once; otherwise A^-1 Jr^T is solved row by row, ``block`` columns at a time (always, with
    ``touched=False``: the reference path). The number of columns solved by the last
    :meth:`delassus` is ``columns_solved``.

    Bodies are not coupled by A, so when A has several connected components (several bodies),
    W is built per component from a factorization of that block alone (dense Cholesky up to
    :data:`BLOCK_DENSE_MAX` unknowns, SuperLU below :data:`BLOCK_DIRECT_MIN`, else the fastest
    direct solver), by the smaller of the two ways for the contacts that touch it; components
    without contacts cost nothing. ``cache`` (a dict kept across frames) holds the sparse block
    solvers by (size, first unknown); after each frame it holds only that frame's.
    """

    def __init__(self, operator, block=64, cache=None, touched=True, schur=None):
        self.solver, self.A, self.G, self.block = operator.solver, operator.matrix, operator.G, int(block)
        self.touched, self.schur = bool(touched), schur
        self.iterative = operator.iterative
        n_comp, labels = connected_components(self.A, directed=False)
        self.parts = None
        if n_comp > 1:  # renumber component by component, so that blocks are contiguous slices
            self.order = np.argsort(labels, kind="stable")
            self.bounds = np.concatenate([[0], np.cumsum(np.bincount(labels, minlength=n_comp))])
            self.parts = range(n_comp)
        self.cache = {} if cache is None else cache
        self.used = set()
        self.columns_solved = 0  # right-hand sides solved by the last :meth:`delassus`
        self.schur_unknowns = 0  # unknowns whose Z came from the Schur complement instead

    def _block_solver(self, idx):
        if idx.size <= BLOCK_DENSE_MAX:
            return DenseCholesky()
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

    def _from_schur(self, A, T, iterative, key=None):
        """Z = (A^-1)_TT from the Schur complement of A (the whole system, or the block ``key`` of a
        body) on T, or None when ``schur`` (:class:`~skfem_affine.contact.schur.SchurInverse`) is
        not given or declines (an iterative solver, too few or too many unknowns)."""
        if self.schur is None or iterative:
            return None
        Z = self.schur.inverse_on(A, T, key=key)
        if Z is not None:
            self.schur_unknowns += T.size
        return Z

    def inverse_on(self, solver, A, T, iterative=False, key=None):
        """Z = (A^-1)_TT (``|T| x |T|``, dense) for the matrix A that ``solver`` has factorised and the
        unknowns T (sorted): from the Schur complement (:meth:`_from_schur`), else the unit
        columns e_T solved, ``block`` at a time, rows T kept."""
        Z = self._from_schur(A, T, iterative, key)
        return self._columns(solver, A, T, iterative) if Z is None else Z

    def _columns(self, solver, A, T, iterative):
        self.columns_solved += T.size
        E = sp.csc_matrix((np.ones(T.size), T, np.arange(T.size + 1)), shape=(A.shape[0], T.size))
        return gram(solver, E, self.block, iterative)

    def _product(self, solver, A, Jb, iterative=False, key=None):
        """Jb A^-1 Jb^T for Jb (CSC, m x n) and the n x n matrix A that ``solver`` has factorised: from
        Z = (A^-1)_TT on the touched unknowns T when the Schur complement gives it or there are fewer
        of them than rows, else per row."""
        counts = np.diff(Jb.indptr)
        T = np.flatnonzero(counts)
        dense = isinstance(solver, DenseCholesky)  # a small body's block: one triangular solve is cheaper
        Z = self._from_schur(A, T, iterative, key) if self.touched and not dense else None
        if Z is None and self.touched and T.size < Jb.shape[0]:
            Z = self._columns(solver, A, T, iterative)
        if Z is not None:
            Jt = sp.csc_matrix((Jb.data, Jb.indices, np.concatenate([[0], np.cumsum(counts[T])])),
                               shape=(Jb.shape[0], T.size))
            W = Jt @ (Jt @ Z).T
        else:
            self.columns_solved += Jb.shape[0]
            W = gram(solver, Jb.T, self.block, iterative)
        return 0.5 * (W + W.T)

    def delassus(self, J):
        """W = J A^-1 J^T (dense, symmetric), A^-1 ~ G A_r^-1 G^T in a reduced frame."""
        Jr = sp.csr_matrix(J @ self.G) if self.G is not None else sp.csr_matrix(J)
        self.Jr, self.columns_solved, self.schur_unknowns = Jr, 0, 0
        k = J.shape[0]
        if self.parts is None:
            self._evict()
            return self._product(self.solver, self.A, Jr.tocsc(), self.iterative)
        W = np.zeros((k, k))
        Jc = Jr[:, self.order].tocsc()
        Jc.eliminate_zeros()
        Ap = sp.csr_matrix(self.A)[self.order][:, self.order].tocsr()
        self.local = []
        for c in self.parts:
            s, e = self.bounds[c], self.bounds[c + 1]
            a, b = Jc.indptr[s], Jc.indptr[e]
            if a == b:  # no contact touches this component
                continue
            # its columns of J, on the rows of the contacts that touch it
            rows, local = np.unique(Jc.indices[a:b], return_inverse=True)
            Jb = sp.csc_matrix((Jc.data[a:b], local, Jc.indptr[s:e + 1] - a), shape=(rows.size, e - s))
            idx = self.order[s:e]
            solver = self._block_solver(idx)
            Ab = Ap[s:e, s:e]
            with serial_blas() if idx.size < BLOCK_DIRECT_MIN else _nothing():
                solver.factorize(Ab)
                W[np.ix_(rows, rows)] += self._product(solver, Ab, Jb, key=(e - s, int(idx[0])))
            self.local.append((idx, rows, Jb, solver))
        self._evict()
        return W

    def apply(self, lam):
        """dv = A^-1 J^T lambda on the free DOFs (through G when reduced): one solve (per component)."""
        if self.parts is None:
            y = _solve(self.solver, (self.Jr.T @ lam)[:, None], self.iterative)[:, 0]
        else:
            y = np.zeros(self.Jr.shape[1])
            for idx, rows, Jb, solver in self.local:
                with serial_blas() if idx.size < BLOCK_DIRECT_MIN else _nothing():
                    y[idx] = _solve(solver, (Jb.T @ lam[rows])[:, None])[:, 0]
        return self.G @ y if self.G is not None else y
