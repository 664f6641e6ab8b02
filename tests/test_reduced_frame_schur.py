"""A reduced frame (affinification, rigidification) factorised with the reduced unknowns its contacts
touch last: its dq against the plain factorisation's, W against unit-column solves, a run against the
run with the route off, and contacts on several bodies declining."""
import numpy as np
import pytest

pytest.importorskip("pypardiso")

import skfem_affine as sa  # noqa: E402
from skfem_affine.contact import delassus  # noqa: E402
from skfem_affine.integrators.problem import Operator  # noqa: E402
from skfem_affine.reducers.full import touched_unknowns  # noqa: E402
from skfem_affine.solvers import Pardiso, PardisoSchur  # noqa: E402

from test_delassus import REDUCERS, plain_delassus  # noqa: E402
from resuming import resume_bit_identically  # noqa: E402


def _scene(reducer, name="drop", **kw):
    kw = kw or dict(resolution=1, shape="box")
    sim = sa.scenes.SCENES[name](**kw, reducer=REDUCERS[reducer]())
    sim.contact.schur.min_size = 1  # these small scenes touch fewer unknowns than a new analysis needs
    return sim


def _spy_solves(sim, check=None):
    """The reducer's results, frame by frame; ``check(result)`` called while its factorisation holds."""
    reducer, seen = sim.integrator.reducer, []
    original = reducer.solve

    def spy(problem):
        result = original(problem)
        if check is not None:
            check(result)
        seen.append(result)
        return result

    reducer.solve = spy
    return seen


@pytest.mark.parametrize("reducer", ["affine", "rigid"])
def test_the_reduced_frame_with_the_contacts_unknowns_last_solves_as_the_plain_factorisation(reducer):
    """The frame's factorisation of A_r with the touched reduced unknowns last solves as a plain
    factorisation of the same A_r."""
    plain, taken = Pardiso(), []

    def check(result):
        op = result.operator
        if op is None or op.schur is None:
            return
        assert op.G is not None and isinstance(op.solver, PardisoSchur)
        Ar = op.matrix
        rhs = np.random.default_rng(len(taken)).normal(size=Ar.shape[0])
        plain.factorize(Ar)
        ref = plain.solve(rhs)
        assert np.abs(op.solver.solve(rhs) - ref).max() <= 1e-10 * np.abs(ref).max()
        taken.append(True)

    sim = _scene(reducer)
    _spy_solves(sim, check)
    list(sim.run(60))
    assert taken, "no reduced frame was factorised with its contacts' unknowns last"
    assert any(rec.get("frame_schur", 0) > 0 for rec in sim.stats)


@pytest.mark.parametrize("reducer", ["affine", "rigid"])
def test_w_from_the_reduced_frames_complement_equals_the_unit_columns(reducer):
    sim = _scene(reducer)
    taken = []

    def check(op, J):
        if op.schur is None:
            return
        keep, S = op.schur
        Jr = J @ op.G
        T = touched_unknowns(Jr)
        assert np.isin(T, keep).all()
        ref = plain_delassus(op, J)[0]
        res = delassus.Resolvent(op, block=7, cache={}, bodies=sim.contact.bodies)
        W = res.delassus(J)
        assert np.abs(W - ref).max() <= 1e-10 * np.abs(ref).max()
        assert res.schur_unknowns == T.size and res.columns_solved == 0
        columns = delassus.Resolvent(Operator(op.solver, op.matrix, op.G), block=7, cache={},
                                     bodies=sim.contact.bodies)
        assert np.abs(W - columns.delassus(J)).max() <= 1e-10 * np.abs(ref).max() and columns.columns_solved > 0
        taken.append(True)

    original = sim.contact.resolve

    def spy(problem, result, rec):  # while the frame's factorisation holds
        cs = sim.contact.current
        if cs is not None and cs.size:
            check(result.operator, cs.J)
        return original(problem, result, rec)

    sim.contact.resolve = spy
    for _ in sim.run(150):
        if len(taken) >= 4:
            break
    assert taken, "no reduced frame took its own Schur complement"


def test_an_affinified_contact_run_is_the_run_with_the_route_off_to_round_off():
    runs = []
    for frame in (True, False):
        sim = _scene("affine")
        sim.contact.schur.frame = frame
        runs.append([s.x.copy() for s in sim.run(50)])
        assert frame == any(rec.get("frame_schur", 0) > 0 for rec in sim.stats)
    scale = sim.size
    for xa, xb in zip(*runs):
        assert np.abs(xa - xb).max() <= 1e-9 * scale


def test_reduced_contacts_on_several_bodies_factorise_plainly():
    """Through G (two bodies of 40 DOFs, each with a 12-column affine part and 10 elastic DOFs), contacts
    touching one body take the route, contacts touching both do not (unless no bodies are given)."""
    from types import SimpleNamespace

    import scipy.sparse as sp

    from skfem_affine.contact.schur import SchurInverse
    from skfem_affine.reducers.full import contact_factorization
    from test_schur import _spd
    rng = np.random.default_rng(3)
    body = sp.bmat([[sp.csr_matrix(rng.normal(size=(30, 12))), None], [None, sp.identity(10)]])
    G = sp.block_diag([body, body], format="csr")  # 80 free DOFs x 44 reduced unknowns
    bodies = np.repeat([0, 1], 40)
    Ar = _spd(44, seed=7)
    Ar = sp.csr_matrix(sp.block_diag([Ar[:22, :22], Ar[22:, 22:]]))
    rows = {1: [0, 35], 2: [35, 75]}  # free DOFs in contact: on body 0 only, or on both bodies

    def route(which, bodies):
        J = sp.csr_matrix((np.ones(2), (np.arange(2), rows[which])), shape=(2, 80))
        return contact_factorization(SchurInverse(min_size=1), bodies, Pardiso(), SimpleNamespace(J=J), Ar, G)

    assert route(1, bodies) is not None and route(2, None) is not None
    assert route(2, bodies) is None


def test_a_resumed_affinified_run_with_the_frames_complement_is_bit_identical(tmp_path):
    sim = _scene("affine")
    list(sim.run(30))
    assert any(rec.get("frame_schur", 0) > 0 for rec in sim.stats)
    resumed = resume_bit_identically(sim, lambda: _scene("affine"), tmp_path / "run.npz")
    assert any(rec.get("frame_schur", 0) > 0 for rec in list(resumed.stats)[-8:])


def test_a_changed_pattern_is_factorised_with_few_touched_unknowns_last():
    """Below min_size a new analysis is declined while the pattern stays (the plain factorisation keeps
    its analysis), taken when it changed (the plain one analyses anew as well), and a resumed
    SchurInverse remembers the last pattern."""
    from skfem_affine.contact.schur import SchurInverse, pattern_key
    from test_schur import _spd
    A, B = _spd(60, seed=1), _spd(60, seed=2)
    assert not np.array_equal(pattern_key(A), pattern_key(B))
    T = np.arange(5, 25, 2)
    schur = SchurInverse(min_size=128)
    assert schur.factorize_on(A, T) is None and schur.factorize_on(A, T) is None
    state = schur.state_dict()
    handle, keep, S = schur.factorize_on(B, T)
    assert np.array_equal(keep, T)
    Z = np.linalg.inv(B.toarray())[np.ix_(T, T)]
    assert np.abs(np.linalg.inv(S) - Z).max() <= 1e-12 * np.abs(Z).max()
    resumed = SchurInverse(min_size=128)
    resumed.load_state_dict(state)
    assert resumed.factorize_on(B, T) is not None
    again = SchurInverse(min_size=128)
    again.load_state_dict(state)
    assert again.factorize_on(A, T) is None
