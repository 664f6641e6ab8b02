"""The Delassus operator W = J A^-1 J^T (per body, through G when reduced) against the plain path of
3 solves per contact on the frame's factorisation, and its per-block solver cache stays bounded."""
import numpy as np
import pytest
import scipy.sparse as sp

import skfem_affine as sa
from skfem_affine.contact import delassus
from skfem_affine.contact.pgs import projected_gauss_seidel
from skfem_affine.integrators.problem import Operator
from skfem_affine.solvers import SuperLU


def plain_delassus(operator, J):
    """The plain path: A^-1 applied to every column of (J G)^T (3 solves per contact), W = (J G) A^-1 (J G)^T."""
    Jr = (J @ operator.G) if operator.G is not None else J
    R = sp.csr_matrix(Jr).T.toarray()
    if operator.iterative:
        Y = np.column_stack([operator.solver.solve(R[:, j]) for j in range(R.shape[1])])
    else:
        Y = np.asarray(operator.solver.solve(R)).reshape(R.shape)
    W = sp.csr_matrix(Jr) @ Y
    return 0.5 * (W + W.T), Jr, Y


def frames_with_contact(sim, frames, check, want=3):
    """Calls ``check(operator, J)`` in up to ``want`` frames with contacts (reduced ones when the run
    is reduced), while the frame's solver holds that frame's factorisation; returns the count."""
    done, original = [], sim.contact.resolve

    def spy(problem, result, rec):
        op, cs = result.operator, sim.contact.current
        if cs is not None and cs.size and (sim.reducer is None or op.G is None or op.G.shape[1] < op.G.shape[0]):
            check(op, cs.J)
            done.append(True)
        return original(problem, result, rec)

    sim.contact.resolve = spy
    for _ in sim.run(frames):
        if len(done) >= want:
            break
    assert done, "no frame with contact"
    return len(done)


REDUCERS = {"full": lambda: None, "affine": lambda: sa.Affinification(tau_a=1.0, tau_e=2.0),
            "rigid": lambda: sa.Rigidification(tau_r=0.05)}
SCENES = {"drop": dict(resolution=1, shape="box"), "stacked_beams": dict(resolution=1),
          "pills": dict(n=3, resolution=1)}


@pytest.mark.parametrize("reducer", list(REDUCERS))
@pytest.mark.parametrize("scene", list(SCENES))
def test_delassus_equals_the_plain_path(scene, reducer):
    sim = sa.scenes.SCENES[scene](**SCENES[scene], reducer=REDUCERS[reducer]())

    def check(op, J):
        ref, Jr, Y = plain_delassus(op, J)
        scale = np.abs(ref).max()
        res = delassus.Resolvent(op, block=7, cache={})
        W = res.delassus(J)
        assert np.abs(W - ref).max() <= 1e-9 * scale, np.abs(W - ref).max() / scale
        lam = np.random.default_rng(1).normal(size=J.shape[0])
        dv = res.apply(lam)
        want = Y @ lam
        want = op.G @ want if op.G is not None else want
        assert np.abs(dv - want).max() <= 1e-9 * np.abs(want).max()

    assert frames_with_contact(sim, 120, check) == 3


def _rigid_box_on_plane():
    """A stiff box thrown sideways onto the plane: rigidification keeps it one rigid body."""
    mesh = sa.scenes.box_mesh(0.3, 3, (0.0, 0.0, 0.16))
    body = sa.ElasticBody(mesh, sa.NeoHookean(E=1e8, nu=0.3), density=1000.0, velocity=(1.0, 0.0, -0.5))
    return sa.Simulation([body], dt=0.01, gravity=(0, 0, -9.81), colliders=[sa.Plane((0, 0, 0), (0, 0, 1))],
                         reducer=sa.Rigidification(tau_r=10.0))


def test_contacts_on_a_rigid_body_touch_its_six_dofs_and_match_the_plain_path():
    sim = _rigid_box_on_plane()

    def check(op, J):
        assert op.G.shape[1] == 6  # the whole box is one rigid body
        k = J.shape[0] // 3
        assert k >= 9  # a face of vertices touches
        ref, Jr, Y = plain_delassus(op, J)  # 3 solves per vertex contact
        res = delassus.Resolvent(op, cache={})
        W = res.delassus(J)
        assert np.unique(res.Jr.indices).size == 6  # the contacts touch the body's 6 DOFs only
        assert np.abs(W - ref).max() <= 1e-10 * np.abs(ref).max()
        u0 = J @ np.tile([1.0, 0.0, -0.5], J.shape[1] // 3)  # sliding into the plane
        lam, lam_ref = np.zeros(3 * k), np.zeros(3 * k)
        projected_gauss_seidel(W, u0, lam, 0.5, 200, 1e-12)
        projected_gauss_seidel(ref, u0, lam_ref, 0.5, 200, 1e-12)
        assert np.allclose(lam, lam_ref, rtol=1e-8, atol=1e-10 * np.abs(lam_ref).max())
        dv, dv_ref = res.apply(lam), op.G @ (Y @ lam_ref)
        assert np.allclose(dv, dv_ref, atol=1e-9 * np.abs(dv_ref).max())

    assert frames_with_contact(sim, 30, check, want=1) == 1


def _laplacian(m):
    """An SPD chain of m unknowns (one component)."""
    return sp.diags([-np.ones(m - 1), 3.0 * np.ones(m), -np.ones(m - 1)], [-1, 0, 1], format="csr")


def test_block_solver_cache_holds_one_frames_blocks():
    """Components (bodies, or a reduced frame's clusters) change from frame to frame: the cache of
    per-block solvers keeps only the blocks of the current frame, however many frames pass."""
    rng = np.random.default_rng(0)
    cache = {}
    for frame in range(12):
        sizes = rng.integers(delassus.BLOCK_DENSE_MAX + 1, delassus.BLOCK_DENSE_MAX + 60, size=3)
        A = sp.block_diag([_laplacian(int(m)) for m in sizes], format="csr")
        solver = SuperLU()
        solver.factorize(A)
        n = A.shape[0]
        cols = rng.choice(n, 6, replace=False)
        J = sp.csr_matrix((np.ones(6), (np.arange(6), cols)), shape=(6, n))
        res = delassus.Resolvent(Operator(solver, A), cache=cache)
        W = res.delassus(J)
        E = np.zeros((n, 6))
        E[cols, np.arange(6)] = 1.0
        assert np.allclose(W, solver.solve(E)[cols], atol=1e-12)
        touched = len({int(np.searchsorted(np.cumsum(sizes), c, side="right")) for c in cols})
        assert len(cache) == touched <= 3
