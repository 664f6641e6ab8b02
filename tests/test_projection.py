"""Analytic eigensystems (Smith, de Goes & Kim 2019) and the fused element pass against numpy."""
import os

import numpy as np
import pytest

import skfem_affine as sa
from skfem_affine._eigensystems import COROTATIONAL, NEOHOOKEAN, STVK, _spectrum
from skfem_affine.materials import project_psd, rotation_svd
from skfem_affine.lab.scenes import beam_mesh
from forking import exit_code_of

CODES = {sa.StVK: STVK, sa.Corotational: COROTATIONAL, sa.NeoHookean: NEOHOOKEAN}
rng = np.random.default_rng(3)


def rotations(m):
    Q = np.linalg.qr(rng.normal(size=(m, 3, 3)))[0]
    return Q * np.sign(np.linalg.det(Q))[:, None, None]


def deformations(kind, m=8):
    if kind == "random":
        return np.eye(3) + 0.4 * rng.normal(size=(m, 3, 3))
    if kind == "near_singular":
        return rotations(m) @ np.diag([1.3, 0.7, 1e-4]) @ rotations(m).transpose(0, 2, 1)
    if kind == "inverted":
        F = np.eye(3) + 0.3 * rng.normal(size=(m, 3, 3))
        F[:, :, 0] *= -1.0
        return F
    diagonals = [[1, 1, 1], [2, 2, 0.5], [0.5, 0.5, 0.5], [1.5, 0.8, 0.8], [2, 2, -0.5], [1, 1, 0], [3, 0.2, 0.2]]
    D = np.array([np.diag(d) for d in diagonals], dtype=float)
    if kind == "repeated":
        return D
    if kind == "rotated_repeated":
        k = len(D)
        return rotations(k) @ D @ rotations(k).transpose(0, 2, 1)
    raise ValueError(kind)


KINDS = ["random", "near_singular", "inverted", "repeated", "rotated_repeated"]


@pytest.mark.parametrize("cls", list(CODES))
@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("nu", [0.3, 0.45])
def test_analytic_projection_equals_eigendecomposition_clamp(cls, kind, nu):
    mat = cls(E=1e5, nu=nu)
    F = deformations(kind)
    C = mat.stress_derivative(F).reshape(-1, 9, 9)
    exact = project_psd(C)  # numpy eigh per element, negative eigenvalues set to 0
    fast = mat.stress_derivative(F, project=True).reshape(-1, 9, 9)
    scale = np.abs(C).reshape(len(C), -1).max(axis=1)[:, None, None]
    assert np.all(np.abs(fast - exact) <= 1e-9 * scale)


@pytest.mark.parametrize("cls", list(CODES))
def test_projection_had_negative_modes_to_remove(cls):
    F = np.concatenate([deformations("inverted"), deformations("near_singular")])
    C = cls(E=1e5, nu=0.3).stress_derivative(F).reshape(-1, 9, 9)
    assert np.linalg.eigvalsh(C).min() < -1e-3 * np.abs(C).max()  # the test above is not vacuous


@pytest.mark.parametrize("cls", list(CODES))
@pytest.mark.parametrize("kind", ["random", "inverted"])
def test_twist_flip_scaling_eigenvalues_are_the_spectrum(cls, kind):
    mat = cls(E=1e5, nu=0.35)
    F = deformations(kind)
    C = mat.stress_derivative(F).reshape(-1, 9, 9)
    _, s, _ = rotation_svd(F)
    for e in range(len(F)):
        twist, flip, Hs = np.empty(3), np.empty(3), np.empty((3, 3))
        _spectrum(CODES[cls], float(mat.mu), float(mat.kernel_lam), s[e].copy(), twist, flip, Hs)
        analytic = np.sort(np.concatenate([twist, flip, np.linalg.eigvalsh(Hs)]))
        numeric = np.linalg.eigvalsh(C[e])
        assert np.allclose(analytic, numeric, rtol=0, atol=1e-9 * np.abs(numeric).max())


@pytest.mark.parametrize("cls", list(CODES))
def test_twist_is_the_sum_quotient_and_flip_the_difference_quotient(cls):
    """Rayleigh quotients q^T C q of the modes u_i v_j^T -/+ u_j v_i^T against the closed forms."""
    mat = cls(E=1e5, nu=0.35)
    F = deformations("random", 4)
    C = mat.stress_derivative(F).reshape(-1, 9, 9)
    U, s, V = rotation_svd(F)
    for e in range(len(F)):
        twist, flip, Hs = np.empty(3), np.empty(3), np.empty((3, 3))
        _spectrum(CODES[cls], float(mat.mu), float(mat.kernel_lam), s[e].copy(), twist, flip, Hs)
        for k, (i, j) in enumerate([(1, 2), (0, 2), (0, 1)]):
            a, b = np.outer(U[e, :, i], V[e, :, j]), np.outer(U[e, :, j], V[e, :, i])
            for sign, lam in ((-1.0, twist[k]), (1.0, flip[k])):
                q = ((a + sign * b) / np.sqrt(2)).ravel()
                assert np.isclose(q @ C[e] @ q, lam, rtol=1e-9, atol=1e-9 * mat.mu)
        S = np.stack([np.outer(U[e, :, i], V[e, :, i]).ravel() for i in range(3)])
        assert np.allclose(S @ C[e] @ S.T, Hs, rtol=1e-9, atol=1e-9 * mat.mu)


class CustomNeoHookean(sa.NeoHookean):
    """A user subclass without its own closed form: takes the generic (Rayleigh-quotient) path."""


def test_custom_subclass_uses_the_generic_path():
    assert sa.NeoHookean(E=1e5, nu=0.3).closed_form()
    assert not CustomNeoHookean(E=1e5, nu=0.3).closed_form()


def test_mixed_materials_evaluate_equals_per_material_reference():
    mesh = beam_mesh(2)
    m = mesh.t.shape[1]
    kinds = [sa.StVK(E=2e5, nu=0.3), sa.Corotational(E=1e5, nu=0.4), sa.NeoHookean(E=5e4, nu=0.35),
             CustomNeoHookean(E=3e5, nu=0.2)]
    per_element = [kinds[e % 4] for e in range(m)]
    body = sa.ElasticBody(mesh, per_element, fixed=mesh.nodes_satisfying(lambda p: p[0] < 1e-9))
    sysm = sa.assembly.ElasticSystem([body])
    x = sysm.p0 + 0.15 * np.random.default_rng(5).normal(size=sysm.p0.shape)
    F = sysm.deformation_gradients(x)
    P = np.empty((m, 3, 3))
    C = np.empty((m, 9, 9))
    for e in range(m):
        mat = per_element[e]
        P[e] = mat.stress(F[e:e + 1])[0]
        C[e] = mat.stress_derivative(F[e:e + 1]).reshape(9, 9)
    for project in (False, True):
        Cref = project_psd(C) if project else C
        d = sysm.evaluate(x, project=project)
        assert np.abs(d.P - P).max() <= 1e-12 * np.abs(P).max()
        assert np.abs(d.C - Cref).max() <= 1e-9 * np.abs(Cref).max()
        vg = sysm.volumes[:, None, None] * sysm.grads
        He = np.einsum("ekj,eajbq,elq->ekalb", vg, Cref.reshape(-1, 3, 3, 3, 3), sysm.grads).reshape(-1, 12, 12)
        assert np.abs(d.He - He).max() <= 1e-9 * np.abs(He).max()
        fe = -np.einsum("eaj,ekj->eka", P, vg)
        f = np.bincount(sysm.edofs.ravel(), weights=fe.ravel(), minlength=3 * sysm.n)
        assert np.abs(d.f - f).max() <= 1e-12 * np.abs(f).max()
        t = sysm.evaluate_tangent(x, project=project)
        assert np.array_equal(t.C, d.C) and np.array_equal(t.f, d.f) and np.array_equal(t.P, d.P)
    assert np.linalg.eigvalsh(d.C).min() >= -1e-9 * np.abs(d.C).max()
    f_only, none = sysm.forces_and_stiffness(x, tangent=False)
    assert none is None and np.abs(f_only - f).max() <= 1e-12 * np.abs(f).max()
    assert np.abs(sysm._internal_force(P) - f).max() <= 1e-12 * np.abs(f).max()


def test_element_blocks_of_a_subset_equal_the_full_evaluation():
    mesh = beam_mesh(2)
    m = mesh.t.shape[1]
    kinds = [sa.StVK(E=2e5, nu=0.3), sa.NeoHookean(E=5e4, nu=0.35), CustomNeoHookean(E=3e5, nu=0.2),
             CustomNeoHookean(E=1e5, nu=0.3)]
    body = sa.ElasticBody(mesh, [kinds[e % 4] for e in range(m)])
    sysm = sa.assembly.ElasticSystem([body])
    x = sysm.p0 + 0.15 * np.random.default_rng(6).normal(size=sysm.p0.shape)
    d = sysm.evaluate(x)
    elems = np.random.default_rng(7).choice(m, size=m // 3, replace=False)
    He = sysm.element_blocks(d.F, elems)
    assert np.abs(He - d.He[elems]).max() <= 1e-12 * np.abs(d.He).max()


@pytest.mark.slow
@pytest.mark.parametrize("sweeps", [0, 1, 2, 4])
def test_svd_of_interleaved_lanes(sweeps):
    """svd3_lanes: F = U diag(s) V^T with proper rotations, s descending, s[2] carrying det F's sign;
    few ``sweeps`` force the scalar finish of unconverged lanes, 13 elements a partial last block."""
    from skfem_affine._kernels import _LANES, svd3_lanes
    F = np.concatenate([deformations("random", 4), deformations("inverted", 2), deformations("repeated")])
    lanes = lambda: np.empty((_LANES, 3, 3))  # noqa: E731
    for e0 in range(0, len(F), _LANES):
        U, V, s = lanes(), lanes(), np.empty((_LANES, 3))
        svd3_lanes(F, e0, len(F), U, s, V, np.empty((6, _LANES)), np.empty((9, _LANES)),
                   np.empty((3, 3)), np.empty((3, 3)), sweeps)
        for b in range(min(_LANES, len(F) - e0)):
            f = F[e0 + b]
            assert np.allclose(U[b] @ np.diag(s[b]) @ V[b].T, f, rtol=0, atol=1e-12 * np.abs(f).max())
            for R in (U[b], V[b]):
                assert np.allclose(R.T @ R, np.eye(3), atol=1e-12) and np.isclose(np.linalg.det(R), 1.0)
            assert s[b, 0] >= s[b, 1] >= abs(s[b, 2]) - 1e-12
            assert np.isclose(np.prod(s[b]), np.linalg.det(f), rtol=1e-10, atol=1e-12)  # s[2] carries det's sign


@pytest.mark.skipif(not hasattr(os, "fork"), reason="needs os.fork")
def test_element_pass_works_in_a_forked_child():
    """The element pass's helper threads do not survive a fork: the child must make its own.

    A full-space and an affinification frame (oracle, strain rates, reduced assembly) run in the
    parent first, then in a forked child, whichever threading layer numba has.
    """
    sims = [sa.scenes.cantilever(resolution=2, E=1e5, damping=None),
            sa.scenes.cantilever(resolution=2, E=1e5, damping=None, reducer=sa.Affinification(tau_a=1.0, tau_e=2.0))]
    for sim in sims:
        sim.step()  # the parent's helper threads exist now
    pid = os.fork()
    if pid == 0:  # child: a hang here would stall the test, an exception gives exit code 1
        try:
            for sim in sims:
                sim.step()
            os._exit(0 if all(np.all(np.isfinite(sim.state.x)) for sim in sims) else 1)
        except BaseException:
            os._exit(1)
    assert exit_code_of(pid, "the forked child hung in the element pass") == 0
