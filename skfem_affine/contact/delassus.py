r"""The Delassus operator W = J A^-1 J^T of a frame's contacts (paper sec. 3.3).

The Jacobian J (3 rows n, t1, t2 per contact) maps free-DOF velocities to the relative
velocity of each contact vertex against its closest point. W is applied through the frame's
factorisation and, for a reduced frame, through G: ``A^-1 ~ G (G^T A G)^-1 G^T``, so
``W = (J G) A_r^-1 (J G)^T``. Only the unknowns that contacts touch matter: W comes from
the Schur complement of the system on them (:class:`Resolvent`), without a solve per contact
row. What it needs of the frame comes in the reducer's
:class:`~skfem_affine.integrators.problem.Operator`.
"""
import numpy as np
import scipy.sparse as sp
from scipy.linalg import cholesky, solve_triangular
from scipy.sparse.csgraph import connected_components

from skfem_affine.solvers import PardisoSchur, has_pardiso
from skfem_affine.threads import serial_blas


# Below this many touched unknowns, and without a kept Schur analysis, W comes from solves with the
# frame's factorisation: one solve cost 1/40 to 1/100 of a factorisation on the paper's wheel and
# octopus, and a new Schur analysis with its factorisation about two factorisations.
SCHUR_MIN = 128


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


def schur_solver():
    """The Schur complement solver of the Delassus operator: :class:`~skfem_affine.solvers.PardisoSchur`
    when Pardiso is installed, else None (W then comes from solves with the frame's solver)."""
    return PardisoSchur() if has_pardiso() else None


class Resolvent:
    """A^-1 applied to the columns of J^T with the frame's system, through G when reduced (sec. 3.3).

    ``operator`` (:class:`~skfem_affine.integrators.problem.Operator`) holds the frame's
    system matrix (full A, or A_r = G^T A G of a reducer), the solver that has factorised it,
    and the reducer's mapping G (n_free x r), or None in full space, so that
    ``W = (J G) A_r^-1 (J G)^T``.

    W needs A^-1 only on the unknowns C that contacts touch (the non-zero columns of J G):
    ``W = J_C (A^-1)_CC J_C^T``. A contact on an affine (rigid) body touches its 12 (6) unknowns
    through G, so a body with hundreds of contacts adds 12 (6) unknowns to C, not 3 per contact.
    With ``schur`` (:class:`~skfem_affine.solvers.PardisoSchur`), ``(A^-1)_CC = S^-1`` from the
    Schur complement S of A on C or a superset of it (one factorisation, no solve per column;
    :meth:`_kept`); without, the frame's solver solves the unit columns of C, ``block`` at a
    time. A does not couple bodies: S is block diagonal, and W is built block by block.
    """

    def __init__(self, operator, block=64, schur=None):
        self.solver, self.A, self.G, self.block = operator.solver, operator.matrix, operator.G, int(block)
        self.iterative = operator.iterative
        self.schur = schur

    def _solve(self, R):
        if self.iterative:  # CG takes one right-hand side at a time
            return np.column_stack([self.solver.solve(np.ascontiguousarray(R[:, j])) for j in range(R.shape[1])])
        return np.asarray(self.solver.solve(R)).reshape(R.shape)

    def _inverse_on(self, C):
        """(A^-1)_CC by solves of the unit columns of C, ``block`` at a time."""
        n, k = self.A.shape[0], C.size
        Z = np.empty((k, k))
        for s in range(0, k, self.block):
            cols = np.arange(s, min(s + self.block, k))
            E = np.zeros((n, cols.size))
            E[C[cols], np.arange(cols.size)] = 1.0
            Z[:, cols] = self._solve(E)[C]
        return Z

    def _kept(self, C):
        """The unknowns W is built on (C or a superset) and whether by the Schur complement.

        The Schur complement's analysis is kept while the contacts touch a subset of its unknowns
        at most twice their number (a body at rest, contacts that come and go), and the set grows
        by the new ones while that bound holds, so that a numeric factorisation suffices. A new
        analysis costs about twice a factorisation: then, below :data:`SCHUR_MIN` unknowns, solves
        with the frame's factorisation are cheaper.
        """
        if self.schur is None:
            return C, False
        last = self.schur.analysed(self.A)
        if last is not None:
            if last.size <= 2 * C.size and np.isin(C, last).all():
                return last, True
            grown = np.union1d(last, C)
            if grown.size <= 2 * C.size:
                return grown, True
        if C.size < SCHUR_MIN and not self.iterative:
            return C, False
        return C, True

    def delassus(self, J):
        """W = J A^-1 J^T (dense, symmetric), A^-1 ~ G A_r^-1 G^T in a reduced frame."""
        Jr = sp.csr_matrix(J @ self.G) if self.G is not None else sp.csr_matrix(J)
        Jr.eliminate_zeros()
        self.Jr = Jr
        k = J.shape[0]
        C = np.unique(Jr.indices)
        W = np.zeros((k, k))
        if not C.size:
            return W
        keep, schur = self._kept(C)
        Jc = Jr[:, keep].tocsc()
        M = self.schur.complement(self.A, keep) if schur else self._inverse_on(keep)
        # M is block diagonal over the bodies (A does not couple them): one block per component
        # of its own pattern, so that W = sum_b J_b M_b^-1 J_b^T (Schur) or J_b M_b J_b^T
        nz = np.nonzero(M)
        _, labels = connected_components(sp.csr_matrix((np.ones(nz[0].size), nz), shape=M.shape), directed=False)
        order = np.argsort(labels, kind="stable")
        bounds = np.flatnonzero(np.diff(labels[order], prepend=-1, append=labels.max() + 1))
        with serial_blas():
            for s, e in zip(bounds[:-1], bounds[1:]):
                part = order[s:e]
                Jb = Jc[:, part].tocsr()
                rows = np.flatnonzero(np.diff(Jb.indptr))
                if not rows.size:  # kept unknowns no contact touches this frame
                    continue
                Jb, Mb = Jb[rows], M[np.ix_(part, part)]
                if not schur:  # M = (A^-1)_CC
                    W[np.ix_(rows, rows)] += Jb @ (Jb @ (0.5 * (Mb + Mb.T))).T
                    continue
                X = solve_triangular(cholesky(Mb, lower=True), Jb.T.toarray(), lower=True)  # W_b = X^T X
                W[np.ix_(rows, rows)] += X.T @ X
        return 0.5 * (W + W.T)

    def apply(self, lam):
        """dv = A^-1 J^T lambda on the free DOFs (through G when reduced): one solve."""
        y = self._solve((self.Jr.T @ lam)[:, None])[:, 0]
        return self.G @ y if self.G is not None else y
