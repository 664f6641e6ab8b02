"""A full-space frame whose contacts touch several bodies, factorised body by body with each body's touched
unknowns last: its solves and W against the plain factorisation and unit columns, a body declined, the
patterns refused, a contact run against the run without Schur complements, and a resumed run."""
import numpy as np
import pytest
import scipy.sparse as sp

pytest.importorskip("pypardiso")

import skfem_affine as sa  # noqa: E402
from skfem_affine.contact import delassus  # noqa: E402
from skfem_affine.contact.blocks import BlockSolver, body_bounds  # noqa: E402
from skfem_affine.contact.schur import SchurInverse  # noqa: E402
from skfem_affine.integrators.problem import Operator  # noqa: E402
from skfem_affine.reducers.full import touched_unknowns  # noqa: E402
from skfem_affine.solvers import Pardiso, PardisoSchur  # noqa: E402

from resuming import resume_bit_identically  # noqa: E402
from test_delassus import plain_delassus  # noqa: E402
from test_schur import _spd  # noqa: E402

SIZES = (50, 61, 47)


def _system(touched=(0, 1, 2), per_body=12, seed=5):
    A = sp.block_diag([_spd(m, seed=m) for m in SIZES], format="csr")
    bodies = np.repeat(np.arange(3), SIZES)
    first = np.concatenate([[0], np.cumsum(SIZES)])
    rng = np.random.default_rng(seed)
    cols = np.sort(np.concatenate([first[b] + rng.choice(SIZES[b], per_body, replace=False) for b in touched]))
    J = sp.csr_matrix((rng.normal(size=90), (rng.integers(0, 27, 90), rng.choice(cols, 90))), shape=(27, A.shape[0]))
    return A, J, bodies


def test_blocks_solve_as_the_plain_factorisation_and_give_the_unit_columns_w():
    A, J, bodies = _system()
    T = touched_unknowns(J)
    solver, keep, S = SchurInverse(min_size=1).factorize_blocks(A, T, bodies)
    assert isinstance(solver, BlockSolver) and isinstance(S, list) and len(S) == 3
    assert np.array_equal(keep, T) and sum(Sb.shape[0] for Sb in S) == T.size
    plain = Pardiso()
    plain.factorize(A)
    b = np.random.default_rng(1).normal(size=(A.shape[0], 3))
    ref = plain.solve(b)
    assert np.abs(solver.solve(b) - ref).max() <= 1e-12 * np.abs(ref).max()
    assert np.abs(solver.solve(b[:, 0]) - ref[:, 0]).max() <= 1e-12 * np.abs(ref).max()
    op = Operator(solver, A, schur=(keep, S))
    want = plain_delassus(Operator(plain, A), J)[0]
    res = delassus.Resolvent(op, block=5, cache={}, bodies=bodies)
    W = res.delassus(J)
    assert np.abs(W - want).max() <= 1e-12 * np.abs(want).max()
    assert res.schur_unknowns == T.size and res.columns_solved == 0
    columns = delassus.Resolvent(Operator(plain, A), block=5, cache={}, bodies=bodies)
    assert np.abs(W - columns.delassus(J)).max() <= 1e-12 * np.abs(want).max() and columns.columns_solved > 0
    lam = np.random.default_rng(2).normal(size=J.shape[0])
    assert np.allclose(res.apply(lam), plain.solve(J.T @ lam), rtol=0, atol=1e-12 * np.abs(want).max())


def test_a_declined_body_is_factorised_plainly_and_its_columns_solved():
    """Body 1 touches 4 unknowns, below min_size: its block is factorised plainly, its Z from its unit
    columns with the frame's solver; body 2 has no contact."""
    A, J, bodies = _system(touched=(0,), per_body=12)
    extra = sp.csr_matrix((np.ones(4), (np.arange(20, 24), 50 + np.array([3, 9, 20, 40]))), shape=J.shape)
    J = sp.csr_matrix(J + extra)
    T = touched_unknowns(J)
    solver, keep, S = SchurInverse(min_size=10).factorize_blocks(A, T, bodies)
    assert np.array_equal(keep, T[T < 50]) and len(S) == 1
    assert isinstance(solver.handles[0], PardisoSchur) and type(solver.handles[1]) is Pardiso
    op = Operator(solver, A, schur=(keep, S))
    plain = Pardiso()
    plain.factorize(A)
    want = plain_delassus(Operator(plain, A), J)[0]
    res = delassus.Resolvent(op, block=5, cache={}, schur=SchurInverse(min_size=1), bodies=bodies)
    W = res.delassus(J)
    assert np.abs(W - want).max() <= 1e-12 * np.abs(want).max()
    assert res.schur_unknowns == keep.size and res.columns_solved == 4  # no complement of its own for body 1


def test_no_block_taken_coupled_blocks_or_scattered_bodies_are_declined():
    A, J, bodies = _system()
    T = touched_unknowns(J)
    assert SchurInverse(min_size=100).factorize_blocks(A, T, bodies) is None  # every block declines
    coupled = sp.lil_matrix(A)
    coupled[3, 60] = coupled[60, 3] = 0.1
    assert SchurInverse(min_size=1).factorize_blocks(sp.csr_matrix(coupled), T, bodies) is None
    scattered = bodies.copy()
    scattered[[0, 60]] = scattered[[60, 0]]
    assert SchurInverse(min_size=1).factorize_blocks(A, T, scattered) is None
    assert body_bounds(np.array([0, 0, 1, 1, 1])).tolist() == [0, 2, 5] and body_bounds(np.array([1, 0])) is None


def _beams(**kw):
    sim = sa.scenes.SCENES["stacked_beams"](resolution=1, **kw)
    if sim.contact.schur is not None:
        sim.contact.schur.min_size = 1  # these small beams touch fewer unknowns than a new analysis needs
    return sim


def test_the_beams_frames_factorised_body_by_body_solve_and_give_w_as_the_plain_factorisation():
    """Checked in each frame while the bodies' handles hold its factorisation."""
    sim = _beams()
    reducer, contact, seen, checked = sim.integrator.reducer, sim.contact, [], []
    solve, resolve = reducer.solve, contact.resolve

    def spy_solve(problem):
        result = solve(problem)
        seen.append((problem.matrix(), problem.b, result.dv))
        return result

    def spy_resolve(problem, result, rec):
        op, cs = result.operator, contact.current
        if cs is not None and op.schur is not None and isinstance(op.schur[1], list):
            A, b, dv = seen[-1]
            plain = Pardiso()
            plain.factorize(A)
            ref = plain.solve(b)
            assert np.abs(dv - ref).max() <= 1e-12 * np.abs(ref).max()
            want = plain_delassus(Operator(plain, A), cs.J)[0]
            W = delassus.Resolvent(op, cache={}, bodies=contact.bodies).delassus(cs.J)
            assert np.abs(W - want).max() <= 1e-12 * np.abs(want).max()
            checked.append(len(op.schur[1]))
        return resolve(problem, result, rec)

    reducer.solve, contact.resolve = spy_solve, spy_resolve
    list(sim.run(40))
    assert checked, "no frame was factorised body by body"


def test_a_run_factorised_body_by_body_is_the_run_without_schur_complements_to_round_off():
    runs = []
    for schur in (True, False):
        sim = _beams(contact=sa.PGS(schur=schur))
        runs.append([s.x.copy() for s in sim.run(40)])
        assert schur == any(rec.get("frame_schur", 0) > 0 for rec in sim.stats)
    scale = np.abs(runs[1][0]).max()
    for xa, xb in zip(*runs):
        assert np.abs(xa - xb).max() <= 1e-9 * scale


def test_a_resumed_run_factorised_body_by_body_is_bit_identical(tmp_path):
    sim = _beams()
    list(sim.run(30))
    assert any(rec.get("frame_schur", 0) > 0 for rec in sim.stats)
    resumed = resume_bit_identically(sim, _beams, tmp_path / "run.npz")
    assert any(rec.get("frame_schur", 0) > 0 for rec in list(resumed.stats)[-8:])


def test_the_blocks_setting_off_factorises_several_bodies_plainly():
    sim = _beams()
    sim.contact.schur.blocks = False
    ops = []
    resolve = sim.contact.resolve

    def spy(problem, result, rec):
        ops.append(result.operator)
        return resolve(problem, result, rec)

    sim.contact.resolve = spy
    list(sim.run(30))
    assert ops and not any(op.schur is not None and isinstance(op.schur[1], list) for op in ops)
    with pytest.raises(TypeError, match="blocks"):
        SchurInverse(blocks="yes")


def test_the_blocks_handles_stay_bounded_and_still_solve():
    """More blocks than ``systems``: the caches keep at most that many handles; the frame's solver keeps
    its own until the frame is done, so its solves stay right."""
    A, J, bodies = _system(touched=(0, 1, 2))
    T = touched_unknowns(J)
    schur = SchurInverse(min_size=1, systems=1)
    plain = Pardiso()
    plain.factorize(A)
    b = np.random.default_rng(3).normal(size=A.shape[0])
    for scale in (1.0, 2.0, 3.0):
        solver, keep, S = schur.factorize_blocks(A * scale, T, bodies)
        assert len(schur._kept_by) <= 1 and len(schur._plain_by) <= 1
        assert np.abs(solver.solve(b) - plain.solve(b) / scale).max() <= 1e-12 * np.abs(plain.solve(b)).max()


def test_the_delassus_operator_inverts_each_bodys_complement_from_the_factor_its_handle_made(monkeypatch):
    """No second Cholesky factorisation of a body's complement: the handle's factor is handed to the
    inverse, left unchanged (the handle still solves with it), and W is the one from a factorisation of S."""
    from skfem_affine.contact import schur as schur_module
    A, J, bodies = _system()
    T = touched_unknowns(J)
    solver, keep, S = SchurInverse(min_size=1).factorize_blocks(A, T, bodies)
    factors = [h.factor_of(Sb) for h, Sb in zip(solver.handles, S)]
    assert all(L is not None for L in factors)
    kept = [L.copy() for L in factors]
    given = []

    def spy(S_b, pos, factor=None):
        given.append(factor is not None and any(factor is L for L in factors))
        return schur_module.inverse_on_positions(S_b, pos, factor)

    monkeypatch.setattr(delassus, "inverse_on_positions", spy)
    op = Operator(solver, A, schur=(keep, S))
    W = delassus.Resolvent(op, block=5, cache={}, bodies=bodies).delassus(J)
    assert given == [True] * 3
    assert all(np.array_equal(L, k) for L, k in zip(factors, kept))
    monkeypatch.undo()
    for h in solver.handles:  # without the factors: LAPACK factorises each S_b again
        h._complemented = None
    again = delassus.Resolvent(op, block=5, cache={}, bodies=bodies).delassus(J)
    assert np.array_equal(W, again)
