"""One frame as data: system_coefficients (eq. 1), StepProblem (eq. 1-2), Operator, StepResult."""
import numpy as np
import pytest
import scipy.sparse as sp

import skfem_affine as sa
from skfem_affine.integrators.problem import (Model, Operator, StepProblem, StepResult, merge_stats,
                                              system_coefficients)


def test_system_coefficients_are_eq_1():
    h, d = 0.02, sa.Rayleigh(alpha=0.3, beta=0.05)
    assert system_coefficients(h, d) == (1 + h * 0.3, h * 0.05 + h * h)
    assert system_coefficients(h, None) == (1.0, h * h)


def test_step_problem_is_the_linearized_backward_euler_step():
    sim = sa.scenes.cantilever(resolution=2, damping=sa.Rayleigh(0.1, 0.01))
    for s in sim.run(3):
        pass
    model = sim.model
    assert isinstance(model, Model) and model.coefficients == system_coefficients(sim.dt, sim.damping)
    p = StepProblem.at(model, s.x, s.v, frame=s.frame + 1)
    sysm, h, (cm, ck) = sim.system, sim.dt, model.coefficients
    M, H = sysm.Mff, p.Hmat
    assert abs(p.matrix() - (cm * M + ck * H)).max() <= 1e-12 * abs(p.matrix()).max()
    # b = h (f + D v + h K v) with D = -(alpha M + beta H), K = -H (eq. 2)
    vf = s.v.reshape(-1)[sysm.free]
    f = (sysm.forces_and_stiffness(s.x, tangent=False)[0] + sim.f_gravity)[sysm.free]
    b = h * (f - (0.1 * M + 0.01 * H) @ vf - h * H @ vf)
    assert np.allclose(p.b, b, rtol=1e-12, atol=1e-12 * np.abs(b).max())
    assert p.b is p.b  # computed once
    A, b2, _ = sim.linear_system(s.x, s.v)  # the simulation's public helper builds the same problem
    assert (A != p.matrix()).nnz == 0 and np.array_equal(b2, p.b)


def test_operator_gives_the_whole_matrix_of_an_upper_triangle():
    A = sp.random(6, 6, density=0.5, random_state=0) + 6 * sp.identity(6)
    A = (A + A.T).tocsr()
    op = Operator(sa.solvers.SuperLU(), sp.triu(A, format="csr"), upper=True)
    assert abs(op.matrix - A).max() == 0 and op.G is None and not op.iterative
    assert Operator(sa.solvers.AMGCG(), A).iterative


def test_step_result_positions_and_stats():
    x, v = np.zeros((4, 3)), np.ones((4, 3))
    assert np.array_equal(StepResult(dv=np.zeros(3)).positions(x, v, 0.1), x + 0.1 * v)
    rec = {"assembly": 1.0, "solver": "a"}
    merge_stats(rec, {"assembly": 0.5, "solver": "b", "dofs": 3})
    assert rec == {"assembly": 1.5, "solver": "b", "dofs": 3}
