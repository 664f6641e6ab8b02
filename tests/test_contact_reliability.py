"""Contact never leaves bodies in a wrong state: penetrations resolve without launching, fast
impacts do not tunnel, the barrier refuses a start it could not move."""
import warnings

import numpy as np
import pytest

import skfem_affine as sa
from skfem_affine.lab import scenes


def _bottoms(sim, frames):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", sa.SimulationWarning)
        return np.array([s.x[:, 2].min() for s in sim.run(frames)])


@pytest.mark.parametrize("shape, depth", [("box", 0.3), ("ball", 0.4)])
def test_a_body_starting_inside_the_floor_is_pushed_out_without_launch(shape, depth):
    sim = scenes.drop(shape=shape, height=-depth)
    bottom = _bottoms(sim, 60)
    pen = np.array([r["max_penetration"] for r in sim.stats])
    assert pen[0] > 0.5 * depth * 0.8  # a real penetration to resolve
    assert np.all(np.diff(pen[:20]) < 0)  # shrinks every frame
    assert pen[40:].max() < 1e-3  # resolved within a bounded number of frames
    assert bottom.max() < 1e-3  # never launched above the floor
    # the push-out's energy is accounted as work (raising the body), never as velocity
    work = sum(r.get("contact_work", 0.0) for r in sim.stats)
    assert work > 0 and sim.stats[-1]["energy"] <= sim.stats[0]["energy"] + work + 1e-6
    assert np.linalg.norm(sim.state.v, axis=1).max() < 0.5


def test_overlapping_bodies_are_separated():
    sim = scenes.stacked_beams(resolution=1, n=2, gap=-0.15)
    tops = _bottoms(sim, 40)
    pen = [r["max_penetration"] for r in sim.stats]
    assert pen[0] > 0.05 and max(pen[30:]) < 1e-3 and pen[-1] < 1e-4
    assert np.isfinite(tops).all()


def test_a_body_starting_inside_a_sphere_is_pushed_out_smoothly():
    sim = scenes.drop(shape="box", height=0.3, gravity=(0, 0, 0),
                      colliders=[sa.Sphere(center=(0.25, 0.25, 0.3), radius=0.3)])
    _bottoms(sim, 60)
    pen = [r["max_penetration"] for r in sim.stats]
    assert pen[0] > 0.1 and pen[-1] < 0.1 * pen[0]
    speed = np.linalg.norm(sim.state.v, axis=1).max()
    assert speed < 0.5  # pushed out through the positions, not launched


@pytest.mark.parametrize("speed", [20.0, 200.0])
@pytest.mark.parametrize("shape", ["box", "ball"])
def test_fast_impacts_do_not_tunnel_through_a_plane_or_a_thin_wall(shape, speed):
    sim = scenes.drop(shape=shape, height=0.05, velocity=(0, 0, -speed))
    assert _bottoms(sim, 20).min() > -1e-4
    assert max(r["max_penetration"] for r in sim.stats) < 1e-4
    t = 0.002
    wall = sa.Box(center=(0.5 + t, 0, 0.55), half_extents=(t, 1.0, 1.0))
    sim = scenes.drop(shape=shape, height=0.3, velocity=(speed, 0, 0), gravity=(0, 0, 0), colliders=[wall])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", sa.SimulationWarning)
        xmax = max(s.x[:, 0].max() for s in sim.run(20))
    assert xmax < 0.5 + 1e-4


def test_the_barrier_refuses_a_start_on_or_inside_a_collider():
    for height in (0.0, -0.1):
        with pytest.raises(ValueError, match=r"collider 0 \(Plane\): 25 vertices on or inside it, e.g. 0 "):
            scenes.drop(shape="box", height=height, integrator="implicit_euler", contact=None)
    sim = scenes.drop(shape="box", height=0.1, integrator="implicit_euler", contact=None)
    with pytest.raises(ValueError, match="collider 0 \\(Sphere\\)"):
        sim.colliders = [sa.Sphere(center=(0, 0, 0.35), radius=0.2)]
    list(sim.run(2))  # the valid start still runs
    assert sim.stats[-1]["max_penetration"] == 0.0


def test_push_limit_is_checked_and_bounds_the_correction():
    with pytest.raises(ValueError, match="push_limit"):
        sa.PGS(push_limit=0.0)
    sim = scenes.drop(shape="box", height=-0.3, contact=sa.PGS(push_limit=0.01))
    _bottoms(sim, 3)
    pen = [r["max_penetration"] for r in sim.stats]
    assert 0.0 < pen[0] - pen[1] <= 0.01 + 1e-9
