"""Affinification and rigidification as reducers of the simulation."""
import numpy as np
import pytest

import skfem_affine as sa
from skfem_affine.reducers.affine.rigidification import strain_rates


def test_zero_thresholds_reproduce_the_full_solve():
    ref = sa.scenes.cantilever(resolution=3, solver="superlu", damping=sa.Rayleigh(0.1, 0.01), E=1e5)
    sim = sa.scenes.cantilever(resolution=3, solver="superlu", damping=sa.Rayleigh(0.1, 0.01),
                               reducer=sa.Affinification(tau_a=0, tau_e=0, solver="superlu"), E=1e5)
    for a, b in zip(ref.run(20), sim.run(20)):
        assert np.abs(a.x - b.x).max() <= 1e-10 * ref.size
        assert np.all(b.clusters == -1)
    assert sim.stats[-1]["dofs"] == ref.stats[-1]["dofs"]


def test_uniform_affine_motion_becomes_one_affine_body_and_stays_affine():
    """A free cube given v = c + L x (no gravity): one affine body whose motion stays exactly affine.

    With a tight tau it is one body at the first frame (all F_dot equal); later the predicted
    rates feel the (non-affine) elastic response to the strain, so a tau that tolerates it keeps
    the body whole, and its motion then stays exactly affine.
    """
    x0 = sa.scenes.free_body(resolution=3).system.p0
    L = np.array([[0.02, 0.01, 0.0], [-0.01, 0.03, 0.02], [0.0, 0.01, -0.02]])
    v0 = (x0 - x0.mean(0)) @ L.T + [0.5, 0.0, -0.2]
    tight = sa.scenes.free_body(resolution=3, velocity=v0, reducer=sa.Affinification(tau_a=1e-9, tau_e=1e-9))
    assert np.all(tight.step().clusters == 0)
    sim = sa.scenes.free_body(resolution=3, velocity=v0, reducer=sa.Affinification(tau_a=1.0, tau_e=1.0))
    for s in sim.run(30):
        assert s.clusters.max() == 0 and np.all(s.clusters == 0)
        # positions remain an affine image of the rest positions: least-squares fit is exact
        Xh = np.c_[x0, np.ones(len(x0))]
        coef, *_ = np.linalg.lstsq(Xh, s.x, rcond=None)
        assert np.abs(Xh @ coef - s.x).max() <= 1e-10 * sim.size
    assert sim.stats[-1]["dofs"] == 12
    # linear momentum is conserved by the projection and the reduced solve, to round-off of the
    # momentum's scale (total mass x largest speed): a component that starts at 0 is not exactly 0
    m = sim.system.lumped_mass[:, None]
    scale = m.sum() * np.abs(v0).max()
    assert np.abs((m * s.v).sum(0) - (m * v0).sum(0)).max() <= 1e-12 * scale


def test_affinification_is_close_to_full_and_reduces_dofs():
    ref = sa.scenes.cantilever(resolution=3, E=1e5, damping=None)
    sim = sa.scenes.cantilever(resolution=3, reducer=sa.Affinification(tau_a=1e-2, tau_e=2e-2), E=1e5, damping=None)
    for a, b in zip(ref.run(60), sim.run(60)):
        pass
    assert np.abs(a.x - b.x).max() < 0.05 * ref.size
    assert sim.stats.mean("dofs") < 0.8 * ref.stats.mean("dofs")
    r = sim.stats[-1]
    for key in ("prediction", "clustering", "map_assembly", "reduced_assembly", "factorization", "solve",
                "n_clusters", "elastic_dofs", "reduced_fraction"):
        assert key in r


def test_very_large_tau_is_stable_for_200_frames():
    sim = sa.scenes.cantilever(resolution=3, reducer=sa.Affinification(tau_a=1e6, tau_e=1e6), E=1e5, damping=None)
    for s in sim.run(200):
        assert np.all(np.isfinite(s.x))
    assert np.mean(s.clusters >= 0) > 0.8
    assert sim.energy()["total"] <= 1e-9 * abs(sim.energy()["gravity"])


def test_seeded_runs_are_reproducible():
    runs = []
    for _ in range(2):
        sim = sa.scenes.cantilever(resolution=2, reducer=sa.Affinification(tau_a=1e-2, tau_e=2e-2, seed=4),
                                   E=1e5, damping=None)
        for s in sim.run(10):
            pass
        runs.append((s.x, s.clusters))
    assert np.array_equal(runs[0][1], runs[1][1]) and np.array_equal(runs[0][0], runs[1][0])


@pytest.mark.parametrize("seeding", ["index", "temporal"])
@pytest.mark.parametrize("preconditioner", ["ichol", "amg"])
def test_options_run(seeding, preconditioner):
    sim = sa.scenes.cantilever(resolution=2, reducer=sa.Affinification(
        tau_a=1e-2, tau_e=2e-2, seeding=seeding, preconditioner=preconditioner), E=1e5, damping=None)
    for s in sim.run(10):
        pass
    assert np.all(np.isfinite(s.x)) and np.any(s.clusters >= 0)


def test_resource_limiting_forces_a_fraction_affine():
    sim = sa.scenes.cantilever(resolution=3, reducer=sa.Affinification(tau_a=0.0, tau_e=0.0,
                                                                        min_fraction=0.5), E=1e5, damping=None)
    for s in sim.run(10):
        pass
    assert np.mean(s.clusters >= 0) > 0.3


def test_bad_reducer_arguments():
    with pytest.raises(ValueError, match="tau_a"):
        sa.Affinification(tau_a=-1)
    with pytest.raises(ValueError, match="tau_e"):
        sa.Affinification(tau_e=np.nan)
    with pytest.raises(ValueError, match="seeding"):
        sa.Affinification(seeding="spiral")
    with pytest.raises(ValueError, match="preconditioner"):
        sa.Affinification(preconditioner="jacobi")
    with pytest.raises(ValueError, match="fraction"):
        sa.Affinification(min_fraction=2)
    with pytest.raises(ValueError, match="warmup"):
        sa.Rigidification(warmup_frames=-1)
    with pytest.raises(ValueError, match="min_body_elements"):
        sa.Affinification(min_body_elements=1)


def test_min_body_elements_dissolves_small_bodies():
    smallest = {}
    for k in (2, 6):
        sim = sa.scenes.cantilever(resolution=3, E=1e5, damping=None,
                                   reducer=sa.Affinification(tau_a=0.05, tau_e=0.1, min_body_elements=k))
        sizes = [np.bincount(s.clusters[s.clusters >= 0]) for s in sim.run(15) if np.any(s.clusters >= 0)]
        assert sizes
        smallest[k] = min(c.min() for c in sizes)
        assert smallest[k] >= k
    assert smallest[2] < 6  # the default keeps bodies of fewer than 6 elements in this scene


def test_rigidification_metric_is_the_squared_strain_rate_at_the_midpoint():
    """||sym(F^T F_dot)||^2 with F at x + h v / 2 (Mercier-Aubin et al. 2022), against numpy."""
    sim = sa.scenes.cantilever(resolution=2, reducer=sa.Rigidification(1e-2, 2e-2), E=1e5, damping=None)
    for _ in range(3):
        sim.step()
    sysm = sim.system
    x = sim.state.x
    v = np.random.default_rng(0).normal(size=x.shape)
    F = sysm.deformation_gradients(x + 0.5 * sim.dt * v)
    E = np.einsum("eki,ekj->eij", F, sysm.deformation_gradients(v))
    E = 0.5 * (E + E.transpose(0, 2, 1))
    ref = np.einsum("eij,eij->e", E, E)
    assert np.allclose(strain_rates(sysm, x, v, sim.dt), ref, rtol=1e-12, atol=0)
    # a rigid rotation rate about the current shape has no strain rate
    W = np.array([[0.0, -0.5, -0.2], [0.5, 0.0, -0.3], [0.2, 0.3, 0.0]])  # [w]x
    mid = np.linalg.solve(np.eye(3) - 0.5 * sim.dt * W, x.T).T  # y = x + h/2 W y
    spin = mid @ W.T  # v = w x y, so that F_dot = [w]x F at the midpoint y
    assert np.allclose(mid, x + 0.5 * sim.dt * spin)
    assert np.all(strain_rates(sysm, x, spin, sim.dt) < 1e-24)


def test_shared_arguments_have_one_name():
    assert sa.Affinification(0.1, 0.2, min_fraction=0.4).min_fraction == 0.4
    assert sa.Rigidification(min_fraction=0.2).min_fraction == 0.2
    for cls, old in ((sa.Affinification, "min_affine_fraction"), (sa.Rigidification, "min_rigid_fraction")):
        with pytest.raises(TypeError, match=old):  # the names before min_fraction are gone
            cls(**{old: 0.3})
    with pytest.raises(ValueError, match="min_fraction"):
        sa.Rigidification(min_fraction=-0.1)
    with pytest.raises(TypeError):  # beyond the thresholds, arguments are keyword-only
        sa.Affinification(0.1, 0.2, "random")
    a = sa.Affinification(seeding="index", preconditioner="amg", seed=3, solver="superlu")
    r = sa.Rigidification(seeding="index", preconditioner="amg", seed=3, solver="superlu")
    for key in ("seeding", "preconditioner_kind", "seed", "solver_spec", "min_fraction", "tau_e"):
        assert type(getattr(a, key)) is type(getattr(r, key))
        assert getattr(a, key) == getattr(r, key) or key == "tau_e"


def test_the_simulation_checks_the_reducers_declared_integrators():
    body = sa.scenes.cantilever(resolution=1).bodies[0]
    with pytest.raises(ValueError, match="newton_iters"):  # was silently ignored: the reducer solves once
        sa.Simulation(body, reducer=sa.Affinification(), newton_iters=3)
    with pytest.raises(ValueError, match="linearized"):
        sa.Simulation(body, reducer=sa.Rigidification(), integrator="implicit_euler")
    with pytest.raises(TypeError, match="reducer"):
        sa.Simulation(body, reducer=object())
    with pytest.raises(ValueError, match="integrator"):
        sa.Simulation(body, integrator="rk4")
    assert sa.Affinification.integrators == ("linearized",) and sa.Rigidification.integrators == ("linearized",)
    # the full space iterates: newton_iters > 1 is fine without a reducer
    sim = sa.Simulation(body, newton_iters=3, gravity=(0, 0, -9.81))
    sim.step()
    assert sim.stats[-1]["newton_iters"] >= 1


def test_a_reducer_gets_the_model_never_the_simulation():
    sim = sa.scenes.cantilever(resolution=1, reducer=sa.Affinification(0.1, 0.2))
    red = sim.reducer
    assert red.model is sim.model and red.setup_time > 0
    assert not any(isinstance(v, sa.Simulation) for v in vars(red).values())
    sim.step()
    assert not any(isinstance(v, sa.Simulation) for v in vars(red).values())
