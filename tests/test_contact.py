"""Contact: detection, PGS, Delassus through G, and the physical checks of issue 4."""
import numpy as np
import pytest
import scipy.sparse as sp
import skfem

import skfem_affine as sa
from skfem_affine.contact import delassus, geometry
from skfem_affine.contact import pgs as contact
from skfem_affine.lab.scenes import box_mesh

G_ACC = 9.81


def _block(size=0.2, cells=2, z0=0.0, E=1e6, R=None, **kw):
    mesh = box_mesh(size, cells, (0.0, 0.0, z0 + size / 2))
    if R is not None:
        mesh = skfem.MeshTet(R @ mesh.p, mesh.t)
    return sa.ElasticBody(mesh, sa.NeoHookean(E=E, nu=0.3), density=1000.0, **kw)


# ---------------------------------------------------------------------------- geometry
def test_closest_points_on_triangles_against_sampling():
    rng = np.random.default_rng(0)
    k = 200
    a, b, c = (rng.normal(size=(k, 3)) for _ in range(3))
    p = 1.5 * rng.normal(size=(k, 3))
    W = geometry.closest_points_on_triangles(p, a, b, c)
    assert np.all(W >= -1e-12) and np.allclose(W.sum(axis=1), 1.0)
    q = W[:, :1] * a + W[:, 1:2] * b + W[:, 2:] * c
    s = np.linspace(0, 1, 201)
    u, v = [g.ravel() for g in np.meshgrid(s, s)]
    keep = u + v <= 1
    u, v = u[keep], v[keep]
    samples = a[:, None] + u[None, :, None] * (b - a)[:, None] + v[None, :, None] * (c - a)[:, None]
    brute = np.linalg.norm(samples - p[:, None], axis=2).min(axis=1)
    exact = np.linalg.norm(q - p, axis=1)
    assert np.all(exact <= brute + 1e-12)
    assert np.allclose(exact, brute, atol=2e-2 * np.linalg.norm(b - a, axis=1).max() / 200 * 10)


def test_boundary_surface_is_closed_and_outward():
    sim = sa.scenes.pills(n=2)
    tris, owner = geometry.boundary_surface(sim.system)
    x = sim.system.p0
    for b in range(2):
        t = tris[owner == b]
        a, bb, c = x[t[:, 0]], x[t[:, 1]], x[t[:, 2]]
        # divergence theorem: the enclosed volume from outward triangles equals the mesh volume
        vol = np.einsum("ij,ij->i", a, np.cross(bb, c)).sum() / 6.0
        body_vol = sim.system.volumes[sim.system.body_of_element == b].sum()
        assert vol == pytest.approx(body_vol, rel=1e-10)


def test_body_contact_measures_overlap_and_ignores_edges():
    lower = _block(0.4, 2)
    overlap = 0.01
    upper = _block(0.2, 2, z0=0.4 - overlap)
    beside = sa.ElasticBody(box_mesh(0.2, 1, (0.31, 0.0, 0.5)), sa.NeoHookean(E=1e6, nu=0.3))  # off the edge
    sim = sa.Simulation([lower, upper, beside], contact=sa.PGS(margin=0.005))
    cs = sim.contact.detector.find(sim.state.x, sim.state.v, sim.dt)
    body = sim.contact.detector.body_of_vertex
    up = body[cs.vertex] == 1
    assert np.allclose(cs.distance[up], -overlap)                 # the upper box's bottom inside the lower
    assert np.allclose(cs.normal[up], [0, 0, 1])
    low = (body[cs.vertex] == 0)
    assert np.allclose(cs.distance[low], -overlap) and np.allclose(cs.normal[low], [0, 0, -1])
    assert up.sum() == 9 and low.sum() == 1   # the upper bottom's 3 x 3 vertices; the lower top's centre
    side = body[cs.vertex] == 2
    assert np.all(cs.distance[side] > 0)                          # beside an edge is not inside



def test_gravity_alone_takes_one_pass_over_body_pairs(monkeypatch):
    """v + h g - v is h g only up to rounding: the relative approach speeds are those of v, and
    the pairs between bodies (vertex and edge) are searched once, not once per velocity."""
    lower, upper = _block(0.4, 2), _block(0.2, 2, z0=0.401)
    sim = sa.Simulation([lower, upper], contact=sa.PGS(margin=0.005))
    det = sim.contact.detector
    rng = np.random.default_rng(0)
    x, v = sim.state.x, rng.normal(scale=0.3, size=sim.state.x.shape)
    calls = []
    find = det.edge_pairs.find
    monkeypatch.setattr(det.edge_pairs, "find", lambda *a, **k: calls.append(1) or find(*a, **k))
    w = v + sim.dt * np.array([0.0, 0.0, -9.81])
    assert np.ptp(w - v, axis=0).any()                            # the rounding the test is about
    cs, ref = det.find(x, v, sim.dt, w), det.find(x, v, sim.dt)
    assert len(calls) == 2                                         # one pass per call
    body = det.body_contacts(cs)
    assert np.array_equal(cs.key[body], ref.key[det.body_contacts(ref)])
    w[0] += 1.0                                                   # a non-uniform change: both velocities
    det.find(x, v, sim.dt, w)
    assert len(calls) == 4

# ---------------------------------------------------------------------------- PGS
def test_pgs_single_contact_closed_form_and_cone():
    W = np.diag([2.0, 4.0, 4.0])
    lam = np.zeros(3)
    sweeps = contact.projected_gauss_seidel(W, np.array([-1.0, -3.0, 3.0]), lam, 0.5, 50, 1e-12)
    assert lam[0] == pytest.approx(0.5)                            # stops the approach: u_n = 0
    # the unconstrained tangent impulse (0.75, -0.75) is projected onto the disk |lam_t| <= mu lam_n
    assert np.allclose(lam[1:], 0.25 * np.array([1, -1]) / np.sqrt(2)) and sweeps <= 3
    # separating contacts carry no impulse
    lam = np.zeros(3)
    contact.projected_gauss_seidel(W, np.array([1.0, -3.0, 3.0]), lam, 0.5, 50, 1e-12)
    assert np.all(lam == 0)


def test_pgs_solves_a_coupled_lcp():
    rng = np.random.default_rng(3)
    k = 6
    B = rng.normal(size=(3 * k, 3 * k))
    W = B @ B.T + 3 * k * np.eye(3 * k)
    u0 = rng.normal(size=3 * k)
    lam = np.zeros(3 * k)
    contact.projected_gauss_seidel(W, u0, lam, 0.4, 500, 1e-13)
    u = u0 + W @ lam
    ln, un = lam[0::3], u[0::3]
    lt = lam.reshape(-1, 3)[:, 1:]
    ut = u.reshape(-1, 3)[:, 1:]
    scale = np.abs(u0).max()  # velocities; impulses scale as u0 / W
    assert np.all(ln >= 0) and np.all(un >= -1e-9 * scale)
    assert np.allclose(ln * un, 0, atol=1e-9 * scale * np.abs(ln).max())
    assert np.all(np.linalg.norm(lt, axis=1) <= 0.4 * ln + 1e-12)
    # sticking contacts have zero slip; sliding ones oppose the slip (maximal dissipation)
    inside = np.linalg.norm(lt, axis=1) < 0.4 * ln - 1e-9
    assert np.allclose(ut[inside], 0, atol=1e-8)
    sliding = (ln > 1e-9) & ~inside
    cosine = -np.einsum("ij,ij->i", lt[sliding], ut[sliding]) / (
        np.linalg.norm(lt[sliding], axis=1) * np.linalg.norm(ut[sliding], axis=1))
    assert np.allclose(cosine, 1.0, atol=1e-6)


# ---------------------------------------------------------------------------- Delassus
@pytest.mark.parametrize("scene,reducer", [("drop", None), ("drop", "affine"), ("bowling", "affine"),
                                           ("bowling", None)])
def test_delassus_equals_dense_inverse_through_G(scene, reducer):
    red = sa.Affinification(tau_a=1.0, tau_e=2.0) if reducer else None
    sim = sa.scenes.SCENES[scene](resolution=1, reducer=red)
    captured = {}
    original = sim.contact.resolve

    def spy(problem, result, rec):
        captured.clear()
        if sim.contact.current is not None:
            resolvent = delassus.Resolvent(result.operator, block=sim.contact.settings.block)
            captured["W"] = resolvent.delassus(sim.contact.current.J)
            captured["resolvent"] = resolvent
            captured["operator"] = result.operator
        return original(problem, result, rec)

    sim.contact.resolve = spy
    for state in sim.run(80):
        op = captured.get("operator")
        if "W" in captured and sim.contact.current.size > 3 and (red is None or op.G.shape[1] != op.G.shape[0]):
            break
    J = sim.contact.current.J.toarray()
    if red is None:
        assert op.G is None
        Ainv = np.linalg.inv(op.matrix.toarray())
    else:
        G = op.G.toarray()
        Ainv = G @ np.linalg.inv(op.matrix.toarray()) @ G.T
        assert op.G.shape[1] != op.G.shape[0]  # really reduced (either numbering)
    assert np.allclose(captured["W"], J @ Ainv @ J.T, rtol=1e-8, atol=1e-12 * np.abs(captured["W"]).max())
    lam = np.random.default_rng(0).normal(size=J.shape[0])
    assert np.allclose(captured["resolvent"].apply(lam), Ainv @ J.T @ lam, atol=1e-10 * np.abs(Ainv @ J.T @ lam).max())


def test_no_contact_code_without_colliders_or_second_body(monkeypatch):
    def refuse(*args, **kwargs):
        raise AssertionError("contact code ran")

    monkeypatch.setattr(contact.Contact, "__init__", refuse)
    sim = sa.scenes.free_body(resolution=1)
    for _ in sim.run(3):
        pass
    assert sim.contact is None and sim.stats.total("contact") == 0.0
    assert sim.contact_model == "none" and all(r["contact_model"] == "none" for r in sim.stats)
    assert sim.stats.summary()["contact_s"] == 0.0


# ---------------------------------------------------------------------------- physics
@pytest.mark.parametrize("reducer", [None, "affinification"])
def test_resting_body_sinks_less_than_one_percent(reducer):
    height = 0.2
    red = sa.Affinification(tau_a=0.5, tau_e=1.0) if reducer else None
    sim = sa.Simulation(_block(height, 2), dt=0.01, gravity=(0, 0, -G_ACC), colliders=[sa.Plane()], reducer=red)
    lowest = min(s.x[:, 2].min() for s in sim.run(300))
    assert -lowest < 0.01 * height
    assert sim.state.x[:, 2].max() < height * 1.01  # resting, not bouncing away
    if red is not None:
        assert np.mean([r["reduced_fraction"] for r in sim.stats]) > 0.5


def _incline(mu, theta, frames=100):
    c, s = np.cos(theta), np.sin(theta)
    R = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])   # turns the flat block and plane by theta about y
    sim = sa.Simulation(_block(0.2, 2, R=R), dt=0.01, gravity=(0, 0, -G_ACC), colliders=[sa.Plane(normal=R[:, 2])],
                        contact=sa.PGS(friction=mu))
    m = sim.system.lumped_mass
    down = R[:, 0]  # downhill along the plane
    vel = np.array([(m @ st.v) / m.sum() @ down for st in sim.run(frames)])
    return vel, sim


@pytest.mark.parametrize("mu", [0.1, 0.25])
def test_block_slides_down_an_incline_with_coulomb_friction(mu):
    theta = np.radians(20)
    vel, sim = _incline(mu, theta)
    t = sim.dt * np.arange(1, len(vel) + 1)
    a = np.polyfit(t[20:], vel[20:], 1)[0]
    expected = G_ACC * (np.sin(theta) - mu * np.cos(theta))
    assert a == pytest.approx(expected, rel=0.05)


def test_block_sticks_on_an_incline_when_friction_exceeds_tan_theta():
    theta = np.radians(20)
    vel, sim = _incline(1.2 * np.tan(theta), theta)
    # after settling, the centre of mass does not creep: < 0.1 mm over the last 70 frames
    assert abs(vel[30:].sum() * sim.dt) < 1e-4
    # and just below tan(theta) it slides
    vel, _ = _incline(0.8 * np.tan(theta), theta)
    assert vel[-1] > 0.5


@pytest.mark.parametrize("reducer", [None, "affinification"])
def test_zero_restitution_drop_never_gains_energy(reducer):
    red = sa.Affinification(tau_a=0.5, tau_e=1.0) if reducer else None
    sim = sa.scenes.drop(resolution=1, height=0.1, reducer=red)
    energy = [sim.energy()["total"]]
    for _ in sim.run(60):
        energy.append(sim.energy()["total"])
    contacts = np.array([r["n_contacts"] for r in sim.stats])
    assert contacts[:5].max() == 0 and contacts[-20:].min() > 0  # it did hit the plane
    steps = np.diff(energy)
    assert steps.max() <= 1e-9 * abs(energy[0])


@pytest.mark.parametrize("scene,kwargs,tolerance", [
    ("stacked_beams", dict(resolution=2, n=2), 1e-3),          # 1 mm: 0.25 % of the beams' width
    ("pills", dict(n=8, resolution=1, solver="superlu"), 0.01),  # 1 cm: 10 % of a pill's radius
])
@pytest.mark.slow
def test_stacks_run_200_frames_without_deep_interpenetration(scene, kwargs, tolerance):
    sim = sa.scenes.SCENES[scene](**kwargs)
    deepest = 0.0
    for s in sim.run(200):
        cs = sim.contact.current
        if cs is not None:
            deepest = min(deepest, cs.distance.min())
    assert np.all(np.isfinite(s.x)) and np.all(np.isfinite(s.v))
    assert -deepest < tolerance
    d, _ = sim.colliders[0].query(s.x)  # every vertex, not only the detected ones
    assert d.min() > -tolerance
    # the bodies are at rest, held up by contact (gravity would have taken them far below)
    assert np.abs(s.v).max() < 0.2
    if scene == "pills":
        assert s.x[:, 2].min() > -tolerance and s.x[:, 2].max() < 0.6
    else:
        tops = [b[:, 2].max() for b in sim.split(s.x)]
        assert tops == pytest.approx([0.4, 0.8], abs=0.02)


def test_affinified_drop_follows_the_full_centre_of_mass():
    def trajectory(reducer):
        sim = sa.scenes.drop(resolution=1, shape="box", reducer=reducer)
        m = sim.system.lumped_mass
        return np.array([m @ s.x / m.sum() for s in sim.run(120)]), sim

    full, _ = trajectory(None)
    reduced, sim = trajectory(sa.Affinification(tau_a=1.0, tau_e=2.0))
    assert np.mean([r["reduced_fraction"] for r in sim.stats]) > 0.5
    # stated tolerance: 3 % of the box's size (measured 1.5 % at 85 % of the elements affine)
    assert np.abs(reduced - full).max() < 0.03 * 0.5


def test_warm_start_saves_pgs_iterations():
    def mean_sweeps(warm):
        sim = sa.Simulation(_block(0.2, 2), dt=0.01, gravity=(0, 0, -G_ACC), colliders=[sa.Plane()],
                            contact=sa.PGS(warm_start=warm, tolerance=1e-8, iterations=200))
        for _ in sim.run(40):
            pass
        return np.mean([r["pgs_iterations"] for r in sim.stats[10:]])

    assert mean_sweeps(True) < 0.5 * mean_sweeps(False)


def test_prediction_takes_contact_impulses_as_explicit_forces():
    """New contacts: one Jacobi step of the bilateral constraint with the lumped mass (sec. 3.4)."""
    body = _block(0.2, 2, velocity=(0.0, 0.0, -1.0))
    sim = sa.Simulation(body, dt=0.01, colliders=[sa.Plane()], reducer=sa.Affinification())
    rec = {}
    cs = sim.contact.detect(sim.model, sim.state.x, sim.state.v, rec)
    bottom = np.flatnonzero(np.isclose(sim.state.x[:, 2], 0.0))
    assert set(cs.vertex[cs.distance <= 1e-12]) == set(bottom)
    impulse = sim.contact.prediction_impulse().reshape(-1, 3)
    # lambda_n = m_v |v_n| stops each touching vertex; nothing else is pushed
    assert np.allclose(impulse[bottom, 2], sim.system.lumped_mass[bottom] * 1.0)
    others = np.setdiff1d(np.arange(sim.system.n), bottom)
    assert np.allclose(impulse[others], 0.0) and np.allclose(impulse[:, :2], 0.0)
    # the next frame warm-starts from the solved impulses instead
    sim.step()
    sim.contact.detect(sim.model, sim.state.x, sim.state.v, rec)
    assert np.all(sim.contact.matched[np.isin(sim.contact.current.vertex, bottom)])


@pytest.mark.parametrize("name", ["drop", "stacked_beams", "pills", "bowling", "toothbrush"])
def test_contact_scenes_take_overrides_and_run(name):
    sim = sa.scenes.SCENES[name](resolution=1, dt=0.005, contact=sa.PGS(friction=0.1, iterations=20))
    assert sim.scene == name and sim.frames > 0 and sim.dt == 0.005
    assert sim.contact.settings.friction == 0.1 and sim.colliders and sim.contact_model == "pgs"
    for s in sim.run(3):
        pass
    assert np.all(np.isfinite(s.x)) and all("n_contacts" in r and r["contact_model"] == "pgs" for r in sim.stats)
    with pytest.raises(ValueError, match="resolution"):
        sa.scenes.SCENES[name](resolution=0)


def test_capsule_mesh_is_a_capsule():
    mesh = sa.scenes.capsule_mesh(0.1, 0.2, 2, center=(1.0, 2.0, 3.0), axis=2)
    body = sa.ElasticBody(mesh, sa.NeoHookean(E=1e5, nu=0.3))   # valid: no folded or flat elements
    d, _ = sa.Capsule(a=(1, 2, 2.8), b=(1, 2, 3.2), radius=0.1).query(mesh.p[:, mesh.boundary_nodes()].T)
    assert np.abs(d).max() < 1e-12
    exact = np.pi * 0.1 ** 2 * 0.4 + 4 / 3 * np.pi * 0.1 ** 3
    assert body.volumes.sum() == pytest.approx(exact, rel=0.08)  # inscribed polyhedron, 4 cells across


def test_contact_impulses_in_the_prediction_elastify_the_impact():
    """Sec. 3.4 / Fig. 3: with the contact impulses as explicit forces, the oracle sees the impact
    coming and elastifies the region; without them the falling affine block stays affine."""
    def elastic_fraction(with_impulses):
        sim = sa.scenes.drop(resolution=2, shape="box", height=0.02, reducer=sa.Affinification(tau_a=2.0, tau_e=4.0))
        if not with_impulses:
            sim.contact.prediction_impulse = lambda: 0.0
        for _ in sim.run(12):
            pass
        return np.array([1.0 - r["reduced_fraction"] for r in sim.stats])

    with_impulses, without = elastic_fraction(True), elastic_fraction(False)
    assert with_impulses[:5].max() == 0.0 and without.max() == 0.0   # free fall is one affine body
    assert with_impulses[5:].max() > 0.05                            # the impact elastifies elements


def test_the_contact_model_of_each_integrator_is_recorded():
    """colliders= means PGS with friction under the linearized integrator, a frictionless IPC
    barrier under the Newton integrators: sim.contact_model and every frame's record say which."""
    for kwargs, expected in [({}, "pgs"), (dict(integrator="implicit_euler", contact=None), "ipc-barrier"),
                             (dict(contact=False, colliders=[]), "none")]:
        sim = sa.scenes.drop(resolution=1, **kwargs)
        sim.step()
        assert sim.contact_model == expected and sim.stats[-1]["contact_model"] == expected
    assert sa.scenes.free_body(resolution=1, integrator="bdf2").contact_model == "none"
