"""The scenes: physically plausible defaults and the paper's scenes (procedural or from a mesh file)."""
import os

import numpy as np
import pytest

import skfem_affine as sa
from skfem_affine.lab import scenes


def rest_tip_deflection(k):
    """Tip deflection of the default cantilever run to rest (its own damping; h = 0.05 s to settle fast).

    The static equilibrium does not depend on the time step; backward Euler's
    numerical damping at the larger step only brings the beam to rest sooner.
    """
    sim = scenes.cantilever(resolution=k, dt=0.05)
    tip = sim.system.p0[:, 0] > 4.0 - 1e-9
    for s in sim.run(100):
        pass
    assert np.abs(s.v).max() < 1e-4  # at rest
    return -(s.x[tip, 2] - sim.system.p0[tip, 2]).mean()


def test_default_cantilever_sags_as_an_euler_bernoulli_beam():
    """Static deflection against delta = rho g A L^4 / (8 E I) = 0.19 m (4.7 % of the length).

    P1 tets lock in bending (nu = 0.35): 31 % too stiff at k = 3, 21 % at k = 4. Richardson
    extrapolation in 1/k^2 (as examples/beam_frequency.py) lands within 7 %.
    """
    exact = scenes.euler_bernoulli_tip_deflection()
    assert exact == pytest.approx(0.188352, rel=1e-6)
    d3, d4 = rest_tip_deflection(3), rest_tip_deflection(4)
    assert 0 < d3 < d4 < exact  # locking: too stiff, less so when refined
    assert d4 == pytest.approx(exact, rel=0.25)
    extrapolated = (16 * d4 - 9 * d3) / (16 - 9)
    assert extrapolated == pytest.approx(exact, rel=0.15)
    assert d4 < 0.05 * 4.0  # a beam, not a rope


def test_old_rope_like_cantilever_stays_reachable_by_keywords():
    sim = scenes.cantilever(resolution=1, E=1e5, damping=None)
    assert sim.damping == sa.Rayleigh()
    assert sim.bodies[0].materials[0].E == 1e5 and sim.bodies[0].density[0] == 1000.0
    default = scenes.cantilever(resolution=1)
    assert default.damping == sa.Rayleigh(0.03, 0.02) and default.bodies[0].materials[0].E == 2e7
    assert scenes.euler_bernoulli_tip_deflection(E=1e5) > 4.0  # why it hung like a rope
    assert scenes.cantilever(resolution=1, damping=(0.0, 0.0)).damping == sa.Rayleigh()  # the CLI's spelling


def test_euler_bernoulli_frequency_matches_the_closed_form():
    L, a, E, rho = 4.0, 0.5, 1e8, 1000.0
    expected = 1.8751 ** 2 / (2 * np.pi * L ** 2) * np.sqrt(E * a ** 4 / 12 / (rho * a * a))
    assert scenes.euler_bernoulli_frequency(L, a, E, rho) == pytest.approx(expected, rel=1e-12)


# ---------------------------------------------------------------------------- the paper's scenes
def test_new_scenes_are_registered():
    assert {"wheel", "octopus", "armadillo", "twisting_beam"} <= set(scenes.SCENES)


def test_twisting_beam_turns_its_end_along_the_twist_path_and_twists():
    sim = scenes.twisting_beam(resolution=1, rate=np.pi, reducer=sa.Affinification(1.1e-3, 1e-3))
    assert sim.scene == "twisting_beam" and sim.frames == 1350 and sim.dt == 0.01
    body = sim.bodies[0]
    end = body.prescribed_vertices[0]
    X = body.mesh.p.T
    for state in sim.run(25):
        assert np.abs(state.x[end] - sim.path(state.time)).max() <= 1e-12
    assert np.array_equal(state.x[body.fixed], X[body.fixed])
    # the middle section turned part of the way: a twist, not a rigid turn
    mid = np.flatnonzero(np.isclose(X[:, 0], 2.0))
    turn = lambda x: np.arctan2(x[:, 2] - 0.5, x[:, 1] - 0.5)
    corner = mid[np.argmax(np.hypot(X[mid, 1] - 0.5, X[mid, 2] - 0.5))]
    d_mid = (turn(state.x[[corner]]) - turn(X[[corner]]))[0]
    assert 0.0 < np.abs(np.angle(np.exp(1j * d_mid))) < np.pi * 0.25


def test_wheel_has_a_stiff_hub_and_a_soft_tyre_and_lands_on_the_plane():
    sim = scenes.wheel(resolution=1, height=0.01)
    body = sim.bodies[0]
    assert sim.dt == 0.005 and len(body.materials) == 2
    E = np.array([m.E for m in body.materials])[body.material_index]
    mid = body.mesh.p[:, body.mesh.t].mean(axis=1)
    r = np.hypot(mid[0], mid[2] - body.mesh.p[2].mean())
    assert E[r < 0.5 * 0.4].min() == 1e8 and E[r > 0.8 * 0.4].max() == 1e6  # hub inside, tyre outside
    assert np.ptp(body.mesh.p[1]) == pytest.approx(0.16) and np.ptp(body.mesh.p[0]) == pytest.approx(0.8)
    for s in sim.run(40):
        pass
    assert s.x[:, 2].min() > -2e-3  # resting on the plane, not through it
    assert s.x[:, 2].min() < 1e-3


def test_wheel_mesh_is_a_disc_without_degenerate_elements():
    mesh, hub = scenes.wheel_mesh(1, radius=1.0, width=0.25, hub_fraction=0.5)
    r = np.hypot(mesh.p[0], mesh.p[2])
    assert r.max() == pytest.approx(1.0) and 0 < hub.mean() < 1
    vol = sa.kinematics.signed_volumes(mesh.p, mesh.t)
    assert np.abs(vol).sum() == pytest.approx(np.pi * 0.25, rel=0.05)  # polygonal disc
    with pytest.raises(ValueError, match="hub_fraction"):
        scenes.wheel_mesh(1, hub_fraction=1.5)


def test_wheel_from_the_papers_mesh(shared_meshes):
    sim = scenes.wheel(mesh=os.path.join(shared_meshes, "wheelFatHD.mesh"), density=(10.0, 3.0))
    body = sim.bodies[0]
    assert body.n_elements == 15797 and len(body.materials) == 2
    hub = np.array([m.E for m in body.materials])[body.material_index] == 1e8
    assert np.all(body.density == np.where(hub, 10.0, 3.0))
    ext = np.ptp(body.mesh.p, axis=1)
    assert ext[1] < 0.5 * min(ext[0], ext[2])  # the axle turned to y
    assert 0.5 < np.mean(hub) < 0.8  # the hub, within 3/4 of the radius, where the mesh is finest
    assert body.mesh.p[2].min() == pytest.approx(0.1)


def test_mesh_argument_is_checked(tmp_path):
    with pytest.raises(ValueError, match="does not exist"):
        scenes.wheel(mesh=str(tmp_path / "none.mesh"))
    with pytest.raises(TypeError, match="mesh"):
        scenes.octopus(mesh=3)


def test_a_pull_gives_the_closed_form_acceleration():
    """A constant force F on a free body in space: its centre of mass accelerates at F / M."""
    for reducer in (None, sa.Affinification(tau_a=1e-2, tau_e=2e-2)):
        kw = dict(resolution=2, spin=(0.0, 0.0, 0.0), velocity=(0.0, 0.0, 0.0))
        probe = scenes.free_body(**kw)
        F = np.array([3.0, -1.0, 2.0])
        mass = probe.system.lumped_mass
        corner = np.flatnonzero(np.all(probe.system.p0 > 0.2, axis=1))  # the pull acts on a few vertices
        pull = sa.lab.loads.Pull(corner, F, start=0.0, stop=0.095, weights=mass[corner])
        f = pull(0.0, None, None)
        assert np.allclose(f / mass[corner, None], F / mass[corner].sum())  # shared by mass: one acceleration
        assert not np.any(pull(0.095, None, None))
        sim = scenes.free_body(**kw, reducer=reducer, forces=[pull.vertex_force()])
        for s in sim.run(20):  # 10 frames pulled (t = 0 ... 0.09 at their start), 10 coasting
            pass
        momentum = (mass[:, None] * s.v).sum(axis=0)
        assert momentum == pytest.approx(F * 0.1, rel=1e-8, abs=1e-10)
    body = probe.bodies[0]
    assert np.allclose(sa.lab.loads.vertex_volumes(body.mesh, body.density), mass)  # the lumped masses


def test_pull_checks_its_input():
    with pytest.raises(ValueError, match="vertices"):
        sa.lab.loads.Pull([], (0, 0, 1.0))
    with pytest.raises(ValueError, match="3-vector"):
        sa.lab.loads.Pull([0], (0, 1.0))
    with pytest.raises(ValueError, match="start < stop"):
        sa.lab.loads.Pull([0], (0, 0, 1.0), start=1.0, stop=0.5)
    with pytest.raises(ValueError, match="selects no vertex"):  # an all-False mask pulls nothing: refused
        sa.lab.loads.Pull(np.zeros(4, dtype=bool), (0, 0, 1.0))
    with pytest.raises(ValueError, match="selects no vertex"):
        scenes.free_body(resolution=1, forces=[sa.VertexForce(np.zeros(8, dtype=bool), (0, 0, 1.0))])
    with pytest.raises(ValueError, match="weights"):
        sa.lab.loads.Pull([0, 1], (0, 0, 1.0), weights=[1.0, -1.0])
    with pytest.raises(ValueError):
        scenes.free_body(resolution=1, forces=[sa.lab.loads.Pull([10 ** 6], (0, 0, 1.0)).vertex_force()])


def test_octopus_falls_into_the_bowl_and_the_tug_lifts_a_tentacle():
    pulled, still = scenes.octopus(frames=40), scenes.octopus(frames=40, pull=None)
    assert isinstance(pulled.colliders[0], sa.Bowl) and not still.motion.forces
    (_, pull), = pulled.motion.forces
    assert isinstance(pull, sa.lab.loads.Pull)
    assert pull.start == pytest.approx(0.16) and pull.stop == pytest.approx(0.22) and pull.force[2] > 0
    for a, b in zip(pulled.run(25), still.run(25)):
        pass
    lift = a.x[pull.vertices, 2].mean() - b.x[pull.vertices, 2].mean()
    far = np.linalg.norm(pulled.system.p0 - pulled.system.p0[pull.vertices].mean(axis=0), axis=1) > 0.4
    assert lift > 0.01
    assert lift > 5 * np.abs(a.x[far, 2] - b.x[far, 2]).max()  # a tug on the tentacle, not a lift of the body


def test_octopus_from_the_papers_mesh(shared_meshes):
    path = os.path.join(shared_meshes, "octopusP2.mesh")
    sim = scenes.octopus(mesh=path, size=0.5, frames=10)
    assert sim.system.m == 6170 and np.ptp(sim.system.p0[:, :2], axis=0).max() == pytest.approx(0.5)
    assert sim.system.p0[:, 2].min() == pytest.approx(0.25) and sim.motion.forces[0][1].vertices.size > 1
    up = scenes.octopus(mesh=path, up=1)  # the file's y axis points up
    assert np.ptp(up.system.p0[:, 2]) == pytest.approx(np.ptp(sa.io.load_mesh(path).p[1]))
    with pytest.raises(ValueError, match="up"):
        scenes.octopus(mesh=path, up=3)


def test_armadillo_keeps_the_resource_limit_on_impact():
    sim = scenes.armadillo(resolution=2, dt=0.01)
    assert sim.reducer.min_fraction == pytest.approx(1 / 3) and sim.reducer.tau_a == 4e-13
    shares = [np.mean(s.clusters >= 0) for s in sim.run(12)]
    assert min(shares[3:]) > 0.2  # everything deforms on impact, a third stays affine (less dissolved singletons)
    full = scenes.armadillo(resolution=1, reducer=None)
    assert full.reducer is None
    blob = scenes.blob_mesh(2)
    assert blob.boundary_facets().size > 0 and np.all(np.isfinite(blob.p))


def test_twist_path_rotates_the_clamped_end_about_the_beam_axis():
    mesh, fixed_end, turned_end, path = scenes.twisting_beam_setup(resolution=2, rate=np.pi / 4)
    assert np.all(mesh.p[0, fixed_end] == 0) and np.all(mesh.p[0, turned_end] == 4.0)
    rest = mesh.p[:, turned_end].T
    assert np.allclose(path(0.0), rest)
    x = path(2.0)  # a quarter turn
    off0, off = rest[:, 1:] - 0.5, x[:, 1:] - 0.5
    assert np.allclose(x[:, 0], 4.0) and np.allclose(np.linalg.norm(off, axis=1), np.linalg.norm(off0, axis=1))
    assert np.allclose(off, np.column_stack([-off0[:, 1], off0[:, 0]]))  # +90 degrees about +x
    h = 1e-6
    assert np.allclose(path.velocity(1.3), (path(1.3 + h) - path(1.3 - h)) / (2 * h), atol=1e-6)
    with pytest.raises(ValueError, match="shape"):
        scenes.TwistPath(np.zeros(3), (0, 0, 0))


def test_pills_from_the_papers_pill(shared_meshes):
    sim = scenes.pills(mesh=os.path.join(shared_meshes, "Pill.mesh"), n=5)
    a, b = sim.bodies[0], sim.bodies[4]  # the second layer lies crosswise
    assert a.n_elements == 4976 and np.ptp(a.mesh.p, axis=1).argmax() == 0 and np.ptp(b.mesh.p, axis=1).argmax() == 1
    assert np.ptp(a.mesh.p[0]) == pytest.approx(2 * (0.12 + 0.1))


@pytest.mark.parametrize("make, name", [
    (lambda: scenes.box_mesh(1.0, 2.5), "cells"),
    (lambda: scenes.box_mesh(1.0, 0), "cells"),
    (lambda: scenes.box_mesh(1.0, (2, 2)), "cells"),
    (lambda: scenes.box_mesh((1.0, -1.0, 1.0), 2), "size"),
    (lambda: scenes.box_mesh(1.0, 2, center=(0, 0, "1")), "center"),
    (lambda: scenes.drop(size=-0.5), "size"),
    (lambda: scenes.drop(height=-0.5), "height"),
    (lambda: scenes.stacked_beams(gap=-0.5), "gap"),
    (lambda: scenes.stacked_beams(width=0.0), "width"),
    (lambda: scenes.capsule_mesh(0.0, 0.1, 1), "radius"),
    (lambda: scenes.capsule_mesh(0.1, -0.1, 1), "half_length"),
    (lambda: scenes.ball_mesh(np.nan, 1), "radius"),
    (lambda: scenes.beam_mesh(1, length=-4.0), "length"),
    (lambda: scenes.cantilever(resolution=1, width=0), "width"),
    (lambda: scenes.free_body(resolution=1, size=-1.0), "size"),
    (lambda: scenes.pills(n=1, radius=0.0), "radius"),
    (lambda: scenes.pills(n=1, bowl_radius=-1.0), "bowl_radius"),
    (lambda: scenes.bowling(n=1, radius=-0.1), "radius"),
    (lambda: scenes.bowling(n=2, heights=(0.1, -0.2)), "heights"),
    (lambda: scenes.bowling(n=1, mattress=(2.0, 0.0, 0.2)), "mattress"),
    (lambda: scenes.toothbrush_mesh(cell=0.0), "cell"),
    (lambda: scenes.wheel_mesh(radius=-0.4), "radius"),
    (lambda: scenes.wheel(height=-1.0), "height"),
    (lambda: scenes.octopus_mesh(arm_length=-0.1), "arm_length"),
    (lambda: scenes.octopus(height=-1.0), "height"),
    (lambda: scenes.blob_mesh(radius=0.0), "radius"),
    (lambda: scenes.blob_mesh(bumps=1.5), "bumps"),
    (lambda: scenes.armadillo(size=0.0), "size"),
    (lambda: scenes.twisting_beam_setup(length=0.0), "length"),
    (lambda: scenes.paper_beam(length="6"), "length"),
])
def test_scene_helpers_refuse_bad_geometry_naming_it(make, name):
    with pytest.raises((TypeError, ValueError), match=rf"(?<![a-z_]){name}(?![a-z_])"):
        make()
