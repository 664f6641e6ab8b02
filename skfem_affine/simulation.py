"""The user-facing :class:`Simulation`: bodies, settings, state and statistics of a run.

A simulation builds the :class:`~skfem_affine.integrators.problem.Model` of the run (system,
h, damping, gravity, scene size), its contact model, its reducer
(:class:`~skfem_affine.reducers.full.FullSpace` when none is given) and its integrator, and
delegates each :meth:`Simulation.step` to the integrator:

* ``integrator="linearized"`` (default): the affinification paper's linearized backward Euler,
  :class:`~skfem_affine.integrators.linearized.LinearizedEuler` (eq. 1-2, Algorithm 1);
* ``integrator="implicit_euler" | "bdf2"``: Newton on the incremental potential in positions
  (adaptive-subspace paper, eq. 1-3), :mod:`skfem_affine.integrators.newton`.

Nothing below the simulation receives it: reducers and contact are given the model and the
frame's :class:`~skfem_affine.integrators.problem.StepProblem`.
"""
import contextlib
import signal
import threading
import time
from dataclasses import dataclass

import numpy as np

import skfem_affine
from skfem_affine import checkpoint, stress
from skfem_affine._json import jsonable

from skfem_affine.assembly import ElasticSystem
from skfem_affine.body import check_bodies
from skfem_affine.checks import choice, flag, integer, positive, real, real_array
from skfem_affine.vertex_sets import vector_p1_dofs
from skfem_affine.contact import pgs
from skfem_affine.contact.colliders import check_colliders
from skfem_affine.contact.geometry import Detector
from skfem_affine.contact.ipc import IPC, IPCContact
from skfem_affine.contact.barrier import barrier_of
from skfem_affine.integrators import newton
from skfem_affine.integrators.linearized import LinearizedEuler
from skfem_affine.integrators.newton_integrator import NewtonIntegrator
from skfem_affine.integrators.problem import PHASES, Model, Rayleigh, StepProblem, StepResult
from skfem_affine.motion import Motion
from skfem_affine.motion import work as motion_work
from skfem_affine.monitor import Diverged, Monitor, SimulationWarning, warn_stiff_elements
from skfem_affine.reducers.base import Reducer
from skfem_affine.reducers.full import FullSpace
from skfem_affine.solvers import SolverError, make_solver
from skfem_affine.summary import Summary

INTEGRATORS = ("linearized",) + newton.SCHEMES

__all__ = ["Simulation", "SimulationDiverged", "SimulationWarning", "State", "Stats", "Rayleigh", "INTEGRATORS"]


@contextlib.contextmanager
def _interrupts_held():
    """Ctrl-C (SIGINT) held back until the block ends, then handed to its handler. Signals reach
    only the main thread; elsewhere, or under a handler set outside Python, the block runs as is."""
    handler = signal.getsignal(signal.SIGINT)
    if threading.current_thread() is not threading.main_thread() or handler is None:
        yield
        return
    caught = []
    signal.signal(signal.SIGINT, lambda signum, frame: caught.append(frame))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, handler)
        if caught and callable(handler):
            handler(signal.SIGINT, caught[0])


def _load_component(name, comp, loaded):
    """``comp.load_state_dict(loaded)``; whatever error its loader raises on values it cannot take
    becomes a ValueError naming the component."""
    try:
        comp.load_state_dict(loaded)
    except Exception as err:
        missing = f"entry {err} is missing" if isinstance(err, KeyError) else f"{type(err).__name__}: {err}"
        raise ValueError(f"the {name} state is damaged ({missing})") from None


class SimulationDiverged(RuntimeError):
    """A step failed the divergence policy (:mod:`skfem_affine.monitor`): a non-finite state, a
    failed linear solve, energy created by the step, a body torn apart, or (when asked to raise)
    inverted elements or a Newton solve that did not converge. ``frame`` is the frame that failed;
    the simulation (its state and every component's) stays at the frame before it."""

    def __init__(self, frame, reason="non-finite state detected"):
        self.frame = frame
        super().__init__(f"{reason} at frame {frame}")


@dataclass
class State:
    """Positions and velocities (n, 3) of all vertices after ``frame`` steps."""

    x: np.ndarray
    v: np.ndarray
    frame: int = 0
    time: float = 0.0
    clusters: np.ndarray = None  # per element: -1 elastic, else affine/rigid body index

    def copy(self):
        return State(self.x.copy(), self.v.copy(), self.frame, self.time,
                     None if self.clusters is None else self.clusters.copy())

    def dofs(self, basis, field="displacement"):
        """This state as a DOF vector of a scikit-fem ``ElementVector(ElementTetP1())`` basis.

        For ``basis.interpolate``, ``basis.probes``, skfem's plotting and forms. The basis is on
        the body's mesh (one body; for several, :meth:`Simulation.to_dofs`).

        Parameters
        ----------
        basis : skfem.Basis
            ``Basis(mesh, ElementVector(ElementTetP1()))`` on the mesh of the state's body.
        field : {"displacement", "position", "velocity"}
            Displacement from the rest pose of ``basis.mesh`` (m, default), positions (m) or
            velocities (m/s).

        Returns
        -------
        (basis.N,) array

        Examples
        --------
        >>> u = sim.state.dofs(basis)                       # doctest: +SKIP
        >>> tip_displacement = basis.probes(tip.T) @ u      # doctest: +SKIP
        """
        nodal = vector_p1_dofs(basis, self.x.shape[0])
        values = {"displacement": lambda: self.x - basis.mesh.p.T, "position": lambda: self.x,
                  "velocity": lambda: self.v}
        out = np.zeros(basis.N)
        out[nodal] = values[choice(field, "field", tuple(values))]().T
        return out

    @classmethod
    def from_dofs(cls, basis, u, v=None, frame=0, time=0.0):
        """A state from scikit-fem DOF vectors of an ``ElementVector(ElementTetP1())`` basis: the
        displacement ``u`` from the rest pose of ``basis.mesh`` (m) and optionally the velocity ``v``
        (m/s, default zero). The inverse of :meth:`dofs`; e.g. ``sim.state = State.from_dofs(basis,
        u_static)`` starts a run from a scikit-fem static solution."""
        n = basis.mesh.p.shape[1] if hasattr(basis, "mesh") else 0
        nodal = vector_p1_dofs(basis, n)
        u = real_array(u, "u", shape=(basis.N,))
        v = np.zeros(basis.N) if v is None else real_array(v, "v", shape=(basis.N,))
        return cls(basis.mesh.p.T + u[nodal].T, np.ascontiguousarray(v[nodal].T), frame, time)


class Stats(list):
    """Per-frame records (dicts): wall time of each phase in seconds, DOFs solved, solver."""

    PHASES = PHASES

    def total(self, key):
        return float(sum(r.get(key, 0.0) for r in self))

    def mean(self, key):
        return self.total(key) / max(len(self), 1)

    def problems(self):
        """Frames accepted with a defect the divergence policy warns about: ``{"inverted_frames":
        frames with inverted elements, "unconverged_frames": frames whose Newton solve stopped
        before its tolerance, "unresolved_contact_frames": frames whose PGS contact solve left a
        large residual (``contact_unresolved``), "max_penetration": the largest penetration (m)
        recorded}``."""
        return {"inverted_frames": sum(1 for r in self if r.get("inverted_elements")),
                "unconverged_frames": sum(1 for r in self if "newton_converged" in r and not r["newton_converged"]),
                "unresolved_contact_frames": sum(1 for r in self if r.get("contact_unresolved")),
                "max_penetration": max((r.get("max_penetration", 0.0) for r in self), default=0.0)}

    def phase_totals(self):
        return {k: self.total(k) for k in self.PHASES if any(k in r for r in self)}

    def summary(self):
        """Frames, wall time, mean DOFs and phase totals; under an error budget also the largest
        estimated error in the budget's unit (``max_estimated_error``), in metres
        (``max_estimated_error_m``) and the unit it was read in at the end (``error_unit_m``: the
        response so far, the scene size, or 1). A :class:`~skfem_affine.summary.Summary`: a dict
        that prints as a table."""
        wall = self.total("wall")
        out = {"frames": len(self), "wall_s": wall, "frames_per_s": len(self) / wall if wall else float("inf"),
               "mean_dofs": self.mean("dofs"), **{f"{k}_s": v for k, v in self.phase_totals().items()}}
        budgeted = [r for r in self if "estimated_error" in r]
        if budgeted:
            out["max_estimated_error"] = max(r["estimated_error"] for r in budgeted)
            out["max_estimated_error_m"] = max(r["estimated_error"] * r.get("error_unit", 0.0) for r in budgeted)
            out["error_unit_m"] = budgeted[-1].get("error_unit")
        return Summary(out)


class Simulation:
    """Time integration of one or more elastic bodies.

    Parameters
    ----------
    bodies : ElasticBody or list of them
    dt : float
        Time step h (s), > 0.
    gravity : (3,) array
        Gravitational acceleration (m/s^2), default zero.
    damping : Rayleigh, optional
        Default undamped.
    reducer : Reducer, optional
        Adaptive model reduction (e.g. ``sa.Affinification``, :mod:`skfem_affine.reducers.base`);
        None solves in full space. A reducer declares the integrators it runs under; any other
        combination raises a ValueError.
    solver : str or solver object
        See :mod:`skfem_affine.solvers`; default ``"auto"``.
    integrator : {"linearized", "implicit_euler", "bdf2"}
        "linearized" (default) is the affinification paper's linearized backward Euler,
        iterated by ``newton_iters``; the others minimise the incremental potential by
        Newton (:mod:`skfem_affine.integrators.newton`), as the adaptive-subspace reducer needs.
    newton_iters : int
        Linearized: 1 (default) is the paper's step; more iterates Newton with a line search
        to a converged implicit Euler step (full space only: a reducer with
        ``newton_iters > 1`` is refused). Other integrators: the iteration cap (default 50).
    newton_tol : float
        Linearized: Newton stops when the largest position change of an iteration is below
        ``newton_tol`` times the scene size (default 1e-9). Other integrators:
        ||d||_inf / h <= newton_tol times the scene size (default 1e-6, 1/s).
    project_hessian : bool
        Project element Hessians to PSD (default True) so that A is SPD.
    mass : {"lumped", "consistent"}
    colliders : list of colliders, optional
        Static obstacles (:mod:`skfem_affine.contact.colliders`: ``sa.Plane``, ``sa.Sphere``, ...).
    contact : PGS or IPC, optional
        Contact settings: :class:`skfem_affine.contact.pgs.PGS` under the linearized integrator,
        :class:`skfem_affine.contact.ipc.IPC` under the Newton integrators (see Notes).
    on_inverted, on_nonconvergence : {"warn", "raise", "ignore"}
        What a frame with inverted elements (det F <= 0), resp. a Newton solve that stopped before
        its tolerance, does: ``"warn"`` (default; one :class:`SimulationWarning` per run, every
        frame counted in ``sim.stats``), ``"raise"`` :class:`SimulationDiverged`, or ``"ignore"``
        (counted only).
    check_energy : bool
        Refuse a step that creates energy (default True; :mod:`skfem_affine.monitor`).
    forces : list of VertexForce, optional
        External forces on vertices as functions of time and state
        (``sa.VertexForce(vertices, force(t, x, v))``, :mod:`skfem_affine.motion`), added to gravity.
        Moving boundaries are given to the bodies (``ElasticBody(prescribed=sa.Prescribed(...))``).

    Notes
    -----
    **Contact model.** The same ``colliders=`` give a different contact model under each
    integrator, recorded per frame in ``sim.stats`` as ``"contact_model"`` and in
    :attr:`contact_model`:

    * ``"pgs"`` (linearized integrator): frictional contact (Coulomb cone, friction of
      ``contact=PGS(...)``, default ``PGS()``) by projected Gauss-Seidel on the frame's
      Delassus operator, against the colliders and between bodies. It runs when there are
      colliders or several bodies; ``contact=False`` turns it off. With contact, the
      ``"auto"`` solver means the direct solver (the Delassus operator needs A^-1 on many
      columns).
    * ``"ipc-barrier"`` (Newton integrators, one body and ``contact=None``, or ``contact=False``):
      a frictionless IPC log-barrier against the colliders only, added to the incremental
      potential (:mod:`skfem_affine.contact.barrier`); ``contact=PGS(...)`` is refused. Bodies do
      not touch each other under it: several bodies with ``contact=None`` get ``"ipc"`` below
      (``sa.IPC()``), and ``contact=False`` is how to say that they may pass through each other.
    * ``"ipc"`` (Newton integrators, ``contact=sa.IPC(friction=...)``): IPC contact from ipctk
      (:mod:`skfem_affine.contact.ipc`): barrier, lagged smoothed friction and continuous
      collision detection in the line search, against the colliders, between bodies and within
      a body. The start state must be intersection-free (a ValueError names the gap otherwise).
    * ``"none"``: no collider and a single body (or ``contact=False``); no contact code runs.
    """

    def __init__(self, bodies, dt=0.01, gravity=(0.0, 0.0, 0.0), damping=None, reducer=None,
                 solver="auto", newton_iters=None, newton_tol=None, project_hessian=True, mass="lumped",
                 colliders=None, contact=None, integrator="linearized", on_inverted="warn",
                 on_nonconvergence="warn", check_energy=True, forces=None):
        bodies = check_bodies(bodies)
        integrator = choice("linearized" if integrator is None else integrator, "integrator", INTEGRATORS)
        self.integrator_name = integrator
        self.dt = positive(dt, "time step dt")
        self.gravity = real_array(gravity, "gravity", shape=(3,))
        if damping is not None and not isinstance(damping, Rayleigh):
            raise TypeError("damping must be a Rayleigh(alpha, beta) or None")
        self.damping = damping or Rayleigh()
        linearized = integrator == "linearized"
        if reducer is not None and not isinstance(reducer, Reducer):
            raise TypeError(f"reducer must be None or a reducer such as sa.Affinification(...) "
                            f"(a skfem_affine.reducers.base.Reducer), got {type(reducer).__name__}")
        if reducer is not None and reducer.model is not None:
            raise ValueError(f"reducer {reducer!r} already runs in another simulation (it holds that run's clusters, "
                             f"bases and controllers); give each simulation its own reducer object")
        # one place for the Newton settings: a reducer's own (AdaptiveSubspace(newton_tol=...)) are
        # adopted when the simulation's are not given, and must agree with them when both are
        newton_tol, newton_iters = newton.resolve_newton_settings(newton_tol, newton_iters, reducer)
        newton_iters = (1 if linearized else 50) if newton_iters is None else newton_iters
        newton_tol = (1e-9 if linearized else 1e-6) if newton_tol is None else newton_tol
        self.newton_iters = integer(newton_iters, "newton_iters", low=1)
        self.newton_tol = positive(newton_tol, "newton_tol")
        self.project_hessian = flag(project_hessian, "project_hessian")
        self.system = ElasticSystem(bodies, mass=mass)
        self.bodies = self.system.bodies
        self.size = float(np.linalg.norm(np.ptp(self.system.p0, axis=0)))
        self.f_gravity = self.system.gravity_force(self.gravity)
        # prescribed vertices and vertex forces; None when there are none (the frame then runs unchanged)
        self.motion = Motion(self.system, forces)
        self.model = Model(self.system, self.dt, self.damping, self.gravity, self.f_gravity,
                           self.project_hessian, self.size, self.motion if self.motion.active else None)
        if linearized:
            self.contact = pgs.make_contact(self.model, colliders, contact)
            self.colliders = [] if self.contact is None else self.contact.colliders
            self.contact_model = "none" if self.contact is None else pgs.MODEL
        else:  # Newton integrators: contact enters the incremental potential (barrier.py or ipc.py)
            if contact is not None and contact is not False and not isinstance(contact, IPC):
                raise ValueError("contact=sa.PGS(...) runs with integrator='linearized'; the Newton integrators "
                                 "take contact=sa.IPC(...) (or None: the frictionless barrier against the colliders, and IPC "
                                 "between several bodies)")
            self.contact = None
            # several bodies touch each other by default: IPC between them (the barrier sees only colliders)
            self._ipc_default = contact is None and len(bodies) > 1
            self._ipc = IPC() if self._ipc_default else contact if isinstance(contact, IPC) else None
        # the other bodies' surfaces, for max_penetration when no contact model measures them
        self._bodies_detector = (Detector(self.system, [], edge_contact=False)
                                 if self.contact is None and len(bodies) > 1 else None)
        if self.contact is not None and isinstance(solver, str) and solver == "auto":
            solver = "direct"
        self.solver = make_solver(solver)
        self.reducer = reducer
        # the settings a checkpoint must match, as built (a budget moves thresholds during the run)
        self._settings = {"reducer_settings": None if reducer is None else checkpoint.settings_of(reducer),
                          "contact_settings": repr(contact)}
        x0 = self.system.p0.copy()
        if self.motion.paths:  # prescribed vertices start on their paths
            idx, xp = self.motion.positions(0.0)
            x0[idx] = xp
        v0 = np.concatenate([b.velocity for b in bodies])
        self.state = State(x0, v0)
        self.stats = Stats()
        active = reducer if reducer is not None else FullSpace(self.solver)
        if self.contact is not None:  # the contacts' Schur complement may come from the frame's own factorisation
            active.use_contact(self.contact.schur, self.contact.bodies)
        active.check_integrator(integrator, self.newton_iters)
        if linearized:
            self.integrator = LinearizedEuler(self.model, active, self.solver, self.contact, self.newton_iters,
                                              self.newton_tol)
        else:
            self.integrator = NewtonIntegrator(self.model, integrator, active, self.solver, None,
                                               tol=self.newton_tol, max_iters=self.newton_iters)
            self.colliders = colliders  # the barrier of the colliders (property setter)
        if self.system.free.size:  # a scene whose vertices all follow paths has nothing to reduce
            active.attach(self.model)
        self.monitor = Monitor(self.system, self.f_gravity, self.size, on_inverted, on_nonconvergence, check_energy,
                               method="full space" if reducer is None else type(reducer).__name__)
        if linearized:  # slivers: the linearized step's round-off on them (a Newton step iterates it away)
            self.monitor.stiffness_ratio = warn_stiff_elements(self.system, self.dt)

    # ------------------------------------------------------------------ public
    @property
    def colliders(self):
        """The static colliders (a list; empty without any).

        Under the Newton integrators they may be replaced between steps: the IPC barrier is
        rebuilt for the new list.
        """
        return self._colliders

    @colliders.setter
    def colliders(self, colliders):
        colliders = check_colliders(colliders)
        if isinstance(getattr(self, "integrator", None), NewtonIntegrator):
            if self._ipc is not None:  # ipctk: bodies against colliders, each other and themselves
                try:
                    self.integrator.barrier = IPCContact(self.model, colliders, self._ipc, x0=self.state.x)
                except ValueError as err:
                    if not self._ipc_default:
                        raise
                    raise ValueError(f"{err}. Several bodies under integrator={self.integrator_name!r} get IPC "
                                     "contact between them by default (contact=None means sa.IPC()); "
                                     "contact=False keeps only the colliders' barrier and lets the bodies "
                                     "pass through each other") from None
                self.contact_model = "ipc"
            else:
                barrier = barrier_of(self.model, colliders)
                if barrier is not None:
                    barrier.check_state(self.state.x)
                self.integrator.barrier = barrier
                self.contact_model = "ipc-barrier" if colliders else "none"
        elif hasattr(self, "_colliders"):
            raise ValueError("the colliders of a simulation with integrator='linearized' are fixed at "
                             "construction (its contact state is built for them)")
        self._colliders = colliders

    def run(self, frames):
        """Advance ``frames`` steps, yielding a copy of the state after each one.

        Each step is a transaction (:meth:`step`): a run that raises or is interrupted (Ctrl-C)
        stops at the last frame it completed, which ``sim.state`` and ``sim.stats`` then hold, and
        ``sim.run`` continues from there as if it had never been stopped.
        """
        frames = integer(frames, "frames", low=0)
        for _ in range(frames):
            self.step()
            yield self.state.copy()

    def step(self):
        """Advance one time step; returns the new state.

        A step is a transaction: whatever it raises (:class:`SimulationDiverged`, an error in a
        user's force or path, a ``KeyboardInterrupt`` from Ctrl-C at any point of it) leaves the
        simulation as it was before it: the state, the statistics and the state of every component
        (the integrator's history, the reducer's clusters, random generator and controllers, the
        contact warm starts, the solver's ordering, the monitor), so that a run continued after it
        equals one that never tried the step. The new state and its statistics record are
        computed first and committed together at the end of the step.
        """
        saved = self._snapshot()
        try:
            state, rec = self._advance()
            self.stats.append(rec)  # the commit (an interrupt between the two is rolled back too)
            self.state = state
        except BaseException:
            self._restore(saved)
            raise
        return state

    def _snapshot(self):
        """What :meth:`_restore` puts back: the state, the statistics (the list and its length) and
        the state of every component (what a checkpoint saves)."""
        return {"state": self.state, "stats": (self.stats, len(self.stats)),
                "components": {name: comp.state_dict() for name, comp in self._components().items()}}

    def _restore(self, saved):
        """Put back a :meth:`_snapshot`; Ctrl-C is held back until it is done (a second interrupt
        would otherwise leave it half restored)."""
        with _interrupts_held():
            stats, n = saved["stats"]
            del stats[n:]
            self.state, self.stats = saved["state"], stats
            for name, comp in self._components().items():
                comp.load_state_dict(saved["components"][name])

    def _advance(self):
        """The next state and its statistics record; it changes the components (the reducer's
        end of frame included) but neither ``self.state`` nor ``self.stats``, which :meth:`step`
        commits."""
        t0, c0 = time.perf_counter(), time.process_time()
        s = self.state
        frame = s.frame + 1
        self._check_state(s, "sim.state")
        if not (np.all(np.isfinite(s.x)) and np.all(np.isfinite(s.v))):
            raise SimulationDiverged(frame)  # e.g. a state set from outside: before contact detection
        rec = {"frame": frame, "contact": 0.0, "contact_model": self.contact_model}
        barrier = self.integrator.barrier
        self.monitor.start(s, barrier)
        try:
            x, v, result = self.integrator.step(s, rec)
        except SolverError as err:
            raise SimulationDiverged(frame, f"linear solve failed ({err})") from err
        except np.linalg.LinAlgError as err:
            raise SimulationDiverged(frame, f"a dense factorisation failed ({err})") from err
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(v))):
            raise SimulationDiverged(frame)
        t1 = time.perf_counter()
        uncorrected = self.integrator.uncorrected
        if uncorrected is not None and self.monitor.check_energy:
            # contact pushed penetrations out through the positions: the energy it moved counts as work
            work = self.monitor.energies(x, v, barrier)[0] - self.monitor.energies(uncorrected, v, barrier)[0]
            rec["contact_work"] = work
            rec["external_work"] = rec.get("external_work", 0.0) + work
        moved = self.integrator.last_motion
        if moved is not None and self.monitor.check_energy:
            # a moving clamp and vertex forces put energy in: their work counts as external work
            work = motion_work(self.system, self.f_gravity, *moved, s.x, s.v, x, v, self.dt)
            rec["motion_work"] = work
            rec["external_work"] = rec.get("external_work", 0.0) + work
        try:
            self.monitor.check(frame, s.x, x, v, rec, barrier)
        except Diverged as err:
            raise SimulationDiverged(frame, str(err)) from None
        if self.contact is not None:  # colliders at x_{t+1}; bodies at the frame's detection (x_t)
            rec["max_penetration"] = max(self.contact.detector.max_penetration(x, bodies=False),
                                         rec.get("body_penetration", 0.0))
        elif self.colliders or self._bodies_detector is not None:
            rec["max_penetration"] = self.max_penetration(x)
        rec["checks"] = time.perf_counter() - t1
        self.monitor.accept()
        state = State(x, v, frame, s.time + self.dt, result.clusters)
        rec["wall"] = time.perf_counter() - t0
        rec["cpu"] = time.process_time() - c0  # the work of every thread of the process: load from elsewhere adds none
        if self.system.free.size:  # a time budget reads the frame's wall time (a reducer with nothing to
            self.integrator.reducer.end_frame(rec)  # solve is not attached)
        return state, rec

    def max_penetration(self, x=None):
        """Largest penetration depth (m, >= 0) of a surface vertex into a collider or another body
        at positions x (default: the current state)."""
        x = self.state.x if x is None else self._positions(x, "x")
        if self.contact is not None:
            return self.contact.detector.max_penetration(x)
        depth = 0.0
        for c in self.colliders:
            d, _ = c.query(x)
            depth = max(depth, float(-d.min(initial=0.0)))
        if self._bodies_detector is not None:
            depth = max(depth, self._bodies_detector.max_penetration(x))
        return depth

    # ------------------------------------------------------------------ checkpoints
    def _components(self):
        """The parts whose state later frames depend on, by checkpoint name."""
        reducer = self.integrator.reducer if self.system.free.size else None  # (attached only with free DOFs)
        comps = {"integrator": self.integrator, "reducer": reducer, "contact": self.contact,
                 "solver": self.solver, "monitor": self.monitor}
        return {k: c for k, c in comps.items() if c is not None and hasattr(c, "state_dict")}

    def _signature(self):
        """What a checkpoint must match to be loaded into this simulation."""
        return {"integrator": self.integrator_name, "reducer": type(self.integrator.reducer).__name__,
                "contact_model": self.contact_model, "n_vertices": int(self.system.n),
                "n_elements": int(self.system.m), "dt": float(self.dt), "mesh": checkpoint.mesh_hash(self.system),
                **checkpoint.setup_signature(self.system), "gravity": self.gravity.tolist(),
                "damping": [self.damping.alpha, self.damping.beta], "mass": self.system.mass_kind,
                "colliders": [repr(c) for c in self.colliders], **self._settings}

    def save(self, path):
        """Write a checkpoint of the run to ``path`` (an ``.npz``; :mod:`skfem_affine.checkpoint`).

        Resume it with :meth:`load_state` on a simulation built with the same arguments: the
        frames after it are then bit-identical to those of an uninterrupted run. Returns the path.
        """
        s = self.state
        comps = {"state": {"x": s.x, "v": s.v, "frame": int(s.frame), "time": float(s.time),
                           "clusters": s.clusters if s.clusters is not None else None}}
        comps.update({k: c.state_dict() for k, c in self._components().items()})
        stats = []
        for r in self.stats:
            rec = {}
            for k, val in r.items():
                try:
                    rec[k] = jsonable(val)
                except TypeError:  # a statistic that is no plain value is not kept
                    pass
            stats.append(rec)
        header = dict(self._signature(), package=skfem_affine.__version__, frame=int(s.frame), stats=stats)
        return checkpoint.write(path, header, comps)

    def load_state(self, path):
        """Resume from a checkpoint written by :meth:`save` of a simulation built the same way.

        Raises
        ------
        ValueError
            The file is no checkpoint, comes from an incompatible format version, does not match
            this simulation (mesh, bodies, materials, density, fixed and prescribed vertices,
            gravity, damping, colliders, integrator, reducer and its settings, contact model and
            settings, time step), or is damaged (the message names the entry). The simulation is
            then left as it was.

        Whatever else it raises, a ``KeyboardInterrupt`` (Ctrl-C) included, the simulation is
        likewise left as it was: its state, statistics and every component.
        """
        header, arrays = checkpoint.read(path)
        checkpoint.check_matches(path, header, self._signature())
        values = header["values"]
        saved = self._snapshot()
        try:
            state = self._loaded_state(checkpoint.unflatten(arrays, values, "state"))
            for name, comp in self._components().items():
                loaded = checkpoint.unflatten(arrays, values, name)
                checkpoint.check_like(name, loaded, saved["components"][name])
                _load_component(name, comp, loaded)
            self.state, self.stats = state, Stats(header["stats"])  # the commit
        except (TypeError, ValueError) as err:
            self._restore(saved)
            raise ValueError(f"checkpoint {path} is damaged: {err}") from None
        except BaseException:  # an interrupt (Ctrl-C) or any other error: nothing half loaded
            self._restore(saved)
            raise
        return self.state

    def _loaded_state(self, st):
        """The State of a checkpoint's ``state.*`` entries, checked (ValueError naming the entry)."""
        for key in ("x", "v", "frame", "time", "clusters"):
            if key not in st:
                raise ValueError(f"state.{key} is missing")
        x = real_array(st["x"], "state.x", shape=(self.system.n, 3))
        v = real_array(st["v"], "state.v", shape=(self.system.n, 3))
        frame = integer(st["frame"], "state.frame", low=0)
        time_ = real(st["time"], "state.time", low=0.0)
        clusters = st["clusters"]
        if clusters is not None:
            clusters = np.asarray(clusters)
            if clusters.shape != (self.system.m,) or clusters.dtype.kind not in "iu":
                raise ValueError(f"state.clusters must be {self.system.m} integers (one per element), got "
                                 f"{clusters.dtype} of shape {clusters.shape}")
        return State(x, v, frame, time_, clusters)

    def energy(self, state=None):
        """Kinetic, strain, gravitational and total energy (J) of a state (default: the current one)."""
        s = self.state if state is None else state
        self._check_state(s, "state")
        vf = s.v.reshape(-1)
        kin = 0.5 * vf @ (self.system.M @ vf)
        strain = self.system.strain_energy(s.x)
        grav = -self.f_gravity @ (s.x - self.system.p0).reshape(-1)
        return {"kinetic": kin, "strain": strain, "gravity": grav, "total": kin + strain + grav}

    def stress(self, state=None):
        """Strains and stresses of a state (default: the current one), per element and at vertices.

        Returns a :class:`~skfem_affine.stress.Stresses`: Green-Lagrange ``strain``, first
        Piola ``piola`` and ``cauchy`` stress tensors (m, 3, 3), ``von_mises`` (m,), ``principal``
        (m, 3, largest first), ``energy_density`` (m,), in Pa (J/m^3 for the energy), each from
        the element's own material; ``.vertex`` holds the volume-weighted averages at the
        vertices. Definitions in :mod:`skfem_affine.stress`.
        """
        s = self.state if state is None else state
        x = getattr(s, "x", s)
        x = real_array(x, "state positions")
        if x.shape != self.state.x.shape:
            raise ValueError(f"state must be a State of this simulation or positions of shape "
                             f"{self.state.x.shape}, got shape {x.shape}")
        return stress.evaluate(self.system, x)

    def to_dofs(self, basis, state=None, field="displacement"):
        """One body's part of a state (default: the current one) as a DOF vector of ``basis``, a
        scikit-fem ``Basis(body.mesh, ElementVector(ElementTetP1()))``; the body is the one whose
        mesh ``basis.mesh`` is. See :meth:`State.dofs` for ``field``."""
        s = self.state if state is None else state
        mesh = getattr(basis, "mesh", None)
        match = [k for k, b in enumerate(self.bodies) if b.mesh is mesh]
        if not match:
            raise ValueError("basis must be built on the mesh of one of the simulation's bodies "
                             "(Basis(body.mesh, ElementVector(ElementTetP1())))")
        k = match[0]
        part = State(self.split(s.x)[k], self.split(s.v)[k], s.frame, s.time)
        return part.dofs(basis, field)

    def split(self, x):
        """Per-body views of a stacked per-vertex array (e.g. ``state.x``)."""
        n = self.system.n
        if not hasattr(x, "shape") or x.ndim < 1 or x.shape[0] != n:
            raise ValueError(f"x must hold one row per vertex ({n}) of the simulation's bodies, got "
                             f"{'shape ' + str(x.shape) if hasattr(x, 'shape') else type(x).__name__}")
        return self.system.split(x)

    def _positions(self, x, name):
        """``x`` as an (n, 3) float array, or an error naming it."""
        return real_array(x, name, shape=(self.system.n, 3), finite=False)

    def _check_state(self, state, name):
        """TypeError/ValueError naming ``name`` unless ``state`` is a State with (n, 3) arrays x and v."""
        if not isinstance(state, State):
            raise TypeError(f"{name} must be a sa.State (e.g. sim.state.copy()), got {type(state).__name__}")
        n = self.system.n
        for key in ("x", "v"):
            a = getattr(state, key)
            if not isinstance(a, np.ndarray) or a.dtype.kind != "f":
                raise TypeError(f"{name}.{key} must be a float array of shape ({n}, 3), got {type(a).__name__}"
                                f"{'' if not isinstance(a, np.ndarray) else ' of ' + str(a.dtype)}")
            if a.shape != (n, 3):
                raise ValueError(f"{name}.{key} must have shape ({n}, 3) (one row per vertex), got shape {a.shape}")

    def linear_system(self, x, v, rec=None, frame=None):
        """A (CSR, free DOFs), b, and the frame's evaluation (eq. 1-2) at state (x, v).

        Returns ``(A, b, data)``; ``data`` is the :class:`~skfem_affine.assembly.FrameData`
        (``data.f`` includes gravity), or the given ``frame`` evaluated at x.
        """
        problem = StepProblem.at(self.model, x, v, data=frame, rec=rec)
        return problem.matrix(), problem.b, problem.data
