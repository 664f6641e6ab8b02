"""Element subdomains of a fixed METIS vertex partition and their exact subspace Hessians (sec. 3.6, 3.9).

Subdomains are element sets (an element belongs to the part of its first vertex), so the subdomain
energies sum exactly to Psi: sum_l U^T H_l U = U^T H U.
"""
import numpy as np
import scipy.sparse as sp

from skfem_affine._kernels import scatter_add
from skfem_affine.assembly import Pattern


class BlockDiagonal:
    """CSR pattern of a block-diagonal matrix stacked from per-block :class:`Pattern` s."""

    def __init__(self, patterns):
        nnz = np.cumsum([0] + [p.nnz for p in patterns])
        size = np.cumsum([0] + [p.shape[0] for p in patterns])
        self.slot = np.concatenate([np.where(p.slot >= 0, p.slot + o, -1) for p, o in zip(patterns, nnz[:-1])])
        self.indices = np.concatenate([p.indices + s for p, s in zip(patterns, size[:-1])]).astype(np.int32)
        self.indptr = np.concatenate([[0]] + [p.indptr[1:] + o for p, o in zip(patterns, nnz[:-1])]).astype(np.int32)
        self.nnz, self.shape = int(nnz[-1]), (int(size[-1]), int(size[-1]))

    def scatter(self, blocks):
        return scatter_add(self.slot, blocks.reshape(-1), self.nnz)

    def matrix(self, data):
        return sp.csr_matrix((data, self.indices, self.indptr), shape=self.shape)


class Subdomains:
    """Element subdomains of a fixed vertex partition with the data for exact U^T H_l U (sec. 3.9)."""

    def __init__(self, system, parts):
        self.parts = parts
        self.L = int(parts.max()) + 1
        self.of_element = parts[system.t[0]]
        dof_map = np.full(3 * system.n, -1, dtype=np.int64)
        dof_map[system.free] = np.arange(system.free.size)
        self.elems, self.dofs, self.patterns = [], [], []
        self.local = np.full((system.m, 12), -1, dtype=np.int64)  # DOF's index within its element's subdomain
        order = np.argsort(self.of_element, kind="stable")
        bounds = np.searchsorted(self.of_element[order], np.arange(self.L + 1))
        for l in range(self.L):  # once, at set-up: per-subdomain element and DOF lists
            el = order[bounds[l]:bounds[l + 1]]
            ed = dof_map[system.edofs[el]]  # (k, 12)
            dofs = np.unique(ed[ed >= 0])
            self.local[el] = np.where(ed >= 0, np.searchsorted(dofs, np.where(ed >= 0, ed, 0)), -1)
            self.elems.append(el)
            self.dofs.append(dofs)
            loc = self.local[el]
            self.patterns.append(Pattern(np.where(loc >= 0, loc, dofs.size),
                                         np.concatenate([np.arange(dofs.size), [-1]])))
        rows = dof_map[system.edofs].ravel()
        ok = rows >= 0
        self.grad_rows, self.grad_cols, self.grad_keep = rows[ok], np.repeat(self.of_element, 12)[ok], ok
        self.nfree = system.free.size
        self._stacks = {}

    def exact(self, He, which, U):
        """U_l^T H_l U_l (len(which), a, a) from element blocks He (m, 12, 12).

        The subdomains' elastic Hessians are scattered at once into one block-diagonal sparse
        matrix over their stacked local DOFs; then one sparse product H U and a small dense
        product per subdomain.
        """
        which = np.asarray(list(which), dtype=np.int64)
        a = U.shape[1]
        out = np.zeros((which.size, a, a))
        if not which.size:
            return out
        pattern, elems, off, dofs = self._stacked(which)
        HU = pattern.matrix(pattern.scatter(He[elems])) @ U[dofs]
        Us = U[dofs]
        for k in range(len(which)):  # small dense products, one per subdomain
            seg = slice(off[k], off[k + 1])
            out[k] = Us[seg].T @ HU[seg]
        return out

    def exact_sum(self, He, which, U, masked=None):
        """sum_l B_l^T H_l B_l over subdomains ``which`` (a, a), B = U with the rows in the boolean
        mask ``masked`` (free DOFs) zeroed; only the unmasked rows are multiplied."""
        which = np.asarray(list(which), dtype=np.int64)
        a = U.shape[1]
        if not which.size:
            return np.zeros((a, a))
        pattern, elems, off, dofs = self._stacked(which)
        H = pattern.matrix(pattern.scatter(He[elems]))
        if masked is None:
            Us = U[dofs]
            return Us.T @ (H @ Us)
        keep = np.flatnonzero(~masked[dofs])
        Bs = U[dofs[keep]]
        return Bs.T @ (H[keep][:, keep] @ Bs)

    def _stacked(self, which):
        """Block-diagonal pattern of subdomains ``which`` over their stacked local DOFs, stacked
        from the per-subdomain patterns (no sorting), with the elements, DOF offsets and DOFs."""
        key = which.tobytes()
        if key not in self._stacks:
            if len(self._stacks) >= 8:
                self._stacks.pop(next(iter(self._stacks)))
            off = np.concatenate([[0], np.cumsum([self.dofs[l].size for l in which])])
            self._stacks[key] = (BlockDiagonal([self.patterns[l] for l in which]),
                                 np.concatenate([self.elems[l] for l in which]), off,
                                 np.concatenate([self.dofs[l] for l in which]))
        return self._stacks[key]

    def projected_gradients(self, ge, U):
        """U^T grad Psi_l per subdomain, (L, a), from element gradients ge (m, 4, 3)."""
        G = sp.csr_matrix((ge.reshape(-1)[self.grad_keep], (self.grad_rows, self.grad_cols)),
                          shape=(self.nfree, self.L))
        return np.asarray((G.T @ U))
