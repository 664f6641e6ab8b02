r"""The reduced system solved with the full system's factorisation, for frames that reduce little.

A frame whose bodies are few and small has nearly the full space's unknowns, but a factorisation of
A_r = G^T A G of a pattern it has not seen pays a new symbolic analysis (ordering and elimination
tree), a large part of a numeric factorisation's cost, while the full A keeps its pattern from frame
to frame. With C (k x n) spanning the complement of G's range, C G = 0 (on each body's rows the
3 n_b - w directions its w columns do not reach),

.. math:: G A_r^{-1} G^T = A^{-1} - A^{-1} C^T S^{-1} C A^{-1}, \qquad S = C A^{-1} C^T,

the reduced solve is a full one corrected in k dimensions: A is factorised as in full space (its
analysis kept), ``Z = A^-1 C^T`` costs one solve of k right-hand sides, and S is a dense k x k
Cholesky. :class:`ConstrainedSolver` applies A_r^-1 this way; :data:`CONSTRAINTS_MAX` bounds k.
The result equals the direct factorisation of A_r to round-off.
"""
import numpy as np
import scipy.linalg as la
import scipy.sparse as sp

# Most constraints k (reduced vertices' DOFs beyond their bodies' columns) for which a frame whose A_r
# pattern is new is solved through A's factorisation: Z costs a solve of k right-hand sides, well under
# a new analysis up to a few dozen (measured in docs/affinification.md, "A frame that reduces little").
CONSTRAINTS_MAX = 64


def constraints(gmap):
    """The frame's constraint count k: the reduced vertices' free DOFs minus their bodies' columns."""
    return gmap.G.shape[0] - gmap.G.shape[1]


class ConstrainedSolver:
    """A_r^-1 through the factorisation of A (module docstring), as a solver of the reduced system.

    Parameters
    ----------
    full : solver object
        A direct solver that has factorised the frame's full A (free DOFs).
    gmap : Mapping
        The frame's mapping (compact numbering).
    numbering : FullNumbering, optional
        The reduced system's renumbering (:class:`~skfem_affine.reducers.affine.numbering.FullNumbering`):
        its ``columns`` (the unknown of each compact column) and ``size`` unknowns, those without a column
        (``idle``) decoupled with the diagonal ``idle_values``; None: the compact numbering.
    """

    name = "pardiso-constrained"
    iterative = False
    last_iterations = 1

    def __init__(self, full, gmap, numbering=None):
        self.full = full
        r, w, nb = gmap.G.shape[1], gmap.width, gmap.n_bodies
        ne = gmap.n_elastic
        if numbering is None:
            self.columns, self.idle, self.idle_values = np.arange(r), np.zeros(0, dtype=np.int64), np.zeros(0)
        else:
            self.columns, self.idle, self.idle_values = numbering.columns, numbering.idle, numbering.idle_values
        self.elastic_rows, self.elastic_cols = gmap.elastic_dofs, self.columns[:ne]
        self.body_cols = self.columns[ne:].reshape(nb, w)
        # per body: its free-DOF rows, Gamma_b = Q1 R (thin QR) and the complement Qc (C_b^T)
        free, vc = gmap.free, gmap.vcluster
        body = vc[free // 3]
        red = np.flatnonzero(body >= 0)
        red = red[np.argsort(body[red], kind="stable")]
        cuts = np.searchsorted(body[red], np.arange(nb + 1))
        self.rows, self.Q1, self.R = [], [], []
        ct_rows, ct_cols, ct_vals, k = [], [], [], 0
        for b in range(nb):
            rows = red[cuts[b]:cuts[b + 1]]
            Gam = gmap.rows[free[rows] // 3, free[rows] % 3, :]
            Q, R = np.linalg.qr(Gam, mode="complete")
            Qc = Q[:, w:]
            self.rows.append(rows)
            self.Q1.append(np.ascontiguousarray(Q[:, :w]))
            self.R.append(R[:w])
            ct_rows.append(np.repeat(rows, Qc.shape[1]))
            ct_cols.append(np.tile(k + np.arange(Qc.shape[1]), rows.size))
            ct_vals.append(Qc.ravel())
            k += Qc.shape[1]
        self.k = k
        n = gmap.G.shape[0]
        self.Ct = sp.csr_matrix((np.concatenate(ct_vals) if nb else np.zeros(0),
                                 (np.concatenate(ct_rows) if nb else np.zeros(0, int),
                                  np.concatenate(ct_cols) if nb else np.zeros(0, int))), shape=(n, k))
        if k:
            self.Z = np.asarray(full.solve(self.Ct.toarray())).reshape(n, k)
            S = np.asarray(self.Ct.T @ self.Z)
            self.S = la.cho_factor(0.5 * (S + S.T), lower=True)

    def solve(self, y):
        """x = A_r^-1 y for y (size,) or (size, c) in the reduced system's numbering."""
        y = np.asarray(y, dtype=float)
        Y = y.reshape(y.shape[0], -1)
        F = np.zeros((self.full_rows, Y.shape[1]))
        F[self.elastic_rows] = Y[self.elastic_cols]
        for rows, Q1, R, cols in zip(self.rows, self.Q1, self.R, self.body_cols):  # G^T F = y on each body
            F[rows] = Q1 @ la.solve_triangular(R, Y[cols], trans="T")
        U = np.asarray(self.full.solve(F)).reshape(F.shape)
        if self.k:
            U -= self.Z @ la.cho_solve(self.S, self.Ct.T @ U)
        X = np.zeros_like(Y)
        X[self.elastic_cols] = U[self.elastic_rows]
        for rows, Q1, R, cols in zip(self.rows, self.Q1, self.R, self.body_cols):  # G X = U: X = G^+ U
            X[cols] = la.solve_triangular(R, Q1.T @ U[rows])
        if self.idle.size:
            X[self.idle] = Y[self.idle] / self.idle_values[:, None]
        return X.reshape(y.shape)

    @property
    def full_rows(self):
        return self.Ct.shape[0]
