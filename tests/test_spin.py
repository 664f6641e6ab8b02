"""The spin of free bodies: the linearized step's rotation-aware Taylor term, and rigid bodies' exact motion."""
import warnings

import numpy as np
import pytest

import skfem_affine as sa
from skfem_affine.lab import scenes


def angular_momentum(sim, s):
    """|L| about the centre of mass (lumped mass)."""
    m = sim.system.lumped_mass[:, None]
    c = (m * s.x).sum(0) / m.sum()
    return np.linalg.norm((m * np.cross(s.x - c, s.v)).sum(0))


def kept_spin(sim, seconds):
    """|L(T)| / |L(0)| after ``seconds`` of the run."""
    L0 = angular_momentum(sim, sim.state)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no energy created, nothing inverted
        for s in sim.run(int(round(seconds / sim.dt))):
            pass
    return angular_momentum(sim, s) / L0


@pytest.mark.parametrize("E", [1e5, 1e6, 1e7, 1e8, 1e9])
def test_the_linearized_step_keeps_a_stiff_free_body_spinning_as_implicit_euler_does(E):
    """A free cube spinning at w = 2 rad/s, h = 0.01, over 5 s: the default step keeps at least implicit
    Euler's angular momentum less 2 % (the docs' law: a loss of at most h w^2 per unit time) and
    creates none."""
    w, T = 2.0, 5.0
    kept = {}
    for integrator in ("linearized", "implicit_euler"):
        sim = scenes.free_body(resolution=1, spin=(0, 0, w), material=sa.NeoHookean(E=E, nu=0.35),
                               integrator=integrator)
        kept[integrator] = kept_spin(sim, T)
    h = sim.dt
    assert kept["linearized"] >= kept["implicit_euler"] - 0.02, kept
    assert 1 - h * w * w * T <= kept["linearized"] <= 1.0, kept


def _rigid_spinner(E, warmup_frames=3, stretch=1.0):
    """A free 48-tet cube spinning about a tilted axis, held rigid by thresholds it never exceeds;
    ``stretch`` scales its start positions about the centre (a stressed rigid body)."""
    sim = scenes.free_body(resolution=2, spin=(0.5, 1.0, 2.0), velocity=(0.1, 0.0, 0.0),
                           material=sa.NeoHookean(E=E, nu=0.35),
                           reducer=sa.Rigidification(1e6, 2e6, warmup_frames=warmup_frames))
    if stretch != 1.0:
        x = sim.state.x
        c = x.mean(axis=0)
        sim.state.x[:] = c + stretch * (x - c)
        sim.state.v[:] = (0.1, 0.0, 0.0) + np.cross((0.5, 1.0, 2.0), sim.state.x - c)
    return sim


@pytest.mark.parametrize("E", [1e5, 1e8])
def test_a_free_rigid_body_keeps_its_angular_momentum(E):
    """One rigid body for 497 of 500 frames (elastic for its 3 warm-up frames): the vector L kept to 1 %
    of |L0|, the centre moving at constant velocity, the energy of its rigid frames constant to 1e-6."""
    sim = _rigid_spinner(E)
    m = sim.system.lumped_mass[:, None]
    L0 = (m * np.cross(sim.state.x - (m * sim.state.x).sum(0) / m.sum(), sim.state.v)).sum(0)
    for s in sim.run(500):
        pass
    assert all(r["n_clusters"] == 1 and r["reduced_fraction"] == 1.0 for r in sim.stats[3:])
    L = (m * np.cross(s.x - (m * s.x).sum(0) / m.sum(), s.v)).sum(0)
    assert np.linalg.norm(L - L0) <= 0.01 * np.linalg.norm(L0)
    assert (m * s.v).sum(0) / m.sum() == pytest.approx((0.1, 0.0, 0.0), abs=1e-9)
    assert sim.stats[-1]["energy"] == pytest.approx(sim.stats[3]["energy"], rel=1e-6)


def test_a_rigid_body_interior_adds_nothing():
    """A stressed body (started 2 % stretched) rigid from the first frame moves the same, to round-off,
    whatever its stiffness: its interior's forces and stiffness do not enter its 6 DOFs."""
    runs = []
    for E in (1e5, 1e8):
        sim = _rigid_spinner(E, warmup_frames=0, stretch=1.02)
        for s in sim.run(100):
            pass
        assert all(r["n_clusters"] == 1 and r["reduced_fraction"] == 1.0 for r in sim.stats)
        runs.append(s)
    assert np.abs(runs[0].x - runs[1].x).max() <= 1e-9 * sim.size
    assert np.abs(runs[0].v - runs[1].v).max() <= 1e-9
