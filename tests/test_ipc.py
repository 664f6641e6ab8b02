"""IPC contact from ipctk (contact/ipc.py): non-penetration, friction, start checks, derivatives.

Most tests minimise the package's incremental potential with its Newton loop step by step, so that
they can watch every line-search trial; the last ones run the same contact through the Simulation
(``contact=sa.IPC(...)`` under a Newton integrator).
"""
import ipctk
import numpy as np
import pytest
import skfem

import skfem_affine as sa
from skfem_affine.contact import ipc
from skfem_affine.integrators import newton
from skfem_affine.integrators.potential import IncrementalPotential


class IPCPotential(IncrementalPotential):
    """The incremental potential with IPC contact, its friction lagged at the step's start (as the
    Newton integrator does); the contact Hessian enters through ``contact_hessian``."""

    def __init__(self, sim, x_t, v_t, contact, x_prev=None, v_prev=None, tol=1e-4):
        super().__init__(sim.model, x_t, v_t, x_prev, v_prev, barrier=contact, tol=tol, max_iters=50)
        contact.begin_step(self.x_t, self.x_hat, self.c)


def cube(center, size=0.5, cells=2, velocity=(0, 0, 0), E=1e5, fixed=None):
    mesh = skfem.MeshTet.init_tensor(*[np.linspace(-size / 2, size / 2, cells + 1)] * 3).translated(center)
    return sa.ElasticBody(mesh, sa.NeoHookean(E=E, nu=0.35), density=1000.0, fixed=fixed,
                          velocity=np.asarray(velocity, float))


def run(sim, contact, frames, tol=1e-4, check=None, potential=IPCPotential, bdf2=False):
    """Implicit Euler (or BDF2) steps by full Newton; ``check(x_t, x_{t+1})`` after each step."""
    x, v = sim.state.x.reshape(-1).copy(), sim.state.v.reshape(-1).copy()
    prev = (None, None)
    recs = []
    for _ in range(frames):
        ip = potential(sim, x, v, contact, *prev, tol=tol)
        rec = {}
        x1, rec["newton_converged"] = newton.newton_solve(ip, sim.solver, rec)
        v1 = ip.velocity(x1)
        if check is not None:
            check(x, x1)
        prev = (x, v) if bdf2 else prev
        x, v = x1, v1
        recs.append(rec)
    return x, v, recs


# ---------------------------------------------------------------------------- (a) non-penetration
def test_bodies_driven_fast_into_each_other_and_the_ground_never_intersect():
    """Cubes at 3, 8 and 6 m/s with h = 0.02 (up to 16 cm, a third of a cube, per step) onto each
    other, a plane and a sphere: every line-search trial segment of every Newton iteration is
    collision-free (ipctk's CCD), every state intersection-free."""
    bodies = [cube((0, 0, 0.26), velocity=(0, 0, -3)), cube((0.1, 0.05, 0.9), velocity=(0, 0, -8)),
              cube((1.0, 0.0, 0.6), velocity=(-6, 0, -2))]
    sim = sa.Simulation(bodies, dt=0.02, gravity=(0, 0, -9.81), integrator="implicit_euler")
    colliders = [sa.Plane((0, 0, 0), (0, 0, 1)), sa.Sphere((1.0, 0.0, -0.25), 0.4)]
    contact = ipc.IPCContact(sim, colliders, ipc.IPC(friction=0.3))
    closest = {"surface": np.inf, "collider 0": np.inf, "collider 1": np.inf}
    segments = []
    ccd = ipctk.TightInclusionCCD(1e-6, 10_000)  # an independent check (capped: conservative)

    class Recording(IPCPotential):
        def with_step(self, x, d):
            y = super().with_step(x, d)
            segments.append((x, y))
            return y

    def check(x0, x1):
        starts = [a for a, _ in segments] + [x1]
        for a, b in segments:
            Va, Vb = contact.vertices(a), contact.vertices(b)
            if any(b is s or np.array_equal(b, s) for s in starts):  # a step Newton took
                assert ipctk.is_step_collision_free(contact.mesh, Va, Vb, 0.0, None, ccd)
            assert not ipctk.has_intersections(contact.mesh, Vb)
            assert Vb[:, 2].min() > 0                                          # above the plane
            assert np.linalg.norm(Vb - (1.0, 0.0, -0.25), axis=1).min() > 0.4  # outside the sphere
        segments.clear()
        for k, g in contact.gaps(x1).items():
            closest[k] = min(closest[k], g)

    _, _, recs = run(sim, contact, 25, check=check, potential=Recording)
    assert closest["surface"] < contact.dhat and closest["collider 0"] < contact.dhat  # they did touch
    assert closest["collider 1"] < contact.dhat
    assert sum(r["newton_converged"] for r in recs) >= 23


def test_max_step_stops_before_a_crossing():
    sim = sa.Simulation([cube((0, 0, 0.3)), cube((0, 0, 0.9))], dt=0.01, integrator="implicit_euler")
    contact = ipc.IPCContact(sim, [sa.Plane((0, 0, 0), (0, 0, 1)), sa.Sphere((2, 0, 0), 0.5)])
    x = sim.state.x.reshape(-1).copy()
    dx = np.zeros_like(x).reshape(-1, 3)
    n0 = sim.bodies[0].mesh.p.shape[1]
    dx[n0:, 2] = -0.2                                      # the upper cube 0.1 deep into the lower one
    a = contact.max_step(x, dx.reshape(-1))
    assert 0.9 * 0.45 < a < 0.5                            # time of impact 0.5, rescaled by 0.9
    dx[:] = 0.0
    dx[:n0, 2] = -0.1                                      # the lower cube 0.05 below the plane
    assert contact.max_step(x, dx.reshape(-1)) == pytest.approx(0.9 * 0.5)
    dx[:] = (3.0, 0.0, 0.0)                                # both into the sphere: conservative advancement
    a = contact.max_step(x, dx.reshape(-1))
    V = contact.vertices(x + a * dx.reshape(-1))
    assert np.linalg.norm(V - (2, 0, 0), axis=1).min() > 0.5 and a > 0.1
    assert contact.max_step(x, np.zeros_like(x)) == 1.0


def test_body_and_self_contact_flags():
    """Without body contact the cubes pass through each other; self contact alone keeps a body's own surface."""
    sim = sa.Simulation([cube((0, 0, 0.3)), cube((0, 0, 0.9))], dt=0.01, integrator="implicit_euler")
    x = sim.state.x.reshape(-1).copy()
    n0 = sim.bodies[0].mesh.p.shape[1]
    through = np.zeros((x.size // 3, 3))
    through[n0:, 2] = -0.2                     # the upper cube 0.1 into the lower one
    fold = np.zeros((x.size // 3, 3))
    top = np.flatnonzero(sim.state.x[:n0, 2] > 0.5 - 1e-9)
    fold[top, 2] = -0.6                       # the lower cube's top face through its bottom face
    steps = {}
    for body, own in [(True, True), (False, True), (True, False), (False, False)]:
        c = ipc.IPCContact(sim, [], ipc.IPC(body_contact=body, self_contact=own))
        steps[body, own] = (c.max_step(x, through.reshape(-1)), c.max_step(x, fold.reshape(-1)))
    assert steps[True, True][0] < 0.5 and steps[True, True][1] < 0.9
    assert steps[False, True][0] == 1.0 and steps[False, True][1] < 0.9
    assert steps[True, False][0] < 0.5 and steps[True, False][1] == 1.0
    assert steps[False, False] == (1.0, 1.0)


def test_collider_contact_stays_on_the_elastic_pattern():
    sim = sa.Simulation(cube((0, 0, 0.25), fixed=[0]), dt=0.01, integrator="implicit_euler")
    contact = ipc.IPCContact(sim, [sa.Plane((0, 0, -1e-4), (0, 0, 1))], ipc.IPC(friction=0.5))
    x = sim.state.x.reshape(-1).copy()
    contact.begin_step(x)
    x[sim.system.free] += 1e-4
    data, rest = contact.hessian_parts(x)
    H = contact.hessian(x)
    assert rest is None and H.nnz > 0
    assert abs(sim.system.pattern.matrix(data) - H).max() < 1e-12 * abs(H).max()


# ---------------------------------------------------------------------------- (b) friction
def incline(mu, theta=np.radians(20), frames=40, bdf2=False):
    g = 9.81
    sim = sa.Simulation(cube((0, 0, 0.25), E=1e6), dt=0.01, integrator="implicit_euler",
                        gravity=(g * np.sin(theta), 0, -g * np.cos(theta)))  # the incline is the plane z = 0
    contact = ipc.IPCContact(sim, [sa.Plane((0, 0, -0.5e-3 * sim.size), (0, 0, 1))], ipc.IPC(friction=mu))
    xs = []
    run(sim, contact, frames, tol=1e-5, check=lambda x0, x1: xs.append(x1.reshape(-1, 3)[:, 0].mean()), bdf2=bdf2)
    return np.array(xs), sim, contact


@pytest.mark.parametrize("mu, bdf2", [(0.1, False), (0.25, False), (0.25, True)])
def test_block_on_an_incline_slides_with_g_sin_minus_mu_cos(mu, bdf2):
    """BDF2 too: the friction potential follows the scheme's velocity (x - x_hat) / (c h)."""
    theta, h = np.radians(20), 0.01
    xs, _, _ = incline(mu, theta, bdf2=bdf2)
    acc = np.diff(xs, 2)[10:] / h ** 2           # after the block has settled on the barrier
    expected = 9.81 * (np.sin(theta) - mu * np.cos(theta))
    assert np.mean(acc) == pytest.approx(expected, rel=0.01)  # measured within 0.1 %


def test_block_on_an_incline_sticks_when_mu_exceeds_tan_theta():
    theta = np.radians(20)
    xs, sim, contact = incline(1.2 * np.tan(theta), theta, frames=50)
    creep = xs[-1] - xs[9]
    # the smoothed static friction creeps below epsv; sliding would cover 0.5 g sin(theta) t^2 ~ 0.27 m
    assert abs(creep) < contact.epsv * 0.4
    xs0, _, _ = incline(0.8 * np.tan(theta), theta, frames=50)
    assert xs0[-1] - xs0[9] > 100 * abs(creep)


# ---------------------------------------------------------------------------- (c) start checks
def test_a_touching_or_penetrating_start_is_a_clear_value_error():
    sim = sa.Simulation(cube((0, 0, 0.25)), dt=0.01, integrator="implicit_euler")
    with pytest.raises(ValueError, match="intersection-free start.*collider 0"):
        ipc.IPCContact(sim, [sa.Plane((0, 0, 0), (0, 0, 1))])            # gap exactly 0
    with pytest.raises(ValueError, match="intersection-free start.*collider 1"):
        ipc.IPCContact(sim, [sa.Plane((0, 0, -1), (0, 0, 1)), sa.Sphere((0, 0, 0.05), 0.1)])  # inside
    two = sa.Simulation([cube((0, 0, 0.25)), cube((0, 0, 0.7))], dt=0.01, integrator="implicit_euler", contact=False)
    with pytest.raises(ValueError, match="intersect"):
        ipc.IPCContact(two, [])                                          # overlapping by 5 cm
    touching = sa.Simulation([cube((0, 0, 0.25)), cube((0, 0, 0.75))], dt=0.01, integrator="implicit_euler",
                             contact=False)
    with pytest.raises(ValueError, match="intersection-free start"):
        ipc.IPCContact(touching, [])                                     # faces in contact: gap 0
    ipc.IPCContact(touching, [], ipc.IPC(body_contact=False, self_contact=False))  # no body contact: fine
    apart = sa.Simulation([cube((0, 0, 0.25)), cube((0, 0, 0.76))], dt=0.01, integrator="implicit_euler")
    assert ipc.IPCContact(apart, [sa.Plane((0, 0, -0.01), (0, 0, 1))]).intersection_free(apart.state.x.reshape(-1))


def test_settings_are_validated_by_name():
    for kw, name in [({"dhat": 0.0}, "dhat"), ({"kappa": -1.0}, "kappa"), ({"friction": -0.1}, "friction"),
                     ({"epsv": np.nan}, "epsv"), ({"ccd_rescaling": 1.5}, "ccd_rescaling"),
                     ({"ccd_max_iterations": 0}, "ccd_max_iterations")]:
        with pytest.raises(ValueError, match=name):
            ipc.IPC(**kw)
    for kw, name in [({"self_contact": "yes"}, "self_contact"), ({"friction": "0.3"}, "friction"),
                     ({"ccd_max_iterations": True}, "ccd_max_iterations")]:  # a bool is no number
        with pytest.raises(TypeError, match=name):
            ipc.IPC(**kw)
    sim = sa.Simulation(cube((0, 0, 0.25)), dt=0.01, integrator="implicit_euler")
    with pytest.raises(TypeError, match="sa.IPC"):
        ipc.IPCContact(sim, [], settings={"friction": 0.3})
    with pytest.raises(TypeError, match="query"):
        ipc.IPCContact(sim, [object()])
    c = ipc.IPCContact(sim, [], ipc.IPC(dhat=1e-3, kappa=50.0, friction=0.4, epsv=1e-2))
    assert (c.dhat, c.kappa, c.mu, c.epsv) == (1e-3, 50.0, 0.4, 1e-2)
    with pytest.raises(ValueError, match="dt"):
        ipc.IPCContact(sim.system, [])                      # a bare ElasticSystem needs dt
    with pytest.raises(TypeError, match="ElasticSystem"):
        ipc.IPCContact(object(), [])
    c = ipc.IPCContact(sim.system, [], dt=0.01)
    assert (c.h, c.size) == (0.01, pytest.approx(sim.size))


# ---------------------------------------------------------------------------- (d) derivatives
def test_barrier_and_friction_functions_match_finite_differences():
    d = np.array([1e-4, 3e-4, 6e-4, 9.9e-4])
    e, e1, e2 = ipc.physical_barrier(d, 1e-3, 7.0)
    eps = 1e-9
    ep, ep1, _ = ipc.physical_barrier(d + eps, 1e-3, 7.0)
    em, em1, _ = ipc.physical_barrier(d - eps, 1e-3, 7.0)
    assert np.allclose(e1, (ep - em) / (2 * eps), rtol=1e-5) and np.allclose(e2, (ep1 - em1) / (2 * eps), rtol=1e-4)
    assert np.all(e > 0) and np.all(e1 < 0)
    # the same function as ipctk's physical barrier
    assert e[1] == pytest.approx(7.0 * ipctk.barrier(d[1] ** 2, 1e-6) / 1e-9, rel=1e-12)
    y = np.array([0.0, 0.2, 0.7, 1.0, 3.0])
    f0, f1y, f2 = ipc.smooth_friction(y, 1.0)
    f0p, f1yp, _ = ipc.smooth_friction(y + 1e-7, 1.0)
    assert np.allclose((f0p - f0)[1:] / 1e-7, (f1y * y)[1:], atol=1e-6)
    assert np.allclose((f1yp * (y + 1e-7) - f1y * y)[1:3] / 1e-7, f2[1:3], atol=1e-6)
    assert f0[0] == pytest.approx(1 / 3) and f1y[-1] == pytest.approx(1 / 3) and f2[-1] == 0


@pytest.mark.parametrize("with_sphere", [False, True])
def test_contact_gradient_and_hessian_match_finite_differences(with_sphere):
    """Body-body, plane (and sphere) contact, friction lagged and sliding, fixed vertices dropped.

    The Hessian is exact for planes; on a sphere it drops the collider-curvature term
    kappa b'(d) grad^2 d (as barrier.py does), a relative 3e-5 here.
    """
    lower, upper = cube((0, 0, 0.25), fixed=[0, 1, 2]), cube((0.13, 0.07, 0.7505))
    sim = sa.Simulation([lower, upper], dt=0.01, integrator="implicit_euler")
    colliders = [sa.Plane((0, 0, -1e-3), (0, 0, 1)), sa.Sphere((0, -0.5 - 0.25 - 1.2e-3, 0.25), 0.5)]
    colliders = colliders if with_sphere else colliders[:1]
    contact = ipc.IPCContact(sim, colliders, ipc.IPC(dhat=2e-3, friction=0.5, epsv=0.05))
    x0 = sim.state.x.reshape(-1).copy()
    contact.begin_step(x0)
    assert len(contact.lagged[2]) > 0 and all(len(a) for a, _, _ in contact.lagged[3])  # every kind is active
    rng = np.random.default_rng(1)
    free = sim.system.free
    x = x0.copy()
    x[free] += 1e-5 * rng.normal(size=free.size)                    # a little sliding in every direction
    x.reshape(-1, 3)[sim.system.vertex_offsets[1]:, 0] += 2e-3      # the upper cube slides fast (> epsv h)
    g, H = contact.gradient(x), contact.hessian(x, project=False)
    assert g.shape == (free.size,) and H.shape == (free.size, free.size)
    p = rng.normal(size=free.size)
    p /= np.abs(p).max()
    eps = 1e-8
    xp, xm = x.copy(), x.copy()
    xp[free] += eps * p
    xm[free] -= eps * p
    assert (contact.energy(xp) - contact.energy(xm)) / (2 * eps) == pytest.approx(g @ p, rel=1e-6)
    Hp = H @ p
    fd = (contact.gradient(xp) - contact.gradient(xm)) / (2 * eps)
    assert np.linalg.norm(fd - Hp) < (1e-4 if with_sphere else 1e-6) * np.linalg.norm(Hp)
    # split on the elastic pattern and off it: the same matrix; body contact leaves the pattern
    data, rest = contact.hessian_parts(x, project=False)
    assert rest is not None and abs(sim.system.pattern.matrix(data) + rest - H).max() < 1e-9 * abs(H).max()
    # the projected Hessian is symmetric PSD
    Hpsd = contact.hessian(x).toarray()
    assert np.allclose(Hpsd, Hpsd.T) and np.linalg.eigvalsh(Hpsd).min() > -1e-8 * np.abs(Hpsd).max()
    # vertex energies (the subspace oracle's contact shares) sum to the contact energy, with the
    # lagged friction (body-body, plane, sphere) and without it; fixed vertices get theirs too
    assert contact.vertex_energy(x).sum() == pytest.approx(contact.energy(x), rel=1e-10)
    contact.lagged = None
    assert contact.vertex_energy(x).sum() == pytest.approx(contact.energy(x), rel=1e-10)


@pytest.mark.parametrize("reducer", [None, "subspace"])
def test_simulation_runs_ipc_contact_between_bodies_and_with_the_ground(reducer):
    """``Simulation(..., integrator="implicit_euler", contact=sa.IPC(...))``: a cube dropped on another
    resting on a plane; no surface ever intersects, in full space and under the subspace reducer."""
    def cube(z, v):
        mesh = sa.scenes.box_mesh((0.2, 0.2, 0.2), (2, 2, 2), center=(0.0, 0.0, z))
        return sa.ElasticBody(mesh, sa.NeoHookean(E=1e5, nu=0.3), density=1000.0, velocity=(0.0, 0.0, v))
    red = None if reducer is None else sa.AdaptiveSubspace(never_slower=False)  # every step by the reducer
    sim = sa.Simulation([cube(0.3, -3.0), cube(0.0, 0.0)], dt=0.01, gravity=(0, 0, -9.81),
                        integrator="implicit_euler", colliders=[sa.Plane((0, 0, -0.15), (0, 0, 1))],
                        contact=sa.IPC(friction=0.3), reducer=red)
    assert sim.contact_model == "ipc"
    contact = sim.integrator.barrier
    lowest_gap = np.inf
    for state in sim.run(15):
        assert contact.intersection_free(state.x.reshape(-1))
        top, bottom = sim.split(state.x)
        lowest_gap = min(lowest_gap, top[:, 2].min() - bottom[:, 2].max())
        assert state.x[:, 2].min() > -0.15
    assert all(r["contact_model"] == "ipc" for r in sim.stats)
    assert lowest_gap < 0.05  # the falling cube reached the other one (0.1 m apart at the start)


def test_simulation_refuses_pgs_under_newton_and_ipc_under_linearized():
    body = sa.scenes.cantilever(resolution=1).bodies[0]
    with pytest.raises(ValueError, match="IPC"):
        sa.Simulation(body, integrator="implicit_euler", contact=sa.PGS())
    with pytest.raises((ValueError, TypeError), match="PGS"):
        sa.Simulation(body, colliders=[sa.Plane((0, 0, -1), (0, 0, 1))], contact=sa.IPC())


@pytest.mark.parametrize("gap", [2e-4, 1e-3])
def test_sliding_from_a_start_inside_dhat_decelerates_by_coulomb(gap):
    """A box started inside the barrier's range (dhat = 8.7e-4 m) is pushed by many times its
    weight at x_t; friction lagged at that force stopped it far too soon. Its normal force is taken
    from the step's solution (lagged iterations): v = v0 - mu g t, x = v0 t - mu g t^2 / 2."""
    mu, v0, g, h, n = 0.5, 2.0, 9.81, 0.01, 8
    mesh = skfem.MeshTet.init_tensor(*[np.linspace(-0.25, 0.25, 2)] * 2, np.linspace(gap, 0.5 + gap, 2))
    body = sa.ElasticBody(mesh, sa.NeoHookean(E=1e6, nu=0.3), velocity=(v0, 0, 0))
    sim = sa.Simulation(body, dt=h, gravity=(0, 0, -g), integrator="implicit_euler", colliders=[sa.Plane()],
                        contact=sa.IPC(friction=mu))
    for s in sim.run(n):
        pass
    t = n * h
    assert s.v[:, 0].mean() == pytest.approx(v0 - mu * g * t, rel=0.02)
    assert s.x[:, 0].mean() == pytest.approx(v0 * t - 0.5 * mu * g * t * t, rel=0.03)


# ---------------------------------------------------------------------------- reproducibility
@pytest.fixture
def ipctk_on_two_threads():
    """ipctk's own default on a multi-core machine: its loops on several threads."""
    before = ipctk.get_num_threads()
    ipctk.set_num_threads(2)
    yield
    ipctk.set_num_threads(before)


def test_contact_sums_are_bit_identical_on_repeated_calls(ipctk_on_two_threads):
    """ipctk's parallel loops sum in the order its threads finish; the contact model runs them on
    the package's thread count (skfem_affine.threads.ipctk_threads), so the same state gives the
    same gradient and Hessian to the last bit, whatever ipctk's count outside."""
    sim = sa.scenes.stacked_beams(resolution=1, n=3, gap=5e-4, integrator="implicit_euler",
                                  contact=sa.IPC(friction=0.5))
    contact = sim.integrator.barrier
    x = sim.state.x.reshape(-1) + 1e-5 * np.random.default_rng(0).standard_normal(3 * sim.system.n)
    contact.begin_step(x)
    assert len(contact._collisions(x)) > 50

    def fresh(f):
        contact._cache = (None, None)  # the collisions built again
        return f(x)

    g, H, e = fresh(contact.gradient), fresh(contact.hessian).toarray(), fresh(contact.energy)
    for _ in range(30):
        assert np.array_equal(fresh(contact.gradient), g)
        assert np.array_equal(fresh(contact.hessian).toarray(), H)
        assert fresh(contact.energy) == e
    assert ipctk.get_num_threads() == 2  # the caller's count is left as it was


@pytest.mark.parametrize("integrator", ["implicit_euler", "bdf2"])
def test_two_runs_with_ipc_friction_between_bodies_are_bit_identical(ipctk_on_two_threads, integrator):
    def run():
        sim = sa.scenes.stacked_beams(resolution=1, n=3, gap=5e-3, integrator=integrator,
                                      contact=sa.IPC(friction=0.5))
        return np.array([s.x for s in sim.run(7)])
    a, b = run(), run()
    assert np.array_equal(a, b)


# ---------------------------------------------------------------------------- units
def falling_blocks(scale_m, scale_kg, contact, gravity):
    """Two blocks (0.2 m and 0.3 m, E 1e5 Pa, 1000 kg/m^3) falling onto a plane and onto each
    other, in the unit system of length ``scale_m`` (m) and mass ``scale_kg`` (kg) per unit
    (SI: 1, 1; mm-tonne-s: 1e-3, 1e3, so that E is in MPa, density in t/mm^3, g 9810 mm/s^2).
    Without gravity they are thrown down (contact=False: the lower block alone, with the
    colliders' barrier)."""
    L, E_unit = 1.0 / scale_m, scale_m / scale_kg  # lengths in units; Pa = kg / (m s^2) in units
    def block(size, z, vz, off=0.0):
        mesh = sa.scenes.box_mesh((size * L,) * 3, (2, 2, 2), center=(off * L, 0.5 * off * L, z * L))
        return sa.ElasticBody(mesh, sa.NeoHookean(E=1e5 * E_unit, nu=0.3), density=1000.0 * scale_m ** 3 / scale_kg,
                              velocity=(0.0, 0.0, vz * L))
    g = (0.0, 0.0, -9.81 * L if gravity else 0.0)
    bodies = [block(0.3, 0.152, 0.0 if gravity else -0.5), block(0.2, 0.42, 0.0 if gravity else -1.0, off=0.03)]
    sim = sa.Simulation(bodies if contact is not False else bodies[:1], dt=0.01, gravity=g,
                        integrator="implicit_euler", colliders=[sa.Plane()], contact=contact)
    return sim, np.array([s.x for s in sim.run(12)]) * scale_m


@pytest.mark.parametrize("gravity", [True, False])
@pytest.mark.parametrize("contact", [None, False], ids=["ipc", "barrier"])
def test_the_same_scene_in_si_and_mm_tonne_s_moves_the_same(contact, gravity):
    """The default barrier stiffness comes from the scene's own scales (its gravity, or mass, dt and
    dhat without gravity): in mm-tonne-s the trajectories are the SI ones to round-off. ``contact=None``
    with two bodies is ipctk's IPC; ``contact=False`` with one body the colliders' barrier."""
    si, x_m = falling_blocks(1.0, 1.0, contact, gravity)
    mm, x_mm = falling_blocks(1e-3, 1e3, contact, gravity)
    assert si.contact_model == mm.contact_model == ("ipc" if contact is None else "ipc-barrier")
    assert x_m[:, :, 2].min() < 0.152 - 0.15 + 2 * si.integrator.barrier.dhat  # it reached the plane
    assert np.abs(x_mm - x_m).max() < 1e-8 * si.size


# ---------------------------------------------------------------------------- accepted states
def thrown_boxes(offset=0.0):
    """Two 0.3 m boxes thrown at each other at 8 and 15 m/s (0.46 m closer per step of 0.02 s,
    0.4 m apart), the lower one over a plane, the upper one ``offset`` aside: IPC between them by
    default."""
    def box(z, vz, off):
        mesh = sa.scenes.box_mesh((0.3, 0.3, 0.3), (2, 2, 2), center=(off, 0.5 * off, z))
        return sa.ElasticBody(mesh, sa.NeoHookean(E=1e5, nu=0.3), density=1000.0, velocity=(0.0, 0.0, vz))
    return sa.Simulation([box(0.3, 8.0, 0.0), box(1.0, -15.0, offset)], dt=0.02, gravity=(0, 0, -9.81),
                         integrator="implicit_euler", colliders=[sa.Plane()])


def inside_tets(points, X, t):
    """Mask (k,) of the points (k, 3) strictly inside a tetrahedron of the mesh (X (n, 3), t (4, m))."""
    A = np.stack([X[t[i]] - X[t[0]] for i in (1, 2, 3)], axis=2)                  # (m, 3, 3)
    lam = np.einsum("mij,kmj->kmi", np.linalg.inv(A), points[:, None, :] - X[t[0]][None])
    bary = np.concatenate([1.0 - lam.sum(axis=2, keepdims=True), lam], axis=2)   # (k, m, 4)
    return (bary > 1e-9).all(axis=2).any(axis=1)


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore:Newton stopped")  # 50 iterations at frame 2
def test_thrown_boxes_keep_apart():
    """Every accepted state is intersection-free (ipctk's exact test, and no vertex inside the other
    box); the frictionless, tilting contact sends the boxes sliding off each other sideways."""
    sim = thrown_boxes()
    contact, n0 = sim.integrator.barrier, sim.bodies[0].mesh.p.shape[1]
    assert sim.contact_model == "ipc"
    for s in sim.run(2):
        assert contact.intersection_free(s.x.reshape(-1))
        for a, b in [(s.x[:n0], s.x[n0:]), (s.x[n0:], s.x[:n0])]:
            assert not np.any(inside_tets(b, a, sim.bodies[0].mesh.t))
        assert sim.stats[-1]["max_penetration"] == sim.max_penetration() == 0.0
    assert contact.gaps(s.x.reshape(-1))["surface"] < contact.dhat  # they touched
    apart = s.x[:n0, :2].mean(axis=0) - s.x[n0:, :2].mean(axis=0)
    assert np.linalg.norm(apart) > 0.1  # sliding off each other sideways


def test_a_step_that_ends_intersecting_is_refused_naming_the_frame():
    """Without the line search's CCD bound, Newton steps the thrown boxes into each other: the step
    is refused (never accepted with a warning), the simulation stays at the frame before."""
    sim = thrown_boxes(offset=0.05)  # (aligned edges would meet at distance zero: an infinite barrier)
    contact = sim.integrator.barrier
    contact.max_step = lambda x, dx: 1.0  # the CCD bound switched off
    with pytest.raises(sa.SimulationDiverged, match="intersects.* at frame 1"):
        sim.step()
    assert sim.state.frame == 0 and len(sim.stats) == 0


def test_max_penetration_measures_bodies_under_a_newton_integrator():
    sim = thrown_boxes()
    x = sim.state.x.copy()
    n0 = sim.bodies[0].mesh.p.shape[1]
    x[n0:, 2] -= 0.4 + 0.05        # the upper box 5 cm into the lower one
    assert sim.max_penetration(x) >= 0.05 - 1e-12
