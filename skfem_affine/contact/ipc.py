r"""IPC contact for the Newton integrators, from ipctk (Li et al. 2020; the IPC Toolkit).

The contact potential added to the incremental potential (paper eq. 2) is

.. math:: C(x) = B(x) + D(x),

* :math:`B` the **barrier** over every primitive pair of the boundary surface closer than
  :math:`\hat d` (point-triangle, edge-edge, and their degenerate cases, between bodies and
  within a body) and over surface vertices against static colliders. ipctk's physical barrier
  is :math:`\kappa\, b(d^2, \hat d^2) / \hat d^3` with :math:`b(s, \hat s) = -(s - \hat s)^2 \ln(s/\hat s)`,
  so that :math:`\kappa` is a force (N).
* :math:`D` the **lagged smoothed friction** potential: normal forces, tangent bases and the
  contact set are frozen at the start of the step (:meth:`IPCContact.begin_step`), and
  :math:`D(x) = c h\,\sum_k \mu \lambda_k f_0(\|T_k^T v\|)` with the step's velocity
  :math:`v = (x - \hat x)/(c h)` (implicit Euler: :math:`\hat x = x_t`, :math:`c = 1`), so that
  :math:`\nabla_x D` is the Coulomb force :math:`\mu\lambda_k` in the sliding regime
  (:math:`\|T^T v\| \ge \epsilon_v`) and a stiff spring below :math:`\epsilon_v`.

The line search's largest step (:meth:`IPCContact.max_step`) is ipctk's continuous collision
detection (``compute_collision_free_stepsize``): every trial state of the Newton loop, and so every
time step, stays intersection-free, whatever the speed and the time step.

Static colliders (decision): every collider enters through its signed distance, as in
:mod:`~skfem_affine.contact.barrier`: the same physical barrier on each surface vertex's distance,
the same lagged friction against the collider's tangent plane at the vertex, and a vertex CCD:

* :class:`~skfem_affine.contact.colliders.Plane`: the exact time of impact of each vertex. A plane
  bounds a convex half-space, so vertices above it keep every edge and face above it: the
  guarantee is complete.
* any other collider (``Sphere``, ``Box``, ``Capsule``, ``Bowl``, ``SDFCollider``): conservative
  advancement on the signed distance (exact for a true distance, conservative for a lower
  bound). Only vertices are kept outside: a body edge can cut a convex corner or a sphere's cap
  between two vertices. Use planes where that matters.

ipctk's own planes (``CollisionMesh.planes``) are not used: ipctk 1.6 builds a plane-vertex
collision only within dhat/2 of the plane while its barrier acts up to dhat, so the energy jumps
at dhat/2 and a Newton line search stalls there (checked in ``tests/test_ipc.py``).

The collision mesh is the boundary surface of every body
(:func:`~skfem_affine.contact.geometry.boundary_surface`); fixed vertices take part in the geometry
but their DOFs are dropped from gradients and Hessians. Because contact couples vertices that are
not mesh neighbours, :meth:`IPCContact.hessian` is a sparse matrix on the free DOFs, to be added
to the elastic Hessian: ``A = pattern.matrix(data) + weight * contact.hessian(x)``.
"""
import functools
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from skfem_affine._extras import Optional
from skfem_affine.checks import choice, flag, integer, nonnegative, positive, real
from skfem_affine.contact.barrier import stiffness_force
from skfem_affine.contact.colliders import Plane, check_colliders
from skfem_affine.contact.geometry import boundary_surface
from skfem_affine.threads import ipctk_threads

ipctk = Optional("ipctk", "sa.IPC (the Newton integrators' contact, their default with several bodies)", "ipc")


@dataclass(frozen=True)
class IPC:
    """Settings of the IPC contact model for the Newton integrators.

    Parameters
    ----------
    dhat : float, optional
        Barrier activation distance (m); default 1e-3 of the scene size (bounding-box diagonal).
    kappa : float, optional
        Barrier stiffness (N, ipctk's physical barrier); default ``100 m_avg a``
        (:func:`~skfem_affine.contact.barrier.stiffness_force`) with m_avg the mean vertex mass and
        a the scene's gravity magnitude (``dhat / dt^2`` without gravity): the force of a vertex at
        half of ``dhat`` is about 430 times its weight.
    friction : float
        Coulomb coefficient mu >= 0 (the same spelling as ``sa.PGS(friction=...)``).
    epsv : float, optional
        Friction smoothing velocity (m/s): below it friction is a stiff spring (static
        friction creeps at most at about ``epsv``); default 1e-3 of the scene size per second.
    self_contact : bool
        Contact between non-adjacent surface primitives of the same body (of the same
        connected surface component).
    body_contact : bool
        Contact between different bodies (different connected surface components).
    ccd : {"additive", "tight_inclusion"}
        ipctk's narrow-phase CCD between surfaces: additive CCD (Li et al. 2021, conservative
        advancement on the distance; fast on parallel faces, the common case of stacked and
        resting bodies) or Tight-Inclusion (Wang et al. 2021, interval root finding; can take
        seconds per query on parallel faces approaching each other).
    ccd_tolerance : float
        Tight-Inclusion CCD tolerance (relative time of impact).
    ccd_max_iterations : int
        CCD iteration cap (a capped query returns a conservative step).
    ccd_rescaling : float
        Fraction in (0, 1] of the time of impact taken as the largest step (ipctk's
        conservative rescaling; the remaining gap keeps the barrier finite).
    """

    dhat: float = None
    kappa: float = None
    friction: float = 0.0
    epsv: float = None
    self_contact: bool = True
    body_contact: bool = True
    ccd: str = "additive"
    ccd_tolerance: float = 1e-6
    ccd_max_iterations: int = 1_000_000
    ccd_rescaling: float = 0.9

    def __post_init__(self):
        put = object.__setattr__  # frozen: store the checked values
        for name in ("dhat", "kappa", "epsv"):
            if getattr(self, name) is not None:
                put(self, name, positive(getattr(self, name), f"IPC {name}"))
        put(self, "friction", nonnegative(self.friction, "IPC friction"))
        put(self, "ccd_tolerance", positive(self.ccd_tolerance, "IPC ccd_tolerance"))
        put(self, "ccd_rescaling", real(self.ccd_rescaling, "IPC ccd_rescaling", low=0.0, high=1.0, include_low=False))
        put(self, "ccd_max_iterations", integer(self.ccd_max_iterations, "IPC ccd_max_iterations", low=1))
        put(self, "ccd", choice(self.ccd, "IPC ccd", ("additive", "tight_inclusion")))
        for name in ("self_contact", "body_contact"):
            put(self, name, flag(getattr(self, name), f"IPC {name}"))


# ---------------------------------------------------------------------------- scalar functions
def physical_barrier(d, dhat, kappa):
    r"""ipctk's physical barrier :math:`\kappa b(d^2, \hat d^2)/\hat d^3` and its first two d-derivatives.

    Elementwise; inf for d <= 0, zero for d >= dhat.
    """
    d = np.asarray(d, float)
    e, e1, e2 = np.zeros_like(d), np.zeros_like(d), np.zeros_like(d)
    act = (d > 0) & (d < dhat)
    s, sh = d[act] ** 2, dhat * dhat
    lg = np.log(s / sh)
    b = -(s - sh) ** 2 * lg
    b1 = -2.0 * (s - sh) * lg - (s - sh) ** 2 / s                      # db/ds
    b2 = -2.0 * lg - 4.0 * (s - sh) / s + (s - sh) ** 2 / s ** 2       # d2b/ds2
    k = kappa / dhat ** 3
    e[act] = k * b
    e1[act] = k * 2.0 * d[act] * b1
    e2[act] = k * (4.0 * s * b2 + 2.0 * b1)
    e[d <= 0] = np.inf
    return e, e1, e2


def smooth_friction(y, epsv):
    r"""IPC's mollified friction :math:`f_0(y)`, :math:`f_1(y)/y` and :math:`f_2(y)` (y >= 0).

    :math:`f_1(y) = 2y/\epsilon - y^2/\epsilon^2` for :math:`y < \epsilon`, 1 beyond;
    :math:`f_0' = f_1`, :math:`f_0(0) = \epsilon/3`, :math:`f_2 = f_1'`.
    """
    y = np.asarray(y, float)
    inner = y < epsv
    f0 = np.where(inner, -y ** 3 / (3 * epsv ** 2) + y ** 2 / epsv + epsv / 3, y)
    f1_over_y = np.where(inner, 2.0 / epsv - y / epsv ** 2, 1.0 / np.maximum(y, epsv))
    f2 = np.where(inner, 2.0 / epsv - 2.0 * y / epsv ** 2, 0.0)
    return f0, f1_over_y, f2


# ---------------------------------------------------------------------------- the contact model
def _package_threads(method):
    """``method`` with ipctk on the package's thread count (:func:`skfem_affine.threads.ipctk_threads`),
    so that its sums come out the same on every run."""
    @functools.wraps(method)
    def wrapped(*args, **kwargs):
        with ipctk_threads():
            return method(*args, **kwargs)
    return wrapped


class IPCContact:
    """IPC contact of one model: barrier, lagged friction and CCD on the free DOFs.

    Parameters
    ----------
    model : Simulation, object with ``system``, ``dt``, ``size`` and ``gravity``, or ElasticSystem
        ``system`` is the :class:`~skfem_affine.assembly.ElasticSystem`; given the system
        itself, pass ``dt``; the size is then its bounding-box diagonal, and the default barrier
        stiffness the one of a scene without gravity.
    colliders : list of colliders
        Static obstacles (``query(points) -> (distance, normal)``), through their signed distances.
    settings : IPC, optional
    x0 : array (n, 3) or (3n,), optional
        The start state checked for intersections (default the rest positions).
    dt : float, optional
        The time step, when ``model`` has none.

    Raises
    ------
    ValueError
        When the start state intersects or touches (a gap <= 0 anywhere): IPC needs an
        intersection-free start.
    """

    @_package_threads
    def __init__(self, model, colliders=(), settings=None, x0=None, dt=None):
        settings = IPC() if settings is None else settings
        if not isinstance(settings, IPC):
            raise TypeError(f"settings must be sa.IPC(...), got {type(settings).__name__}")
        sysm = getattr(model, "system", model)
        if not (hasattr(sysm, "pattern") and hasattr(sysm, "bodies")):
            raise TypeError(f"model must be a Simulation (or have .system) or an ElasticSystem, "
                            f"got {type(model).__name__}")
        dt = getattr(model, "dt", None) if dt is None else dt
        if dt is None or not (np.isscalar(dt) and np.isfinite(dt) and dt > 0):
            raise ValueError(f"IPC contact needs the time step: dt must be a finite number > 0, got {dt!r}")
        self.settings, self.system, self.h = settings, sysm, float(dt)
        size = getattr(model, "size", None)
        self.size = float(np.linalg.norm(np.ptp(sysm.p0, axis=0)) if size is None else size)
        self.colliders = check_colliders(colliders)
        self.dhat = 1e-3 * self.size if settings.dhat is None else settings.dhat
        self.kappa = (stiffness_force(sysm, getattr(model, "gravity", None), self.dhat, self.h)
                      if settings.kappa is None else settings.kappa)
        self.mu = settings.friction
        self.epsv = 1e-3 * self.size if settings.epsv is None else settings.epsv

        # collision mesh: boundary surface of every body, on its own vertex numbering
        tris, _ = boundary_surface(sysm)
        self.surface = np.unique(tris)                                   # global vertex ids
        local = np.full(sysm.n, -1, dtype=np.int64)
        local[self.surface] = np.arange(self.surface.size)
        faces = local[tris].astype(np.int32)
        edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
        edges = np.unique(edges, axis=0).astype(np.int32)
        if not (settings.self_contact or settings.body_contact):
            faces, edges = np.zeros((0, 3), np.int32), np.zeros((0, 2), np.int32)  # colliders only
        rest = np.asfortranarray(sysm.p0[self.surface])
        self.mesh = ipctk.CollisionMesh(rest, np.asfortranarray(edges), np.asfortranarray(faces))
        # "body" is a connected component of the surface (ipctk's compiled filter; a Python
        # filter takes the GIL in ipctk's parallel broad phase)
        if settings.body_contact != settings.self_contact:
            within = ipctk.make_connected_components_filter(np.asfortranarray(faces))
            self.mesh.can_collide = within if settings.body_contact else ~within
        self.barrier = ipctk.BarrierPotential(self.dhat, self.kappa, True)
        self.friction = ipctk.FrictionPotential(self.epsv)
        if settings.ccd == "additive":
            self.ccd = ipctk.AdditiveCCD(int(settings.ccd_max_iterations), settings.ccd_rescaling)
        else:
            self.ccd = ipctk.TightInclusionCCD(settings.ccd_tolerance, int(settings.ccd_max_iterations),
                                               settings.ccd_rescaling)

        # collision-mesh DOF -> free DOF (-1: fixed)
        dof_map = np.full(3 * sysm.n, -1, dtype=np.int64)
        dof_map[sysm.free] = np.arange(sysm.free.size)
        cdofs = dof_map[(3 * self.surface[:, None] + np.arange(3)).ravel()]
        keep = np.flatnonzero(cdofs >= 0)
        self.cdofs = cdofs
        self._pattern_keys = None  # sorted row * nfree + col of the free-DOF pattern
        self.nfree = sysm.free.size
        self.select = sp.csr_matrix((np.ones(keep.size), (cdofs[keep], keep)),
                                    shape=(self.nfree, 3 * self.surface.size))  # free <- collision DOFs
        self._cache = (None, None)
        self.lagged = None   # (x_hat, c, tangential collisions, sdf friction data) of the current step
        self.check_start(sysm.p0.reshape(-1) if x0 is None else np.asarray(x0, float).reshape(-1))

    # ------------------------------------------------------------------ geometry
    def vertices(self, x):
        """Collision-mesh vertex positions (V, 3) of the flat state x."""
        return np.asfortranarray(x.reshape(-1, 3)[self.surface])

    @_package_threads
    def _collisions(self, x):
        """ipctk's normal collisions at x (cached for the last x)."""
        cx, cc = self._cache
        if cx is not None and np.array_equal(cx, x):
            return cc
        cc = ipctk.NormalCollisions()
        if self.mesh.num_faces:
            cc.build(self.mesh, self.vertices(x), self.dhat)
        self._cache = (x.copy(), cc)
        return cc

    def _sdf(self, V):
        for c in self.colliders:
            d, nrm = c.query(V)
            yield np.asarray(d, float), np.asarray(nrm, float)

    @_package_threads
    def gaps(self, x):
        """Smallest gaps: surface to surface (inf beyond dhat) and to each collider (by index)."""
        V = self.vertices(x)
        out = {}
        if self.mesh.num_faces:
            cc = self._collisions(x)  # the pairs within dhat (farther ones are no concern)
            out["surface"] = cc.compute_minimum_distance(self.mesh, V) if len(cc) else np.inf
        for i, (d, _) in enumerate(self._sdf(V)):
            out[f"collider {i}"] = float(d.min())
        return out

    @_package_threads
    def check_start(self, x):
        """Raise ValueError unless x is intersection-free with every gap > 0 (IPC's precondition)."""
        V = self.vertices(x)
        if self.mesh.num_faces and ipctk.has_intersections(self.mesh, V):
            raise ValueError("IPC contact needs an intersection-free start: the bodies' surfaces intersect")
        bad = {k: g for k, g in self.gaps(x).items() if not g > 0}
        if bad:
            raise ValueError(f"IPC contact needs an intersection-free start with positive gaps, got gap "
                             f"{', '.join(f'{g:.3g} to {k}' for k, g in bad.items())}; move the bodies apart "
                             f"(at least dhat = {self.dhat:.3g} is a good start)")

    # ------------------------------------------------------------------ lagged friction
    @_package_threads
    def begin_step(self, x_t, x_hat=None, c=1.0):
        """Freeze the friction of the step starting at x_t (flat (3n,)).

        ``x_hat`` and ``c`` are the scheme's velocity form ``v = (x - x_hat)/(c h)``
        (implicit Euler: x_hat = x_t, c = 1; BDF2: the potential's ``x_hat`` and c = 2/3).
        """
        x_t = np.asarray(x_t, float).reshape(-1)
        x_hat = x_t.copy() if x_hat is None else np.asarray(x_hat, float).reshape(-1)
        if self.mu == 0:
            self.lagged = None
            return
        V = self.vertices(x_t)
        tc = ipctk.TangentialCollisions()
        tc.build(self.mesh, V, self._collisions(x_t), self.barrier, self.mu)
        sdf = []
        for d, nrm in self._sdf(V):
            _, e1, _ = physical_barrier(d, self.dhat, self.kappa)
            act = np.flatnonzero(e1 < 0)
            sdf.append((act, -e1[act], nrm[act]))              # vertex, normal force, lagged normal
        self.lagged = (x_hat, float(c), tc, sdf)

    def normal_force(self):
        """The total lagged normal force (N) of the current step's friction (0 without friction)."""
        if self.lagged is None:
            return 0.0
        tc = self.lagged[2]
        total = float(sum(tc[i].normal_force_magnitude for i in range(len(tc))))
        return total + float(sum(lam.sum() for _, lam, _ in self.lagged[3]))

    def relag(self, x):
        r"""Freeze the step's friction again, at its solution x (flat (3n,)) instead of x_t.

        Returns the relative change of the total normal force,
        :math:`|\lambda(x) - \lambda(x_t)| / \max(\lambda(x), \lambda(x_t))` (0 without friction). The normal force at x_t is not the step's when it starts away
        from equilibrium (inside dhat, or at an impact): a body started 2e-4 m above a plane is
        pushed by many times its weight there, and friction lagged at that force stops it far too
        soon. :class:`~skfem_affine.integrators.newton_integrator.NewtonIntegrator` re-solves the
        step while this change is large (IPC's lagged friction iterations).
        """
        if self.lagged is None:
            return 0.0
        before = self.normal_force()
        x_hat, c = self.lagged[:2]
        self.begin_step(x, x_hat, c)
        after = self.normal_force()
        top = max(before, after)
        return abs(after - before) / top if top > 0 else 0.0

    def _velocities(self, x):
        x_hat, c = self.lagged[:2]
        return np.asfortranarray(((x - x_hat) / (c * self.h)).reshape(-1, 3)[self.surface])

    def _sdf_friction(self, U):
        """Per collider: active vertices, mu lambda, tangential velocity u, its norm, lagged normal."""
        for act, lam, nrm in self.lagged[3]:
            u = U[act] - np.einsum("ij,ij->i", U[act], nrm)[:, None] * nrm
            yield act, self.mu * lam, u, np.linalg.norm(u, axis=1), nrm

    # ------------------------------------------------------------------ potential
    @_package_threads
    def energy(self, x):
        """Barrier plus friction energy C(x); inf at a zero gap (and inside a collider)."""
        V = self.vertices(x)
        e = float(self.barrier(self._collisions(x), self.mesh, V))
        for d, _ in self._sdf(V):
            e += float(physical_barrier(d, self.dhat, self.kappa)[0].sum())
        if self.lagged is not None:
            c = self.lagged[1]
            U = self._velocities(x)
            e += c * self.h * float(self.friction(self.lagged[2], self.mesh, U))
            for _, ml, _, y, _ in self._sdf_friction(U):
                e += c * self.h * float(np.sum(ml * smooth_friction(y, self.epsv)[0]))
        return e if np.isfinite(e) else np.inf

    @_package_threads
    def _surface_gradient(self, x):
        V = self.vertices(x)
        g = np.asarray(self.barrier.gradient(self._collisions(x), self.mesh, V), float).reshape(-1, 3)
        for d, nrm in self._sdf(V):
            g += physical_barrier(d, self.dhat, self.kappa)[1][:, None] * nrm
        if self.lagged is not None:
            U = self._velocities(x)
            g += np.asarray(self.friction.gradient(self.lagged[2], self.mesh, U), float).reshape(-1, 3)
            for act, ml, u, y, _ in self._sdf_friction(U):
                np.add.at(g, act, (ml * smooth_friction(y, self.epsv)[1])[:, None] * u)
        return g

    def gradient(self, x):
        """dC/dx on the free DOFs (nfree,)."""
        return self.select @ self._surface_gradient(x).reshape(-1)

    def hessian(self, x, project=True):
        """grad^2 C on the free DOFs, a (nfree, nfree) CSR matrix.

        ``project``: ipctk's per-collision PSD projection (clamped eigenvalues), and the SDF
        barrier's negative curvature clamped to 0; False gives the exact Hessian (tests).
        """
        r, c, v = self._hessian_coo(x, project)
        return sp.csr_matrix((v, (r, c)), shape=(self.nfree, self.nfree))

    @_package_threads
    def _hessian_coo(self, x, project):
        """The contact Hessian's entries (rows, cols, values) on the free DOFs (duplicates summed later)."""
        V = self.vertices(x)
        psd = ipctk.PSDProjectionMethod.CLAMP if project else ipctk.PSDProjectionMethod.NONE
        rows, cols, vals = [], [], []

        def add_sparse(M, scale=1.0):
            M = M.tocoo()
            rows.append(M.row), cols.append(M.col), vals.append(scale * M.data)

        def add_blocks(verts, blocks):  # 3 x 3 blocks on single vertices
            r = np.broadcast_to(3 * verts[:, None, None] + np.arange(3)[None, :, None], blocks.shape)
            rows.append(r.ravel()), cols.append(np.swapaxes(r, 1, 2).ravel()), vals.append(blocks.ravel())

        cc = self._collisions(x)
        if len(cc):
            add_sparse(self.barrier.hessian(cc, self.mesh, V, psd))
        for d, nrm in self._sdf(V):
            e2 = physical_barrier(d, self.dhat, self.kappa)[2]
            if project:
                e2 = np.maximum(e2, 0.0)
            act = np.flatnonzero(e2 != 0)
            add_blocks(act, e2[act, None, None] * nrm[act, :, None] * nrm[act, None, :])
        if self.lagged is not None:
            ch = self.lagged[1] * self.h
            U = self._velocities(x)
            if len(self.lagged[2]):
                add_sparse(self.friction.hessian(self.lagged[2], self.mesh, U, psd), 1.0 / ch)
            for act, ml, u, y, nrm in self._sdf_friction(U):
                _, f1y, f2 = smooth_friction(y, self.epsv)
                P = np.eye(3)[None] - nrm[:, :, None] * nrm[:, None, :]
                t = np.divide(u, y[:, None], out=np.zeros_like(u), where=y[:, None] > 0)
                # f1/y on the tangent plane, f2 along the slip: both >= 0 (PSD as it stands)
                Hv = f1y[:, None, None] * P + (f2 - f1y)[:, None, None] * t[:, :, None] * t[:, None, :]
                add_blocks(act, (ml / ch)[:, None, None] * Hv)
        if not rows:
            return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
        r, c = self.cdofs[np.concatenate(rows)], self.cdofs[np.concatenate(cols)]
        keep = (r >= 0) & (c >= 0)   # fixed DOFs dropped
        return r[keep], c[keep], np.concatenate(vals)[keep]

    def hessian_parts(self, x, project=True):
        """:meth:`hessian` split as ``(data, rest)``: its entries on the free-DOF pattern
        ``system.pattern`` as a data array, and the rest (couplings of vertices that are not mesh
        neighbours) as a CSR matrix, or None when there is none.

        ``pattern.matrix(elastic + w * data) + w * rest`` keeps the matrix pattern of the elastic
        Hessian whenever contact couples only mesh neighbours (colliders, no body contact), so a
        direct solver reuses its analysis.
        """
        r, c, v = self._hessian_coo(x, project)
        pat = self.system.pattern
        if self._pattern_keys is None:
            self._pattern_keys = pat.rows.astype(np.int64) * self.nfree + pat.indices
        key = r * self.nfree + c
        pos = np.minimum(np.searchsorted(self._pattern_keys, key), pat.nnz - 1)
        on = self._pattern_keys[pos] == key
        data = np.bincount(pos[on], weights=v[on], minlength=pat.nnz)
        off = ~on
        rest = None
        if np.any(off):
            rest = sp.csr_matrix((v[off], (r[off], c[off])), shape=(self.nfree, self.nfree))
        return data, rest

    def hessian_data(self, x):
        """Zeros on the free-DOF pattern: the contact Hessian is :meth:`hessian` or
        :meth:`hessian_parts` (it leaves the pattern), so a potential that adds ``hessian_data``
        and ``hessian`` counts it once."""
        return np.zeros(self.system.pattern.nnz)

    @_package_threads
    def vertex_energy(self, x):
        """Contact energy C(x) per vertex (n,): the shares of the adaptive-subspace oracle (eq. 7).

        Each collision's barrier energy (surface pairs between and within bodies) and, while a
        step's friction is lagged, each tangential collision's friction energy is shared equally
        by its stencil's vertices; a vertex's barrier and friction against a collider are its own.
        The shares sum to :meth:`energy`, so the oracle's nodal energies still sum to E.
        """
        V = self.vertices(x)
        out = np.zeros(V.shape[0])
        E, F = self.mesh.edges, self.mesh.faces

        def share(potential, collisions, X, scale=1.0):
            for i in range(len(collisions)):
                col = collisions[i]
                ids = np.asarray(col.vertex_ids(E, F))
                ids = ids[ids >= 0]
                out[ids] += scale * float(potential(col, col.dof(X, E, F))) / ids.size

        share(self.barrier, self._collisions(x), V)
        for d, _ in self._sdf(V):
            out += physical_barrier(d, self.dhat, self.kappa)[0]
        if self.lagged is not None:
            ch = self.lagged[1] * self.h
            U = self._velocities(x)
            share(self.friction, self.lagged[2], U, ch)
            for act, ml, _, y, _ in self._sdf_friction(U):
                np.add.at(out, act, ch * ml * smooth_friction(y, self.epsv)[0])
        full = np.zeros(self.system.n)
        full[self.surface] = out
        return full

    # ------------------------------------------------------------------ CCD
    @_package_threads
    def max_step(self, x, dx):
        """Largest alpha in [0, 1] such that x + t dx is intersection-free for t in [0, alpha].

        ipctk's CCD (``IPC.ccd``) on the collision mesh; against the colliders, each
        vertex's exact time of impact on a plane and conservative advancement on the other
        signed distances. The time of impact is scaled by ``ccd_rescaling``.
        """
        V0 = self.vertices(x)
        dV = self.vertices(x + dx) - V0
        alpha = 1.0
        if self.mesh.num_faces:
            alpha = float(ipctk.compute_collision_free_stepsize(self.mesh, V0, np.asfortranarray(V0 + dV),
                                                                0.0, None, self.ccd))
        for c in self.colliders:
            alpha = min(alpha, self._collider_step(c, V0, dV))
        return alpha

    def _collider_step(self, c, V0, dV, iterations=100):
        """Largest step fraction of the vertices V0 + t dV before they reach collider c (rescaled)."""
        rescale = self.settings.ccd_rescaling
        d0 = np.asarray(c.query(V0)[0], float)
        if type(c) is Plane:
            rate = dV @ c.normal
            closing = rate < 0
            if not np.any(closing):
                return 1.0
            return min(1.0, float(np.min(rescale * d0[closing] / -rate[closing])))
        step = np.linalg.norm(dV, axis=1)
        # the distance is 1-Lipschitz: a vertex moving less than rescale d0 keeps (1 - rescale) d0
        idx = np.flatnonzero(step > rescale * d0)
        if idx.size == 0:
            return 1.0
        d0, P, D, L = d0[idx], V0[idx], dV[idx], step[idx]
        t = np.zeros(idx.size)
        for _ in range(iterations):
            d = np.asarray(c.query(P + t[:, None] * D)[0], float)
            go = (t < 1.0) & (d > (1.0 - rescale) * d0)
            if not np.any(go):
                break
            t = np.where(go, np.minimum(t + d / L, 1.0), t)
        # a vertex that did not finish its advancement stops where it got to (conservative)
        return float(t.min())

    # ------------------------------------------------------------------ checks
    @_package_threads
    def intersection_free(self, x):
        """True when the surface has no intersection and every vertex lies outside every collider."""
        V = self.vertices(x)
        if self.mesh.num_faces and ipctk.has_intersections(self.mesh, V):
            return False
        return all(d.min() > 0 for d, _ in self._sdf(V))

    @_package_threads
    def step_collision_free(self, x0, x1):
        """ipctk's CCD check of the straight surface path x0 -> x1 (bodies against bodies)."""
        if not self.mesh.num_faces:
            return True
        return bool(ipctk.is_step_collision_free(self.mesh, self.vertices(x0), self.vertices(x1)))

