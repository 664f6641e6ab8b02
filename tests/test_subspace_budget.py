"""AdaptiveSubspace's error budget, time budget and never-slower fall-back (reducers/subspace/control.py)."""
import warnings

import numpy as np
import pytest

import skfem_affine as sa
from skfem_affine.lab import metrics
from skfem_affine.reducers import budget as budgets
from skfem_affine.reducers.subspace import control

import budget_runs

# As in test_budget.py: the estimate models drift with one memory time for every scene and the
# controller keeps it at half the target, so 25 % over the target is allowed.
MARGIN = 1.25


def subspace(**kw):
    kw.setdefault("basis", sa.SkinningEigenmodes(n=8, cache=False))
    kw.setdefault("subdomains", 16)
    return sa.AdaptiveSubspace(**kw)


def cantilever(reducer=None):
    return sa.scenes.cantilever(resolution=3, integrator="implicit_euler", solver="direct", reducer=reducer,
                                newton_tol=1e-3)


def ipc_drop(reducer=None):
    """A soft 0.5 m box (48 tets) at 2 m/s onto a plane, IPC with friction 0.3."""
    return sa.scenes.drop(resolution=1, shape="box", size=0.5, height=0.02, velocity=(0, 0, -2.0),
                          material=sa.NeoHookean(E=1e4, nu=0.35), integrator="implicit_euler",
                          contact=sa.IPC(friction=0.3), solver="direct", reducer=reducer, newton_tol=1e-3)


def error_run(scene, frames, reducer):
    return budget_runs.error_run(scene(), scene(reducer), frames)


@pytest.mark.slow
@pytest.mark.parametrize("name, scene, frames", [("cantilever", cantilever, 40), ("ipc-drop", ipc_drop, 30)])
def test_error_budget_holds_and_the_estimate_is_recorded(name, scene, frames):
    eps = {}
    for target in (0.01, 0.03):
        # never_slower=False, fallback=None: on scenes this small neither time nor nonzeros let reduction
        # pay, and steps solved in full space would hide the estimator
        err, stats = error_run(scene, frames, subspace(target_error=target, never_slower=False, fallback=None))
        assert err <= MARGIN * target, (name, target, err)
        assert all(np.isfinite(r["estimated_error"]) and r["estimated_error"] >= 0 for r in stats)
        assert any(r["shadow"] for r in stats) and any(r["reduced"] for r in stats)
        assert all(r["eps_modal"] == pytest.approx(control.MODAL_RATIO * r["eps_nodal"]) for r in stats)
        eps[target] = np.mean([r["eps_nodal"] for r in stats])
    assert eps[0.01] <= eps[0.03]  # a looser budget never asks for smaller thresholds


def test_the_estimate_follows_a_measured_local_error():
    # on shadow steps the measured local error is the velocity error against full-space Newton
    _, stats = error_run(cantilever, 12, subspace(target_error=0.01, never_slower=False))
    shadows = [r for r in stats if r["shadow"]]
    assert shadows and all(r["local_error"] == r["local_error_measured"] for r in shadows)
    assert any(r["local_error_measured"] > 0 for r in shadows)


def test_defaults_and_explicit_thresholds():
    default = sa.AdaptiveSubspace()
    assert (default.eps_nodal, default.eps_modal, default.target_error, default.never_slower) == (0.5, 0.5, None, True)
    explicit = sa.AdaptiveSubspace(eps_nodal=1e-3)
    assert (explicit.eps_nodal, explicit.eps_modal, explicit.never_slower, explicit.controlled) == (1e-3, 0.5, False, False)
    budgeted = sa.AdaptiveSubspace(target_error=0.02)
    assert budgeted.never_slower and budgeted.eps_modal == control.MODAL_RATIO * budgeted.eps_nodal
    sim = cantilever(subspace(eps_nodal=0.5, eps_modal=0.5))
    for _ in sim.run(3):
        pass
    assert sim.reducer.control is None
    assert not {"estimated_error", "shadow", "eps_nodal", "reduction_pays", "time_budget_miss"} & set(sim.stats[-1])


@pytest.mark.parametrize("kwargs, error, match", [
    (dict(eps_nodal=0.1, target_error=0.01), ValueError, "not both"),
    (dict(eps_modal=0.1, target_error=0.01), ValueError, "not both"),
    (dict(target_error=0.0), ValueError, "target_error"),
    (dict(target_error=2.0), ValueError, "target_error"),
    (dict(time_budget=-1.0), ValueError, "time_budget"),
    (dict(shadow_every=0), ValueError, "shadow_every"),
    (dict(memory=0.0), ValueError, "memory"),
    (dict(never_slower="yes"), TypeError, "never_slower"),
])
def test_bad_budgets_are_refused(kwargs, error, match):
    with pytest.raises(error, match=match):
        sa.AdaptiveSubspace(**kwargs)


class FakeClock:
    """Virtual seconds: a reduced step costs ``reduced`` of them, a full-space step ``full``."""

    def __init__(self, red, reduced, full=1.0):
        self.now, self.reduced, self.full = 0.0, reduced, full
        inner_step, inner_full = red._step, red._full_step

        def step(*args, **kwargs):
            out = inner_step(*args, **kwargs)
            self.now += self.reduced
            return out

        def full_step(*args, **kwargs):
            x, _ = inner_full(*args, **kwargs)
            self.now += self.full
            return x, self.full

        red._step, red._full_step, red.clock = step, full_step, self

    def __call__(self):
        return self.now


def test_the_fall_back_leaves_reduction_that_costs_more_and_returns_when_it_pays():
    red = subspace()  # the defaults: never_slower on
    sim = cantilever(red)
    clock = FakeClock(red, reduced=3.0)
    for _ in range(8):
        sim.step()
    flags = [r["reduced"] for r in sim.stats]
    # two full-space warm-up steps, one reduced step that costs 3 full ones, then full space
    assert flags[:3] == [False, False, True] and not any(flags[3:])
    assert red.control.pays.in_full and not sim.stats[-1]["reduction_pays"]
    clock.reduced = 0.2  # reduction now pays: the next probe finds it and the run returns
    for _ in range(40):
        sim.step()
    flags = [r["reduced"] for r in sim.stats]
    probes = [i for i, r in enumerate(sim.stats) if r["shadow"]]
    assert probes and all(not flags[i] for i in probes)  # a probe returns the full solution
    after = sim.stats[probes[0] + 1:]
    assert all(r["reduced"] for r in after if not r["shadow"])
    assert any(r["shadow"] for r in after)  # shadow steps keep the full cost current
    assert not red.control.pays.in_full


class SlowClock:
    """Each reading one second later: every reduced step runs past its deadline at once."""

    def __init__(self):
        self.now = 0.0

    def __call__(self):
        self.now += 1.0
        return self.now


def test_a_run_that_never_reduces_equals_full_space_newton():
    red = subspace()
    red.clock = SlowClock()
    sim, full = cantilever(red), cantilever()
    for _ in range(30):
        sim.step()
        full.step()
    assert not any(r["reduced"] for r in sim.stats)
    assert any(r.get("over_deadline") for r in sim.stats)
    np.testing.assert_allclose(sim.state.x, full.state.x, rtol=0, atol=1e-12 * full.size)
    np.testing.assert_allclose(sim.state.v, full.state.v, rtol=0, atol=1e-10)


def test_the_time_budget_caps_the_enrichment():
    def run(time_budget):
        red = subspace(eps_nodal=1e-7, eps_modal=1e-7, time_budget=time_budget, fallback=None)
        sim = cantilever(red)
        sim.step()
        if time_budget is not None:
            rec = {"wall": 3 * time_budget}  # the clock says: three times the budget
            red.end_frame(rec)
            assert rec["time_budget_miss"] and rec["min_fraction_next"] == pytest.approx(1.0)
        sim.step()
        return sim.stats[-1]
    free = run(None)
    capped = run(0.01)
    assert free["enriched_ratio"] > 0.2 and capped["enriched_ratio"] == 0.0 and capped["min_fraction"] == 1.0


def test_capped_enrichment_takes_the_largest_errors_first():
    part_of = np.array([0, 0, 1, 1, 1, 2, 2])
    add = np.ones(7, dtype=bool)
    enriched = np.zeros(7, dtype=bool)
    score = np.array([0.1, 0.2, 0.5, 0.0, 0.0, 0.9, 0.1])
    parts = np.array([0, 1, 2])
    got = control.capped_enrichment(add, enriched, parts, part_of, score, cap=5)
    assert got.tolist() == [False, False, True, True, True, True, True]  # parts 2 (0.9) and 1 (0.5): 5 vertices
    assert not control.capped_enrichment(add, np.ones(7, dtype=bool), parts, part_of, score, cap=5).any()


def test_controller_state_is_plain_numbers_and_restores():
    red = subspace(target_error=0.01, time_budget=1.0)
    sim = cantilever(red)
    for _ in sim.run(4):
        pass
    state = red.state_dict()["controllers"]
    assert set(state) == {"error_budget", "timer", "pays", "shadows", "plan", "thresholds"}
    assert all(isinstance(v, (int, float, bool)) or (isinstance(v, list) and all(isinstance(u, float) for u in v))
               for d in state.values() for v in d.values())
    other = subspace(target_error=0.01, time_budget=1.0)
    cantilever(other)
    other.controllers = state
    assert other.controllers == state and other.eps_nodal == red.eps_nodal
    plain = subspace(eps_nodal=0.5)
    cantilever(plain)
    with pytest.raises(ValueError, match="no controllers"):
        plain.controllers = state


def test_step_costs_judge_by_step_and_by_newton_iteration():
    p = control.StepCosts(patience=1)
    p.full_solved(9.0, iterations=3)  # the first (symbolic analysis) is no sample
    p.full_solved(1.0, iterations=2)
    assert p.full_cost == 1.0 and p.full_iteration == 0.5
    p.reduced_solved(0.8, 0.1, iterations=1)  # cheaper per step, but one reduced iteration costs 0.8 > 0.5
    assert not p.pays()
    p.reduced_solved(0.8, 0.1, fresh=True, iterations=4)  # 0.2 per iteration
    assert p.pays()
    p.shadow_solved(0.4, iterations=2)  # a shadow measures the full step where the run is now
    assert p.full_cost == 0.4 and not p.pays()


def test_trial_steps_get_a_shorter_deadline_and_a_phase_change_asks_for_a_shadow():
    c = control.Controllers(never_slower=True)
    assert [c.plan() for _ in range(control.WARMUP)] == ["full"] * control.WARMUP and c.deadline() is None
    c.pays.full_solved(5.0, 2)
    c.pays.full_solved(1.0, 2)
    assert c.plan() == "reduced" and c.deadline() == pytest.approx(control.TRIAL)  # the first reduced step
    c.reduced_measured(0.4, shadow=False)
    c.pays.reduced_solved(0.4, 0.1, iterations=2)
    c.pays.decide(c.shadow_period())
    assert c.plan() == "reduced" and c.deadline() == pytest.approx(1.0)
    assert not c.shadow_due("reduced")
    c.reduced_measured(0.1, shadow=False)  # four times cheaper than where the full cost was measured
    assert c.shadow_due("reduced")


def plucked_beam(reducer=None):
    """The k=1 cantilever (24 tets) released from its tip-load shape (a cubic, 0.3 m at the tip), no gravity."""
    sim = sa.scenes.cantilever(resolution=1, integrator="implicit_euler", solver="direct", reducer=reducer,
                               newton_tol=1e-3, gravity=(0.0, 0.0, 0.0))
    x = sim.state.x.copy()
    s = x[:, 0] / np.ptp(sim.system.p0[:, 0])
    x[:, 2] -= 0.3 * s ** 2 * (3 - s) / 2
    sim.state.x = x
    return sim


def ipc_incline(reducer=None):
    """A 0.5 m box (48 tets) 0.5 mm above a 20-degree incline (gravity tilted), IPC friction 0.25: it
    settles on the barrier and slides."""
    g, theta = 9.81, np.radians(20)
    return sa.scenes.drop(resolution=1, shape="box", size=0.5, height=5e-4, velocity=(0, 0, 0),
                          gravity=(g * np.sin(theta), 0, -g * np.cos(theta)), material=sa.NeoHookean(E=1e6, nu=0.35),
                          integrator="implicit_euler", contact=sa.IPC(friction=0.25), solver="direct",
                          reducer=reducer, newton_tol=1e-6)


def response_error(scene, frames, reducer):
    """The reduced run's largest vertex distance to the full-space run over its final response, and its stats."""
    full, red = scene(), scene(reducer)
    worst = response = 0.0
    for _ in range(frames):
        full.step()
        red.step()
        response = max(response, metrics.response_amplitude(full.state.x, full.system.p0))
        worst = max(worst, metrics.distance_m(red.state.x, full.state.x))
    return worst / response, red.stats


def test_a_reduced_step_that_would_break_the_budget_is_refused():
    """The plucked beam's first reduced steps would take the estimate past the budget (to 2.4 budgets
    unrefused): they are solved again in full space, and the estimate stays within the budget."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", budgets.BudgetWarning)
        err, stats = response_error(plucked_beam, 20, subspace(target_error=0.01, never_slower=False, fallback=None))
    assert any(r["refused"] and r["shadow"] and not r["reduced"] for r in stats)
    assert any(r["reduced"] for r in stats)
    assert max(r["estimated_error"] for r in stats) <= 0.01
    assert err <= MARGIN * 0.01, err


def test_steps_solved_in_full_space_take_the_friction_iterations_of_the_full_space_run():
    """On the incline, the first frames are shadows and refused steps: their full-space solves must be
    the full-space run's (its lagged friction relagged at the solution), or the box slides off at
    another speed that no later frame takes back."""
    red = subspace(target_error=0.01, never_slower=False, fallback=None)
    full, sim = ipc_incline(), ipc_incline(red)
    for _ in range(8):
        full.step()
        sim.step()
        if sim.stats[-1]["reduced"]:
            break
        assert np.array_equal(sim.state.x, full.state.x)  # every step so far solved in full space
    assert len(sim.stats) >= 3
    err, _ = response_error(ipc_incline, 30, subspace(target_error=0.01, never_slower=False, fallback=None))
    assert err <= MARGIN * 0.01, err
