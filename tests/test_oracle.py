"""The one-iteration PCG oracle (eq. 13-14)."""
import numpy as np
import pytest

import skfem_affine as sa
from skfem_affine import oracle


@pytest.fixture(scope="module")
def bent():
    sim = sa.scenes.cantilever(resolution=3, damping=sa.Rayleigh(0.1, 0.01))
    for s in sim.run(10):
        pass
    A, b, data = sim.linear_system(s.x, s.v)
    return sim, A, b, data


def test_matrix_free_stiffness_equals_assembled(bent):
    sim, A, b, data = bent
    Hp = oracle.stiffness_operator(sim.system, data.C)
    p = np.random.default_rng(0).normal(size=b.size)
    ref = data.Hmat @ p
    assert np.linalg.norm(Hp(p) - ref) <= 1e-10 * np.linalg.norm(ref)


@pytest.mark.parametrize("kind", ["ichol", "amg"])
def test_prediction_reduces_the_residual(bent, kind):
    sim, A, b, data = bent
    P = oracle.Preconditioner(sim.system, sim.dt, sim.damping, kind=kind)
    dv = oracle.predict(lambda p: A @ p, b, P)
    assert np.linalg.norm(A @ dv - b) < 0.1 * np.linalg.norm(b)
    r = np.random.default_rng(1).normal(size=b.size)
    assert r @ P.apply(r) > 0


def test_exact_preconditioner_gives_the_solution_in_one_iteration(bent):
    sim, A, b, data = bent
    import scipy.sparse.linalg as spla
    lu = spla.splu(A.tocsc())

    class Exact:
        def apply(self, r):
            return lu.solve(r)

    dv = oracle.predict(lambda p: A @ p, b, Exact())
    assert np.linalg.norm(A @ dv - b) <= 1e-10 * np.linalg.norm(b)


def test_gravity_is_split_out(bent):
    sim, A, b, data = bent
    P = oracle.Preconditioner(sim.system, sim.dt, kind="ichol")
    g = np.full(b.size, -0.1)
    assert np.allclose(oracle.predict(lambda p: A @ p, np.zeros_like(b), P, gravity_dv=g), g)


def test_bad_kind():
    sim = sa.scenes.cantilever(resolution=1)
    with pytest.raises(ValueError, match="kind"):
        oracle.Preconditioner(sim.system, 0.01, kind="jacobi")
