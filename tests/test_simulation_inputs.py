"""Loose arguments of the simulation, the reducers and contact raise errors that name them."""
import numpy as np
import pytest

import skfem_affine as sa
from skfem_affine.contact.barrier import Barrier
from skfem_affine.lab import scenes


@pytest.fixture(scope="module")
def body():
    return scenes.cantilever(resolution=1).bodies[0]


@pytest.mark.parametrize("kwargs, error, match", [
    (dict(newton_iters=2.7), ValueError, "newton_iters must be an integer"),
    (dict(newton_iters=0), ValueError, "newton_iters must be an integer >= 1"),
    (dict(newton_iters="3"), TypeError, "newton_iters"),
    (dict(gravity=(0, 0, "9.81")), TypeError, "gravity"),
    (dict(gravity=(0, 9.81)), ValueError, "gravity"),
    (dict(gravity=(0, 0, np.inf)), ValueError, "gravity"),
    (dict(project_hessian="False"), TypeError, "project_hessian"),
    (dict(integrator="euler"), ValueError, "integrator must be one of"),
    (dict(damping=sa.Rayleigh(0.0, 0.0), dt="0.01"), TypeError, "dt"),
])
def test_simulation_arguments(body, kwargs, error, match):
    with pytest.raises(error, match=match):
        sa.Simulation(body, **kwargs)


def test_bodies_and_frames(body):
    with pytest.raises(TypeError, match="bodies"):
        sa.Simulation(None)
    sim = sa.Simulation(body)
    with pytest.raises(ValueError, match="frames must be an integer"):
        list(sim.run(2.5))
    with pytest.raises(ValueError, match="frames must be an integer >= 0"):
        list(sim.run(-1))
    assert sa.Simulation(body, newton_iters=3.0).newton_iters == 3


@pytest.mark.parametrize("make, error, match", [
    (lambda: sa.Rayleigh(alpha="0.1"), TypeError, "Rayleigh alpha"),
    (lambda: sa.Rayleigh(beta=-1.0), ValueError, "Rayleigh beta"),
    (lambda: sa.Affinification(tau_a="1e-4"), TypeError, "tau_a"),
    (lambda: sa.Affinification(tau_a=-1.0), ValueError, "tau_a"),
    (lambda: sa.Affinification(min_fraction=1.5), ValueError, "min_fraction"),
    (lambda: sa.Affinification(min_fraction=-0.1), ValueError, "min_fraction"),
    (lambda: sa.Affinification(preconditioner="ilu"), ValueError, "preconditioner must be one of"),
    (lambda: sa.Affinification(seeding="best"), ValueError, "seeding must be one of"),
    (lambda: sa.Affinification(seed=1.5), ValueError, "seed must be an integer"),
    (lambda: sa.Affinification(seed=-1), ValueError, "seed"),
    (lambda: sa.Affinification(min_body_elements=2.9), ValueError, "min_body_elements"),
    (lambda: sa.Affinification(min_body_elements=1), ValueError, "min_body_elements"),
    (lambda: sa.Rigidification(warmup_frames=2.5), ValueError, "warmup_frames"),
    (lambda: sa.Rigidification(tau_r=np.nan), ValueError, "tau_r"),
    (lambda: sa.AdaptiveSubspace(eps_nodal="0.5"), TypeError, "eps_nodal"),
    (lambda: sa.AdaptiveSubspace(subdomains=2.9), ValueError, "subdomains"),
    (lambda: sa.AdaptiveSubspace(record_residual="yes"), TypeError, "record_residual"),
    (lambda: sa.AdaptiveSubspace(hessian_init="zero"), ValueError, "hessian_init"),
    (lambda: sa.AdaptiveSubspace(blas_threads=0), ValueError, "blas_threads"),
    (lambda: sa.SkinningEigenmodes(n=2.5), ValueError, "n must be an integer"),
    (lambda: sa.SkinningEigenmodes(cache="no"), TypeError, "cache"),
    (lambda: sa.PGS(friction="0.5"), TypeError, "PGS friction"),
    (lambda: sa.PGS(iterations=2.5), ValueError, "PGS iterations"),
    (lambda: sa.PGS(erp=1.5), ValueError, "PGS erp"),
    (lambda: sa.PGS(margin=-1.0), ValueError, "PGS margin"),
    (lambda: sa.PGS(warm_start="False"), TypeError, "PGS warm_start"),
    (lambda: sa.PGS(body_contact=2), TypeError, "PGS body_contact"),
    (lambda: sa.PGS(block=0), ValueError, "PGS block"),
    (lambda: sa.PGS(iterations=20, max_iterations=10), ValueError, "PGS max_iterations"),
    (lambda: sa.PGS(max_iterations=True), TypeError, "PGS max_iterations"),
])
def test_component_arguments(make, error, match):
    with pytest.raises(error, match=match):
        make()


def test_valid_values_are_stored_as_plain_numbers():
    pgs = sa.PGS(friction=np.float32(0.25), iterations=10.0, warm_start=np.True_)
    assert type(pgs.friction) is float and type(pgs.iterations) is int and pgs.warm_start is True
    assert sa.Affinification(seed=None).seed is None
    assert sa.AdaptiveSubspace(eps_progress=np.inf).eps_progress == np.inf


def test_barrier_arguments(body):
    sim = sa.Simulation(body, integrator="implicit_euler")
    with pytest.raises(TypeError, match=r"colliders\[0\] is the class Plane"):
        Barrier(sim.model, [sa.Plane])
    with pytest.raises(ValueError, match="dhat"):
        Barrier(sim.model, [sa.Plane()], dhat=0.0)
    with pytest.raises(TypeError, match="kappa"):
        Barrier(sim.model, [sa.Plane()], kappa="1e3")


def test_one_reducer_in_two_simulations_is_refused(body):
    red = sa.Affinification(0.01, 0.02)
    sa.Simulation(body, reducer=red)
    with pytest.raises(ValueError, match="reducer .*already runs in another simulation"):
        sa.Simulation(body, reducer=red)
    sub = sa.AdaptiveSubspace(basis=sa.AffineModes(), eps_nodal=0.5)
    sa.Simulation(body, reducer=sub, integrator="implicit_euler")
    with pytest.raises(ValueError, match="reducer"):
        sa.Simulation(body, reducer=sub, integrator="implicit_euler")


def test_the_same_body_listed_twice_is_refused(body):
    with pytest.raises(ValueError, match=r"bodies\[0\] and bodies\[1\] are the same ElasticBody"):
        sa.Simulation([body, body])


def test_states_and_arrays_given_to_the_simulation_are_checked(body):
    sim = sa.Simulation(body, gravity=(0, 0, -9.81))
    n = sim.system.n
    with pytest.raises(TypeError, match="state"):
        sim.energy(3)
    with pytest.raises(ValueError, match=rf"state.x must have shape \({n}, 3\)"):
        sim.energy(sa.State(np.zeros((3, 3)), np.zeros((3, 3))))
    with pytest.raises(ValueError, match="state.v"):
        sim.energy(sa.State(sim.state.x, np.zeros((n, 2))))
    with pytest.raises(ValueError, match=rf"x must have shape \({n}, 3\)"):
        sim.max_penetration(np.zeros((4, 3)))
    with pytest.raises(TypeError, match="x"):
        sim.max_penetration("x")
    with pytest.raises(ValueError, match=rf"x must hold one row per vertex \({n}\)"):
        sim.split(np.zeros(5))
    assert [a.shape for a in sim.split(sim.state.x)] == [(n, 3)]
    sim.state.x = np.zeros((4, 3))
    with pytest.raises(ValueError, match=rf"sim.state.x must have shape \({n}, 3\)"):
        sim.step()
    sim.state = sa.State(sim.system.p0.copy(), np.zeros((n, 3)))
    sim.state.v = [[0.0, 0.0, 0.0]] * n  # a list: not an array of the state
    with pytest.raises(TypeError, match="sim.state.v"):
        sim.step()
    sim.state.v = np.zeros((n, 3))
    assert sim.energy()["total"] == 0.0 and sim.step().frame == 1
