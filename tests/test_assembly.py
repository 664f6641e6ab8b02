"""The fused element kernel and the fixed-pattern scatter against plain numpy."""
import numpy as np
import pytest

import skfem_affine as sa
from skfem_affine.materials import project_psd
from skfem_affine.lab.scenes import beam_mesh


@pytest.mark.parametrize("cls", [sa.StVK, sa.Corotational, sa.NeoHookean])
@pytest.mark.parametrize("project", [False, True])
def test_element_kernel_equals_einsum(cls, project):
    rng = np.random.default_rng(1)
    body = sa.ElasticBody(beam_mesh(2), cls(E=1e5, nu=0.4))
    sysm = sa.assembly.ElasticSystem([body])
    x = sysm.p0 + 0.15 * rng.normal(size=sysm.p0.shape)  # strongly deformed, some elements indefinite
    F = sysm.deformation_gradients(x)
    _, C = sysm.stresses(F, project=False)
    He, C_used = sysm.element_stiffness(F, C.copy(), project=project)
    Cref = project_psd(C) if project else C  # eigendecomposition per element
    vg = sysm.volumes[:, None, None] * sysm.grads
    ref = np.einsum("ekj,eajbq,elq->ekalb", vg, Cref, sysm.grads).reshape(-1, 12, 12)
    assert np.abs(He - ref).max() <= 1e-9 * np.abs(ref).max()
    assert np.abs(C_used - Cref.reshape(-1, 9, 9)).max() <= 1e-9 * np.abs(Cref).max()
    if project:
        assert np.linalg.eigvalsh(He).min() >= -1e-9 * np.abs(He).max()


def test_pattern_scatter_equals_dense_assembly_on_free_dofs():
    mesh = beam_mesh(1)
    body = sa.ElasticBody(mesh, sa.NeoHookean(E=1e5, nu=0.3), fixed=mesh.nodes_satisfying(lambda p: p[0] < 1e-9))
    sysm = sa.assembly.ElasticSystem([body])
    blocks = np.random.default_rng(0).normal(size=(sysm.m, 12, 12))
    dense = np.zeros((3 * sysm.n, 3 * sysm.n))
    for e in range(sysm.m):
        d = sysm.edofs[e]
        dense[np.ix_(d, d)] += blocks[e]
    free = sysm.free
    H = sysm.pattern.matrix(sysm.pattern.scatter(blocks)).toarray()
    assert np.allclose(H, dense[np.ix_(free, free)])
    assert np.allclose(sysm.full_pattern.matrix(sysm.full_pattern.scatter(blocks)).toarray(), dense)


def test_stiffness_is_the_derivative_of_the_forces():
    body = sa.ElasticBody(beam_mesh(1), sa.NeoHookean(E=1e5, nu=0.3))
    sysm = sa.assembly.ElasticSystem([body])
    rng = np.random.default_rng(2)
    x = sysm.p0 + 0.05 * rng.normal(size=sysm.p0.shape)
    f, H = sysm.forces_and_stiffness(x, project=False, full=True)
    dx = rng.normal(size=x.shape)
    eps = 1e-6
    fp, _ = sysm.forces_and_stiffness(x + eps * dx, tangent=False)
    fm, _ = sysm.forces_and_stiffness(x - eps * dx, tangent=False)
    assert np.allclose(-(fp - fm) / (2 * eps), H @ dx.ravel(), rtol=1e-6, atol=1e-6 * np.abs(H @ dx.ravel()).max())
    # and the forces are minus the gradient of the strain energy
    e_p, e_m = sysm.strain_energy(x + eps * dx), sysm.strain_energy(x - eps * dx)
    assert (e_p - e_m) / (2 * eps) == pytest.approx(-f @ dx.ravel(), rel=1e-6)


def test_compiled_deformation_gradients_equal_the_kinematics_einsum():
    rng = np.random.default_rng(2)
    sysm = sa.assembly.ElasticSystem([sa.ElasticBody(beam_mesh(2), sa.NeoHookean(E=1e5, nu=0.3))])
    x = sysm.p0 + 0.1 * rng.normal(size=sysm.p0.shape)
    ref = sa.kinematics.deformation_gradient(x, sysm.t, sysm.grads)
    assert np.abs(sysm.deformation_gradients(x) - ref).max() <= 1e-13
