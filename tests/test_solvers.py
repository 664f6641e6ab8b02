"""Direct solvers: Pardiso's upper-triangle input, analysis reuse and fresh analyses."""
import numpy as np
import pytest
import scipy.sparse as sp

import skfem_affine as sa

pytestmark = pytest.mark.skipif(not sa.solvers.has_pardiso(), reason="pypardiso not installed")


def spd(n, seed, density=0.05):
    rng = np.random.default_rng(seed)
    B = sp.random(n, n, density=density, random_state=rng)
    return (B @ B.T + n * sp.identity(n)).tocsr()


def test_pardiso_upper_and_full_inputs_agree_and_patterns_are_reanalysed():
    solver = sa.solvers.Pardiso()
    for seed, n in [(0, 60), (0, 60), (1, 60), (2, 45), (2, 45)]:  # same, changed and resized patterns
        A = spd(n, seed)
        A.data *= 1.0 + seed  # new values on a reused pattern too
        b = np.arange(n, dtype=float)
        solver.factorize(A)
        x_full = solver.solve(b)
        solver.factorize(sp.triu(A, format="csr"), upper=True)
        x_upper = solver.solve(b)
        ref = np.linalg.solve(A.toarray(), b)
        assert np.allclose(x_full, ref, rtol=1e-10) and np.allclose(x_upper, ref, rtol=1e-10)


def test_pardiso_solves_several_right_hand_sides():
    A = spd(40, 3)
    solver = sa.solvers.Pardiso()
    solver.factorize(A)
    B = np.random.default_rng(0).random((40, 3))
    assert np.allclose(solver.solve(B), np.linalg.solve(A.toarray(), B), rtol=1e-10)


def test_affinification_with_the_upper_triangle_matches_the_full_matrix_path():
    # same seed, same clusters: Pardiso on the reduced upper triangle against SuperLU on the whole matrix
    runs = []
    for solver in ("pardiso", "superlu"):
        sim = sa.scenes.cantilever(resolution=2, E=1e5, damping=None,
                                   reducer=sa.Affinification(tau_a=0.3, tau_e=0.6, solver=solver))
        for s in sim.run(15):
            pass
        assert max(r["n_clusters"] for r in sim.stats) > 0
        runs.append(s.x)
    assert np.abs(runs[0] - runs[1]).max() <= 1e-8 * sim.size
