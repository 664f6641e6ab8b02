"""Procedural scenes: each returns a ready :class:`~skfem_affine.Simulation`.

Every scene takes keyword overrides (``material``, ``dt``, ``reducer``,
``damping``, ``solver``, ...) that are passed on to the body or simulation,
and records its default number of frames in ``sim.frames``.
"""
import numpy as np
import skfem

from .body import ElasticBody
from .integrator import Simulation
from .materials import NeoHookean

SIM_KEYS = ("dt", "gravity", "damping", "reducer", "solver", "newton_iters", "newton_tol", "integrator",
            "project_hessian", "mass")


def _split(kwargs):
    sim = {k: kwargs.pop(k) for k in SIM_KEYS if k in kwargs}
    return sim, kwargs


def beam_mesh(resolution, length=4.0, width=1.0):
    """A length x width x width box with ``resolution`` cells across: 24 k^3 tets (length 4)."""
    k = int(resolution)
    if k < 1:
        raise ValueError(f"resolution must be >= 1, got {resolution}")
    nx = max(1, int(round(k * length / width)))
    return skfem.MeshTet.init_tensor(np.linspace(0, length, nx + 1), np.linspace(0, width, k + 1),
                                     np.linspace(0, width, k + 1))


def cantilever(resolution=6, length=4.0, width=1.0, frames=370, **kwargs):
    """A beam pinned at x = 0 falling under gravity (paper Fig. 17 / Table 1 "Beam").

    Defaults: Neo-Hookean E = 1e5 Pa, nu = 0.35, density 1000 kg/m^3, h = 0.01 s,
    370 frames; ``resolution=k`` gives 24 k^3 tets (k=6: 5184, about the paper's 5.5k).
    """
    sim_kw, body_kw = _split(dict(kwargs))
    sim_kw.setdefault("dt", 0.01)
    sim_kw.setdefault("gravity", (0.0, 0.0, -9.81))
    mesh = beam_mesh(resolution, length, width)
    body_kw.setdefault("material", NeoHookean(E=1e5, nu=0.35))
    body_kw.setdefault("density", 1000.0)
    body_kw.setdefault("fixed", mesh.nodes_satisfying(lambda p: p[0] < 1e-9 * length))
    sim = Simulation(ElasticBody(mesh, name="cantilever", **body_kw), **sim_kw)
    sim.frames = frames
    sim.scene = "cantilever"
    return sim


def free_body(resolution=3, shape="cube", size=1.0, spin=(0.0, 0.0, 2.0), velocity=(0.5, 0.0, 0.0),
              frames=100, **kwargs):
    """A cube (or ball) flying without gravity, spinning about its centre of mass.

    ``spin`` is the angular velocity (rad/s), ``velocity`` the centre-of-mass velocity.
    """
    sim_kw, body_kw = _split(dict(kwargs))
    sim_kw.setdefault("dt", 0.01)
    k = int(resolution)
    if shape == "cube":
        mesh = skfem.MeshTet.init_tensor(*[np.linspace(-size / 2, size / 2, k + 1)] * 3)
    elif shape == "ball":
        mesh = skfem.MeshTet.init_ball(nrefs=max(0, k - 1)).scaled(size / 2)
    else:
        raise ValueError(f"shape must be 'cube' or 'ball', got {shape!r}")
    x = mesh.p.T
    com = x.mean(axis=0)
    body_kw.setdefault("velocity", np.asarray(velocity, float) + np.cross(np.asarray(spin, float), x - com))
    body_kw.setdefault("material", NeoHookean(E=1e5, nu=0.35))
    body_kw.setdefault("density", 1000.0)
    sim = Simulation(ElasticBody(mesh, name=f"free_{shape}", **body_kw), **sim_kw)
    sim.frames = frames
    sim.scene = "free_body"
    return sim


SCENES = {"cantilever": cantilever, "free_body": free_body}
