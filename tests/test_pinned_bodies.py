"""Affine bodies containing fixed and prescribed vertices (Affinification(pinned_bodies=True))."""
import numpy as np
import pytest
import skfem

import skfem_affine as sa
from skfem_affine.reducers.affine import mapping as reduction


def affine_fit_residual(x, v, vertices):
    """Largest residual of v_i = c + B x_i fitted over ``vertices`` (least squares): 0 for an affine motion."""
    P = np.hstack([np.ones((vertices.size, 1)), x[vertices]])
    coef, *_ = np.linalg.lstsq(P, v[vertices], rcond=None)
    return np.abs(P @ coef - v[vertices]).max()


def bodies_with(state, system, mask):
    """The vertex sets of this frame's bodies that contain a vertex of ``mask``."""
    vc = reduction.vertex_clusters(state.clusters, system.t, system.n)
    out = []
    for b in np.unique(vc[mask & (vc >= 0)]):
        out.append(np.flatnonzero(vc == b))
    return out


def test_a_body_with_pinned_vertices_keeps_them_pinned_and_moves_affinely():
    mesh = skfem.MeshTet.init_tensor(np.linspace(0, 2, 5), np.linspace(0, 1, 3), np.linspace(0, 1, 3))
    clamp = mesh.nodes_satisfying(lambda p: p[0] < 1e-9)  # a face: coplanar pins
    body = sa.ElasticBody(mesh, sa.NeoHookean(E=1e5, nu=0.35), density=1000.0, fixed=clamp)
    red = sa.Affinification(1e-4, 2e-4, min_fraction=1.0, pinned_bodies=True)
    sim = sa.Simulation(body, dt=0.01, gravity=(0, 0, -9.81), reducer=red)
    X = mesh.p.T
    seen = 0
    for state in sim.run(15):
        assert np.abs(state.x[clamp] - X[clamp]).max() <= 1e-12
        for verts in bodies_with(state, sim.system, sim.system.fixed):
            seen += 1
            # the pins (velocity 0) belong to the body's affine velocity field
            assert affine_fit_residual(X, state.v, verts) <= 1e-10 * max(np.abs(state.v).max(), 1.0)
    assert seen > 0 and any(r.get("pinned_bodies", 0) for r in sim.stats)
    assert np.abs(state.x - X).max() > 1e-3  # the rest sags


def test_a_body_pinned_at_four_non_coplanar_vertices_does_not_move():
    mesh = skfem.MeshTet.init_tensor(*[np.linspace(0, 1, 4)] * 3)
    X = mesh.p.T
    t0 = mesh.t[:, 0]  # the four vertices of one tet: non-coplanar
    body = sa.ElasticBody(mesh, sa.NeoHookean(E=1e5, nu=0.35), density=1000.0, fixed=t0)
    red = sa.Affinification(1e-4, 2e-4, min_fraction=1.0, pinned_bodies=True)
    sim = sa.Simulation(body, dt=0.01, gravity=(0, 0, -9.81), reducer=red)
    fixed = np.zeros(X.shape[0], dtype=bool)
    fixed[t0] = True
    seen = 0
    previous = sim.state.copy()
    for state in sim.run(10):
        for verts in bodies_with(state, sim.system, fixed):
            if np.sum(fixed[verts]) == 4:
                seen += 1
                assert np.abs(state.v[verts]).max() <= 1e-12
                assert np.abs(state.x[verts] - previous.x[verts]).max() <= 1e-12
        previous = state
    assert seen > 0


def test_a_body_with_a_prescribed_clamp_follows_it():
    mesh = skfem.MeshTet.init_tensor(np.linspace(0, 2, 5), np.linspace(0, 1, 3), np.linspace(0, 1, 3))
    clamp = mesh.nodes_satisfying(lambda p: p[0] < 1e-9)

    def lift(t, X):  # a rigid motion of the clamp: rotation about y and a rise
        a = 0.5 * t
        c, s = np.cos(a), np.sin(a)
        return X @ np.array([[c, 0, -s], [0, 1, 0], [s, 0, c]]) + np.array([0.0, 0.0, 0.3 * t])

    body = sa.ElasticBody(mesh, sa.NeoHookean(E=1e5, nu=0.35), density=1000.0, prescribed=sa.Prescribed(clamp, lift))
    red = sa.Affinification(1e-4, 2e-4, min_fraction=1.0, pinned_bodies=True)
    sim = sa.Simulation(body, dt=0.01, reducer=red)
    X = mesh.p.T
    seen = 0
    for state in sim.run(15):
        assert np.abs(state.x[clamp] - lift(state.time, X[clamp])).max() <= 1e-12
        for verts in bodies_with(state, sim.system, sim.system.prescribed):
            seen += 1
            assert affine_fit_residual(X, state.v, verts) <= 1e-9 * np.abs(state.v).max()
    assert seen > 0


def test_the_constrained_solve_without_pins_is_the_papers_reduced_step():
    """Solving G^T A G y = G^T (b + A (v - g0)) for v directly equals eq. 9-12 (project, solve dq, add d)."""
    from skfem_affine.integrators.problem import StepProblem
    from skfem_affine.reducers.affine import pinned
    from skfem_affine.solvers import make_solver

    mesh = skfem.MeshTet.init_tensor(np.linspace(0, 2, 5), np.linspace(0, 1, 3), np.linspace(0, 1, 3))
    body = sa.ElasticBody(mesh, sa.NeoHookean(E=1e5, nu=0.35), velocity=(0.0, 0.0, 0.0))
    red = sa.Affinification(1e-4, 2e-4, min_fraction=0.7)
    sim = sa.Simulation(body, dt=0.01, reducer=red, damping=sa.Rayleigh(0.1, 0.01),
                        forces=[sa.VertexForce([0, 1], (0.0, 5.0, -20.0))])
    for _ in range(5):
        sim.step()
    s = sim.state
    problem = StepProblem.at(sim.model, s.x, s.v)
    vc = reduction.vertex_clusters(red.labels, sim.system.t, sim.system.n)
    gmap = red._mapping(problem, vc, int(red.labels.max()) + 1)
    assert gmap.n_bodies > 0
    G, free = gmap.G, sim.system.free
    vf = s.v.reshape(-1)[free]
    q = gmap.project(red.mdiag, vf)
    d = reduction.discrepancy(G, q, vf)
    vp = s.v.copy()
    vp.reshape(-1)[free] += d
    A = problem.matrix()
    dq = np.linalg.solve((G.T @ A @ G).toarray(), G.T @ problem.rhs(vp))
    paper = reduction.lift(G, dq, d)
    ours, _ = pinned.solve(problem, G, np.zeros(free.size), make_solver("direct"), {})
    assert np.abs(ours - paper).max() <= 1e-9 * np.abs(paper).max()


def test_pinned_bodies_option_is_checked():
    with pytest.raises(TypeError, match="pinned_bodies"):
        sa.Affinification(pinned_bodies="yes")
