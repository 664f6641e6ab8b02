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


def _tet_mesh(p, t):
    return skfem.MeshTet(np.asarray(p, float).T.copy(), np.asarray(t).T.copy(), validate=False)


UNIT_TET = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]


def test_unused_vertices_are_refused_with_the_remedy():
    m = small_mesh()
    p = np.hstack([m.p, [[9.0, 9.0], [9.0, 8.0], [9.0, 7.0]]])
    mesh = skfem.MeshTet(p, m.t, validate=False)
    n = m.p.shape[1]
    with pytest.raises(ValueError, match=rf"2 vertices used by no element: \[{n}, {n + 1}\].*remove_unused_nodes"):
        sa.ElasticBody(mesh, MAT)
    body = sa.ElasticBody(mesh.remove_unused_nodes(), MAT)  # the remedy the message gives works
    assert body.n_vertices == n


@pytest.mark.parametrize("p, t, match", [
    ([[0, 0, 0]] * 4, [[0, 1, 2, 3]], "all its vertices coincide"),
    (UNIT_TET + [[0.5, 0.5, 0.5]] * 4, [[0, 1, 2, 3], [4, 5, 6, 7]], r"degenerate.*\[1\]"),   # 0/0 quality
    (UNIT_TET + [[2, 2, 2]], [[0, 1, 2, 3], [1, 2, 3, 4], [1, 2, 3, 3]], r"\[2\].*same vertex twice"),
    (UNIT_TET, [[0, 1, 2, 3], [3, 1, 2, 0]], r"duplicated elements.*\[0, 1\]"),
    (UNIT_TET + [[1e-12, 1e-12, 1e-12]], [[0, 1, 2, 3], [0, 1, 2, 4], [4, 1, 2, 3]], r"degenerate.*\[1\]"),
])
def test_degenerate_elements_are_named_even_when_quality_is_nan(p, t, match):
    with pytest.raises(ValueError, match=match):
        sa.ElasticBody(_tet_mesh(p, t), MAT)


def test_empty_and_non_finite_meshes_are_refused():
    with pytest.raises(ValueError, match="mesh is empty"):
        sa.ElasticBody(skfem.MeshTet(np.zeros((3, 0)), np.zeros((4, 0), dtype=int), validate=False), MAT)
    with pytest.raises(ValueError, match="mesh is empty"):
        sa.ElasticBody(skfem.MeshTet(np.eye(3, 4), np.zeros((4, 0), dtype=int), validate=False), MAT)
    p = np.array(UNIT_TET, float)
    p[2, 1] = np.inf
    with pytest.raises(ValueError, match=r"non-finite.*vertices \[2\]"):
        sa.ElasticBody(_tet_mesh(p, [[0, 1, 2, 3]]), MAT)
    with pytest.raises(ValueError, match=r"elements \[0\] reference vertices out of range"):
        sa.ElasticBody(_tet_mesh(UNIT_TET, [[0, 1, 2, 4]]), MAT)


def test_quadratic_mesh_is_refused_with_the_way_to_its_vertices():
    m2 = skfem.MeshTet2.init_tensor(*[np.linspace(0, 1, 2)] * 3) if hasattr(skfem.MeshTet2, "init_tensor") \
        else skfem.MeshTet2()
    with pytest.raises(TypeError, match=r"mesh must be a linear \(P1\).*MeshTet2.*mesh\.p\[:, :mesh\.nvertices\]"):
        sa.ElasticBody(m2, MAT)
    body = sa.ElasticBody(skfem.MeshTet(m2.p[:, :m2.nvertices], m2.t), MAT)
    assert body.n_vertices == m2.nvertices and body.volumes.sum() == pytest.approx(1.0)


@pytest.mark.parametrize("scale", [1e-80, 1e-3, 1e3, 1e80])
def test_mesh_check_does_not_depend_on_the_unit_of_length(scale):
    m = small_mesh()
    body = sa.ElasticBody(m.scaled(scale), MAT)
    assert body.volumes.sum() == pytest.approx(4.0 * scale ** 3, rel=1e-9)


def test_mesh_too_small_for_floating_point_is_refused():
    with pytest.raises(ValueError, match="too large or too small"):
        sa.ElasticBody(small_mesh().scaled(1e-120), MAT)


@pytest.mark.parametrize("kwargs, error, match", [
    (dict(material=sa.NeoHookean(E=np.full(5, 1e5), nu=0.3)), ValueError, "material E.*length 24"),
    (dict(material=sa.StVK(E=1e5, nu=np.full(25, 0.3))), ValueError, "material nu.*length 24"),
    (dict(material=sa.NeoHookean), TypeError, "class NeoHookean"),
    (dict(material=[sa.NeoHookean] * 24), TypeError, "class NeoHookean"),
    (dict(density="1000"), TypeError, "density"),
    (dict(density=True), TypeError, "density"),
    (dict(density=np.full(23, 1000.0)), ValueError, "density.*length 24"),
    (dict(density=[1000.0] * 23 + [np.inf]), ValueError, "density.*finite"),
    (dict(fixed=[0, 1] + [0] * 17 + [1]), ValueError, "fixed.*boolean mask.*indices"),
    (dict(fixed=[True, 3]), TypeError, "fixed mixes booleans and integers"),
    (dict(fixed="0"), ValueError, "fixed: .0. is not a boundary of the mesh"),  # a str names a boundary
    (dict(fixed=np.ones((20, 1), dtype=bool)), ValueError, "boolean fixed mask"),
    (dict(velocity=["1", "0", "0"]), TypeError, "velocity"),
    (dict(velocity=np.zeros((20, 2))), ValueError, "velocity"),
    (dict(name=3), TypeError, "name"),
])
def test_loose_body_arguments_are_refused(kwargs, error, match):
    args = dict(material=MAT, **kwargs) if "material" not in kwargs else kwargs
    with pytest.raises(error, match=match):
        sa.ElasticBody(small_mesh(), **args)


def test_fixed_accepts_masks_indices_and_sets():
    m = small_mesh()
    n = m.p.shape[1]
    mask = np.zeros(n, dtype=bool)
    mask[[0, 5]] = True
    for fixed in (mask, [0, 5], np.array([5, 0, 5]), {0, 5}, np.array([[0], [5]])):
        assert np.array_equal(sa.ElasticBody(m, MAT, fixed=fixed).fixed, mask)
    assert not sa.ElasticBody(m, MAT, fixed=[]).fixed.any()
    assert sa.ElasticBody(m, MAT, fixed=[0, 1]).fixed.sum() == 2  # short 0/1 lists are indices


@pytest.mark.parametrize("E, nu, error, match", [
    (1e5, "0.3", TypeError, "nu"),
    ("1e5", 0.3, TypeError, "E"),
    (True, 0.3, TypeError, "E"),
    (1e5, None, TypeError, "nu"),
    (1e5 + 0j, 0.3, TypeError, "E"),
    (np.full((2, 2), 1e5), 0.3, ValueError, "E"),
    (np.full(3, 1e5), np.full(4, 0.3), ValueError, "same length"),
    (np.zeros(0), 0.3, ValueError, "E"),
    (1e308, 0.49999, ValueError, "non-finite Lame"),
    (1e5, np.inf, ValueError, "nu"),
])
def test_loose_material_parameters_are_refused(E, nu, error, match):
    for cls in (sa.StVK, sa.Corotational, sa.NeoHookean):
        with pytest.raises(error, match=match):
            cls(E=E, nu=nu)
