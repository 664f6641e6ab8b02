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
(:meth:`DenseBlocks.apply`). The blocks' rows of Jr = J G, their entries of A and W's entries are
gathered and added by compiled loops over J's, G's and A's nonzeros: a resting pile's frame costs
the blocks' arithmetic, not a sparse product and fancy indexing per frame. Measured in
``docs/contact.md``.
"""
import numpy as np
import scipy.linalg
from numba import njit

from skfem_affine import _compile_notice  # noqa: F401 (one stderr line when the cached kernels compile)
from skfem_affine.solvers import SolverError

# Blocks of at most DENSE_MAX used unknowns are factorised densely: an affine body with a few dozen
# elastic vertices at its contacts. Above about this size a dense block costs more than its unit
# columns solved by the frame's factorisation (measured in docs/contact.md, the resting pile), so
# larger blocks are left to that factorisation.
DENSE_MAX = 160

_NONE = np.zeros(0, dtype=np.int64)


def used_unknowns(G, size):
    """Mask (size,) of the unknowns of a frame's system that a column of G (n_free x size) reaches; all
    of them in full space (G None). The others are a renumbered frame's idle unknowns, decoupled."""
    used = np.zeros(size, dtype=bool)
    if G is None:
        used[:] = True
    else:
        used[G.tocsr().indices] = True
    return used


@njit(cache=True)
def _reach(J_indices, G_indptr, G_indices, has_g, block, small):
    """Which blocks the columns of J reach through G (G the identity without ``has_g``): (touched per block
    label, the reached unknowns in small blocks, whether one outside them is reached)."""
    touched = np.zeros(small.size, dtype=np.bool_)
    mark = np.zeros(block.size, dtype=np.bool_)
    count, rest = 0, False
    for p in range(J_indices.size):
        c = J_indices[p]
        lo, hi = (G_indptr[c], G_indptr[c + 1]) if has_g else (0, 1)
        for q in range(lo, hi):
            u = G_indices[q] if has_g else c
            b = block[u]
            if b >= 0 and small[b]:
                touched[b] = True
                if not mark[u]:
                    mark[u] = True
                    count += 1
            else:
                rest = True
    return touched, count, rest


@njit(cache=True)
def _gather(indptr, indices, data, upper, cols, pos):
    """A[cols][:, cols] (dense) from A's CSR arrays, only the entries within the blocks of ``cols``
    (``pos``: the place of each unknown in ``cols``, -1 elsewhere); ``upper``: A given by its upper triangle."""
    m = cols.size
    out = np.zeros((m, m))
    for i in range(m):
        u = cols[i]
        for p in range(indptr[u], indptr[u + 1]):
            j = pos[indices[p]]
            if j >= 0:
                out[i, j] += data[p]
                if upper and j != i:
                    out[j, i] += data[p]
    return out


@njit(cache=True)
def _dense_rows(J_indptr, J_indices, J_data, G_indptr, G_indices, G_data, has_g, pos, ncols, col_block, nblocks):
    """Jr = J G on the columns with ``pos`` >= 0, dense (rows of J x ``ncols``), each entry summed in the
    order of a sparse product; and per block (``col_block``: the block of each dense column) its rows."""
    k = J_indptr.size - 1
    Jd = np.zeros((k, ncols))
    seen = np.zeros((nblocks, k), dtype=np.bool_)
    for i in range(k):
        for p in range(J_indptr[i], J_indptr[i + 1]):
            c = J_indices[p]
            lo, hi = (G_indptr[c], G_indptr[c + 1]) if has_g else (0, 1)
            for q in range(lo, hi):
                u, g = (G_indices[q], G_data[q]) if has_g else (c, 1.0)
                j = pos[u]
                if j >= 0:
                    Jd[i, j] += J_data[p] * g
                    seen[col_block[j], i] = True
    return Jd, seen


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
    touched : int
        The unknowns in small blocks that the last :meth:`parts` found the contacts touch.
    rest : bool
        Whether the last :meth:`parts` found the contacts touch an unknown outside the small blocks.
    """

    def __init__(self, operator, labels, used, largest=DENSE_MAX):
        self.operator = operator
        self.labels = np.where(used, 0 if labels is None else labels, -1)
        self.counts = np.bincount(self.labels[self.labels >= 0], minlength=1)  # used unknowns per block label
        self.small = (self.counts > 0) & (self.counts <= int(largest))
        self.factors = {}
        self.touched, self.rest = 0, False

    def in_small(self):
        """Mask of the unknowns in small blocks."""
        return (self.labels >= 0) & self.small[np.maximum(self.labels, 0)]

    def _factorize(self, labels):
        """The factors of the blocks ``labels`` not yet factorised, from one gather of their entries of A."""
        labels = [b for b in labels if b not in self.factors]
        if not labels:
            return
        want = np.zeros(self.small.size, dtype=bool)
        want[labels] = True
        every = np.flatnonzero(want[np.maximum(self.labels, 0)] & (self.labels >= 0))
        every = every[np.argsort(self.labels[every], kind="stable")]  # block by block, each sorted
        pos = np.full(self.labels.size, -1, dtype=np.int64)
        pos[every] = np.arange(every.size)
        matrix, upper = self.operator.stored
        matrix = matrix.tocsr()
        A = _gather(matrix.indptr, matrix.indices, np.asarray(matrix.data, dtype=float), upper, every, pos)
        s = 0
        for b in labels:  # increasing, as ``every``
            e = s + int(self.counts[b])
            try:
                L = np.linalg.cholesky(A[s:e, s:e])
            except np.linalg.LinAlgError as err:
                raise SolverError(f"block {b} of the frame's system ({e - s} unknowns) is not positive definite: "
                                  f"{err}") from err
            self.factors[b] = (every[s:e], L)
            s = e

    def parts(self, J, G):
        """Per small block b that the contacts reach (J: their rows on the free DOFs, CSR; G: the frame's
        mapping, CSR, or None in full space): (its rows of J, C_b), its part of W = Jr A^-1 Jr^T being
        ``C_b C_b^T`` with ``C_b^T = L_b^-1 Jb^T`` (Jb: those rows of Jr = J G on the block's unknowns,
        dense); and the blocks' labels. Sets :attr:`touched` and :attr:`rest`."""
        if G is None:
            gp, gi, gd, has_g = _NONE, _NONE, np.zeros(0), False
        else:
            gp, gi, gd, has_g = G.indptr, G.indices, np.asarray(G.data, dtype=float), True
        touched, self.touched, self.rest = _reach(J.indices, gp, gi, has_g, self.labels, self.small)
        labels = np.flatnonzero(touched)
        if not labels.size:
            return [], labels
        self._factorize(labels)
        sizes = np.array([self.factors[b][0].size for b in labels])
        cols = np.concatenate([self.factors[b][0] for b in labels])  # the blocks' unknowns, block by block
        cuts = np.concatenate([[0], np.cumsum(sizes)])
        pos = np.full(self.labels.size, -1, dtype=np.int64)
        pos[cols] = np.arange(cols.size)
        Jd, seen = _dense_rows(J.indptr, J.indices, np.asarray(J.data, dtype=float), gp, gi, gd, has_g, pos,
                               cols.size, np.repeat(np.arange(labels.size), sizes), labels.size)
        out = []
        for q, b in enumerate(labels):
            L = self.factors[b][1]
            r = np.flatnonzero(seen[q])
            Ct = scipy.linalg.solve_triangular(L, Jd[r, cuts[q]:cuts[q + 1]].T, lower=True, check_finite=False)
            out.append((r, Ct.T))
        self._last = (labels, Jd, cuts)
        return out, labels

    def apply(self, lam, x):
        """x on the blocks of the last :meth:`parts` set to their part of A^-1 Jr^T lam (``lam``: one
        impulse per row of J): Jr^T lam summed row by row, as a sparse product does, then each block's
        Cholesky solve."""
        labels, Jd, cuts = self._last
        r = _transposed_product(Jd, np.asarray(lam, dtype=float))
        for q, b in enumerate(labels):
            idx, L = self.factors[b]
            x[idx] = scipy.linalg.cho_solve((L, True), r[cuts[q]:cuts[q + 1]], check_finite=False)
        return x


@njit(cache=True)
def _transposed_product(Jd, lam):
    """Jd^T lam, the rows added in order (the sums of a sparse ``Jr.T @ lam``)."""
    out = np.zeros(Jd.shape[1])
    for i in range(Jd.shape[0]):
        if lam[i] != 0.0:
            for j in range(Jd.shape[1]):
                out[j] += Jd[i, j] * lam[i]
    return out
