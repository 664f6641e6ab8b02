"""The oracle of a body on its support: the bodies' mean response first (a two-level guess), then
one PCG step, so that a body whose support balances its weight is predicted at rest."""
import numpy as np
import scipy.sparse.linalg as spla

import skfem_affine as sa
from skfem_affine.integrators.problem import StepProblem
from skfem_affine.lab.scenes import box_mesh
from skfem_affine.reducers.affine import oracle


def _two_boxes():
    """Two free, stiff boxes (the stiffness outweighs the mass in A, as in the paper's pills)."""
    mat = sa.NeoHookean(E=1e6, nu=0.3)
    bodies = [sa.ElasticBody(box_mesh(0.2, 2, (0.0, 0.0, 0.1)), mat, density=100.0),
              sa.ElasticBody(box_mesh(0.12, 2, (0.02, 0.01, 0.26)), mat, density=100.0)]
    return sa.Simulation(bodies, dt=0.01, gravity=(0.0, 0.0, -9.81), damping=sa.Rayleigh(0.03, 0.02))


def _support_rhs(sim, rng):
    """b_ng of a body resting on its support: the weight's impulse upwards (support and elastic
    forces together) plus a self-balanced local part, per body and axis of zero sum, 30 times larger."""
    sysm = sim.system
    up = -sim.dt * sim.model.f_gravity[sysm.free]
    T = oracle.body_translations(sysm)
    local = rng.standard_normal(sysm.free.size)
    local -= T @ ((T.T @ local) / np.asarray(T.sum(axis=0)).ravel())  # zero sum per body and axis
    return up + local * 30 * np.linalg.norm(up) / np.linalg.norm(local), T


def test_body_translations_are_one_column_per_body_and_axis():
    sim = _two_boxes()
    T = oracle.body_translations(sim.system)
    n0 = sim.bodies[0].mesh.p.shape[1]
    assert T.shape == (3 * sim.system.n, 6)
    assert np.array_equal(np.asarray(T.sum(axis=0)).ravel(), [n0] * 3 + [sim.system.n - n0] * 3)
    assert np.array_equal(T[3 * n0 + 1].toarray().ravel(), [0, 0, 0, 0, 1, 0])


def test_a_supported_body_is_predicted_at_rest():
    sim = _two_boxes()
    sysm = sim.system
    problem = StepProblem.at(sim.model, sim.state.x, sim.state.v)
    A, H = problem.matrix(), problem.Hmat
    mdiag = sysm.Mff.diagonal()
    apply_A = oracle.system_operator(mdiag, H, sim.model.coefficients)
    precond = oracle.Preconditioner(sysm, sim.dt, sim.damping)
    b, T = _support_rhs(sim, np.random.default_rng(0))
    gravity_dv = np.tile(sim.model.gravity, sysm.n)[sysm.free] * sim.dt
    exact = spla.spsolve(A.tocsc(), b) + gravity_dv
    mass = np.asarray(T.T @ mdiag)

    def mean_speed(dv):  # the largest body-mean velocity change (m/s); the weight's step is 0.098
        return np.abs((T.T @ (mdiag * dv)) / mass).max()

    # in closed form the bodies' means balance: H has no translation, A T = c_M M T, so their mean
    # change is (1 / c_M - 1) h g: damping's share of one step of gravity
    cm = sim.model.coefficients[0]
    assert np.isclose(mean_speed(exact), (1 - 1 / cm) * 9.81 * sim.dt, rtol=1e-6)
    x0 = oracle.coarse_guess(T, mdiag, H, sim.model.coefficients, b)
    stats = {}
    guided = oracle.predict(apply_A, b, precond, gravity_dv=gravity_dv, stats=stats, x0=x0)
    assert mean_speed(guided - exact) < 1e-3 * 9.81 * sim.dt
    # a single step from zero scales the translation with the local part's alpha: it keeps most of gravity
    plain = oracle.predict(apply_A, b, precond, gravity_dv=gravity_dv)
    assert mean_speed(plain - exact) > 0.5 * 9.81 * sim.dt
    # and the guided step is closer to the exact velocity change in the energy norm A
    err = lambda dv: float((dv - exact) @ (A @ (dv - exact)))
    assert err(guided) < err(plain)
    assert 0.0 <= stats["oracle_residual"] < 1.0


def _resting_stack(reducer):
    """The stack of tests/test_resting_contact.py: a box on the ground, a smaller one on it."""
    mat = sa.NeoHookean(E=1e6, nu=0.3)
    bodies = [sa.ElasticBody(box_mesh(0.2, 2, (0.0, 0.0, 0.1)), mat, density=1000.0),
              sa.ElasticBody(box_mesh(0.12, 2, (0.02, 0.01, 0.26)), mat, density=1000.0)]
    return sa.Simulation(bodies, dt=0.01, gravity=(0.0, 0.0, -9.81), colliders=[sa.Plane()], reducer=reducer)


def test_the_reducer_predicts_a_resting_stack_at_rest(monkeypatch):
    predicted = []
    plain_predict = oracle.predict

    def recording(*args, **kwargs):
        dv = plain_predict(*args, **kwargs)
        predicted.append((kwargs.get("x0") is not None, np.abs(dv).max()))
        return dv
    monkeypatch.setattr(oracle, "predict", recording)
    for budget in (False, True):
        predicted.clear()
        sim = _resting_stack(sa.Affinification(never_slower=False) if budget else sa.Affinification(1e-5, 1e-4))
        for _ in range(60):
            sim.step()
        guided, speed = predicted[-1]  # the last frame's oracle (the budget's own estimate comes later)
        if budget:  # under an error budget the paper's oracle: most of gravity's step (0.098 m/s)
            assert not any(g for g, _ in predicted)
        else:  # at rest (|v| < 1e-6 m/s) the support balances the weight: predicted at rest
            assert guided and np.abs(sim.state.v).max() < 1e-6
            assert speed < 1e-3 * 9.81 * sim.dt
