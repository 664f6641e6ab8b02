r"""Linearized backward Euler (paper eq. 1-2) and a Newton option; :class:`Simulation`.

One frame solves, on the free DOFs,

.. math::
    A = M - hD - h^2 K, \qquad b = h(f + D\dot x_t + hK\dot x_t), \qquad
    A\,\Delta\dot x = b,

with K = df/dx (negative semi-definite, K = -H) and Rayleigh damping
D = -(alpha M + beta (-K)) = -alpha M - beta H, so that

.. math:: A = (1 + h\alpha) M + (h\beta + h^2) H

is symmetric positive definite whenever H is (element Hessians are projected
to PSD by default). Then v += dv, x += h v (symplectic order, as Algorithm 1).

This single Newton step, taken from x_t, is the paper's integrator. With
``newton_iters > 1`` the step is iterated, with a backtracking line search on
the incremental potential

.. math:: \Phi(v) = \tfrac12 (v - v_t)^T M (v - v_t) + \Psi(x_t + h v) - h f_{ext}^T v
          + \tfrac h2 v^T(\alpha M + \beta H_t) v,

whose minimiser is the converged implicit Euler step (the reference solve).

``integrator="implicit_euler" | "bdf2"`` instead runs the full Newton solve of
:mod:`skfem_affine.newton` on the incremental potential in positions (adaptive-subspace paper,
eq. 1-3), to the tolerance ||d||_inf / h <= newton_tol * size, at most ``newton_iters``
iterations (default 50 there); implicit Euler converges to the same step as ``newton_iters > 1``.
"""
import time
from dataclasses import dataclass, field

import numpy as np

from skfem_affine.contact import pgs as _contact
from skfem_affine.integrators import newton
from skfem_affine.contact.colliders import check_colliders
from skfem_affine.assembly import ElasticSystem
from skfem_affine.body import ElasticBody
from skfem_affine.checks import positive
from skfem_affine.solvers import SolverError, make_solver


class SimulationDiverged(RuntimeError):
    """The state became non-finite (or the linear system stopped being solvable)."""

    def __init__(self, frame, reason="non-finite state detected"):
        self.frame = frame
        super().__init__(f"{reason} at frame {frame}")


@dataclass(frozen=True)
class Rayleigh:
    """Rayleigh damping D = -(alpha M + beta H) with H = -K the stiffness (alpha, beta >= 0)."""

    alpha: float = 0.0
    beta: float = 0.0

    def __post_init__(self):
        for name in ("alpha", "beta"):
            val = getattr(self, name)
            if not np.isfinite(val) or val < 0:
                raise ValueError(f"Rayleigh {name} must be finite and >= 0, got {val}")


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


class Stats(list):
    """Per-frame records (dicts): wall time of each phase in seconds, DOFs solved, solver."""

    PHASES = ("assembly", "prediction", "clustering", "map_assembly", "reduced_assembly",
              "factorization", "solve", "line_search", "contact")

    def total(self, key):
        return float(sum(r.get(key, 0.0) for r in self))

    def mean(self, key):
        return self.total(key) / max(len(self), 1)

    def phase_totals(self):
        return {k: self.total(k) for k in self.PHASES if any(k in r for r in self)}

    def summary(self):
        wall = self.total("wall")
        return {"frames": len(self), "wall_s": wall, "frames_per_s": len(self) / wall if wall else float("inf"),
                "mean_dofs": self.mean("dofs"), **{f"{k}_s": v for k, v in self.phase_totals().items()}}


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
    reducer : object, optional
        Adaptive model reduction (e.g. affinification); None solves in full space.
    solver : str or solver object
        See :mod:`skfem_affine.solvers`; default ``"auto"``.
    integrator : {"linearized", "implicit_euler", "bdf2"}
        "linearized" (default) is the affinification paper's linearized backward Euler,
        iterated by ``newton_iters``; the others minimise the incremental potential by
        Newton (:mod:`skfem_affine.newton`), as the adaptive-subspace reducer needs.
    newton_iters : int
        Linearized: 1 (default) is the paper's step; more iterates Newton with a line search
        to a converged implicit Euler step. Other integrators: the iteration cap (default 50).
    newton_tol : float
        Linearized: Newton stops when the largest position change of an iteration is below
        ``newton_tol`` times the scene size (default 1e-9). Other integrators:
        ||d||_inf / h <= newton_tol times the scene size (default 1e-6, 1/s).
    project_hessian : bool
        Project element Hessians to PSD (default True) so that A is SPD.
    mass : {"lumped", "consistent"}
    colliders : list of colliders, optional
        Static obstacles (:mod:`skfem_affine.colliders`: ``sa.Plane``, ``sa.Sphere``, ...).
    contact : PGS, optional
        Contact solver settings (:class:`skfem_affine.contact.PGS`); the default ``PGS()``
        is used when there are colliders or several bodies. ``False`` turns contact off.
        Without colliders and with a single body no contact code runs. With contact, the
        ``"auto"`` solver means the direct solver: the Delassus operator needs A^-1 on
        many columns.
    """

    def __init__(self, bodies, dt=0.01, gravity=(0.0, 0.0, 0.0), damping=None, reducer=None,
                 solver="auto", newton_iters=None, newton_tol=None, project_hessian=True, mass="lumped",
                 colliders=None, contact=None, integrator="linearized"):
        bodies = [bodies] if isinstance(bodies, ElasticBody) else list(bodies)
        if not bodies or not all(isinstance(b, ElasticBody) for b in bodies):
            raise TypeError("Simulation needs an ElasticBody or a non-empty list of them")
        self.dt = positive(dt, "time step dt")
        self.gravity = np.asarray(gravity, dtype=float)
        if self.gravity.shape != (3,) or not np.all(np.isfinite(self.gravity)):
            raise ValueError(f"gravity must be a finite 3-vector, got {gravity!r}")
        if damping is not None and not isinstance(damping, Rayleigh):
            raise TypeError("damping must be a Rayleigh(alpha, beta) or None")
        self.damping = damping or Rayleigh()
        linearized = integrator in ("linearized", None)
        newton_iters = (1 if linearized else 50) if newton_iters is None else newton_iters
        newton_tol = (1e-9 if linearized else 1e-6) if newton_tol is None else newton_tol
        if int(newton_iters) < 1:
            raise ValueError(f"newton_iters must be >= 1, got {newton_iters}")
        self.newton_iters = int(newton_iters)
        self.newton_tol = positive(newton_tol, "newton_tol")
        self.project_hessian = bool(project_hessian)
        self.system = ElasticSystem(bodies, mass=mass)
        self.bodies = self.system.bodies
        if linearized:
            self.contact = _contact.make_contact(self, colliders, contact)
            self.colliders = [] if self.contact is None else self.contact.colliders
        else:  # Newton integrators: colliders enter the incremental potential as an IPC barrier (barrier.py)
            if contact not in (None, False):
                raise ValueError("PGS contact runs with integrator='linearized'; the Newton integrators "
                                 "use the IPC barrier against the colliders")
            self.contact, self.colliders = None, check_colliders(colliders)
        if self.contact is not None and isinstance(solver, str) and solver == "auto":
            solver = "direct"
        self.solver = make_solver(solver)
        if reducer is not None and not (hasattr(reducer, "attach") and hasattr(reducer, "solve")):
            raise TypeError(f"reducer must be None or a reducer such as sa.Affinification(...), "
                            f"got {type(reducer).__name__}")
        self.reducer = reducer
        self.stepper = None if linearized else newton.TimeStepper(self, integrator, self.newton_iters,
                                                                  self.newton_tol)
        self.size = float(np.linalg.norm(np.ptp(self.system.p0, axis=0)))
        self.f_gravity = self.system.gravity_force(self.gravity)
        x0 = self.system.p0.copy()
        v0 = np.concatenate([b.velocity for b in bodies])
        self.state = State(x0, v0)
        self.stats = Stats()
        if reducer is not None:
            reducer.attach(self)

    # ------------------------------------------------------------------ public
    def run(self, frames):
        """Advance ``frames`` steps, yielding a copy of the state after each one."""
        frames = int(frames)
        if frames < 0:
            raise ValueError(f"frames must be >= 0, got {frames}")
        for _ in range(frames):
            self.step()
            yield self.state.copy()

    def step(self):
        """Advance one time step; returns the new state."""
        t0 = time.perf_counter()
        rec = {"frame": self.state.frame + 1, "contact": 0.0}
        s = self.state
        try:
            if self.stepper is not None:  # Newton on the incremental potential (newton.py)
                x, v = self.stepper.step(rec)
            else:
                if self.contact is not None:
                    self.contact.detect(self, rec)  # Algorithm 1: find contacts at x_t
                dv = self._linear_step(rec) if self.newton_iters == 1 else self._newton_step(rec)
                if self.contact is not None:  # Algorithm 1: PGS contact solve with the frame's factorization
                    dv = dv + self.contact.resolve(self, dv, self._resolvent(), rec)
        except SolverError as err:
            raise SimulationDiverged(self.state.frame + 1, f"linear solve failed ({err})") from err
        if self.stepper is None:
            v = s.v.copy()
            v.reshape(-1)[self.system.free] += dv
            integrate = getattr(self.reducer, "integrate", None)
            x = integrate(self, s.x, v) if integrate else s.x + self.dt * v
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(v))):
            raise SimulationDiverged(s.frame + 1)
        self.state = State(x, v, s.frame + 1, s.time + self.dt, rec.pop("clusters", None))
        rec["wall"] = time.perf_counter() - t0
        self.stats.append(rec)
        return self.state

    def contact_impulse(self):
        """Contact impulses J^T lambda (free DOFs) that the oracle's prediction takes as explicit
        forces (sec. 3.4): warm-started, and estimated for new contacts; 0 without contact."""
        return 0.0 if self.contact is None else self.contact.prediction_impulse()

    def _resolvent(self):
        """A^-1 on columns with this frame's factorization, through the reducer's G (sec. 3.3)."""
        red, c = self.reducer, self.contact
        if red is None:
            return _contact.Resolvent(self.solver, self.last_matrix, block=c.settings.block, cache=c.block_solvers)
        if not all(hasattr(red, k) for k in ("G", "Ar", "solver")):
            raise TypeError(f"contact needs the reducer's frame mapping G, reduced matrix Ar and its factorised "
                            f"solver; {type(red).__name__} does not expose them")
        return _contact.Resolvent(red.solver, red.Ar, red.G, block=c.settings.block, cache=c.block_solvers)

    def energy(self, state=None):
        """Kinetic, strain, gravitational and total energy (J) of a state."""
        s = state or self.state
        vf = s.v.reshape(-1)
        kin = 0.5 * vf @ (self.system.M @ vf)
        strain = self.system.strain_energy(s.x)
        grav = -self.f_gravity @ (s.x - self.system.p0).reshape(-1)
        return {"kinetic": kin, "strain": strain, "gravity": grav, "total": kin + strain + grav}

    def split(self, x):
        """Per-body views of a stacked per-vertex array (e.g. ``state.x``)."""
        return self.system.split(x)

    # ------------------------------------------------------------------ internals
    def linear_system(self, x, v, rec=None, frame=None):
        """A (CSR, free DOFs), b, and the frame's evaluation (eq. 1-2) at state (x, v).

        Returns ``(A, b, data)``; ``data`` is the :class:`~skfem_affine.assembly.FrameData`
        with ``data.f`` including gravity and ``data.Hmat`` the stiffness matrix.
        """
        t0 = time.perf_counter()
        sysm = self.system
        data = frame if frame is not None else sysm.evaluate(x, project=self.project_hessian)
        data.f = data.f + self.f_gravity
        data.Hmat = sysm.pattern.matrix(data.H)
        A, b = self.system_matrix(data.H), self.rhs(data.f, data.Hmat, v)
        if rec is not None:
            rec["assembly"] = rec.get("assembly", 0.0) + time.perf_counter() - t0
        return A, b, data

    def system_matrix(self, H):
        """A = (1 + h alpha) M + (h beta + h^2) H on the free DOFs (eq. 1)."""
        h, d = self.dt, self.damping
        return self.system.pattern.matrix((1.0 + h * d.alpha) * self.system.mass_data + (h * d.beta + h * h) * H)

    def rhs(self, f, Hmat, v):
        """b = h (f - alpha M v - (beta + h) H v) on the free DOFs (eq. 2); f includes gravity."""
        h, d, free = self.dt, self.damping, self.system.free
        vf = v.reshape(-1)[free]
        return h * (f[free] - d.alpha * (self.system.Mff @ vf) - (d.beta + h) * (Hmat @ vf))

    def solve(self, A, b, rec):
        """Factorize and solve A dv = b in full space with the configured solver."""
        t0 = time.perf_counter()
        self.solver.factorize(A)
        self.last_matrix = A
        t1 = time.perf_counter()
        dv = self.solver.solve(b)
        t2 = time.perf_counter()
        rec["factorization"] = rec.get("factorization", 0.0) + t1 - t0
        rec["solve"] = rec.get("solve", 0.0) + t2 - t1
        rec["dofs"] = A.shape[0]
        rec["solver"] = self.solver.name
        rec["iterations"] = rec.get("iterations", 0) + self.solver.last_iterations
        return dv

    def _linear_step(self, rec):
        s = self.state
        if self.reducer is not None:
            return self.reducer.solve(self, rec)
        A, b, _ = self.linear_system(s.x, s.v, rec)
        return self.solve(A, b, rec)

    def _potential(self, v, H0):
        """Incremental potential Phi(v) (see module docstring); v on free DOFs."""
        sysm, h, d = self.system, self.dt, self.damping
        s = self.state
        x = s.x.copy()
        x.reshape(-1)[sysm.free] += h * v
        dv = v - s.v.reshape(-1)[sysm.free]
        fg = self.f_gravity[sysm.free]
        return (0.5 * dv @ (sysm.Mff @ dv) + sysm.strain_energy(x) - h * fg @ v
                + 0.5 * h * v @ (d.alpha * (sysm.Mff @ v) + d.beta * (H0 @ v)))

    def _newton_step(self, rec):
        """Newton on Phi from v = 0 (x = x_t): the first iterate is the linear step."""
        sysm, h, d = self.system, self.dt, self.damping
        s = self.state
        free = sysm.free
        vt = s.v.reshape(-1)[free]
        v = np.zeros_like(vt)
        H0 = None
        phi = None
        for it in range(self.newton_iters):
            x = s.x.copy()
            x.reshape(-1)[free] += h * v
            t0 = time.perf_counter()
            f, H = sysm.forces_and_stiffness(x, project=self.project_hessian)
            f += self.f_gravity
            if H0 is None:
                H0data, H0 = H, sysm.pattern.matrix(H)
            grad = sysm.Mff @ (v - vt) - h * f[free] + h * (d.alpha * (sysm.Mff @ v) + d.beta * (H0 @ v))
            A = sysm.pattern.matrix((1.0 + h * d.alpha) * sysm.mass_data + h * h * H + h * d.beta * H0data)
            rec["assembly"] = rec.get("assembly", 0.0) + time.perf_counter() - t0
            step = self.solve(A, -grad, rec)
            phi = self._potential(v, H0) if phi is None else phi
            alpha = 1.0
            slope = grad @ step
            while True:
                trial = v + alpha * step
                phi_trial = self._potential(trial, H0)
                if phi_trial <= phi + 1e-4 * alpha * slope or alpha < 1e-6:
                    break
                alpha *= 0.5
            v, phi = trial, phi_trial
            rec["newton_iters"] = it + 1
            if h * alpha * np.abs(step).max() <= self.newton_tol * self.size:
                break
        return v - vt
