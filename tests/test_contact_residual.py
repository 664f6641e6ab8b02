"""The contact residual of the PGS solve: its definition, the stopping rule, and the report of
a contact the solve leaves unresolved (a heavy stiff body on a light one)."""
import warnings

import numpy as np
import pytest
import scipy.sparse as sp

import skfem_affine as sa
from skfem_affine.contact import pgs
from skfem_affine.lab.scenes import box_mesh
from skfem_affine.monitor import SimulationWarning


def _lcp(k=6, seed=3):
    rng = np.random.default_rng(seed)
    B = rng.normal(size=(3 * k, 3 * k))
    return B @ B.T + 3 * k * np.eye(3 * k), rng.normal(size=3 * k)


def test_residual_of_one_contact_in_closed_form():
    W = np.diag([2.0, 4.0, 4.0])
    u0 = np.array([-1.0, -3.0, 0.0])
    # no impulse: the approach -1 m/s is the complementarity residual; the tangent step
    # (0.75, 0) projected onto the disk of radius 0 gives 0: no cone residual
    assert pgs.contact_residual(W, u0, np.zeros(3), 0.5) == pytest.approx((1.0, 0.0))
    # the solution: lam_n = 0.5 (u_n = 0), lam_t on the cone's rim against the slip
    lam = np.array([0.5, 0.25, 0.0])
    assert pgs.contact_residual(W, u0, lam, 0.5) == pytest.approx((0.0, 0.0), abs=1e-15)
    # a tangent impulse inside the cone while the contact slides: u_t = -2, step 4, lam_t - u_t / step
    # = 0.1 + 0.5 = 0.6 projected to 0.25: residual 4 * 0.15
    assert pgs.contact_residual(W, u0, np.array([0.5, 0.1, 0.0]), 0.5)[1] == pytest.approx(0.6)
    assert pgs.velocity_scale(u0) == 3.0     # the tangential slip is the largest velocity to remove


def test_pgs_stops_at_the_residual_tolerance():
    W, u0 = _lcp()
    scale = pgs.velocity_scale(u0)
    for tol in (1e-3, 1e-8):
        lam = np.zeros_like(u0)
        sweeps = pgs.projected_gauss_seidel(W, u0, lam, 0.4, 500, tol)
        assert sweeps < 500 and max(pgs.contact_residual(W, u0, lam, 0.4)) <= tol * scale
        if sweeps > 1:  # one sweep fewer had not reached it
            lam = np.zeros_like(u0)
            pgs.projected_gauss_seidel(W, u0, lam, 0.4, sweeps - 1, 0.0)
            assert max(pgs.contact_residual(W, u0, lam, 0.4)) > tol * scale


def test_frames_record_the_contact_residual():
    body = sa.ElasticBody(box_mesh(0.2, 2, (0, 0, 0.1)), sa.NeoHookean(E=1e6, nu=0.3), density=1000.0)
    sim = sa.Simulation(body, dt=0.01, gravity=(0, 0, -9.81), colliders=[sa.Plane()])
    for _ in sim.run(5):
        pass
    rec = sim.stats[-1]
    assert rec["n_contacts"] > 0 and rec["pgs_converged"] and not rec["contact_unresolved"]
    assert rec["contact_residual"] == max(rec["contact_complementarity"], rec["contact_cone"])
    assert rec["contact_residual"] <= sa.PGS().tolerance * rec["contact_scale"]
    assert rec["contact_scale"] == pytest.approx(9.81 * 0.01, rel=0.5)  # at rest: one step of gravity


def _heavy_on_light(ratio, **contact):
    """A stiff box (E = 1e9) ``ratio`` times denser than the soft box it lands on."""
    light = sa.ElasticBody(box_mesh(0.2, 2, (0, 0, 0.1)), sa.NeoHookean(E=1e6, nu=0.3), density=10.0)
    heavy = sa.ElasticBody(box_mesh(0.2, 2, (0, 0, 0.302)), sa.NeoHookean(E=1e9, nu=0.3), density=10.0 * ratio)
    return sa.Simulation([light, heavy], dt=0.01, gravity=(0, 0, -9.81), colliders=[sa.Plane()],
                         contact=sa.PGS(**contact))


def test_an_unresolved_contact_is_reported_naming_the_frame():
    sim = _heavy_on_light(1e4, iterations=20, max_iterations=20)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for _ in sim.run(4):
            pass
    said = [str(w.message) for w in caught if issubclass(w.category, SimulationWarning)]
    assert len(said) == 1 and "contact unresolved at frame 2" in said[0]  # once per run
    assert [r["contact_unresolved"] for r in sim.stats] == [False, True, True, True]
    assert sim.stats.problems()["unresolved_contact_frames"] == 3


def test_sweeps_go_on_while_contact_is_unresolved():
    """The same heavy box: the extra sweeps (default 40 x the cap) keep the light box on the floor, and
    frames still above the unresolved level are reported."""
    sim = _heavy_on_light(1e4)
    n = sim.bodies[0].mesh.p.shape[1]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SimulationWarning)  # a few frames stay above 1 %: reported
        for _ in sim.run(12):
            pass
    assert max(r["pgs_iterations"] for r in sim.stats) > sa.PGS().iterations
    # frames that still miss 1 % of the velocity to remove say so
    assert all(r["contact_unresolved"] == _unresolved(r) for r in sim.stats)
    assert sim.state.x[:n, 2].min() > -1e-2                 # at most 1 cm into the floor (measured 5 mm; 9 cm without)
    light = sim.state.x[:n].mean(axis=0)
    assert np.hypot(light[0], light[1]) < 5e-3              # not squeezed out sideways
    assert sim.state.x[n:, 2].min() > 0.1                   # the heavy box still on top of it


def _unresolved(rec):
    """The frame's contact solve or its penetration correction ends above 1 % of its velocity scale."""
    return (rec["contact_residual"] > pgs.UNRESOLVED * rec["contact_scale"]
            or rec.get("correction_residual", 0.0) > pgs.UNRESOLVED * rec.get("correction_scale", np.inf))


def _stack(gravity=(0, 0, -9.81), **contact):
    """A 0.2 m stiff box (E = 1e8, density 1e4) resting on a 0.4 m soft one (E = 1e6, density 1): 1250
    times its mass."""
    light = sa.ElasticBody(box_mesh(0.4, 2, (0, 0, 0.2)), sa.NeoHookean(E=1e6, nu=0.3), density=1.0)
    heavy = sa.ElasticBody(box_mesh(0.2, 2, (0, 0, 0.502)), sa.NeoHookean(E=1e8, nu=0.3), density=1e4)
    return sa.Simulation([light, heavy], dt=0.01, gravity=gravity, colliders=[sa.Plane()],
                         contact=sa.PGS(friction=0.5, **contact))


@pytest.mark.slow
def test_a_heavy_box_rests_on_a_light_one_for_500_frames():
    """The penetration correction sweeps on while it leaves more than 1 % of the frame's velocity
    scale: the light box's penetration into the floor, which the contact solve's small residual
    feeds every frame, stays bounded instead of piling up, and the stack stands."""
    sim = _stack()
    n = sim.bodies[0].mesh.p.shape[1]
    with warnings.catch_warnings():
        warnings.simplefilter("error", SimulationWarning)  # nothing left unresolved
        bottoms = np.array([s.x[:n, 2].min() for s in sim.run(500)])
    assert bottoms.min() > -1e-3                          # measured 0.1 mm (11 mm by frame 450 without)
    heavy = sim.state.x[n:]
    assert np.hypot(*heavy[:, :2].mean(axis=0)) < 5e-3    # no drift off the top
    assert np.ptp(heavy[:, 2]) < 0.2 + 1e-3               # not tilted: its 0.2 m height, upright
    assert sim.stats.problems()["unresolved_contact_frames"] == 0


def test_a_penetration_correction_left_short_is_reported_at_its_first_frame():
    """Without gravity the contact solve has nothing to remove, but the light box starts 1 mm in the
    floor with the heavy one resting on it: 20 sweeps of the correction leave most of the push
    asked for, and the first frame says so."""
    sim = _stack(gravity=(0, 0, 0), iterations=20, max_iterations=20)
    n = sim.bodies[0].mesh.p.shape[1]
    sim.state.x[:, 2] -= 1e-3
    sim.state.x[n:, 2] -= 2e-3  # the heavy box resting on the light one
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for _ in sim.run(3):
            pass
    said = [str(w.message) for w in caught if issubclass(w.category, SimulationWarning)]
    assert len(said) == 1 and "contact unresolved at frame 1" in said[0] and "penetration correction" in said[0]
    first = sim.stats[0]
    assert first["contact_residual"] <= pgs.UNRESOLVED * first["contact_scale"]  # the velocity solve is fine
    assert first["correction_residual"] > pgs.UNRESOLVED * first["correction_scale"] and first["contact_unresolved"]
    assert all(r["contact_unresolved"] == _unresolved(r) for r in sim.stats)
    assert sim.stats.problems()["unresolved_contact_frames"] == 3
    assert sim.state.x[:n, 2].min() < -5e-4  # still in the floor


def test_max_iterations_is_checked():
    with pytest.raises(ValueError, match="max_iterations"):
        sa.PGS(iterations=50, max_iterations=10)
    assert sa.PGS(iterations=30).sweep_limit == 1200 and sa.PGS(max_iterations=50).sweep_limit == 50


# ---------------------------------------------------------------------------- split impulse
def test_low_rank_split_impulse_equals_the_dense_solve():
    """B B^T never formed: the same velocities as PGS on the dense W_r = B B^T (rank 12 here)."""
    rng = np.random.default_rng(5)
    k, r = 40, 12
    B = np.where(rng.random((k, r)) < 0.5, rng.normal(size=(k, r)), 0.0)
    # a solvable problem: lam* >= 0 on half the rows, the others separating by s >= 0
    on = rng.random(k) < 0.5
    u0 = -B @ (B.T @ np.where(on, rng.random(k), 0.0)) + np.where(on, 0.0, rng.random(k))
    lam = np.zeros(k)
    Bs = sp.csr_matrix(B)
    w = pgs.projected_gauss_seidel_lowrank(Bs.indptr, Bs.indices, Bs.data, r, u0, lam, 5000, 1e-12)
    assert np.allclose(w, B.T @ lam)
    u = u0 + B @ w
    assert np.all(lam >= 0) and np.all(u >= -1e-10) and np.abs(lam * u).max() < 1e-10
    dense = np.zeros(3 * k)  # the dense path, with two zero tangent rows per contact and no friction
    W = np.zeros((3 * k, 3 * k))
    W[0::3, 0::3] = B @ B.T
    u03 = np.zeros(3 * k)
    u03[0::3] = u0
    pgs.projected_gauss_seidel(W, u03, dense, 0.0, 5000, 1e-12)
    assert np.allclose(B.T @ dense[0::3], w, atol=1e-8)  # B^T lam is unique, lam need not be


def test_rigid_motions_factor_the_inverse_of_their_mass():
    sim = _heavy_on_light(10.0)
    G, C = sim.contact._rigid_motions(sim.state.x)
    MG = (G.T @ (sim.system.Mff @ G)).toarray()
    assert np.allclose((C @ C.T).toarray() @ MG, np.eye(12), atol=1e-9)


def test_bodies_touching_at_rest_without_gravity_take_no_extra_sweeps():
    mat = sa.NeoHookean(E=1e6, nu=0.3)
    bodies = [sa.ElasticBody(box_mesh(0.2, 2, (0, 0, 0.1)), mat, density=1000.0),
              sa.ElasticBody(box_mesh(0.12, 2, (0.02, 0.0, 0.26)), mat, density=1000.0)]
    sim = sa.Simulation(bodies, dt=0.01, colliders=[sa.Plane()])
    for _ in sim.run(4):
        pass
    assert all(r["pgs_iterations"] <= sa.PGS().iterations and r["pgs_converged"] for r in sim.stats)
