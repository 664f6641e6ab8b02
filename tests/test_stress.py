"""Strains and stresses (skfem_affine.stress) against closed forms at static equilibrium.

Equilibrium is one implicit step with a time step far longer than the bodies' periods and
Newton run to convergence (the inertia left is below 1e-3 of the loads); loads are the
consistent nodal forces of a traction on boundary faces.
"""
import meshio
import numpy as np
import pytest
import skfem

import skfem_affine as sa


def face_forces(mesh, on_face, traction):
    """Consistent nodal forces (vertex indices, (k, 3)) of a traction, linear on each facet.

    ``on_face(X)`` picks the boundary facets whose three vertices (X of shape (3, k)) all
    satisfy it; ``traction(X, n)`` is the traction (k, 3) at points X (k, 3) with outward
    normals n (k, 3).
    """
    X = mesh.p.T
    fac = mesh.facets[:, mesh.boundary_facets()]
    fac = fac[:, np.all([on_face(X[f].T) for f in fac], axis=0)]
    a, b, c = X[fac[0]], X[fac[1]], X[fac[2]]
    cross = np.cross(b - a, c - a)
    area = 0.5 * np.linalg.norm(cross, axis=1)
    n = cross / (2 * area[:, None])
    n *= np.sign(np.einsum("ij,ij->i", n, (a + b + c) / 3 - X.mean(axis=0)))[:, None]  # convex bodies
    tv = [traction(X[f], n) for f in fac]
    forces = np.zeros_like(X)
    for k in range(3):  # int phi_k t dA for t linear on the facet
        np.add.at(forces, fac[k], (tv[k] + tv[0] + tv[1] + tv[2]) * area[:, None] / 12.0)
    idx = np.flatnonzero(np.any(forces != 0, axis=1))
    return idx, forces[idx]


def static(mesh, forces, fixed=None, material=None, dt=100.0):
    body = sa.ElasticBody(mesh, material or sa.NeoHookean(E=1e7, nu=0.3), fixed=fixed)
    idx, f = forces
    sim = sa.Simulation(body, dt=dt, newton_iters=30, newton_tol=1e-12, solver="direct",
                        forces=[sa.VertexForce(idx, lambda t, x, v: f)], on_nonconvergence="raise")
    sim.step()
    return sim


def centroids(mesh):
    return mesh.p[:, mesh.t].mean(axis=1)


def test_uniaxial_tension_gives_force_over_area_in_the_bar():
    L, w, force = 1.0, 0.1, 10.0
    mesh = skfem.MeshTet.init_tensor(np.linspace(0, L, 11), np.linspace(0, w, 3), np.linspace(0, w, 3))
    pull = face_forces(mesh, lambda X: X[0] > L - 1e-9, lambda X, n: np.tile([force / w ** 2, 0, 0], (len(X), 1)))
    assert np.allclose(pull[1].sum(axis=0), [force, 0, 0])
    sim = static(mesh, pull, fixed=mesh.nodes_satisfying(lambda p: p[0] < 1e-9))
    s = sim.stress()
    mid = np.abs(centroids(mesh)[0] - L / 2) < 0.2 * L  # away from the clamp (Saint-Venant)
    ref = force / w ** 2
    assert s.cauchy[mid, 0, 0] == pytest.approx(ref, rel=2e-3)
    assert s.piola[mid, 0, 0] == pytest.approx(ref, rel=2e-3)
    other = s.cauchy[mid].reshape(-1, 9)[:, 1:]
    assert np.abs(other).max() < 2e-3 * ref
    assert s.von_mises[mid] == pytest.approx(ref, rel=2e-3)
    assert s.principal[mid, 0] == pytest.approx(ref, rel=2e-3)
    E = sim.bodies[0].materials[0].E
    assert s.strain[mid, 0, 0] == pytest.approx(ref / E, rel=5e-3)  # linear elastic: eps = sigma / E
    # energy density sigma^2 / 2E, and its integral the strain energy of the run
    assert s.energy_density[mid] == pytest.approx(ref ** 2 / (2 * E), rel=5e-3)
    assert sim.system.volumes @ s.energy_density == pytest.approx(sim.energy()["strain"], rel=1e-12)
    assert s.vertex.cauchy.shape == (mesh.p.shape[1], 3, 3) and s.vertex.location == "vertex"
    inner = np.abs(mesh.p[0] - L / 2) < 0.1 * L
    assert s.vertex.cauchy[inner, 0, 0] == pytest.approx(ref, rel=2e-3)


def test_hydrostatic_compression_gives_minus_p_identity():
    mesh = skfem.MeshTet.init_tensor(*[np.linspace(-0.05, 0.05, 4)] * 3)
    p = 1e4
    squeeze = face_forces(mesh, lambda X: np.ones(X.shape[1], dtype=bool), lambda X, n: -p * n)
    # a free body under dead hydrostatic compression may turn (it lowers the loads' potential):
    # a step of 50 ms (about 50 periods of the cube) is static to 1e-4 yet short enough to keep it still
    s = static(mesh, squeeze, dt=0.05).stress()
    assert np.abs(s.piola + p * np.eye(3)).max() < 1e-4 * p  # nominal traction = -p N exactly
    assert np.abs(s.cauchy + p * np.eye(3)).max() < 2e-3 * p  # true stress, areas shrunk by ~1e-3
    assert np.abs(s.vertex.cauchy + p * np.eye(3)).max() < 2e-3 * p
    assert s.principal == pytest.approx(-p, rel=2e-3)
    assert np.all(s.von_mises < 1e-3 * p)


def pure_bending_root_stress(nx, nz, L=0.2, w=0.1, M=0.1):
    """Top-fibre stress at the root of a clamped beam under an end moment M, over M c / I.

    From a volume-weighted linear fit of sigma_xx over z of the elements next to the clamp
    (their stress is constant per element; the fit reads it off at the top fibre z = c).
    With nu = 0 the exact solution is pure bending everywhere, clamp included.
    """
    mesh = skfem.MeshTet.init_tensor(np.linspace(0, L, nx + 1), np.linspace(0, w, 2), np.linspace(0, w, nz + 1))
    c, inertia = w / 2, w * w ** 3 / 12
    couple = face_forces(mesh, lambda X: X[0] > L - 1e-9,
                         lambda X, n: np.stack([M * (X[:, 2] - c) / inertia, 0 * X[:, 0], 0 * X[:, 0]], axis=1))
    assert np.sum(couple[1][:, 0] * (mesh.p[2, couple[0]] - c)) == pytest.approx(M)
    sim = static(mesh, couple, fixed=mesh.nodes_satisfying(lambda p: p[0] < 1e-9),
                 material=sa.NeoHookean(E=1e7, nu=0.0))
    s = sim.stress()
    cen = centroids(mesh)
    root = cen[0] < L / 10
    z, sxx, V = cen[2, root] - c, s.cauchy[root, 0, 0], sim.system.volumes[root]
    A = np.stack([np.ones_like(z), z], axis=1) * np.sqrt(V)[:, None]
    a, b = np.linalg.lstsq(A, sxx * np.sqrt(V), rcond=None)[0]
    return (a + b * c) / (M * c / inertia), a / (M * c / inertia)


def test_pure_bending_root_stress_is_m_c_over_i():
    # linear tets are stiff in bending (locking): 0.96-0.97 on this mesh, closer on finer ones
    top, mean = pure_bending_root_stress(16, 8)
    assert top == pytest.approx(1.0, abs=0.05)
    assert abs(mean) < 0.02  # no net axial stress (1 % on this mesh)
    coarse, _ = pure_bending_root_stress(4, 2)
    assert abs(1 - coarse) > abs(1 - top)


def test_series_writes_stresses_per_cell_and_point(tmp_path):
    sim = sa.scenes.cantilever(resolution=1)
    sim.step()
    sa.io.write_series(tmp_path / "beam", sim, states=[sim.state])
    back = meshio.read(tmp_path / "beam_00001.vtu")
    s = sim.stress()
    for key, (name, _, _) in sa.stress.FIELDS.items():
        assert np.allclose(back.cell_data[name][0].reshape(getattr(s, key).shape), getattr(s, key))
        assert np.allclose(back.point_data[name].reshape(getattr(s.vertex, key).shape), getattr(s.vertex, key))
    assert back.cell_data["cauchy_stress"][0].shape == (sim.system.m, 9)
    sa.io.write_series(tmp_path / "plain", sim, states=[sim.state], stresses=False)
    assert "cauchy_stress" not in meshio.read(tmp_path / "plain_00001.vtu").point_data


def test_vertex_averages_weigh_elements_by_volume_and_skip_inverted_ones():
    sim = sa.scenes.cantilever(resolution=1)
    x = sim.state.x.copy()
    s = sim.stress(x)
    assert np.abs(s.cauchy).max() == 0 and np.all(s.energy_density == 0)
    # one vertex pushed through its opposite face inverts the elements around it
    t = sim.system.t
    v = t[0, 0]
    x[v] = 2 * x[t[1:, 0]].mean(axis=0) - x[v]
    s = sim.stress(x)
    J = np.linalg.det(sim.system.deformation_gradients(x))
    bad = J <= 0
    assert bad.any() and np.all(np.isnan(s.cauchy[bad])) and np.all(np.isfinite(s.strain))
    near = np.any(t == v, axis=0) & ~bad
    w = sim.system.volumes[near]
    if near.any():
        assert np.allclose(s.vertex.cauchy[v], np.tensordot(w, s.cauchy[near], axes=1) / w.sum())
    assert np.allclose(s.vertex.strain[v], np.tensordot(sim.system.volumes[np.any(t == v, axis=0)],
                                                        s.strain[np.any(t == v, axis=0)], axes=1)
                       / sim.system.volumes[np.any(t == v, axis=0)].sum())


def test_stress_refuses_positions_of_another_shape():
    sim = sa.scenes.cantilever(resolution=1)
    with pytest.raises(ValueError, match="state"):
        sim.stress(np.zeros((3, 3)))
