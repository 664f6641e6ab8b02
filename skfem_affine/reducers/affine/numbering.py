"""A reduced frame's unknowns in the full space's numbering, for scenes of several bodies.

A :class:`~skfem_affine.reducers.affine.mapping.Mapping` numbers its columns compactly: the elastic
free DOFs in their order, then the bodies' columns. When a body forms or dissolves, every elastic
unknown after it moves. The contact's Delassus operator factorises each scene body's block of the
frame's system on its own, and keeps that block's analysis under the block's size and first unknown
(:class:`~skfem_affine.contact.delassus.Resolvent`): in the compact numbering a cluster changing in
one body moves the blocks of all the bodies after it, and each of them is analysed anew.

:class:`FullNumbering` renumbers a frame so that elastic free DOF k is unknown k, as in full space, and
the bodies' columns follow all the free DOFs. The free DOFs of reduced vertices keep their unknowns,
decoupled from everything (their row of the system is ``c_M m_k`` on the diagonal, their column of G
is empty, their right-hand side zero, so their solution is zero). A scene body whose clusters did not
change then keeps its block, at the same place, as in full space. The renumbering is increasing, so
an upper triangle stays one, rows stay sorted, and the products with G are the compact ones.
"""
import numpy as np
import scipy.sparse as sp
from numba import njit

from skfem_affine import _compile_notice  # noqa: F401 (one stderr line when the cached kernels compile)


def several_bodies(bodies):
    """Whether the body of each free DOF, ``bodies`` (or None), names more than one body."""
    return bodies is not None and np.size(bodies) > 0 and int(np.min(bodies)) != int(np.max(bodies))


class FullNumbering:
    """The renumbering of one frame's reduced unknowns (module docstring).

    Parameters
    ----------
    gmap : Mapping
        The frame's mapping (compact numbering).
    diagonal : (n_free,) array
        The value on the diagonal of each free DOF's own unknown when its vertex is reduced
        (``c_M`` times the lumped mass: the scale of the system's diagonal).

    Attributes
    ----------
    columns : (r,) int array
        The unknown of each compact column: increasing.
    idle : int array
        The unknowns of reduced vertices' free DOFs (no column of G).
    size : int
        Unknowns in the full numbering (free DOFs plus the bodies' columns).
    body_rows : (n_bodies,) int array
        A free DOF (row of G) of each reduced body.
    """

    def __init__(self, gmap, diagonal):
        nf, r, ne = gmap.G.shape[0], gmap.G.shape[1], gmap.n_elastic
        self.columns = np.concatenate([gmap.elastic_dofs, nf + np.arange(r - ne)]).astype(np.int64)
        self.size = nf + r - ne
        used = np.zeros(self.size, dtype=bool)
        used[self.columns] = True
        self.idle = np.flatnonzero(~used)
        self.idle_values = np.asarray(diagonal, dtype=float)[self.idle]  # idle unknowns are free DOFs (< nf)
        # one free DOF of each reduced body (the first of its rows)
        G = gmap.G
        first = np.full(gmap.n_bodies, nf, dtype=np.int64)
        rows = np.repeat(np.arange(nf), np.diff(G.indptr))
        on_body = G.indices >= ne
        np.minimum.at(first, (G.indices[on_body] - ne) // gmap.width, rows[on_body])
        self.body_rows = first

    def mapping(self, G):
        """G (n_free x r, CSR) with its columns renumbered (n_free x size)."""
        G = sp.csr_matrix(G)
        return sp.csr_matrix((G.data, self.columns[G.indices].astype(G.indices.dtype), G.indptr),
                             shape=(G.shape[0], self.size))

    def matrix(self, A):
        """The reduced matrix A_r (r x r CSR, whole or upper triangle, rows sorted) renumbered, with the
        idle unknowns' diagonal (size x size CSR)."""
        A = sp.csr_matrix(A)
        indptr, indices, data = _renumbered(A.indptr, A.indices, A.data, self.columns, self.size, self.idle,
                                            self.idle_values)
        return sp.csr_matrix((data, indices, indptr), shape=(self.size, self.size))

    def vector(self, b):
        """A reduced right-hand side (r,) renumbered (size,), zero on the idle unknowns."""
        out = np.zeros(self.size)
        out[self.columns] = b
        return out

    def order(self, order):
        """An elimination order of the compact unknowns (int array) renumbered: the idle unknowns
        first (they fill nothing), then the others in the given order (int32)."""
        return np.concatenate([self.idle, self.columns[np.asarray(order)]]).astype(np.int32)

    def compact(self, x):
        """The compact entries (r,) of a vector in the full numbering (size,)."""
        return np.asarray(x)[self.columns]


@njit(cache=True)
def _renumbered(indptr, indices, data, columns, size, idle, idle_values):
    """CSR (indptr, indices, data) of rows and columns moved by the increasing ``columns``, and the
    ``idle`` unknowns' diagonal entries ``idle_values`` (int32 index arrays)."""
    r = indptr.size - 1
    out_ptr = np.zeros(size + 1, dtype=np.int32)
    for i in range(size):
        out_ptr[i + 1] = 1
    for i in range(r):
        out_ptr[columns[i] + 1] = indptr[i + 1] - indptr[i]
    for i in range(size):
        out_ptr[i + 1] += out_ptr[i]
    out_ind = np.empty(out_ptr[size], dtype=np.int32)
    out_val = np.empty(out_ptr[size])
    for i in range(r):
        p = out_ptr[columns[i]]
        for q in range(indptr[i], indptr[i + 1]):
            out_ind[p] = columns[indices[q]]
            out_val[p] = data[q]
            p += 1
    for j in range(idle.size):
        out_ind[out_ptr[idle[j]]] = idle[j]
        out_val[out_ptr[idle[j]]] = idle_values[j]
    return out_ptr, out_ind, out_val
