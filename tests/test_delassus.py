"""The Delassus operator W = J A^-1 J^T (through G when reduced, from the unknowns the contacts touch,
the bodies' columns solved side by side) against the plain path of 3 solves per contact on the
frame's factorisation, and its solver cache stays bounded."""
import numpy as np
import pytest
import scipy.sparse as sp

import skfem_affine as sa
from skfem_affine.contact import delassus
from skfem_affine.contact.pgs import projected_gauss_seidel
from skfem_affine.integrators.problem import Operator
from skfem_affine.lab.scenes import box_mesh
from skfem_affine.solvers import AMGCG, SuperLU


def plain_delassus(operator, J):
    """The plain path: A^-1 applied to every column of (J G)^T (3 solves per contact), W = (J G) A^-1 (J G)^T."""
    Jr = (J @ operator.G) if operator.G is not None else J
    R = sp.csr_matrix(Jr).T.toarray()
    if operator.iterative:
        Y = np.column_stack([operator.solver.solve(R[:, j]) for j in range(R.shape[1])])
    else:
        Y = np.asarray(operator.solver.solve(R)).reshape(R.shape)
    W = sp.csr_matrix(Jr) @ Y
    return 0.5 * (W + W.T), Jr, Y


def frames_with_contact(sim, frames, check, want=3):
    """Calls ``check(operator, J)`` in up to ``want`` frames with contacts (reduced ones when the run
    is reduced), while the frame's solver holds that frame's factorisation; returns the count."""
    done, original = [], sim.contact.resolve

    def spy(problem, result, rec):
        op, cs = result.operator, sim.contact.current
        if cs is not None and cs.size and (sim.reducer is None or op.G is None or op.G.shape[1] != op.G.shape[0]):
            check(op, cs.J)
            done.append(True)
        return original(problem, result, rec)

    sim.contact.resolve = spy
    for _ in sim.run(frames):
        if len(done) >= want:
            break
    assert done, "no frame with contact"
    return len(done)


REDUCERS = {"full": lambda: None, "affine": lambda: sa.Affinification(tau_a=1.0, tau_e=2.0),
            "rigid": lambda: sa.Rigidification(tau_r=0.05)}
SCENES = {"drop": dict(resolution=1, shape="box"), "stacked_beams": dict(resolution=1),
          "pills": dict(n=3, resolution=1)}


@pytest.mark.parametrize("reducer", list(REDUCERS))
@pytest.mark.parametrize("scene", list(SCENES))
def test_delassus_equals_the_plain_path(scene, reducer):
    sim = sa.scenes.SCENES[scene](**SCENES[scene], reducer=REDUCERS[reducer]())

    def check(op, J):
        ref, Jr, Y = plain_delassus(op, J)
        scale = np.abs(ref).max()
        res = delassus.Resolvent(op, block=7, cache={})
        W = res.delassus(J)
        assert np.abs(W - ref).max() <= 1e-9 * scale, np.abs(W - ref).max() / scale
        rows = delassus.Resolvent(op, block=7, cache={}, touched=False)  # per row of J, per body
        assert np.abs(W - rows.delassus(J)).max() <= 1e-12 * scale
        assert res.columns_solved <= rows.columns_solved
        lam = np.random.default_rng(1).normal(size=J.shape[0])
        dv = res.apply(lam)
        want = Y @ lam
        want = op.G @ want if op.G is not None else want
        assert np.abs(dv - want).max() <= 1e-9 * np.abs(want).max()

    assert frames_with_contact(sim, 120, check) == 3


def _box_on_plane(reducer, colliders=1):
    """A stiff box thrown sideways onto the plane (``colliders`` copies of it): rigidification keeps
    it one rigid body, affinification one affine body."""
    mesh = sa.scenes.box_mesh(0.3, 3, (0.0, 0.0, 0.16))
    body = sa.ElasticBody(mesh, sa.NeoHookean(E=1e8, nu=0.3), density=1000.0, velocity=(1.0, 0.0, -0.5))
    return sa.Simulation([body], dt=0.01, gravity=(0, 0, -9.81),
                         colliders=[sa.Plane((0, 0, 0), (0, 0, 1)) for _ in range(colliders)],
                         reducer=reducer)


def test_contacts_on_a_rigid_body_touch_its_six_dofs_and_match_the_plain_path():
    sim = _box_on_plane(sa.Rigidification(tau_r=10.0))

    def check(op, J):
        assert op.G.shape[1] == 6  # the whole box is one rigid body
        k = J.shape[0] // 3
        assert k >= 9  # a face of vertices touches
        ref, Jr, Y = plain_delassus(op, J)  # 3 solves per vertex contact
        res = delassus.Resolvent(op, cache={})
        W = res.delassus(J)
        assert np.unique(res.Jr.indices).size == 6  # the contacts touch the body's 6 DOFs only
        assert res.columns_solved == 6              # and W solves those, not 3 per contact
        assert np.abs(W - ref).max() <= 1e-10 * np.abs(ref).max()
        u0 = J @ np.tile([1.0, 0.0, -0.5], J.shape[1] // 3)  # sliding into the plane
        lam, lam_ref = np.zeros(3 * k), np.zeros(3 * k)
        projected_gauss_seidel(W, u0, lam, 0.5, 200, 1e-12)
        projected_gauss_seidel(ref, u0, lam_ref, 0.5, 200, 1e-12)
        assert np.allclose(lam, lam_ref, rtol=1e-8, atol=1e-10 * np.abs(lam_ref).max())
        dv, dv_ref = res.apply(lam), op.G @ (Y @ lam_ref)
        assert np.allclose(dv, dv_ref, atol=1e-9 * np.abs(dv_ref).max())

    assert frames_with_contact(sim, 30, check, want=1) == 1


def test_contacts_on_an_affine_body_solve_its_twelve_dofs():
    """A rigidly moving affine body with a face of contacts: W solves its 12 reduced unknowns, not 3
    columns per contact, and equals the plain path."""
    sim = _box_on_plane(sa.Affinification(tau_a=1.0, tau_e=2.0))

    def check(op, J):
        assert op.G.shape[1] == 12  # the whole box is one affine body
        assert J.shape[0] // 3 >= 16
        ref, _, Y = plain_delassus(op, J)
        res = delassus.Resolvent(op, cache={})
        W = res.delassus(J)
        assert res.columns_solved == 12
        assert np.abs(W - ref).max() <= 1e-10 * np.abs(ref).max()
        lam = np.random.default_rng(2).normal(size=J.shape[0])
        want = op.G @ (Y @ lam)
        assert np.allclose(res.apply(lam), want, atol=1e-10 * np.abs(want).max())

    assert frames_with_contact(sim, 30, check, want=2) == 2


def test_a_vertex_with_several_contacts_is_solved_once_in_full_space():
    """Full space, a box on two copies of the floor: every touching vertex has two contacts (6 rows)
    on its 3 unknowns, and W solves those 3 columns once, equal to the plain path."""
    sim = _box_on_plane(None, colliders=2)

    def check(op, J):
        assert op.G is None
        ref, _, _ = plain_delassus(op, J)
        res = delassus.Resolvent(op, block=5, cache={})
        W = res.delassus(J)
        assert res.columns_solved == np.unique(J.indices).size == J.shape[0] // 2
        assert np.abs(W - ref).max() <= 1e-10 * np.abs(ref).max()

    assert frames_with_contact(sim, 30, check, want=2) == 2


def _laplacian(m):
    """An SPD chain of m unknowns (one component)."""
    return sp.diags([-np.ones(m - 1), 3.0 * np.ones(m), -np.ones(m - 1)], [-1, 0, 1], format="csr")


def test_the_delassus_cache_holds_one_frames_factorisation():
    """Bodies change from frame to frame (sizes, first unknowns): with a direct frame solver nothing is
    factorised again (the cache stays empty), with an iterative one the cache keeps the one direct
    factorisation of the current frame, frame after frame."""
    rng = np.random.default_rng(0)
    caches = {"direct": {}, "iterative": {}}
    for frame in range(6):
        sizes = rng.integers(30, 90, size=3)
        A = sp.block_diag([_laplacian(int(m)) for m in sizes], format="csr")
        bodies = np.repeat(np.arange(3), sizes)
        n = A.shape[0]
        cols = rng.choice(n, 6, replace=False)
        J = sp.csr_matrix((np.ones(6), (np.arange(6), cols)), shape=(6, n))
        for kind, cache in caches.items():
            solver = AMGCG() if kind == "iterative" else SuperLU()
            solver.factorize(A)
            W = delassus.Resolvent(Operator(solver, A), cache=cache, bodies=bodies).delassus(J)
            E = np.zeros((n, 6))
            E[cols, np.arange(6)] = 1.0
            assert np.allclose(W, np.linalg.solve(A.toarray(), E)[cols], atol=1e-12)
        assert len(caches["direct"]) == 0 and list(caches["iterative"]) == [(n, 0)]


def _contacts_on(cols, rng, per_vertex):
    """J of ``per_vertex`` contacts (3 rows n, t1, t2 each) on every vertex whose 3 unknowns start at
    each of ``cols``: a vertex with several contacts (several colliders) touches the same 3 unknowns."""
    rows = []
    for c in cols:
        for _ in range(per_vertex):
            frame, _ = np.linalg.qr(rng.normal(size=(3, 3)))
            rows.append((c, frame))
    return rows


def _jacobian(entries, n):
    data, r, c = [], [], []
    for i, (cols, frame) in enumerate(entries):
        cols = np.atleast_1d(cols)
        for v, col in enumerate(cols):   # several vertices: weights +1 on the first, -1/(v) on the others
            w = 1.0 if v == 0 else -1.0 / (len(cols) - 1)
            for a in range(3):
                for b in range(3):
                    r.append(3 * i + a)
                    c.append(col + b)
                    data.append(w * frame[a, b])
    return sp.csr_matrix((data, (r, c)), shape=(3 * len(entries), n))


def _spd(m, rng):
    """An SPD block of m unknowns coupled along a chain (one component)."""
    return (_laplacian(m) + sp.diags(rng.uniform(0.1, 1.0, m))).tocsr()


@pytest.mark.parametrize("per_vertex", [1, 4])
@pytest.mark.parametrize("sizes", [(60,), (60, 900, 45), (30, 30)])
def test_touched_unknowns_give_the_per_row_delassus(sizes, per_vertex):
    """W from Z = (A^-1)_TT on the unknowns the contacts touch equals J A^-1 J^T, with A one body or
    several (their columns solved side by side), vertices with several contacts and contacts between
    two bodies; it solves |T| columns when fewer than the rows."""
    rng = np.random.default_rng(3)
    A = sp.block_diag([_spd(m, rng) for m in sizes], format="csr")
    n, starts = A.shape[0], np.concatenate([[0], np.cumsum(sizes)])
    entries, verts = [], []
    for s, e in zip(starts[:-1], starts[1:]):   # 3 vertices with per_vertex contacts each per body
        verts.append(s + 3 * rng.choice((e - s) // 3, 3, replace=False))
        entries += _contacts_on(verts[-1], rng, per_vertex)
    if len(sizes) > 1:                          # a vertex of body 0 on a triangle of body 1
        frame, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        entries.append((np.array([verts[0][0], starts[1], starts[1] + 3, starts[1] + 6]), frame))
    J = _jacobian(entries, n)
    solver = SuperLU()
    solver.factorize(A)
    ref = J @ np.linalg.solve(A.toarray(), J.T.toarray())
    res = delassus.Resolvent(Operator(solver, A), block=5, cache={}, bodies=np.repeat(np.arange(len(sizes)), sizes))
    W = res.delassus(J)
    assert np.abs(W - ref).max() <= 1e-12 * np.abs(ref).max()
    assert np.array_equal(W, W.T)
    # per body, the fewer of its touched unknowns and its rows, solved side by side: with 4 contacts
    # per vertex, the 9 unknowns of its 3 vertices (12 rows), plus in body 1 the triangle's 9 of the
    # body-body contact
    count = 0
    for s, e in zip(starts[:-1], starts[1:]):
        Jb = J[:, s:e]
        touched, rows = np.unique(Jb.indices).size, np.flatnonzero(np.diff(Jb.tocsr().indptr)).size
        count = max(count, min(touched, rows))
    assert res.columns_solved == count
    if per_vertex == 4:
        assert count == (18 if len(sizes) > 1 else 9)
    lam = rng.normal(size=J.shape[0])
    assert np.allclose(res.apply(lam), np.linalg.solve(A.toarray(), J.T @ lam), rtol=1e-10, atol=1e-12)


def _mixed_pile(reducer):
    """Five boxes: a stiff one on the ground under a soft one (affine and elastic at once under
    affinification), a box pinned by its bottom face under a small one, and one far off and high up
    that no contact reaches in the frames checked."""
    stiff, soft = sa.NeoHookean(E=1e9, nu=0.3), sa.NeoHookean(E=2e4, nu=0.3)
    pinned = box_mesh(0.2, 2, (0.5, 0.0, 0.1))
    bodies = [sa.ElasticBody(box_mesh(0.2, 2, (0.0, 0.0, 0.101)), stiff, density=1000.0),
              sa.ElasticBody(box_mesh(0.14, 2, (0.02, 0.01, 0.273)), soft, density=1000.0),
              sa.ElasticBody(pinned, soft, density=1000.0, fixed=pinned.p[2] < 1e-9),
              sa.ElasticBody(box_mesh(0.1, 2, (0.51, 0.01, 0.252)), stiff, density=1000.0),
              sa.ElasticBody(box_mesh(0.1, 2, (3.0, 0.0, 8.0)), stiff, density=1000.0)]
    return sa.Simulation(bodies, dt=0.01, gravity=(0.0, 0.0, -9.81), colliders=[sa.Plane()], reducer=reducer)


def _counted(Jr, labels):
    """Columns of the packed solve: the most, over bodies, of the fewer of a body's touched unknowns
    and its rows of Jr."""
    Jc = sp.csc_matrix(Jr)
    most = 0
    for b in np.unique(labels):
        Jb = Jc[:, np.flatnonzero(labels == b)]
        touched = np.flatnonzero(np.diff(Jb.indptr)).size
        rows = np.unique(Jb.indices).size
        most = max(most, min(touched, rows))
    return most


MIXED = {"full": lambda: None, "affine": lambda: sa.Affinification(tau_a=0.1, tau_e=0.2),
         "rigid": lambda: sa.Rigidification(tau_r=0.05)}


@pytest.mark.parametrize("reducer", list(MIXED))
def test_several_bodies_solve_their_columns_together_with_the_frames_solver(reducer):
    """Bodies are not coupled by A: the columns of every body are solved in one set of right-hand
    sides with the frame's own factorisation (the unknowns of different bodies share a column), no
    body's block factorised again. W and dv = A^-1 J^T lambda equal the plain path (3 solves per
    contact on the whole system) to round-off, with affine and elastic bodies, a pinned body and a
    body without contacts; the columns solved are the most any one body needs."""
    sim = _mixed_pile(MIXED[reducer]())
    if sim.contact.schur is not None:  # the columns, not the full-space frame's own Schur complement
        sim.contact.schur.frame = False
    bodies = sim.contact.bodies
    assert bodies.shape == sim.system.free.shape
    seen = {"mixed": False}

    def check(op, J):
        ref, Jr, Y = plain_delassus(op, J)
        scale = np.abs(ref).max()
        res = delassus.Resolvent(op, block=7, cache={}, bodies=bodies)
        W = res.delassus(J)
        assert np.abs(W - ref).max() <= 1e-12 * scale, np.abs(W - ref).max() / scale
        assert np.array_equal(W, W.T)
        labels = delassus.unknown_bodies(bodies, op.G)
        assert res.columns_solved == _counted(Jr, labels)
        assert 4 not in labels[np.unique(sp.csr_matrix(Jr).indices)]  # the far box has no contact
        rows = delassus.Resolvent(op, block=7, cache={}, touched=False)  # one system, per row of J
        assert np.abs(W - rows.delassus(J)).max() <= 1e-12 * scale
        lam = np.random.default_rng(1).normal(size=J.shape[0])
        want = Y @ lam
        want = op.G @ want if op.G is not None else want
        assert np.abs(res.apply(lam) - want).max() <= 1e-11 * np.abs(want).max()
        if op.G is not None:
            Gc = sp.csc_matrix(op.G)
            width = np.diff(Gc.indptr)
            seen["mixed"] |= bool(np.any(width == 1) and np.any(width > 1))

    assert frames_with_contact(sim, 40, check, want=3) == 3
    if reducer == "affine":
        assert seen["mixed"], "no frame with both elastic and affine unknowns"


def test_unknowns_of_reduced_frames_belong_to_the_body_of_their_rows():
    bodies = np.array([0, 0, 0, 1, 1, 1])
    G = sp.csr_matrix(np.array([[1, 0, 0], [0, 2, 0], [0, 1, 0], [0, 0, 1], [0, 0, 3], [0, 0, 1.0]]))
    assert delassus.unknown_bodies(bodies, G).tolist() == [0, 0, 1]
    assert delassus.unknown_bodies(bodies, None) is bodies
    G = sp.csr_matrix(np.array([[1, 0], [0, 0], [0, 0], [0, 0], [1, 0], [0, 1.0]]))  # a column on two bodies
    assert delassus.unknown_bodies(bodies, G) is None


def test_bodies_must_name_every_free_dof():
    A = _laplacian(6)
    solver = SuperLU()
    solver.factorize(A)
    for bad in (np.zeros(5, dtype=int), np.zeros(6)):
        with pytest.raises(ValueError, match="bodies"):
            delassus.Resolvent(Operator(solver, A), bodies=bad)


def test_several_bodies_with_an_iterative_frame_solver_are_solved_directly():
    """CG would solve the bodies' shared columns to one tolerance for all: with several bodies, an
    iterative frame's Delassus operator and apply come from one direct factorisation of A, kept in
    the cache (one entry)."""
    rng = np.random.default_rng(5)
    sizes = (45, 60)
    A = sp.block_diag([_spd(m, rng) for m in sizes], format="csr")
    solver = AMGCG(tol=1e-4)
    solver.factorize(A)
    n = A.shape[0]
    bodies = np.repeat(np.arange(2), sizes)
    J = _jacobian(_contacts_on([3, 9, 48, 51], rng, 2), n)
    cache = {}
    res = delassus.Resolvent(Operator(solver, A), cache=cache, bodies=bodies)
    W = res.delassus(J)
    dense = np.linalg.inv(A.toarray())
    ref = J @ dense @ J.T.toarray()
    assert np.abs(W - ref).max() <= 1e-12 * np.abs(ref).max()
    lam = rng.normal(size=J.shape[0])
    assert np.allclose(res.apply(lam), dense @ (J.T @ lam), rtol=1e-10, atol=1e-12)
    assert len(cache) == 1


def test_jacobian_equals_its_entries_summed():
    """J from the compiled rows against J assembled entry by entry by scipy (COO, duplicates summed): vertex
    contacts on triangles, collider contacts (the vertex itself at weight 0), edge-edge contacts (``own``),
    a triangle repeating a vertex, and fixed DOFs dropped; the same pattern and values, sorted."""
    from skfem_affine.contact.geometry import ContactSet
    rng = np.random.default_rng(3)
    n, k = 12, 9
    vertex = rng.integers(0, n, k)
    others = rng.integers(0, n, (k, 3))
    weights = rng.random((k, 3))
    others[:3], weights[:3] = vertex[:3, None], 0.0  # collider contacts
    others[3, 2] = others[3, 1]  # a repeated vertex: its two entries summed
    normal = rng.normal(size=(k, 3))
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    own = np.ones(k)
    own[-2:] = [0.3, 0.6]  # edge-edge contacts
    free = np.setdiff1d(np.arange(3 * n), [0, 1, 2, 17])  # vertex 0 fixed, one DOF of vertex 5
    for own_ in (None, own):
        cs = ContactSet(vertex, others, weights, normal, np.zeros(k), np.arange(k), own=own_)
        J = delassus.jacobian(cs, n, free)
        frames = cs.frames()
        w = np.column_stack([np.ones(k) if own_ is None else own_, -weights])
        verts = np.column_stack([vertex, others])
        dof = np.full(3 * n, -1)
        dof[free] = np.arange(free.size)
        r, c, v = [], [], []
        for i in range(k):
            for a in range(3):
                for q in range(4):
                    for d in range(3):
                        if dof[3 * verts[i, q] + d] >= 0 and w[i, q] * frames[i, a, d] != 0:
                            r.append(3 * i + a)
                            c.append(dof[3 * verts[i, q] + d])
                            v.append(w[i, q] * frames[i, a, d])
        ref = sp.csr_matrix((v, (r, c)), shape=(3 * k, free.size))
        ref.sum_duplicates()
        assert J.has_sorted_indices and np.array_equal(J.indptr, ref.indptr)
        assert np.array_equal(J.indices, ref.indices)
        assert np.abs(J.data - ref.data).max() <= 1e-15
