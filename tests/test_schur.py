"""Z = (A^-1)_TT from Pardiso's Schur complement on the touched unknowns T, against the inverse
itself and against the unit-column solves (the Delassus operator W in full and reduced space)."""
import os
import subprocess
import sys

import numpy as np
import pytest
import scipy.sparse as sp

pytest.importorskip("pypardiso")

import skfem_affine as sa  # noqa: E402
from skfem_affine.contact import delassus  # noqa: E402
from skfem_affine.contact.schur import SchurInverse  # noqa: E402
from skfem_affine.integrators.problem import Operator  # noqa: E402
from skfem_affine.solvers import PardisoSchur, SuperLU  # noqa: E402

from test_delassus import REDUCERS, frames_with_contact, plain_delassus  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _spd(n, seed=0):
    """A sparse SPD matrix of n unknowns (a perturbed chain with a few long-range couplings)."""
    rng = np.random.default_rng(seed)
    i = rng.integers(0, n, 2 * n)
    j = rng.integers(0, n, 2 * n)
    B = sp.coo_matrix((rng.normal(size=i.size), (i, j)), shape=(n, n)).tocsr()
    B = B + B.T + sp.diags([-np.ones(n - 1), -np.ones(n - 1)], [-1, 1])
    return sp.csr_matrix(B + sp.diags(np.abs(B).sum(axis=1).A1 + 1.0))


def test_complement_inverts_to_the_inverse_on_the_kept_unknowns():
    A = _spd(60)
    keep = np.array([2, 5, 11, 30, 31, 59])
    S = PardisoSchur().complement(A, keep)
    Z = np.linalg.inv(A.toarray())[np.ix_(keep, keep)]
    assert np.abs(np.linalg.inv(S) - Z).max() <= 1e-12 * np.abs(Z).max()
    U = sp.triu(A, format="csr")
    assert np.abs(PardisoSchur().complement(U, keep, upper=True) - S).max() <= 1e-12 * np.abs(S).max()


@pytest.mark.parametrize("keep", [np.arange(31), np.arange(60), np.array([3, 3]), np.array([5, 2]), np.array([-1, 4])])
def test_complement_refuses_unsorted_repeated_or_more_than_half_the_unknowns(keep):
    with pytest.raises(ValueError, match="keep"):
        PardisoSchur().complement(_spd(60), keep)


def test_schur_inverse_keeps_its_analysis_for_subsets_and_declines_small_or_large_sets():
    A = _spd(80, seed=1)
    inv = np.linalg.inv(A.toarray())
    schur = SchurInverse(min_size=4)
    # a subset of the kept set reuses its analysis; a set that grows it, or another one, is analysed anew
    for T, analyses in [(np.arange(10, 30), 1), (np.arange(12, 28), 1), (np.arange(5, 30), 2), (np.arange(6, 20), 2),
                        (np.arange(40, 45), 3)]:
        A = A.copy()
        A.data *= 1.0 + 1e-3 * analyses  # new values, same pattern: every call a new factorisation
        Z = schur.inverse_on(A, T)
        ref = np.linalg.inv(A.toarray())[np.ix_(T, T)]
        assert np.abs(Z - ref).max() <= 1e-11 * np.abs(ref).max()
        assert schur.analyses == analyses
    assert schur.inverse_on(A, np.arange(3)) is None  # below min_size without a kept analysis
    assert schur.inverse_on(A, np.arange(41)) is None  # more than half the unknowns
    assert inv.shape == (80, 80)


def test_schur_inverse_grows_its_set_only_once_an_analysis_has_served_a_later_frame():
    """Contacts that move every frame (landing) are analysed on the touched unknowns alone; once a kept
    analysis serves a later frame (settling), new unknowns grow it."""
    A = _spd(200, seed=4)
    schur = SchurInverse(min_size=4)
    kept = []
    for T in [np.arange(10, 40), np.arange(15, 45), np.arange(20, 50), np.arange(22, 48), np.arange(18, 52)]:
        Z = schur.inverse_on(A, T)
        ref = np.linalg.inv(A.toarray())[np.ix_(T, T)]
        assert np.abs(Z - ref).max() <= 1e-11 * np.abs(ref).max() and np.array_equal(Z, Z.T)
        kept.append(schur._kept_by[None].analysed(A))
    # 15..44 and 20..49 each a new analysis on T alone; 22..47 a subset (served); 18..51 then grows it
    assert [k.size for k in kept] == [30, 30, 30, 30, 34] and np.array_equal(kept[4], np.arange(18, 52))
    assert np.array_equal(kept[3], kept[2]) and schur.analyses == 4
    with pytest.raises(ValueError, match="schur_served"):
        schur.load_state_dict({"schur_systems": np.array([[-1, -1]]), "schur0.keep": np.arange(3),
                               "schur_served": np.zeros(2, dtype=bool), "schur_seen": np.zeros(0, np.int64)})


def test_a_resumed_schur_inverse_grows_its_set_as_the_saved_run():
    A = _spd(120, seed=5)
    ahead = SchurInverse(min_size=4)
    ahead.inverse_on(A, np.arange(10, 40))
    ahead.inverse_on(A, np.arange(12, 38))  # served: the next new unknowns grow the kept set
    resumed = SchurInverse(min_size=4)
    resumed.load_state_dict({k: v.copy() for k, v in ahead.state_dict().items()})
    T = np.arange(8, 36)
    assert np.array_equal(ahead.inverse_on(A, T), resumed.inverse_on(A, T))
    assert np.array_equal(resumed._kept_by[None].analysed(A), np.arange(8, 40))


@pytest.mark.parametrize("reducer", list(REDUCERS))
def test_delassus_from_the_schur_complement_equals_the_plain_path(reducer):
    """The falling box in full space, and reduced frames whose system has more than twice the unknowns
    the contacts touch (smaller ones, e.g. the whole box affine, solve their columns)."""
    sim = sa.scenes.SCENES["drop"](resolution=1, shape="box", reducer=REDUCERS[reducer]())
    schur = SchurInverse(min_size=1)
    taken = []

    def check(op, J):
        ref, Jr, Y = plain_delassus(op, J)
        res = delassus.Resolvent(op, block=7, cache={}, schur=schur)
        W = res.delassus(J)
        assert np.abs(W - ref).max() <= 1e-9 * np.abs(ref).max(), np.abs(W - ref).max() / np.abs(ref).max()
        T = np.unique(sp.csr_matrix(Jr).indices)
        eligible = res.parts is None and 2 * T.size <= Jr.shape[1]
        assert (res.schur_unknowns == T.size) if eligible else (res.schur_unknowns == 0)
        taken.append(eligible)

    frames_with_contact(sim, 120, check, want=6)
    assert any(taken), "no frame took the Schur complement"


def test_small_bodies_solve_their_columns_with_the_others():
    sim = sa.scenes.SCENES["stacked_beams"](resolution=1)
    schur = SchurInverse(min_size=1)

    def check(op, J):
        ref = plain_delassus(op, J)[0]
        res = delassus.Resolvent(op, block=7, cache={}, schur=schur, bodies=sim.contact.bodies)
        assert np.abs(res.delassus(J) - ref).max() <= 1e-9 * np.abs(ref).max()
        assert res.parts is not None and res.schur_unknowns == 0

    frames_with_contact(sim, 120, check, want=1)


def test_each_large_body_takes_the_schur_complement_of_its_block():
    """Two bodies above SCHUR_BLOCK_MIN unknowns, each keeping its own analysis across frames."""
    m = delassus.SCHUR_BLOCK_MIN + 100
    schur = SchurInverse(min_size=1)
    rng = np.random.default_rng(3)
    for frame in range(3):
        A = sp.block_diag([_spd(m, seed=frame), _spd(m + 7, seed=frame + 10)], format="csr")
        solver = SuperLU()
        solver.factorize(A)
        cols = np.sort(rng.choice(A.shape[0], 40, replace=False))
        J = sp.csr_matrix((rng.normal(size=60), (rng.integers(0, 30, 60), rng.choice(cols, 60))),
                          shape=(30, A.shape[0]))
        op = Operator(solver, A)
        ref = plain_delassus(op, J)[0]
        res = delassus.Resolvent(op, cache={}, schur=schur, bodies=np.repeat([0, 1], [m, m + 7]))
        assert np.abs(res.delassus(J) - ref).max() <= 1e-9 * np.abs(ref).max()
        assert res.schur_unknowns == np.unique(J.indices).size and res.columns_solved == 0
    assert len(schur._kept_by) == 2 and set(schur._served) <= set(schur._kept_by)


def test_schur_inverse_keeps_the_analyses_of_its_last_systems_only():
    schur = SchurInverse(min_size=1, systems=2)
    for first in range(4):
        A = _spd(40 + first, seed=first)
        schur.inverse_on(A, np.arange(5, 15), key=(40 + first, 0))
    assert list(schur._kept_by) == [(42, 0), (43, 0)] and set(schur._served) == {(42, 0), (43, 0)}


def test_a_resumed_schur_inverse_analyses_the_saved_sets_and_gives_the_same_bits():
    A = _spd(80, seed=2)
    ahead = SchurInverse(min_size=4)
    ahead.inverse_on(A, np.arange(10, 30))
    ahead.inverse_on(A, np.arange(12, 26))  # kept: the analysis of 10..29
    resumed = SchurInverse(min_size=4)
    resumed.load_state_dict({k: v.copy() for k, v in ahead.state_dict().items()})
    A = A.copy()
    A.data *= 1.01
    T = np.arange(14, 24)
    assert np.array_equal(ahead.inverse_on(A, T), resumed.inverse_on(A, T))
    with pytest.raises(ValueError, match="schur0.keep"):
        resumed.load_state_dict({"schur_systems": np.array([[-1, -1]]), "schur0.keep": np.array([3, 2]),
                                 "schur_served": np.zeros(1, dtype=bool), "schur_seen": np.zeros(0, np.int64)})


def test_stress_script_survives_varied_calls_in_a_subprocess():
    """Patterns, sets, thread counts and handles varied call to call (benchmarks/schur_stress.py)."""
    run = subprocess.run([sys.executable, os.path.join(ROOT, "benchmarks", "schur_stress.py"), "--calls", "60",
                          "--check-every", "3", "--vertices", "60"], capture_output=True, text=True, timeout=300,
                         env=dict(os.environ, PYTHONPATH=ROOT))
    assert run.returncode == 0, run.stderr[-2000:]
    assert "survived 60 calls" in run.stdout


@pytest.mark.slow
def test_routes_script_gives_z_from_every_route_to_round_off_in_a_subprocess():
    """benchmarks/delassus_routes.py: Z from the Schur complement and from Pardiso's partial solve against the
    unit columns, and the frame's own solve on those factorisations (new MKL modes: run apart)."""
    run = subprocess.run([sys.executable, os.path.join(ROOT, "benchmarks", "delassus_routes.py"), "--cube", "6",
                          "--reps", "2"], capture_output=True, text=True, timeout=300, env=dict(os.environ, PYTHONPATH=ROOT))
    assert run.returncode == 0, run.stderr[-2000:]
    errors = [float(line.rsplit(" ", 1)[1]) for line in run.stdout.splitlines()
              if "against the unit columns" in line or "residual" in line]
    assert len(errors) == 4 and max(errors) < 1e-12, run.stdout


@pytest.mark.slow
def test_stress_script_survives_the_schur_factorisation_serving_the_frames_solves_in_a_subprocess():
    """benchmarks/schur_stress.py --frame-solves: mode iparm(36) = 2, whose factorisation also solves the
    whole system (phase 33), with new patterns, sets, values and thread counts call to call."""
    run = subprocess.run([sys.executable, os.path.join(ROOT, "benchmarks", "schur_stress.py"), "--frame-solves",
                          "--calls", "40", "--vertices", "60"], capture_output=True, text=True, timeout=300,
                         env=dict(os.environ, PYTHONPATH=ROOT))
    assert run.returncode == 0, run.stderr[-2000:]
    assert "survived 40 calls" in run.stdout


def test_a_state_without_its_served_flags_or_last_pattern_is_refused():
    state = SchurInverse(min_size=4).state_dict()
    assert state["schur_seen"].size == 0  # saved even before any frame's factorisation
    for key in ("schur_served", "schur_seen"):
        with pytest.raises(KeyError, match=key):
            SchurInverse().load_state_dict({k: v for k, v in state.items() if k != key})
    with pytest.raises(ValueError, match="schur_seen"):
        SchurInverse().load_state_dict(dict(state, schur_seen=np.arange(3)))


@pytest.mark.slow
def test_bound_script_gives_z_of_the_partial_solve_as_s_inverse_in_a_subprocess():
    """benchmarks/delassus_bound.py on the smallest stacked beams: per body, the partial solve's Z against
    S^-1 from the factorisation with the touched unknowns last, and Pardiso's flop counts reported."""
    run = subprocess.run([sys.executable, os.path.join(ROOT, "benchmarks", "delassus_bound.py"), "--scene",
                          "stacked_beams", "--cells", "1", "--frame", "1", "--reps", "1"], capture_output=True,
                         text=True, timeout=300, env=dict(os.environ, PYTHONPATH=ROOT))
    assert run.returncode == 0, run.stderr[-2000:]
    head = run.stdout.splitlines()[0]
    assert float(head.rsplit(" ", 1)[1]) < 1e-12 and float(head.split("residual ")[1].split(";")[0]) < 1e-12, run.stdout
    assert "| plain factorisation |" in run.stdout and "at least" in run.stdout


def test_the_inverse_on_positions_takes_a_given_factor_where_it_is_the_cheaper_route():
    """With S's Cholesky factor given, S^-1 on all or most of S's unknowns comes from it (potri only),
    on few from S's own complement as without it; the factor is left unchanged."""
    from scipy.linalg import lapack
    from skfem_affine.contact.schur import inverse_on_positions
    rng = np.random.default_rng(0)
    B = rng.normal(size=(60, 60))
    S = B @ B.T + 60 * np.eye(60)
    L = lapack.dpotrf(S, lower=1, clean=1)[0]
    doubled = np.sqrt(2.0) * L  # the factor of 2 S: shows which route was taken
    kept = doubled.copy()
    for size, from_factor in ((60, True), (55, True), (20, False)):
        pos = np.sort(rng.choice(60, size, replace=False))
        ref = np.linalg.inv(S)[np.ix_(pos, pos)]
        assert np.abs(inverse_on_positions(S, pos, L) - ref).max() <= 1e-13 * np.abs(ref).max()
        Z = inverse_on_positions(S, pos, doubled)
        assert np.allclose(Z, ref / 2 if from_factor else ref, rtol=0, atol=1e-13 * np.abs(ref).max())
    assert np.array_equal(doubled, kept)
