"""The prediction oracle (sec. 3.4, eq. 13-14): matrix-free H p, the A_p preconditioners, one PCG step."""
import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

import skfem_affine as sa
from skfem_affine.reducers.affine import ichol, oracle


@pytest.fixture(scope="module")
def bent():
    """A damped cantilever (k = 3) bent by 10 frames under gravity, and its system A, b."""
    sim = sa.scenes.cantilever(resolution=3, damping=sa.Rayleigh(0.03, 0.02), E=1e5)
    for _ in sim.run(10):
        pass
    A, b, data = sim.linear_system(sim.state.x, sim.state.v)
    return sim, A, b, data


@pytest.fixture(scope="module")
def preconditioners(bent):
    sim = bent[0]
    return {kind: oracle.Preconditioner(sim.system, sim.dt, sim.damping, kind=kind) for kind in oracle.KINDS}


def test_matrix_free_product_equals_assembled_stiffness(bent):
    sim = bent[0]
    sysm = sim.system
    x = sim.state.x
    _, H = sysm.forces_and_stiffness(x, project=False)
    _, C = sysm.stresses(sysm.deformation_gradients(x), project=False)
    p = np.random.default_rng(0).standard_normal(sysm.free.size)
    ref = sysm.pattern.matrix(H) @ p
    for Ce in (C, C.reshape(-1, 9, 9)):
        Hp = oracle.stiffness_operator(sysm, Ce)(p)
        assert np.linalg.norm(Hp - ref) <= 1e-10 * np.linalg.norm(ref)


def test_preconditioner_matrix_is_eq14(bent, preconditioners):
    """A_p = (1 + h alpha) M + (h^2 + h beta) B^T W B with W = V mu I_9 (on the free DOFs)."""
    sim = bent[0]
    sysm, h, d = sim.system, sim.dt, sim.damping
    B = sysm.deformation_operator()[:, sysm.free]
    mu, _ = oracle.element_moduli(sysm)
    W = sp.diags(np.repeat(sysm.volumes * mu, 9))
    ref = (1 + h * d.alpha) * sysm.Mff + (h * h + h * d.beta) * (B.T @ W @ B)
    Ap = preconditioners["ichol"].matrix
    assert abs(Ap - ref).max() <= 1e-12 * abs(ref).max()


@pytest.mark.parametrize("kind", oracle.KINDS)
def test_preconditioner_is_spd_and_close_to_exact(bent, preconditioners, kind):
    P = preconditioners[kind]
    rng = np.random.default_rng(1)
    R = rng.standard_normal((P.shape[0], 20))
    Z = np.column_stack([P.apply(r) for r in R.T])
    assert np.all(np.einsum("ij,ij->j", Z, R) > 0)
    assert np.allclose(R.T @ Z, Z.T @ R, rtol=1e-6, atol=1e-12 * np.abs(R.T @ Z).max())  # symmetric
    exact = spla.splu(P.matrix.tocsc()).solve(R)
    assert np.linalg.norm(Z - exact) <= 0.05 * np.linalg.norm(exact)


def test_unknown_kind_raises(bent):
    sim = bent[0]
    with pytest.raises(ValueError, match="kind"):
        oracle.Preconditioner(sim.system, sim.dt, kind="jacobi")


@pytest.mark.parametrize("kind", oracle.KINDS)
@pytest.mark.parametrize("split_gravity", [False, True])
def test_one_iteration_reduces_the_residual(bent, preconditioners, kind, split_gravity):
    sim, A, b, data = bent
    sysm = sim.system
    if split_gravity:
        b = b - sim.dt * sim.f_gravity[sysm.free]
    h, d = sim.dt, sim.damping
    Hp = oracle.stiffness_operator(sysm, data.C)
    m = sysm.Mff.diagonal()
    apply_A = lambda p: (1 + h * d.alpha) * m * p + (h * d.beta + h * h) * Hp(p)  # noqa: E731
    dv = oracle.predict(apply_A, b, preconditioners[kind])
    assert np.linalg.norm(A @ dv - b) < 0.2 * np.linalg.norm(b)
    assert np.allclose(dv, oracle.predict(A, b, preconditioners[kind]), rtol=1e-9, atol=1e-14)


def test_exact_preconditioner_gives_exact_solution_in_one_iteration(bent):
    sim, A, b, _ = bent
    lu = spla.splu(A.tocsc())
    g = np.tile(sim.gravity, sim.system.n)[sim.system.free] * sim.dt
    dv = oracle.predict(A, b, lu.solve, gravity_dv=g)
    exact = lu.solve(b)
    assert np.linalg.norm(dv - g - exact) <= 1e-10 * np.linalg.norm(exact)


def test_degenerate_cases_return_gravity_or_zeros(bent, preconditioners):
    sim, A, b, _ = bent
    P = preconditioners["ichol"]
    g = np.full(b.size, -0.1)
    assert np.array_equal(oracle.predict(A, np.zeros_like(b), P, gravity_dv=g), g)
    assert np.array_equal(oracle.predict(A, np.zeros_like(b), P), np.zeros_like(b))
    assert np.array_equal(oracle.predict(lambda p: -p, b, P, gravity_dv=g), g)  # z.A z < 0
    assert np.array_equal(oracle.predict(lambda p: 0 * p, b, P), np.zeros_like(b))  # z.A z = 0


def test_ichol_breakdown_is_caught_and_shifted():
    """IC(0) of Kershaw's SPD matrix meets a negative pivot; the factor of a shifted matrix is used."""
    A = sp.csr_matrix(np.array([[3.0, -2, 0, 2], [-2, 3, -2, 0], [0, -2, 3, -2], [2, 0, -2, 3]]))
    assert np.all(np.linalg.eigvalsh(A.toarray()) > 0)
    factor = ichol.incomplete_cholesky(A, fill=None)
    assert factor.shift > 0
    assert np.all(factor.L.diagonal() > 0)
    r = np.random.default_rng(0).standard_normal(4)
    z = factor.solve(r)
    assert np.all(np.isfinite(z)) and z @ r > 0


def test_oracle_factor_of_a_random_spd_matrix_is_spd():
    X = sp.random(40, 40, density=0.2, random_state=np.random.default_rng(1))
    A = sp.csr_matrix(X @ X.T + 1e-6 * sp.eye(40))
    perm, factor, shift = oracle.ichol_factor(A)
    assert sorted(perm) == list(range(40)) and shift >= 0
    assert np.all(factor.L.diagonal() > 0)
    R = np.random.default_rng(0).standard_normal((40, 5))
    Z = factor.solve(R[perm])
    assert np.all(np.isfinite(Z)) and np.all(np.einsum("ij,ij->j", Z, R[perm]) > 0)
