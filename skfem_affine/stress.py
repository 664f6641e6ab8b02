r"""Strains and stresses of a state: per element and averaged to the vertices.

For P1 tetrahedra the deformation gradient F is constant in each element, so every quantity
below is one value per element; :attr:`Stresses.vertex` holds their averages at the vertices.

Per element, from F and the element's own material (:meth:`~skfem_affine.materials.Material.stress`
and :meth:`~skfem_affine.materials.Material.energy_density`):

================================  ==================================================  ========
field                             definition                                          unit
================================  ==================================================  ========
``strain``                        Green-Lagrange strain :math:`E = (F^T F - I)/2`     1
``piola``                         first Piola-Kirchhoff stress :math:`P(F)`           Pa
``cauchy``                        Cauchy (true) stress :math:`\sigma = P F^T / J`     Pa
``von_mises``                     :math:`\sqrt{3/2\, s:s}`, :math:`s` the deviator    Pa
                                  of :math:`\sigma`
``principal``                     eigenvalues of :math:`\sigma`, largest first        Pa
``energy_density``                strain energy per rest volume :math:`\psi(F)`       J/m^3
================================  ==================================================  ========

:math:`J = \det F`. An inverted element (J <= 0) has no Cauchy stress: its ``cauchy``,
``von_mises`` and ``principal`` are NaN, and it is left out of the vertex averages.

Vertex averages weigh each element touching the vertex by its rest volume. The tensors
(``strain``, ``piola``, ``cauchy``) and ``energy_density`` are averaged; ``von_mises`` and
``principal`` at a vertex are those of the averaged Cauchy stress (as finite element
post-processors do), so they never mix directions of different elements.

Usage::

    s = sim.stress()                  # or sim.stress(state)
    s.von_mises.max()                 # per element, Pa
    s.vertex.cauchy[tip]              # (k, 3, 3) averaged at vertices, Pa
"""
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

__all__ = ["Stresses", "FIELDS", "evaluate", "vertex_average"]

#: Each field's name -> (its ParaView field name, what it is, its unit).
FIELDS = {
    "strain": ("green_lagrange_strain", "Green-Lagrange strain (F^T F - I)/2", "1"),
    "piola": ("first_piola_stress", "first Piola-Kirchhoff stress P", "Pa"),
    "cauchy": ("cauchy_stress", "Cauchy stress P F^T / det F", "Pa"),
    "von_mises": ("von_mises_stress", "von Mises stress of the Cauchy stress", "Pa"),
    "principal": ("principal_stress", "principal Cauchy stresses, largest first", "Pa"),
    "energy_density": ("strain_energy_density", "strain energy per rest volume psi(F)", "J/m^3"),
}


@dataclass
class Stresses:
    """Strains and stresses at one location kind (see the module docstring for definitions).

    Attributes
    ----------
    strain, piola, cauchy : (k, 3, 3) arrays
        Green-Lagrange strain (1), first Piola-Kirchhoff stress (Pa), Cauchy stress (Pa).
    von_mises : (k,) array
        von Mises stress of the Cauchy stress (Pa).
    principal : (k, 3) array
        Principal Cauchy stresses, largest first (Pa).
    energy_density : (k,) array
        Strain energy per rest volume (J/m^3).
    location : {"element", "vertex"}
        k is the number of elements or of vertices.
    vertex : Stresses or None
        For per-element stresses, their volume-weighted averages at the vertices.
    """

    strain: np.ndarray
    piola: np.ndarray
    cauchy: np.ndarray
    von_mises: np.ndarray
    principal: np.ndarray
    energy_density: np.ndarray
    location: str = "element"
    vertex: "Stresses" = None

    def fields(self):
        """The fields by their ParaView names (``cauchy_stress``, ...), tensors as (k, 9)."""
        out = {}
        for key, (name, _, _) in FIELDS.items():
            a = getattr(self, key)
            out[name] = a.reshape(a.shape[0], -1) if a.ndim == 3 else a
        return out


def _invariants(cauchy):
    """von Mises (k,) and principal stresses (k, 3), largest first, of symmetric tensors; NaN stays NaN."""
    k = cauchy.shape[0]
    ok = np.all(np.isfinite(cauchy.reshape(k, 9)), axis=1)
    principal = np.full((k, 3), np.nan)
    principal[ok] = np.linalg.eigvalsh(cauchy[ok])[:, ::-1]
    dev = cauchy - np.trace(cauchy, axis1=1, axis2=2)[:, None, None] / 3.0 * np.eye(3)
    von_mises = np.sqrt(1.5 * np.einsum("eij,eij->e", dev, dev))
    return von_mises, principal


def vertex_average(t, weights, n):
    """Sparse (n x m) operator averaging per-element values to vertices, weighted by ``weights``.

    Elements of zero weight are left out; a vertex whose elements all have zero weight gets NaN.
    """
    m = t.shape[1]
    A = sp.csr_matrix((np.repeat(weights, 4), (t.T.ravel(), np.repeat(np.arange(m), 4))), shape=(n, m))
    total = np.asarray(A.sum(axis=1)).ravel()
    with np.errstate(divide="ignore"):
        scale = np.where(total > 0, 1.0 / total, np.nan)
    return sp.diags(scale) @ A


def evaluate(system, x):
    """Strains and stresses of the elements of ``system`` (an ElasticSystem) at positions x (n, 3).

    Returns per-element :class:`Stresses` whose ``vertex`` holds the vertex averages.
    """
    F = system.deformation_gradients(x)
    P, _ = system.stresses(F, tangent=False)
    psi = np.empty(system.m)
    for mat, idx in system.groups:
        psi[idx] = mat.energy_density(F[idx])
    strain = 0.5 * (np.einsum("eki,ekj->eij", F, F) - np.eye(3))
    J = np.linalg.det(F)
    ok = J > 0
    cauchy = np.full_like(F, np.nan)
    sig = np.einsum("eik,ejk->eij", P[ok], F[ok]) / J[ok, None, None]
    cauchy[ok] = 0.5 * (sig + sig.transpose(0, 2, 1))  # symmetric for isotropic materials, to round-off
    vm, principal = _invariants(cauchy)
    element = Stresses(strain, P, cauchy, vm, principal, psi, "element")

    avg = vertex_average(system.t, np.where(ok, system.volumes, 0.0), system.n)
    every = vertex_average(system.t, system.volumes, system.n)

    def tensors(a, op):
        return (op @ np.where(np.isfinite(a), a, 0.0).reshape(a.shape[0], 9)).reshape(-1, 3, 3)

    vc = tensors(cauchy, avg)
    vvm, vprincipal = _invariants(vc)
    element.vertex = Stresses(tensors(strain, every), tensors(P, every), vc, vvm, vprincipal, every @ psi, "vertex")
    return element
