"""Procedural scenes: each returns a ready :class:`~skfem_affine.Simulation`.

Every scene takes keyword overrides (``material``, ``dt``, ``reducer``,
``damping``, ``solver``, ``colliders``, ``contact``, ...) that are passed on to the
body or simulation, and records its default number of frames in ``sim.frames``
and its name in ``sim.scene``.

Contact scenes (paper sec. 4): :func:`drop`, :func:`stacked_beams`, :func:`pills`,
:func:`bowling`, :func:`toothbrush`, :func:`wheel`, :func:`octopus`, :func:`armadillo`
(resource-limited). Their meshes are procedural scikit-fem meshes (``MeshTet.init_tensor``,
``init_ball``, mapped or restricted), so no mesher is needed; ``pills``, ``wheel``,
``octopus`` and ``armadillo`` also take ``mesh=``, a mesh file such as the paper's own.

The twisting beam (paper Fig. 9), :func:`twisting_beam`, turns one end progressively through
prescribed motion (:class:`~skfem_affine.Prescribed` along a :class:`TwistPath`);
:func:`twisting_beam_setup` gives its mesh, ends and path.
"""
import os

import numpy as np
import skfem

from skfem_affine.body import ElasticBody
from skfem_affine.checks import integer, real, real_array
from skfem_affine.contact.colliders import Bowl, Plane
from skfem_affine.contact.pgs import PGS
from skfem_affine.lab.io import load_mesh
from skfem_affine.lab.loads import Pull, vertex_volumes
from skfem_affine.motion import Prescribed
from skfem_affine.reducers.affine.affinification import Affinification
from skfem_affine.simulation import Rayleigh, Simulation
from skfem_affine.materials import MATERIALS, NeoHookean

SIM_KEYS = ("dt", "gravity", "damping", "reducer", "solver", "newton_iters", "newton_tol", "integrator",
            "project_hessian", "mass", "colliders", "contact", "on_inverted", "on_nonconvergence", "check_energy",
            "forces")


def _split(kwargs):
    sim = {k: kwargs.pop(k) for k in SIM_KEYS if k in kwargs}
    return sim, kwargs


def _material(material, E, nu):
    """``material`` itself, or the material of that name (``"neohookean"``, ``"stvk"``, ``"corotational"``) at E, nu."""
    if not isinstance(material, str):
        return material
    if material not in MATERIALS:
        raise ValueError(f"material must be one of {', '.join(MATERIALS)} or a Material, got {material!r}")
    return MATERIALS[material](E=E, nu=nu)


def _lengths(**values):
    """Each value (a number or an array of them) finite and > 0, or an error naming it; returns
    them in the order given (arrays as float arrays, numbers as floats)."""
    out = [real_array(v, name, low=0.0, include_low=False) for name, v in values.items()]
    out = [float(a) if a.ndim == 0 else a for a in out]
    return out[0] if len(out) == 1 else out


def _heights(**values):
    """Each value (a number or an array of them) finite and >= 0 (a gap, a height above the
    ground: a negative one starts the bodies inside it), or an error naming it."""
    out = [real_array(v, name, low=0.0) for name, v in values.items()]
    out = [float(a) if a.ndim == 0 else a for a in out]
    return out[0] if len(out) == 1 else out


def _vector(value, name):
    """A (3,) array from a number or 3 numbers (``box_mesh``'s size and cells)."""
    a = np.asarray(value)
    if a.shape not in ((), (3,)):
        raise ValueError(f"{name} must be a number or 3 numbers, got shape {a.shape}")
    return [value] * 3 if a.ndim == 0 else value


def beam_mesh(resolution, length=4.0, width=1.0):
    """A length x width x width box with ``resolution`` cells across: 24 k^3 tets (length 4)."""
    k = integer(resolution, "resolution", low=1)
    length, width = _lengths(length=length, width=width)
    nx = max(1, int(round(k * length / width)))
    return skfem.MeshTet.init_tensor(np.linspace(0, length, nx + 1), np.linspace(0, width, k + 1),
                                     np.linspace(0, width, k + 1))


def cantilever(resolution=6, length=4.0, width=1.0, frames=370, E=2e7, nu=0.35, density=1000.0,
               damping=Rayleigh(alpha=0.03, beta=0.02), **kwargs):
    """A beam pinned at x = 0 swinging down under gravity and vibrating (paper Fig. 17 / Table 1 "Beam").

    Defaults: a 4 x 1 x 1 m beam, Neo-Hookean E = 2e7 Pa (stiff rubber), nu = 0.35,
    density 1000 kg/m^3, the paper's Rayleigh damping (alpha = 0.03, beta = 0.02),
    h = 0.01 s, 370 frames. Euler-Bernoulli theory puts its static tip deflection
    at :func:`euler_bernoulli_tip_deflection` = 0.19 m (under 5 % of the length)
    and its first bending frequency at :func:`euler_bernoulli_frequency` = 1.4 Hz,
    so the beam swings down, overshoots and rings for a few periods in 370 frames.
    ``resolution=k`` gives 24 k^3 tets (k=6: 5184, about the paper's 5.5k).

    ``material`` (a Material, or a name built with ``E`` and ``nu``: ``"neohookean"``,
    ``"stvk"``, ``"corotational"``) overrides the Neo-Hookean default; ``damping`` is a Rayleigh, an
    ``(alpha, beta)`` pair (so that the command line's ``--set "damping=(0, 0)"``
    reaches it) or None (undamped). ``cantilever(E=1e5, damping=None)`` is a soft,
    rope-like variant (the tip sinks metres below the clamp: large deformation on purpose).
    """
    sim_kw, body_kw = _split(dict(kwargs))
    sim_kw.setdefault("dt", 0.01)
    sim_kw.setdefault("gravity", (0.0, 0.0, -9.81))
    sim_kw["damping"] = Rayleigh(*damping) if isinstance(damping, (tuple, list)) else damping
    mesh = beam_mesh(resolution, length, width)
    body_kw["material"] = _material(body_kw.get("material", "neohookean"), E, nu)
    body_kw["density"] = density
    body_kw.setdefault("fixed", mesh.nodes_satisfying(lambda p: p[0] < 1e-9 * length))
    sim = Simulation(ElasticBody(mesh, name="cantilever", **body_kw), **sim_kw)
    sim.frames = frames
    sim.scene = "cantilever"
    return sim


def paper_beam(mesh=None, resolution=2, length=6.854, width=2.0, material="neohookean", E=1e5, nu=0.35,
               density=100.0, damping=(0.03, 0.02), frames=370, **kwargs):
    """The paper's scaling beam (Table 1 "Beam", Table 2): long axis z, the z-min end pinned, gravity along -y.

    ``mesh`` is a mesh file (e.g. the paper's ``beam1264.mesh``, 5516 tets) or a skfem.MeshTet;
    without one, a procedural ``width`` x ``width`` x ``length`` box (the paper's beam is
    2 x 2 x 6.854) with ``resolution`` cells across (6 k^2 round(k length / width) tets), so
    that sizes past the paper's files can be reached. The paper's set-up: ``material`` a name
    (``"neohookean"``, ``"stvk"``, ``"corotational"``) built with ``E`` = 1e5 and ``nu`` = 0.35,
    or a Material; density 100; Rayleigh damping alpha = 0.03, beta = 0.02 (a pair or a
    Rayleigh); h = 0.01; gravity -9.8 along y, across the beam; 370 frames. The pinned
    vertices are those on the z-min face, and the elements touching them stay elastic.
    """
    sim_kw, body_kw = _split(dict(kwargs))
    sim_kw.setdefault("dt", 0.01)
    sim_kw.setdefault("gravity", (0.0, -9.8, 0.0))
    sim_kw["damping"] = Rayleigh(*damping) if isinstance(damping, (tuple, list)) else damping
    if mesh is None:
        k = integer(resolution, "resolution", low=1)
        length, width = _lengths(length=length, width=width)
        nz = max(1, int(round(k * length / width)))
        m = skfem.MeshTet.init_tensor(np.linspace(-width / 2, width / 2, k + 1),
                                      np.linspace(-width / 2, width / 2, k + 1), np.linspace(0.0, length, nz + 1))
    else:
        m = _mesh_from(mesh)
    material = _material(material, E, nu)
    z = m.p[2]
    body_kw.setdefault("fixed", np.flatnonzero(z < z.min() + 1e-6 * np.ptp(z)))
    body = ElasticBody(m, name="beam", material=material, density=density, **body_kw)
    return _scene(Simulation(body, **sim_kw), "paper_beam", frames)


def euler_bernoulli_tip_deflection(length=4.0, width=1.0, E=2e7, density=1000.0, g=9.81):
    r"""Static tip deflection of a square cantilever under its own weight (Euler-Bernoulli).

    .. math:: \delta = \frac{\rho g A L^4}{8 E I}, \qquad A = w^2,\ I = w^4 / 12.
    """
    area, inertia = width ** 2, width ** 4 / 12.0
    return density * g * area * length ** 4 / (8.0 * E * inertia)


def euler_bernoulli_frequency(length=4.0, width=1.0, E=2e7, density=1000.0):
    r"""First bending frequency (Hz) of a square cantilever (Euler-Bernoulli).

    .. math:: f_1 = \frac{1.8751^2}{2 \pi L^2} \sqrt{\frac{E I}{\rho A}}.
    """
    area, inertia = width ** 2, width ** 4 / 12.0
    return 1.8751 ** 2 / (2 * np.pi * length ** 2) * np.sqrt(E * inertia / (density * area))


def free_body(resolution=3, shape="cube", size=1.0, spin=(0.0, 0.0, 2.0), velocity=(0.5, 0.0, 0.0),
              frames=100, **kwargs):
    """A cube (or ball) flying without gravity, spinning about its centre of mass.

    ``spin`` is the angular velocity (rad/s), ``velocity`` the centre-of-mass velocity.
    """
    sim_kw, body_kw = _split(dict(kwargs))
    sim_kw.setdefault("dt", 0.01)
    k = integer(resolution, "resolution", low=1)
    size = _lengths(size=size)
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
    size = _lengths(size=_vector(size, "size"))
    center = real_array(center, "center", shape=(3,))
    cells = [integer(c, "cells", low=1) for c in _vector(cells, "cells")]
    axes = [np.linspace(c - s / 2, c + s / 2, n + 1) for c, s, n in zip(center, size, cells)]
    return skfem.MeshTet.init_tensor(*axes)


def ball_mesh(radius, resolution, center=(0.0, 0.0, 0.0)):
    """scikit-fem's ball, refined ``resolution`` times (8 * 8^k tets), scaled and moved."""
    radius = _lengths(radius=radius)
    return skfem.MeshTet.init_ball(nrefs=_resolution(resolution)).scaled(radius).translated(center)


def capsule_mesh(radius, half_length, resolution, center=(0.0, 0.0, 0.0), axis=0):
    """A capsule (segment of ``half_length`` along ``axis`` swept by a ball of ``radius``).

    A tensor box around the segment is mapped onto the capsule: each point q off
    the segment moves radially to ``q ||q||_inf / ||q||_2``, which sends the box's
    faces onto the capsule's cylinder and hemispherical caps.
    """
    k = _resolution(resolution)
    radius, half_length = _lengths(radius=radius), _heights(half_length=half_length)
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
    size, height = _lengths(size=size), _heights(height=height)
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
    length, width = _lengths(length=length, width=width)
    gap = _heights(gap=gap)
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
          materials=None, mesh=None, **kwargs):
    """``n`` capsules dropped into a bowl, alternating two materials (paper Table 1 "Pills").

    Pills lie in layers of four, each layer turned by 90 degrees, the lowest at the
    bowl's rim height. Defaults: Neo-Hookean (E = 2e4, nu = 0.34) and (E = 1e6,
    nu = 0.36), density 1000, h = 0.01, friction 0.3; ``materials`` overrides the pair.
    ``mesh`` (a skfem.MeshTet or a mesh file, e.g. the paper's ``Pill.mesh``) replaces the
    procedural capsule: its longest extent is laid along the pill's axis and scaled to
    ``2 (half_length + radius)``.
    """
    radius, half_length, bowl_radius = _lengths(radius=radius, half_length=half_length, bowl_radius=bowl_radius)
    bowl = Bowl(center=(0.0, 0.0, bowl_radius), radius=bowl_radius)
    sim_kw, body_kw = _contact_scene_kwargs(kwargs, 0.3, bowl)
    n = _count(n)
    mats = materials or (NeoHookean(E=2e4, nu=0.34), NeoHookean(E=1e6, nu=0.36))
    body_kw.setdefault("density", 1000.0)
    if "material" in body_kw:
        mats = (body_kw.pop("material"),) * 2
    spacing = 2 * radius + 0.025 * bowl_radius
    pill = None
    if mesh is not None:  # centred, its long axis along x, scaled to the capsule's length
        pill = _mesh_from(mesh)
        q = pill.p - 0.5 * (pill.p.max(axis=1) + pill.p.min(axis=1))[:, None]
        q = np.roll(q, -int(np.argmax(np.ptp(q, axis=1))), axis=0)
        pill = _rebuilt(pill, q * 2 * (half_length + radius) / np.ptp(q[0]))
    bodies = []
    for i in range(n):
        layer, slot = divmod(i, 4)
        offset = (slot - 1.5) * spacing
        axis = layer % 2
        centre = [0.0, 0.0, bowl_radius + layer * (2 * radius + 0.05 * bowl_radius)]
        centre[1 - axis] = offset
        centre[axis] = 0.02 * bowl_radius * (slot - 1.5)  # slightly staggered, so that pills roll
        if pill is None:
            m = capsule_mesh(radius, half_length, resolution, centre, axis=axis)
        else:
            m = _rebuilt(pill, np.roll(pill.p, axis, axis=0) + np.asarray(centre)[:, None])
        bodies.append(ElasticBody(m, mats[i % 2], name=f"pill{i}", **body_kw))
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
    radius, mattress = _lengths(radius=radius, mattress=real_array(mattress, "mattress", shape=(3,)))
    heights = np.linspace(0.1, 0.6, n) if heights is None else np.broadcast_to(_heights(heights=heights), (n,))
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
    cell, bristle_height, head_length = _lengths(cell=cell, bristle_height=bristle_height, head_length=head_length)
    c = cell / k
    L, W, T = _lengths(handle=real_array(handle, "handle", shape=(3,)))
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


# ---------------------------------------------------------------------------- meshes from files
def _mesh_from(mesh):
    """A skfem.MeshTet, given one or the path of a mesh file (MEDIT .mesh, ...; :func:`io.load_mesh`)."""
    if isinstance(mesh, skfem.Mesh):
        return mesh
    if isinstance(mesh, (str, os.PathLike)):
        if not os.path.isfile(mesh):
            raise ValueError(f"mesh file {os.fspath(mesh)!r} does not exist")
        return load_mesh(os.fspath(mesh))
    raise TypeError(f"mesh must be a skfem.MeshTet or the path of a mesh file, got {type(mesh).__name__}")


def _rebuilt(mesh, p):
    return skfem.MeshTet(np.ascontiguousarray(p), mesh.t, _subdomains=mesh.subdomains)


def _disc_map(q):
    """Map points of the square [-1, 1]^2 ((2, n)) onto the unit disc: q -> q ||q||_inf / ||q||_2."""
    r2 = np.linalg.norm(q, axis=0)
    return q * np.where(r2 > 0, np.abs(q).max(axis=0) / np.maximum(r2, 1e-300), 1.0)


# ---------------------------------------------------------------------------- wheel (paper Fig. 13)
def wheel_mesh(resolution=1, radius=0.4, width=0.16, hub_fraction=0.75):
    """A solid wheel (a disc of ``radius`` and ``width``, axle along y) and its hub elements.

    A tensor box over the square [-1, 1]^2 (x, z) x [-width/2, width/2] (y) is mapped
    onto the disc by q -> q ||q||_inf / ||q||_2, which sends square rings to circles
    (no degenerate element at the axle). ``resolution=k`` has 8 k cells across the
    diameter. Returns ``(mesh, is_hub)``: elements whose centroid lies within
    ``hub_fraction * radius`` of the axle.
    """
    k = _resolution(resolution)
    radius, width = _lengths(radius=radius, width=width)
    across = 8 * k
    thick = max(1, int(round(across * width / (2 * radius))))
    box = box_mesh((2.0, width, 2.0), (across, thick, across))
    p = box.p.copy()
    p[[0, 2]] = radius * _disc_map(p[[0, 2]])
    mesh = skfem.MeshTet(np.ascontiguousarray(p), box.t)
    return mesh, _hub(mesh, 1, hub_fraction)


def _hub(mesh, axle, hub_fraction):
    """Elements whose centroid is within ``hub_fraction`` of the largest distance to the axle."""
    if not 0.0 < float(hub_fraction) < 1.0:
        raise ValueError(f"hub_fraction must lie in (0, 1), got {hub_fraction}")
    off = [a for a in range(3) if a != axle]
    centre = 0.5 * (mesh.p.max(axis=1) + mesh.p.min(axis=1))
    q = mesh.p[off] - centre[off, None]
    radius = np.linalg.norm(q, axis=0).max()
    mid = q[:, mesh.t].mean(axis=1)
    return np.linalg.norm(mid, axis=0) < float(hub_fraction) * radius


def wheel(resolution=1, mesh=None, radius=None, width=0.16, hub_fraction=0.75, height=0.1, frames=300, **kwargs):
    """A two-material wheel (stiff hub, soft tyre) dropped onto a plane z = 0 (paper Fig. 13, Table 1 "Wheel").

    Procedural by default (:func:`wheel_mesh`), or ``mesh``: a skfem.MeshTet or a mesh file
    (e.g. the paper's ``wheelFatHD.mesh``). A file is turned so that its thinnest extent
    (the axle) lies along y and centred, and scaled to ``radius`` when given (the procedural
    wheel's default is 0.4 m, a file keeps its own units); its elements are split into hub and
    tyre by the centroid's distance to the axle (``hub_fraction`` of the outer radius),
    since the paper's files carry no material labels. The wheel starts ``height`` above
    the plane. Defaults: hub Neo-Hookean E = 1e8, nu = 0.34; tyre E = 1e6, nu = 0.4
    (the tyre's own weight squashes it by a few %); density 1000; h = 0.005 (as the
    paper), friction 0.5. ``hub_material`` and ``tyre_material`` override the materials
    (the paper's Table 1 lists E = 1.4e3 and 5e5, nu = 0.34 and 0.4); ``density`` is a
    number or a (hub, tyre) pair.
    """
    kwargs.setdefault("dt", 0.005)
    height = _heights(height=height)
    radius = None if radius is None else _lengths(radius=radius)
    sim_kw, body_kw = _contact_scene_kwargs(kwargs, 0.5, Plane())
    if mesh is None:
        m, hub = wheel_mesh(resolution, 0.4 if radius is None else radius, width, hub_fraction)
    else:
        m = _mesh_from(mesh)
        axle = int(np.argmin(np.ptp(m.p, axis=1)))
        p = np.roll(m.p, 1 - axle, axis=0)  # cyclic: the axle becomes y
        p = p - 0.5 * (p.max(axis=1) + p.min(axis=1))[:, None]
        if radius is not None:
            p *= radius / np.linalg.norm(p[[0, 2]], axis=0).max()
        m = _rebuilt(m, p)
        hub = _hub(m, 1, hub_fraction)
    m = m.translated((0.0, 0.0, height - m.p[2].min()))
    hard = body_kw.pop("hub_material", NeoHookean(E=1e8, nu=0.34))
    soft = body_kw.pop("tyre_material", NeoHookean(E=1e6, nu=0.4))
    body_kw.setdefault("material", [hard if h else soft for h in hub])
    density = body_kw.pop("density", 1000.0)
    if isinstance(density, (tuple, list)) and len(density) == 2:
        density = np.where(hub, float(density[0]), float(density[1]))
    body_kw["density"] = density
    return _scene(Simulation(ElasticBody(m, name="wheel", **body_kw), **sim_kw), "wheel", frames)


# ---------------------------------------------------------------------------- octopus (paper Fig. 11)
def octopus_mesh(resolution=1, cell=0.05, head=(0.2, 0.2, 0.2), arm_length=0.15, arm_width=0.05):
    """A head (box) on four flat arms along +-x and +-y, one conforming tet mesh.

    A tensor grid of cells ``cell / resolution`` keeps the head's cells and the bottom
    layer (``arm_width`` thick) of the arms. Returns the mesh; z = 0 is its bottom.
    """
    k = _resolution(resolution)
    cell, arm_length, arm_width = _lengths(cell=cell, arm_length=arm_length, arm_width=arm_width)
    c = cell / k
    hx, hy, hz = _lengths(head=real_array(head, "head", shape=(3,)))
    reach = max(hx, hy) / 2 + arm_length
    n = int(round(2 * reach / c))
    axis = np.linspace(-reach, reach, n + 1)
    mesh = skfem.MeshTet.init_tensor(axis, axis, np.linspace(0.0, hz, int(round(hz / c)) + 1))
    x, y, z = mesh.p[:, mesh.t].mean(axis=1)
    in_head = (np.abs(x) < hx / 2) & (np.abs(y) < hy / 2)
    a = arm_width / 2
    in_arm = (z < arm_width) & (((np.abs(y) < a) & (np.abs(x) < reach)) | ((np.abs(x) < a) & (np.abs(y) < reach)))
    return mesh.restrict(np.flatnonzero(in_head | in_arm))


def tentacle_tip(mesh, fraction=0.2):
    """Vertices near the one farthest from the vertical axis through the centre (a tentacle's tip).

    ``fraction`` of the mesh's horizontal extent is the radius of the tip region.
    """
    p = mesh.p
    centre = 0.5 * (p.max(axis=1) + p.min(axis=1))
    d = np.linalg.norm(p[:2] - centre[:2, None], axis=0)
    tip = int(np.argmax(d))
    span = np.ptp(p[:2], axis=1).max()
    return np.flatnonzero(np.linalg.norm(p - p[:, [tip]], axis=0) <= fraction * span)


def octopus(resolution=1, mesh=None, height=0.25, bowl_radius=0.5, size=None, up=2, pull="tentacle", tug=0.25,
            frames=300, **kwargs):
    """A soft octopus dropped into a bowl, one tentacle tugged mid-run (paper Fig. 11, Table 1 "Octopus").

    Procedural by default (:func:`octopus_mesh`: a head on four arms, about 0.5 m across),
    or ``mesh``: a skfem.MeshTet or a mesh file (e.g. the paper's ``octopus.mesh``, in its
    own units; ``up`` names its upward axis, 1 for the paper's), its longest horizontal
    extent scaled to ``size`` when given. The body starts with its bottom ``height``
    above the bowl's lowest point. ``pull``: "tentacle"
    (default) tugs the tip of one tentacle (:func:`tentacle_tip`) up and outwards with
    ``tug`` times the body's weight from 40 % to 55 % of the run; a
    :class:`~skfem_affine.lab.loads.Pull` of your own; or None. The tug is a
    :class:`~skfem_affine.VertexForce` of the simulation (``forces=``). Defaults:
    Neo-Hookean E = 5e4, nu = 0.34, density 1000, h = 0.01, friction 0.3 (the paper
    lists E = 4e3, nu = 0.34).
    """
    height, bowl_radius = _heights(height=height), _lengths(bowl_radius=bowl_radius)
    size = None if size is None else _lengths(size=size)
    bowl = Bowl(center=(0.0, 0.0, bowl_radius), radius=bowl_radius)
    sim_kw, body_kw = _contact_scene_kwargs(kwargs, 0.3, bowl)
    if mesh is None:
        m = octopus_mesh(resolution)
    else:
        m = _mesh_from(mesh)
        if up not in (0, 1, 2):
            raise ValueError(f"up must be the axis 0, 1 or 2 of the mesh that points up, got {up!r}")
        m = _rebuilt(m, np.roll(m.p, 2 - up, axis=0))  # cyclic: keeps the elements' orientation
    p = m.p - np.array([*(0.5 * (m.p[:2].max(axis=1) + m.p[:2].min(axis=1))), m.p[2].min()])[:, None]
    if size is not None:
        p *= float(size) / np.ptp(p[:2], axis=1).max()
    m = _rebuilt(m, p + np.array([0.0, 0.0, height])[:, None])
    body_kw.setdefault("material", NeoHookean(E=5e4, nu=0.34))
    body_kw.setdefault("density", 1000.0)
    density = np.broadcast_to(np.asarray(body_kw["density"], dtype=float), (m.t.shape[1],))
    masses = vertex_volumes(m, density)  # the vertices' lumped masses
    if isinstance(pull, str):
        if pull != "tentacle":
            raise ValueError(f"pull must be 'tentacle', a Pull or None, got {pull!r}")
        tip = tentacle_tip(m)
        out = m.p[:2, tip].mean(axis=1) - 0.5 * (m.p[:2].max(axis=1) + m.p[:2].min(axis=1))
        direction = np.array([*(out / max(np.linalg.norm(out), 1e-300)), 2.0]) / np.sqrt(5.0)
        weight = float(masses.sum()) * float(np.linalg.norm(sim_kw.get("gravity", (0.0, 0.0, -9.81))))
        T = frames * sim_kw.get("dt", 0.01)
        pull = Pull(tip, float(tug) * weight * direction, 0.4 * T, 0.55 * T, weights=masses[tip])
    if pull is not None:
        if not isinstance(pull, Pull):
            raise TypeError(f"pull must be 'tentacle', a Pull or None, got {type(pull).__name__}")
        sim_kw["forces"] = list(sim_kw.get("forces") or []) + [pull.vertex_force()]
    return _scene(Simulation(ElasticBody(m, name="octopus", **body_kw), **sim_kw), "octopus", frames)


# ---------------------------------------------------------------------------- resource-limited (Fig. 16)
def blob_mesh(resolution=2, radius=0.3, bumps=0.25):
    """A closed, lumpy body: scikit-fem's ball with its radius modulated by smooth bumps.

    Each point moves radially by the factor ``1 + bumps * s(direction)`` (s in [-1, 1]
    built from low-order spherical harmonics, so the surface has head-, leg- and
    tail-like lobes); centred at the origin.
    """
    radius = _lengths(radius=radius)
    bumps = real(bumps, "bumps", low=0.0, high=1.0, include_high=False)  # 1: the surface reaches the centre
    ball = skfem.MeshTet.init_ball(nrefs=_resolution(resolution))
    p = ball.p
    r = np.linalg.norm(p, axis=0)
    u = p / np.maximum(r, 1e-300)
    s = 0.6 * u[0] * u[1] + 0.8 * (u[2] ** 2 - 1.0 / 3.0) + 0.5 * u[0] * (u[0] ** 2 - 3 * u[1] ** 2)
    s /= np.abs(s).max()
    return skfem.MeshTet(np.ascontiguousarray(radius * p * (1.0 + bumps * s)), ball.t)


def armadillo(resolution=2, mesh=None, size=0.6, speed=3.0, min_fraction=1 / 3, frames=300, **kwargs):
    """A resource-limited run: a closed soft body thrown onto a plane (paper Fig. 16 "Armadillo").

    Every element deforms on impact, and the reducer must still keep at least
    ``min_fraction`` of the elements affine (resource limiting, sec. 3.5: the
    paper keeps a third). Procedural by default (:func:`blob_mesh`, a lumpy closed body)
    or ``mesh``: a skfem.MeshTet or a mesh file, scaled to ``size`` (largest extent).
    Unless ``reducer`` is given, the simulation uses
    ``Affinification(tau_a=4e-13, tau_e=6e-12, min_fraction=min_fraction)``,
    the paper's near-zero thresholds, so only the resource limit makes bodies affine;
    a reducer passed in keeps its own settings. The body starts just above the plane
    moving down at ``speed`` (m/s). Defaults: Neo-Hookean E = 5e4, nu = 0.35, density
    1000, h = 0.005 (as the paper), friction 0.5 (the paper lists E = 1.2e2).
    """
    kwargs.setdefault("dt", 0.005)
    size, speed = _lengths(size=size), _heights(speed=speed)
    sim_kw, body_kw = _contact_scene_kwargs(kwargs, 0.5, Plane())
    if "reducer" not in sim_kw:
        sim_kw["reducer"] = Affinification(tau_a=4e-13, tau_e=6e-12, min_fraction=min_fraction)
    m = blob_mesh(resolution) if mesh is None else _mesh_from(mesh)
    p = m.p - 0.5 * (m.p.max(axis=1) + m.p.min(axis=1))[:, None]
    p *= float(size) / np.ptp(p, axis=1).max()
    p[2] += 0.02 * size - p[2].min()
    m = _rebuilt(m, p)
    body_kw.setdefault("material", NeoHookean(E=5e4, nu=0.35))
    body_kw.setdefault("density", 1000.0)
    body_kw.setdefault("velocity", (0.0, 0.0, -float(speed)))
    return _scene(Simulation(ElasticBody(m, name="armadillo", **body_kw), **sim_kw), "armadillo", frames)


# ---------------------------------------------------------------------------- twisting beam (Fig. 9)
class TwistPath:
    """Positions of clamped vertices turned progressively about an axis (paper Fig. 9).

    ``path(t)`` rotates the ``rest`` positions (k, 3) about the line through ``center``
    along ``axis`` by the angle ``rate * t`` (rad); ``path.velocity(t)`` is its time
    derivative. The twisting beam holds one end fixed and moves the other along this
    path, which needs prescribed motion in the frame path.
    """

    def __init__(self, rest, center, axis=(1.0, 0.0, 0.0), rate=np.pi / 4):
        self.rest = np.array(rest, dtype=float)
        if self.rest.ndim != 2 or self.rest.shape[1] != 3:
            raise ValueError(f"rest positions must have shape (k, 3), got {self.rest.shape}")
        self.center = np.asarray(center, dtype=float)
        a = np.asarray(axis, dtype=float)
        if self.center.shape != (3,) or a.shape != (3,) or not np.linalg.norm(a) > 0:
            raise ValueError("center must be a 3-vector and axis a non-zero 3-vector")
        self.axis = a / np.linalg.norm(a)
        self.rate = float(rate)

    def angle(self, t):
        return self.rate * float(t)

    def rotation(self, t):
        """The rotation matrix at time t (Rodrigues' formula)."""
        th, k = self.angle(t), self.axis
        K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
        return np.eye(3) + np.sin(th) * K + (1.0 - np.cos(th)) * (K @ K)

    def __call__(self, t, X=None):
        """Positions at time t of the ``rest`` positions, or of X (k, 3) if given: the
        ``path(t, X)`` of :class:`~skfem_affine.Prescribed`."""
        X = self.rest if X is None else np.asarray(X, dtype=float)
        return self.center + (X - self.center) @ self.rotation(t).T

    def velocity(self, t):
        """d path / dt = rate * axis x (x(t) - center)."""
        return self.rate * np.cross(self.axis, self(t) - self.center)


def twisting_beam_setup(resolution=2, length=4.0, width=1.0, rate=np.pi / 4):
    """The twisting beam's mesh, its two clamped ends and the path of the turned one.

    Returns ``(mesh, fixed_end, turned_end, path)``: vertex indices of the end held at
    x = 0, of the end at x = ``length`` turned about the beam's axis, and the
    :class:`TwistPath` of the latter (the scene: :func:`twisting_beam`).
    """
    mesh = beam_mesh(resolution, length, width)
    x = mesh.p[0]
    fixed_end = np.flatnonzero(x < 1e-9 * length)
    turned_end = np.flatnonzero(x > length * (1 - 1e-9))
    path = TwistPath(mesh.p[:, turned_end].T, (length, width / 2, width / 2), (1.0, 0.0, 0.0), rate)
    return mesh, fixed_end, turned_end, path


def twisting_beam(resolution=2, length=4.0, width=1.0, rate=np.pi / 4, frames=1350, E=5e3, nu=0.38,
                  density=100.0, damping=Rayleigh(alpha=0.03, beta=0.02), **kwargs):
    """A beam held at x = 0 whose other end turns progressively about the beam's axis (paper Fig. 9).

    The turned end is :class:`~skfem_affine.Prescribed` along a :class:`TwistPath` at ``rate``
    rad/s (default a quarter turn every 2 s), so it follows the rotation exactly while the beam
    twists. Defaults: the paper's Table 1 row (Neo-Hookean E = 5e3 Pa, nu = 0.38, h = 0.01 s,
    1350 frames; its affinification thresholds are ``sa.Affinification(1.1e-3, 1e-3)``), density
    100 kg/m^3 and the paper's Rayleigh damping (0.03, 0.02), no gravity (the twist alone). ``resolution=k`` gives 24 k^3 tets; the paper's 642k tets are
    beyond this machine. ``material`` overrides ``E`` and ``nu``.
    """
    sim_kw, body_kw = _split(dict(kwargs))
    sim_kw.setdefault("dt", 0.01)
    sim_kw["damping"] = Rayleigh(*damping) if isinstance(damping, (tuple, list)) else damping
    mesh, fixed_end, turned_end, path = twisting_beam_setup(resolution, length, width, rate)
    body_kw.setdefault("material", NeoHookean(E=E, nu=nu))
    body_kw["density"] = density
    body_kw.setdefault("fixed", fixed_end)
    body_kw.setdefault("prescribed", Prescribed(turned_end, path))
    sim = Simulation(ElasticBody(mesh, name="twisting_beam", **body_kw), **sim_kw)
    sim.path = path
    return _scene(sim, "twisting_beam", frames)


#: The ready-made scenes by name (what ``skfem-affine scenes`` lists): name -> factory.
SCENES = {"cantilever": cantilever, "paper_beam": paper_beam, "free_body": free_body, "drop": drop, "stacked_beams": stacked_beams,
          "pills": pills, "bowling": bowling, "toothbrush": toothbrush, "wheel": wheel, "octopus": octopus,
          "armadillo": armadillo, "twisting_beam": twisting_beam}
