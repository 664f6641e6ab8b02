"""Bad input is refused with a clear message; rest data matches scikit-fem."""
import numpy as np
import pytest
import skfem
from skfem import Basis, ElementTetP1, ElementVector

import skfem_affine as sa
from skfem_affine.kinematics import deformation_gradient, deformation_operator, shape_gradients, signed_volumes
from skfem_affine.lab.scenes import beam_mesh

MAT = sa.NeoHookean(E=1e5, nu=0.3)


def small_mesh():
    return beam_mesh(1)


def test_shape_gradients_and_volumes_match_rest_edge_matrix():
    mesh = beam_mesh(2)
    grads, vol = shape_gradients(mesh)
    p, t = mesh.p.T, mesh.t
    Dm = np.stack([p[t[1]] - p[t[0]], p[t[2]] - p[t[0]], p[t[3]] - p[t[0]]], axis=-1)
    Dinv = np.linalg.inv(Dm)
    scale = np.abs(Dinv).max()  # 1 / element size
    assert np.allclose(grads[:, 1:], Dinv, rtol=0, atol=1e-12 * scale)
    assert np.allclose(grads[:, 0], -Dinv.sum(axis=1), rtol=0, atol=1e-12 * scale)
    assert np.allclose(vol, np.abs(signed_volumes(mesh.p, t)))
    assert vol.sum() == pytest.approx(4.0)


def test_B_operator_gives_F_and_matches_scikit_fem_dof_order():
    mesh = beam_mesh(2)
    grads, _ = shape_gradients(mesh)
    basis = Basis(mesh, ElementVector(ElementTetP1()))
    assert np.array_equal(basis.nodal_dofs, 3 * np.arange(mesh.p.shape[1]) + np.arange(3)[:, None])
    L = np.array([[1.1, 0.2, 0.0], [0.1, 0.9, 0.3], [0.0, -0.2, 1.2]])
    x = mesh.p.T @ L.T + 0.3
    B = deformation_operator(mesh.t, grads, mesh.p.shape[1])
    F = (B @ x.ravel()).reshape(-1, 3, 3)
    assert np.allclose(F, L) and np.allclose(deformation_gradient(x, mesh.t, grads), L)


def test_lumped_mass_is_rho_volume_over_four_and_consistent_mass_totals():
    body = sa.ElasticBody(beam_mesh(2), MAT, density=1200.0)
    lumped = sa.assembly.ElasticSystem([body])
    consistent = sa.assembly.ElasticSystem([body], mass="consistent")
    per_vertex = np.bincount(body.mesh.t.ravel(), weights=np.repeat(body.volumes, 4) / 4, minlength=body.n_vertices)
    assert np.allclose(lumped.lumped_mass, 1200.0 * per_vertex)
    ones = np.ones(3 * body.n_vertices)
    assert ones @ consistent.M @ ones == pytest.approx(3 * 1200.0 * 4.0)
    assert abs(consistent.M - consistent.M.T).max() <= 1e-14 * abs(consistent.M).max()


def test_non_tetrahedral_mesh_is_refused():
    with pytest.raises(TypeError, match="tetrahedral"):
        sa.ElasticBody(skfem.MeshHex.init_tensor(*[np.linspace(0, 1, 3)] * 3), MAT)
    with pytest.raises(TypeError, match="tetrahedral"):
        sa.ElasticBody(skfem.MeshTri(), MAT)
    with pytest.raises(TypeError, match="MeshTet"):
        sa.ElasticBody(np.zeros((3, 4)), MAT)


def test_nan_in_mesh_is_refused():
    m = small_mesh()
    p = m.p.copy()
    p[1, 3] = np.nan
    with pytest.raises(ValueError, match="non-finite.*vertices \\[3\\]"):
        sa.ElasticBody(skfem.MeshTet(p, m.t, validate=False), MAT)


def test_degenerate_element_is_named():
    p = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [0, 0, 1]], float).T
    t = np.array([[0, 1, 2, 4], [0, 1, 2, 3]]).T  # second tet is flat (all z = 0)
    with pytest.raises(ValueError, match="degenerate.*\\[1\\]"):
        sa.ElasticBody(skfem.MeshTet(p, t, validate=False), MAT)


def test_inverted_element_is_named():
    # two tets on the same side of their shared face: the mesh folds over itself
    p = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.2, 0.2, 1], [0.3, 0.3, 0.5]], float).T
    t = np.array([[0, 1, 2, 3], [0, 1, 2, 4]]).T
    with pytest.raises(ValueError, match="inverted rest element: elements 0 and 1"):
        sa.ElasticBody(skfem.MeshTet(p, t, validate=False), MAT)


@pytest.mark.parametrize("density", [0.0, -1.0, np.nan])
def test_bad_density(density):
    with pytest.raises(ValueError, match="density"):
        sa.ElasticBody(small_mesh(), MAT, density=density)


def test_fixed_out_of_range_and_wrong_type():
    m = small_mesh()
    with pytest.raises(ValueError, match="out of range"):
        sa.ElasticBody(m, MAT, fixed=[0, m.p.shape[1]])
    with pytest.raises(ValueError, match="boolean fixed mask"):
        sa.ElasticBody(m, MAT, fixed=np.ones(3, dtype=bool))
    with pytest.raises(TypeError, match="indices"):
        sa.ElasticBody(m, MAT, fixed=[0.5])


def test_material_array_of_wrong_length():
    m = small_mesh()
    with pytest.raises(ValueError, match="length 3.*24 elements"):
        sa.ElasticBody(m, [MAT] * 3)
    with pytest.raises(TypeError, match="Material"):
        sa.ElasticBody(m, "rubber")


def test_material_dict_by_subdomain():
    m = beam_mesh(2).with_subdomains({"left": lambda x: x[0] < 2, "right": lambda x: x[0] >= 2})
    body = sa.ElasticBody(m, {"left": sa.NeoHookean(E=1e5, nu=0.3), "right": sa.StVK(E=1e6, nu=0.3)})
    assert len(body.materials) == 2 and set(np.unique(body.material_index)) == {0, 1}
    with pytest.raises(ValueError, match="not a subdomain"):
        sa.ElasticBody(m, {"middle": MAT})
    with pytest.raises(ValueError, match="in no subdomain"):
        sa.ElasticBody(m, {"left": MAT})


def test_velocity_shape_and_values():
    m = small_mesh()
    with pytest.raises(ValueError, match="velocity"):
        sa.ElasticBody(m, MAT, velocity=np.zeros((2, 3)))
    with pytest.raises(ValueError, match="non-finite"):
        sa.ElasticBody(m, MAT, velocity=(np.nan, 0, 0))
    body = sa.ElasticBody(m, MAT, velocity=(1.0, 0, 0), fixed=[0])
    assert np.all(body.velocity[0] == 0) and np.all(body.velocity[1:, 0] == 1.0)


@pytest.mark.parametrize("dt", [0.0, -0.01, np.nan, np.inf])
def test_bad_time_step(dt):
    body = sa.ElasticBody(small_mesh(), MAT)
    with pytest.raises(ValueError, match="time step dt"):
        sa.Simulation(body, dt=dt)


def test_bad_simulation_arguments():
    body = sa.ElasticBody(small_mesh(), MAT)
    with pytest.raises(TypeError, match="ElasticBody"):
        sa.Simulation(small_mesh())
    with pytest.raises(ValueError, match="gravity"):
        sa.Simulation(body, gravity=(0, 0))
    with pytest.raises(ValueError, match="alpha"):
        sa.Rayleigh(alpha=-1.0)
    with pytest.raises(ValueError, match="unknown solver"):
        sa.Simulation(body, solver="magic")
    with pytest.raises(ValueError, match="newton_iters"):
        sa.Simulation(body, newton_iters=0)
    with pytest.raises(ValueError, match="mass"):
        sa.Simulation(body, mass="heavy")
    with pytest.raises(TypeError, match="reducer"):
        sa.Simulation(body, reducer="affine")


def test_shared_meshes_load_and_validate(shared_meshes):
    import os
    for name in ("beam913.mesh", "Pill.mesh", "wheelFatHD.mesh", "octopus.mesh", "bed.mesh"):
        mesh = sa.io.load_mesh(os.path.join(shared_meshes, name))
        body = sa.ElasticBody(mesh, MAT)
        assert body.n_elements == mesh.t.shape[1]
