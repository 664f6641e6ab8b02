"""Procedural scenes: each returns a ready :class:`~skfem_affine.Simulation`.

Every scene takes keyword overrides (``material``, ``dt``, ``reducer``,
``damping``, ``solver``, ``colliders``, ``contact``, ...) that are passed on to the
body or simulation, and records its default number of frames in ``sim.frames``
and its name in ``sim.scene``.

Contact scenes (paper sec. 4): :func:`drop`, :func:`stacked_beams`, :func:`pills`,
:func:`bowling`, :func:`toothbrush`. Their meshes are procedural scikit-fem meshes
(``MeshTet.init_tensor``, ``init_ball``, mapped or restricted), so no mesher is needed.
"""
import numpy as np
import skfem

from skfem_affine.body import ElasticBody
from skfem_affine.checks import integer
from skfem_affine.contact.colliders import Bowl, Plane
from skfem_affine.contact.pgs import PGS
from skfem_affine.simulation import Simulation
from skfem_affine.materials import NeoHookean

SIM_KEYS = ("dt", "gravity", "damping", "reducer", "solver", "newton_iters", "newton_tol", "integrator",
            "project_hessian", "mass", "colliders", "contact", "on_inverted", "on_nonconvergence", "check_energy")


def _split(kwargs):
    sim = {k: kwargs.pop(k) for k in SIM_KEYS if k in kwargs}
    return sim, kwargs


def beam_mesh(resolution, length=4.0, width=1.0):
    """A length x width x width box with ``resolution`` cells across: 24 k^3 tets (length 4)."""
    k = integer(resolution, "resolution", low=1)
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
    k = integer(resolution, "resolution", low=1)
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





# ---------------------------------------------------------------------------- contact scenes
def _resolution(resolution):
    return integer(resolution, "resolution", low=1)


def box_mesh(size, cells, center=(0.0, 0.0, 0.0)):
    """A box of ``size`` (3,) with ``cells`` (3,) tensor cells (6 tets each) centred at ``center``."""
    size, center = np.broadcast_to(np.asarray(size, float), (3,)), np.asarray(center, float)
    cells = np.broadcast_to(np.asarray(cells, int), (3,))
    axes = [np.linspace(c - s / 2, c + s / 2, n + 1) for c, s, n in zip(center, size, cells)]
    return skfem.MeshTet.init_tensor(*axes)


def ball_mesh(radius, resolution, center=(0.0, 0.0, 0.0)):
    """scikit-fem's ball, refined ``resolution`` times (8 * 8^k tets), scaled and moved."""
    return skfem.MeshTet.init_ball(nrefs=_resolution(resolution)).scaled(radius).translated(center)


def capsule_mesh(radius, half_length, resolution, center=(0.0, 0.0, 0.0), axis=0):
    """A capsule (segment of ``half_length`` along ``axis`` swept by a ball of ``radius``).

    A tensor box around the segment is mapped onto the capsule: each point q off
    the segment moves radially to ``q ||q||_inf / ||q||_2``, which sends the box's
    faces onto the capsule's cylinder and hemispherical caps.
    """
    k = _resolution(resolution)
    across = 2 * k
    along = max(across, int(round(across * (half_length + radius) / radius)))
    mesh = box_mesh((2 * (half_length + radius), 2 * radius, 2 * radius), (along, across, across))
    p = mesh.p.T.copy()
    seg = np.clip(p[:, 0], -half_length, half_length)
    q = p - np.column_stack([seg, np.zeros((len(p), 2))])
    q2 = np.linalg.norm(q, axis=1)
    scale = np.where(q2 > 0, np.abs(q).max(axis=1) / np.maximum(q2, 1e-300), 1.0)
    p = np.column_stack([seg, np.zeros((len(p), 2))]) + scale[:, None] * q
    p = np.roll(p, axis, axis=1) + np.asarray(center, float)
    return skfem.MeshTet(np.ascontiguousarray(p.T), mesh.t)


def _contact_scene_kwargs(kwargs, friction, collider):
    """Split keyword overrides; defaults h = 0.01, gravity -z, ``collider`` and PGS(friction)."""
    sim_kw, body_kw = _split(dict(kwargs))
    sim_kw.setdefault("dt", 0.01)
    sim_kw.setdefault("gravity", (0.0, 0.0, -9.81))
    sim_kw.setdefault("colliders", [collider])
    sim_kw.setdefault("contact", PGS(friction=friction))
    return sim_kw, body_kw


def _count(n):
    return integer(n, "n", low=1)


def _scene(sim, name, frames):
    sim.frames, sim.scene = frames, name
    return sim


def drop(resolution=2, shape="ball", size=0.5, height=0.3, frames=150, **kwargs):
    """A soft ball (or box) of diameter ``size`` dropped from ``height`` (gap) onto a plane z = 0.

    Defaults: Neo-Hookean E = 1e5 Pa, nu = 0.35, density 1000, h = 0.01 s, friction 0.5;
    ``resolution=k``: 8^(k+1) tets for the ball, 6 (2k)^3 for the box.
    """
    sim_kw, body_kw = _contact_scene_kwargs(kwargs, 0.5, Plane((0.0, 0.0, 0.0), (0.0, 0.0, 1.0)))
    k = _resolution(resolution)
    centre = (0.0, 0.0, height + size / 2)
    if shape == "ball":
        mesh = ball_mesh(size / 2, k, centre)
    elif shape == "box":
        mesh = box_mesh(size, 2 * k, centre)
    else:
        raise ValueError(f"shape must be 'ball' or 'box', got {shape!r}")
    body_kw.setdefault("material", NeoHookean(E=1e5, nu=0.35))
    body_kw.setdefault("density", 1000.0)
    return _scene(Simulation(ElasticBody(mesh, name=f"drop_{shape}", **body_kw), **sim_kw), "drop", frames)


def stacked_beams(resolution=2, n=2, length=2.0, width=0.4, gap=0.02, frames=200, **kwargs):
    """``n`` beams stacked crosswise (paper Fig. 8) and dropped by ``gap`` onto a plane and each other.

    Defaults: Neo-Hookean E = 1e6, nu = 0.35, density 1000, h = 0.01, friction 0.5;
    each beam has ``resolution`` cells across its width (6 k^2 round(k length / width) tets).
    """
    sim_kw, body_kw = _contact_scene_kwargs(kwargs, 0.5, Plane())
    k = _resolution(resolution)
    n = _count(n)
    along = max(1, int(round(k * length / width)))
    body_kw.setdefault("material", NeoHookean(E=1e6, nu=0.35))
    body_kw.setdefault("density", 1000.0)
    bodies = []
    for i in range(n):
        z = gap + i * (width + gap) + width / 2
        size, cells = ((length, width, width), (along, k, k)) if i % 2 == 0 else ((width, length, width), (k, along, k))
        bodies.append(ElasticBody(box_mesh(size, cells, (0.0, 0.0, z)), name=f"beam{i}", **body_kw))
    return _scene(Simulation(bodies, **sim_kw), "stacked_beams", frames)


def pills(n=8, resolution=1, radius=0.1, half_length=0.12, bowl_radius=0.6, frames=300,
          materials=None, **kwargs):
    """``n`` capsules dropped into a bowl, alternating two materials (paper Table 1 "Pills").

    Pills lie in layers of four, each layer turned by 90 degrees, the lowest at the
    bowl's rim height. Defaults: Neo-Hookean (E = 2e4, nu = 0.34) and (E = 1e6,
    nu = 0.36), density 1000, h = 0.01, friction 0.3; ``materials`` overrides the pair.
    """
    bowl = Bowl(center=(0.0, 0.0, bowl_radius), radius=bowl_radius)
    sim_kw, body_kw = _contact_scene_kwargs(kwargs, 0.3, bowl)
    n = _count(n)
    mats = materials or (NeoHookean(E=2e4, nu=0.34), NeoHookean(E=1e6, nu=0.36))
    body_kw.setdefault("density", 1000.0)
    if "material" in body_kw:
        mats = (body_kw.pop("material"),) * 2
    spacing = 2 * radius + 0.025 * bowl_radius
    bodies = []
    for i in range(n):
        layer, slot = divmod(i, 4)
        offset = (slot - 1.5) * spacing
        axis = layer % 2
        centre = [0.0, 0.0, bowl_radius + layer * (2 * radius + 0.05 * bowl_radius)]
        centre[1 - axis] = offset
        centre[axis] = 0.02 * bowl_radius * (slot - 1.5)  # slightly staggered, so that pills roll
        mesh = capsule_mesh(radius, half_length, resolution, centre, axis=axis)
        bodies.append(ElasticBody(mesh, mats[i % 2], name=f"pill{i}", **body_kw))
    return _scene(Simulation(bodies, **sim_kw), "pills", frames)


def bowling(n=3, resolution=1, radius=0.15, heights=None, mattress=(2.0, 0.8, 0.25), frames=150, **kwargs):
    """``n`` stiff balls dropped from different ``heights`` onto a soft mattress lying on a plane.

    Higher drops elastify larger regions (paper Fig. 3). Defaults: balls Neo-Hookean
    E = 1e7, nu = 0.3, density 1500; mattress E = 2e4, nu = 0.3, density 200; h = 0.01,
    friction 0.5. ``ball_material`` and ``mattress_material`` override the materials.
    """
    sim_kw, body_kw = _contact_scene_kwargs(kwargs, 0.5, Plane())
    k = _resolution(resolution)
    n = _count(n)
    heights = np.linspace(0.1, 0.6, n) if heights is None else np.broadcast_to(np.asarray(heights, float), (n,))
    ball_mat = body_kw.pop("ball_material", NeoHookean(E=1e7, nu=0.3))
    mat_mat = body_kw.pop("mattress_material", NeoHookean(E=2e4, nu=0.3))
    L, W, T = mattress
    cells = (max(1, int(round(4 * k * L / W))), 4 * k, max(1, int(round(4 * k * T / W))))
    bed = ElasticBody(box_mesh((L, W, T), cells, (0.0, 0.0, T / 2)), mat_mat, density=200.0, name="mattress")
    xs = (np.arange(n) - (n - 1) / 2) * (L / max(n, 1))
    balls = [ElasticBody(ball_mesh(radius, k, (x, 0.0, T + radius + hgt)), ball_mat, density=1500.0,
                         name=f"ball{i}", **body_kw) for i, (x, hgt) in enumerate(zip(xs, heights))]
    return _scene(Simulation([bed] + balls, **sim_kw), "bowling", frames)


def toothbrush_mesh(resolution=1, cell=0.02, handle=(0.40, 0.08, 0.04), bristle_height=0.06, head_length=0.16):
    """A toothbrush as one conforming mesh: a handle slab with tufts of bristles under its head.

    The tensor grid (cells of ``cell / resolution``) covers handle and bristle layer; the
    bristle layer keeps only every other cell column under the head (tufts). Returns
    ``(mesh, is_bristle)``, the second a boolean per element.
    """
    k = _resolution(resolution)
    c = cell / k
    L, W, T = handle
    nx, ny = int(round(L / c)), int(round(W / c))
    nb, nt = int(round(bristle_height / c)), int(round(T / c))
    mesh = skfem.MeshTet.init_tensor(np.linspace(0, L, nx + 1), np.linspace(-W / 2, W / 2, ny + 1),
                                     np.linspace(0, bristle_height + T, nb + nt + 1))
    mid = mesh.p[:, mesh.t].mean(axis=1)
    ix, iy = np.floor(mid[0] / c).astype(int), np.floor((mid[1] + W / 2) / c).astype(int)
    tuft = (mid[0] > L - head_length) & (ix % (2 * k) < k) & (iy % (2 * k) < k)
    in_handle = mid[2] > bristle_height
    keep = np.flatnonzero(in_handle | tuft)
    sub = mesh.restrict(keep)
    return sub, ~in_handle[keep]


def toothbrush(resolution=1, speed=0.5, frames=150, **kwargs):
    """A toothbrush (stiff handle, soft bristles) pushed with ``speed`` (m/s) along -x, bristles on a plane.

    Paper Fig. 1 and Table 1 "Toothbrush". Defaults: handle Neo-Hookean E = 1e7, bristles
    E = 5e4 (nu = 0.38 both), density 1000, h = 0.01, friction 0.8; ``handle_material`` and
    ``bristle_material`` override the materials.
    """
    sim_kw, body_kw = _contact_scene_kwargs(kwargs, 0.8, Plane())
    mesh, bristle = toothbrush_mesh(resolution)
    hard = body_kw.pop("handle_material", NeoHookean(E=1e7, nu=0.38))
    soft = body_kw.pop("bristle_material", NeoHookean(E=5e4, nu=0.38))
    body_kw.setdefault("material", [soft if b else hard for b in bristle])
    body_kw.setdefault("density", 1000.0)
    body_kw.setdefault("velocity", (-float(speed), 0.0, 0.0))
    mesh = mesh.translated((0.0, 0.0, 1e-3))
    return _scene(Simulation(ElasticBody(mesh, name="toothbrush", **body_kw), **sim_kw), "toothbrush", frames)


SCENES = {"cantilever": cantilever, "free_body": free_body, "drop": drop, "stacked_beams": stacked_beams,
          "pills": pills, "bowling": bowling, "toothbrush": toothbrush}
