r"""The volumetric energy on nodal volume ratios: near-incompressible bodies without locking.

Linear tetrahedra lock when the material is nearly incompressible: one volume constraint per
element leaves too few motions that keep every element's volume, so bending becomes far too stiff.
A body built with ``volumetric="nodal"`` moves the volumetric part of its energy from the
elements to the vertices, which are about five times fewer (one constraint per vertex):

.. math::

    \Psi(x) = \sum_e V_e\, \psi_\mathrm{shear}(F_e) + \sum_a \frac{\lambda_a V_a}{2} (J_a - 1)^2,
    \qquad J_a = \frac{v_a}{V_a},\quad v_a = \sum_{e \ni a} \frac{V_e \det F_e}{4},
    \quad V_a = \sum_{e \ni a} \frac{V_e}{4},

with :math:`\psi_\mathrm{shear}` the body's material at :math:`\lambda = 0` (the same class with
``E = 2 mu``, ``nu = 0``) and :math:`\lambda_a` the volume average of the elements' :math:`\lambda`
around vertex a. Small strains give linear elasticity with the body's (mu, lam), the volumetric
strain averaged over each vertex's patch (the average nodal pressure tetrahedron of Bonet and
Burton). The forces are the exact gradient of this energy and the stiffness its Hessian:

* the gradient: vertex pressures :math:`p_a = \lambda_a (J_a - 1)` act on every element through the
  stress :math:`\bar p_e\, \mathrm{cof} F_e`, :math:`\bar p_e` the mean of p over the element's vertices;
* the Hessian: per element :math:`\bar p_e\, \partial^2 \det F / \partial F^2` (added to the
  material's dP/dF, projected with it), and per vertex the positive semi-definite
  :math:`(\lambda_a / V_a)\, g_a g_a^T`, :math:`g_a = \partial v_a / \partial x`, which couples every
  pair of vertices of a's patch (the stiffness pattern widens to vertices two elements apart).
"""
import numpy as np
from numba import njit

from skfem_affine.materials import cofactor, det_hessian, determinant


class NodalVolume:
    """The vertex part of the energy above for the elements ``elems`` of a system.

    Parameters
    ----------
    t : (4, m) int array
        The system's elements (vertex indices).
    volumes : (m,) array
        Rest volumes V_e.
    grads : (m, 4, 3) array
        Rest shape gradients.
    elems : int array
        The elements whose volumetric energy lives on their vertices.
    lam : (len(elems),) array
        The first Lame parameter of each of those elements.
    n : int
        Number of vertices of the system.

    Attributes
    ----------
    vertices : int array
        The vertices of those elements (the a of the sums); ``rest`` (n,) holds V_a and ``lam``
        lam_a, one per entry of ``vertices``.
    """

    def __init__(self, t, volumes, grads, elems, lam, n):
        self.elems = np.asarray(elems, dtype=np.int64)
        te = t[:, self.elems]                                  # (4, k)
        k = self.elems.size
        quarter = np.tile(volumes[self.elems] / 4.0, 4)        # V_e / 4 per (vertex slot, element), j-major
        self.rest = np.bincount(te.ravel(), weights=quarter, minlength=n)              # V_a
        self.vertices = np.flatnonzero(self.rest > 0)
        self.lam = np.bincount(te.ravel(), weights=quarter * np.tile(lam, 4), minlength=n)[self.vertices] \
            / self.rest[self.vertices]                         # lam_a
        self._te = te
        self._quarter = volumes[self.elems] / 4.0
        self._vg = volumes[self.elems, None, None] * grads[self.elems]   # (k, 4, 3)
        # the patch of vertex a: the vertices of the elements around it; one row per
        # (vertex a, element e around a), listing where e's four vertices sit in a's patch
        inc_vertex, inc_elem = te.ravel(), np.tile(np.arange(k), 4)
        keys = inc_vertex[:, None] * n + te[:, inc_elem].T     # (4k, 4)
        ukeys, where = np.unique(keys.ravel(), return_inverse=True)
        self._where = where.reshape(-1, 4)                     # entry of the flat patch list
        self._inc_elem = inc_elem
        self.patch_vertex = ukeys % n                          # flat patch list, grouped by owner
        owner = np.searchsorted(self.vertices, ukeys // n)
        self.patch_ptr = np.concatenate([[0], np.cumsum(np.bincount(owner, minlength=self.vertices.size))])

    def couplings(self):
        """Global DOF pairs (rows, cols) of the vertex terms, in the order :meth:`add_hessian` writes them."""
        size = np.diff(self.patch_ptr)
        owner = np.repeat(np.arange(size.size), size)          # per flat patch entry
        s1 = np.repeat(np.arange(owner.size), size[owner])     # pairs (s1, s2) of one patch, s1-major
        first = np.repeat(np.cumsum(size[owner]) - size[owner], size[owner])
        s2 = self.patch_ptr[owner[s1]] + np.arange(s1.size) - first
        r = 3 * self.patch_vertex[s1][:, None, None] + np.arange(3)[None, :, None]
        c = 3 * self.patch_vertex[s2][:, None, None] + np.arange(3)[None, None, :]
        r, c = np.broadcast_arrays(r, c)
        return r.ravel(), c.ravel()

    def ratios(self, F):
        """J_a of the vertices ``vertices`` from the deformation gradients F (m, 3, 3) of the whole system."""
        v = np.tile(self._quarter * determinant(F[self.elems]), 4)   # V_e det F_e / 4 at each vertex
        return np.bincount(self._te.ravel(), weights=v, minlength=self.rest.size)[self.vertices] \
            / self.rest[self.vertices]

    def energy(self, F):
        """sum_a lam_a V_a / 2 (J_a - 1)^2."""
        J = self.ratios(F)
        return float(np.sum(0.5 * self.lam * self.rest[self.vertices] * (J - 1.0) ** 2))

    def element_pressures(self, F):
        """p-bar_e (k,): the mean over each element's vertices of p_a = lam_a (J_a - 1)."""
        p = np.zeros(self.rest.size)
        p[self.vertices] = self.lam * (self.ratios(F) - 1.0)
        return p[self._te].mean(axis=0)

    def element_terms(self, F, tangent=True):
        """The stresses p-bar_e cof F_e (k, 3, 3) and, if asked, their dP/dF p-bar_e d^2 det F (k, 9, 9)."""
        Fv = F[self.elems]
        pbar = self.element_pressures(F)
        P = pbar[:, None, None] * cofactor(Fv)
        C = pbar[:, None, None] * det_hessian(Fv).reshape(-1, 9, 9) if tangent else None
        return P, C

    def add_hessian(self, F, slot, out):
        """out[slot] += the vertex terms (lam_a / V_a) g_a g_a^T, slot from :meth:`couplings` on a pattern."""
        Fv = F[self.elems]
        dv = np.einsum("eij,ekj->eki", cofactor(Fv), self._vg)    # d v_e / d x_k = V_e cof(F_e) grad phi_k
        contrib = 0.25 * dv[self._inc_elem]                       # (4k, 4, 3): into g of the row's vertex
        g = np.stack([np.bincount(self._where.ravel(), weights=contrib[:, :, i].ravel(),
                                  minlength=self.patch_vertex.size) for i in range(3)], axis=1)
        _patch_outer(self.patch_ptr, self.lam / self.rest[self.vertices], g, slot, out)
        return out


@njit(cache=True)
def _patch_outer(ptr, w, g, slot, out):
    """out[slot[q]] += w_a g[s1, i] g[s2, j] over the vertices a, the pairs (s1, s2) of a's patch, i, j."""
    q = 0
    for a in range(w.size):
        for s1 in range(ptr[a], ptr[a + 1]):
            for s2 in range(ptr[a], ptr[a + 1]):
                for i in range(3):
                    wi = w[a] * g[s1, i]
                    for j in range(3):
                        k = slot[q]
                        q += 1
                        if k >= 0:
                            out[k] += wi * g[s2, j]
