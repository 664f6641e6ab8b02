"""Each metric against a hand-computed case (paper sec. 4.1, Fig. 6)."""
from types import SimpleNamespace

import numpy as np
import pytest

import skfem_affine as sa
from skfem_affine.lab import metrics


def test_distance_error_is_the_largest_vertex_distance_over_size():
    ref = np.zeros((3, 3))
    x = ref.copy()
    x[1] = (3.0, 4.0, 0.0)   # distance 5
    x[2] = (1.0, 0.0, 0.0)   # distance 1
    assert metrics.distance_error(x, ref, size=10.0) == pytest.approx(0.5)
    assert metrics.distance_error(ref, ref, size=1.0) == 0.0
    with pytest.raises(ValueError, match="shape"):
        metrics.distance_error(x[:2], ref, 1.0)
    with pytest.raises(ValueError, match="size"):
        metrics.distance_error(x, ref, 0.0)


def test_residual_norm_by_hand():
    A = np.array([[2.0, 0.0], [0.0, 4.0]])
    # A dv - b = (2 - 1, 4 - 2) = (1, 2): |r| = sqrt 5 = |b|
    assert metrics.residual_norm(A, np.array([1.0, 1.0]), np.array([1.0, 2.0])) == pytest.approx(1.0)
    assert metrics.residual_norm(A, np.array([0.5, 0.5]), np.array([1.0, 2.0])) == pytest.approx(0.0)
    assert metrics.residual_norm(A, np.array([1.0, 0.0]), np.zeros(2)) == pytest.approx(2.0)  # |A dv| when b = 0


def test_full_space_residual_of_full_zero_and_reduced_steps():
    sim = sa.scenes.cantilever(resolution=1, solver="direct", E=1e5, damping=None)
    evaluator = sa.scenes.cantilever(resolution=1, E=1e5, damping=None)
    s0 = sim.state.copy()
    s1 = sim.step().copy()
    assert metrics.full_space_residual(evaluator, s0, s1) < 1e-9      # the full solve leaves nothing
    assert metrics.full_space_residual(evaluator, s0, s0) == pytest.approx(1.0)  # no step: |-b| / |b|
    red = sa.scenes.cantilever(resolution=1, reducer=sa.Affinification(tau_a=1e3, tau_e=1e3), E=1e5, damping=None)
    for _ in range(5):
        before = red.state.copy()
        after = red.step().copy()
    assert 1e-4 < metrics.full_space_residual(evaluator, before, after) < 1.0


def test_reference_step_restarts_the_full_space_reference():
    # a rigid translation without gravity: no forces, so the restarted step is x + h v exactly
    sim = sa.scenes.free_body(resolution=1, spin=(0.0, 0.0, 0.0), velocity=(1.0, 2.0, 0.0))
    state = sim.state.copy()
    state.x = state.x + 0.3
    nxt = metrics.reference_step(sim, state)
    assert np.allclose(nxt.x, state.x + sim.dt * state.v, atol=1e-12)
    moved = nxt.x.copy()
    moved[0] += (0.0, 0.0, 0.2)
    assert metrics.distance_error(moved, nxt.x, sim.size) == pytest.approx(0.2 / sim.size)
    # restarting the full-space cantilever from its own state t-1 reproduces state t
    beam, again = (sa.scenes.cantilever(resolution=1, E=1e5, damping=None) for _ in range(2))
    s1 = beam.step().copy()
    s2 = beam.step().copy()
    assert metrics.distance_error(metrics.reference_step(again, s1).x, s2.x, beam.size) < 1e-12
    with pytest.raises(ValueError, match="full-space"):
        metrics.reference_step(sa.scenes.cantilever(resolution=1, reducer=sa.Affinification(), E=1e5, damping=None), s1)


def test_energy_error_is_normalised_by_the_largest_reference_energy():
    assert np.allclose(metrics.energy_error([0.0, 1.0, 3.0], [0.0, 2.0, 2.0], scale=4.0), [0.0, 0.25, 0.25])
    assert np.allclose(metrics.energy_error([1.0], [0.0], scale=0.0), [1.0])


def test_dof_ratio_clusters_speedup_phases_by_hand():
    assert metrics.dof_ratio([10, 20], [30, 30]) == pytest.approx(0.5)
    assert metrics.mean_clusters([{"n_clusters": 2}, {"n_clusters": 4}, {}]) == pytest.approx(2.0)
    assert metrics.mean_clusters([]) == 0.0
    assert metrics.speedup(10.0, 4.0) == pytest.approx(2.5)
    assert np.allclose(metrics.speedup([1.0, 2.0], [0.5, 4.0]), [2.0, 0.5])
    recs = [{"assembly": 0.1, "solve": 0.3}, {"assembly": 0.2}]
    assert metrics.phase_times(recs) == pytest.approx({"assembly": 0.3, "solve": 0.3})


def test_summarise_against_a_reference():
    ref = SimpleNamespace(wall=np.array([1.0, 1.0, 1.0]), dofs=np.array([10.0, 10.0, 10.0]))
    recs = [{"wall": 0.5, "dofs": 5, "n_clusters": 1, "distance_error": 0.01, "solve": 0.2},
            {"wall": 0.5, "dofs": 3, "n_clusters": 3, "distance_error": 0.03, "solve": 0.1}]
    s = metrics.summarise(recs, ref)
    assert s["frames"] == 2 and s["wall_s"] == pytest.approx(1.0)
    assert s["speedup"] == pytest.approx(2.0)        # the reference's first 2 frames: 2 s
    assert s["dof_ratio"] == pytest.approx(8 / 20)
    assert s["mean_clusters"] == pytest.approx(2.0)
    assert s["max_distance_error"] == pytest.approx(0.03)
    assert s["max_step_error"] is None and s["solve_s"] == pytest.approx(0.3)
    assert metrics.summarise(recs)["speedup"] is None
