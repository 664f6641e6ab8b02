r"""Moving boundaries and external forces: :class:`Prescribed` vertices and :class:`VertexForce`.

* :class:`Prescribed` (given to an :class:`~skfem_affine.ElasticBody`, beside ``fixed``):
  vertices whose positions follow a function of time, ``path(t, X) -> x`` with X the rest
  positions (k, 3) of the vertices: a clamp that rotates, translates or shakes. They are not
  unknowns of any solve (the system's ``fixed`` mask holds both kinds, ``prescribed`` the moving
  ones); their positions follow the path exactly.
* :class:`VertexForce` (given to a :class:`~skfem_affine.Simulation` as ``forces=[...]``): a
  force ``force(t, x, v) -> (k, 3)`` on vertices, from the time and their positions and
  velocities (a user pulling a tentacle). It adds to gravity.

:class:`Motion` gathers both for a run; the integrator evaluates it once per frame and puts the
values into the frame's problem (one way: no reducer calls back):

* linearized integrator (:class:`~skfem_affine.integrators.linearized.LinearizedEuler`): the
  prescribed velocity over the step :math:`v_p = (\mathrm{path}(t+h) - x_{p,t})/h` enters the
  right-hand side of the free DOFs through the coupling blocks (:func:`coupling`),
  :math:`b_f \mathrel{-}= M_{fp}(\Delta v_p + h\alpha v_p) + c_K H_{fp} v_p`; the forces are
  evaluated at (t, x_t, v_t), explicitly;
* Newton integrators: the prescribed DOFs sit at path(t + h) in every iterate of the
  incremental potential (:class:`~skfem_affine.integrators.potential.IncrementalPotential`),
  the forces (at t, x_t, v_t) add to :math:`f_{ext}`.
"""
from dataclasses import dataclass

import numpy as np

from skfem_affine.checks import real_array
from skfem_affine.vertex_sets import needs_mesh, vertices_of

__all__ = ["Prescribed", "VertexForce", "Motion", "Targets", "coupling", "work"]


def vertex_indices(vertices, n, name, mesh=None):
    """Vertex indices (k,) int64, none repeated, at least one, from any selection that
    :func:`~skfem_affine.vertex_sets.vertices_of` takes (of ``mesh`` when given), checked against n."""
    a = vertices_of(mesh, vertices, n=n, name=name)
    if a.size == 0:
        if np.asarray(vertices).dtype == bool:
            raise ValueError(f"{name} mask selects no vertex")
        raise ValueError(f"{name} is empty: give at least one vertex")
    if np.unique(a).size != a.size:
        raise ValueError(f"{name} repeats vertices")
    return a


class Prescribed:
    """Vertices whose positions follow ``path(t, X) -> x`` (a moving clamp).

    Parameters
    ----------
    vertices : vertex indices, boolean mask, boundary name(s) or scikit-fem DofsView
        The body's vertices (e.g. ``mesh.nodes_satisfying(...)``, a name of ``mesh.boundaries``
        or ``basis.get_dofs(...)``; :mod:`skfem_affine.vertex_sets`).
    path : callable
        ``path(t, X)`` with t the time (s) and X the rest positions (k, 3) of ``vertices``
        returns their positions (k, 3) at t. At t = 0 it gives the initial positions (the
        simulation starts there); for a smooth start let ``path(0, X) == X``.

    Notes
    -----
    The path's positions are followed exactly (to round-off: they are copied, not integrated);
    the vertices' velocities are the path's finite differences over each step.

    Examples
    --------
    A clamp at x = 0 turning about the x axis at 1 rad/s:

    >>> import numpy as np
    >>> def turn(t, X):
    ...     c, s = np.cos(t), np.sin(t)
    ...     return X @ np.array([[1, 0, 0], [0, c, s], [0, -s, c]])
    >>> clamp = Prescribed([0, 1, 2], turn)
    """

    def __init__(self, vertices, path):
        if not callable(path):
            raise TypeError(f"path must be a callable path(t, X) -> (k, 3) positions, got {type(path).__name__}")
        if not needs_mesh(vertices):  # their kind now; their range, names and DofsViews when bound to a body
            vertex_indices(vertices, None, "vertices")
        self.vertices = vertices
        self.path = path

    def __repr__(self):
        k = np.size(self.vertices) if np.asarray(self.vertices).dtype != bool else int(np.sum(self.vertices))
        return f"Prescribed({k} vertices, path={getattr(self.path, '__name__', self.path)!r})"

    def bind(self, rest, mesh=None):
        """Check against a body's rest positions (n, 3) (and its mesh, for boundary names and
        DofsViews): the vertex indices and path(0, X).

        Returns the indices (k,); raises ValueError/TypeError naming ``vertices`` or ``path``.
        """
        idx = vertex_indices(self.vertices, rest.shape[0], "prescribed vertices", mesh)
        evaluate_path(self.path, 0.0, rest[idx])
        return idx


def evaluate_path(path, t, X):
    """``path(t, X)`` as a finite (k, 3) float array, or a ValueError/TypeError naming ``path``."""
    try:
        x = np.asarray(path(float(t), X.copy()), dtype=float)
    except (TypeError, ValueError) as err:
        raise type(err)(f"path(t, X) failed at t = {t:g}: {err}") from err
    if x.shape != X.shape:
        raise ValueError(f"path(t, X) must return an array of the shape of X {X.shape}, got {x.shape} at t = {t:g}")
    if not np.all(np.isfinite(x)):
        raise ValueError(f"path(t, X) returned non-finite positions at t = {t:g}")
    return x


class VertexForce:
    """A force on vertices as a function of time and state: ``force(t, x, v) -> (k, 3)``.

    Parameters
    ----------
    vertices : vertex indices, boolean mask, boundary name(s) or scikit-fem DofsView
        Indices into the simulation's stacked vertices (``state.x``); for one body, its own.
        With ``body=`` they are that body's indices. Boundary names of ``mesh.boundaries`` and
        a ``DofsView`` (``basis.get_dofs(...)``) refer to the body's mesh: they need ``body=``
        when the simulation has several bodies (:mod:`skfem_affine.vertex_sets`).
    force : callable or (3,) array
        ``force(t, x, v)`` with x, v the positions and velocities (k, 3) of ``vertices``
        returns the force on each (k, 3) or one force for all (3,), in newtons. A constant
        (3,) array is a constant force on each vertex.
    body : ElasticBody, optional
        The body whose vertices ``vertices`` index.

    Notes
    -----
    The force is evaluated once per step at the start of the step (t, x_t, v_t): explicit
    in time, like gravity.
    """

    def __init__(self, vertices, force, body=None):
        if not callable(force):
            value = real_array(force, "force")
            if value.shape != (3,) or not np.all(np.isfinite(value)):
                raise ValueError(f"force must be a callable force(t, x, v) or a finite (3,) vector, got shape "
                                 f"{value.shape}")
            force = _Constant(value)
        if not needs_mesh(vertices):  # their kind now; their range, names and DofsViews in the simulation
            vertex_indices(vertices, None, "VertexForce vertices")
        self.vertices, self.force, self.body = vertices, force, body

    def __repr__(self):
        return f"VertexForce({np.size(self.vertices)} vertices, force={self.force!r})"


class _Constant:
    def __init__(self, value):
        self.value = value

    def __call__(self, t, x, v):
        return self.value

    def __repr__(self):
        return f"constant {self.value.tolist()}"


@dataclass
class Targets:
    """The prescribed vertices of one step: indices (k,), positions x and velocities v (k, 3) at t + h."""

    vertices: np.ndarray
    x: np.ndarray
    v: np.ndarray

    @property
    def dofs(self):
        return (3 * self.vertices[:, None] + np.arange(3)).ravel()


class Motion:
    """The prescribed vertices and vertex forces of a run, evaluated per step by the integrator.

    Parameters
    ----------
    system : ElasticSystem
        Its bodies' :class:`Prescribed` (``body.prescribed``) are gathered with the bodies' vertex offsets.
    forces : list of VertexForce

    Notes
    -----
    Attributes (plain, for checkpoints): ``paths`` a list of (vertices (k,), rest X (k, 3), path),
    ``forces`` a list of (vertices (k,), force callable).
    """

    def __init__(self, system, forces=()):
        self.paths = []
        for body, off in zip(system.bodies, system.vertex_offsets):
            for pres, idx in zip(body.prescribed, body.prescribed_vertices):
                self.paths.append((idx + off, system.p0[idx + off].copy(), pres.path))
        self.n = system.n
        if isinstance(forces, VertexForce):
            forces = [forces]
        if forces is None:
            forces = []
        if not isinstance(forces, (list, tuple)):
            raise TypeError(f"forces must be a list of sa.VertexForce, got {type(forces).__name__}")
        self.forces = []
        bodies = list(system.bodies)
        for k, f in enumerate(forces):
            if not isinstance(f, VertexForce):
                raise TypeError(f"forces[{k}] must be a sa.VertexForce(vertices, force), got {type(f).__name__}")
            if f.body is None:
                mesh = bodies[0].mesh if len(bodies) == 1 else None  # one body: its mesh names its boundaries
                idx = vertex_indices(f.vertices, system.n, f"forces[{k}] vertices", mesh)
            else:
                match = [i for i, b in enumerate(bodies) if b is f.body]
                if not match:
                    raise ValueError(f"forces[{k}] body is not one of the simulation's bodies")
                i = match[0]
                idx = vertex_indices(f.vertices, bodies[i].n_vertices, f"forces[{k}] vertices",
                                     bodies[i].mesh) + system.vertex_offsets[i]
            self.forces.append((idx, f.force))

    @property
    def active(self):
        """Whether there is anything to evaluate (no Motion work at all otherwise)."""
        return bool(self.paths or self.forces)

    @property
    def vertices(self):
        """All prescribed vertices (stacked indices)."""
        if not self.paths:
            return np.zeros(0, dtype=np.int64)
        return np.concatenate([p[0] for p in self.paths])

    def positions(self, t):
        """(vertices (k,), positions (k, 3)) of the prescribed vertices at time t."""
        if not self.paths:
            return np.zeros(0, dtype=np.int64), np.zeros((0, 3))
        return self.vertices, np.concatenate([evaluate_path(path, t, X) for _, X, path in self.paths])

    def targets(self, t_next, x, dt):
        """:class:`Targets` of the step to t_next from positions x (n, 3): path(t_next) and (path - x)/h; None without paths."""
        if not self.paths:
            return None
        idx, xp = self.positions(t_next)
        return Targets(idx, xp, (xp - x[idx]) / dt)

    def force(self, t, x, v):
        """The vertex forces (3n,) at (t, x, v), or None without forces."""
        if not self.forces:
            return None
        out = np.zeros((self.n, 3))
        for k, (idx, fn) in enumerate(self.forces):
            fk = np.asarray(fn(float(t), x[idx].copy(), v[idx].copy()), dtype=float)
            if fk.shape == (3,):
                fk = np.broadcast_to(fk, (idx.size, 3))
            if fk.shape != (idx.size, 3) or not np.all(np.isfinite(fk)):
                raise ValueError(f"forces[{k}]: force(t, x, v) must return finite values of shape ({idx.size}, 3) "
                                 f"or (3,), got shape {fk.shape} at t = {t:g}")
            np.add.at(out, idx, fk)
        return out.reshape(-1)


def coupling(problem, targets):
    r"""The free rows of A dv_p - h(-alpha M - (beta + h) H) v_p^t for prescribed DOFs (eq. 1-2).

    With the prescribed DOFs p moving with velocity :math:`v_p^{t+1}` over the step and
    :math:`\Delta v_p = v_p^{t+1} - v_p^t`, the free rows of eq. 1-2 read
    :math:`A_{ff}\Delta v_f = b_f - A_{fp}\Delta v_p - h(\alpha M_{fp} + (\beta + h)H_{fp}) v_p^t`,
    i.e. :math:`b_f - M_{fp}(\Delta v_p + h\alpha v_p^{t+1}) - c_K H_{fp} v_p^{t+1}` with
    :math:`c_K = h\beta + h^2`. Returns that subtracted vector (n_free,); H_fp v comes from the
    element blocks of the frame (``problem.data.He``), M_fp from the system's mass (zero when lumped).
    """
    m, sysm = problem.model, problem.system
    h, alpha = m.dt, m.damping.alpha
    _, ck = m.coefficients
    n = sysm.n
    vnew = np.zeros((n, 3))
    vnew[targets.vertices] = targets.v
    out = np.zeros(3 * n)
    touch = np.flatnonzero(np.any(np.isin(sysm.t, targets.vertices), axis=0))
    if touch.size:
        ve = vnew[sysm.t[:, touch].T].reshape(-1, 12)                 # (k, 12) element velocities
        fe = np.einsum("eij,ej->ei", problem.data.He[touch], ve)     # H_e v_e
        np.add.at(out, sysm.edofs[touch].ravel(), fe.ravel())
    out *= ck
    if sysm.mass_kind != "lumped":
        w = np.zeros((n, 3))
        w[targets.vertices] = (targets.v - problem.v[targets.vertices]) + h * alpha * targets.v
        out += sysm.M @ w.reshape(-1)
    return out[sysm.free]


def work(system, f_gravity, targets, f_ext, x0, v0, x, v, dt):
    r"""The work (J) the vertex forces and the prescribed vertices did on the body over one step.

    For the simulation's energy check (:mod:`skfem_affine.monitor`), which refuses a step that
    creates energy: a moving clamp and a pull put energy in.

    * Vertex forces alone: :math:`f_{ext}\cdot\Delta x`.
    * With prescribed vertices, the clamp's force reaches the body through the elements next to
      it and, with ``pinned_bodies``, through a body's constraints; both are in the step's force
      balance, so the work is that of everything but the elastic forces and gravity,
      :math:`\sum (M\Delta v/h - f(x_{t+1}) - Mg)\cdot\Delta x` over all DOFs (vertex forces and
      damping included, the latter negative). A first-order estimate that also credits an
      integrator's own energy error as work, so with prescribed vertices the check is weaker:
      it still refuses non-finite states and torn bodies.
    """
    dx = (np.asarray(x) - np.asarray(x0)).reshape(-1)
    if targets is None:
        return 0.0 if f_ext is None else float(f_ext @ dx)
    dv = (np.asarray(v) - np.asarray(v0)).reshape(-1)
    f_int = system.forces_and_stiffness(np.asarray(x).reshape(-1, 3), tangent=False)[0]
    return float((system.M @ dv / dt - f_int - f_gravity) @ dx)
