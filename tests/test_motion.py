"""Prescribed motion (sa.Prescribed) and vertex forces (sa.VertexForce) under every integrator and reducer."""
import copy

import numpy as np
import pytest
import skfem

import skfem_affine as sa
from skfem_affine.integrators.problem import StepProblem


def beam(k=2, length=2.0):
    mesh = skfem.MeshTet.init_tensor(np.linspace(0, length, 2 * k + 1), np.linspace(0, 0.5, k + 1),
                                     np.linspace(0, 0.5, k + 1))
    return mesh, mesh.nodes_satisfying(lambda p: p[0] < 1e-9)


def turn(t, X):
    """Rotation about the beam's axis (y = z = 0.25) at 3 rad/s."""
    a = 3.0 * t
    c, s = np.cos(a), np.sin(a)
    C = np.array([0.0, 0.25, 0.25])
    return (X - C) @ np.array([[1, 0, 0], [0, c, s], [0, -s, c]]) + C


SETUPS = {  # (a function of each setup: a reducer object serves one simulation)
    "linearized-full": dict(),
    "linearized-affinification": dict(reducer=sa.Affinification(1e-4, 2e-4, min_fraction=0.5)),
    "linearized-rigidification": dict(reducer=sa.Rigidification(1e-3, 2e-3, min_fraction=0.5)),
    "linearized-newton": dict(newton_iters=4),
    "implicit-euler": dict(integrator="implicit_euler"),
    "bdf2": dict(integrator="bdf2", damping=sa.Rayleigh(0.1, 0.01)),
    # near a moving clamp the subspace moves through enriched nodes: a tolerance that enriches them
    "subspace": dict(integrator="implicit_euler", reducer=sa.AdaptiveSubspace(eps_nodal=1e-3)),
}


def _setup(name):
    """The keyword arguments of a setup, with a fresh copy of its reducer."""
    kw = dict(SETUPS[name])
    if "reducer" in kw:
        kw["reducer"] = copy.deepcopy(kw["reducer"])
    return kw


@pytest.mark.parametrize("setup", SETUPS)
def test_prescribed_rotation_moves_the_clamp_exactly_along_the_path(setup):
    mesh, clamp = beam()
    body = sa.ElasticBody(mesh, sa.NeoHookean(E=1e5, nu=0.35), density=1000.0,
                          prescribed=sa.Prescribed(clamp, turn))
    sim = sa.Simulation(body, dt=0.01, **_setup(setup))
    X = mesh.p.T
    for state in sim.run(12):
        assert np.abs(state.x[clamp] - turn(state.time, X[clamp])).max() <= 1e-12
    # the clamp drags its neighbours round: the layer next to it turned by a fair share of the clamp's angle
    layer = mesh.nodes_satisfying(lambda p: abs(p[0] - 0.5) < 1e-9)
    dx = state.x[layer] - X[layer]
    assert np.abs(dx).max() > 0.2 * np.abs(turn(state.time, X[layer]) - X[layer]).max()
    assert np.all(np.isfinite(state.v))


def test_linearized_coupling_solves_the_full_system_rows_of_the_free_dofs():
    """A_ff dv_f + A_fp dv_p = b_f over all DOFs (consistent mass, damped): the coupling is eq. 1-2's."""
    mesh, clamp = beam()
    body = sa.ElasticBody(mesh, sa.NeoHookean(E=1e5, nu=0.35), density=1000.0,
                          prescribed=sa.Prescribed(clamp, turn), velocity=(0.0, 0.1, -0.2))
    sim = sa.Simulation(body, dt=0.01, mass="consistent", damping=sa.Rayleigh(0.2, 0.01), gravity=(0, 0, -9.81))
    for _ in range(3):
        sim.step()
    s0 = sim.state.copy()
    s1 = sim.step()
    sysm, h = sim.system, sim.dt
    alpha, beta = sim.damping.alpha, sim.damping.beta
    f, H = sysm.forces_and_stiffness(s0.x, full=True)
    f = f + sim.f_gravity
    A = (1 + h * alpha) * sysm.M + (h * beta + h * h) * H
    v0 = s0.v.reshape(-1)
    b = h * (f - alpha * (sysm.M @ v0) - (beta + h) * (H @ v0))
    dv = s1.v.reshape(-1) - v0
    free = sysm.free
    res = (A @ dv - b)[free]
    assert np.abs(res).max() <= 1e-9 * np.abs(b[free]).max()
    assert np.abs(dv[~np.isin(np.arange(dv.size), free)]).max() > 0  # the clamp did move


@pytest.mark.parametrize("setup", ["linearized-full", "linearized-affinification", "implicit-euler"])
def test_constant_external_force_gives_the_closed_form_acceleration(setup):
    """F on one face of a free body, no gravity: the centre of mass accelerates at F / m."""
    mesh = skfem.MeshTet.init_tensor(*[np.linspace(0, 0.5, 3)] * 3)
    face = mesh.nodes_satisfying(lambda p: p[0] > 0.5 - 1e-9)
    per_vertex = np.array([3.0, -1.0, 2.0])
    body = sa.ElasticBody(mesh, sa.NeoHookean(E=1e5, nu=0.35), density=500.0)
    kw = _setup(setup)
    if setup == "implicit-euler":
        kw["newton_tol"] = 1e-12
    sim = sa.Simulation(body, dt=0.01, forces=[sa.VertexForce(face, per_vertex)], **kw)
    m = sim.system.lumped_mass
    a = per_vertex * face.size / m.sum()
    x0 = m @ sim.state.x / m.sum()
    k = 10
    for _ in range(k):
        state = sim.step()
    vc = m @ state.v / m.sum()
    xc = m @ state.x / m.sum()
    rtol = 1e-9 if setup.startswith("linearized") else 1e-6
    np.testing.assert_allclose(vc, k * sim.dt * a, rtol=rtol)
    # backward Euler positions: x_k = x_0 + h sum_j v_j = x_0 + h^2 a k (k + 1) / 2
    np.testing.assert_allclose(xc - x0, sim.dt ** 2 * a * k * (k + 1) / 2, rtol=rtol)
    assert np.ptp(state.x[:, 0] - mesh.p[0]) > 0  # the body deforms: the force acts on one face only


def test_vertex_force_sees_time_and_state_and_may_name_its_body():
    seen = []

    def pull(t, x, v):
        seen.append((t, x.shape, v.shape))
        return np.tile([0.0, 0.0, 1.0 + t], (x.shape[0], 1))

    mesh = skfem.MeshTet.init_tensor(*[np.linspace(0, 0.5, 3)] * 3)
    a = sa.ElasticBody(mesh, sa.NeoHookean(E=1e5, nu=0.35))
    b = sa.ElasticBody(mesh.translated((2.0, 0.0, 0.0)), sa.NeoHookean(E=1e5, nu=0.35))
    sim = sa.Simulation([a, b], dt=0.01, contact=False, forces=[sa.VertexForce([0, 1], pull, body=b)])
    sim.step()
    sim.step()
    assert seen[0] == (0.0, (2, 3), (2, 3)) and seen[1][0] == pytest.approx(0.01)
    n = mesh.p.shape[1]
    assert np.all(sim.state.v[:n] == 0) and sim.state.v[n:, 2].max() > 0


def test_prescribed_affine_motion_of_all_vertices_is_followed_exactly_with_affinification():
    mesh = skfem.MeshTet.init_tensor(*[np.linspace(0, 1, 3)] * 3)
    B = np.array([[0.1, 0.2, 0.0], [0.0, -0.1, 0.3], [0.05, 0.0, 0.2]])

    def affine(t, X):
        return X + t * (X @ B.T) + t ** 2 * np.array([0.3, -0.2, 1.0])

    body = sa.ElasticBody(mesh, sa.NeoHookean(E=1e5, nu=0.35),
                          prescribed=sa.Prescribed(np.arange(mesh.p.shape[1]), affine))
    sim = sa.Simulation(body, dt=0.01, reducer=sa.Affinification(1e-4, 2e-4), gravity=(0, 0, -9.81))
    for state in sim.run(10):
        assert np.abs(state.x - affine(state.time, mesh.p.T)).max() <= 1e-12


def test_prescribed_path_starts_the_simulation_and_runs_beside_fixed_vertices():
    mesh, clamp = beam()
    tip = mesh.nodes_satisfying(lambda p: p[0] > 2.0 - 1e-9)

    def shake(t, X):
        return X + np.array([0.0, 0.0, 0.05 * np.sin(20 * t) + 0.01])

    body = sa.ElasticBody(mesh, sa.StVK(E=1e5, nu=0.3), fixed=clamp, prescribed=sa.Prescribed(tip, shake))
    sim = sa.Simulation(body, dt=0.005)
    assert np.allclose(sim.state.x[tip, 2] - mesh.p[2, tip], 0.01)  # starts on the path
    for state in sim.run(5):
        assert np.array_equal(state.x[clamp], mesh.p.T[clamp])
        assert np.abs(state.x[tip] - shake(state.time, mesh.p.T[tip])).max() <= 1e-12


def test_linearized_newton_and_implicit_euler_agree_with_a_prescribed_clamp():
    mesh, clamp = beam()
    out = []
    for kw in (dict(newton_iters=30, newton_tol=1e-13), dict(integrator="implicit_euler", newton_tol=1e-11)):
        body = sa.ElasticBody(mesh, sa.NeoHookean(E=1e5, nu=0.35), prescribed=sa.Prescribed(clamp, turn))
        sim = sa.Simulation(body, dt=0.01, gravity=(0, 0, -9.81), **kw)
        for _ in range(5):
            sim.step()
        out.append(sim.state.x)
    assert np.abs(out[0] - out[1]).max() <= 1e-8


def test_bad_motion_input_is_refused_with_a_named_error():
    mesh, clamp = beam()
    mat = sa.NeoHookean(E=1e5, nu=0.35)
    with pytest.raises(TypeError, match="path"):
        sa.Prescribed(clamp, "not a function")
    with pytest.raises(ValueError, match="path"):
        sa.ElasticBody(mesh, mat, prescribed=sa.Prescribed(clamp, lambda t, X: X[:, :2]))
    with pytest.raises(ValueError, match="path"):
        sa.ElasticBody(mesh, mat, prescribed=sa.Prescribed(clamp, lambda t, X: X * np.nan))
    with pytest.raises(ValueError, match="also fixed"):
        sa.ElasticBody(mesh, mat, fixed=clamp, prescribed=sa.Prescribed(clamp, turn))
    with pytest.raises(ValueError, match="prescribed vertices"):
        sa.ElasticBody(mesh, mat, prescribed=sa.Prescribed([0, 10 ** 6], turn))
    with pytest.raises(TypeError, match="prescribed"):
        sa.ElasticBody(mesh, mat, prescribed=turn)
    body = sa.ElasticBody(mesh, mat)
    with pytest.raises(TypeError, match="forces"):
        sa.Simulation(body, forces="gravity")
    with pytest.raises(TypeError, match="forces\\[0\\]"):
        sa.Simulation(body, forces=[lambda t, x, v: x])
    with pytest.raises(ValueError, match="VertexForce vertices: vertex indices must be >= 0"):
        sa.VertexForce([-1], (0, 0, 1.0))
    with pytest.raises(ValueError, match="forces\\[0\\] vertices"):
        sa.Simulation(body, forces=[sa.VertexForce([10 ** 6], (0, 0, 1.0))])
    with pytest.raises(ValueError, match="force"):
        sa.VertexForce([0], (0.0, 1.0))
    sim = sa.Simulation(body, forces=[sa.VertexForce([0, 1], lambda t, x, v: np.zeros((3, 3)))])
    with pytest.raises(ValueError, match="forces\\[0\\]"):
        sim.step()


def test_step_problem_carries_the_frame_values_and_no_simulation():
    """The integrator hands the reducer the targets and forces as data."""
    mesh, clamp = beam()
    seen = {}

    from skfem_affine.reducers.full import FullSpace
    from skfem_affine.solvers import make_solver

    class Recording(FullSpace):
        def solve(self, problem):
            if isinstance(problem, StepProblem):
                seen["targets"], seen["f_ext"] = problem.targets, problem.f_ext
            return super().solve(problem)

    body = sa.ElasticBody(mesh, sa.NeoHookean(E=1e5, nu=0.35), prescribed=sa.Prescribed(clamp, turn))
    sim = sa.Simulation(body, dt=0.01, reducer=Recording(make_solver("direct")),
                        forces=[sa.VertexForce([int(np.argmax(mesh.p[0]))], (0.0, 0.0, -1.0))])
    sim.step()
    np.testing.assert_array_equal(seen["targets"].x, turn(0.01, mesh.p.T[clamp]))
    assert seen["f_ext"].shape == (3 * mesh.p.shape[1],) and seen["f_ext"].sum() == -1.0


@pytest.mark.parametrize("setup", ["linearized-full", "linearized-affinification", "implicit-euler"])
def test_a_prescribed_press_pushes_a_block_onto_a_plane(setup):
    """Prescribed vertices beside contact: the top follows its path, the bottom stays above the plane."""
    mesh = skfem.MeshTet.init_tensor(np.linspace(0, 1, 4), np.linspace(0, 0.5, 3), np.linspace(0.1, 0.6, 3))
    top = mesh.nodes_satisfying(lambda p: p[2] > 0.6 - 1e-9)

    def press(t, X):
        return X - np.array([0.0, 0.0, 0.3 * t])

    body = sa.ElasticBody(mesh, sa.NeoHookean(E=1e4, nu=0.3), density=100.0, prescribed=sa.Prescribed(top, press))
    sim = sa.Simulation(body, dt=0.01, gravity=(0, 0, -9.81), colliders=[sa.Plane((0, 0, 0), (0, 0, 1))],
                        **_setup(setup))
    for state in sim.run(40):
        assert np.abs(state.x[top] - press(state.time, mesh.p.T[top])).max() <= 1e-12
    assert state.x[:, 2].min() > -1e-6  # pressed onto the plane, not through it
    bottom = mesh.nodes_satisfying(lambda p: p[2] < 0.1 + 1e-9)
    assert state.x[bottom, 2].max() < 0.02  # it reached the plane


@pytest.mark.parametrize("setup", ["linearized-full", "implicit-euler"])
def test_a_checkpoint_resumes_a_prescribed_run_bit_identically(setup, tmp_path):
    mesh, clamp = beam()

    def build():
        body = sa.ElasticBody(mesh, sa.NeoHookean(E=1e5, nu=0.35), prescribed=sa.Prescribed(clamp, turn))
        return sa.Simulation(body, dt=0.01, forces=[sa.VertexForce([int(np.argmax(mesh.p[0]))], (0.0, 0.0, -2.0))],
                             **_setup(setup))

    sim = build()
    for _ in range(4):
        sim.step()
    path = sim.save(str(tmp_path / "run.npz"))
    for _ in range(4):
        sim.step()
    again = build()
    again.load_state(path)
    for _ in range(4):
        again.step()
    assert np.array_equal(again.state.x, sim.state.x) and np.array_equal(again.state.v, sim.state.v)
