"""The Newton integrators: implicit Euler and BDF2 on the incremental potential (eq. 1-3).

One step builds the :class:`~skfem_affine.integrators.potential.IncrementalPotential` of the
state (BDF2 from the second step on, with the state before), hands it to the reducer (which runs
:func:`skfem_affine.integrators.newton.newton` with its direction) or, without a reducer, to the
full-space :func:`~skfem_affine.integrators.newton.newton_solve`, and returns the new positions
and the scheme's velocities. Contact is the IPC barrier in the potential
(:mod:`skfem_affine.contact.barrier`).
"""
import time

import numpy as np

from skfem_affine.checks import flag, integer
from skfem_affine.integrators.newton import newton_solve
from skfem_affine.integrators.potential import SCHEMES, IncrementalPotential
from skfem_affine.integrators.problem import StepResult, merge_stats


class NewtonIntegrator:
    """Implicit Euler or BDF2 steps by Newton on the incremental potential.

    Parameters
    ----------
    model : Model
        The run's fixed data (``system``, ``dt``, ``damping``, ``f_gravity``, ``size``,
        ``project_hessian``).
    scheme : {"implicit_euler", "bdf2"}
    reducer : Reducer or None
        ``reducer.solve(potential) -> StepResult`` with ``x`` set; None: full-space Newton.
    solver : solver of :mod:`skfem_affine.solvers`
        The full-space Newton solve's linear solver (unused with a reducer).
    barrier : Barrier or None
        The colliders' IPC barrier (:func:`skfem_affine.contact.barrier.barrier_of`).
    tol, max_iters : float, int
        The Newton settings (the Simulation's ``newton_tol``, ``newton_iters``).

    Notes
    -----
    BDF2 needs the state before the current one: the integrator keeps (x_{t-1}, v_{t-1}) of the
    state it last stepped from, and a state that does not follow it (the first one, or one
    changed from outside) starts with an implicit Euler step.
    """

    uncorrected = None  # positions are never corrected after the solve (contact is in the potential)
    last_motion = None  # the step's prescribed targets and vertex forces (for the energy check)
    #: Lagged friction (IPC contact, full space): the step is solved again with the normal forces of
    #: its solution while they differ by more than FRICTION_TOL (relative) from those it used, at
    #: most FRICTION_ITERATIONS times.
    FRICTION_TOL = 0.05
    FRICTION_ITERATIONS = 4

    def __init__(self, model, scheme, reducer, solver, barrier, tol=1e-6, max_iters=50):
        if scheme not in SCHEMES:
            raise ValueError(f"integrator must be 'linearized' or one of {SCHEMES}, got {scheme!r}")
        self.model, self.scheme, self.reducer, self.solver, self.barrier = model, scheme, reducer, solver, barrier
        self.tol, self.max_iters = tol, max_iters
        self.history = None  # (frame, x_prev, v_prev)

    def state_dict(self):
        """BDF2's history: the state the last step started from."""
        if self.history is None:
            return {"history": False}
        frame, x, v = self.history
        return {"history": True, "frame": int(frame), "x_prev": x.copy(), "v_prev": v.copy()}

    def load_state_dict(self, state):
        if not flag(state["history"], "history"):
            self.history = None
            return
        shape = (self.model.system.n, 3)
        for key in ("x_prev", "v_prev"):
            if np.shape(state[key]) != shape:
                raise ValueError(f"{key} must have shape {shape}, got {np.shape(state[key])}")
        frame = integer(state["frame"], "frame", low=0)
        self.history = (frame, np.array(state["x_prev"], float), np.array(state["v_prev"], float))

    def potential(self, state):
        """The :class:`IncrementalPotential` of one step from ``state``."""
        prev = (None, None)
        if self.scheme == "bdf2" and self.history is not None and self.history[0] == state.frame - 1:
            prev = self.history[1:]
        motion, extra = getattr(self.model, "motion", None), {}
        self.last_motion = None
        if motion is not None and motion.active:  # the step's prescribed positions and vertex forces
            extra = dict(targets=motion.targets(state.time + self.model.dt, state.x, self.model.dt),
                         f_ext=motion.force(state.time, state.x, state.v))
            self.last_motion = (extra["targets"], extra["f_ext"])  # for the simulation's energy check
        return IncrementalPotential(self.model, state.x, state.v, *prev, barrier=self.barrier,
                                    tol=self.tol, max_iters=self.max_iters, **extra)

    def step(self, state, rec):
        """One step from ``state``; returns ``(x, v, result)`` with (n, 3) arrays and the StepResult."""
        t0 = time.perf_counter()
        problem = self.potential(state)
        if hasattr(self.barrier, "begin_step"):  # lagged friction of the step (IPCContact)
            self.barrier.begin_step(problem.x_t, problem.x_hat, problem.c)
        rec["assembly"] = rec.get("assembly", 0.0) + time.perf_counter() - t0
        rec["integrator"] = problem.scheme
        if not self.model.system.free.size:  # every vertex fixed or prescribed: nothing to solve
            result = StepResult(x=problem.x_start.copy())
        elif self.reducer is None:
            stats = {}
            x, _ = newton_solve(problem, self.solver, stats)
            result = StepResult(x=x, stats=stats)
        else:
            result = self.reducer.solve(problem)
        relag = getattr(self.barrier, "relag", None)
        if relag is not None and (self.reducer is None or self.reducer.name == "full"):
            for _ in range(self.FRICTION_ITERATIONS):
                # lagged friction: its normal forces from the solution, while they differ from those used
                if relag(result.x) <= self.FRICTION_TOL:
                    break
                stats = result.stats
                x, _ = newton_solve(problem, self.solver, stats)
                stats["friction_iterations"] = stats.get("friction_iterations", 0) + 1
                result = StepResult(x=x, stats=stats)
        merge_stats(rec, result.stats)
        v = problem.velocity(result.x)  # zero on fixed DOFs, which stay at x_t; the path's on prescribed ones
        self.history = (state.frame, state.x.copy(), state.v.copy())
        return result.x.reshape(-1, 3), v.reshape(-1, 3), result

