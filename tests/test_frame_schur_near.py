"""The full-space frame's Schur complement on a predicted superset of the touched unknowns (the vertices a
collider may reach within a few frames): its analysis serves the frames after while a body lands, Z and W
from it equal the unit columns' and the plain factorisation's, runs match the run without prediction, and
a resumed run is bit for bit the saved one."""
import numpy as np
import pytest

pytest.importorskip("pypardiso")

import skfem_affine as sa  # noqa: E402
from skfem_affine.contact import delassus  # noqa: E402
from skfem_affine.contact.schur import SchurInverse, inverse_on_positions  # noqa: E402
from skfem_affine.integrators.problem import Operator  # noqa: E402
from skfem_affine.reducers.full import touched_unknowns  # noqa: E402
from skfem_affine.solvers import Pardiso, SolverError  # noqa: E402

from test_delassus import frames_with_contact, plain_delassus  # noqa: E402
from test_schur import _spd  # noqa: E402
from resuming import resume_bit_identically  # noqa: E402


def _ball(lookahead=4, spread=4.0):
    """A soft ball landing on a plane: its touched unknowns grow from 3 to 42 over four frames."""
    sim = sa.scenes.SCENES["drop"](resolution=2, shape="ball")
    sim.contact.schur.min_size = 1  # this small scene touches fewer unknowns than a new analysis needs
    sim.contact.schur.spread = spread
    sim.contact.detector.lookahead = lookahead
    return sim


def _analyses(sim, frames):
    """The new analyses of each frame with contacts, and the frames whose kept set was larger than T."""
    out, wider = [], 0
    for _ in range(frames):
        before = sim.contact.schur.analyses
        sim.step()
        cs = sim.contact.current
        if cs is not None:
            out.append(sim.contact.schur.analyses - before)
            wider += sim.stats[-1].get("frame_schur", 0) > touched_unknowns(cs.J).size
    return out, wider


def test_the_predicted_set_holds_the_touched_unknowns_and_more():
    sim = _ball()
    seen = []
    for _ in range(30):
        sim.step()
        cs = sim.contact.current
        if cs is not None:
            T = touched_unknowns(cs.J)
            assert np.isin(T, cs.near_unknowns).all() and np.all(np.diff(cs.near_unknowns) > 0)
            seen.append(cs.near_unknowns.size > T.size)
    assert any(seen)


def test_a_predicted_superset_is_analysed_once_for_the_landing_frames():
    """Landing, the touched unknowns change every frame inside the predicted set: one analysis serves them."""
    with_near, wider = _analyses(_ball(), 42)
    without, _ = _analyses(_ball(lookahead=None), 42)
    assert wider > 10
    assert sum(with_near) < sum(without)
    assert with_near[1:4] == [1, 0, 0] and without[1:4] == [1, 1, 1]


def test_z_and_w_from_the_superset_equal_the_unit_columns_and_the_plain_factorisation():
    sim = _ball()
    taken = []

    def check(op, J):
        if op.schur is None:
            return
        keep, S = op.schur
        T = touched_unknowns(J)
        plain = Pardiso()
        plain.factorize(op.matrix)
        Zref = plain.solve(np.eye(op.shape[0])[:, T])[T]
        Z = inverse_on_positions(S.copy(), np.searchsorted(keep, T))
        assert np.abs(Z - Zref).max() <= 1e-12 * np.abs(Zref).max()
        b = np.linspace(-1.0, 1.0, op.shape[0])
        assert np.abs(op.solver.solve(b) - plain.solve(b)).max() <= 1e-12 * np.abs(plain.solve(b)).max()
        ref = plain_delassus(op, J)[0]
        res = delassus.Resolvent(op, block=7, cache={}, bodies=sim.contact.bodies)
        W = res.delassus(J)
        assert np.abs(W - ref).max() <= 1e-12 * np.abs(ref).max()
        assert res.schur_unknowns == T.size and res.columns_solved == 0
        rows = delassus.Resolvent(Operator(plain, op.matrix), block=7, cache={}, touched=False)
        assert np.abs(W - rows.delassus(J)).max() <= 1e-12 * np.abs(ref).max()
        taken.append(keep.size > T.size)

    frames_with_contact(sim, 40, check, want=6)
    assert any(taken), "no frame took the complement on a superset of its touched unknowns"


def test_a_run_with_prediction_is_the_run_without_to_round_off():
    runs = [[s.x.copy() for s in sim.run(45)] for sim in (_ball(), _ball(lookahead=None))]
    scale = np.abs(runs[1][0]).max()
    for xa, xb in zip(*runs):
        assert np.abs(xa - xb).max() <= 1e-9 * scale


def test_a_resumed_run_on_a_predicted_superset_is_bit_identical(tmp_path):
    sim = _ball()
    list(sim.run(24))
    resumed = resume_bit_identically(sim, _ball, tmp_path / "run.npz", frames=6)
    cs = resumed.contact.current
    assert resumed.stats[-1].get("frame_schur", 0) > touched_unknowns(cs.J).size


def test_the_inverse_on_some_positions_of_s_is_the_inverse_of_its_complement_on_them():
    S = _spd(60).toarray()
    pos = np.sort(np.random.default_rng(3).choice(60, 23, replace=False))
    ref = np.linalg.inv(S)
    assert np.abs(inverse_on_positions(S.copy(), pos) - ref[np.ix_(pos, pos)]).max() <= 1e-12 * np.abs(ref).max()
    assert np.abs(inverse_on_positions(S.copy(), np.arange(60)) - ref).max() <= 1e-12 * np.abs(ref).max()


def test_the_predicted_set_must_hold_the_touched_unknowns_and_spread_is_checked():
    A = _spd(40)
    schur = SchurInverse(min_size=1)
    with pytest.raises(ValueError, match="near"):
        schur.factorize_on(A, np.array([1, 5, 9]), near=np.array([1, 5, 8, 12]))
    solver, keep, S = schur.factorize_on(A, np.array([1, 5, 9]), near=np.array([1, 2, 5, 9]))
    assert np.array_equal(keep, [1, 2, 5, 9])
    solver, keep, S = SchurInverse(min_size=1).factorize_on(A, np.array([1, 5, 9]), near=np.arange(0, 14))
    assert np.array_equal(keep, [1, 5, 9])  # more than ``spread`` times T: the touched unknowns alone
    with pytest.raises(ValueError, match="spread"):
        SchurInverse(spread=0.5)


def test_the_lookahead_is_checked():
    sim = _ball()
    for bad in (-1, float("nan"), "2"):
        with pytest.raises(ValueError, match="lookahead"):
            sim.contact.detector.lookahead = bad


@pytest.mark.parametrize("pos", [[0, 1, 2, 3], [1, 3]])
def test_an_indefinite_complement_is_a_solver_error(pos):
    # the whole of S inverted, and only part of it (the rest factorised first)
    S = np.diag([1.0, -2.0, 3.0, -4.0]) if len(pos) == 4 else np.diag([-1.0, 2.0, 3.0, 4.0])
    with pytest.raises(SolverError, match="not positive definite"):
        inverse_on_positions(S, np.array(pos))
