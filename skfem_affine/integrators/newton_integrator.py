"""The Newton integrators: implicit Euler and BDF2 on the incremental potential (eq. 1-3).

One step builds the :class:`~skfem_affine.integrators.potential.IncrementalPotential` of the
state (BDF2 from the second step on, with the state before), hands it to the reducer (which runs
:func:`skfem_affine.integrators.newton.newton` with its direction) or, without a reducer, to the
full-space :func:`~skfem_affine.integrators.newton.newton_solve`, and returns the new positions
and the scheme's velocities. Contact is the IPC barrier in the potential
(:mod:`skfem_affine.contact.barrier`).
"""
import time
import types

from skfem_affine.integrators._contract_stub import StepResult
from skfem_affine.integrators.newton import newton_solve, resolve_newton_settings
from skfem_affine.integrators.potential import SCHEMES, IncrementalPotential
from skfem_affine.contact.barrier import barrier_of

# timings that add up when a reducer's statistics are merged into the frame's record
_PHASES = ("assembly", "prediction", "clustering", "map_assembly", "reduced_assembly",
           "factorization", "solve", "line_search", "contact")


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

    BDF2 needs the state before the current one: the integrator keeps (x_{t-1}, v_{t-1}) of the
    state it last stepped from, and a state that does not follow it (the first one, or one
    changed from outside) starts with an implicit Euler step.
    """

    def __init__(self, model, scheme, reducer, solver, barrier, tol=1e-6, max_iters=50):
        if scheme not in SCHEMES:
            raise ValueError(f"integrator must be 'linearized' or one of {SCHEMES}, got {scheme!r}")
        self.model, self.scheme, self.reducer, self.solver, self.barrier = model, scheme, reducer, solver, barrier
        self.tol, self.max_iters = tol, max_iters
        self.history = None  # (frame, x_prev, v_prev)

    def potential(self, state):
        """The :class:`IncrementalPotential` of one step from ``state``."""
        prev = (None, None)
        if self.scheme == "bdf2" and self.history is not None and self.history[0] == state.frame - 1:
            prev = self.history[1:]
        return IncrementalPotential(self.model, state.x, state.v, *prev, barrier=self.barrier,
                                    tol=self.tol, max_iters=self.max_iters)

    def step(self, state, rec):
        """One step from ``state``; returns ``(x, v, result)`` with (n, 3) arrays and the StepResult."""
        t0 = time.perf_counter()
        problem = self.potential(state)
        rec["assembly"] = rec.get("assembly", 0.0) + time.perf_counter() - t0
        rec["integrator"] = problem.scheme
        if self.reducer is None:
            stats = {}
            x, _ = newton_solve(problem, self.solver, stats)
            result = StepResult(x=x, stats=stats)
        else:
            result = self.reducer.solve(problem)
        for key, val in result.stats.items():
            rec[key] = rec.get(key, 0.0) + val if key in _PHASES else val
        v = problem.velocity(result.x)  # zero on fixed DOFs, which stay at x_t
        self.history = (state.frame, state.x.copy(), state.v.copy())
        return result.x.reshape(-1, 3), v.reshape(-1, 3), result


class TimeStepper:
    """Adapter of the current :class:`~skfem_affine.Simulation` to :class:`NewtonIntegrator`.

    TEMPORARY (issue #11): simulation.py builds ``newton.TimeStepper(sim, integrator, newton_iters,
    newton_tol)`` before its scene size and reducer exist; this adapter builds the integrator on
    the first step and rebuilds the barrier when ``sim.colliders`` changes. It goes when
    simulation.py builds the Model, the barrier and a NewtonIntegrator itself.
    """

    def __init__(self, sim, scheme, max_iters, tol):
        if scheme not in SCHEMES:
            raise ValueError(f"integrator must be 'linearized' or one of {SCHEMES}, got {scheme!r}")
        if sim.reducer is not None and scheme not in getattr(type(sim.reducer), "integrators", ("linearized",)):
            raise ValueError(f"{type(sim.reducer).__name__} runs with integrator='linearized'; "
                             f"integrator={scheme!r} needs a reducer such as AdaptiveSubspace")
        # as before the one-place rule: a reducer's own Newton settings (or defaults) win
        red_tol, red_iters = resolve_newton_settings(None, None, sim.reducer)
        self.sim, self.scheme = sim, scheme
        self.tol = float(tol) if red_tol is None else red_tol
        self.max_iters = int(max_iters) if red_iters is None else red_iters
        self.integrator, self._colliders = None, None

    def _model(self):
        sim = self.sim
        return types.SimpleNamespace(system=sim.system, dt=sim.dt, damping=sim.damping, gravity=sim.gravity,
                                     f_gravity=sim.f_gravity, project_hessian=sim.project_hessian, size=sim.size)

    def _current(self):
        sim = self.sim
        if self.integrator is None:
            self.integrator = NewtonIntegrator(self._model(), self.scheme, sim.reducer, sim.solver, None,
                                               self.tol, self.max_iters)
        colliders = tuple(getattr(sim, "colliders", None) or ())
        if self._colliders is None or tuple(map(id, colliders)) != tuple(map(id, self._colliders)):
            self.integrator.barrier, self._colliders = barrier_of(self.integrator.model, colliders), colliders
        return self.integrator

    @property
    def contact(self):
        """The barrier of the current colliders, or None."""
        return self._current().barrier

    def potential(self):
        return self._current().potential(self.sim.state)

    def step(self, rec):
        x, v, _ = self._current().step(self.sim.state, rec)
        return x, v

