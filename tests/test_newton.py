"""Full-space Newton on the incremental potential: implicit Euler and BDF2 (sec. 3.1, eq. 1-3)."""
import numpy as np
import pytest

import skfem_affine as sa
from skfem_affine.integrators import newton


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
    for _ in range(3):
        sim.step()
    ip = sim.stepper.potential()
    x = ip.x_t.copy()
    x = newton.newton_solve(ip, 1e-10, 50, sim.solve, {})
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
