"""Errors and budgets in the user's units: relative to the response, to the scene size, or in metres."""
import math

import numpy as np
import pytest
import skfem

import skfem_affine as sa
from skfem_affine.lab import metrics, runners
from skfem_affine.reducers import budget


def test_the_unit_is_the_response_so_far_floored_or_the_size_or_a_metre():
    eb = budget.ErrorBudget(0.01, 1e-3, relative_to="response")
    assert eb.scale(10.0, 0.0) == pytest.approx(budget.RESPONSE_FLOOR * 10.0)  # at rest: the floor
    assert eb.scale(10.0, 0.5) == 0.5
    assert eb.scale(10.0, 0.2) == 0.5  # the running maximum: a beam swinging back keeps its response
    assert budget.ErrorBudget(0.01, 1e-3, relative_to="size").scale(10.0, 0.5) == 10.0
    assert budget.ErrorBudget(0.01, 1e-3, relative_to="metre").scale(10.0, 0.5) == 1.0


def test_the_estimate_accumulates_metres_and_reads_them_in_the_unit():
    eb = budget.ErrorBudget(0.01, 1e-3, memory=0.5, relative_to="response")
    h = 0.01
    eb.scale(4.0, 0.1)
    eb.advance(0.2, h, 4.0)                      # D = h delta = 2e-3 m
    assert eb.drift == pytest.approx(2e-3) and eb.estimate == pytest.approx(2e-3 / 0.1)
    eb.scale(4.0, 0.4)                           # the response grew: the same metres are a smaller part of it
    eb.advance(0.0, h, 4.0)
    assert eb.estimate == pytest.approx(math.exp(-h / 0.5) * 2e-3 / 0.4)
    assert eb.local_rate == 0.0
    size = budget.ErrorBudget(0.01, 1e-3)        # the scene size: the former definition
    size.advance(0.2, h, 4.0)
    assert size.estimate == pytest.approx(h * 0.2 / 4.0)


def test_a_frame_that_would_break_the_budget_is_refused():
    eb = budget.ErrorBudget(0.01, 1e-3, relative_to="metre")
    eb.scale(1.0)
    h = 0.01
    assert not eb.breaks(0.01 * budget.KICK * 0.9 / h, h)      # under a quarter of the budget in one frame
    assert eb.breaks(0.01 * budget.KICK * 1.1 / h, h)          # over it
    eb.drift = eb.estimate = 0.0099                           # near the budget: a small frame would cross it
    assert eb.breaks(0.01 * 0.05 / h, h) and not eb.breaks(0.0, h)


@pytest.mark.parametrize("make", [sa.Affinification, sa.Rigidification,
                                  lambda **kw: sa.AdaptiveSubspace(target_error=0.01, **kw)])
def test_a_bad_unit_is_refused_naming_the_argument(make):
    with pytest.raises(ValueError, match="relative_to must be one of 'response', 'size', 'metre'"):
        make(relative_to="percent")
    with pytest.raises(ValueError, match="relative_to"):
        make(relative_to=1.0)


def test_units_and_their_budgets_are_checked():
    assert sa.Affinification().relative_to == "response" == budget.DEFAULT_RELATIVE_TO
    assert sa.Affinification(target_error=0.002, relative_to="metre").target_error == 0.002
    assert sa.Rigidification(target_error=5.0, relative_to="metre").target_error == 5.0  # 5 m: allowed
    with pytest.raises(ValueError, match="target_error"):
        sa.Affinification(target_error=2.0)                   # 200 % of the response
    with pytest.raises(ValueError, match="explicit thresholds"):
        sa.Affinification(0.1, 0.2, relative_to="size")
    with pytest.raises(ValueError, match="give target_error with it"):
        sa.AdaptiveSubspace(relative_to="size")
    assert sa.AdaptiveSubspace(target_error=0.01).relative_to == "response"
    assert sa.Affinification(0.1, 0.2).relative_to is None


def test_response_amplitude_and_distances_by_hand():
    rest = np.zeros((2, 3))
    frames = np.array([[[0, 0, 0], [0, 0, 0]], [[0, 3, 4], [1, 0, 0]], [[0, 0, 1], [0, 0, 0]]], float)
    assert metrics.response_amplitude(frames, rest) == 5.0
    assert metrics.distance_m(frames[1], frames[2]) == pytest.approx(math.sqrt(9 + 9))
    assert metrics.relative(2.0, 4.0) == 0.5 and metrics.relative(2.0, 0.0) is None


def _cube(material):
    mesh = skfem.MeshTet.init_tensor(*[np.linspace(0, 1, 3)] * 3)
    return sa.Simulation(sa.ElasticBody(mesh, material), dt=0.01).system


def test_cauchy_stress_of_uniaxial_stretch_is_the_closed_form():
    E, nu, eps = 1e6, 0.3, 0.02
    system = _cube(sa.StVK(E=E, nu=nu))
    lam, mu = E * nu / ((1 + nu) * (1 - 2 * nu)), E / (2 * (1 + nu))
    x = system.p0 * np.array([1 + eps, 1.0, 1.0])
    sigma = metrics.cauchy_stress(system, x)
    e = eps + eps ** 2 / 2                        # Green-Lagrange E_xx; S = lam tr(E) I + 2 mu E
    expected = np.diag([(1 + eps) * (lam + 2 * mu) * e, lam * e / (1 + eps), lam * e / (1 + eps)])
    np.testing.assert_allclose(sigma, np.broadcast_to(expected, sigma.shape), rtol=1e-10, atol=1e-6)


def test_cauchy_stress_under_hydrostatic_compression_is_a_pressure():
    system = _cube(sa.NeoHookean(E=1e6, nu=0.3))
    sigma = metrics.cauchy_stress(system, 0.95 * system.p0)
    p = sigma[:, 0, 0]
    assert np.all(p < 0)
    np.testing.assert_allclose(sigma, p[:, None, None] * np.eye(3), atol=1e-8 * abs(p).max())


def test_stress_error_by_hand():
    ref = np.zeros((2, 3, 3))
    ref[1, 0, 0] = 10.0
    other = ref.copy()
    other[0, 1, 1] = 2.0
    assert metrics.largest_stress(ref) == 10.0
    assert metrics.stress_error(other, ref, metrics.largest_stress(ref)) == pytest.approx(0.2)


def test_the_response_budget_holds_and_is_tighter_than_the_size_one():
    full = sa.scenes.cantilever(resolution=2, solver="direct")
    runs = {unit: sa.scenes.cantilever(resolution=2, solver="direct",
                                       reducer=sa.Affinification(target_error=0.01, relative_to=unit,
                                                                 never_slower=False))
            for unit in ("response", "size")}
    worst = dict.fromkeys(runs, 0.0)
    response = 0.0
    for _ in range(60):
        full.step()
        response = max(response, metrics.response_amplitude(full.state.x, full.system.p0))
        for unit, sim in runs.items():
            sim.step()
            worst[unit] = max(worst[unit], metrics.distance_m(sim.state.x, full.state.x))
    assert worst["response"] / response <= 1.25 * 0.01
    assert worst["size"] / full.size <= 1.25 * 0.01
    dofs = {u: np.mean([r.get("reduced_dofs", r["dofs"]) for r in s.stats]) for u, s in runs.items()}
    assert dofs["response"] > dofs["size"]  # the response (7 cm) is far under the size (4.2 m): fewer bodies
    # online, the unit is the response so far: never more than the run's response the report divides by
    assert all(r["error_unit"] <= response * (1 + 1e-9) for r in runs["response"].stats)


def test_compare_reports_both_normalisations_and_the_stress_error():
    spec = runners.SceneSpec.make("cantilever", resolution=1)
    _, runs = runners.compare(spec, 6, ("affinification",), step_error=False, residual=False, warm=False,
                              keep_every=0)
    s = runs["affinification"].summary
    assert s["response_m"] > 0 and s["size_m"] == pytest.approx(runs["full"].sim.size)
    assert s["max_response_error"] == pytest.approx(s["max_distance_m"] / s["response_m"])
    assert s["max_distance_error"] == pytest.approx(s["max_distance_m"] / s["size_m"])
    assert s["max_stress_error"] is not None and s["max_stress_error"] >= 0
    assert runs["full"].summary["max_stress_error"] == 0.0
