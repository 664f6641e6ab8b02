"""A reduced frame whose contacts touch several bodies, factorised body by body with each body's touched
reduced unknowns last: its solves and W against the plain factorisation and its unit columns, a body
declined, a run against the run with the route off, and a resumed run."""
import numpy as np
import pytest
import scipy.sparse as sp

pytest.importorskip("pypardiso")

import skfem_affine as sa  # noqa: E402
from skfem_affine.contact import delassus  # noqa: E402
from skfem_affine.contact.schur import SchurInverse  # noqa: E402
from skfem_affine.integrators.problem import Operator  # noqa: E402
from skfem_affine.reducers.affine.blocks import BodyBlocks  # noqa: E402
from skfem_affine.solvers import Pardiso, PardisoSchur  # noqa: E402

from resuming import resume_bit_identically  # noqa: E402
from test_delassus import plain_delassus  # noqa: E402
from test_schur import _spd  # noqa: E402


def _pills(route=True, frames=0, tau=1.0):
    """Three coarse pills in the bowl, affine from the first frame, touching the bowl and each other from
    about frame 24 (at ``tau`` = 0.3 partly elastic from about frame 28); ``route``: the frames
    factorised body by body with their touched unknowns last."""
    sim = sa.scenes.pills(n=3, resolution=1, reducer=sa.Affinification(tau_a=tau, tau_e=2.0 * tau))
    sim.contact.schur.min_size = 1
    sim.contact.schur.blocks = route
    for _ in range(frames):
        sim.step()
    return sim


def _scattered(seed=3):
    """An upper triangle of three bodies' blocks whose unknowns interleave (as a reduced frame's in the
    full numbering: a body's free DOFs, then the bodies' columns after every free DOF), their labels,
    and contacts' unknowns: a few of bodies 0 and 2, more than half of body 1's (its complement is
    declined)."""
    sizes = (30, 24, 36)
    A = sp.block_diag([_spd(m, seed=m) for m in sizes], format="csr")
    labels = np.repeat(np.arange(3), sizes)
    perm = np.random.default_rng(seed).permutation(labels.size)  # scatter the bodies' unknowns
    P = sp.csr_matrix((np.ones(labels.size), (perm, np.arange(labels.size))))
    A = sp.csr_matrix(P @ A @ P.T)
    labels = labels[np.argsort(perm)]
    U = sp.triu(A, format="csr")
    U.sort_indices()
    T = np.sort(np.concatenate([np.flatnonzero(labels == 0)[::3], np.flatnonzero(labels == 2)[1::4],
                                np.flatnonzero(labels == 1)[:13]]))
    return A, U, labels, T


def test_body_blocks_with_the_touched_unknowns_last_solve_and_give_z():
    A, U, labels, T = _scattered()
    order = np.arange(A.shape[0], dtype=np.int32)
    blocks, schur = BodyBlocks(), SchurInverse(min_size=100)
    plain = Pardiso()
    plain.factorize(A)
    b = np.random.default_rng(1).normal(size=(A.shape[0], 2))
    ref = plain.solve(b)
    Ainv = np.linalg.inv(A.toarray())
    for frame in range(2):  # a new pattern is taken below min_size, and its analysis then kept
        blocks.factorize(U * (1 + frame), labels, order, touched=T, schur=schur)
        assert blocks.analyses == (3 if frame == 0 else 0)
        keep, S = blocks.complements
        assert len(S) == 2 and set(labels[keep]) == {0, 2}  # body 1: more than half its unknowns, declined
        kinds = [type(handle) for handle, _ in blocks.blocks]
        assert kinds == [PardisoSchur, Pardiso, PardisoSchur]
        assert np.abs(blocks.solve(b) - ref / (1 + frame)).max() <= 1e-12 * np.abs(ref).max()
        ends = np.cumsum([Sb.shape[0] for Sb in S])
        for Sb, e in zip(S, ends):
            kb = keep[e - Sb.shape[0]:e]
            assert np.all(np.diff(kb) > 0) and np.unique(labels[kb]).size == 1
            assert np.array_equal(kb, T[labels[T] == labels[kb[0]]])
            Z = np.linalg.inv(Sb) * (1 + frame)
            assert np.abs(Z - Ainv[np.ix_(kb, kb)]).max() <= 1e-12 * np.abs(Ainv).max()
    blocks.factorize(U, labels, order)  # no contacts given: plain blocks, no complements
    assert blocks.complements is None and blocks.analyses == 2


def test_a_body_block_whose_pattern_its_handle_knows_keeps_min_size():
    A, U, labels, T = _scattered()
    order = np.arange(A.shape[0], dtype=np.int32)
    blocks = BodyBlocks()
    blocks.factorize(U, labels, order)  # plain: the handles know the patterns
    blocks.factorize(U, labels, order, touched=T, schur=SchurInverse(min_size=100))
    assert blocks.complements is None and blocks.analyses == 0
    blocks.factorize(U, labels, order, touched=T, schur=SchurInverse(min_size=5))
    assert len(blocks.complements[1]) == 2


def test_w_from_the_bodies_complements_equals_the_plain_path_and_the_unit_columns():
    """Scattered bodies' complements in the Operator: W and the applied impulses as with the plain
    factorisation, body 1 (declined) from its unit columns, solved on its own block only."""
    A, U, labels, T = _scattered()
    blocks = BodyBlocks()
    blocks.factorize(U, labels, np.arange(A.shape[0], dtype=np.int32), touched=T, schur=SchurInverse())
    rng = np.random.default_rng(2)
    rows, cols = np.concatenate([rng.integers(0, 30, 90), np.arange(T.size) % 30]), np.concatenate([rng.choice(T, 90), T])
    J = sp.csr_matrix((rng.normal(size=rows.size), (rows, cols)), shape=(30, A.shape[0]))  # every T touched
    G = sp.identity(A.shape[0], format="csr")  # the labels are those of G's rows: bodies = labels
    plain = Pardiso()
    plain.factorize(A)
    want = plain_delassus(Operator(plain, A, G), J)[0]
    res = delassus.Resolvent(Operator(blocks, A, G, schur=blocks.complements), block=4, cache={}, bodies=labels)
    W = res.delassus(J)
    assert np.abs(W - want).max() <= 1e-12 * np.abs(want).max()
    assert res.schur_unknowns == blocks.complements[0].size and 0 < res.columns_solved <= 13
    lam = rng.normal(size=J.shape[0])
    ref = plain.solve(J.T @ lam)
    assert np.abs(res.apply(lam) - ref).max() <= 1e-12 * np.abs(ref).max()


def _check_frames(sim, frames, want=3):
    """In reduced frames whose contacts' complements came from the bodies' blocks: the frame's solves and
    W against a plain factorisation of A_r, while its factorisation holds. Returns the frames checked."""
    reducer, contact, seen, checked = sim.integrator.reducer, sim.contact, [], []
    solve, resolve = reducer.solve, contact.resolve

    def spy_solve(problem):
        result = solve(problem)
        seen.append((problem, result))
        return result

    def spy_resolve(problem, result, rec):
        op, cs = result.operator, contact.current
        if cs is not None and op.G is not None and isinstance(op.solver, BodyBlocks) and op.schur is not None:
            plain = Pardiso()
            plain.factorize(op.matrix)
            y = np.random.default_rng(len(checked)).normal(size=op.shape[0])
            ref = plain.solve(y)
            assert np.abs(op.solver.solve(y) - ref).max() <= 1e-10 * np.abs(ref).max()
            want = plain_delassus(Operator(plain, op.matrix, op.G), cs.J)[0]
            W = delassus.Resolvent(op, cache={}, bodies=contact.bodies).delassus(cs.J)
            assert np.abs(W - want).max() <= 1e-10 * np.abs(want).max()
            checked.append(len(op.schur[1]))
        return resolve(problem, result, rec)

    reducer.solve, contact.resolve = spy_solve, spy_resolve
    for _ in sim.run(frames):
        if len(checked) >= want:
            break
    return checked


def test_the_pills_reduced_frames_factorised_body_by_body_solve_and_give_w_as_the_plain_factorisation():
    checked = _check_frames(_pills(frames=30, tau=0.3), 20)
    assert checked and max(checked) >= 2, "no reduced frame took several bodies' complements"


def test_an_affinified_run_with_the_bodies_complements_is_the_run_without_them_to_round_off():
    a, b = _pills(route=True, tau=0.3), _pills(route=False, tau=0.3)
    for _ in range(42):
        a.step()
        b.step()
    assert any(r.get("frame_schur", 0) > 0 and "blocks_analysed" in r for r in a.stats)
    assert not any(r.get("frame_schur", 0) > 0 and "blocks_analysed" in r for r in b.stats)
    assert np.abs(a.state.x - b.state.x).max() <= 1e-9 * a.size


def test_a_resumed_run_with_the_bodies_complements_is_bit_identical(tmp_path):
    sim = _pills(frames=36, tau=0.3)
    assert any(r.get("frame_schur", 0) > 0 and "blocks_analysed" in r for r in sim.stats)
    resumed = resume_bit_identically(sim, lambda: _pills(tau=0.3), tmp_path / "pills.npz", frames=6)
    assert any(r.get("frame_schur", 0) > 0 and "blocks_analysed" in r for r in list(resumed.stats)[-6:])


def _island(m=12, idle=200, seed=0):
    """An SPD block of ``m`` coupled unknowns among ``idle`` isolated ones (an affine body's 12 columns in
    its scene body's block of idle unknowns), upper triangle, and the coupled unknowns."""
    rng = np.random.default_rng(seed)
    B = rng.normal(size=(m, m))
    pos = np.sort(rng.choice(m + idle, m, replace=False))
    A = sp.lil_matrix((m + idle, m + idle))
    A.setdiag(1.0 + rng.random(m + idle))
    A[np.ix_(pos, pos)] = B @ B.T + m * np.eye(m)
    U = sp.triu(sp.csr_matrix(A), format="csr")
    U.sort_indices()
    return U, pos


def test_a_schur_set_of_every_coupled_unknown_is_refused():
    """Pardiso corrupted memory (segfaults in about half the runs of 400 calls) on a Schur set holding every
    coupled unknown beside isolated ones, as on a set of all the unknowns: such sets are refused, and
    declined by the Schur inverse and the bodies' blocks (the body factorised plainly, its columns solved)."""
    from skfem_affine.solvers import schur_set_fits
    U, pos = _island()
    W = sp.csr_matrix(U + sp.triu(U, 1).T)
    for P in (U, W):
        assert not schur_set_fits(P.indptr, P.indices, 12) and schur_set_fits(P.indptr, P.indices, 6)
    assert not schur_set_fits(U.indptr, U.indices, 107) and schur_set_fits(U.indptr, U.indices, 1)
    with pytest.raises(ValueError, match="coupled"):
        PardisoSchur(solves=True).complement(U, pos, upper=True)
    half = PardisoSchur(solves=True).complement(U, pos[:6], upper=True)
    Ainv = np.linalg.inv(W.toarray())
    assert np.abs(np.linalg.inv(half) - Ainv[np.ix_(pos[:6], pos[:6])]).max() <= 1e-12 * np.abs(Ainv).max()
    schur = SchurInverse(min_size=1)
    assert schur.complement_block(U, pos, (0, 0), floor=False) is None
    assert schur.inverse_on(U, pos, upper=True) is None
    labels = np.zeros(U.shape[0], dtype=np.int64)
    blocks = BodyBlocks()
    blocks.factorize(U, labels, np.arange(U.shape[0], dtype=np.int32), touched=pos, schur=schur)
    assert blocks.complements is None and type(blocks.blocks[0][0]) is Pardiso


def test_idle_unknowns_are_solved_by_their_diagonal_and_left_out_of_the_blocks():
    """Unknowns whose row and column hold the diagonal alone (a reduced vertex's, idle in the full
    numbering) are not given to a body's handle: the blocks hold only the coupled unknowns and the
    touched ones, and the solve equals the plain factorisation's; a non-positive idle diagonal is a
    SolverError."""
    from skfem_affine.solvers import coupled_unknowns
    from skfem_affine.solvers import SolverError
    A, _, labels, T = _scattered()
    rng = np.random.default_rng(5)
    idle = np.sort(rng.choice(A.shape[0], 20, replace=False))
    A = sp.lil_matrix(A)
    A[idle, :] = 0.0
    A[:, idle] = 0.0
    A[idle, idle] = rng.uniform(1.0, 3.0, idle.size)
    A = sp.csr_matrix(A)
    U = sp.triu(A, format="csr")
    U.sort_indices()
    assert np.array_equal(np.flatnonzero(~coupled_unknowns(U.indptr, U.indices)), idle)
    touched = np.union1d(T, idle[:3])  # a touched idle unknown stays in its body's block
    order = np.arange(A.shape[0], dtype=np.int32)
    plain = Pardiso()
    plain.factorize(A)
    b = rng.normal(size=A.shape[0])
    for args in ((), (touched, SchurInverse(min_size=1))):
        blocks = BodyBlocks()
        blocks.factorize(U, labels, order, *args)
        held = np.concatenate([idx for _, idx in blocks.blocks])
        left_out = np.setdiff1d(idle, args[0] if args else [])
        assert np.intersect1d(held, left_out).size == 0 and held.size + left_out.size == A.shape[0]
        assert np.abs(blocks.solve(b) - plain.solve(b)).max() <= 1e-12 * np.abs(plain.solve(b)).max()
    A = sp.lil_matrix(A)
    A[idle[5], idle[5]] = 0.0
    with pytest.raises(SolverError, match="positive definite"):
        BodyBlocks().factorize(sp.triu(sp.csr_matrix(A), format="csr"), labels, order)
