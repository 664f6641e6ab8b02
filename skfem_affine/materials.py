r"""Hyperelastic materials, vectorised over elements.

Each material gives, for deformation gradients ``F`` of shape ``(m, 3, 3)``,

* :meth:`~Material.energy_density` psi(F), shape ``(m,)``;
* :meth:`~Material.stress`, the first Piola-Kirchhoff stress P = d psi / dF, ``(m, 3, 3)``;
* :meth:`~Material.stress_derivative`, ``dP[e, i, j, k, l] = d P_ij / d F_kl``,
  ``(m, 3, 3, 3, 3)``, optionally projected to positive semi-definite.

Parameters ``E`` and ``nu`` may be scalars or ``(m,)`` arrays (one value per
element), so a heterogeneous body is evaluated in one call per material kind.
Lame parameters come from :func:`lame_parameters`, the one place they are computed.
Each material is also available as scikit-fem forms, :meth:`Material.forms`.

Models (paper sec. 4; stable Neo-Hookean: Smith, de Goes & Kim 2018):

* :class:`StVK`: ``psi = mu E:E + lam/2 tr(E)^2``, ``E = (F^T F - I)/2``;
* :class:`Corotational`: ``psi = mu |F - R|^2 + lam/2 tr(R^T F - I)^2``, ``F = R S``;
* :class:`NeoHookean` (stable Neo-Hookean, Smith, de Goes & Kim 2018):
  psi = mu/2 (tr F^T F - 3) - mu (J - 1) + lam'/2 (J - 1)^2, lam' = lam + mu
  so that it linearises to the same Lame parameters; defined for J <= 0.
"""
import numpy as np

from skfem_affine._eigensystems import COROTATIONAL, GENERIC, NEOHOOKEAN, STVK, evaluate_elements
from skfem_affine.checks import real_array

# Levi-Civita symbol, used for the cofactor and the Hessian of det F.
_EPS = np.zeros((3, 3, 3))
_EPS[0, 1, 2] = _EPS[1, 2, 0] = _EPS[2, 0, 1] = 1.0
_EPS[0, 2, 1] = _EPS[2, 1, 0] = _EPS[1, 0, 2] = -1.0
_I3 = np.eye(3)


def lame_parameters(E, nu):
    """Lame parameters ``(lam, mu)`` from Young's modulus and Poisson ratio, validated.

    The order is scikit-fem's (:func:`skfem.models.elasticity.lame_parameters`), so the two
    can be swapped for one another.

    ``E`` and ``nu`` are real numbers or 1-D arrays of them (one value per element; two arrays
    must have the same length), E > 0 and -1 < nu < 0.5, all finite. Anything else raises a
    TypeError or ValueError naming ``E`` or ``nu``.
    """
    E = real_array(E, "Young's modulus E", low=0.0, include_low=False)
    nu = real_array(nu, "Poisson ratio nu", low=-1.0, high=0.5, include_low=False, include_high=False)
    for what, a in (("E", E), ("nu", nu)):
        if a.ndim > 1:
            raise ValueError(f"{what} must be a number or a 1-D array (one value per element), got shape {a.shape}")
        if a.ndim == 1 and a.size == 0:
            raise ValueError(f"{what} is an empty array; give a number or one value per element")
    if E.ndim and nu.ndim and E.shape != nu.shape:
        raise ValueError(f"E and nu per element must have the same length, got {E.shape[0]} and {nu.shape[0]}")
    with np.errstate(over="ignore", invalid="ignore"):
        mu = E / (2.0 * (1.0 + nu))
        lam = E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))
    if not (np.all(np.isfinite(mu)) and np.all(np.isfinite(lam))):
        raise ValueError("E and nu give non-finite Lame parameters (E too large, or nu too close to 0.5 or -1)")
    return lam, mu


def determinant(F):
    """det F for (m, 3, 3) arrays."""
    return (F[:, 0, 0] * (F[:, 1, 1] * F[:, 2, 2] - F[:, 1, 2] * F[:, 2, 1])
            - F[:, 0, 1] * (F[:, 1, 0] * F[:, 2, 2] - F[:, 1, 2] * F[:, 2, 0])
            + F[:, 0, 2] * (F[:, 1, 0] * F[:, 2, 1] - F[:, 1, 1] * F[:, 2, 0]))


def cofactor(F):
    """d(det F)/dF = cof F, (m, 3, 3): columns f1 x f2, f2 x f0, f0 x f1."""
    c0, c1, c2 = F[:, :, 0], F[:, :, 1], F[:, :, 2]
    return np.stack([np.cross(c1, c2), np.cross(c2, c0), np.cross(c0, c1)], axis=2)


# d^2 J / dF_ij dF_kl = eps_ikp eps_jlq F_pq is linear in F: one (81 x 9) matrix.
_DET_HESSIAN = np.einsum("ikp,jlq->ijklpq", _EPS, _EPS).reshape(81, 9)


def det_hessian(F):
    """d^2(det F)/dF_ij dF_kl = eps_ikp eps_jlq F_pq, (m, 3, 3, 3, 3)."""
    return (F.reshape(-1, 9) @ _DET_HESSIAN.T).reshape(-1, 3, 3, 3, 3)


_NONE = np.empty((0, 4, 3))


def _per_element(a, m):
    return np.ascontiguousarray(np.broadcast_to(a, (m,)), dtype=float)


def project_psd(C, F=None):
    """Project dP/dF, (m, 3, 3, 3, 3) or (m, 9, 9), to positive semi-definite.

    Without ``F``: eigendecomposition of every element tensor (any material).
    With ``F`` (isotropic materials, all of ours): in the basis Q_k = U E_k V^T
    from the SVD F = U S V^T (3 scalings, 3 twists, 3 flips) dP/dF is block
    diagonal, D = Q^T C Q = d^2 psi at S (Smith et al. 2019): six scalar
    eigenvalues and a 3 x 3 scaling block. Clamping them is the exact
    projection; a compiled per-element kernel (:mod:`skfem_affine._kernels`)
    does it without a 9 x 9 eigensolver and leaves PSD elements untouched.
    """
    shape = C.shape
    C = C.reshape(shape[0], 9, 9)
    if F is None:
        C = 0.5 * (C + C.transpose(0, 2, 1))
        w, Q = np.linalg.eigh(C)
        return np.einsum("eik,ek,ejk->eij", Q, np.maximum(w, 0.0), Q, optimize=True).reshape(shape)
    from skfem_affine._kernels import element_hessians
    out = np.ascontiguousarray(C, dtype=float).copy()
    F = np.ascontiguousarray(F, dtype=float)
    none = np.empty((0, 4, 3))
    element_hessians(out, F, none, none, True, np.empty((0, 12, 12)), False)
    return out.reshape(shape)


class Material:
    """Base class: a hyperelastic energy from (E, nu). Subclasses define the kernels.

    A subclass implements :meth:`energy_density`, :meth:`stress` and ``_stress_derivative``
    (unprojected dP/dF); the PSD projection then uses Rayleigh quotients in the isotropic
    mode basis (:func:`project_psd`). StVK, Corotational and NeoHookean instead have a
    closed form (``_code``) evaluated by one compiled pass with analytic eigenvalues
    (:mod:`skfem_affine._eigensystems`).
    """

    name = "material"
    _code = GENERIC

    def __init__(self, E, nu):
        self.lam, self.mu = lame_parameters(E, nu)
        self.E = np.asarray(E, dtype=float)
        self.nu = np.asarray(nu, dtype=float)

    def __repr__(self):
        def fmt(a):
            return f"{float(a):g}" if a.ndim == 0 else f"array({a.shape[0]})"
        return f"{type(self).__name__}(E={fmt(self.E)}, nu={fmt(self.nu)})"

    @classmethod
    def merged(cls, materials):
        """One material of this kind whose (E, nu) are per-element arrays."""
        return cls(E=np.array([float(m.E) for m in materials]), nu=np.array([float(m.nu) for m in materials]))

    def energy_density(self, F):
        """psi(F), shape (m,)."""
        raise NotImplementedError

    def stress(self, F):
        """First Piola-Kirchhoff stress P(F), shape (m, 3, 3)."""
        raise NotImplementedError

    def stress_derivative(self, F, project=False):
        """dP/dF, shape (m, 3, 3, 3, 3); ``project=True`` clamps it to PSD."""
        if self.closed_form():
            return self._compiled(F, tangent=True, project=project)[1].reshape(-1, 3, 3, 3, 3)
        C = self._stress_derivative(F)
        return project_psd(C, F) if project else C

    def _stress_derivative(self, F):
        raise NotImplementedError

    def closed_form(self):
        """True when this exact class has a compiled closed form (``_code``).

        A subclass that changes the energy without declaring its own ``_code`` uses its
        own :meth:`stress` and ``_stress_derivative`` with the generic projection.
        """
        return "_code" in type(self).__dict__ and self._code != GENERIC

    @property
    def kernel_lam(self):
        """The second parameter the compiled closed form takes (lam; lam' for Neo-Hookean)."""
        return self.lam

    def _compiled(self, F, stress=False, tangent=False, project=False):
        """(P (m, 3, 3), dP/dF (m, 9, 9)) from the closed form of ``_code``, zero-length if not asked."""
        F = np.ascontiguousarray(F, dtype=float).reshape(-1, 3, 3)
        m = F.shape[0]
        P, C = np.empty((m if stress else 0, 3, 3)), np.empty((m if tangent else 0, 9, 9))
        evaluate_elements(F, np.full(m, type(self)._code, dtype=np.int64), _per_element(self.mu, m),
                          _per_element(self.kernel_lam, m), project, P, C, _NONE, _NONE,
                          np.empty((0, 12, 12)), _NONE)
        return P, C

    def forms(self, project=False):
        """scikit-fem forms ``(tangent, force)`` for a displacement field ``w['disp']``.

        ``tangent`` is the ``BilinearForm`` of the (positive) stiffness
        ``int grad v : dP/dF : grad u``; ``force`` is the ``LinearForm`` of the
        internal force ``-int P : grad v``; F = I + grad(disp). Usage::

            basis = Basis(mesh, ElementVector(ElementTetP1()))
            K = asm(tangent, basis, disp=basis.interpolate(u))
            f = asm(force, basis, disp=basis.interpolate(u))

        Only for materials with scalar (E, nu). These forms re-evaluate the
        material for each of the 144 basis-function pairs: they are the
        reference and the user-facing path, the simulator uses
        :mod:`skfem_affine.assembly`.
        """
        from skfem import BilinearForm, LinearForm
        from skfem.helpers import grad, ddot

        if self.E.ndim or self.nu.ndim:
            raise ValueError("forms() needs a material with scalar E and nu")

        def at_points(disp):
            G = grad(disp)  # (3, 3, m, q)
            F = np.eye(3)[:, :, None, None] + G
            shape = F.shape[2:]
            return np.moveaxis(F, (0, 1), (-2, -1)).reshape(-1, 3, 3), shape

        @BilinearForm
        def tangent(u, v, w):
            F, shape = at_points(w["disp"])
            C = self.stress_derivative(F, project=project).reshape(shape + (3, 3, 3, 3))
            return np.einsum("ij...,...ijkl,kl...->...", grad(v), C, grad(u))

        @LinearForm
        def force(v, w):
            F, shape = at_points(w["disp"])
            P = np.moveaxis(self.stress(F).reshape(shape + (3, 3)), (-2, -1), (0, 1))
            return -ddot(P, grad(v))

        return tangent, force


class StVK(Material):
    """Saint-Venant Kirchhoff: psi = mu E:E + lam/2 tr(E)^2 (not stable under compression)."""

    name = "stvk"
    _code = STVK

    def _green(self, F):
        return 0.5 * (np.einsum("eki,ekj->eij", F, F) - _I3)

    def energy_density(self, F):
        E = self._green(F)
        tr = np.trace(E, axis1=1, axis2=2)
        return self.mu * np.einsum("eij,eij->e", E, E) + 0.5 * self.lam * tr ** 2

    def stress(self, F):
        # P = F S, S = 2 mu E + lam tr(E) I
        return self._compiled(F, stress=True)[0].reshape(np.shape(F))

    def _stress_derivative(self, F):
        # dP_ijkl = d_ik S_lj + mu (F_il F_kj + (F F^T)_ik d_jl) + lam F_ij F_kl
        return self._compiled(F, tangent=True)[1].reshape(-1, 3, 3, 3, 3)


class NeoHookean(Material):
    """Stable Neo-Hookean (Smith, de Goes & Kim 2018), psi = mu/2 (I_C - 3) - mu (J - 1) + lam'/2 (J - 1)^2.

    lam' = lam + mu makes the small-strain limit match linear elasticity with
    the Lame parameters of (E, nu). Rest-stable and defined for inverted F.
    """

    name = "neohookean"
    _code = NEOHOOKEAN

    @property
    def lam_snh(self):
        return self.lam + self.mu

    @property
    def kernel_lam(self):
        return self.lam_snh

    def energy_density(self, F):
        J = determinant(F)
        Ic = np.einsum("eij,eij->e", F, F)
        return 0.5 * self.mu * (Ic - 3.0) - self.mu * (J - 1.0) + 0.5 * self.lam_snh * (J - 1.0) ** 2

    def stress(self, F):
        # P = mu F + (lam' (J - 1) - mu) cof F
        return self._compiled(F, stress=True)[0].reshape(np.shape(F))

    def _stress_derivative(self, F):
        # lam' g g^T + (lam' (J - 1) - mu) d^2J/dF^2 + mu I, g = vec(cof F)
        return self._compiled(F, tangent=True)[1].reshape(-1, 3, 3, 3, 3)


def rotation_svd(F):
    """Rotation-variant SVD F = U diag(s) V^T with det U = det V = +1 (s[2] may be < 0)."""
    U, s, Vt = np.linalg.svd(F)
    V = Vt.transpose(0, 2, 1).copy()
    du, dv = np.linalg.det(U) < 0, np.linalg.det(V) < 0
    U[du, :, 2] *= -1.0
    s[du, 2] *= -1.0
    V[dv, :, 2] *= -1.0
    s[dv, 2] *= -1.0
    return U, s, V


def signed_singular_values(F):
    """The singular values of :func:`rotation_svd` (the smallest negative when det F < 0), shape (m, 3).

    From the eigenvalues of F^T F, without the vectors: the energy needs no rotation, and a
    batched symmetric eigenvalue solve costs a fraction of a batched SVD.
    """
    F = np.asarray(F, dtype=float).reshape(-1, 3, 3)
    s = np.sqrt(np.maximum(np.linalg.eigvalsh(np.einsum("eki,ekj->eij", F, F)), 0.0))[:, ::-1].copy()
    s[determinant(F) < 0, 2] *= -1.0
    return s


class Corotational(Material):
    """Corotational: ``psi = mu |F - R|^2 + lam/2 (tr(R^T F) - 3)^2`` with ``F = R S`` (polar).

    The exact Hessian differentiates R: dR = U Omega V^T with
    Omega_ij = ((U^T dF V)_ij - (U^T dF V)_ji) / (s_i + s_j).
    """

    name = "corotational"
    _code = COROTATIONAL

    def energy_density(self, F):
        s = signed_singular_values(F)
        return self.mu * np.sum((s - 1.0) ** 2, axis=1) + 0.5 * self.lam * (s.sum(axis=1) - 3.0) ** 2

    def stress(self, F):
        # P = 2 mu (F - R) + lam (tr S - 3) R, R = U V^T
        return self._compiled(F, stress=True)[0].reshape(np.shape(F))

    def _stress_derivative(self, F):
        # 2 mu I + lam vec(R) vec(R)^T + (lam (tr S - 3) - 2 mu) dR/dF, from the twist modes
        return self._compiled(F, tangent=True)[1].reshape(-1, 3, 3, 3, 3)


def shear_part(material):
    """The material of the same class at lam = 0 (E = 2 mu, nu = 0): its energy without the
    volumetric stiffness lam, which a body with ``volumetric="nodal"`` puts on its vertices
    (:mod:`skfem_affine.nodal_volume`)."""
    return type(material)(E=2.0 * material.mu, nu=np.zeros_like(material.nu))


MATERIALS = {cls.name: cls for cls in (StVK, Corotational, NeoHookean)}
