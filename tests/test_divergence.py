"""The divergence policy (skfem_affine.monitor): nothing wrong passes as a result."""
import warnings

import numpy as np
import pytest
import skfem

import skfem_affine as sa
from skfem_affine.lab import scenes
from skfem_affine.monitor import Monitor


def _run(sim, frames):
    """Frames until the end or SimulationDiverged; returns (states, error)."""
    states = []
    try:
        for s in sim.run(frames):
            states.append(s)
    except sa.SimulationDiverged as err:
        return states, err
    return states, None


def test_huge_gravity_is_refused_at_the_first_bad_frame():
    sim = scenes.cantilever(resolution=2, gravity=(0, 0, -1e6))
    states, err = _run(sim, 30)
    assert err is not None and err.frame == 1 and "frame 1" in str(err)
    assert "torn apart" in str(err) and not states and sim.state.frame == 0


def test_the_energy_check_names_the_frame_and_the_energies(monkeypatch):
    # without the tearing test, the energy test trips at the first frame whose energy explodes
    monkeypatch.setattr(Monitor, "_tearing", lambda *args: None)
    sim = scenes.cantilever(resolution=2, E=1e5, damping=None, gravity=(0, 0, -1e6), on_inverted="ignore")
    states, err = _run(sim, 30)
    assert err is not None and "energy grew" in str(err) and f"frame {err.frame}" in str(err)
    assert err.frame == len(states) + 1 and len(states) < 15
    energies = [r["energy"] for r in sim.stats]
    assert all(np.isfinite(energies)) and max(energies) < 1e13


def test_a_stiff_fast_spinning_body_is_refused_by_the_linearized_step():
    sim = scenes.free_body(resolution=2, spin=(0, 0, 30.0), material=sa.NeoHookean(E=1e9, nu=0.3))
    states, err = _run(sim, 5)  # theta = h w = 0.3: past what the rotation-aware Taylor term carries
    assert err is not None and err.frame <= 2 and "energy grew" in str(err) and "x in one step" in str(err)
    assert f"frame {err.frame}" in str(err) and len(states) == err.frame - 1


@pytest.mark.parametrize("E, spin", [(1e5, 30.0), (1e9, 2.0), (1e7, 10.0)])
def test_legitimate_spinning_runs_pass_and_lose_energy(E, spin):
    sim = scenes.free_body(resolution=2, spin=(0, 0, spin), material=sa.NeoHookean(E=E, nu=0.3))
    states, err = _run(sim, 30)
    assert err is None
    energies = [r["energy"] for r in sim.stats]
    assert energies[-1] <= energies[0]


def test_ordinary_scenes_never_trip_the_checks():
    for sim, frames in ((scenes.cantilever(resolution=2), 80), (scenes.drop(), 60),
                        (scenes.cantilever(resolution=2, integrator="bdf2"), 40)):
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            states, err = _run(sim, frames)
        assert err is None
        assert all(r["inverted_elements"] == 0 for r in sim.stats)


def _crushed(**kw):
    """A soft cube squeezed flat by a huge initial velocity: elements invert."""
    mesh = skfem.MeshTet.init_tensor(*[np.linspace(0, 1, 3)] * 3)
    v = np.zeros((mesh.nvertices, 3))
    v[:, 2] = -60.0 * mesh.p[2]
    body = sa.ElasticBody(mesh, sa.NeoHookean(E=1e3, nu=0.3), velocity=v,
                          fixed=np.flatnonzero(mesh.p[2] < 1e-9))
    return sa.Simulation(body, dt=0.01, **kw)


def test_inverted_elements_warn_once_and_are_counted():
    sim = _crushed()
    with pytest.warns(sa.SimulationWarning, match="inverted element") as record:
        states, err = _run(sim, 3)
    assert err is None and len([w for w in record if "inverted" in str(w.message)]) == 1
    assert sum(r["inverted_elements"] > 0 for r in sim.stats) >= 1
    assert sim.stats.problems()["inverted_frames"] == sum(r["inverted_elements"] > 0 for r in sim.stats)
    assert "of the full space run" in str(record[0].message)  # several simulations may share a process


def test_inverted_warning_names_the_reduced_method():
    sim = _crushed(reducer=sa.Affinification(tau_e=1e-12, tau_a=1e-12))
    with pytest.warns(sa.SimulationWarning, match="inverted element.* of the Affinification run"):
        _run(sim, 3)


def test_inverted_elements_raise_when_asked():
    sim = _crushed(on_inverted="raise")
    states, err = _run(sim, 3)
    assert err is not None and "inverted element" in str(err) and f"frame {err.frame}" in str(err)
    assert err.frame == sim.state.frame + 1 and sim.monitor.inverted(
        sim.system.deformation_gradients(sim.state.x)) == 0  # the returned states have none


def test_newton_non_convergence_warns_or_raises():
    sim = scenes.cantilever(resolution=2, integrator="implicit_euler", newton_iters=1, newton_tol=1e-12)
    with pytest.warns(sa.SimulationWarning, match="Newton stopped"):
        states, err = _run(sim, 3)
    assert err is None and not any(r["newton_converged"] for r in sim.stats)
    assert sim.stats.problems()["unconverged_frames"] == 3
    sim = scenes.cantilever(resolution=2, integrator="implicit_euler", newton_iters=1, newton_tol=1e-12,
                            on_nonconvergence="raise")
    states, err = _run(sim, 3)
    assert err is not None and err.frame == 1 and "Newton stopped after 1 iteration" in str(err)


def test_policy_arguments_are_checked():
    body = scenes.cantilever(resolution=1).bodies[0]
    with pytest.raises(ValueError, match="on_inverted must be one of"):
        sa.Simulation(body, on_inverted="explode")
    with pytest.raises(TypeError, match="check_energy"):
        sa.Simulation(body, check_energy="no")


def test_a_linalg_error_inside_a_reducer_becomes_simulation_diverged(monkeypatch):
    from skfem_affine.reducers.subspace import reducer as subspace

    def broken(*args, **kwargs):
        raise np.linalg.LinAlgError("2-th leading minor not positive definite")

    monkeypatch.setattr(subspace, "schur_solve", broken)
    sim = scenes.cantilever(resolution=1, integrator="bdf2",
                            reducer=sa.AdaptiveSubspace(basis=sa.SkinningEigenmodes(n=2, cache=False), subdomains=2,
                                                        never_slower=False))  # step 1 reduced
    states, err = _run(sim, 2)
    assert err is not None and err.frame == 1 and "leading minor" in str(err)


def test_a_non_finite_state_is_refused_before_contact_detection():
    sim = scenes.drop()
    sim.state.v[0, 0] = np.nan
    states, err = _run(sim, 1)
    assert err is not None and "non-finite state detected at frame 1" in str(err) and not sim.stats


def test_checks_can_be_switched_off():
    sim = scenes.free_body(resolution=2, spin=(0, 0, 30.0), material=sa.NeoHookean(E=1e9, nu=0.3),
                           check_energy=False, on_inverted="ignore")
    states, err = _run(sim, 1)
    assert err is None and "energy" not in sim.stats[0] and sim.stats[0]["inverted_elements"] is None


def test_a_non_finite_newton_direction_becomes_simulation_diverged(monkeypatch):
    from skfem_affine.integrators import newton

    def nan_direction(self, x, g, data, rec, e):
        return np.full_like(g, np.nan)

    monkeypatch.setattr(newton.FullSpaceDirection, "__call__", nan_direction)
    sim = scenes.drop(integrator="implicit_euler", contact=None)  # with the barrier's collider queries
    states, err = _run(sim, 2)
    assert err is not None and err.frame == 1 and "Newton direction is not finite" in str(err)


def test_a_state_changed_from_outside_is_not_taken_for_created_energy():
    sim = scenes.free_body(resolution=2, spin=(0, 0, 1.0))
    list(sim.run(2))
    sim.state.v *= 20.0  # a kick: 400x the kinetic energy, given by the user, not by the integrator
    states, err = _run(sim, 3)
    assert err is None and sim.stats[-1]["energy"] > 100 * sim.stats[1]["energy"]


def test_a_body_at_rest_with_nothing_acting_runs():
    """Its energy is the round-off of the strain energy near rest (~mu ulp(1) per volume): no growth."""
    mesh = skfem.MeshTet.init_tensor(np.linspace(0, 1, 21), np.linspace(0, 0.1, 3), np.linspace(0, 0.1, 3))
    body = sa.ElasticBody(mesh, sa.NeoHookean(E=1e7, nu=0.3), fixed=mesh.nodes_satisfying(lambda x: x[0] < 1e-9))
    sim = sa.Simulation(body, dt=0.005)
    states, err = _run(sim, 3)
    assert err is None and len(states) == 3
    assert np.abs(states[-1].x - mesh.p.T).max() < 1e-12


def test_energy_created_without_work_is_warned_naming_the_frame():
    # the linearized step of a very stiff cube spinning fast (h w = 0.15) creates a fifth of its energy
    # in frame 2: not a blow-up (the step is accepted), but wrong, so it is said
    sim = scenes.free_body(resolution=2, spin=(0, 0, 15.0), material=sa.NeoHookean(E=1e9, nu=0.3))
    with pytest.warns(sa.SimulationWarning, match="created .* J .* at frame 2 ") as record:
        states, err = _run(sim, 3)
    assert err is None and len(record) == 1
    assert sim.stats[1]["energy_gain"] > 0.2


def _quiet(sim, frames):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return _run(sim, frames)


def test_bodies_overlapping_at_rest_without_gravity_are_no_blow_up():
    # their energies are round-off (1e-14 J): the energy test has a floor on the scale of the problem
    a = sa.ElasticBody(scenes.box_mesh(0.5, 2, center=(0.1, 0.2, 0.3)), sa.NeoHookean(E=1e5, nu=0.3))
    b = sa.ElasticBody(scenes.box_mesh(0.5, 2, center=(0.5, 0.2, 0.3)), sa.NeoHookean(E=1e5, nu=0.3))
    sim = sa.Simulation([a, b])
    states, err = _quiet(sim, 10)
    assert err is None
    assert 0 < sim.monitor.energy_floor < 1e-6


def test_a_load_ramped_from_zero_on_a_bar_at_rest_is_no_blow_up():
    mesh = scenes.beam_mesh(1).translated((0.1, 0.3, 0.7))
    right, left = np.flatnonzero(mesh.p[0] > 4.09), np.flatnonzero(mesh.p[0] < 0.1 + 1e-9)
    force = sa.VertexForce(right, lambda t, x, v: np.array([0.0, 0.0, -1e-3 * t]))
    sim = sa.Simulation(sa.ElasticBody(mesh, sa.NeoHookean(E=1e5, nu=0.3), fixed=left), forces=[force])
    states, err = _quiet(sim, 5)
    assert err is None


def test_a_blow_up_from_rest_is_still_refused_above_the_floor(monkeypatch):
    monkeypatch.setattr(Monitor, "_tearing", lambda *args: None)
    sim = scenes.cantilever(resolution=2, E=1e5, gravity=(0, 0, -1e6), on_inverted="ignore")
    monitor_floor = sim.monitor.energy_floor
    states, err = _run(sim, 30)
    assert err is not None and "energy grew" in str(err) and monitor_floor < 1e-3


def _sliver(quality):
    """One tetrahedron whose volume is ``quality`` times that of a regular one with its longest edge."""
    p = np.array([[0, 0, 0], [1, 0, 0], [0.5, np.sqrt(3) / 2, 0], [0.5, np.sqrt(3) / 6, 0.0]]).T
    p[2, 3] = quality / (6 * np.sqrt(2)) * 3 / (np.sqrt(3) / 4)
    return skfem.MeshTet(p, np.array([[0, 1, 2, 3]]).T)


def test_a_sliver_the_linearized_step_gets_wrong_is_warned_naming_it():
    # relative volume 5e-9 passes validation (1e-9) but falls 53 % short in 0.5 s under the linearized step
    body = sa.ElasticBody(_sliver(5e-9), sa.NeoHookean(E=1e5, nu=0.3))
    with pytest.warns(sa.SimulationWarning, match=r"element\(s\) \[0\] .* h\^2 k/m = 5.5e\+15"):
        sim = sa.Simulation(body, gravity=(0, 0, -9.81))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        exact = sa.Simulation(body, gravity=(0, 0, -9.81), integrator="implicit_euler")  # exact: no warning
        fine = sa.Simulation(sa.ElasticBody(_sliver(1e-5), sa.NeoHookean(E=1e5, nu=0.3)), gravity=(0, 0, -9.81))
    assert fine.monitor.stiffness_ratio < 1e-2 * sa.monitor.STIFF_RATIO
    # what the warning is about: backward Euler drops h^2 g n (n + 1) / 2
    drops = []
    for s in (sim, exact, fine):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            x0 = s.state.x[:, 2].mean()
            for state in s.run(20):
                pass
        drops.append((x0 - state.x[:, 2].mean()) / (1e-4 * 9.81 * 20 * 21 / 2))
    assert abs(drops[0] - 1) > 0.05 and abs(drops[1] - 1) < 1e-6 and abs(drops[2] - 1) < 1e-5


REFUSED_STEP_SCENES = {
    "bdf2": lambda: scenes.cantilever(resolution=1, E=1e5, integrator="bdf2"),
    "bdf2-subspace": lambda: scenes.cantilever(resolution=1, E=1e5, integrator="bdf2", reducer=sa.AdaptiveSubspace(
        basis=sa.SkinningEigenmodes(n=4, cache=False), subdomains=8, eps_nodal=0.05, eps_modal=0.05)),
    "affinification": lambda: scenes.cantilever(resolution=2, E=1e5, reducer=sa.Affinification(0.05, 0.1)),
    "rigidification-pgs": lambda: scenes.drop(resolution=1, shape="box", height=0.02,
                                              reducer=sa.Rigidification(0.05, 0.1, warmup_frames=1)),
}


@pytest.mark.parametrize("scene", sorted(REFUSED_STEP_SCENES))
def test_a_run_continued_after_a_refused_step_equals_one_that_never_failed(scene, monkeypatch):
    make, frames, fail_at = REFUSED_STEP_SCENES[scene], 6, 4
    ref = make()
    expected = [s.x for s in ref.run(frames)]
    sim = make()
    list(sim.run(fail_at - 1))
    check = sim.monitor.check

    def refuse_once(frame, *args):  # the divergence policy refuses the step after everything ran
        from skfem_affine.monitor import Diverged
        monkeypatch.setattr(sim.monitor, "check", check)
        check(frame, *args)
        raise Diverged("energy grew (injected)")

    monkeypatch.setattr(sim.monitor, "check", refuse_once)
    with pytest.raises(sa.SimulationDiverged, match=f"at frame {fail_at}"):
        sim.step()
    assert sim.state.frame == fail_at - 1 and len(sim.stats) == fail_at - 1
    got = [s.x for s in sim.run(frames - fail_at + 1)]
    for a, b in zip(got, expected[fail_at - 1:]):
        assert np.array_equal(a, b)
