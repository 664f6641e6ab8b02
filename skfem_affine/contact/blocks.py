r"""A frame whose contacts touch several bodies, factorised body by body with each body's touched unknowns last.

A does not couple bodies, so each body's block A_b is a system of its own. Factorised in Pardiso's
Schur mode that also solves (:class:`~skfem_affine.solvers.PardisoSchur`, ``solves=True``) with the
unknowns T_b the contacts touch eliminated last, the one factorisation solves the body's part of the
frame and leaves its Schur complement S_b, so ``(A^-1)_{T_b T_b} = S_b^-1`` with no second
factorisation. Pardiso's complement of the whole system on every body's T at once would be one dense
block of ``|T|^2`` entries instead of the sum of the ``|T_b|^2`` (measured in ``docs/contact.md``).
A body whose complement :class:`~skfem_affine.contact.schur.SchurInverse` declines (too few touched
unknowns without a kept analysis, more than half its unknowns, no contact) is factorised plainly on a
handle of its own; the Delassus operator then solves its unit columns with the frame's solver.
"""
import numpy as np
import scipy.sparse as sp


class BlockSolver:
    """The frame's solver when A is factorised block by block: ``solve(b)`` solves each block's rows of b
    with that block's handle (a block whose rows of b are zero has x = 0 there, unsolved: the Delassus
    operator's columns of one body). ``bounds``: the blocks' first unknowns and the end, increasing."""

    name = "pardiso-blocks"
    iterative = False

    def __init__(self, bounds, handles):
        self.bounds, self.handles = np.asarray(bounds, dtype=np.int64), list(handles)
        self.last_iterations = 1

    def solve(self, b):
        b = np.asarray(b, dtype=float)
        x = np.zeros_like(b)
        for s, e, handle in zip(self.bounds[:-1], self.bounds[1:], self.handles):
            if np.any(b[s:e]):
                x[s:e] = handle.solve(b[s:e])
        return x


def body_bounds(bodies):
    """The first unknown of each body with unknowns and the end (``bodies``: the body of each unknown), or
    None when a body's unknowns are not one contiguous range."""
    bodies = np.asarray(bodies)
    if bodies.size == 0 or np.any(np.diff(bodies) < 0):
        return None
    return np.concatenate([[0], np.flatnonzero(np.diff(bodies)) + 1, [bodies.size]]).astype(np.int64)


class UpperBlocks:
    """The upper triangle of a block-diagonal A, cut into its blocks without copying its pattern.

    The positions of the upper triangle in A's CSR pattern are kept with that pattern (a frame's
    pattern seldom changes), so each frame costs one gather; a pattern with an entry outside the
    blocks is refused once, when first seen."""

    def __init__(self):
        self._key = None  # (indptr, indices, bounds) of the last pattern
        self._take = None

    def split(self, A, bounds):
        """Per block ``[s, e)``: its upper triangle as CSR (sorted indices), or None when A couples blocks."""
        A = sp.csr_matrix(A)
        key = self._key
        if key is None or not (_same(key[0], A.indptr) and _same(key[1], A.indices) and _same(key[2], bounds)):
            P = sp.triu(sp.csr_matrix((np.arange(A.nnz, dtype=float), A.indices, A.indptr), shape=A.shape),
                        format="csr")
            P.sort_indices()
            row = np.repeat(np.arange(A.shape[0]), np.diff(P.indptr))
            end = bounds[np.searchsorted(bounds, row, side="right")]
            coupled = bool(np.any(P.indices >= end))
            self._key = (A.indptr.copy(), A.indices.copy(), np.array(bounds))
            self._take = None if coupled else (P.data.astype(np.int64), P.indptr, P.indices)
        if self._take is None:
            return None
        take, indptr, indices = self._take
        data = A.data[take]
        out = []
        for s, e in zip(bounds[:-1], bounds[1:]):
            p, q = indptr[s], indptr[e]
            out.append(sp.csr_matrix((data[p:q], indices[p:q] - s, indptr[s:e + 1] - p), shape=(e - s, e - s)))
        return out


def factorize_blocks(schur, A, T, bounds, split, plain):
    """A factorised block by block with each block's touched unknowns last where ``schur`` accepts.

    Parameters
    ----------
    schur : SchurInverse
        Decides per block (keyed by its size and first unknown) and keeps its analysis.
    A : sparse matrix
        The frame's whole symmetric matrix (CSR), block diagonal over ``bounds``.
    T : (k,) int array
        The sorted unknowns the contacts touch.
    bounds : int array
        The blocks' first unknowns and the end (:func:`body_bounds`).
    split : UpperBlocks
        Cuts A into its blocks' upper triangles.
    plain : callable
        ``plain(key)``: the plain Pardiso handle of a block whose complement is declined.

    Returns
    -------
    (BlockSolver, keep, [S_b]) or None
        The frame's solver, the unknowns eliminated last (sorted, the blocks' one after another) and
        each such block's complement, in the order of ``keep``; None when A couples blocks or no
        block's complement is taken (the caller then factorises A whole).
    """
    blocks = split.split(A, bounds)
    if blocks is None:
        return None
    cut = np.searchsorted(T, bounds)
    planned = []
    for i, (s, Ab) in enumerate(zip(bounds[:-1], blocks)):
        Tb = T[cut[i]:cut[i + 1]] - s
        out = schur.complement_block(Ab, Tb, (Ab.shape[0], int(s))) if Tb.size else None
        planned.append((int(s), Ab, out))
    if all(out is None for _, _, out in planned):
        return None
    handles, keep, parts = [], [], []
    for s, Ab, out in planned:
        if out is None:
            handle = plain((Ab.shape[0], s))
            handle.factorize(Ab, upper=True)
        else:
            handle, kept, S = out
            keep.append(kept + s)
            parts.append(S)
        handles.append(handle)
    return BlockSolver(bounds, handles), np.concatenate(keep), parts


def _same(a, b):
    return a.shape == b.shape and np.array_equal(a, b)
