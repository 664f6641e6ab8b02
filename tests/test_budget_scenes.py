"""An error budget is a promise: on every registered scene, at two budgets, the achieved error
stays within 1.25 budgets (small resolutions, few frames; docs/budget.md)."""
import warnings

import numpy as np
import pytest

import skfem_affine as sa
from skfem_affine.lab import metrics
from skfem_affine.reducers import budget

MARGIN = 1.25
BUDGETS = (0.01, 0.03)  # relative to the response: the default unit
FRAMES = 40

#: The smallest version of each registered scene (a scene added to the registry must be added here).
SMALL = {"cantilever": dict(resolution=1), "paper_beam": dict(resolution=1), "free_body": dict(resolution=1),
         "drop": dict(resolution=1, shape="box"), "stacked_beams": dict(resolution=1), "pills": dict(n=2),
         "bowling": dict(n=1), "toothbrush": dict(), "wheel": dict(), "octopus": dict(),
         "armadillo": dict(resolution=1), "twisting_beam": dict(resolution=1)}
#: Contact-free scenes, where rigidification's estimate is checked too (on the contact scenes at this
#: size nearly every frame is an impact frame, solved in full space).
RIGID = ("cantilever", "paper_beam", "free_body", "drop")


def achieved(name, reducers, frames=FRAMES):
    """Largest vertex distance to the full-space run over the full-space run's response, per reducer."""
    factory = sa.scenes.SCENES[name]
    full = factory(solver="direct", reducer=None, **SMALL[name])  # reducer=None: the armadillo has its own
    sims = [factory(solver="direct", reducer=r, **SMALL[name]) for r in reducers]
    worst, response = np.zeros(len(sims)), 0.0
    for _ in range(frames):
        full.step()
        response = max(response, metrics.response_amplitude(full.state.x, full.system.p0))
        for i, sim in enumerate(sims):
            sim.step()
            worst[i] = max(worst[i], metrics.distance_m(sim.state.x, full.state.x))
    return worst / response


def test_every_registered_scene_is_listed():
    assert set(SMALL) == set(sa.scenes.SCENES)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(SMALL))
def test_affinification_keeps_its_budget_on_every_scene(name):
    budgets = BUDGETS[1:] if name == "armadillo" else BUDGETS  # the armadillo at 1 %: its own test below
    errors = achieved(name, [sa.Affinification(target_error=b, never_slower=False) for b in budgets])
    for b, err in zip(budgets, errors):
        assert err <= MARGIN * b, (name, b, err)


@pytest.mark.slow
@pytest.mark.parametrize("name", RIGID)
def test_rigidification_keeps_its_budget(name):
    errors = achieved(name, [sa.Rigidification(target_error=b, never_slower=False) for b in BUDGETS])
    for b, err in zip(BUDGETS, errors):
        assert err <= MARGIN * b, (name, b, err)


@pytest.mark.slow
def test_rigidification_on_the_soft_twisting_beam_keeps_its_budget():
    """Its velocity errors keep moving the vertices for many frames after the frames that made them
    (the estimate counts how far: ErrorBudget.amplification)."""
    errors = achieved("twisting_beam", [sa.Rigidification(target_error=b, never_slower=False) for b in BUDGETS], 60)
    assert np.all(errors <= MARGIN * np.array(BUDGETS)), errors


def test_affinification_on_the_thrown_armadillo_keeps_its_tight_budget():
    """After landing, the rolling contact with friction carries a small reduced error on."""
    errors = achieved("armadillo", [sa.Affinification(target_error=0.01, never_slower=False)])
    assert errors[0] <= MARGIN * 0.01, errors


@pytest.mark.slow
def test_affinification_on_the_twisting_beam_in_size_units_over_a_longer_run():
    """The beam's slow swing keeps carrying the velocity errors of its reduced frames on (without the
    amplification: 1.97 budgets at 1 % of the size over 90 frames)."""
    factory = sa.scenes.SCENES["twisting_beam"]
    full = factory(solver="direct", **SMALL["twisting_beam"])
    red = factory(solver="direct", reducer=sa.Affinification(target_error=0.01, relative_to="size", never_slower=False),
                  **SMALL["twisting_beam"])
    worst = 0.0
    for _ in range(90):
        full.step()
        red.step()
        worst = max(worst, metrics.distance_error(red.state.x, full.state.x, full.size))
    assert worst <= MARGIN * 0.01, worst


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="the rigid update and the full-space linearized step lose a spinning body's "
                                       "angular momentum differently, which no frame's local error shows "
                                       "(docs/budget.md, 'What the estimate misses')")
def test_rigidification_on_a_free_spinning_body_keeps_its_budget_or_says_so():
    """500 frames of a free body spinning at 2 rad/s: within 1.25 budgets, or a warning at the frame
    the estimate passes the budget."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", budget.BudgetWarning)
        errors = achieved("free_body", [sa.Rigidification(target_error=0.01, never_slower=False)], 500)
    warned = [w for w in caught if issubclass(w.category, budget.BudgetWarning)]
    assert errors[0] <= MARGIN * 0.01 or warned, errors
