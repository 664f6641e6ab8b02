"""AdaptiveSubspace with IPC contact: enrichment follows contact (ground and body-body), the
result stays intersection-free and close to full-space IPC Newton; the full-space fallback."""
import numpy as np
import pytest

import skfem_affine as sa
from skfem_affine.reducers.subspace.reducer import coupled_nonzeros, falls_back


def drop(reducer, frames_apart=0.02):
    """A soft 0.5 m box (384 tets) at 2 m/s, ``frames_apart`` above a plane, friction 0.3."""
    return sa.scenes.drop(resolution=2, shape="box", size=0.5, height=frames_apart, velocity=(0, 0, -2.0),
                          material=sa.NeoHookean(E=1e4, nu=0.35), integrator="implicit_euler",
                          contact=sa.IPC(friction=0.3), reducer=reducer, newton_tol=1e-3)


def two_cubes(reducer, cells=3):
    """A soft cube at 2 m/s onto another resting on a plane (body-body and ground contact)."""
    def cube(z, v):
        mesh = sa.scenes.box_mesh((0.5, 0.5, 0.5), (cells,) * 3, center=(0.0, 0.0, z))
        return sa.ElasticBody(mesh, sa.NeoHookean(E=1e4, nu=0.35), density=1000.0, velocity=(0.0, 0.0, v))
    return sa.Simulation([cube(0.251, 0.0), cube(0.251 + 0.52, -2.0)], dt=0.01, gravity=(0, 0, -9.81),
                         integrator="implicit_euler", colliders=[sa.Plane((0, 0, 0), (0, 0, 1))],
                         contact=sa.IPC(friction=0.3), reducer=reducer, newton_tol=1e-3)


def subspace(**kw):
    kw.setdefault("basis", sa.SkinningEigenmodes(n=16, cache=False))
    kw.setdefault("eps_nodal", 0.05)
    kw.setdefault("eps_modal", 0.05)
    return sa.AdaptiveSubspace(**kw)


def body_contact_vertices(contact, x):
    """Mesh vertices in a surface-surface collision stencil within dhat (between the bodies)."""
    cc = contact._collisions(x.reshape(-1))
    ids = set()
    for i in range(len(cc)):
        ids |= {int(j) for j in cc[i].vertex_ids(contact.mesh.edges, contact.mesh.faces) if j >= 0}
    return contact.surface[sorted(ids)]


def test_contact_energy_enters_the_oracles_nodal_shares():
    """The oracle's nodal energy shares (eq. 7) include IPC's barrier and friction per vertex and
    sum to E; its point gradients include the contact gradient."""
    from skfem_affine.reducers.subspace import oracle as so
    sim = two_cubes(None, cells=2)
    for _ in range(3):
        sim.step()
    ip = sim.integrator.potential(sim.state)
    contact = ip.barrier
    contact.begin_step(ip.x_t, ip.x_hat, ip.c)
    x = ip.x_t
    assert contact.lagged is not None and len(contact.lagged[2]) > 0  # body-body friction active
    W = so.element_energies(sim.system, x.reshape(-1, 3))
    shares = so.nodal_shares(ip, x, W)
    # the shares sum to E up to a constant: their change is E's change
    y = x.copy()
    y[ip.free] += 1e-4 * np.random.default_rng(0).normal(size=ip.free.size)
    Wy = so.element_energies(sim.system, y.reshape(-1, 3))
    assert ip.energy(y) - ip.energy(x) == pytest.approx(so.nodal_shares(ip, y, Wy).sum() - shares.sum(), rel=1e-8)
    cv = contact.vertex_energy(x)
    assert cv[body_contact_vertices(contact, x)].min() > 0  # the contacting vertices carry contact energy
    point = so.point_gradients(ip, x)
    g_contact = np.zeros(x.size)
    g_contact[ip.free] = ip.weight * contact.gradient(x)
    assert np.abs(g_contact).max() > 0
    # removing contact from the point stencils changes them exactly by the contact gradient
    ip.barrier = None
    assert np.allclose(point - so.point_gradients(ip, x), g_contact.reshape(-1, 3))


@pytest.mark.slow
def test_enrichment_follows_contact_with_the_ground():
    """At and after impact the vertices within dhat of the plane are enriched; each state is
    intersection-free and within 1 % of the scene size of full-space IPC Newton."""
    red = subspace(subdomains=24, fallback=None)
    sim, full = drop(red), drop(None)
    contact = sim.integrator.barrier
    touched = 0
    for frame in range(6):
        near = np.flatnonzero(sim.state.x[:, 2] < contact.dhat)  # in contact at the start of the step
        s, f = sim.step(), full.step()
        assert contact.intersection_free(s.x.reshape(-1))
        assert np.abs(s.x - f.x).max() < 0.01 * sim.size
        if near.size:
            touched += 1
            assert red.step_enriched[near].mean() >= 0.8, (frame, red.step_enriched[near].mean())
            # enrichment sits at the contact: the enriched vertices are in the lower half of the box
            z = s.x[red.step_enriched, 2]
            assert np.mean(z < s.x[:, 2].mean()) >= 0.8
    assert touched >= 3
    assert any(r["enriched_ratio"] > 0 for r in sim.stats) and all(r["reduced"] for r in sim.stats)


@pytest.mark.slow
def test_enrichment_follows_contact_between_bodies():
    """A cube landing on another: in the steps that start in body-body contact, most vertices of
    the contact are enriched; in the falling cube, which touches nothing else, its far half (more
    than half its height above the contact) is enriched at most half as much as its contact; no surface
    intersects; the error against full-space IPC Newton stays below 1 % of the size.

    The whole scene is no yardstick: the lower cube touches the ground as well, so the oracle
    rightly enriches both of its faces, and the 4-vertex subdomains that carry them reach into
    its interior in a shape that depends on the METIS build."""
    red = subspace(subdomains=32, fallback=None)
    sim, full = two_cubes(red), two_cubes(None)
    contact = sim.integrator.barrier
    falling = np.flatnonzero(sim.state.x[:, 2] > 0.51)  # the upper cube (the lower one spans z < 0.51)
    covered = []
    for _ in range(3):
        x = sim.state.x
        near = body_contact_vertices(contact, x)  # in contact at the start of the step
        far = falling[x[falling, 2] > x[falling, 2].min() + 0.25]
        s, f = sim.step(), full.step()
        assert contact.intersection_free(s.x.reshape(-1))
        assert np.abs(s.x - f.x).max() < 0.01 * sim.size
        if near.size:
            e = red.step_enriched
            covered.append((e[near].mean(), e[np.intersect1d(near, falling)].mean(), e[far].mean()))
    assert len(covered) >= 2
    for at_contact, falling_contact, falling_far in covered[:2]:  # the impact steps
        assert at_contact >= 0.5 and falling_contact >= 0.3 and falling_far <= 0.5 * falling_contact, covered


def test_falls_back_when_the_coupled_system_outgrows_the_full_one():
    """The default rule counts nonzeros: r^2 + 2 r s + rho s against the full system's nnz;
    a number is a fraction of the free DOFs; None never falls back."""
    nfree, nnz = 3000, 3000 * 40  # 40 nonzeros per row
    assert coupled_nonzeros(300, 100, 40) == 100 ** 2 + 2 * 100 * 300 + 40 * 300
    # the crossover: s* = (nnz - r^2) / (2 r + rho) = (120000 - 10000) / 240 = 458.3 DOFs
    assert not falls_back(458, nfree, 100, nnz) and falls_back(459, nfree, 100, nnz)
    # fewer active columns tolerate more enrichment
    assert not falls_back(459, nfree, 50, nnz) and falls_back(459, nfree, 200, nnz)
    assert not falls_back(600, nfree, 100, nnz, 0.2) and falls_back(601, nfree, 100, nnz, 0.2)
    assert not falls_back(nfree, nfree, 100, nnz, None) and not falls_back(0, nfree, 100, nnz, 0.0)
    for bad in (1.5, -0.1, "often", True):
        with pytest.raises(ValueError, match="fallback"):
            sa.AdaptiveSubspace(fallback=bad)


@pytest.mark.slow
def test_the_fallback_solves_in_full_space_and_returns_when_enrichment_is_released():
    """fallback=0: as soon as the oracle enriches, the step continues by full-space Newton
    (``rec["reduced"]`` False) and gives full Newton's trajectory; without fallback the same
    scene stays reduced; the stats name the solver."""
    off = subspace(subdomains=24, fallback=None)
    sim_off = drop(off)
    red = subspace(subdomains=24, fallback=0.0)
    sim, full = drop(red), drop(None)
    for _ in range(5):
        s, f = sim.step(), full.step()
        sim_off.step()
        assert np.abs(s.x - f.x).max() < 0.01 * sim.size
    flags = [r["reduced"] for r in sim.stats]
    assert not all(flags)                                  # contact enriched: full-space steps
    assert all(r["reduced"] for r in sim_off.stats)
    assert any(r["enriched_ratio"] > 0 for r in sim_off.stats)
    for r in sim.stats:
        assert r["solver"] == ("schur-pcg" if r["reduced"] else red.fallback_solver.name)
    # the default rule (nonzeros) falls back on this small scene once contact enriches
    dflt = subspace(subdomains=24)
    sim_d = drop(dflt)
    for _ in range(3):
        sim_d.step()
    assert sim_d.stats[0]["reduced"] and not all(r["reduced"] for r in sim_d.stats)
    # a step that starts with no enriched node and enriches none stays reduced
    quiet = subspace(subdomains=24, fallback=0.0, eps_nodal=1e9, eps_modal=1e9)
    sim_q = drop(quiet, frames_apart=0.3)
    sim_q.step()
    assert sim_q.stats[-1]["reduced"] and sim_q.stats[-1]["enriched_ratio"] == 0


def test_after_a_full_space_step_downdating_releases_nodes_the_subspace_captures():
    """The full step's displacement is fitted on the active modes; a rigid translation is fitted
    exactly, so every enriched node is released and the next step is reduced again."""
    red = subspace(subdomains=8, fallback=0.0)
    sim = sa.scenes.free_body(resolution=2, velocity=(0, 0, -1.0), spin=(0, 0, 0), integrator="implicit_euler",
                              reducer=red, newton_tol=1e-6)
    sim.step()
    red.enriched[:] = red.free_vertex      # as if contact had enriched everything
    sim.step()
    assert sim.stats[-1]["reduced"] is False and sim.stats[-1]["enriched_after_downdate"] == 0.0
    sim.step()
    assert sim.stats[-1]["reduced"] is True
