"""The mapping G (eq. 7-8), projection (eq. 9), discrepancy (eq. 11) and reduced system (eq. 10)."""
import numpy as np
import pytest

import skfem_affine as sa
from skfem_affine import reduction


@pytest.fixture(scope="module")
def setup():
    sim = sa.scenes.cantilever(resolution=2, damping=sa.Rayleigh(0.1, 0.01))
    for s in sim.run(5):
        pass
    sysm = sim.system
    X = sysm.p0
    vcl = np.full(sysm.n, -1)
    vcl[(X[:, 0] > 1.2) & (X[:, 0] < 2.3)] = 0
    vcl[X[:, 0] > 2.9] = 1
    return sim, s, vcl


def maps(sim, vcl, kind):
    sysm = sim.system
    if kind == "affine":
        Gam = reduction.affine_rows(vcl, sysm.p0, sysm.lumped_mass, 2)
    else:
        Gam, _ = reduction.rigid_rows(vcl, sim.state.x, sysm.lumped_mass, 2)
    el = np.flatnonzero(vcl[sysm.free // 3] < 0)
    G = reduction.assemble_G(sysm.free, vcl, Gam, el, 2, Gam.shape[2])
    return Gam, el, G


def test_G_reproduces_affine_fields_exactly(setup):
    sim, s, vcl = setup
    sysm = sim.system
    _, el, G = maps(sim, vcl, "affine")
    L = np.array([[0.3, -0.1, 0.2], [0.05, 0.1, -0.4], [0.2, 0.3, 0.0]])
    v = (sysm.p0 @ L.T + [1.0, -2.0, 0.5]).ravel()[sysm.free]
    q = reduction.project(G, sysm.Mff.diagonal(), v)
    assert np.allclose(G @ q, v, atol=1e-12)
    assert np.allclose(reduction.discrepancy(G, q, v), 0, atol=1e-12)
    # the affine coordinates are the field's matrix L (row-major) in each body
    for c in range(2):
        assert np.allclose(q[el.size + 12 * c + 3: el.size + 12 * c + 12], L.ravel())


@pytest.mark.parametrize("kind", ["affine", "rigid"])
def test_projection_preserves_momentum(setup, kind):
    sim, s, vcl = setup
    sysm = sim.system
    x = sysm.p0 if kind == "affine" else s.x  # affine r_i live in the rest frame
    _, _, G = maps(sim, vcl, kind)
    v = np.random.default_rng(0).normal(size=sysm.free.size)
    vp = G @ reduction.project(G, sysm.Mff.diagonal(), v)
    m = np.repeat(sysm.lumped_mass, 3)[sysm.free]
    full_v = np.zeros(3 * sysm.n)
    full_p = np.zeros(3 * sysm.n)
    full_v[sysm.free], full_p[sysm.free] = v, vp
    p0 = (sysm.lumped_mass[:, None] * full_v.reshape(-1, 3)).sum(0)
    p1 = (sysm.lumped_mass[:, None] * full_p.reshape(-1, 3)).sum(0)
    L0 = (sysm.lumped_mass[:, None] * np.cross(x, full_v.reshape(-1, 3))).sum(0)
    L1 = (sysm.lumped_mass[:, None] * np.cross(x, full_p.reshape(-1, 3))).sum(0)
    scale = np.abs(m * v).sum()
    assert np.linalg.norm(p1 - p0) <= 1e-10 * scale
    assert np.linalg.norm(L1 - L0) <= 1e-10 * scale * np.abs(x).max()
    assert not np.allclose(vp, v)  # the projection did something


def test_rigid_rows_reproduce_rigid_fields(setup):
    sim, s, vcl = setup
    sysm = sim.system
    _, el, G = maps(sim, vcl, "rigid")
    w, vc = np.array([0.3, -1.0, 0.5]), np.array([1.0, 0.0, -0.5])
    v = (vc + np.cross(w, s.x)).ravel()[sysm.free]
    q = reduction.project(G, sysm.Mff.diagonal(), v)
    assert np.allclose(G @ q, v, atol=1e-12)
    assert np.allclose(q[el.size + 3: el.size + 6], w)


@pytest.mark.parametrize("kind", ["affine", "rigid"])
@pytest.mark.parametrize("blocks", ["all", "where_needed"])
@pytest.mark.parametrize("upper", [False, True])
def test_reduced_matrix_equals_GtAG(setup, kind, blocks, upper):
    sim, s, vcl = setup
    A, b, data = sim.linear_system(s.x, s.v)
    if blocks == "where_needed":  # element blocks assembled only outside affine bodies
        data = sim.system.evaluate_tangent(s.x, project=sim.project_hessian)
    Gam, el, G = maps(sim, vcl, kind)
    R = reduction.reduced_matrix(sim, data, vcl, Gam, 2, el, affine=kind == "affine", upper=upper)
    ref = (G.T @ A @ G).toarray()
    if upper:  # the upper triangle only, sorted rows (what Pardiso reads)
        ref = np.triu(ref)
        rows = np.split(R.indices, R.indptr[1:-1])
        assert all(np.all(np.diff(r) > 0) for r in rows)
    assert np.abs(R.toarray() - ref).max() <= 1e-12 * np.abs(ref).max()


def test_no_clusters_is_the_identity(setup):
    sim, s, _ = setup
    sysm = sim.system
    vcl = np.full(sysm.n, -1)
    Gam = reduction.affine_rows(vcl, sysm.p0, sysm.lumped_mass, 0)
    el = np.arange(sysm.free.size)
    G = reduction.assemble_G(sysm.free, vcl, Gam, el, 0, 12)
    A, b, data = sim.linear_system(s.x, s.v)
    assert (G != sp_identity(el.size)).nnz == 0
    R = reduction.reduced_matrix(sim, data, vcl, Gam, 0, el)
    assert abs(R - A).max() == 0


def sp_identity(n):
    import scipy.sparse as sp
    return sp.identity(n, format="csr")


def test_vertex_clusters():
    t = np.array([[0, 1, 2, 3], [4, 5, 6, 7], [3, 4, 8, 9]]).T
    vc = reduction.vertex_clusters(np.array([0, 1, -1]), t, 10)
    assert list(vc) == [0, 0, 0, 0, 1, 1, 1, 1, -1, -1]
