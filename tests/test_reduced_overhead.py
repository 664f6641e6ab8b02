"""What a reduced frame pays beyond full space when it reduces little: its unknowns in the full
space's numbering (several bodies), A_r solved through the full A's factorisation (few constraints),
and the predicted rates of the previously reduced elements only; each against the old path."""
import numpy as np
import pytest
import scipy.sparse as sp

import skfem_affine as sa
from skfem_affine.reducers.affine import constrained
from skfem_affine.reducers.affine.affinification import element_rates
from skfem_affine.reducers.affine.mapping import affine_mapping, reduced_matrix, rigid_mapping
from skfem_affine.reducers.affine.numbering import FullNumbering, several_bodies

from resuming import resume_bit_identically

pytest.importorskip("pypardiso")

from skfem_affine.solvers import Pardiso  # noqa: E402


def _pills(new=True, frames=0, reducer=None, numbering=None):
    """Three coarse pills in the bowl (bodies from the first frame, contacts from frame 24); ``new``:
    the route through A's factorisation (at any constraint count), else the direct one; ``numbering``
    (default ``new``): the full numbering, with which the frames are factorised per body."""
    sim = sa.scenes.pills(n=3, resolution=1, reducer=reducer or sa.Affinification(tau_a=1.0, tau_e=2.0))
    r = sim.integrator.reducer
    r.full_numbering = new if numbering is None else numbering
    r.constraints_max = 10 ** 9 if new else -1
    for _ in range(frames):
        sim.step()
    return sim


def _frame(sim):
    """The next frame's problem (at the simulation's state) and the reducer's result for it."""
    seen = {}
    original = sim.integrator.reducer.solve

    def spy(problem):
        seen["problem"], seen["result"] = problem, original(problem)
        return seen["result"]

    sim.integrator.reducer.solve = spy
    sim.step()
    sim.integrator.reducer.solve = original
    return seen["problem"], seen["result"]


def test_several_bodies():
    assert several_bodies(np.array([0, 0, 1])) and not several_bodies(np.array([2, 2]))
    assert not several_bodies(None) and not several_bodies(np.zeros(0, int))


def test_full_numbering_embeds_the_reduced_system():
    """A_r, G, b and an order renumbered: the compact system sits at ``columns``, idle unknowns hold
    their diagonal only, and G's products are unchanged."""
    sim = _pills(new=False, frames=2)
    problem, result = _frame(sim)
    gmap, model = result.mapping, sim.model
    assert gmap.n_bodies > 0
    Ar = reduced_matrix(model, problem.data, gmap, upper=True)
    diag = np.arange(1.0, gmap.G.shape[0] + 1)
    num = FullNumbering(gmap, diag)
    W = num.matrix(Ar)
    assert W.has_sorted_indices and np.all(np.diff(num.columns) > 0)
    P = sp.csr_matrix((np.ones(num.columns.size), (num.columns, np.arange(num.columns.size))),
                      shape=(num.size, num.columns.size))
    expect = (P @ Ar @ P.T).toarray()
    expect[num.idle, num.idle] = diag[num.idle]
    assert np.array_equal(W.toarray(), expect)
    assert np.array_equal(sp.triu(W).toarray(), W.toarray())  # still an upper triangle
    Gw = num.mapping(gmap.G)
    dq = np.random.default_rng(0).normal(size=gmap.G.shape[1])
    assert np.array_equal(Gw @ num.vector(dq), gmap.G @ dq)
    assert np.array_equal(num.compact(num.vector(dq)), dq)
    order = np.arange(gmap.G.shape[1])[::-1]
    o = num.order(order)
    assert np.array_equal(np.sort(o), np.arange(num.size)) and np.array_equal(o[num.idle.size:], num.columns[order])


def test_a_run_in_the_full_numbering_is_the_compact_run_bit_for_bit():
    """Several bodies: the renumbered frames (factorised with the renumbered order) give the same positions."""
    a, b = _pills(new=False), _pills(new=False)
    a.integrator.reducer.full_numbering, a.integrator.reducer.blocks = True, None  # factorised whole
    assert several_bodies(a.contact.bodies)
    for _ in range(40):
        a.step()
        b.step()
        assert np.array_equal(a.state.x, b.state.x) and np.array_equal(a.state.v, b.state.v)
    assert a.stats[-1]["n_clusters"] > 0 and a.stats[-1]["n_contacts"] > 0
    assert a.stats[-1]["dofs"] == b.stats[-1]["dofs"] < a.system.free.size


@pytest.mark.parametrize("kind", ["affine", "rigid", "affine-numbered"])
def test_the_constrained_solver_solves_the_reduced_system(kind):
    """A_r^-1 y through A's factorisation and the k-dimensional correction against A_r factorised
    directly, one right-hand side and several."""
    sim = _pills(new=False, frames=3)
    problem, result = _frame(sim)
    model, sysm = sim.model, sim.system
    rng = np.random.default_rng(1)
    vc = result.mapping.vcluster
    gmap = result.mapping
    if kind == "rigid":
        gmap = rigid_mapping(sysm.free, vc, problem.x, sysm.lumped_mass, gmap.n_bodies)
    else:
        gmap = affine_mapping(sysm.free, vc, sysm.p0, sysm.lumped_mass, gmap.n_bodies)
    A = problem.matrix()
    Ar = (gmap.G.T @ A @ gmap.G).tocsr()
    full = Pardiso()
    full.factorize(A)
    if kind == "affine-numbered":
        num = FullNumbering(gmap, np.full(gmap.G.shape[0], 2.0))
        Ar = num.matrix(Ar)
        solver = constrained.ConstrainedSolver(full, gmap, num)
    else:
        solver = constrained.ConstrainedSolver(full, gmap)
    assert solver.k == constrained.constraints(gmap) > 0
    direct = Pardiso()
    direct.factorize(Ar)
    for shape in [(Ar.shape[0],), (Ar.shape[0], 5)]:
        y = rng.normal(size=shape)
        ref = direct.solve(y)
        assert np.abs(solver.solve(y) - ref).max() <= 1e-9 * np.abs(ref).max()


def test_a_run_through_the_full_factorisation_follows_the_direct_run():
    """Frames with a new A_r pattern solved through A's factorisation: the run stays with the old
    path to round-off, and the route is taken only while the clusters change."""
    a, b = _pills(new=True, numbering=False), _pills(new=False)
    for _ in range(30):
        a.step()
        b.step()
    scale = np.abs(b.state.x).max()
    assert np.abs(a.state.x - b.state.x).max() <= 1e-10 * scale
    through = [bool(r.get("through_full")) for r in a.stats]
    assert through[0] and any(through[1:]) and not all(through)
    assert not any(r.get("through_full") for r in b.stats)


def test_the_route_through_the_full_factorisation_is_refused_beyond_its_constraints():
    sim = _pills(new=True, numbering=False)
    sim.integrator.reducer.constraints_max = 0
    for _ in range(3):
        sim.step()
    assert sim.stats[-1]["n_clusters"] > 0 and not any(r.get("through_full") for r in sim.stats)


def test_a_checkpoint_resumes_the_route_bit_for_bit(tmp_path):
    sim = _pills(new=True, numbering=False, frames=26)
    resumed = resume_bit_identically(sim, lambda: _pills(new=True, numbering=False), tmp_path / "pills.npz", frames=6)
    assert any(r.get("through_full") for r in resumed.stats[-6:])


def test_a_checkpoint_resumes_the_frames_factorised_per_body_bit_for_bit(tmp_path):
    sim = _pills(new=False, numbering=True, frames=26)
    resumed = resume_bit_identically(sim, lambda: _pills(new=False, numbering=True), tmp_path / "pills.npz",
                                     frames=6)
    analysed = [r["blocks_analysed"] for r in resumed.stats[-6:] if "blocks_analysed" in r]
    assert analysed and min(analysed) < 3  # some bodies kept their analysis


def test_a_run_factorised_per_body_follows_the_whole_factorisation():
    """Several bodies, each its own block: the same frames as the whole A_r factorised, to round-off,
    bit for bit while no contact mixes the round-off in. The blocks are factorised plainly (with the
    contacts' unknowns last they round otherwise: tests/test_reduced_frame_blocks.py)."""
    a, b = _pills(new=False, numbering=True), _pills(new=False)
    a.contact.schur.blocks = False
    for frame in range(30):
        a.step()
        b.step()
        if frame < 24:
            assert np.array_equal(a.state.x, b.state.x)
    assert np.abs(a.state.x - b.state.x).max() <= 1e-10 * np.abs(b.state.x).max()
    assert any("blocks_analysed" in r for r in a.stats)


def test_body_blocks_solve_as_the_whole_factorisation():
    from skfem_affine.reducers.affine.blocks import BodyBlocks, unknown_labels
    sim = _pills(new=False, frames=29)
    problem, result = _frame(sim)
    gmap = result.mapping
    Ar = reduced_matrix(sim.model, problem.data, gmap, upper=True)
    num = FullNumbering(gmap, np.full(gmap.G.shape[0], 2.0))
    W = num.matrix(Ar)
    labels = unknown_labels(sim.contact.bodies, num, gmap.width)
    assert np.array_equal(np.unique(labels), [0, 1, 2])
    Gw = num.mapping(gmap.G)  # each reduced body's columns within one scene body
    assert np.all(labels[Gw.indices] == np.repeat(sim.contact.bodies, np.diff(Gw.indptr)))
    order = num.order(gmap.elimination_order(sim.integrator.reducer.vertex_rank))
    blocks, whole = BodyBlocks(), Pardiso()
    blocks.factorize(W, labels, order)
    assert blocks.analyses == 3
    whole.factorize(W, upper=True)
    y = np.random.default_rng(4).normal(size=(W.shape[0], 3))
    ref = whole.solve(y)
    assert np.abs(blocks.solve(y) - ref).max() <= 1e-10 * np.abs(ref).max()
    blocks.factorize(W, labels, order)
    assert blocks.analyses == 0  # the same patterns: numeric factorisations only


def test_pardiso_knows_the_pattern_it_analysed(tmp_path):
    A = sp.csr_matrix(sp.diags([4.0] * 6) + sp.diags([1.0] * 5, 1) + sp.diags([1.0] * 5, -1))
    s = Pardiso()
    assert not s.analysed_for(A)
    s.factorize(A)
    assert s.analysed_for(A) and s.analysed_for(sp.triu(A, format="csr"), upper=True)
    assert not s.analysed_for(sp.csr_matrix(sp.diags([4.0] * 6)))
    loaded = Pardiso()
    loaded.load_state_dict(s.state_dict())  # a checkpoint's pattern counts as analysed
    assert loaded.analysed_for(A)


def test_the_rates_of_some_elements_are_those_of_all():
    sim = _pills(new=False)
    sysm = sim.system
    v = np.random.default_rng(2).normal(size=(sysm.n, 3))
    some = np.arange(0, sysm.m, 7)
    assert np.array_equal(element_rates(v, sysm.t[:, some], sysm.grads[some]), sysm.deformation_gradients(v)[some])


def test_the_whole_matrix_from_its_upper_triangle_is_scipys():
    """Operator.matrix of an upper triangle: the entries and order of U + triu(U, 1)^T, zeros dropped."""
    from skfem_affine.integrators.problem import Operator
    from skfem_affine.upper import whole_from_upper
    A = sp.random(60, 60, density=0.1, random_state=3, format="csr")
    A = (A + A.T + sp.diags(np.full(60, 3.0))).tocsr()
    U = sp.triu(A, format="csr")
    U.sort_indices()
    U.data[::5] = 0.0  # stored zeros
    U.data[1::7] *= -1.0
    ref = (U + sp.triu(U, k=1, format="csr").T).tocsr()
    for W in (whole_from_upper(U), Operator(None, U, upper=True).matrix):
        assert W.has_sorted_indices
        assert np.array_equal(W.indptr, ref.indptr) and np.array_equal(W.indices, ref.indices)
        assert np.array_equal(W.data, ref.data)


def test_the_benchmark_steps_full_space_and_both_routes_in_turn(benchmark_script, tmp_path):
    bench = benchmark_script("reduced_overhead")
    means, gap = bench.main(["--scene", "pile", "--cells", "1", "--start", "3", "--frames", "2", "--warmup", "1",
                             "--checkpoints", str(tmp_path)])
    assert list(means) == ["full", "old route", "new route"] and gap <= 1e-9
    assert means["new route"]["dofs"] == means["old route"]["dofs"] < means["full"]["dofs"]
    assert (tmp_path / "pile_full_3.npz").is_file() and (tmp_path / "pile_affinification_3.npz").is_file()


def test_the_coarse_guess_by_group_sums_is_scipys_bit_for_bit():
    """T^T A T of the bodies' translations summed in scipy's order: the same guess, bit for bit."""
    from skfem_affine.reducers.affine import oracle
    sim = _pills(new=False, frames=1)
    problem, _ = _frame(sim)
    sysm, model = sim.system, sim.model
    T = oracle.body_translations(sysm)
    b = np.random.default_rng(5).normal(size=sysm.free.size)
    mdiag = sysm.Mff.diagonal()
    cm, ck = model.coefficients
    TAT = (cm * (T.T @ sp.diags(mdiag) @ T) + ck * (T.T @ (problem.Hmat @ T))).toarray()
    ref = T @ np.linalg.solve(TAT, T.T @ b)
    assert np.array_equal(oracle.coarse_guess(T, mdiag, problem.Hmat, model.coefficients, b), ref)
    T2 = T.copy()
    T2.data[:] = 2.0  # not unit entries: scipy's products
    TAT2 = (cm * (T2.T @ sp.diags(mdiag) @ T2) + ck * (T2.T @ (problem.Hmat @ T2))).toarray()
    assert np.array_equal(oracle.coarse_guess(T2, mdiag, problem.Hmat, model.coefficients, b),
                          T2 @ np.linalg.solve(TAT2, T2.T @ b))


def test_the_benchmark_times_the_factorisations_of_one_frame(benchmark_script, tmp_path):
    bench = benchmark_script("reduced_overhead")
    times = bench.main(["--scene", "pile", "--cells", "1", "--start", "3", "--checkpoints", str(tmp_path),
                        "--factorisations"])
    assert len(times) == 5 and all(t > 0 for t in times.values())
