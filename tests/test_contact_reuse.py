"""Work the contact solve does once per frame (the contact frames) or on a fixed sparsity (the rigid
motions of the split impulse) gives the same frames, impulses and velocities as building them anew."""
import numpy as np
import scipy.sparse as sp

import skfem_affine as sa
from skfem_affine.contact import pgs
from skfem_affine.contact.geometry import ContactSet, tangent_basis
from skfem_affine.lab.scenes import box_mesh


def _pile(reducer=None):
    """Two small soft boxes on the ground, the upper one off centre and 0.5 mm into the lower one
    (so that the split impulse runs)."""
    mat = sa.NeoHookean(E=1e6, nu=0.35)
    bodies = [sa.ElasticBody(box_mesh(0.3, 2, (0.0, 0.0, 0.152)), mat, density=1000.0),
              sa.ElasticBody(box_mesh(0.2, 2, (0.03, -0.02, 0.4015)), mat, density=1000.0)]
    return sa.Simulation(bodies, dt=0.01, gravity=(0.0, 0.0, -9.81), colliders=[sa.Plane()], solver="direct",
                         reducer=reducer)


def _frames_anew(cs):
    t1, t2 = tangent_basis(cs.normal)
    return np.stack([cs.normal, t1, t2], axis=1)


def _rigid_motions_anew(contact, x):
    """G and C assembled from triplets each frame, the bodies' blocks of M_G summed vertex by vertex
    (the construction the fixed sparsity replaces)."""
    sysm = contact.rigid[-1]
    body = np.repeat(np.arange(len(sysm.bodies)), np.diff(sysm.vertex_offsets))
    pinned = np.zeros(len(sysm.bodies), dtype=bool)
    np.logical_or.at(pinned, body, sysm.fixed)
    movable = np.flatnonzero(~pinned[body])
    dof = np.full(3 * sysm.n, -1)
    dof[sysm.free] = np.arange(sysm.free.size)
    rank = np.cumsum(~pinned) - 1
    body, rows, nb = rank[body[movable]], dof[3 * movable[:, None] + np.arange(3)], int((~pinned).sum())
    m = sysm.lumped_mass[movable]
    centre = np.stack([np.bincount(body, m * x[movable, k], nb) for k in range(3)], axis=1)
    r = x[movable] - centre[body] / np.bincount(body, m, nb)[body, None]
    vals = np.zeros((movable.size, 3, 6))
    vals[:, :, :3] = np.eye(3)
    for i in range(3):  # omega x r = -[r]_x omega
        vals[:, i, 3:] = -np.cross(np.eye(3)[i], r)
    cols = 6 * body[:, None, None] + np.arange(6)[None, None, :]
    G = sp.csr_matrix((vals.ravel(), (np.broadcast_to(rows[:, :, None], vals.shape).ravel(),
                                      np.broadcast_to(cols, vals.shape).ravel())), shape=(sysm.free.size, 6 * nb))
    blocks = np.zeros((nb, 6, 6))
    np.add.at(blocks, body, m[:, None, None] * np.einsum("kri,krj->kij", vals, vals))
    C = np.linalg.inv(np.linalg.cholesky(blocks)).transpose(0, 2, 1)
    C = sp.block_diag(list(C), format="csr")
    return G, C


def test_contact_frames_are_computed_once_and_equal_a_fresh_basis():
    rng = np.random.default_rng(0)
    n = rng.normal(size=(7, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    cs = ContactSet(np.arange(7), np.zeros((7, 3), int), np.zeros((7, 3)), n, np.zeros(7), np.arange(7))
    F = cs.frames()
    assert cs.frames() is F and not F.flags.writeable
    assert np.array_equal(F, _frames_anew(cs))
    assert np.allclose(np.einsum("kij,klj->kil", F, F), np.eye(3))


def test_rigid_motions_on_their_fixed_sparsity_equal_the_triplet_assembly():
    sim = _pile(sa.Affinification(tau_a=1e-4, tau_e=2e-4))
    for _ in range(3):
        sim.step()
    x = sim.state.x + 0.01 * np.random.default_rng(1).normal(size=sim.state.x.shape)
    G, C = sim.contact._rigid_motions(x)
    G0, C0 = _rigid_motions_anew(sim.contact, x)
    assert np.array_equal(G.toarray(), G0.toarray()) and np.array_equal(C.toarray(), C0.toarray())


def test_a_pile_steps_the_same_with_frames_and_rigid_motions_built_anew(monkeypatch):
    """Impulses, velocities and positions of every frame equal those with the contact frames computed
    at each use and G, C assembled from triplets: bit for bit."""
    runs = {}
    for anew in (False, True):
        if anew:
            monkeypatch.setattr(ContactSet, "frames", _frames_anew)
            monkeypatch.setattr(pgs.Contact, "_rigid_motions",
                                _rigid_motions_anew)
        sim, out, split = _pile(sa.Affinification(tau_a=1e-4, tau_e=2e-4)), [], 0
        for _ in range(12):
            sim.step()
            split += sim.contact.correction is not None
            lam = sim.contact.lam.copy() if sim.contact.current is not None else np.zeros(0)
            out.append((lam, sim.state.v.copy(), sim.state.x.copy()))
        runs[anew] = out
        assert split > 5  # the split impulse ran
    for (lam, v, x), (lam0, v0, x0) in zip(runs[False], runs[True]):
        assert np.array_equal(lam, lam0) and np.array_equal(v, v0) and np.array_equal(x, x0)
