"""PGS(solver="block"): block Gauss-Seidel over groups of strongly coupled contacts."""
import numpy as np
import pytest
import scipy.linalg

import skfem_affine as sa
from skfem_affine.contact import pgs
from skfem_affine.lab.scenes import box_mesh
from resuming import resume_bit_identically
from test_contact_solvers import MU, _coupled, _rigid, _solve, assert_complementary_and_in_the_cone


def _twins(seed, k=10, tilt=0.05, compliance=1e-3, coupling=0.02):
    """Contacts in pairs that are almost the same constraint, as where two soft bodies meet (a vertex
    of each on the other's triangle at one spot): the pair's rows are one local 3 x 3 compliance seen
    in two frames ``tilt`` apart; the spots are weakly coupled through the bodies' rigid motion."""
    rng = np.random.default_rng(seed)
    p = rng.uniform(-0.1, 0.1, size=(k, 3))
    p[:, 2] = 0.0
    rows, local = [], np.zeros((6 * k, 6 * k))
    for i, x in enumerate(p):
        r = x - np.array([0.0, 0.0, 0.1])
        cross = np.array([[0, r[2], -r[1]], [-r[2], 0, r[0]], [r[1], -r[0], 0]])
        J = np.hstack([np.eye(3), cross])[[2, 0, 1]]
        a = tilt * rng.normal(size=2)
        R = np.array([[1, -a[0], -a[1]], [a[0], 1, 0], [a[1], 0, 1]])
        rows += [J, R @ J]
        T = np.vstack([np.eye(3), R])
        local[6 * i:6 * i + 6, 6 * i:6 * i + 6] = T @ T.T
    B = np.vstack(rows) / np.sqrt([1.0, 1.0, 1.0, 1e-3, 1e-3, 1e-3])
    W = coupling * B @ B.T / k + local + compliance * np.eye(6 * k)
    u0 = np.tile([-0.1, 0.02, -0.01], 2 * k) + 1e-3 * rng.normal(size=6 * k)
    return W, u0


PROBLEMS = [_coupled(3), _coupled(4), _rigid(5), _rigid(6), _twins(1), _twins(2)]


@pytest.mark.parametrize("problem", PROBLEMS)
def test_block_reaches_the_gauss_seidel_solution(problem):
    W, u0 = problem
    ref, _ = _solve("gauss-seidel", W, u0, cap=50000)
    lam, sweeps = _solve("block", W, u0)
    assert sweeps < 20000
    assert np.abs(lam - ref).max() <= 1e-6 * np.abs(ref).max()
    assert np.abs(W @ (lam - ref)).max() <= 1e-9 * np.abs(u0).max()


@pytest.mark.parametrize("problem", [_coupled(3), _rigid(5), _twins(1)])
def test_block_solution_is_complementary_and_in_the_cone(problem):
    W, u0 = problem
    lam, _ = _solve("block", W, u0)
    assert_complementary_and_in_the_cone(W, u0, lam)


def test_twin_contacts_are_grouped_and_take_far_fewer_sweeps():
    # plain sweeps crawl on the pairs' nearly parallel rows (measured 716-5599 sweeps to 1e-8),
    # solved together they take 8-56
    for seed in (1, 2, 3):
        W, u0 = _twins(seed)
        ptr, members = pgs.contact_groups(W)
        assert np.array_equal(ptr, 2 * np.arange(11)) and np.array_equal(members, np.arange(20))
        _, plain = _solve("gauss-seidel", W, u0, 1e-8)
        _, block = _solve("block", W, u0, 1e-8)
        assert block < plain / 10, (seed, block, plain)


def test_groups_join_the_strongest_pairs_within_the_largest_size():
    W = np.eye(12)
    W[0, 9] = W[9, 0] = 0.9   # contacts 0 and 3, coupled by 0.9
    W[3, 6] = W[6, 3] = 0.6   # contacts 1 and 2, by 0.6
    W[4, 11] = W[11, 4] = -0.7  # contacts 1 and 3, by 0.7 (the sign does not matter)
    ptr, members = pgs.contact_groups(W)
    assert [list(members[a:b]) for a, b in zip(ptr[:-1], ptr[1:])] == [[0, 1, 2, 3]]
    ptr, members = pgs.contact_groups(W, largest=2)   # 0-3 first, then 1-2; 1-3 would exceed 2
    assert [list(members[a:b]) for a, b in zip(ptr[:-1], ptr[1:])] == [[0, 3], [1, 2]]
    ptr, members = pgs.contact_groups(W, coupling=0.8)
    assert [list(members[a:b]) for a, b in zip(ptr[:-1], ptr[1:])] == [[0, 3], [1], [2]]
    W[6, 6] = 0.0  # a contact no impulse acts on is coupled to none
    W[3, 6] = W[6, 3] = 0.0
    ptr, members = pgs.contact_groups(W, coupling=0.65)
    assert [list(members[a:b]) for a, b in zip(ptr[:-1], ptr[1:])] == [[0, 1, 3], [2]]


def test_without_coupled_pairs_block_is_the_plain_sweep_bit_for_bit():
    W, u0 = _rigid(5)
    ptr, _ = pgs.contact_groups(W, coupling=1.0)
    assert ptr.size == 25   # every contact alone
    for cap in (3, 40):
        plain, block = np.zeros_like(u0), np.zeros_like(u0)
        n = pgs.projected_gauss_seidel(W, u0, plain, MU, cap, 1e-9)
        assert pgs.block_gauss_seidel(W, u0, block, MU, cap, 1e-9, coupling=1.0) == n
        assert np.array_equal(plain, block)


def test_block_keeps_the_stopping_rule():
    W = np.diag([2.0, 4.0, 4.0])
    lam = np.zeros(3)
    assert pgs.block_gauss_seidel(W, np.array([-1.0, -3.0, 3.0]), lam, 0.5, 50, 1e-12) <= 3
    assert lam[0] == pytest.approx(0.5) and np.allclose(lam[1:], 0.25 * np.array([1, -1]) / np.sqrt(2))
    W, u0 = _twins(3)
    scale = pgs.velocity_scale(u0)
    for tol in (1e-3, 1e-8):
        lam = np.zeros_like(u0)
        sweeps = pgs.block_gauss_seidel(W, u0, lam, MU, 5000, tol)
        assert sweeps < 5000 and max(pgs.contact_residual(W, u0, lam, MU)) <= tol * scale
    lam = np.zeros_like(u0)
    assert pgs.block_gauss_seidel(W, u0, lam, MU, 2, 0.0) == 2   # the cap
    lam = np.zeros_like(u0)   # past the cap while the residual is above ``loose`` of the scale
    sweeps = pgs.block_gauss_seidel(W, u0, lam, MU, 1, 1e-12, 5000, 1e-4)
    assert 1 < sweeps < 5000 and max(pgs.contact_residual(W, u0, lam, MU)) <= 1e-4 * scale


def test_bad_arguments_name_themselves():
    W, u0 = _twins(1)
    for kwargs, name in (({"coupling": 0.0}, "coupling"), ({"coupling": 1.5}, "coupling"),
                         ({"coupling": "a"}, "coupling"), ({"largest": 0}, "largest"), ({"largest": 2.5}, "largest"),
                         ({"inner": 0}, "inner"), ({"work": 0}, "work")):
        with pytest.raises((ValueError, TypeError), match=name):
            pgs.block_gauss_seidel(W, u0, np.zeros_like(u0), MU, 5, 1e-6, **kwargs)
    with pytest.raises(ValueError, match="W"):
        pgs.contact_groups(np.eye(4))
    assert sa.PGS(solver="block").solver == "block"
    with pytest.raises(ValueError, match="solver"):
        sa.PGS(solver="blocks")


def _stack():
    mat = sa.NeoHookean(E=1e6, nu=0.3)
    bodies = [sa.ElasticBody(box_mesh(0.2, 2, (0.0, 0.0, 0.1)), mat, density=1000.0),
              sa.ElasticBody(box_mesh(0.12, 2, (0.02, 0.01, 0.26)), mat, density=1000.0)]
    return sa.Simulation(bodies, dt=0.01, gravity=(0.0, 0.0, -9.81), colliders=[sa.Plane()],
                         contact=sa.PGS(solver="block"))


def test_a_resting_stack_stays_at_rest_and_resumes_bit_for_bit(tmp_path):
    sim = _stack()
    list(sim.run(30))
    x = sim.state.x.copy()
    n = sim.bodies[0].mesh.p.shape[1]
    resumed = resume_bit_identically(sim, _stack, tmp_path / "stack.npz", frames=10)
    assert all(r["pgs_converged"] for r in list(resumed.stats)[30:])
    for part in (slice(0, n), slice(n, None)):   # no sinking or drifting of either box
        assert np.abs(resumed.state.x[part].mean(axis=0) - x[part].mean(axis=0)).max() < 1e-6
    assert resumed.state.x[:, 2].min() > -1e-6


@pytest.fixture(scope="module")
def impact():
    """The contact problem (W, u0, warm start, friction) of the first frame of two soft cubes meeting
    head-on at 200 m/s each (tests/test_contact_reliability.py): whole faces meet, 250 contacts."""
    mat = sa.NeoHookean(E=1e7, nu=0.35)
    bodies = [sa.ElasticBody(box_mesh(0.5, 4, (s * 0.275, 0.0, 0.0)), mat, density=1000.0, velocity=(-s * 200.0, 0, 0))
              for s in (-1, 1)]
    sim = sa.Simulation(bodies, dt=0.01, gravity=(0, 0, 0), contact=sa.PGS(solver="block"))
    seen, solve = [], pgs.SOLVERS["block"]

    def keeping(W, u0, lam, mu, *args):
        seen.append((W.copy(), u0.copy(), lam.copy(), mu))
        return solve(W, u0, lam, mu, *args)

    pgs.SOLVERS["block"] = keeping
    try:
        sim.step()
    finally:
        pgs.SOLVERS["block"] = solve
    return seen[0]


def test_a_group_visit_solves_its_group_and_keeps_the_velocities(impact):
    # the impact of two cubes at 200 m/s forms groups of 60 contacts; a visit solves the group's
    # own problem (the other impulses held) to its goal, and leaves u = u0 + W lam
    W, u0, lam, mu = impact
    lam = lam.copy()
    ptr, members = pgs.contact_groups(W)
    sizes = np.diff(ptr)
    assert sizes.max() >= 40
    scale = pgs.velocity_scale(u0)
    u = u0 + W @ lam
    for g in np.argsort(-sizes)[:3]:   # the three largest groups in turn
        group = members[ptr[g]:ptr[g + 1]]
        rows = (3 * group[:, None] + np.arange(3)).ravel()
        before = lam.copy()
        pgs._block_visit(W, u, lam, mu, rows, W[np.ix_(rows, rows)].copy(), 100000, 1e-12 * scale)
        others = np.setdiff1d(np.arange(lam.size), rows)
        assert np.array_equal(lam[others], before[others])
        assert np.abs(u - (u0 + W @ lam)).max() <= 1e-10 * scale
        local = u0[rows] + W[np.ix_(rows, others)] @ lam[others]   # the group's problem, the others held
        assert_complementary_and_in_the_cone(W[np.ix_(rows, rows)], local, lam[rows], mu, scale)


def test_the_impact_of_two_cubes_has_one_solution_whatever_the_iteration(impact):
    # the block sweeps, whose groups here hold 60 contacts, reach the plain sweeps' solution:
    # the same velocities to round-off of the 400 m/s the contacts remove
    W, u0, lam0, mu = impact
    scale = pgs.velocity_scale(u0)
    lam = {}
    for solver in ("gauss-seidel", "block"):
        lam[solver] = lam0.copy()
        sweeps = pgs.SOLVERS[solver](W, u0, lam[solver], mu, 5000, 1e-11)
        assert sweeps < 5000
        assert max(pgs.contact_residual(W, u0, lam[solver], mu)) <= 1e-11 * scale
    assert np.abs(W @ (lam["block"] - lam["gauss-seidel"])).max() <= 1e-9 * scale


def _reference_groups(W, coupling, largest):
    """contact_groups by its definition: the coupled pairs, the strongest first, joined under the size cap."""
    k = W.shape[0] // 3
    d = np.sqrt(np.diag(W))
    C = np.abs(W) / np.outer(d, d)
    c = C.reshape(k, 3, k, 3).max(axis=(1, 3))
    i, j = np.nonzero(np.triu(c > coupling, 1))
    parent, size = list(range(k)), [1] * k

    def find(a):
        while parent[a] != a:
            a = parent[a]
        return a

    for p in np.argsort(-c[i, j], kind="stable"):
        a, b = sorted((find(i[p]), find(j[p])))
        if a != b and size[a] + size[b] <= largest:
            parent[b], size[a] = a, size[a] + size[b]
    groups = {}
    for q in range(k):
        groups.setdefault(find(q), []).append(q)
    return [groups[r] for r in sorted(groups)]


@pytest.mark.parametrize("largest", [3, 8, 64])
def test_groups_equal_their_definition(largest):
    """Random couplings in clusters of up to 8 contacts: with a cap of 64 (and 8) every cluster is one group,
    joined without sorting the pairs; with 3 the strongest pairs first. Both as the definition."""
    rng = np.random.default_rng(11)
    k, blocks = 40, []
    for size in (8, 6, 5, 8, 3, 4, 6):
        B = rng.normal(size=(3 * size, 4))  # rank 4 per cluster: strongly coupled rows
        blocks.append(B @ B.T + 0.05 * np.eye(3 * size))
    W = scipy.linalg.block_diag(*blocks)
    perm = np.repeat(3 * rng.permutation(k), 3) + np.tile(np.arange(3), k)  # clusters interleaved
    W = W[np.ix_(perm, perm)]
    ptr, members = pgs.contact_groups(W, largest=largest)
    got = [list(members[ptr[g]:ptr[g + 1]]) for g in range(ptr.size - 1)]
    want = _reference_groups(W, 0.5, largest)
    assert got == want
    assert max(len(g) for g in got) == min(largest, 8)


def test_tied_couplings_keep_the_compiled_sort_order():
    """Identical clusters (tied couplings) beyond the group size: the pairs are joined in the order the compiled
    sort gives the ties, as before the pairs were sorted outside it."""
    rng = np.random.default_rng(5)
    B = rng.normal(size=(18, 3))
    block = B @ B.T + 0.05 * np.eye(18)  # 6 contacts of rank 3: coupled
    W = scipy.linalg.block_diag(block, block, block)
    pairs, values = pgs._coupled_pairs(W, 0.5)
    assert np.unique(values).size < values.size  # ties
    want = pgs._members(pgs._joined(pairs, pgs._strongest_first(values), 18, 4))
    got = pgs.contact_groups(W, largest=4)
    assert all(np.array_equal(a, b) for a, b in zip(got, want))


def _low_rank(seed, k=40, rank=24, compliance=1e-9):
    """A pile-like contact problem: W = B B^T (+ a trace of compliance) of rank ``rank`` for 3k rows, as
    the contacts of affine bodies see their few reduced unknowns; every contact pushed in (seeds 1 and 2
    have a solution; with a random B of low rank, not every seed does)."""
    rng = np.random.default_rng(seed)
    B = rng.normal(size=(3 * k, rank))
    B[0::3] *= 3.0  # normal rows stronger, as a body's support
    u0 = np.tile([-0.1, 0.02, -0.01], k) + 1e-3 * rng.normal(size=3 * k)
    return B @ B.T + compliance * np.eye(3 * k), u0


@pytest.mark.parametrize("seed", [1, 2])
def test_low_rank_problems_reach_the_tolerance_and_the_plain_sweeps_velocities(seed):
    W, u0 = _low_rank(seed)
    assert np.diff(pgs.contact_groups(W)[0]).max() > 1   # groups are formed
    scale = pgs.velocity_scale(u0)
    ref, _ = _solve("gauss-seidel", W, u0, 1e-10, cap=200000)
    for tol in (1e-6, 1e-10):
        lam = np.zeros_like(u0)
        sweeps = pgs.block_gauss_seidel(W, u0, lam, MU, 20000, tol)
        assert sweeps < 20000 and max(pgs.contact_residual(W, u0, lam, MU)) <= tol * scale
    # the velocities of the plain sweeps' solution (W has a null space: the impulses are not unique)
    assert np.abs(W @ (lam - ref)).max() <= 1e-8 * scale


@pytest.mark.parametrize("problem", [_low_rank(1), _twins(2), _rigid(5)])
def test_a_warm_start_at_the_solution_is_left_as_it_is(problem):
    # every group already within the tolerance is passed over: one sweep, the impulses untouched
    W, u0 = problem
    ptr, _ = pgs.contact_groups(W)
    assert np.all(np.diff(ptr) > 1)
    lam, _ = _solve("block", W, u0, 1e-8)
    warm = lam.copy()
    assert pgs.block_gauss_seidel(W, u0, warm, MU, 50, 1e-6) == 1
    assert np.array_equal(warm, lam)


def test_the_resting_stack_takes_no_more_block_sweeps_than_plain_ones():
    # the warm-started frames of the resting two-box stack, each solved from its warm start by both
    sim, seen, solve = _stack(), [], pgs.SOLVERS["block"]

    def keeping(W, u0, lam, *args):
        seen.append((W.copy(), u0.copy(), lam.copy(), args))
        return solve(W, u0, lam, *args)

    pgs.SOLVERS["block"] = keeping
    try:
        list(sim.run(30))
    finally:
        pgs.SOLVERS["block"] = solve
    block = plain = 0
    for W, u0, lam0, args in seen[10:]:
        mu, tol, floor = args[0], args[2], args[5]
        scale = max(pgs.velocity_scale(u0), floor)
        lam = lam0.copy()
        block += pgs.block_gauss_seidel(W, u0, lam, *args)
        assert max(pgs.contact_residual(W, u0, lam, mu)) <= tol * scale
        ref = lam0.copy()  # the plain sweeps, to the tolerance (they may stop short of it at their cap)
        plain += pgs.projected_gauss_seidel(W, u0, ref, *args)
        pgs.projected_gauss_seidel(W, u0, ref, mu, 100000, tol)
        assert np.abs(W @ (lam - ref)).max() <= 4 * tol * scale
    assert block <= plain
