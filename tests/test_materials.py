"""Finite-difference and invariance checks of the three hyperelastic materials."""
import numpy as np
import pytest
import skfem
from skfem import Basis, ElementTetP1, ElementVector, asm

import skfem_affine as sa
from skfem_affine.materials import project_psd, rotation_svd

MATERIALS = [sa.StVK, sa.Corotational, sa.NeoHookean]
rng = np.random.default_rng(0)


def random_rotations(m):
    Q, R = np.linalg.qr(rng.normal(size=(m, 3, 3)))
    Q *= np.sign(np.linalg.det(Q))[:, None, None]
    return Q


def sample_F(kind, m=6):
    if kind == "random":
        return np.eye(3) + 0.3 * rng.normal(size=(m, 3, 3))
    if kind == "near_singular":
        U, V = random_rotations(m), random_rotations(m)
        s = np.array([1.2, 0.8, 1e-3])
        return U @ (s[:, None] * V.transpose(0, 2, 1))
    if kind == "inverted":
        F = np.eye(3) + 0.2 * rng.normal(size=(m, 3, 3))
        F[:, :, 2] *= -1.0
        return F
    raise ValueError(kind)


def fd_check(f, df, F, h=1e-6):
    """Central differences of f at F (m, 3, 3) against df (m, 3, 3, *out)."""
    num = np.zeros_like(df)
    for k in range(3):
        for l in range(3):
            dF = np.zeros_like(F)
            dF[:, k, l] = h
            d = (f(F + dF) - f(F - dF)) / (2 * h)
            num[(slice(None),) + (Ellipsis,) + (k, l)] = d
    return num


@pytest.mark.parametrize("cls", MATERIALS)
@pytest.mark.parametrize("kind", ["random", "near_singular", "inverted"])
def test_stress_and_derivative_match_finite_differences(cls, kind):
    mat = cls(E=1e5, nu=0.3)
    F = sample_F(kind)
    P = mat.stress(F)
    Pn = fd_check(mat.energy_density, P, F)
    scale = np.abs(P).max()
    assert np.abs(P - Pn).max() < 1e-6 * max(scale, mat.mu)
    C = mat.stress_derivative(F)
    Cn = fd_check(mat.stress, C, F)
    assert np.abs(C - Cn).max() < 1e-5 * max(np.abs(C).max(), mat.mu)


@pytest.mark.parametrize("cls", MATERIALS)
def test_zero_stress_at_rest_and_zero_energy_under_rotation(cls):
    mat = cls(E=3e4, nu=0.45)
    I = np.repeat(np.eye(3)[None], 4, axis=0)
    assert np.abs(mat.stress(I)).max() < 1e-9 * mat.mu
    R = random_rotations(5)
    assert np.abs(mat.energy_density(R)).max() < 1e-9 * mat.mu
    assert np.abs(mat.stress(R)).max() < 1e-9 * mat.mu


@pytest.mark.parametrize("cls", MATERIALS)
def test_small_strain_limit_is_linear_elasticity(cls):
    mat = cls(E=2e5, nu=0.3)
    C = mat.stress_derivative(np.eye(3)[None])[0]
    I = np.eye(3)
    lin = (mat.lam * np.einsum("ij,kl->ijkl", I, I)
           + mat.mu * (np.einsum("ik,jl->ijkl", I, I) + np.einsum("il,jk->ijkl", I, I)))
    assert np.allclose(C, lin, rtol=1e-12, atol=1e-9 * mat.mu)


def test_per_element_parameters_broadcast():
    F = sample_F("random", 3)
    E = np.array([1e3, 1e5, 1e7])
    het = sa.NeoHookean(E=E, nu=0.3)
    for e in range(3):
        one = sa.NeoHookean(E=E[e], nu=0.3)
        assert np.allclose(het.stress(F)[e], one.stress(F[e:e + 1])[0])
        assert np.allclose(het.stress_derivative(F)[e], one.stress_derivative(F[e:e + 1])[0])


@pytest.mark.parametrize("cls", MATERIALS)
@pytest.mark.parametrize("kind", ["random", "near_singular", "inverted"])
def test_psd_projection_isotropic_basis_equals_eigendecomposition(cls, kind):
    F = sample_F(kind, 10)
    mat = cls(E=1e5, nu=0.3)
    C = mat.stress_derivative(F)
    exact = project_psd(C)  # per-element 9x9 eigendecomposition
    fast = mat.stress_derivative(F, project=True)  # isotropic mode basis from the SVD of F
    scale = np.abs(C).max()
    assert np.abs(fast - exact).max() < 1e-8 * scale
    w = np.linalg.eigvalsh(fast.reshape(-1, 9, 9))
    assert w.min() > -1e-9 * scale
    if kind == "inverted" and cls is sa.NeoHookean:
        assert np.linalg.eigvalsh(C.reshape(-1, 9, 9)).min() < 0  # projection had work to do


def test_psd_projection_keeps_psd_tensors():
    Cr = sa.NeoHookean(E=1e5, nu=0.3).stress_derivative(np.eye(3)[None])
    assert np.allclose(project_psd(Cr), Cr)
    assert np.allclose(project_psd(Cr, np.eye(3)[None]), Cr)


def test_rotation_svd_is_proper():
    F = sample_F("inverted", 20)
    U, s, V = rotation_svd(F)
    assert np.allclose(np.linalg.det(U), 1) and np.allclose(np.linalg.det(V), 1)
    assert np.allclose(U @ (s[:, :, None] * V.transpose(0, 2, 1)), F)


@pytest.mark.parametrize("E,nu", [(0.0, 0.3), (-1.0, 0.3), (1e5, 0.5), (1e5, 0.7), (1e5, -1.0), (np.nan, 0.3)])
def test_bad_parameters_raise(E, nu):
    with pytest.raises(ValueError, match="E|nu|finite"):
        sa.NeoHookean(E=E, nu=nu)


@pytest.mark.parametrize("cls", MATERIALS)
def test_forms_match_vectorised_assembly(cls):
    mesh = skfem.MeshTet.init_tensor(np.linspace(0, 2, 4), np.linspace(0, 1, 3), np.linspace(0, 1, 3))
    mat = cls(E=1e5, nu=0.35)
    body = sa.ElasticBody(mesh, material=mat, density=1.0)
    basis = Basis(mesh, ElementVector(ElementTetP1()), intorder=1)
    u = 0.05 * rng.normal(size=mesh.p.size)  # node-major, same as the basis
    tangent, force = mat.forms()
    K = asm(tangent, basis, disp=basis.interpolate(u))
    f = asm(force, basis, disp=basis.interpolate(u))
    x = mesh.p.T + u.reshape(-1, 3)
    fast = sa.assembly.ElasticSystem([body])
    f2, H = fast.forces_and_stiffness(x, project=False, full=True)
    assert np.linalg.norm(f - f2) <= 1e-10 * np.linalg.norm(f)
    assert abs(K - H).max() <= 1e-10 * abs(K).max()


def test_lame_parameters_come_in_scikit_fem_order():
    from skfem.models.elasticity import lame_parameters as skfem_lame
    from skfem_affine.materials import lame_parameters
    lam, mu = lame_parameters(1e5, 0.3)
    assert np.allclose((lam, mu), skfem_lame(1e5, 0.3), rtol=1e-15)
    assert mu == pytest.approx(1e5 / 2.6) and lam > mu  # nu = 0.3: lam = 1.5 mu
    m = sa.NeoHookean(E=1e5, nu=0.3)
    assert (m.lam, m.mu) == (lam, mu)
    with pytest.raises(ValueError, match="Poisson"):
        lame_parameters(1e5, 0.5)


def test_signed_singular_values_match_the_rotation_variant_svd_inverted_elements_included():
    from skfem_affine.materials import rotation_svd, signed_singular_values
    rng = np.random.default_rng(3)
    F = np.eye(3) + 0.4 * rng.standard_normal((500, 3, 3))
    F[:50] = -F[:50]  # inverted (det < 0) elements
    assert (np.linalg.det(F) < 0).sum() > 50
    _, s, _ = rotation_svd(F)
    assert np.allclose(signed_singular_values(F), s, rtol=0, atol=1e-12)
