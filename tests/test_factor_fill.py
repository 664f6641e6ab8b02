"""The fill of a reduced system's Cholesky factor (``Pardiso.factor_nonzeros``) in the elimination
order inherited from the mesh, against Pardiso's own nested dissection (METIS) of the same matrix."""
import numpy as np
import pytest

import skfem_affine as sa
from skfem_affine.reducers.affine import mapping as reduction

pytest.importorskip("pypardiso")
from skfem_affine.solvers import Pardiso  # noqa: E402


@pytest.fixture(scope="module")
def reduced():
    """A cantilever's reduced matrix (upper triangle) with two affine bodies, its G^T A G and its order."""
    sim = sa.scenes.cantilever(resolution=4, damping=sa.Rayleigh(0.1, 0.01), E=1e5)
    for s in sim.run(2):
        pass
    sysm = sim.system
    A, _, data = sim.linear_system(s.x, s.v)
    X = sysm.p0
    vcl = np.full(sysm.n, -1)
    vcl[(X[:, 0] > 1.2) & (X[:, 0] < 2.3)] = 0
    vcl[X[:, 0] > 2.9] = 1
    gmap = reduction.affine_mapping(sysm.free, vcl, sysm.p0, sysm.lumped_mass, 2)
    U = reduction.reduced_matrix(sim.model, data, gmap, upper=True)
    order = gmap.elimination_order(reduction.nested_dissection_rank(sysm))
    return U, (gmap.G.T @ A @ gmap.G).tocsr(), order


def test_factor_nonzeros_counts_the_factor_of_the_current_pattern(reduced):
    U, full, order = reduced
    solver = Pardiso()
    assert solver.factor_nonzeros is None
    solver.factorize(U, upper=True, order=order)
    n = U.shape[0]
    # a Cholesky factor holds at least the upper triangle's entries and at most a dense triangle
    assert U.nnz <= solver.factor_nonzeros <= n * (n + 1) // 2
    given = solver.factor_nonzeros
    solver.factorize(U, upper=True, order=order)  # the same pattern: no new analysis, the same factor
    assert solver.factor_nonzeros == given
    sub = U[:-12, :-12]  # a new pattern (one body fewer): analysed anew, its own count
    solver.factorize(sub, upper=True)
    assert solver.analysed_for(sub, upper=True) and not solver.analysed_for(U, upper=True)
    assert sub.nnz <= solver.factor_nonzeros < given


def test_the_inherited_order_fills_about_as_little_as_metis_and_solves_alike(reduced):
    U, full, order = reduced
    given, metis = Pardiso(), Pardiso()
    given.factorize(U, upper=True, order=order)
    metis.factorize(U, upper=True)
    assert given._ordering == "given" and metis._ordering == "metis"
    assert given.factor_nonzeros <= 1.15 * metis.factor_nonzeros
    rhs = np.random.default_rng(3).normal(size=U.shape[0])
    x, y = given.solve(rhs), metis.solve(rhs)
    assert np.linalg.norm(full @ x - rhs) <= 1e-10 * np.linalg.norm(rhs)
    assert np.allclose(x, y, rtol=0, atol=1e-10 * np.abs(y).max())
