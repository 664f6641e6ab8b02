r"""The Delassus operator's part on a frame's small body blocks, from their dense Cholesky factors (sec. 3.3).

A reduced frame's system A_r does not couple the scene's bodies, and a body that is one affine (rigid)
body with a few elastic vertices left at its contacts has a block of a few dozen unknowns: its 12 (6)
reduced ones and 3 per elastic vertex. Its part of ``W = Jr A_r^-1 Jr^T`` is ``Jb A_b^-1 Jb^T``, Jb
the rows of Jr its contacts touch on its unknowns. Solving the unit columns of the touched unknowns
with the frame's factorisation costs a solve of the whole (padded) system per call, the solver's fixed
cost per call and the sparse bookkeeping around them. With the block's dense Cholesky factor
``A_b = L L^T`` (``m^3 / 3`` flops for m unknowns: microseconds for a few dozen) it is ``C C^T`` with
``C^T = L^-1 Jb^T``, one triangular solve and one symmetric product: however many contacts a
resting affine body has, it costs its 12 x 12 block. :class:`DenseBlocks` factorises the blocks of at
most ``largest`` used unknowns that the contacts touch, gives their parts of W
(:meth:`DenseBlocks.parts`) and solves their part of the velocity correction ``A^-1 Jr^T lambda``
(:meth:`DenseBlocks.solve`). Measured in ``docs/contact.md``.
"""
import numpy as np
import scipy.linalg

from skfem_affine.solvers import SolverError

# Blocks of at most DENSE_MAX used unknowns are factorised densely: an affine body with a few dozen
# elastic vertices at its contacts. Dense, an elastic body's block of 81 unknowns costs what its unit
# columns do, one of 192 1.06 times, one of 375 2.8 times (docs/contact.md): larger blocks are left
# to the frame's factorisation.
DENSE_MAX = 160


def used_unknowns(G, size):
    """Mask (size,) of the unknowns of a frame's system that a column of G (n_free x size) reaches; all
    of them in full space (G None). The others are a renumbered frame's idle unknowns, decoupled."""
    used = np.zeros(size, dtype=bool)
    if G is None:
        used[:] = True
    else:
        used[G.tocsr().indices] = True
    return used


class DenseBlocks:
    """Dense Cholesky factors of the blocks of at most ``largest`` used unknowns of one frame's matrix.

    Parameters
    ----------
    operator : Operator
        The frame's :class:`~skfem_affine.integrators.problem.Operator`: its symmetric positive-definite
        system (size x size), whose blocks do not couple, is read when a block is factorised.
    labels : (size,) int array or None
        The block of each unknown; None: one block.
    used : (size,) bool array
        The unknowns in a block (:func:`used_unknowns`); the others belong to none.
    largest : int
        Blocks of more used unknowns are left to the frame's factorisation.

    Attributes
    ----------
    factors : dict
        Block label -> (its unknowns, sorted; the lower Cholesky factor of its part of A, dense), for the
        blocks :meth:`parts` factorised.
    """

    def __init__(self, operator, labels, used, largest=DENSE_MAX):
        self.operator = operator
        self.labels = np.where(used, 0 if labels is None else labels, -1)
        counts = np.bincount(self.labels[self.labels >= 0], minlength=1)
        self.small = (counts > 0) & (counts <= int(largest))  # per block label
        self.factors = {}

    def columns(self, T):
        """Mask of the unknowns T (columns of Jr) in small blocks."""
        lab = self.labels[T]
        return (lab >= 0) & self.small[np.maximum(lab, 0)]

    def _factorize(self, labels):
        """The factors of the blocks ``labels`` not yet factorised, from one gather of their rows of A."""
        labels = [b for b in labels if b not in self.factors]
        if not labels:
            return
        idx = [np.flatnonzero(self.labels == b) for b in labels]
        every = np.concatenate(idx)
        A = self.operator.matrix[every][:, every].toarray()  # block diagonal: the blocks are its diagonal squares
        s = 0
        for b, i in zip(labels, idx):
            e = s + i.size
            try:
                L = np.linalg.cholesky(A[s:e, s:e])
            except np.linalg.LinAlgError as err:
                raise SolverError(f"block {b} of the frame's system ({i.size} unknowns) is not positive definite: "
                                  f"{err}") from err
            self.factors[b] = (i, L)
            s = e

    def parts(self, Jr, T):
        """Per small block b the contacts touch: (its rows of Jr, C_b), its part of W being ``C_b C_b^T`` with
        ``C_b^T = L_b^-1 Jb^T`` (Jb: those rows on the block's unknowns, dense); and the blocks' labels.
        ``Jr`` (k x size, CSR); ``T``: its touched unknowns in small blocks."""
        labels = np.unique(self.labels[T])
        self._factorize(labels)
        cols = np.concatenate([self.factors[b][0] for b in labels])  # the blocks' unknowns, block by block
        cuts = np.concatenate([[0], np.cumsum([self.factors[b][0].size for b in labels])])
        pos = np.full(self.labels.size, -1, dtype=np.int64)
        pos[cols] = np.arange(cols.size)
        rows = np.repeat(np.arange(Jr.shape[0]), np.diff(Jr.indptr))
        col = pos[Jr.indices]
        keep = col >= 0
        rows, col = rows[keep], col[keep]
        Jd = np.zeros((Jr.shape[0], cols.size))  # Jr on the blocks' unknowns, dense (k x a few dozen per block)
        Jd[rows, col] = Jr.data[keep]
        seen = np.zeros((labels.size, Jr.shape[0]), dtype=bool)  # the rows of each block
        seen[np.searchsorted(cuts, col, side="right") - 1, rows] = True
        out = []
        for q, b in enumerate(labels):
            L = self.factors[b][1]
            r = np.flatnonzero(seen[q])
            Ct = scipy.linalg.solve_triangular(L, Jd[r, cuts[q]:cuts[q + 1]].T, lower=True, check_finite=False)
            out.append((r, Ct.T))
        return out, labels

    def solve(self, r, labels, x):
        """x on the blocks ``labels`` (factorised) set to their part of A^-1 r (A does not couple blocks)."""
        for b in labels:
            idx, L = self.factors[b]
            x[idx] = scipy.linalg.cho_solve((L, True), r[idx], check_finite=False)
        return x
