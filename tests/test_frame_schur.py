"""The full-space frame factorised with the contacts' unknowns last (Pardiso's Schur mode that also
solves): its dv against the plain factorisation's, Z and W against unit-column solves, a run against
the run without Schur complements, a resumed run, and the guards that keep MKL's memory intact."""
import numpy as np
import pytest
import scipy.sparse as sp

pytest.importorskip("pypardiso")

import skfem_affine as sa  # noqa: E402
from skfem_affine import solvers  # noqa: E402
from skfem_affine.contact import delassus  # noqa: E402
from skfem_affine.contact.schur import SchurInverse  # noqa: E402
from skfem_affine.integrators.problem import Operator  # noqa: E402
from skfem_affine.reducers.full import touched_unknowns  # noqa: E402
from skfem_affine.solvers import Pardiso, PardisoSchur  # noqa: E402

from test_delassus import frames_with_contact, plain_delassus  # noqa: E402
from test_schur import _spd  # noqa: E402
from resuming import resume_bit_identically  # noqa: E402


def _scene(name, **kw):
    sim = sa.scenes.SCENES[name](**kw)
    sim.contact.schur.min_size = 1  # these small scenes touch fewer unknowns than a new analysis needs
    return sim


def _spy_solves(sim):
    """Per frame solved by the full-space reducer: (A, b, dv, operator)."""
    reducer, seen = sim.integrator.reducer, []
    original = reducer.solve

    def spy(problem):
        result = original(problem)
        seen.append((problem.matrix(), problem.b, result.dv, result.operator))
        return result

    reducer.solve = spy
    return seen


def test_the_frame_factorised_with_the_contacts_unknowns_last_solves_as_the_plain_factorisation():
    sim = _scene("drop", resolution=1, shape="box")
    seen = _spy_solves(sim)
    list(sim.run(60))
    taken = [(A, b, dv, op) for A, b, dv, op in seen if op.schur is not None]
    assert taken, "no frame was factorised with its contacts' unknowns last"
    assert any(rec.get("frame_schur", 0) > 0 for rec in sim.stats)
    plain = Pardiso()
    for A, b, dv, op in taken[:4]:
        plain.factorize(A)
        ref = plain.solve(b)
        assert isinstance(op.solver, PardisoSchur)
        assert np.abs(dv - ref).max() <= 1e-12 * np.abs(ref).max()


def test_z_and_w_from_the_frames_own_complement_equal_the_unit_columns():
    sim = _scene("drop", resolution=1, shape="box")
    taken = []

    def check(op, J):
        if op.schur is None:
            return
        keep, S = op.schur
        T = touched_unknowns(J)
        pos = np.searchsorted(keep, T)
        Zref = op.solver.solve(np.eye(op.shape[0])[:, T])[T]  # unit columns, the same factorisation
        assert np.abs(np.linalg.inv(S)[np.ix_(pos, pos)] - Zref).max() <= 1e-12 * np.abs(Zref).max()
        ref = plain_delassus(op, J)[0]
        res = delassus.Resolvent(op, block=7, cache={}, bodies=sim.contact.bodies)
        W = res.delassus(J)
        assert np.abs(W - ref).max() <= 1e-12 * np.abs(ref).max()
        assert res.schur_unknowns == T.size and res.columns_solved == 0
        columns = delassus.Resolvent(Operator(op.solver, op.matrix), block=7, cache={}, bodies=sim.contact.bodies)
        assert np.abs(W - columns.delassus(J)).max() <= 1e-12 * np.abs(ref).max()
        taken.append(True)

    frames_with_contact(sim, 150, check, want=4)
    assert taken, "no frame took the frame's Schur complement"


@pytest.mark.parametrize("touched", [(0, 1, 2), (1,)])
def test_several_bodies_invert_their_blocks_of_the_frames_complement(touched):
    """A block diagonal (three bodies): W from each body's block of S equals the unit columns'."""
    sizes = (50, 61, 47)
    A = sp.block_diag([_spd(m, seed=m) for m in sizes], format="csr")
    bodies = np.repeat(np.arange(3), sizes)
    first = np.concatenate([[0], np.cumsum(sizes)])
    rng = np.random.default_rng(5)
    cols = np.sort(np.concatenate([first[b] + rng.choice(sizes[b], 12, replace=False) for b in touched]))
    J = sp.csr_matrix((rng.normal(size=80), (rng.integers(0, 24, 80), rng.choice(cols, 80))), shape=(24, A.shape[0]))
    solver, keep, S = SchurInverse(min_size=1).factorize_on(A, touched_unknowns(J))
    op = Operator(solver, A, schur=(keep, S))
    ref = plain_delassus(op, J)[0]
    res = delassus.Resolvent(op, block=7, cache={}, bodies=bodies)
    W = res.delassus(J)
    assert np.abs(W - ref).max() <= 1e-12 * np.abs(ref).max()
    assert res.schur_unknowns == keep.size and res.columns_solved == 0
    columns = delassus.Resolvent(Operator(solver, A), block=7, cache={}, bodies=bodies)
    assert np.abs(W - columns.delassus(J)).max() <= 1e-12 * np.abs(ref).max() and columns.columns_solved > 0


def test_contacts_on_several_bodies_never_take_one_complement_of_all_their_unknowns():
    """Pardiso's complement of several bodies' unknowns is one dense block: those frames are factorised body
    by body (each body's complement on its own, a list; tests/test_frame_blocks.py), never whole."""
    sim = _scene("stacked_beams", resolution=1)
    seen = _spy_solves(sim)
    list(sim.run(40))
    assert any(rec.get("n_contacts", 0) for rec in sim.stats)
    bodies = sim.contact.bodies
    whole = [op for *_, op in seen if op.schur is not None and not isinstance(op.schur[1], list)]
    assert all(bodies[op.schur[0]].min() == bodies[op.schur[0]].max() for op in whole)
    assert any(op.schur is not None and isinstance(op.schur[1], list) for *_, op in seen)


def test_a_contact_run_is_the_run_without_schur_complements_to_round_off():
    runs = []
    for schur in (True, False):
        sim = sa.scenes.SCENES["drop"](resolution=1, shape="box", contact=sa.PGS(schur=schur))
        if schur:
            sim.contact.schur.min_size = 1
        runs.append([s.x.copy() for s in sim.run(50)])
        assert schur == any(rec.get("frame_schur", 0) > 0 for rec in sim.stats)
    scale = np.abs(runs[1][0]).max()
    for xa, xb in zip(*runs):
        assert np.abs(xa - xb).max() <= 1e-9 * scale


def test_the_frame_setting_off_factorises_plainly():
    sim = _scene("drop", resolution=1, shape="box")
    sim.contact.schur.frame = False
    seen = _spy_solves(sim)
    list(sim.run(40))
    assert all(op.schur is None for *_, op in seen) and not any("frame_schur" in rec for rec in sim.stats)


def test_a_resumed_run_with_the_frames_complement_is_bit_identical(tmp_path):
    sim = _scene("drop", resolution=1, shape="box")
    list(sim.run(30))
    assert any(rec.get("frame_schur", 0) > 0 for rec in sim.stats)
    resumed = resume_bit_identically(sim, lambda: _scene("drop", resolution=1, shape="box"), tmp_path / "run.npz")
    assert any(rec.get("frame_schur", 0) > 0 for rec in list(resumed.stats)[-8:])


def test_the_frames_complement_declines_more_than_half_the_unknowns_or_too_few():
    A = _spd(40)
    schur = SchurInverse(min_size=5)
    assert schur.factorize_on(A, np.arange(21)) is None  # a set of every unknown wrote past MKL's buffer
    assert schur.factorize_on(A, np.arange(4)) is None
    solver, keep, S = schur.factorize_on(A, np.arange(3, 23, 2))
    b = np.arange(40.0)
    assert np.abs(A @ solver.solve(b) - b).max() <= 1e-12 * np.abs(b).max()
    with pytest.raises(ValueError, match="keep"):
        PardisoSchur(solves=True).complement(A, np.arange(21))


def test_only_the_solving_mode_solves():
    A = _spd(30)
    with pytest.raises(TypeError, match="factorisation first"):
        PardisoSchur(solves=True).solve(np.ones(30))
    plain = PardisoSchur()
    plain.complement(A, np.arange(5))
    with pytest.raises(TypeError, match="does not solve"):
        plain.solve(np.ones(30))


def test_the_frames_factorisation_and_solves_run_on_its_analysis_thread_count(monkeypatch):
    """An analysis on MKL's default count, then factorisations and solves asked for under one thread:
    each runs on the analysis' count (another count corrupted MKL's heap)."""
    from threadpoolctl import threadpool_limits
    monkeypatch.setattr(solvers, "PARDISO_THREADED_MIN", 1)
    A = _spd(200, seed=4)
    schur = SchurInverse(min_size=1)
    T = np.arange(10, 60)
    handle, keep, S = schur.factorize_on(A, T)
    count = handle._threads
    for scale in (1.0, 1.5, 2.0):
        with threadpool_limits(limits=1, user_api="blas"):
            handle2, keep, S = schur.factorize_on(A * scale, T)
            x = handle2.solve(np.ones(200))
        assert handle2 is handle and handle._threads == count and schur.analyses == 1
        assert np.abs((A * scale) @ x - 1).max() <= 1e-12
        Z = np.linalg.inv((A * scale).toarray())[np.ix_(T, T)]
        assert np.abs(np.linalg.inv(S) - Z).max() <= 1e-12 * np.abs(Z).max()


def test_the_solving_complement_keeps_the_cholesky_factor_of_s_and_solves_with_it():
    """Pardiso forms S without factorising it; LAPACK's factor of S finishes the solve (forward
    substitution, S's own solve, backward substitution), for one or several right-hand sides."""
    from skfem_affine.contact.schur import inverse_on_positions
    A = _spd(80, seed=3)
    keep = np.array([1, 4, 9, 17, 40, 41, 42, 70, 79])
    handle = PardisoSchur(solves=True)
    S = handle.complement(A, keep)
    L = handle.factor_of(S)
    assert np.abs(np.tril(L) @ np.tril(L).T - S).max() <= 1e-13 * np.abs(S).max()
    assert handle.factor_of(S.copy()) is None and PardisoSchur().factor_of(PardisoSchur().complement(A, keep)) is None
    B = np.random.default_rng(0).normal(size=(80, 3))
    ref = np.linalg.solve(A.toarray(), B)
    assert np.abs(handle.solve(B) - ref).max() <= 1e-12 * np.abs(ref).max()
    assert np.abs(handle.solve(B[:, 1]) - ref[:, 1]).max() <= 1e-12 * np.abs(ref).max()
    kept = L.copy()
    Z = inverse_on_positions(S, np.arange(keep.size), L)
    assert np.array_equal(L, kept)  # the handle's factor is left as it was
    assert np.array_equal(Z, inverse_on_positions(S, np.arange(keep.size)))
    assert np.abs(handle.solve(B) - ref).max() <= 1e-12 * np.abs(ref).max()


def test_a_complement_that_is_not_positive_definite_is_a_solver_error():
    A = _spd(40).tolil()
    A[5, 5] = -1e6
    with pytest.raises(solvers.SolverError):
        PardisoSchur(solves=True).complement(sp.csr_matrix(A), np.array([5, 6, 7]))
