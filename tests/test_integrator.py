"""Linearized backward Euler: momentum, statics, energy, extremes, divergence."""
import numpy as np
import pytest

import skfem_affine as sa
from skfem_affine.integrators.rotation import RotationStretch
from skfem_affine.lab.scenes import beam_mesh


def momenta(sim, s):
    m = sim.system.lumped_mass[:, None]
    return (m * s.v).sum(0), (m * np.cross(s.x, s.v)).sum(0)


@pytest.mark.parametrize("shape", ["cube", "ball"])
def test_free_flight_conserves_linear_momentum(shape):
    sim = sa.scenes.free_body(resolution=3, shape=shape, spin=(1.0, 2.0, 3.0), velocity=(0.3, -0.2, 0.1))
    p0, _ = momenta(sim, sim.state)
    for s in sim.run(100):
        p, _ = momenta(sim, s)
        assert np.linalg.norm(p - p0) <= 1e-8 * np.linalg.norm(p0)
    # the centre of mass moves in a straight line at constant speed
    com = (sim.system.lumped_mass[:, None] * s.x).sum(0) / sim.system.lumped_mass.sum()
    com0 = (sim.system.lumped_mass[:, None] * sim.system.p0).sum(0) / sim.system.lumped_mass.sum()
    assert np.allclose(com, com0 + s.time * p0 / sim.system.lumped_mass.sum(), rtol=0, atol=1e-10 * sim.size)


def test_angular_momentum_follows_the_discrete_balance_law():
    """The linearized step changes L by exactly h sum f(x_t) x (h v_{t+1} + e), e the stretch the linear
    position update gives the rotation (its numerical damping of spin).

    Unprojected Hessian so the rotational-invariance identity sum x x K u = sum f x u holds exactly.
    """
    sim = sa.scenes.free_body(resolution=3, spin=(0.5, 1.0, 2.0), project_hessian=False)
    h = sim.dt
    stretch = RotationStretch(sim.system)
    for _ in range(100):
        s0 = sim.state
        f, _ = sim.system.forces_and_stiffness(s0.x, tangent=False)
        e = stretch(s0.x, s0.v, h).reshape(-1, 3)
        s1 = sim.step()
        _, L0 = momenta(sim, s0)
        _, L1 = momenta(sim, s1)
        torque = h * np.cross(f.reshape(-1, 3), h * s1.v + e).sum(0)
        assert np.linalg.norm(L1 - L0 - torque) <= 1e-8 * np.linalg.norm(L0)


def test_angular_momentum_drift_is_first_order_in_h():
    """Relative loss of |L| over time T is about h w^2 T for a spinning body; it halves with h."""
    loss = []
    w = 2.0
    for h in (0.01, 0.005):
        sim = sa.scenes.free_body(resolution=3, spin=(0.0, 0.0, w), velocity=(0, 0, 0), dt=h)
        _, L0 = momenta(sim, sim.state)
        for s in sim.run(int(round(1.0 / h))):
            pass
        _, L1 = momenta(sim, s)
        loss.append(1 - np.linalg.norm(L1) / np.linalg.norm(L0))
        assert loss[-1] == pytest.approx(h * w * w * 1.0, rel=0.1)
    assert loss[1] == pytest.approx(loss[0] / 2, rel=0.05)


def static_tip_deflection(k, length=10.0, E=1e8):
    """Converged quasi-static (huge h, Newton) tip deflection of a cantilever under gravity."""
    mesh = beam_mesh(k, length=length, width=1.0)
    body = sa.ElasticBody(mesh, sa.NeoHookean(E=E, nu=0.0), density=1000.0,
                          fixed=mesh.nodes_satisfying(lambda p: p[0] < 1e-9))
    sim = sa.Simulation(body, dt=1e4, gravity=(0, 0, -9.81), newton_iters=30, newton_tol=1e-12)
    s = sim.step()
    tip = mesh.p[0] > length - 1e-9
    return -s.x[tip, 2].mean() + mesh.p[2, tip].mean(), sim


def test_cantilever_static_deflection_converges_to_euler_bernoulli():
    L, E, rho, g = 10.0, 1e8, 1000.0, 9.81
    q, I = rho * g * 1.0, 1.0 / 12.0
    exact = q * L ** 4 / (8 * E * I)
    errors = []
    for k in (2, 4, 6):  # P1 tets lock in bending: 45%, 18%, 9% here
        d, sim = static_tip_deflection(k, L, E)
        errors.append(abs(d - exact) / exact)
        assert sim.stats[-1]["newton_iters"] < 30  # converged
    assert errors[0] > errors[1] > errors[2]
    assert errors[-1] < 0.10, errors


def test_newton_first_iterate_is_the_linearized_step():
    a = sa.scenes.cantilever(resolution=2, damping=sa.Rayleigh(0.1, 0.01), E=1e5)
    b = sa.scenes.cantilever(resolution=2, damping=sa.Rayleigh(0.1, 0.01), newton_iters=2, newton_tol=1e30, E=1e5)
    for _ in range(5):
        sa_, sb = a.step(), b.step()
    assert np.allclose(sa_.x, sb.x, rtol=0, atol=1e-12)


def test_newton_converges_to_implicit_euler():
    """At convergence M (v1 - v0) = h f(x0 + h v1) (undamped)."""
    sim = sa.scenes.cantilever(resolution=2, newton_iters=50, newton_tol=1e-13, E=1e5, damping=None)
    for _ in range(3):
        s0 = sim.state
        s1 = sim.step()
        f, _ = sim.system.forces_and_stiffness(s1.x, tangent=False)
        f += sim.f_gravity
        free = sim.system.free
        r = sim.system.Mff @ (s1.v - s0.v).reshape(-1)[free] - sim.dt * f[free]
        assert np.linalg.norm(r) <= 1e-8 * np.linalg.norm(sim.dt * f[free])


def test_damped_energy_decays_and_undamped_does_not_grow():
    und = sa.scenes.cantilever(resolution=2, material=sa.NeoHookean(E=1e6, nu=0.3), damping=None)
    dam = sa.scenes.cantilever(resolution=2, material=sa.NeoHookean(E=1e6, nu=0.3),
                               damping=sa.Rayleigh(alpha=2.0, beta=0.01))
    e_und, e_dam = [und.energy()["total"]], [dam.energy()["total"]]
    k_und, k_dam = [], []
    for su, sd in zip(und.run(150), dam.run(150)):
        e_und.append(und.energy(su)["total"])
        e_dam.append(dam.energy(sd)["total"])
        k_und.append(und.energy(su)["kinetic"])
        k_dam.append(dam.energy(sd)["kinetic"])
    scale = abs(min(e_und))
    # backward Euler is dissipative: no growth beyond round-off
    assert max(e_und) <= e_und[0] + 1e-9 * scale
    assert np.all(np.diff(e_und) <= 1e-6 * scale)
    # with damping the swinging dies out: far less kinetic energy late in the run, more energy lost
    assert np.mean(k_dam[-50:]) < 0.3 * np.mean(k_und[-50:])
    assert e_dam[-1] < e_und[-1]
    assert np.all(np.diff(e_dam) <= 1e-6 * scale)


MATERIALS = [sa.StVK, sa.Corotational, sa.NeoHookean]


@pytest.mark.parametrize("cls", MATERIALS)
@pytest.mark.parametrize("E", [1e2, 1e5, 1e9])
@pytest.mark.parametrize("nu", [0.0, 0.3, 0.49])
@pytest.mark.parametrize("h", [1e-4, 1e-2, 5e-2])
@pytest.mark.parametrize("reduced", [False, True], ids=["full", "affinification"])
def test_extremes_grid(cls, E, nu, h, reduced):
    """Finite, energy-bounded states at extreme stiffness, compressibility and time step."""
    reducer = sa.Affinification(tau_a=1e-4, tau_e=2e-4) if reduced else None
    sim = sa.scenes.cantilever(resolution=1, material=cls(E=E, nu=nu), dt=h, reducer=reducer, damping=None)
    for s in sim.run(30):
        assert np.all(np.isfinite(s.x))
    e = sim.energy()
    assert np.isfinite(e["total"])
    # dissipative integrator: total energy never exceeds the initial (zero) by more than round-off
    assert e["total"] <= 1e-9 * max(abs(e["gravity"]), 1.0)


def test_divergence_is_reported_with_the_frame():
    sim = sa.scenes.cantilever(resolution=1, E=1e5, damping=None)
    sim.step()
    sim.state.v[5] = np.nan  # poison the state as a blow-up would
    with pytest.raises(sa.SimulationDiverged, match="non-finite state detected at frame 2"):
        sim.step()


def test_fixed_vertices_do_not_move():
    sim = sa.scenes.cantilever(resolution=2, E=1e5, damping=None)
    fixed = sim.system.fixed
    for s in sim.run(10):
        pass
    assert np.array_equal(s.x[fixed], sim.system.p0[fixed])
    assert np.all(s.v[fixed] == 0)
    assert s.frame == 10 and s.time == pytest.approx(0.1)


@pytest.mark.parametrize("solver", ["superlu", "pardiso", "amg", "auto"])
def test_solvers_agree(solver):
    if solver == "pardiso" and not sa.solvers.has_pardiso():
        pytest.skip("pypardiso not installed")
    ref = sa.scenes.cantilever(resolution=2, solver="superlu", E=1e5, damping=None)
    sim = sa.scenes.cantilever(resolution=2, solver=solver, E=1e5, damping=None)
    for a, b in zip(ref.run(10), sim.run(10)):
        pass
    assert np.allclose(a.x, b.x, atol=1e-6 * ref.size)
    assert sim.stats[-1]["solver"] in ("superlu", "pardiso", "amg")


def test_auto_solver_tries_both_solvers_on_large_systems_then_keeps_the_faster():
    sim = sa.scenes.cantilever(resolution=2, solver=sa.solvers.AutoSolver(amg_min_dofs=10), E=1e5, damping=None)
    for _ in sim.run(6):
        pass
    used, auto = [r["solver"] for r in sim.stats], sim.solver
    direct = used[0]
    assert direct in ("pardiso", "superlu") and used[:2] == [direct, direct] and auto._amg is not None
    assert auto.choice in ("amg", "direct") and used[-1] == (direct if auto.choice == "direct" else "amg")
    if len(auto.trial) == 4:  # AMG-CG ran both systems on trial: the faster per system was kept
        assert used[2:4] == ["amg", "amg"]
        assert auto.choice == ("amg" if auto.trial[3][1] < auto.trial[1][1] else "direct")
    else:  # CG took longer than a direct solve: stopped, that system solved directly
        assert auto.choice == "direct" and used[2] == direct
    # below amg_min_dofs: the direct solver only, no trial
    small = sa.scenes.cantilever(resolution=2, solver="auto", E=1e5, damping=None)
    for _ in small.run(5):
        pass
    assert {r["solver"] for r in small.stats} == {direct} and small.solver.trial == []


def test_auto_solver_keeps_amg_when_it_measures_faster():
    auto = sa.solvers.AutoSolver(amg_min_dofs=10)
    auto.trial = [("direct", 1e3), ("direct", 1e3)]  # direct solves "measured" at 1000 s each
    sim = sa.scenes.cantilever(resolution=2, solver=auto, E=1e5, damping=None)
    for _ in sim.run(4):
        pass
    assert [r["solver"] for r in sim.stats] == ["amg"] * 4 and auto.choice == "amg" and len(auto.trial) == 4


def test_auto_solver_stops_an_amg_trial_slower_than_the_direct_solver():
    auto = sa.solvers.AutoSolver(amg_min_dofs=10)
    auto.trial = [("direct", 1.0), ("direct", 1e-9)]  # a direct solve "measured" at a nanosecond
    sim = sa.scenes.cantilever(resolution=2, solver=auto, E=1e5, damping=None)
    x = []
    for state in sim.run(2):
        x.append(state.x)
    assert sim.stats[0]["solver"] in ("pardiso", "superlu")  # the AMG system on trial was solved directly
    assert auto.choice == "direct" and auto.amg_abandoned
    reference = sa.scenes.cantilever(resolution=2, solver="direct", E=1e5, damping=None)
    for a, state in zip(x, reference.run(2)):
        assert np.allclose(a, state.x, rtol=0, atol=1e-9)


def test_auto_solver_abandons_amg_when_it_converges_slowly():
    sim = sa.scenes.cantilever(resolution=3, material=sa.NeoHookean(E=1e9, nu=0.49), dt=0.05,
                               solver=sa.solvers.AutoSolver(amg_min_dofs=10, amg_max_iterations=5), damping=None)
    for _ in sim.run(4):
        pass
    assert sim.solver._amg is not None  # tried (and too slow: more iterations than allowed, or than a direct solve)
    assert sim.solver.amg_abandoned and sim.solver.choice == "direct"
    assert sim.stats[-1]["solver"] in ("pardiso", "superlu")


def test_stats_record_phases_and_dofs():
    sim = sa.scenes.cantilever(resolution=2, E=1e5, damping=None)
    for _ in sim.run(3):
        pass
    r = sim.stats[-1]
    for key in ("assembly", "factorization", "solve", "wall", "dofs", "solver"):
        assert key in r
    assert r["dofs"] == sim.system.free.size
    summ = sim.stats.summary()
    assert summ["frames"] == 3 and summ["wall_s"] > 0


def test_multiple_bodies_are_independent_without_contact():
    a = sa.scenes.cantilever(resolution=2, E=1e5, damping=None)
    m2 = beam_mesh(1)
    b = sa.ElasticBody(m2.translated((0, 3, 0)), sa.StVK(E=1e6, nu=0.3), density=500.0,
                       velocity=(0, 0, 1.0))
    both = sa.Simulation([a.bodies[0], b], dt=0.01, gravity=(0, 0, -9.81))
    for s in both.run(5):
        pass
    for s_a in a.run(5):
        pass
    xa, xb = both.split(s.x)
    assert np.allclose(xa, s_a.x, atol=1e-12)
    # the free body falls ballistically: z = z0 + v t - g t^2/2 with backward Euler's h-shift
    t = 0.05
    expected = m2.p[2].mean() + 1.0 * t - 9.81 * sum((k + 1) for k in range(5)) * 0.01 ** 2
    assert xb[:, 2].mean() == pytest.approx(expected, abs=1e-9)


@pytest.mark.slow
def test_heterogeneous_materials():
    mesh = beam_mesh(2)
    mats = [sa.NeoHookean(E=1e5, nu=0.3), sa.NeoHookean(E=1e7, nu=0.3), sa.StVK(E=1e6, nu=0.2)]
    per_element = [mats[i % 3] for i in range(mesh.t.shape[1])]
    body = sa.ElasticBody(mesh, per_element, fixed=mesh.nodes_satisfying(lambda p: p[0] < 1e-9))
    sim = sa.Simulation(body, dt=0.01, gravity=(0, 0, -9.81))
    assert len(sim.system.groups) == 2
    for s in sim.run(5):
        pass
    # the same forces as evaluating each element with its own material
    F = sim.system.deformation_gradients(s.x)
    P, _ = sim.system.stresses(F, tangent=False)
    for e in (0, 1, 2, 7):
        assert np.allclose(P[e], per_element[e].stress(F[e:e + 1])[0])
