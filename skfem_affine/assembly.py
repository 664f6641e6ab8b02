"""Per-frame assembly of internal forces and stiffness into a fixed sparsity pattern.

:class:`ElasticSystem` merges one or more :class:`~skfem_affine.body.ElasticBody`
into one set of arrays (vertices, elements, rest shape gradients, materials,
mass) and precomputes, once, the CSR pattern of the stiffness restricted to
the free DOFs together with the scatter index of every element-matrix entry.
Each frame then costs: F for all elements, one compiled pass per element giving P,
the (PSD-projected) dP/dF, the 12 x 12 block and the element force
(:func:`~skfem_affine._eigensystems.evaluate_elements`), and two scatters.

Sign convention: ``f`` is the internal force ``-dPsi/dx``; the assembled
``H = dPsi^2/dx^2 = -K`` is the (positive) stiffness, K = df/dx of paper eq. 1.
"""
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import skfem
from skfem import Basis, BilinearForm, ElementTetP1, ElementVector, asm
from skfem.helpers import dot

from skfem_affine._eigensystems import GENERIC, evaluate_elements, internal_force, scatter_forces
from skfem_affine._kernels import deformation_gradients, element_hessians, scatter_add
from skfem_affine.body import check_bodies
from skfem_affine.checks import choice
from skfem_affine.kinematics import deformation_operator, element_dofs
from skfem_affine.materials import shear_part
from skfem_affine.nodal_volume import NodalVolume
from skfem_affine.threads import serial_blas


@dataclass
class FrameData:
    """Per-frame evaluation of the elastic energy (see :meth:`ElasticSystem.evaluate`)."""

    F: np.ndarray   # (m, 3, 3) deformation gradients
    P: np.ndarray   # (m, 3, 3) first Piola-Kirchhoff stresses
    C: np.ndarray   # (m, 9, 9) dP/dF as used (symmetrised, PSD-projected if asked)
    He: np.ndarray  # (m, 12, 12) element stiffness blocks V G^T C G
    f: np.ndarray   # (3n,) internal forces
    H: np.ndarray   # stiffness data on ElasticSystem.pattern (free DOFs)


_NONE = np.empty((0, 4, 3))


def _restricted(mat, idx, sel):
    """The material of the group on elements ``idx`` restricted to its elements ``sel`` (a subset)."""
    if np.ndim(mat.E):  # per-element parameters of a merged material group
        pos = np.searchsorted(idx, sel)
        return type(mat)(E=mat.E[pos], nu=mat.nu[pos])
    return mat


class Pattern:
    """CSR pattern of the element matrices restricted to a subset of DOFs.

    ``dof_map[g]`` is the row/column of global DOF ``g`` in the restricted
    matrix, or -1 when the DOF is dropped (fixed).
    """

    def __init__(self, edofs, dof_map, couplings=None):
        size = int(dof_map.max()) + 1
        r = dof_map[edofs[:, :, None]]
        c = dof_map[edofs[:, None, :]]
        r, c = np.broadcast_arrays(r, c)
        keep = ((r >= 0) & (c >= 0)).ravel()
        key = r.ravel()[keep] * size + c.ravel()[keep]
        if couplings is not None:  # DOF pairs beyond the elements' (rows, cols), e.g. NodalVolume.couplings()
            xr, xc = dof_map[couplings[0]], dof_map[couplings[1]]
            xkeep = (xr >= 0) & (xc >= 0)
            key = np.concatenate([key, xr[xkeep] * size + xc[xkeep]])
        ukey, slot = np.unique(key, return_inverse=True)
        # per element-matrix entry, -1: dropped; int32, the width of the CSR indices, halves what the
        # scatter reads (measured in docs/integration.md)
        self.slot = np.full(keep.size, -1, dtype=np.int32)
        self.slot[keep] = slot[:int(keep.sum())]
        self.coupling_slot = None  # the same for each pair of ``couplings``
        if couplings is not None:
            self.coupling_slot = np.full(xkeep.size, -1, dtype=np.int32)
            self.coupling_slot[xkeep] = slot[int(keep.sum()):]
        rows, cols = ukey // size, ukey % size
        self.indptr = np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=size))])
        self.indices = cols.astype(np.int32)
        self.indptr = self.indptr.astype(np.int32)
        self.rows = rows
        self.shape = (size, size)
        self.nnz = ukey.size
        self.diagonal = np.searchsorted(ukey, np.arange(size) * (size + 1))
        self.upper = np.flatnonzero(cols >= rows)

    def scatter(self, blocks):
        """Sum element blocks (m, 12, 12) into the pattern's data array."""
        return scatter_add(self.slot, blocks.reshape(-1), self.nnz)

    def matrix(self, data):
        return sp.csr_matrix((data, self.indices, self.indptr), shape=self.shape)

    def vertex_graph(self):
        """CSR ``(indptr, indices)`` of the vertex-level graph (DOFs 3u..3u+2 = vertex u), self-loops included.

        Valid when whole vertices are kept or dropped (fixed vertices), as here; built on first use.
        """
        if getattr(self, "_vertex_graph", None) is None:
            P = self.matrix(np.ones(self.nnz))[::3, ::3].tocsr()
            P.sort_indices()
            if 9 * P.nnz != self.nnz:
                raise ValueError("the pattern is not made of whole 3 x 3 vertex blocks")
            self._vertex_graph = (P.indptr.astype(np.int64), P.indices.astype(np.int64))
        return self._vertex_graph

    def locate(self, A):
        """Positions in this pattern of the nonzeros of a (restricted) sparse matrix A."""
        A = A.tocoo()
        key = A.row.astype(np.int64) * self.shape[0] + A.col
        ukey = self.rows.astype(np.int64) * self.shape[0] + self.indices
        pos = np.searchsorted(ukey, key)
        if np.any(pos >= ukey.size) or np.any(ukey[np.minimum(pos, ukey.size - 1)] != key):
            raise ValueError("matrix has entries outside the pattern")
        return pos, A.data


class ElasticSystem:
    """All bodies of a scene as one discrete system with precomputed rest data.

    Parameters
    ----------
    bodies : list of ElasticBody
    mass : {"lumped", "consistent"}
        Lumped (default, as the paper's code) is diagonal, rho V / 4 per vertex.
    """

    def __init__(self, bodies, mass="lumped"):
        choice(mass, "mass", ("lumped", "consistent"))
        self.bodies = check_bodies(bodies)
        offsets = np.cumsum([0] + [b.n_vertices for b in self.bodies])
        eoffsets = np.cumsum([0] + [b.n_elements for b in self.bodies])
        self.vertex_offsets, self.element_offsets = offsets, eoffsets
        self.body_of_vertex = np.repeat(np.arange(len(self.bodies)), np.diff(offsets))  # (n,) the body of each vertex
        self.n, self.m = int(offsets[-1]), int(eoffsets[-1])
        self.p0 = np.concatenate([b.mesh.p.T for b in self.bodies])
        self.t = np.concatenate([b.mesh.t + o for b, o in zip(self.bodies, offsets)], axis=1)
        self.grads = np.concatenate([b.grads for b in self.bodies])
        self.volumes = np.concatenate([b.volumes for b in self.bodies])
        self.density = np.concatenate([b.density for b in self.bodies])
        # every vertex whose position is not an unknown: fixed ones and prescribed (moving) ones
        self.fixed = np.concatenate([b.fixed for b in self.bodies])
        self.prescribed = np.zeros(self.n, dtype=bool)
        for b, o in zip(self.bodies, offsets):
            for idx in getattr(b, "prescribed_vertices", ()):
                self.prescribed[idx + o] = True
        self.fixed = self.fixed | self.prescribed
        self.body_of_element = np.repeat(np.arange(len(self.bodies)), np.diff(eoffsets))
        self._group_materials()
        self.edofs = element_dofs(self.t)
        self._vg = self.volumes[:, None, None] * self.grads  # V_e grad phi, (m, 4, 3)
        fixed_dofs = np.repeat(self.fixed, 3)
        self.free = np.flatnonzero(~fixed_dofs)
        dof_map = np.full(3 * self.n, -1, dtype=np.int64)
        dof_map[self.free] = np.arange(self.free.size)
        self.pattern = Pattern(self.edofs, dof_map, None if self.nodal is None else self.nodal.couplings())
        self._full_pattern = None
        self.mass_kind = mass
        self._assemble_mass()

    # ------------------------------------------------------------------ rest data
    def _group_materials(self):
        """Group elements by material kind; one vectorised material per group.

        ``groups`` holds the bodies' materials. The elements evaluate ``evaluated_groups``:
        the same, except in bodies with ``volumetric="nodal"``, whose elements carry their
        material's shear part (:func:`~skfem_affine.materials.shear_part`) and whose volumetric
        energy is ``nodal``'s (:mod:`skfem_affine.nodal_volume`).
        """
        mats, index, evaluated = [], [], []
        for b in self.bodies:
            index.append(b.material_index + len(mats))
            mats.extend(b.materials)
            evaluated.extend(shear_part(mt) if b.volumetric == "nodal" else mt for mt in b.materials)
        self.material_list = mats
        self.material_index = np.concatenate(index)
        self.groups = self._by_kind(mats)
        nodal_bodies = [i for i, b in enumerate(self.bodies) if b.volumetric == "nodal"]
        self.nodal = None  # the vertex part of the energy of the bodies with volumetric="nodal"
        self.evaluated_groups = self.groups
        if nodal_bodies:
            self.evaluated_groups = self._by_kind(evaluated)
            lam = np.zeros(self.m)
            for mat, elems in self.groups:
                lam[elems] = mat.lam
            elems = np.flatnonzero(np.isin(self.body_of_element, nodal_bodies))
            self.nodal = NodalVolume(self.t, self.volumes, self.grads, elems, lam[elems], self.n)
        # per-element closed-form code and parameters of the compiled pass; other materials
        # (user subclasses) give P and dP/dF themselves, group by group
        self._code = np.zeros(self.m, dtype=np.int64)
        self._mu, self._lam = np.zeros(self.m), np.zeros(self.m)
        self._generic = []
        for mat, elems in self.evaluated_groups:
            if mat.closed_form():
                self._code[elems] = mat._code
                self._mu[elems], self._lam[elems] = mat.mu, mat.kernel_lam
            else:
                self._generic.append((mat, elems))
        # the codes of the compiled pass: the elements of nodal bodies come with their P and dP/dF
        self._pass_code = self._code
        if self.nodal is not None:
            self._pass_code = self._code.copy()
            self._pass_code[self.nodal.elems] = GENERIC

    def _by_kind(self, mats):
        """[(material, elements)] with one material per class (merged to per-element (E, nu) if several)."""
        groups = []
        for cls in dict.fromkeys(type(mt) for mt in mats):
            ids = [i for i, mt in enumerate(mats) if type(mt) is cls]
            elems = np.flatnonzero(np.isin(self.material_index, ids))
            if len(ids) == 1:
                mat = mats[ids[0]]
            else:
                mat = cls.merged([mats[i] for i in self.material_index[elems]])
            groups.append((mat, elems))
        return groups

    def _assemble_mass(self):
        """Consistent mass with scikit-fem per body; lumped = its row sums (rho V / 4)."""
        blocks = []
        for b in self.bodies:
            basis = Basis(b.mesh, ElementVector(ElementTetP1()), intorder=2)
            rho = basis.with_element(skfem.ElementTetP0()).interpolate(b.density) \
                if np.ptp(b.density) > 0 else float(b.density[0])

            @BilinearForm
            def mass(u, v, w):
                return w.rho * dot(u, v)

            blocks.append(asm(mass, basis, rho=rho))
        Mc = sp.block_diag(blocks, format="csr")
        self.lumped_mass = np.asarray(Mc.sum(axis=1)).ravel()[::3].copy()  # per vertex
        if self.mass_kind == "lumped":
            self.M = sp.diags(np.repeat(self.lumped_mass, 3)).tocsr()
        else:
            self.M = Mc
        Mff = self.M[self.free][:, self.free]
        pos, vals = self.pattern.locate(Mff)
        self.mass_data = np.bincount(pos, weights=vals, minlength=self.pattern.nnz)
        self.Mff = Mff

    @property
    def full_pattern(self):
        """Pattern over all DOFs (fixed included); built on first use."""
        if self._full_pattern is None:
            self._full_pattern = Pattern(self.edofs, np.arange(3 * self.n),
                                         None if self.nodal is None else self.nodal.couplings())
        return self._full_pattern

    def deformation_operator(self):
        """B (9m x 3n), F = B x (eq. 3)."""
        return deformation_operator(self.t, self.grads, self.n)

    # ------------------------------------------------------------------ per frame
    def deformation_gradients(self, x):
        """F (or F_dot from velocities) of every element at x (n, 3), eq. 3-4; (m, 3, 3)."""
        out = np.empty((self.m, 3, 3))
        deformation_gradients(np.ascontiguousarray(x, dtype=float), self.t, self.grads, out)
        return out

    def strain_energy(self, x):
        """Total elastic energy sum_e V_e psi(F_e), and the vertex part of nodal bodies (``nodal``)."""
        F = self.deformation_gradients(x)
        psi = float(sum(np.dot(self.volumes[idx], mat.energy_density(F[idx])) for mat, idx in self.evaluated_groups))
        return psi if self.nodal is None else psi + self.nodal.energy(F)

    def stresses(self, F, tangent=True, project=True):
        """P (m, 3, 3) and, if asked, dP/dF (m, 3, 3, 3, 3) for all elements (F of all elements).

        In nodal bodies P includes the vertex pressures and dP/dF their element part
        (:mod:`skfem_affine.nodal_volume`); the couplings between vertices are not per element.
        """
        if self.nodal is not None:
            P, C, _, _ = self._elements(np.ascontiguousarray(F, dtype=float), tangent, project, blocks=False)
            return P, (C.reshape(-1, 3, 3, 3, 3) if tangent else None)
        if len(self.groups) == 1:
            mat = self.groups[0][0]
            return mat.stress(F), (mat.stress_derivative(F, project=project) if tangent else None)
        P = np.empty_like(F)
        C = np.empty((F.shape[0], 3, 3, 3, 3)) if tangent else None
        for mat, idx in self.groups:
            P[idx] = mat.stress(F[idx])
            if tangent:
                C[idx] = mat.stress_derivative(F[idx], project=project)
        return P, C

    def element_stiffness(self, F, C, project=True):
        """Element stiffness blocks V G^T C G (m, 12, 12), C projected to PSD if asked.

        Returns ``(He, C9)`` with C9 (m, 9, 9) the symmetrised (projected) dP/dF used.
        """
        He = np.empty((self.m, 12, 12))
        C9 = np.ascontiguousarray(C.reshape(-1, 9, 9))
        element_hessians(C9, F, self._vg, self.grads, project, He)
        return He, C9

    def _elements(self, F, tangent=True, project=True, blocks=True):
        """One compiled pass over the elements: P, dP/dF (m, 9, 9), blocks He and the force f.

        dP/dF and He are zero-length when not asked; the closed-form materials are
        evaluated in the pass, the others (:attr:`_generic`) and the elements of nodal bodies
        (``_nodal_tensors``) first.
        """
        m = self.m
        P, C = np.empty((m, 3, 3)), np.empty((m if tangent else 0, 9, 9))
        for mat, idx in self._generic:
            P[idx] = mat.stress(F[idx])
            if tangent:
                C[idx] = mat.stress_derivative(F[idx], project=False).reshape(-1, 9, 9)
        if self.nodal is not None:
            v = self.nodal.elems
            P[v], Cv = self._nodal_tensors(F, tangent)
            if tangent:
                C[v] = Cv
        He, fe = np.empty((m if blocks else 0, 12, 12)), np.empty((m, 4, 3))
        evaluate_elements(F, self._pass_code, self._mu, self._lam, project, P, C, self._vg, self.grads, He, fe)
        return P, C, He, scatter_forces(self.t, fe, self.n)

    def _nodal_tensors(self, F, tangent):
        """P (k, 3, 3) and unprojected dP/dF (k, 9, 9) of the elements of nodal bodies, ``nodal``.elems:
        their material's shear part plus the vertex pressure terms."""
        v = self.nodal.elems
        P, C = np.empty((v.size, 3, 3)), np.empty((v.size if tangent else 0, 9, 9))
        closed = np.flatnonzero(self._code[v] != GENERIC)
        c = v[closed]
        Pc, Cc = np.empty((c.size, 3, 3)), np.empty((c.size if tangent else 0, 9, 9))
        evaluate_elements(np.ascontiguousarray(F[c]), self._code[c], self._mu[c], self._lam[c], False, Pc, Cc,
                          _NONE, _NONE, np.empty((0, 12, 12)), _NONE)
        P[closed] = Pc
        if tangent:
            C[closed] = Cc
        for mat, idx in self._generic:
            sel = np.intersect1d(idx, v)
            if sel.size:
                pos, mat = np.searchsorted(v, sel), _restricted(mat, idx, sel)
                P[pos] = mat.stress(F[sel])
                if tangent:
                    C[pos] = mat.stress_derivative(F[sel], project=False).reshape(-1, 9, 9)
        Pp, Cp = self.nodal.element_terms(F, tangent)
        P += Pp
        if tangent:
            C += Cp
        return P, C

    def _add_vertex_couplings(self, F, pattern, data):
        """data (on ``pattern``) plus the vertex couplings of nodal bodies, if any."""
        if self.nodal is not None:
            self.nodal.add_hessian(F, pattern.coupling_slot, data)
        return data

    def evaluate(self, x, project=True):
        """Everything one frame needs from the elastic energy at positions x (n, 3).

        Returns a :class:`FrameData` with F, P, the (projected) dP/dF per element,
        the element stiffness blocks, the internal force f (3n,) and the stiffness
        H = -K as data on :attr:`pattern` (free DOFs).
        """
        with serial_blas():
            F = self.deformation_gradients(x)
            P, C, He, f = self._elements(F, project=project)
            H = self._add_vertex_couplings(F, self.pattern, self.pattern.scatter(He))
            return FrameData(F=F, P=P, C=C, He=He, f=f, H=H)

    def evaluate_tangent(self, x, project=True):
        """Like :meth:`evaluate` but without element blocks: F, P, (projected) dP/dF and f.

        For reducers that assemble blocks only where they need them (:meth:`partial_stiffness`).
        """
        F = self.deformation_gradients(x)
        P, C, _, f = self._elements(F, project=project, blocks=False)
        return FrameData(F=F, P=P, C=C, He=None, f=f, H=None)

    def element_blocks(self, F, elems, project=True):
        """Element blocks V G^T C G (k, 12, 12) of ``elems`` only, dP/dF evaluated (and projected) only there."""
        elems = np.asarray(elems)
        C = np.empty((elems.size, 9, 9))
        for mat, idx in self._generic:
            mask = np.isin(elems, idx)
            if not np.any(mask):
                continue
            sel = elems[mask]
            C[mask] = _restricted(mat, idx, sel).stress_derivative(F[sel], project=False).reshape(-1, 9, 9)
        if self.nodal is not None:
            mask = np.isin(elems, self.nodal.elems)
            if np.any(mask):
                C[mask] = self._nodal_tensors(F, True)[1][np.searchsorted(self.nodal.elems, elems[mask])]
        He = np.empty((elems.size, 12, 12))
        evaluate_elements(np.ascontiguousarray(F[elems]), self._pass_code[elems], self._mu[elems], self._lam[elems],
                          project, np.empty((0, 3, 3)), C, np.ascontiguousarray(self._vg[elems]),
                          np.ascontiguousarray(self.grads[elems]), He, np.empty((0, 4, 3)))
        return He

    def partial_stiffness(self, data, elems):
        """Element blocks of ``elems`` only, and their sum on :attr:`pattern` (the others left out;
        the vertex couplings of nodal bodies, which belong to no element, always in).

        ``data.C`` must be the tensor to use (already projected). Returns (He[elems], H data).
        """
        He = np.empty((elems.size, 12, 12))
        element_hessians(np.ascontiguousarray(data.C[elems]), np.ascontiguousarray(data.F[elems]),
                         np.ascontiguousarray(self._vg[elems]), np.ascontiguousarray(self.grads[elems]),
                         False, He, True)
        slot = self.pattern.slot.reshape(self.m, 144)[elems].ravel()
        return He, self._add_vertex_couplings(data.F, self.pattern, scatter_add(slot, He.reshape(-1), self.pattern.nnz))

    def _internal_force(self, P):
        """f = -sum_e V_e P_e grad phi (3n,)."""
        return internal_force(np.ascontiguousarray(P, dtype=float), self._vg, self.t, self.n)

    def forces_and_stiffness(self, x, project=True, full=False, tangent=True):
        """Internal forces f (3n,) and stiffness H = -K at positions x (n, 3).

        Returns ``(f, H)``: by default ``H`` is the data array on
        :attr:`pattern` (free DOFs only); with ``full=True`` a CSR matrix over
        all 3n DOFs. ``tangent=False`` skips H (returns None).
        """
        if not tangent:
            return self._elements(self.deformation_gradients(x), tangent=False, blocks=False)[3], None
        if not full:
            d = self.evaluate(x, project)
            return d.f, d.H
        F = self.deformation_gradients(x)
        _, _, He, f = self._elements(F, project=project)
        pat = self.full_pattern
        return f, pat.matrix(self._add_vertex_couplings(F, pat, pat.scatter(He)))

    def gravity_force(self, g):
        """External force M g (3n,)."""
        return self.M @ np.tile(np.asarray(g, dtype=float), self.n)

    def split(self, x):
        """Per-body views of a stacked (n, ...) array."""
        o = self.vertex_offsets
        return [x[o[i]:o[i + 1]] for i in range(len(self.bodies))]
