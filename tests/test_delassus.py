"""The Delassus operator W = J A^-1 J^T from the unknowns contacts touch (Schur complement or solves of
their unit columns), against the plain path of 3 solves per contact, in full and reduced space."""
import gc

import numpy as np
import pytest
import scipy.sparse as sp

import skfem_affine as sa
from skfem_affine import solvers
from skfem_affine.contact import delassus
from skfem_affine.contact.pgs import projected_gauss_seidel

needs_pardiso = pytest.mark.skipif(not solvers.has_pardiso(), reason="pypardiso not installed")


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
def test_delassus_equals_the_plain_path(scene, reducer, monkeypatch):
    monkeypatch.setattr(delassus, "SCHUR_MIN", 1)  # the Schur complement however few the unknowns
    sim = sa.scenes.SCENES[scene](**SCENES[scene], reducer=REDUCERS[reducer]())
    schur = delassus.schur_solver()

    def check(op, J):
        ref, Jr, Y = plain_delassus(op, J)
        scale = np.abs(ref).max()
        for path in ([schur, None] if schur is not None else [None]):
            res = delassus.Resolvent(op, block=7, schur=path)
            W = res.delassus(J)
            assert np.abs(W - ref).max() <= 1e-9 * scale, (path, np.abs(W - ref).max() / scale)
            lam = np.random.default_rng(1).normal(size=J.shape[0])
            dv = res.apply(lam)
            want = Y @ lam
            want = op.G @ want if op.G is not None else want
            assert np.abs(dv - want).max() <= 1e-9 * np.abs(want).max()
            half = 3 * max(1, J.shape[0] // 6)  # fewer contacts: the Schur analysis of all of them is kept
            ref2 = plain_delassus(op, J[:half])[0]
            W2 = delassus.Resolvent(op, block=7, schur=path).delassus(J[:half])
            assert np.abs(W2 - ref2).max() <= 1e-9 * np.abs(ref2).max()

    assert frames_with_contact(sim, 120, check) == 3


@needs_pardiso
def test_schur_complement_is_the_inverse_on_the_kept_unknowns():
    rng = np.random.default_rng(0)
    n = 60
    B = sp.random(n, n, density=0.05, random_state=1)
    A = sp.csr_matrix(B @ B.T + sp.eye(n) * 2.0)
    Ainv = np.linalg.inv(A.toarray())
    sc = solvers.PardisoSchur()
    for keep in (np.arange(0, n, 3), np.arange(0, n, 3), np.sort(rng.choice(n, 17, replace=False)), [5]):
        keep = np.asarray(keep)
        S = sc.complement(A, keep)
        assert np.allclose(np.linalg.inv(S), Ainv[np.ix_(keep, keep)], rtol=1e-10, atol=1e-13)
    A2 = sp.csr_matrix(A * 3.0)  # same pattern and set: a numeric factorisation only
    S = sc.complement(A2, np.array([5]))
    assert np.isclose(1.0 / S[0, 0], Ainv[5, 5] / 3.0)
    S = sc.complement(sp.triu(A2, format="csr"), np.array([1, 4]), upper=True)
    assert np.allclose(np.linalg.inv(S), Ainv[np.ix_([1, 4], [1, 4])] / 3.0)
    for bad in ([], [3, 3], [4, 2], [n]):
        with pytest.raises(ValueError, match="keep"):
            sc.complement(A, np.asarray(bad, dtype=int))


def _rigid_box_on_plane():
    """A stiff box thrown sideways onto the plane: rigidification keeps it one rigid body."""
    mesh = sa.scenes.box_mesh(0.3, 3, (0.0, 0.0, 0.16))
    body = sa.ElasticBody(mesh, sa.NeoHookean(E=1e8, nu=0.3), density=1000.0, velocity=(1.0, 0.0, -0.5))
    return sa.Simulation([body], dt=0.01, gravity=(0, 0, -9.81), colliders=[sa.Plane((0, 0, 0), (0, 0, 1))],
                         reducer=sa.Rigidification(tau_r=10.0))


def test_body_block_contacts_equal_vertex_contacts_on_a_rigid_body(monkeypatch):
    monkeypatch.setattr(delassus, "SCHUR_MIN", 1)
    sim = _rigid_box_on_plane()

    def check(op, J):
        assert op.G.shape[1] == 6  # the whole box is one rigid body
        k = J.shape[0] // 3
        assert k >= 9  # a face of vertices touches
        ref, Jr, Y = plain_delassus(op, J)  # 3 solves per vertex contact
        for path in [delassus.schur_solver(), None][int(not solvers.has_pardiso()):]:
            res = delassus.Resolvent(op, schur=path)
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


def _factorisations():
    return sum(isinstance(o, (solvers.Pardiso, solvers.SuperLU)) for o in gc.get_objects())


def test_factorisations_held_for_contact_stay_bounded():
    """Over many frames with changing contact sets, the contact keeps no growing set of factorisations."""
    sim = sa.scenes.pills(n=2, resolution=1, reducer=sa.Affinification(tau_a=1.0, tau_e=2.0))
    counts, sizes = [], set()
    for i, _ in enumerate(sim.run(40)):
        if sim.contact.current is not None:
            sizes.add(sim.contact.current.key.tobytes())
        if i in (10, 39):
            gc.collect()
            counts.append(_factorisations())
    assert len(sizes) > 5  # the contact sets did change
    assert counts[1] <= counts[0] <= 4
