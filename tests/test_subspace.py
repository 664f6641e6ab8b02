"""AdaptiveSubspace: full-space limit, threshold trend, stiffness, Schur solve, BFGS, downdating."""
import numpy as np
import pytest
import scipy.linalg as sla
import scipy.sparse as sp

import types

import skfem_affine as sa
from skfem_affine.integrators.potential import IncrementalPotential
from skfem_affine.reducers.subspace import linalg
from skfem_affine.reducers.subspace import oracle as so


def model_of(sim):
    """The run's fixed data read off a Simulation (the attributes a Model carries)."""
    return types.SimpleNamespace(system=sim.system, dt=sim.dt, damping=sim.damping, gravity=sim.gravity,
                                 f_gravity=sim.f_gravity, project_hessian=sim.project_hessian, size=sim.size)


def reducer(**kw):
    kw.setdefault("basis", sa.SkinningEigenmodes(n=4, cache=False))
    kw.setdefault("subdomains", 16)
    kw.setdefault("fallback", None)  # the paper's algorithm; the full-space fallback is tested on its own
    return sa.AdaptiveSubspace(**kw)


def beam(red=None, integrator="implicit_euler", **kw):
    kw.setdefault("resolution", 2)
    kw.setdefault("E", 1e5)  # the earlier soft, undamped defaults
    kw.setdefault("damping", None)
    return sa.scenes.cantilever(integrator=integrator, reducer=red, **kw)


@pytest.mark.parametrize("integrator", ["implicit_euler", "bdf2"])
def test_zero_thresholds_reproduce_the_full_space_newton_solution(integrator):
    tol = 1e-6
    red = reducer(eps_nodal=0, eps_modal=0, eps_progress=0, eps_down=0, newton_tol=tol)
    sim, full = beam(red, integrator), beam(None, integrator, newton_tol=tol)
    for _ in range(6):
        s, f = sim.step(), full.step()
    assert sim.stats[-1]["enriched_ratio"] > 0.9
    # both stop at ||d||_inf / h <= tol * size: the states agree to that accuracy
    assert np.abs(s.x - f.x).max() <= tol * sim.size * sim.dt
    assert np.abs(s.v - f.v).max() <= 10 * tol * sim.size


def test_raising_the_nodal_threshold_enriches_less_and_leaves_a_larger_residual():
    """Fig. 12's trend on a small swinging beam (no contact)."""
    ratio, residual = [], []
    for eps in (0.0, 3e-4, 1e-3, 3e-3):
        sim = beam(reducer(eps_nodal=eps, eps_modal=0.5, newton_tol=1e-4, record_residual=True))
        for _ in sim.run(10):
            pass
        ratio.append(np.mean([r["enriched_ratio"] for r in sim.stats]))
        residual.append(np.mean([r["full_residual"] for r in sim.stats]))
    assert np.all(np.diff(ratio) <= 0) and ratio[0] == 1.0 and ratio[-1] == 0.0, ratio
    assert np.all(np.diff(residual) >= 0) and residual[-1] > 100 * residual[0], residual


def test_a_very_stiff_body_gets_no_nodal_enrichment():
    eps = 1e-3
    runs = {}
    for E in (1e5, 1e9):
        sim = beam(reducer(eps_nodal=eps, eps_modal=eps), material=sa.NeoHookean(E=E, nu=0.35))
        for _ in sim.run(10):
            pass
        runs[E] = max(r["enriched_ratio"] for r in sim.stats)
    assert runs[1e5] > 0.3 and runs[1e9] == 0.0, runs


def random_spd(rng, k):
    A = rng.normal(size=(k, k))
    return A @ A.T + k * np.eye(k)


def test_schur_solve_equals_a_direct_solve_of_eq_19():
    rng = np.random.default_rng(1)
    a, ne = 7, 3 * 20
    K = random_spd(rng, a + ne)
    Hq, C, Hx = K[:a, :a], K[:a, a:], sp.csr_matrix(K[a:, a:])
    g = rng.normal(size=a + ne)
    dq, dx, iters, _ = linalg.schur_solve(Hq, C, Hx, g[:a], g[a:], tol=1e-12)
    direct = np.linalg.solve(K, -g)
    assert np.allclose(np.concatenate([dq, dx]), direct, rtol=0, atol=1e-9 * np.abs(direct).max())
    assert 0 < iters <= ne


def test_schur_solve_refuses_an_indefinite_modal_block():
    with pytest.raises(sa.solvers.SolverError, match="positive definite"):
        linalg.schur_solve(-np.eye(2), np.zeros((2, 0)), sp.csr_matrix((0, 0)), np.ones(2), np.zeros(0))


def test_schur_solve_on_a_simulated_frame_matches_the_direct_solve_to_the_pcg_tolerance():
    red = reducer(eps_nodal=3e-4, eps_modal=3e-4, pcg_tol=1e-5)
    sim = beam(red)
    for _ in sim.run(6):
        pass
    Hq, C, Hx, gq, gx = red.last_system
    assert Hx.shape[0] > 0 and Hq.shape[0] > 12  # nodes and modes were enriched
    K = np.block([[Hq, C], [C.T, Hx.toarray()]])
    g = np.concatenate([gq, gx])
    direct = np.linalg.solve(K, -g)
    dq, dx, iters, _ = linalg.schur_solve(Hq, C, Hx, gq, gx, tol=1e-5)
    err = np.linalg.norm(np.concatenate([dq, dx]) - direct) / np.linalg.norm(direct)
    assert err <= 1e-5 * np.linalg.cond(K) and err < 1e-2
    # the Schur complement system itself is solved to the tolerance
    Sdense = Hx.toarray() - C.T @ np.linalg.solve(Hq, C)
    rhs = C.T @ np.linalg.solve(Hq, gq) - gx
    assert np.linalg.norm(Sdense @ dx - rhs) <= 1.01e-5 * np.linalg.norm(rhs)


def test_bfgs_update_keeps_spd_and_satisfies_the_secant_equation():
    rng = np.random.default_rng(2)
    L, a = 5, 6
    H = np.stack([random_spd(rng, a) for _ in range(L)])
    s = rng.normal(size=a)
    Y = np.stack([random_spd(rng, a) @ s for _ in range(L)])  # y = A_l s with SPD A_l: y^T s > 0
    Y[3] = -Y[3]  # curvature condition fails here: no update
    valid = np.array([True, True, True, True, False])
    before = H.copy()
    linalg.bfgs_update(H, s, Y, valid)
    for l in range(3):
        assert np.allclose(H[l] @ s, Y[l])
        assert np.allclose(H[l], H[l].T) and np.linalg.eigvalsh(H[l]).min() > 0
    assert np.array_equal(H[3], before[3]) and np.array_equal(H[4], before[4])


def test_bfgs_subspace_hessians_stay_symmetric_positive_semidefinite_in_a_run():
    red = reducer(eps_nodal=2e-3, eps_modal=2e-3, subdomains=24)
    sim = beam(red, material=sa.NeoHookean(E=2e4, nu=0.35))
    for _ in range(8):
        sim.step()
        Hl = red.last_hessians
        for H in Hl:
            assert np.allclose(H, H.T, atol=1e-12 * max(np.abs(H).max(), 1e-300))
            assert np.linalg.eigvalsh(H).min() >= -1e-9 * max(np.abs(H).max(), 1e-300)
    assert sum(r["newton_iters"] for r in sim.stats) > 8 * 2  # BFGS updates happened
    Hq = red.last_system[0]
    assert np.linalg.eigvalsh(Hq).min() > 0


def test_downdating_drops_nodes_and_modes_that_contribute_little():
    kept = beam(reducer(eps_nodal=0, eps_modal=0, eps_down=0))
    dropped = beam(reducer(eps_nodal=0, eps_modal=0, eps_down=1e6))
    kept.step(), dropped.step()
    assert kept.reducer.enriched.any() and len(kept.reducer.active) > 1
    assert not dropped.reducer.enriched.any()
    assert dropped.reducer.active == sorted(dropped.reducer.permanent)
    assert dropped.stats[-1]["enriched_after_downdate"] == 0.0 < dropped.stats[-1]["enriched_ratio"]


def test_nodal_error_is_invariant_to_stiffness_and_resolution():
    """Eq. 5, 10: for a uniform stretch, G_i ~ ||P|| / ||dP/dF(I)||, independent of E and mesh size."""
    peak = {}
    for E, k in ((1e5, 2), (1e9, 2), (1e5, 4)):
        sim = sa.scenes.free_body(resolution=k, velocity=(0, 0, 0), spin=(0, 0, 0), integrator="implicit_euler",
                                  material=sa.NeoHookean(E=E, nu=0.3))
        sysm = sim.system
        x = sysm.p0 * np.array([1.01, 1.0, 1.0])
        data = sysm.evaluate(x)
        w = sim.dt ** 2
        ge = so.element_gradients(sysm, data.P)
        area, _ = so.node_scaling(sysm)
        G = so.OneRing(sysm).gradient_norms(w * ge, np.zeros((sysm.n, 3))) / (w * area)
        interior = np.all(np.abs(sysm.p0) < 0.49, axis=1)
        peak[(E, k)] = np.median(G[interior])
    assert peak[(1e5, 2)] == pytest.approx(peak[(1e9, 2)], rel=1e-6)
    assert peak[(1e5, 2)] == pytest.approx(peak[(1e5, 4)], rel=0.1)
    assert 1e-4 < peak[(1e5, 2)] < 1e-2  # a 1 % stretch


def test_node_scaling_of_a_single_tetrahedron():
    import skfem
    mesh = skfem.MeshTet(np.array([[0., 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]), np.array([[0], [1], [2], [3]]))
    sysm = sa.assembly.ElasticSystem([sa.ElasticBody(mesh, sa.NeoHookean(E=1e5, nu=0.3))])
    area, vol = so.node_scaling(sysm)
    Hbar = so.rest_hessian_norms(sysm)[0]
    faces = np.array([np.sqrt(3) / 2, 0.5, 0.5, 0.5])  # face opposite each vertex
    assert np.allclose(area / Hbar, faces)
    assert np.allclose(vol / Hbar, np.full(4, 1 / 24))


def test_modal_query_of_a_mode_aligned_gradient():
    rng = np.random.default_rng(3)
    U = np.linalg.qr(rng.normal(size=(12, 4)))[0]
    q = so.ModalQueries(U, [np.array([0, 1]), np.array([2, 3])])
    g = U[:, 0] * 2.0
    n_scale = np.full(4, 0.5)
    err, _ = q.measure([0, 1], g, np.zeros(4), n_scale, np.ones(4))
    assert err[0] == pytest.approx(np.linalg.norm(g.reshape(4, 3), axis=1).max() / 0.5)
    assert err[1] == pytest.approx(0.0, abs=1e-12)
    dE = np.ones(4)
    _, prog = q.measure([0], np.zeros(12), dE, n_scale, np.full(4, 2.0))
    Ub = U.reshape(4, 3, 4).mean(axis=1)[:, :2]
    expect = sum((Ub[:, c] @ dE) / (Ub[:, c] @ Ub[:, c]) * Ub[:, c].sum() / 2.0 for c in range(2))
    assert prog[0] == pytest.approx(expect)


def test_bad_input():
    with pytest.raises(ValueError, match="integrator"):
        beam(reducer(), integrator="linearized")
    with pytest.raises(TypeError, match="basis"):
        sa.AdaptiveSubspace(basis="skinning")
    with pytest.raises(ValueError, match="eps_nodal"):
        sa.AdaptiveSubspace(eps_nodal=-1)
    with pytest.raises(ValueError, match="subdomains"):
        sa.AdaptiveSubspace(subdomains=0)


def test_modal_queries_fast_path_equals_the_general_one():
    rng = np.random.default_rng(4)
    U = rng.normal(size=(30, 12))
    blocks = [np.arange(0, 4), np.arange(4, 8), np.arange(8, 12)]
    fast = so.ModalQueries(U, blocks)
    slow = so.ModalQueries(U, blocks)
    slow.uniform = False
    args = (rng.normal(size=30), rng.normal(size=10), rng.uniform(1, 2, 10), rng.uniform(1, 2, 10))
    for a, b in zip(fast.measure([0, 2], *args), slow.measure([0, 2], *args)):
        assert np.allclose(a, b)
    assert fast.uniform


def test_masked_inertia_sandwich_equals_the_direct_product():
    """B^T (M + wD + contact) B from the cached U^T (M + wD) U plus row corrections (eq. 19's H_q)."""
    rng = np.random.default_rng(5)
    nf, r = 30, 8
    red = sa.AdaptiveSubspace(basis=sa.AffineModes())
    red.U = rng.normal(size=(nf, r))
    A = sp.random(nf, nf, density=0.2, random_state=1)
    Meff = (A @ A.T + sp.eye(nf)).tocsr()
    extra = sp.lil_matrix((nf, nf))
    extra[4:7, 4:7] = np.eye(3) * 2.0
    extra = extra.tocsr()
    UMU = red.U.T @ (Meff @ red.U)
    cols = np.array([1, 3, 4, 6])
    Ua = red.U[:, cols]
    assert np.allclose(linalg.masked_sandwich(UMU, cols, extra, Ua), Ua.T @ ((Meff + extra) @ Ua))
    S = np.array([3, 4, 5, 20, 21, 22])
    B = Ua.copy()
    B[S] = 0
    Mk = (Meff + extra).tocsr()
    assert np.allclose(linalg.masked_sandwich(UMU, cols, extra, Ua, Mk, S), B.T @ (Mk @ B))


def test_two_bodies_each_get_their_own_modes_and_match_full_space():
    import skfem
    mesh = skfem.MeshTet.init_tensor(*[np.linspace(0, 0.5, 3)] * 3)
    bodies = [sa.ElasticBody(mesh, sa.NeoHookean(E=1e4, nu=0.3), velocity=(0, 0, -1.0)),
              sa.ElasticBody(mesh.translated((1.0, 0, 0)), sa.NeoHookean(E=1e4, nu=0.3), velocity=(0.5, 0, 0),
                             fixed=mesh.nodes_satisfying(lambda p: p[0] < 1e-9))]
    red = reducer(basis=sa.SkinningEigenmodes(n=2, cache=False), eps_nodal=0, eps_modal=0, eps_progress=0,
                  eps_down=0, subdomains=4, newton_tol=1e-7)
    sim = sa.Simulation(bodies, gravity=(0, 0, -9.81), integrator="bdf2", reducer=red)
    full = sa.Simulation(bodies, gravity=(0, 0, -9.81), integrator="bdf2", newton_tol=1e-7)
    assert len(red.basis.blocks) == 4 and red.basis.initial == [0, 2]
    for _ in range(4):
        s, f = sim.step(), full.step()
    assert np.abs(s.x - f.x).max() <= 1e-7 * sim.size * sim.dt


@pytest.mark.parametrize("damping", [None, sa.Rayleigh(alpha=0.5, beta=0.01)])
def test_nodal_energy_shares_sum_to_the_incremental_potential(damping):
    """Eq. 7: the per-node shares add up to E (up to a constant), so sum_i dE_i = dE."""
    sim = beam(resolution=1, damping=damping, mass="consistent")
    ip = IncrementalPotential(model_of(sim), sim.state.x, sim.state.v)
    rng = np.random.default_rng(6)
    diffs = []
    for _ in range(3):
        x = ip.x_t.copy()
        x[ip.free] += 1e-3 * rng.normal(size=ip.free.size)
        W = so.element_energies(sim.system, x.reshape(-1, 3))
        diffs.append(so.nodal_shares(ip, x, W).sum() - ip.energy(x))
    assert np.ptp(diffs) <= 1e-10 * abs(ip.energy(x))


def test_subdomain_hessians_sum_to_the_subspace_hessian():
    """Sec. 3.9: sum_l U^T H_l U over the element subdomains = U^T H U, and each H_l is PSD."""
    red = reducer(subdomains=6)
    sim = beam(red)
    sysm = sim.system
    x = sysm.p0 + np.random.default_rng(7).normal(scale=0.02, size=sysm.p0.shape)
    data = sysm.evaluate(x)
    U = red.U[:, :20]
    Hl = red.sub.exact(data.He, range(red.sub.L), U)
    H = sysm.pattern.matrix(data.H)
    assert np.allclose(Hl.sum(axis=0), U.T @ (H @ U), rtol=1e-10, atol=1e-10 * np.abs(Hl).max())
    assert all(np.linalg.eigvalsh(h).min() >= -1e-9 * np.abs(h).max() for h in Hl)
    part = red.sub.exact(data.He, [1, 3], U)  # a subset, in the order asked
    assert np.allclose(part, Hl[[1, 3]])


def test_masked_exact_sum_equals_the_dense_product():
    red = reducer(subdomains=6)
    sim = beam(red)
    sysm = sim.system
    data = sysm.evaluate(sysm.p0 + np.random.default_rng(8).normal(scale=0.02, size=sysm.p0.shape))
    U = red.U[:, :16]
    masked = np.zeros(sysm.free.size, dtype=bool)
    masked[10:40] = True
    B = U.copy()
    B[masked] = 0.0
    which = [0, 2, 5]
    expect = red.sub.exact(data.He, which, B).sum(axis=0)
    assert np.allclose(red.sub.exact_sum(data.He, which, U, masked), expect, atol=1e-10 * np.abs(expect).max())
    assert np.allclose(red.sub.exact_sum(data.He, which, U), red.sub.exact(data.He, which, U).sum(axis=0))


def test_zero_iteration_caps_and_a_wrong_problem_are_refused():
    with pytest.raises(ValueError, match="pcg_maxiter"):
        sa.AdaptiveSubspace(pcg_maxiter=0)
    with pytest.raises(ValueError, match="max_newton"):
        sa.AdaptiveSubspace(max_newton=0)
    red = reducer()
    beam(red)
    with pytest.raises(ValueError, match="implicit_euler"):
        red.solve(object())
    assert sa.AdaptiveSubspace.integrators == ("implicit_euler", "bdf2")



def test_a_stiff_spinning_cube_whose_modal_block_turns_indefinite_runs_on():
    """E = 1e9 at 3 rad/s: at frame 4 the modal block H_q of an iterate is not positive definite
    (it stopped the run); that iterate and the rest of its step take the full-space Newton
    direction, and every step stays on the full-space solution."""
    def cube(red):
        return sa.scenes.free_body(resolution=2, spin=(0, 0, 3.0), velocity=(0, 0, 0),
                                   material=sa.NeoHookean(E=1e9, nu=0.3), integrator="implicit_euler", reducer=red)
    sim, full = cube(sa.AdaptiveSubspace(eps_nodal=0.01, eps_modal=0.01)), cube(None)
    for _ in range(4):
        s, f = sim.step(), full.step()
        assert np.abs(s.x - f.x).max() <= 1e-4 * sim.size


def test_a_body_with_too_few_free_vertices_for_skinning_modes_is_refused_by_name():
    mesh = sa.scenes.box_mesh(1.0, 1)
    n = mesh.p.shape[1]
    one_free = sa.ElasticBody(mesh, sa.NeoHookean(E=1e5, nu=0.3), fixed=np.arange(n - 1), name="block")
    with pytest.raises(ValueError, match=r"SkinningEigenmodes.*body 0 \('block'\) has 1 free vertex"):
        sa.Simulation(one_free, integrator="implicit_euler", reducer=sa.AdaptiveSubspace())
    # linear modes of its 3 free DOFs, and the affine modes, run (and agree with full space)
    for basis in (sa.LinearModes(cache=False), sa.AffineModes()):
        sim = sa.Simulation(one_free, integrator="implicit_euler", gravity=(0, 0, -9.81),
                            reducer=sa.AdaptiveSubspace(basis=basis, eps_nodal=0.0, eps_progress=np.inf))
        full = sa.Simulation(one_free, integrator="implicit_euler", gravity=(0, 0, -9.81))
        for _ in range(2):
            sim.step(), full.step()
        np.testing.assert_allclose(sim.state.x, full.state.x, atol=1e-6)
