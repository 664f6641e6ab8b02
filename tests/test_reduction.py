"""The mapping G (eq. 7-8), projection (eq. 9), discrepancy (eq. 11) and reduced system (eq. 10)."""
import numpy as np
import pytest
import scipy.sparse as sp

import skfem_affine as sa
from skfem_affine.reducers.affine import mapping as reduction


@pytest.fixture(scope="module")
def setup():
    sim = sa.scenes.cantilever(resolution=2, damping=sa.Rayleigh(0.1, 0.01), E=1e5)
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
        gmap = reduction.affine_mapping(sysm.free, vcl, sysm.p0, sysm.lumped_mass, 2)
    else:
        gmap = reduction.rigid_mapping(sysm.free, vcl, sim.state.x, sysm.lumped_mass, 2)
    assert gmap.kind is {"affine": reduction.AFFINE, "rigid": reduction.RIGID}[kind]
    assert np.array_equal(gmap.elastic_dofs, np.flatnonzero(vcl[sysm.free // 3] < 0))
    return gmap.rows, gmap.elastic_dofs, gmap


def test_G_reproduces_affine_fields_exactly(setup):
    sim, s, vcl = setup
    sysm = sim.system
    _, el, gmap = maps(sim, vcl, "affine")
    G = gmap.G
    L = np.array([[0.3, -0.1, 0.2], [0.05, 0.1, -0.4], [0.2, 0.3, 0.0]])
    v = (sysm.p0 @ L.T + [1.0, -2.0, 0.5]).ravel()[sysm.free]
    q = gmap.project(sysm.Mff.diagonal(), v)
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
    _, _, gmap = maps(sim, vcl, kind)
    v = np.random.default_rng(0).normal(size=sysm.free.size)
    q = gmap.project(sysm.Mff.diagonal(), v)
    vp = gmap.G @ q
    # eq. 9 is the mass-weighted least squares: the normal equations hold
    G, Md = gmap.G, sp.diags(sysm.Mff.diagonal())
    assert np.allclose(G.T @ Md @ G @ q, G.T @ Md @ v, rtol=1e-10, atol=1e-10 * np.abs(G.T @ Md @ v).max())
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
    _, el, gmap = maps(sim, vcl, "rigid")
    G = gmap.G
    w, vc = np.array([0.3, -1.0, 0.5]), np.array([1.0, 0.0, -0.5])
    v = (vc + np.cross(w, s.x)).ravel()[sysm.free]
    q = gmap.project(sysm.Mff.diagonal(), v)
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
    Gam, el, gmap = maps(sim, vcl, kind)
    G = gmap.G
    R = reduction.reduced_matrix(sim.model, data, gmap, upper=upper)
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
    el = np.arange(sysm.free.size)
    gmap = reduction.affine_mapping(sysm.free, vcl, sysm.p0, sysm.lumped_mass, 0)
    A, b, data = sim.linear_system(s.x, s.v)
    assert (gmap.G != sp_identity(el.size)).nnz == 0
    R = reduction.reduced_matrix(sim.model, data, gmap)
    assert abs(R - A).max() <= 1e-13 * abs(A).max()  # same sums, element order


def sp_identity(n):
    import scipy.sparse as sp
    return sp.identity(n, format="csr")


def test_vertex_clusters():
    t = np.array([[0, 1, 2, 3], [4, 5, 6, 7], [3, 4, 8, 9]]).T
    vc = reduction.vertex_clusters(np.array([0, 1, -1]), t, 10)
    assert list(vc) == [0, 0, 0, 0, 1, 1, 1, 1, -1, -1]


def test_elimination_order_is_a_permutation_that_keeps_bodies_together(setup):
    sim, s, vcl = setup
    sysm = sim.system
    _, el, gmap = maps(sim, vcl, "affine")
    rank = reduction.nested_dissection_rank(sysm)
    assert np.array_equal(np.sort(rank[sysm.free[::3] // 3]), np.arange(sysm.free.size // 3))
    assert np.all(rank[sysm.fixed] == -1)
    order = gmap.elimination_order(rank)
    assert np.array_equal(np.sort(order), np.arange(gmap.shape[1]))
    pos = np.empty_like(order)
    pos[order] = np.arange(order.size)
    for b in range(2):  # a body's 12 DOFs are consecutive, after the elastic DOFs of ranks below its top vertex
        cols = pos[el.size + 12 * b: el.size + 12 * (b + 1)]
        assert np.array_equal(cols, np.arange(cols[0], cols[0] + 12))
        top = rank[vcl == b].max()
        earlier = rank[sysm.free[el[pos[:el.size] < cols[0]]] // 3]
        assert earlier.size and earlier.max() <= top


def test_pardiso_with_a_given_order_solves_the_reduced_system(setup):
    pytest.importorskip("pypardiso")
    from skfem_affine.solvers import Pardiso
    sim, s, vcl = setup
    sysm = sim.system
    A, b, data = sim.linear_system(s.x, s.v)
    _, el, gmap = maps(sim, vcl, "affine")
    U = reduction.reduced_matrix(sim.model, data, gmap, upper=True)
    full = (gmap.G.T @ A @ gmap.G).tocsr()
    rhs = np.random.default_rng(1).normal(size=full.shape[0])
    order = gmap.elimination_order(reduction.nested_dissection_rank(sysm))
    solver = Pardiso()
    solver.factorize(U, upper=True, order=order)
    x = solver.solve(rhs)
    assert np.linalg.norm(full @ x - rhs) <= 1e-10 * np.linalg.norm(rhs)
    with pytest.raises(ValueError, match="order"):
        Pardiso().factorize(U, upper=True, order=order[:-1])
    with pytest.raises(ValueError, match="exactly once"):  # right length, one unknown twice
        Pardiso().factorize(U, upper=True, order=np.concatenate([order[:-1], order[:1]]))


@pytest.mark.parametrize("kind", ["affine", "rigid"])
def test_reduced_matrix_with_consistent_mass_equals_GtAG(kind):
    sim = sa.scenes.cantilever(resolution=2, mass="consistent", damping=sa.Rayleigh(0.1, 0.01), E=1e5)
    for s in sim.run(3):
        pass
    X = sim.system.p0
    vcl = np.full(sim.system.n, -1)
    vcl[(X[:, 0] > 1.2) & (X[:, 0] < 2.3)] = 0
    vcl[X[:, 0] > 2.9] = 1
    A, b, data = sim.linear_system(s.x, s.v)
    _, _, gmap = maps(sim, vcl, kind)
    R = reduction.reduced_matrix(sim.model, data, gmap)
    ref = (gmap.G.T @ A @ gmap.G).toarray()
    assert abs(sim.system.Mff - sp.diags(sim.system.Mff.diagonal())).max() > 0  # really not lumped
    assert np.abs(R.toarray() - ref).max() <= 1e-12 * np.abs(ref).max()


def test_rigid_mapping_moves_its_bodies_rigidly_and_the_rest_by_h_v(setup):
    """The rigid body kind integrates positions by an exact rotation about the centre: distances
    inside a body are kept; elastic vertices (and affine mappings) move by x + h v."""
    sim, s, vcl = setup
    sysm, h = sim.system, sim.dt
    gmap = reduction.rigid_mapping(sysm.free, vcl, s.x, sysm.lumped_mass, 2)
    q = np.random.default_rng(2).normal(size=gmap.shape[1])
    v = np.zeros(3 * sysm.n)
    v[sysm.free] = gmap.G @ q  # a rigid velocity field on each body
    v = v.reshape(-1, 3)
    x1 = gmap.positions(s.x, v, h)
    for b in range(2):
        body = np.flatnonzero(vcl == b)
        d0 = np.linalg.norm(s.x[body, None] - s.x[None, body], axis=2)
        d1 = np.linalg.norm(x1[body, None] - x1[None, body], axis=2)
        assert np.abs(d1 - d0).max() <= 1e-12 * d0.max()
        assert np.abs(x1[body] - s.x[body] - h * v[body]).max() > 1e-9  # rotated, not translated along v
    elastic = vcl < 0
    assert np.array_equal(x1[elastic], (s.x + h * v)[elastic])
    affine = reduction.affine_mapping(sysm.free, vcl, sysm.p0, sysm.lumped_mass, 2)
    assert np.array_equal(affine.positions(s.x, v, h), s.x + h * v)
    with pytest.raises(ValueError, match="width"):
        reduction.Mapping(sysm.free, vcl, gmap.rows, 2, reduction.AFFINE)
