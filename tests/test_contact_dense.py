"""The Delassus operator's part on small body blocks from their dense Cholesky factors (an affine or rigid
body's reduced unknowns with its elastic vertices'), against the plain path of 3 solves per contact
row on the frame's factorisation: W, the PGS impulses and the velocity correction to round-off."""
import numpy as np
import pytest
import scipy.linalg
import scipy.sparse as sp

import skfem_affine as sa
from skfem_affine.contact import delassus, pgs
from skfem_affine.contact.dense import DENSE_MAX, DenseBlocks, used_unknowns
from skfem_affine.contact.pgs import projected_gauss_seidel
from skfem_affine.integrators.problem import Operator
from skfem_affine.lab.scenes import box_mesh
from skfem_affine.solvers import SolverError, SuperLU

from test_delassus import _box_on_plane, _mixed_pile, frames_with_contact, plain_delassus


def _stack(reducer):
    """A stiff box resting on the ground and a smaller one dropped on it, off centre (vertex contacts of
    the upper box on the lower one's top face, the lower box's bottom face on the ground)."""
    mat = sa.NeoHookean(E=1e8, nu=0.3)
    bodies = [sa.ElasticBody(box_mesh(0.2, 2, (0.0, 0.0, 0.1)), mat, density=1000.0),
              sa.ElasticBody(box_mesh(0.12, 2, (0.02, 0.01, 0.262)), mat, density=1000.0, velocity=(0.3, 0.0, -0.2))]
    return sa.Simulation(bodies, dt=0.01, gravity=(0.0, 0.0, -9.81), colliders=[sa.Plane()], reducer=reducer)


def _same_as_plain(op, J, bodies=None, dense=DENSE_MAX):
    """W, the PGS impulses of a sliding approach and dv = A^-1 J^T lambda from the dense blocks, against
    the plain path; returns the Resolvent."""
    ref, _, Y = plain_delassus(op, J)
    scale = np.abs(ref).max()
    res = delassus.Resolvent(op, cache={}, bodies=bodies, dense=dense)
    W = res.delassus(J)
    assert np.abs(W - ref).max() <= 1e-12 * scale, np.abs(W - ref).max() / scale
    assert np.array_equal(W, W.T)
    k = J.shape[0] // 3
    u0 = J @ np.tile([0.5, 0.0, -0.3], J.shape[1] // 3)  # sliding into the obstacles
    lam, lam_ref = np.zeros(3 * k), np.zeros(3 * k)
    projected_gauss_seidel(W, u0, lam, 0.5, 300, 1e-13)
    projected_gauss_seidel(ref, u0, lam_ref, 0.5, 300, 1e-13)
    assert np.abs(lam - lam_ref).max() <= 1e-8 * np.abs(lam_ref).max()
    lam = np.random.default_rng(4).normal(size=J.shape[0])
    want = Y @ lam
    want = op.G @ want if op.G is not None else want
    assert np.abs(res.apply(lam) - want).max() <= 1e-11 * np.abs(want).max()
    return res


@pytest.mark.parametrize("reducer", ["affine", "rigid"])
def test_a_moving_reduced_body_takes_w_from_its_block(reducer):
    """A box thrown onto the plane, one affine (rigid) body: its face of vertex contacts takes W from
    its 12 x 12 (6 x 6) block, no column solved, equal to the plain path's 3 solves per contact row."""
    reduced = sa.Affinification(tau_a=1.0, tau_e=2.0) if reducer == "affine" else sa.Rigidification(tau_r=10.0)
    sim = _box_on_plane(reduced)
    width = 12 if reducer == "affine" else 6

    def check(op, J):
        assert op.G.shape[1] == width and J.shape[0] // 3 >= 9
        res = _same_as_plain(op, J)
        assert res.dense_unknowns == width and res.columns_solved == 0 and res.schur_unknowns == 0

    assert frames_with_contact(sim, 30, check, want=2) == 2


def test_bodies_in_contact_take_w_from_their_blocks_in_the_run():
    """Two affine boxes, one landing on the other: the frame's contact takes W from the boxes' blocks
    (``delassus_dense``, no columns), each check equal to the plain path, and the run's positions equal
    those of the same run solving unit columns to the PGS tolerance."""
    sims = {d: _stack(sa.Affinification(tau_a=1.0, tau_e=2.0)) for d in (DENSE_MAX, 0)}
    bodies = sims[DENSE_MAX].contact.bodies
    checked = frames_with_contact(sims[DENSE_MAX], 12, lambda op, J: _same_as_plain(op, J, bodies), want=2)
    assert checked == 2
    for _ in range(20):
        sims[DENSE_MAX].step()
    frames = len(sims[DENSE_MAX].stats)
    try:
        pgs.DENSE_MAX = 0
        for _ in range(frames):
            sims[0].step()
    finally:
        pgs.DENSE_MAX = DENSE_MAX
    dense, columns = sims[DENSE_MAX].stats, sims[0].stats
    touching = [r for r in dense if r["n_contacts"]]
    assert touching and all(r["delassus_dense"] > 0 and r["delassus_columns"] == 0 for r in touching)
    assert any(r["delassus_columns"] > 0 for r in columns)
    # W differs by round-off, so a PGS stop or a block passed over may fall differently: the positions
    # agree to the PGS tolerance (of the contacts' velocities) over a step
    bound = sims[0].contact.settings.tolerance * max(r["contact_scale"] for r in touching) * sims[0].model.dt
    assert np.abs(sims[DENSE_MAX].state.x - sims[0].state.x).max() < bound


@pytest.mark.parametrize("reducer", [None, sa.Affinification(tau_a=1.0, tau_e=2.0)])
def test_dense_blocks_run_on_one_blas_thread(monkeypatch, reducer):
    """The blocks' Cholesky factors, triangular solves and Cholesky solves of a frame's contact run with
    every OpenBLAS (numpy's and scipy's) on one thread, whatever the thread count outside."""
    from threadpoolctl import ThreadpoolController, threadpool_limits

    openblas = ThreadpoolController().select(internal_api="openblas").lib_controllers  # numpy's and scipy's
    assert len(openblas) >= 1
    seen = []

    def spied(fn):
        def call(*args, **kwargs):
            seen.append((fn.__name__, max(lib.num_threads for lib in openblas)))
            return fn(*args, **kwargs)
        return call

    monkeypatch.setattr(scipy.linalg, "solve_triangular", spied(scipy.linalg.solve_triangular))
    monkeypatch.setattr(scipy.linalg, "cho_solve", spied(scipy.linalg.cho_solve))
    monkeypatch.setattr(np.linalg, "cholesky", spied(np.linalg.cholesky))
    sim = _stack(reducer)
    with threadpool_limits(limits=2, user_api="blas"):
        for _ in range(6):
            sim.step()
    assert sum(r["delassus_dense"] for r in sim.stats) > 0
    assert {name for name, _ in seen} >= {"solve_triangular", "cho_solve", "cholesky"}
    assert all(count == 1 for _, count in seen), seen


@pytest.mark.parametrize("reducer, largest", [("full", 60), ("affine", 40)])
def test_small_and_large_blocks_in_one_frame(reducer, largest):
    """The mixed pile (affine and elastic boxes, a pinned one, one far off) with the blocks of at most
    ``largest`` unknowns dense (in full space the pinned box's 54): the small blocks from their factors,
    the others' columns solved, W and dv as the plain path."""
    sim = _mixed_pile(None if reducer == "full" else sa.Affinification(tau_a=0.1, tau_e=0.2))
    if sim.contact.schur is not None:
        sim.contact.schur.frame = False
    bodies, seen = sim.contact.bodies, {"both": False}

    def check(op, J):
        res = _same_as_plain(op, J, bodies, dense=largest)
        seen["both"] |= res.dense_unknowns > 0 and res.columns_solved > 0

    frames_with_contact(sim, 40, check, want=3)
    assert seen["both"]


def test_one_block_in_full_space():
    """One small body in full space (no body labels): its whole block from its factor."""
    sim = _box_on_plane(None, colliders=2)

    def check(op, J):
        res = _same_as_plain(op, J, dense=1000)
        assert res.dense_unknowns == np.unique(sp.csr_matrix(J).indices).size and res.columns_solved == 0

    assert frames_with_contact(sim, 30, check, want=1) == 1


def test_an_indefinite_block_is_a_solver_error():
    A = sp.csr_matrix(np.diag([2.0, 1.0, -1.0, 3.0]))
    solver = SuperLU()
    solver.factorize(sp.identity(4, format="csr"))
    blocks = DenseBlocks(Operator(solver, A), np.array([0, 0, 1, 1]), used_unknowns(None, 4), largest=2)
    J = sp.csr_matrix(np.eye(4)[[2]])
    with pytest.raises(SolverError, match="block 1"):
        blocks.parts(J, None)
    assert blocks.in_small().all()
    assert not DenseBlocks(Operator(solver, A), None, used_unknowns(None, 4), largest=3).in_small().any()


def test_a_frame_with_its_own_schur_complement_takes_no_dense_blocks():
    """Full space, the frame factorised with the touched unknowns last: their complement is there
    already, and W comes from it, not from dense factors of the (small) body's block."""
    pytest.importorskip("pypardiso")
    sim = sa.scenes.drop(resolution=1, shape="box")
    sim.contact.schur.min_size = 1  # this small scene touches fewer unknowns than a new analysis needs
    for _ in sim.run(40):
        pass
    touching = [r for r in sim.stats if r["n_contacts"]]
    assert touching and all(r["delassus_dense"] == 0 for r in touching)
    assert any(r["delassus_schur"] > 0 for r in touching)


def _random_frame(rng, upper):
    """Three bodies' SPD blocks (sizes 5, 7, 4) in one system given whole or by its upper triangle, a G of
    12 free DOFs onto its 16 unknowns (body of each row) and a J of 4 rows on the free DOFs."""
    sizes, blocks = [5, 7, 4], []
    for m in sizes:
        M = rng.normal(size=(m, m))
        blocks.append(M @ M.T + m * np.eye(m))
    A = sp.block_diag(blocks, format="csr")
    bodies = np.repeat([0, 1, 2], 4)  # 4 free DOFs per body
    start = np.cumsum([0] + sizes)
    rows, cols = [], []
    for b in range(3):
        for i in range(4):
            for c in start[b] + (3 * i + np.arange(3)) % sizes[b]:  # every unknown of the body used
                rows.append(4 * b + i)
                cols.append(c)
    G = sp.csr_matrix((rng.normal(size=len(rows)), (rows, cols)), shape=(12, 16))
    J = sp.csr_matrix(rng.normal(size=(4, 12)) * (rng.random((4, 12)) < 0.4))
    stored = sp.triu(A, format="csr") if upper else A
    return A, stored, G, J, bodies


@pytest.mark.parametrize("upper", [False, True])
def test_dense_parts_equal_the_sparse_products_bitwise(upper):
    """The compiled gathers give what scipy does: the blocks' rows of Jr = J G (the same sums), their
    entries of A (given whole or by its upper triangle), W's parts C C^T = Jb A_b^-1 Jb^T, and the
    velocity correction A^-1 Jr^T lam equal to scipy's ``Jr.T @ lam`` and a Cholesky solve, bit for bit."""
    rng = np.random.default_rng(7)
    A, stored, G, J, bodies = _random_frame(rng, upper)
    solver = SuperLU()
    solver.factorize(A)
    op = Operator(solver, stored, G, upper=upper)
    labels = delassus.unknown_bodies(bodies, G)
    blocks = DenseBlocks(op, labels, used_unknowns(G, 16), largest=6)  # bodies 0 and 2 small, 1 not
    parts, touched = blocks.parts(J, G)
    Jr = (J @ G).tocsr()
    T = np.unique(Jr.indices[Jr.data != 0])
    assert np.array_equal(touched, np.unique(labels[T][labels[T] != 1]))
    assert blocks.rest == bool(np.any(labels[T] == 1)) and blocks.touched == np.count_nonzero(labels[T] != 1)
    assert blocks.rest and touched.size == 2  # this J reaches all three bodies
    lam = rng.normal(size=4)
    y = blocks.apply(lam, np.zeros(16))
    r = Jr.T @ lam
    for (rows, C), b in zip(parts, touched):
        idx, L = blocks.factors[b]
        assert np.array_equal(idx, np.flatnonzero(labels == b))
        assert np.array_equal(L, np.linalg.cholesky(A[idx][:, idx].toarray()))
        Jb = Jr[:, idx].toarray()
        assert np.array_equal(rows, np.flatnonzero(np.abs(Jb).sum(axis=1)))
        Ct = scipy.linalg.solve_triangular(L, Jb[rows].T, lower=True)
        assert np.array_equal(C, Ct.T)
        assert np.array_equal(y[idx], scipy.linalg.cho_solve((L, True), r[idx]))
        ref = Jb @ np.linalg.solve(A[idx][:, idx].toarray(), Jb.T)
        assert np.abs(C @ C.T - ref[np.ix_(rows, rows)]).max() <= 1e-12 * np.abs(ref).max()


def test_unknown_bodies_of_a_mapping():
    """The body of each unknown through G (-1 for an empty column), None when a column spans two bodies."""
    G = sp.csr_matrix(np.array([[1.0, 0, 2, 0], [0, 0, 3, 0], [0, 4, 0, 0]]))
    assert np.array_equal(delassus.unknown_bodies(np.array([0, 0, 1]), G), [0, 1, 0, -1])
    assert delassus.unknown_bodies(np.array([0, 1, 1]), G) is None
    assert np.array_equal(delassus.unknown_bodies(np.array([3, 3, 5]), G.tocsc()), [3, 5, 3, -1])
