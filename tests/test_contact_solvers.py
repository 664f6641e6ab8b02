"""The contact iterations of PGS(solver=...): Anderson-accelerated and plain Gauss-Seidel sweeps."""
import numpy as np
import pytest

import skfem_affine as sa
from skfem_affine.contact import pgs
from skfem_affine.lab.scenes import box_mesh

MU = 0.4


def _coupled(seed, k=6):
    """A random well-conditioned coupled problem (every contact pushed in some direction)."""
    rng = np.random.default_rng(seed)
    B = rng.normal(size=(3 * k, 3 * k))
    return B @ B.T + 3 * k * np.eye(3 * k), rng.normal(size=3 * k)


def _rigid(seed, k=24, compliance=1e-3):
    """Many contacts of one nearly rigid body on the ground: W = B B^T + c I with B (3k x 6) the
    contacts' rows of the rigid motions over the body's mass, a stack's redundant contacts."""
    rng = np.random.default_rng(seed)
    p = rng.uniform(-0.1, 0.1, size=(k, 3))
    p[:, 2] = 0.0
    rows = []
    for x in p:  # frames n = z, t1 = x, t2 = y; v = c + omega x (x - centre)
        r = x - np.array([0.0, 0.0, 0.1])
        cross = np.array([[0, r[2], -r[1]], [-r[2], 0, r[0]], [r[1], -r[0], 0]])
        rows.append(np.hstack([np.eye(3), cross])[[2, 0, 1]])
    B = np.vstack(rows) / np.sqrt([1.0, 1.0, 1.0, 1e-3, 1e-3, 1e-3])  # mass 1, inertia 1e-3
    u0 = np.tile([-0.1, 0.02, -0.01], k) + 1e-3 * rng.normal(size=3 * k)
    return B @ B.T + compliance * np.eye(3 * k), u0


def _solve(solver, W, u0, tolerance=1e-12, cap=20000):
    lam = np.zeros_like(u0)
    sweeps = pgs.SOLVERS[solver](W, u0, lam, MU, cap, tolerance)
    return lam, sweeps


@pytest.mark.slow
@pytest.mark.parametrize("problem", [_coupled(3), _coupled(4), _rigid(5), _rigid(6)])
def test_anderson_reaches_the_gauss_seidel_solution(problem):
    W, u0 = problem
    ref, _ = _solve("gauss-seidel", W, u0)
    lam, sweeps = _solve("anderson", W, u0)
    assert sweeps < 20000
    assert np.abs(lam - ref).max() <= 1e-6 * np.abs(ref).max()
    assert np.abs(W @ (lam - ref)).max() <= 1e-9 * np.abs(u0).max()


def assert_complementary_and_in_the_cone(W, u0, lam, mu=MU, scale=None):
    """lam solves the contact problem (W, u0): complementary normals, impulses in the friction cone,
    no slip while sticking, sliding against the slip, and a residual of round-off (of ``scale``,
    default :func:`~skfem_affine.contact.pgs.velocity_scale` of u0)."""
    u = u0 + W @ lam
    ln, un = lam[0::3], u[0::3]
    lt, ut = lam.reshape(-1, 3)[:, 1:], u.reshape(-1, 3)[:, 1:]
    scale = pgs.velocity_scale(u0) if scale is None else scale
    assert np.all(ln >= 0) and np.all(un >= -1e-10 * scale)
    assert np.abs(np.minimum(un, np.diag(W)[0::3] * ln)).max() <= 1e-10 * scale
    assert np.all(np.linalg.norm(lt, axis=1) <= mu * ln * (1 + 1e-12))
    inside = np.linalg.norm(lt, axis=1) < mu * ln * (1 - 1e-6)
    assert np.abs(ut[inside]).max(initial=0.0) <= 1e-9 * scale    # sticking: no slip
    sliding = (ln > 1e-12 * ln.max()) & ~inside & (np.linalg.norm(ut, axis=1) > 1e-9 * scale)
    cosine = -np.einsum("ij,ij->i", lt[sliding], ut[sliding]) / (
        np.linalg.norm(lt[sliding], axis=1) * np.linalg.norm(ut[sliding], axis=1))
    assert np.allclose(cosine, 1.0, atol=1e-6)                   # sliding: against the slip
    assert max(pgs.contact_residual(W, u0, lam, mu)) <= 1e-11 * scale   # recomputed, not the solver's own u


@pytest.mark.parametrize("problem", [_coupled(3), _rigid(5)])
def test_anderson_solution_is_complementary_and_in_the_cone(problem):
    W, u0 = problem
    lam, _ = _solve("anderson", W, u0)
    assert_complementary_and_in_the_cone(W, u0, lam)


def test_anderson_takes_fewer_sweeps_on_a_soft_body():
    # a body whose contacts' own compliance is a tenth of its rigid motion's: measured 5-9 times
    # fewer sweeps to 1e-8 (on a nearly rigid body, compliance 1e-3, both take about as many)
    for seed in (5, 6, 7):
        W, u0 = _rigid(seed, compliance=0.1)
        _, plain = _solve("gauss-seidel", W, u0, 1e-8)
        _, mixed = _solve("anderson", W, u0, 1e-8)
        assert mixed < plain / 3, (seed, mixed, plain)


def test_anderson_keeps_the_stopping_rule():
    W = np.diag([2.0, 4.0, 4.0])
    lam = np.zeros(3)
    sweeps = pgs.anderson_gauss_seidel(W, np.array([-1.0, -3.0, 3.0]), lam, 0.5, 50, 1e-12)
    assert lam[0] == pytest.approx(0.5) and sweeps <= 3
    assert np.allclose(lam[1:], 0.25 * np.array([1, -1]) / np.sqrt(2))
    lam = np.zeros(3)
    pgs.anderson_gauss_seidel(W, np.array([1.0, -3.0, 3.0]), lam, 0.5, 50, 1e-12)
    assert np.all(lam == 0)   # separating: no impulse
    W, u0 = _rigid(5)
    scale = pgs.velocity_scale(u0)
    for tol in (1e-3, 1e-8):
        lam = np.zeros_like(u0)
        sweeps = pgs.anderson_gauss_seidel(W, u0, lam, MU, 5000, tol)
        assert sweeps < 5000 and max(pgs.contact_residual(W, u0, lam, MU)) <= tol * scale
    lam = np.zeros_like(u0)
    assert pgs.anderson_gauss_seidel(W, u0, lam, MU, 7, 0.0) == 7   # the cap


def test_solver_setting_is_checked():
    assert sa.PGS().solver == "block" and sa.PGS(solver="anderson").solver == "anderson"
    for bad in ("newton", 3, None):
        with pytest.raises(ValueError, match="solver"):
            sa.PGS(solver=bad)


def _stack(solver):
    mat = sa.NeoHookean(E=1e6, nu=0.3)
    bodies = [sa.ElasticBody(box_mesh(0.2, 2, (0.0, 0.0, 0.1)), mat, density=1000.0),
              sa.ElasticBody(box_mesh(0.12, 2, (0.02, 0.01, 0.26)), mat, density=1000.0)]
    return sa.Simulation(bodies, dt=0.01, gravity=(0.0, 0.0, -9.81), colliders=[sa.Plane()],
                         contact=sa.PGS(solver=solver))


def _centres(sim):
    x, n = sim.state.x, sim.bodies[0].mesh.p.shape[1]
    return np.array([x[:n].mean(axis=0), x[n:].mean(axis=0)])


def test_a_resting_stack_stays_at_rest():
    sim = _stack("anderson")
    for _ in range(30):
        sim.step()
    settled = _centres(sim)
    for _ in range(20):
        sim.step()
    assert all(r["pgs_converged"] for r in sim.stats[30:])
    assert np.abs(_centres(sim) - settled).max() < 1e-6   # no sinking or drifting (measured 1.4e-8)
    assert sim.state.x[:, 2].min() > -1e-6
