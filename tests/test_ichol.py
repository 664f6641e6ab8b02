"""Incomplete Cholesky (the oracle's preconditioner, eq. 14): IC(0), the threshold variant, breakdown."""
import numpy as np
import pytest
import scipy.sparse as sp

from skfem_affine.reducers.affine.ichol import IncompleteCholeskyBreakdown, incomplete_cholesky


def laplacian_2d(n, shift=0.1):
    T = sp.diags([-1.0, 2.0, -1.0], [-1, 0, 1], shape=(n, n))
    return sp.csr_matrix(sp.kron(T, sp.eye(n)) + sp.kron(sp.eye(n), T) + shift * sp.eye(n * n))


def random_spd(n, seed):
    """A sparse SPD matrix with an irregular pattern and a varying diagonal."""
    rng = np.random.default_rng(seed)
    X = sp.random(n, n, density=4 / n, random_state=rng)
    return sp.csr_matrix(X @ X.T + sp.diags(rng.uniform(0.5, 2.0, n)))


def on_pattern(A, B):
    """Largest |A - B| on the pattern of A."""
    mask = sp.csr_matrix(A, copy=True)
    mask.data[:] = 1.0
    return abs((A - B).multiply(mask)).max()


@pytest.mark.parametrize("A", [laplacian_2d(9), random_spd(60, 0)], ids=["laplacian", "random"])
def test_ic0_reproduces_the_matrix_on_its_pattern(A):
    ic = incomplete_cholesky(A, fill=None)
    L = ic.L
    assert ic.shift == 0
    assert sp.tril(L).nnz == L.nnz                    # lower triangular
    assert L.nnz == sp.tril(A).nnz                    # exactly A's lower pattern
    assert np.array_equal((abs(L) > 0).toarray(), (abs(sp.tril(A)) > 0).toarray())
    LLt = L @ L.T
    assert on_pattern(A, LLt) <= 1e-12 * abs(A).max()
    assert abs(LLt - A).max() > 1e-3 * abs(A).max()   # an incomplete factor: fill was dropped


@pytest.mark.parametrize("fill", [None, 0, 5])
def test_a_tree_pattern_is_factorised_exactly(fill):
    """Tridiagonal, and a star (arrow pattern, hub last): no fill, so every variant is exact."""
    rng = np.random.default_rng(2)
    n = 30
    off = rng.uniform(-1, 1, n - 1)
    tri = sp.diags([off, 3.0 + rng.uniform(0, 1, n), off], [-1, 0, 1], format="csr")
    star = np.diag(rng.uniform(1, 2, n))
    star[n - 1, :n - 1] = star[:n - 1, n - 1] = rng.uniform(-0.1, 0.1, n - 1)
    star[n - 1, n - 1] = 10.0
    for A in (tri, sp.csr_matrix(star)):
        ic = incomplete_cholesky(A, fill=fill)
        exact = np.linalg.cholesky(A.toarray())
        assert np.allclose(ic.L.toarray(), exact, rtol=0, atol=1e-13 * abs(exact).max())
        b = rng.standard_normal(n)
        assert np.allclose(A @ ic.solve(b), b, rtol=0, atol=1e-10 * np.abs(b).max())


def test_unlimited_fill_is_the_exact_cholesky_factor():
    A = random_spd(50, 1)
    ic = incomplete_cholesky(A, fill=10**12, drop=0.0)  # more than any column can hold
    exact = np.linalg.cholesky(A.toarray())
    assert np.allclose(ic.L.toarray(), exact, rtol=0, atol=1e-12 * abs(exact).max())


def test_threshold_variant_keeps_at_most_fill_extra_entries_per_column():
    A = laplacian_2d(12)
    lower = sp.csc_matrix(sp.tril(A))
    for fill in (0, 3):
        L = sp.csc_matrix(incomplete_cholesky(A, fill=fill, drop=0.0).L)
        assert np.all(np.diff(L.indptr) <= np.diff(lower.indptr) + fill)
    few = incomplete_cholesky(A, fill=3, drop=0.0).L.nnz
    dropped = incomplete_cholesky(A, fill=3, drop=0.2).L.nnz
    assert dropped < few


def test_more_fill_is_a_better_preconditioner():
    A = laplacian_2d(15, shift=0.01)
    b = np.random.default_rng(3).standard_normal(A.shape[0])
    errors = []
    for fill in (None, 2, 10):
        x = incomplete_cholesky(A, fill=fill, drop=1e-4).solve(b)
        errors.append(np.linalg.norm(A @ x - b))
    assert errors[0] > errors[1] > errors[2]


def test_solve_is_l_lt_inverse_for_vectors_and_columns():
    A = random_spd(40, 4)
    ic = incomplete_cholesky(A, fill=2, drop=1e-3)
    M = (ic.L @ ic.L.T).toarray()
    B = np.random.default_rng(5).standard_normal((40, 3))
    B0 = B.copy()
    assert np.allclose(M @ ic.solve(B), B, atol=1e-10)
    assert np.allclose(M @ ic.solve(B[:, 0]), B[:, 0], atol=1e-10)
    assert np.array_equal(B, B0)                      # input untouched
    with pytest.raises(ValueError, match="b must have shape"):
        ic.solve(np.ones(7))


def test_breakdown_for_every_shift_raises_clearly():
    A = sp.csr_matrix(np.array([[1.0, 3.0], [3.0, 1.0]]))  # symmetric, positive diagonal, indefinite
    with pytest.raises(IncompleteCholeskyBreakdown, match="non-positive pivot.*every diagonal shift"):
        incomplete_cholesky(A, fill=None)
    assert issubclass(IncompleteCholeskyBreakdown, ValueError)
    ic = incomplete_cholesky(A, fill=None, shifts=(0.0, 3.0))  # 4 I + offdiag 3 is SPD
    assert ic.shift == 3.0


def test_bad_input_names_the_argument():
    A = laplacian_2d(3)
    with pytest.raises(TypeError, match="A must be a square scipy sparse"):
        incomplete_cholesky(A.toarray())
    with pytest.raises(TypeError, match="A must be a square"):
        incomplete_cholesky(sp.csr_matrix(np.ones((2, 3))))
    with pytest.raises(ValueError, match="positive diagonal"):
        incomplete_cholesky(sp.csr_matrix(-A))
    with pytest.raises(ValueError, match="non-finite"):
        incomplete_cholesky(sp.csr_matrix(A * np.nan))
    with pytest.raises(ValueError, match="fill"):
        incomplete_cholesky(A, fill=-1)
    with pytest.raises(ValueError, match="drop"):
        incomplete_cholesky(A, drop=np.inf)
    with pytest.raises(ValueError, match="shifts"):
        incomplete_cholesky(A, shifts=())
