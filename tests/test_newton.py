"""Full-space Newton on the incremental potential: implicit Euler and BDF2 (sec. 3.1, eq. 1-3)."""
import numpy as np
import pytest

import types

import skfem_affine as sa
from skfem_affine.integrators import newton
from skfem_affine.integrators.newton_integrator import NewtonIntegrator
from skfem_affine.simulation import State
from skfem_affine.solvers import make_solver


def model_of(sim):
    """The run's fixed data read off a Simulation (the attributes a Model carries)."""
    return types.SimpleNamespace(system=sim.system, dt=sim.dt, damping=sim.damping, gravity=sim.gravity,
                                 f_gravity=sim.f_gravity, project_hessian=sim.project_hessian, size=sim.size)


def beam(**kw):
    kw.setdefault("resolution", 1)
    kw.setdefault("material", sa.NeoHookean(E=1e5, nu=0.3))
    kw.setdefault("damping", None)
    return sa.scenes.cantilever(**kw)


def final_positions(h, T, scheme):
    sim = beam(dt=h, integrator=scheme, newton_tol=1e-7)
    for s in sim.run(int(round(T / h))):
        pass
    assert all(r["newton_converged"] for r in sim.stats)
    return s.x


def test_bdf2_is_second_order_and_implicit_euler_first():
    T = 0.32
    ref = final_positions(T / 128, T, "bdf2")
    ratio = {}
    for scheme in ("bdf2", "implicit_euler"):
        e1, e2 = (np.abs(final_positions(h, T, scheme) - ref).max() for h in (0.04, 0.02))
        ratio[scheme] = e1 / e2
    assert 3.4 < ratio["bdf2"] < 4.6, ratio
    assert 1.7 < ratio["implicit_euler"] < 2.3, ratio


def test_implicit_euler_equals_the_converged_newton_option():
    damping = sa.Rayleigh(alpha=0.2, beta=0.01)
    a = beam(resolution=2, damping=damping, newton_iters=50, newton_tol=1e-13)
    b = beam(resolution=2, damping=damping, integrator="implicit_euler", newton_tol=1e-10)
    for _ in range(5):
        sa_, sb = a.step(), b.step()
    assert np.abs(sa_.x - sb.x).max() <= 1e-9 * a.size
    assert np.abs(sa_.v - sb.v).max() <= 1e-7 * np.abs(sa_.v).max()


def test_first_newton_iterate_is_the_linearized_step():
    a = beam(resolution=2, damping=sa.Rayleigh(0.1, 0.01))
    b = beam(resolution=2, damping=sa.Rayleigh(0.1, 0.01), integrator="implicit_euler", newton_iters=1)
    sa_, sb = a.step(), b.step()
    assert np.allclose(sa_.x, sb.x, rtol=0, atol=1e-12)


@pytest.mark.parametrize("scheme", ["implicit_euler", "bdf2"])
def test_converged_step_is_stationary_for_the_potential(scheme):
    """grad E(x_{t+1}) = 0: M a = f (a = (x - x~)/(alpha h^2)), i.e. the scheme's momentum balance."""
    sim = beam(resolution=2, integrator=scheme, newton_tol=1e-10)
    integrator = NewtonIntegrator(model_of(sim), scheme, None, make_solver("direct"), None, tol=1e-10)
    state = sim.state
    for _ in range(3):
        x, v, _ = integrator.step(state, {})
        state = State(x, v, state.frame + 1)
    ip = integrator.potential(state)
    assert ip.scheme == scheme
    x, ok = newton.newton_solve(ip, make_solver("direct"), {})
    assert ok
    f, _ = sim.system.forces_and_stiffness(x.reshape(-1, 3), tangent=False)
    g = ip.gradient(x, f)
    assert np.linalg.norm(g) <= 1e-8 * np.linalg.norm(ip.weight * (f + sim.f_gravity)[sim.system.free])
    assert newton.full_space_residual(ip, x) <= 1e-9 * sim.size


def test_bdf2_uses_the_previous_state():
    """BDF2 with x_{t-1} = x_t - h v_t - ... differs from implicit Euler after the first step only."""
    ie = beam(integrator="implicit_euler", newton_tol=1e-10)
    b2 = beam(integrator="bdf2", newton_tol=1e-10)
    s1, t1 = ie.step(), b2.step()
    assert np.allclose(s1.x, t1.x, atol=1e-12)
    assert b2.stats[-1]["integrator"] == "implicit_euler" and ie.stats[-1]["integrator"] == "implicit_euler"
    s2, t2 = ie.step(), b2.step()
    assert b2.stats[-1]["integrator"] == "bdf2"
    assert np.abs(s2.x - t2.x).max() > 1e-6


def test_energy_does_not_grow_and_bdf2_dissipates_less_than_implicit_euler():
    lost = {}
    for scheme in ("implicit_euler", "bdf2"):
        sim = beam(material=sa.NeoHookean(E=1e6, nu=0.3), integrator=scheme, newton_tol=1e-8)
        e = [sim.energy()["total"]]
        for s in sim.run(60):
            e.append(sim.energy(s)["total"])
        scale = abs(min(e))
        assert max(e) <= e[0] + 1e-6 * scale
        lost[scheme] = e[0] - e[-1]
    assert 0 < lost["bdf2"] < 0.5 * lost["implicit_euler"], lost


def test_bad_integrator_and_reducer_combinations():
    with pytest.raises(ValueError, match="integrator"):
        beam(integrator="rk4")
    with pytest.raises(ValueError, match="linearized"):
        beam(integrator="bdf2", reducer=sa.Affinification(tau_a=0.1, tau_e=0.2))


def test_linearized_newton_first_iterate_is_the_linear_step_and_it_converges_to_the_iterated_option():
    damping = sa.Rayleigh(alpha=0.2, beta=0.01)
    lin = beam(resolution=2, damping=damping)
    model, s = model_of(lin), lin.state
    rec = {}
    dv1, A = newton.linearized_newton(model, s.x, s.v, make_solver("direct"), 1e-9, 1, rec)
    lin.step()
    free = lin.system.free
    expect = (lin.state.v - s.v).reshape(-1)[free]
    assert np.abs(dv1 - expect).max() <= 1e-10 * np.abs(expect).max()
    assert rec["newton_iters"] == 1 and A.shape == (free.size, free.size)
    # converged: the same step as the iterated linearized option and as the implicit Euler integrator
    it = beam(resolution=2, damping=damping, newton_iters=50, newton_tol=1e-12)
    ie = beam(resolution=2, damping=damping, integrator="implicit_euler", newton_tol=1e-10)
    for _ in range(3):
        s = it.state
        rec = {}
        dv, _ = newton.linearized_newton(model, s.x, s.v, make_solver("direct"), 1e-12, 50, rec)
        it.step(), ie.step()
        assert rec["newton_converged"] and rec["newton_iters"] > 1
        for other in (it, ie):
            ref = (other.state.v - s.v).reshape(-1)[free]
            assert np.abs(dv - ref).max() <= 1e-7 * np.abs(ref).max()


def test_the_loop_calls_the_direction_and_after_step_once_per_iteration():
    sim = beam(resolution=2, integrator="implicit_euler")
    ip = newton.IncrementalPotential(model_of(sim), sim.state.x, sim.state.v, tol=1e-10, max_iters=20)
    full = newton.FullSpaceDirection(ip, make_solver("direct"))
    calls, steps = [], []

    def direction(x, g, data, rec, e):
        assert e == pytest.approx(ip.energy(x), rel=1e-12) and data.H is not None
        calls.append(x.copy())
        return full(x, g, data, rec, e)

    rec = {}
    x, ok = newton.newton(ip, direction, rec, after_step=lambda x, alpha: steps.append((x.copy(), alpha)))
    assert ok and rec["newton_converged"] and len(calls) == len(steps) == rec["newton_iters"] > 1
    assert np.array_equal(calls[0], ip.x_t) and np.array_equal(steps[-1][0], x)
    assert all(0 < a <= 1 for _, a in steps)
    x2, _ = newton.newton_solve(newton.IncrementalPotential(model_of(sim), sim.state.x, sim.state.v, tol=1e-10,
                                                            max_iters=20), make_solver("direct"), {})
    assert np.array_equal(x, x2)


def test_newton_integrator_restarts_bdf2_with_implicit_euler_after_an_outside_change():
    sim = beam(integrator="bdf2")
    integ = NewtonIntegrator(model_of(sim), "bdf2", None, make_solver("direct"), None)
    state, schemes = sim.state, []
    for _ in range(2):
        rec = {}
        x, v, result = integ.step(state, rec)
        schemes.append(rec["integrator"])
        assert result.x.shape == (x.size,) and rec["newton_converged"]
        state = State(x, v, state.frame + 1)
    rec = {}
    integ.step(State(state.x, np.zeros_like(state.v), state.frame + 5), rec)  # not the state it stepped to
    assert schemes == ["implicit_euler", "bdf2"] and rec["integrator"] == "implicit_euler"
    with pytest.raises(ValueError, match="integrator"):
        NewtonIntegrator(model_of(sim), "rk4", None, None, None)


def test_bad_newton_settings_are_refused():
    sim = beam()
    with pytest.raises(ValueError, match="max_iters"):
        newton.IncrementalPotential(model_of(sim), sim.state.x, sim.state.v, max_iters=0)
    with pytest.raises(ValueError, match="newton_tol"):
        newton.IncrementalPotential(model_of(sim), sim.state.x, sim.state.v, tol=0.0)
    with pytest.raises(ValueError, match="stop_on"):
        newton.newton(newton.IncrementalPotential(model_of(sim), sim.state.x, sim.state.v), None, {}, stop_on="energy")


def test_newton_settings_live_in_one_place():
    resolve = newton.resolve_newton_settings
    assert resolve(None, None, None) == (None, None)
    assert resolve(1e-5, 7, None) == (1e-5, 7)
    red = sa.AdaptiveSubspace
    assert resolve(None, None, red()) == (1e-3, 50)  # neither given: the reducer's defaults
    assert resolve(1e-5, 7, red()) == (1e-5, 7)  # the Simulation's win over the reducer's defaults
    assert resolve(None, None, red(newton_tol=1e-4, max_newton=9)) == (1e-4, 9)  # old code: adopted
    assert resolve(1e-4, None, red(newton_tol=1e-4, max_newton=9)) == (1e-4, 9)  # the same value twice is fine
    with pytest.raises(ValueError, match="newton_tol"):
        resolve(1e-6, None, red(newton_tol=1e-4))
    with pytest.raises(ValueError, match="newton_iters.*max_newton"):
        resolve(None, 20, red(max_newton=9))
