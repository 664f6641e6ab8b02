"""IPC log barrier against static colliders (duck-typed query), with full Newton and AdaptiveSubspace."""
import numpy as np
import pytest

import types

import skfem_affine as sa
from skfem_affine.contact import barrier


def model_of(sim):
    """The run's fixed data read off a Simulation (the attributes a Model carries)."""
    return types.SimpleNamespace(system=sim.system, dt=sim.dt, damping=sim.damping, gravity=sim.gravity,
                                 f_gravity=sim.f_gravity, project_hessian=sim.project_hessian, size=sim.size)


class Plane:
    """A tiny collider: the half-space above a plane (signed distance, normal)."""

    def __init__(self, point, normal):
        self.point = np.asarray(point, float)
        self.normal = np.asarray(normal, float) / np.linalg.norm(normal)

    def query(self, points):
        return (points - self.point) @ self.normal, np.broadcast_to(self.normal, points.shape)


class Sphere:
    def __init__(self, centre, radius):
        self.centre, self.radius = np.asarray(centre, float), float(radius)

    def query(self, points):
        r = points - self.centre
        dist = np.linalg.norm(r, axis=1)
        return dist - self.radius, r / dist[:, None]


def test_barrier_derivatives_match_finite_differences():
    dhat = 0.1
    d = np.array([1e-3, 0.02, 0.05, 0.0999])
    b, b1, b2 = barrier.barrier(d, dhat)
    eps = 1e-7
    bp, bp1, _ = barrier.barrier(d + eps, dhat)
    bm, bm1, _ = barrier.barrier(d - eps, dhat)
    assert np.allclose(b1, (bp - bm) / (2 * eps), rtol=1e-6)
    assert np.allclose(b2, (bp1 - bm1) / (2 * eps), rtol=1e-5)
    assert np.all(b > 0) and np.all(b2 > 0)
    assert barrier.barrier(np.array([0.2]), dhat)[0][0] == 0 and np.isinf(barrier.barrier(np.array([-1e-9]), dhat)[0][0])


def drop(reducer=None, collider=None, E=1e5, frames=30, **kw):
    sim = sa.scenes.free_body(resolution=2, size=0.5, velocity=(0, 0, -2.0), spin=(0, 0, 0), gravity=(0, 0, -9.81),
                              integrator="implicit_euler", reducer=reducer, material=sa.NeoHookean(E=E, nu=0.35), **kw)
    sim.colliders = [collider or Plane((0, 0, -0.3), (0, 0, 1))]
    lowest = []
    for s in sim.run(frames):
        d, _ = sim.colliders[0].query(s.x)
        lowest.append(d.min())
    return sim, np.array(lowest)


def test_contact_gradient_and_hessian_match_finite_differences():
    sim, _ = drop(frames=0)
    contact = barrier.Barrier(model_of(sim), [Plane((0, 0, -0.3), (0, 0, 1))], dhat=0.1)
    x = sim.state.x.copy()
    x[:, 2] -= 0.04  # bottom face 0.01 above the plane
    xf = x.reshape(-1)
    g = contact.gradient(xf)
    H = sim.system.pattern.matrix(contact.hessian_data(xf))
    rng = np.random.default_rng(0)
    p = rng.normal(size=g.size) * 1e-3
    free = sim.system.free
    eps = 1e-4
    xp, xm = xf.copy(), xf.copy()
    xp[free] += eps * p
    xm[free] -= eps * p
    assert (contact.energy(xp) - contact.energy(xm)) / (2 * eps) == pytest.approx(g @ p, rel=1e-5)
    assert np.allclose((contact.gradient(xp) - contact.gradient(xm)) / (2 * eps), H @ p, rtol=1e-4,
                       atol=1e-6 * np.abs(H @ p).max())


def test_full_newton_drop_on_a_plane_never_penetrates_and_bounces_back():
    sim, lowest = drop(frames=40)
    assert lowest.min() > 0
    assert lowest.min() < 0.1 * barrier.barrier_of(model_of(sim), sim.colliders).dhat + 1e-3  # it did touch
    vz = sim.state.v[:, 2].mean()
    assert vz > -0.5  # the downward 2 m/s was stopped
    assert all(r["newton_converged"] for r in sim.stats)


def test_curved_collider_is_not_penetrated():
    _, lowest = drop(collider=Sphere((0.1, 0.0, -1.3), 1.0), frames=30)
    assert 0 < lowest.min() < 0.01


@pytest.mark.slow
def test_adaptive_subspace_with_contact_stays_outside_and_a_stiff_body_is_not_enriched():
    eps = 1e-3
    runs = {}
    for E in (1e4, 1e9):
        red = sa.AdaptiveSubspace(fallback=None, basis=sa.SkinningEigenmodes(n=3, cache=False), eps_nodal=eps, eps_modal=eps,
                                  subdomains=8, newton_tol=1e-4)
        sim, lowest = drop(red, E=E, frames=25)
        assert lowest.min() > 0
        runs[E] = max(r["enriched_ratio"] for r in sim.stats)
    assert runs[1e4] > 0 and runs[1e9] == 0.0, runs


def test_bad_collider():
    sim, _ = drop(frames=0)
    with pytest.raises(TypeError, match="query"):
        barrier.Barrier(model_of(sim), [object()])
    with pytest.raises(ValueError, match="dhat"):
        barrier.Barrier(model_of(sim), [Plane((0, 0, 0), (0, 0, 1))], dhat=0.0)
    assert barrier.barrier_of(model_of(sim), []) is None and barrier.barrier_of(model_of(sim), None) is None


def test_a_cube_sliding_rigidly_down_a_frictionless_ramp_gets_no_enrichment():
    """Fig. 5: large error (the sliding body's momentum) but large progress from the translational mode."""
    th, frames = np.radians(30), 40
    late = {}
    for eps_progress in (1e-4, np.inf):
        red = sa.AdaptiveSubspace(fallback=None, basis=sa.AffineModes(), eps_nodal=5e-3, eps_modal=5e-3, eps_progress=eps_progress,
                                  subdomains=8, newton_tol=1e-4)
        sim = sa.scenes.free_body(resolution=2, size=0.5, velocity=(0, 0, 0), spin=(0, 0, 0), integrator="implicit_euler",
                                  gravity=(9.81 * np.sin(th), 0, -9.81 * np.cos(th)), reducer=red)
        sim.colliders = [Plane((0, 0, -0.25 - 0.5e-3 * sim.size), (0, 0, 1))]  # start inside the barrier's range
        for s in sim.run(frames):
            pass
        late[eps_progress] = [r["enriched_ratio"] for r in sim.stats[10:]]  # after landing
        assert s.v[:, 0].mean() == pytest.approx(9.81 * np.sin(th) * frames * sim.dt, rel=1e-2)  # frictionless slide
    assert max(late[1e-4]) == 0.0
    assert max(late[np.inf]) > 0.0  # the error alone would have enriched


@pytest.mark.slow
def test_raising_the_nodal_threshold_on_a_drop_enriches_less_and_leaves_a_larger_residual():
    """Fig. 12's trend on a small drop scene with contact (mean over the frames after impact)."""
    ratio, residual = [], []
    for eps in (0.0, 3e-3, 1e-2, 3e-2):
        red = sa.AdaptiveSubspace(fallback=None, basis=sa.SkinningEigenmodes(n=4, cache=False), eps_nodal=eps, eps_modal=0.5,
                                  subdomains=16, newton_tol=1e-4, record_residual=True)
        sim = sa.scenes.free_body(resolution=3, size=0.5, velocity=(0, 0, -2.0), spin=(0, 0, 0), gravity=(0, 0, -9.81),
                                  integrator="implicit_euler", reducer=red)
        sim.colliders = [Plane((0, 0, -0.27), (0, 0, 1))]
        for _ in sim.run(12):
            pass
        ratio.append(np.mean([r["enriched_ratio"] for r in sim.stats[4:]]))
        residual.append(np.mean([r["full_residual"] for r in sim.stats[4:]]))
    assert ratio[0] == 1.0 and np.all(np.diff(ratio) < 0) and ratio[-1] < 0.1, ratio
    assert np.all(np.diff(residual) > 0) and residual[0] < 1e-4 * residual[-1], residual


def test_the_package_colliders_passed_to_simulation_act_as_a_barrier_for_newton_integrators():
    sim = sa.scenes.free_body(resolution=2, size=0.5, velocity=(0, 0, -2.0), spin=(0, 0, 0), gravity=(0, 0, -9.81),
                              integrator="implicit_euler", colliders=[sa.Plane(point=(0, 0, -0.3), normal=(0, 0, 1))])
    assert sim.contact is None and len(sim.colliders) == 1  # no PGS with the Newton integrators
    for s in sim.run(20):
        assert s.x[:, 2].min() > -0.3
    assert sim.state.v[:, 2].mean() > -0.5
    with pytest.raises(ValueError, match="PGS"):
        sa.scenes.free_body(resolution=2, integrator="bdf2", contact=sa.PGS())
