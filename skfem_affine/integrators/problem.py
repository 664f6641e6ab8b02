r"""One frame as data: the model of a run, the linearized step (eq. 1-2) and a reducer's answer.

A frame of the linearized backward Euler integrator solves, on the free DOFs,

.. math::
    A\,\Delta\dot x = b, \qquad A = c_M M + c_K H, \qquad
    b = h\big(f - \alpha M \dot x - (\beta + h) H \dot x - H e\big),

with :math:`c_M = 1 + h\alpha`, :math:`c_K = h\beta + h^2` (Rayleigh damping
D = -(alpha M + beta H), H = -df/dx the stiffness, f the internal force plus gravity, e the
stretch the linear position update gives the free bodies' rotation,
:mod:`~skfem_affine.integrators.rotation`; e = 0 recovers eq. 2).
:func:`system_coefficients` is the one place these coefficients are derived.

* :class:`Model`: what is fixed over a run (system, h, damping, gravity, scene size).
* :class:`StepProblem`: one frame, built by the integrator at x_t and handed to the reducer
  and to contact; it never refers back to the simulation.
* :class:`StepResult`: what a reducer returns: the velocity change (or the positions of a
  Newton integrator), the factorised :class:`Operator` that contact's Delassus operator needs,
  the frame's mapping, clusters and statistics.
"""
import time
from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np
import scipy.sparse as sp

from skfem_affine.checks import nonnegative
from skfem_affine.upper import whole_from_upper

# Per-frame timing keys of ``sim.stats`` (seconds); a reducer's stats add to the integrator's.
PHASES = ("assembly", "prediction", "clustering", "map_assembly", "reduced_assembly",
          "factorization", "solve", "line_search", "contact", "oracle_refresh")


@dataclass(frozen=True)
class Rayleigh:
    """Rayleigh damping D = -(alpha M + beta H) with H = -K the stiffness (alpha, beta >= 0)."""

    alpha: float = 0.0
    beta: float = 0.0

    def __post_init__(self):
        for name in ("alpha", "beta"):  # frozen: store the checked float
            object.__setattr__(self, name, nonnegative(getattr(self, name), f"Rayleigh {name}"))


def system_coefficients(dt, damping=None):
    """(c_M, c_K) of A = c_M M + c_K H (eq. 1): c_M = 1 + h alpha, c_K = h beta + h^2.

    ``damping`` is a :class:`Rayleigh` or None (undamped).
    """
    h = float(dt)
    alpha, beta = (0.0, 0.0) if damping is None else (damping.alpha, damping.beta)
    return 1.0 + h * alpha, h * beta + h * h


@dataclass(frozen=True)
class Model:
    """What is fixed over a run, shared by the integrator, the reducer and contact.

    Attributes
    ----------
    system : ElasticSystem
        The bodies, their mass, pattern and free DOFs.
    dt : float
        Time step h (s).
    damping : Rayleigh
    gravity : (3,) array
        Gravitational acceleration.
    f_gravity : (3n,) array
        Gravity force M g on all DOFs.
    project_hessian : bool
        Whether element Hessians are projected to PSD.
    size : float
        Diagonal of the rest bounding box (the scale of tolerances).
    motion : Motion or None
        Prescribed vertices and vertex forces (:class:`skfem_affine.motion.Motion`), evaluated
        by the integrator once per frame; None (or inactive) without them.
    """

    system: object
    dt: float
    damping: Rayleigh
    gravity: np.ndarray
    f_gravity: np.ndarray
    project_hessian: bool
    size: float
    motion: object = None

    @property
    def coefficients(self):
        """(c_M, c_K) of A = c_M M + c_K H (:func:`system_coefficients`)."""
        return system_coefficients(self.dt, self.damping)

    @cached_property
    def rotation_stretch(self):
        """The free bodies' :class:`~skfem_affine.integrators.rotation.RotationStretch` (built on first use)."""
        from skfem_affine.integrators.rotation import RotationStretch
        return RotationStretch(self.system)

    def evaluate(self, x):
        """Forces, dP/dF, element blocks and H at positions x (n, 3) (:meth:`ElasticSystem.evaluate`)."""
        return self.system.evaluate(x, project=self.project_hessian)


@dataclass
class StepProblem:
    """One linearized backward Euler frame (eq. 1-2) at (x_t, v_t), as data.

    Attributes
    ----------
    model : Model
    x, v : (n, 3) arrays
        Positions and velocities at t.
    frame : int
        The frame being computed (t + 1).
    data : FrameData
        The elastic evaluation at x_t; ``data.f`` includes gravity.
    Hmat : CSR matrix
        The stiffness H on the free DOFs.
    contact_impulse : (n_free,) array or 0.0
        J^T lambda_pred, contact impulses the prediction oracle takes as explicit forces (sec. 3.4).
    contacts : ContactSet or None
        The contacts found at x_t.
    targets : Targets or None
        The prescribed vertices' positions and velocities at t + 1 (:class:`skfem_affine.motion.Targets`);
        their motion enters :meth:`rhs` through the coupling blocks (:func:`skfem_affine.motion.coupling`).
    f_ext : (3n,) array or None
        The frame's vertex forces (:class:`skfem_affine.motion.VertexForce`), already in ``data.f``.
    support_impulse : (n_free,) array or 0.0
        J^T lambda_0, the part of ``contact_impulse`` warm-started from the last frame: the steady
        support of bodies at rest (new contacts carry none).
    """

    model: Model
    x: np.ndarray
    v: np.ndarray
    frame: int
    data: object
    Hmat: sp.csr_matrix
    contact_impulse: object = 0.0
    contacts: object = None
    targets: object = None
    f_ext: np.ndarray = None
    support_impulse: object = 0.0
    _b: np.ndarray = field(default=None, init=False, repr=False)
    _coupling: np.ndarray = field(default=None, init=False, repr=False)

    @classmethod
    def at(cls, model, x, v, frame=0, data=None, rec=None, **kwargs):
        """Evaluate the frame at (x, v) (``data``: a :class:`FrameData` already evaluated at x).

        Adds gravity (and ``f_ext``, the frame's vertex forces) to ``data.f``, assembles H, and with
        ``targets`` the prescribed vertices' coupling; the time goes to ``rec["assembly"]``.
        """
        t0 = time.perf_counter()
        data = model.evaluate(x) if data is None else data
        data.f = data.f + model.f_gravity
        if kwargs.get("f_ext") is not None:
            data.f = data.f + kwargs["f_ext"]
        Hmat = model.system.pattern.matrix(data.H)
        problem = cls(model, x, v, frame, data, Hmat, **kwargs)
        if problem.targets is not None:
            from skfem_affine.motion import coupling
            problem._coupling = coupling(problem, problem.targets)
        if rec is not None:
            rec["assembly"] = rec.get("assembly", 0.0) + time.perf_counter() - t0
        return problem

    @property
    def system(self):
        return self.model.system

    def without_elements(self, inside):
        """This frame with the elements ``inside`` (m,) bool left out of f and H (the interiors of rigid
        bodies, whose internal forces are self-equilibrated and whose strain a rigid motion keeps).

        H is summed anew over the other elements' blocks (so those inside are never read); f loses
        the inside elements' internal forces. ``targets``' coupling is kept (no element wholly
        inside a body has a prescribed vertex)."""
        from skfem_affine._eigensystems import scatter_forces
        from skfem_affine._kernels import scatter_add
        sysm, data = self.system, self.data
        outer = np.flatnonzero(~inside)
        elems = np.flatnonzero(inside)
        slot = sysm.pattern.slot.reshape(sysm.m, 144)[outer].ravel()
        H = scatter_add(slot, np.ascontiguousarray(data.He[outer]).reshape(-1), sysm.pattern.nnz)
        # internal force of an element: -V_e P_e grad phi_k on its vertex k
        fe = -np.einsum("e,eij,ekj->eki", sysm.volumes[elems], data.P[elems], sysm.grads[elems], optimize=True)
        f_inside = scatter_forces(np.ascontiguousarray(sysm.t[:, elems]), fe, sysm.n)
        data = replace(data, f=data.f - f_inside, H=H)
        out = StepProblem(self.model, self.x, self.v, self.frame, data, sysm.pattern.matrix(H), self.contact_impulse,
                          self.contacts, self.targets, self.f_ext, self.support_impulse)
        out._coupling = self._coupling
        return out

    def rhs(self, v):
        """b = h (f - alpha M v - (beta + h) H v - H e) on the free DOFs (eq. 2), v (n, 3) all vertices.

        f - h H v - H e is eq. 2's Taylor term f + h K v of f(x_t + h v), with e the stretch the
        linear position update gives the free bodies' rotation (:mod:`~skfem_affine.integrators.rotation`;
        no term when no free body turns). With prescribed vertices, minus their coupling
        (:func:`skfem_affine.motion.coupling`).
        """
        m = self.model
        h, d, sysm = m.dt, m.damping, m.system
        vf = v.reshape(-1)[sysm.free]
        b = h * (self.data.f[sysm.free] - d.alpha * (sysm.Mff @ vf) - (d.beta + h) * (self.Hmat @ vf))
        e = m.rotation_stretch(self.x, v, h)
        if e is not None:
            b -= h * (self.Hmat @ e)
        if self._coupling is not None:
            b -= self._coupling
        return b

    @property
    def b(self):
        """The right-hand side at v_t (eq. 2), computed once."""
        if self._b is None:
            self._b = self.rhs(self.v)
        return self._b

    def matrix(self):
        """A = c_M M + c_K H on the free DOFs (eq. 1), CSR."""
        cm, ck = self.model.coefficients
        sysm = self.model.system
        return sysm.pattern.matrix(cm * sysm.mass_data + ck * self.data.H)


class Operator:
    """The factorised system of a frame, as contact's Delassus operator needs it (sec. 3.3).

    Parameters
    ----------
    solver : solver object
        Has factorised ``matrix``.
    matrix : sparse matrix
        A (full space) or A_r = G^T A G (reduced). With ``upper=True`` the upper triangle is
        given and :attr:`matrix` returns the whole symmetric matrix, built on first use.
    G : sparse matrix, optional
        The frame's mapping (free DOFs x reduced unknowns); None in full space. In a scene of several
        bodies a reducer may number its unknowns as full space does, the reduced vertices' own DOFs
        kept as unknowns with empty columns (:mod:`~skfem_affine.reducers.affine.numbering`): G then
        has more columns than rows.
    schur : (keep, S), optional
        When the factorisation had the sorted unknowns ``keep`` last: their Schur complement S
        (dense), so that ``(A^-1)_keep,keep = S^-1`` without a solve
        (:meth:`~skfem_affine.contact.schur.SchurInverse.factorize_on`).
    """

    def __init__(self, solver, matrix, G=None, upper=False, schur=None):
        self.solver, self.G, self.schur = solver, G, schur
        self._matrix, self._upper = matrix, bool(upper)
        # solvers without the attribute (user objects) are taken as direct
        self.iterative = bool(getattr(solver, "iterative", False))

    @property
    def matrix(self):
        """The factorised symmetric matrix (whole, not one triangle)."""
        if self._upper:
            U = self._matrix
            self._matrix, self._upper = whole_from_upper(U), False
        return self._matrix

    @property
    def stored(self):
        """(the matrix as given, whether it is the upper triangle only): for a reader of its entries that
        need not build the whole matrix."""
        return self._matrix, self._upper

    @property
    def shape(self):
        return self._matrix.shape


@dataclass
class StepResult:
    """What a reducer returns for one frame.

    Attributes
    ----------
    dv : (n_free,) array or None
        Velocity change of the free DOFs (linearized integrator).
    x : (3n,) array or None
        Positions at t + 1 (Newton integrators).
    operator : Operator or None
        The factorised system contact resolves with.
    mapping : Mapping or None
        The frame's reduction (:class:`~skfem_affine.reducers.affine.mapping.Mapping`); its
        :meth:`positions` integrates the positions of its bodies.
    clusters : (m,) int array or None
        Per element: -1 elastic, else its body.
    stats : dict
        Merged into the frame's record of ``sim.stats`` (timings in :data:`PHASES` add up).
    """

    dv: np.ndarray = None
    x: np.ndarray = None
    operator: Operator = None
    mapping: object = None
    clusters: np.ndarray = None
    stats: dict = field(default_factory=dict)

    def positions(self, x, v, dt):
        """x_{t+1} from x_t and v_{t+1} (n, 3): x + h v, or the mapping's own update."""
        if self.mapping is not None:
            return self.mapping.positions(x, v, dt)
        return x + dt * v

    def velocities(self, x, v, x_new):
        """v_{t+1} (n, 3) at x_new from the solved v: v, or the mapping's own (rigid bodies keep L)."""
        if self.mapping is not None:
            return self.mapping.velocities(x, v, x_new)
        return v


def merge_stats(rec, stats):
    """Merge a reducer's statistics into the frame record: timings add up, the rest is set."""
    for key, val in stats.items():
        rec[key] = rec.get(key, 0.0) + val if key in PHASES else val
    return rec
