"""Bodies at rest in contact: their steady, warm-started support is part of equilibrium, so they
become affine under the error budget and stay at rest."""
import dataclasses

import numpy as np
import pytest

import skfem_affine as sa
from skfem_affine.lab.scenes import box_mesh


def _stack(reducer, cells=2):
    """A soft box on the ground and a smaller one resting on it, off centre (its bottom vertices
    inside the lower box's top face); ``cells`` per box edge."""
    mat = sa.NeoHookean(E=1e6, nu=0.3)
    bodies = [sa.ElasticBody(box_mesh(0.2, cells, (0.0, 0.0, 0.1)), mat, density=1000.0),
              sa.ElasticBody(box_mesh(0.12, cells, (0.02, 0.01, 0.26)), mat, density=1000.0)]
    return sa.Simulation(bodies, dt=0.01, gravity=(0.0, 0.0, -9.81), colliders=[sa.Plane()], reducer=reducer)


def _centres(sim):
    x, n = sim.state.x, sim.bodies[0].mesh.p.shape[1]
    return np.array([x[:n].mean(axis=0), x[n:].mean(axis=0)])


@pytest.mark.slow
def test_a_resting_stack_turns_affine_under_the_error_budget_and_stays_at_rest():
    # the default budget, 1 % of the response: the stack's response is its few mm of settling, so
    # the budget is strict, and the boxes turn affine once at rest (measured: whole from frame 52)
    full, reduced = _stack(None), _stack(sa.Affinification(never_slower=False))
    for _ in range(55):
        full.step()
        reduced.step()
    settled = _centres(reduced)
    for _ in range(15):
        full.step()
        reduced.step()
    rest = reduced.stats[-15:]
    # no frame is taken for an impact, and both boxes are affine bodies (all but a few elements)
    assert not any(r.get("impact") for r in rest) and all(r["reduced"] or r["shadow"] for r in rest)
    fractions = [r["reduced_fraction"] for r in rest if r["reduced"]]
    assert all(r["n_clusters"] >= 2 for r in rest if r["reduced"])
    assert np.mean(fractions) >= 0.98 and min(fractions) >= 0.95, fractions
    # at rest: no sinking or drifting, and where the full-space stack rests (to 1e-5 of the size)
    assert np.abs(_centres(reduced) - settled).max() < 1e-6
    assert reduced.state.x[:, 2].min() > -1e-6
    assert np.abs(_centres(reduced) - _centres(full)).max() < 2e-6


@pytest.mark.slow
def test_a_resting_stack_stays_at_rest_under_the_default_budget():
    """The stack of one-cell boxes (12 tets), reduced under the default budget (without the fall-back
    to full space, which such a small scene takes): once settled, 200 frames more at rest move
    neither box nor sink a vertex (measured: 3e-11 m and 6e-10 m). The same over 1000 frames, and
    on the two-cell stack: ``benchmarks/resting_pile.py --stack`` (docs/contact.md)."""
    sim = _stack(sa.Affinification(never_slower=False), cells=1)
    lowest, centres = np.inf, {}
    for frame, state in enumerate(sim.run(300), start=1):
        lowest = min(lowest, float(state.x[:, 2].min()))
        if frame % 50 == 0:
            centres[frame] = _centres(sim)
    rest = sim.stats[100:]
    assert np.mean([bool(r["reduced"]) for r in rest]) > 0.9 and not any(r.get("impact") for r in rest)
    assert np.mean([r["reduced_fraction"] for r in rest if r["reduced"]]) > 0.99  # two affine boxes
    assert max(np.abs(c - centres[100]).max() for c in centres.values()) < 1e-6
    assert lowest > -1e-6


@pytest.mark.slow
def test_a_resting_stack_turns_affine_at_the_papers_thresholds_and_stays_at_rest():
    sim = _stack(sa.Affinification(1e-4, 2e-4))
    for _ in sim.run(60):
        pass
    settled = sim.stats[40:]
    assert np.mean([r["reduced_fraction"] for r in settled]) > 0.8   # measured 0.95-1.0
    assert all(r["n_clusters"] >= 2 for r in settled)
    # 140 frames more at rest: no sinking or drifting (measured 2.7e-8 m and 2e-15 m)
    centres, lowest = _centres(sim), np.inf
    for state in sim.run(140):
        lowest = min(lowest, float(state.x[:, 2].min()))
    assert np.abs(_centres(sim) - centres).max() < 1e-6
    assert lowest > -1e-6
    # the contacts (19, 57 rows of J) on the two affine boxes take W from the boxes' 12 x 12 blocks
    # (dense Cholesky factors of the frame's small blocks), no unit columns solved
    rest = sim.stats[60:]
    assert all(r["delassus_columns"] == 0 for r in rest)
    assert np.median([r["delassus_dense"] for r in rest]) == 24


def test_a_landing_is_still_an_impact():
    sim = sa.scenes.drop(resolution=1, shape="box", height=0.05, reducer=sa.Affinification(never_slower=False))
    for _ in sim.run(20):
        pass
    impacts = [r["frame"] for r in sim.stats if r.get("impact")]
    assert impacts and len(impacts) <= 3     # the frame(s) of the landing, not the rest on the ground
    assert sim.stats[-1]["reduced"] or sim.stats[-1]["shadow"]


def test_a_gap_within_the_slop_counts_as_touching():
    sim = _stack(None)
    sim.step()
    contact = sim.contact
    assert contact.slop == 1e-5 * contact.detector.mean_edge
    cs = contact.current
    cs.distance = np.array([-1e-3, 0.0, 0.5 * contact.slop, 2 * contact.slop, 0.01][:cs.size])
    cs.vertex = cs.vertex[:cs.distance.size]
    b = contact._bias(cs, 0.01)
    expected = np.array([0.0, 0.0, 0.0, contact.slop / 0.01, (0.01 - contact.slop) / 0.01])
    assert np.allclose(b[0::3], expected[:cs.size], rtol=1e-12, atol=0) and not b[1::3].any() and not b[2::3].any()
    assert sa.PGS(slop=0.0).slop == 0.0


@pytest.mark.slow
def test_an_affine_stack_at_rest_converges_in_a_few_sweeps():
    """The resting stack, affine: every frame's solve reaches the tolerance in a few sweeps and the
    stack stays where it rests; without the slop too, with the plain sweeps: the penetration
    correction, sweeping on past its cap while it leaves more than 1 % of the frame's velocity
    scale, removes the nanometre penetrations each solve leaves on the coplanar contacts."""
    runs = {}
    for slop in (None, 0.0):
        sim = _stack(sa.Affinification(1e-4, 2e-4))
        sim.contact.slop = sim.contact.slop if slop is None else slop
        if slop is not None:
            sim.contact.settings = dataclasses.replace(sim.contact.settings, solver="gauss-seidel")
        for _ in sim.run(90):
            pass
        runs[slop] = sim.stats[60:], _centres(sim)
    rest, centres = runs[None]
    assert all(r["pgs_converged"] for r in rest) and max(r["pgs_iterations"] for r in rest) <= 3  # measured 1
    assert np.abs(centres - runs[0.0][1]).max() < 1e-6  # where the stack rests without the slop
    unslopped = runs[0.0][0]
    assert all(r["pgs_converged"] for r in unslopped) and max(r["max_penetration"] for r in unslopped) < 1e-8
