r"""Linearized backward Euler (affinification paper eq. 1-2, Algorithm 1), optionally iterated.

One frame: find contacts at x_t, build the :class:`~skfem_affine.integrators.problem.StepProblem`
(f and H at x_t), let the reducer solve it, resolve contact with the reducer's factorised
operator, then v += dv and x = x + h v (or the mapping's own update of positions and velocities).

With ``newton_iters > 1`` (full space only) the step is iterated, with a backtracking line
search on the incremental potential

.. math:: \Phi(v) = \tfrac12 (v - v_t)^T M (v - v_t) + \Psi(x_t + h v) - h f_{ext}^T v
          + \tfrac h2 v^T(\alpha M + \beta H_t) v,

whose minimiser is the converged implicit Euler step (the reference solve); its first
iterate is the linearized step.
"""
import numpy as np

from skfem_affine.integrators.newton import linearized_newton
from skfem_affine.integrators.problem import Operator, StepProblem, StepResult, merge_stats


class LinearizedEuler:
    """The linearized backward Euler integrator.

    Parameters
    ----------
    model : Model
    reducer : Reducer
        Solves each frame (:class:`~skfem_affine.reducers.full.FullSpace` for no reduction).
    solver : solver object
        The full-space solver of the ``newton_iters > 1`` iteration.
    contact : skfem_affine.contact.pgs.Contact or None
    newton_iters : int
        1: the paper's single step; more: Newton on Phi to a converged implicit Euler step.
    newton_tol : float
        Newton stops when the largest position change of an iteration is below ``newton_tol``
        times the scene size.
    """

    name = "linearized"
    barrier = None  # contact is PGS after the solve, not a barrier in a potential
    uncorrected = None  # x_{t+1} before contact's split-impulse correction (set by each step with one)
    last_motion = None  # the step's prescribed targets and vertex forces (for the energy check)

    def __init__(self, model, reducer, solver, contact=None, newton_iters=1, newton_tol=1e-9):
        self.model, self.reducer, self.solver, self.contact = model, reducer, solver, contact
        self.newton_iters, self.newton_tol = int(newton_iters), float(newton_tol)

    def step(self, state, rec):
        """One frame from ``state``; returns (x, v, result) with x, v (n, 3) at t + 1."""
        model, contact = self.model, self.contact
        free = model.system.free
        contacts, impulse, support = None, 0.0, 0.0
        motion, self.last_motion = {}, None
        if getattr(model, "motion", None) is not None and model.motion.active:  # the frame's prescribed positions and forces
            motion = dict(targets=model.motion.targets(state.time + model.dt, state.x, model.dt),
                          f_ext=model.motion.force(state.time, state.x, state.v))
            self.last_motion = (motion["targets"], motion["f_ext"])  # for the simulation's energy check
        if contact is not None:  # Algorithm 1: find contacts at x_t, within reach of the step's forces too
            contacts = contact.detect(model, state.x, state.v, rec, f_ext=motion.get("f_ext"))
            impulse = contact.prediction_impulse()
            support = contact.support_impulse()
        if not free.size:  # every vertex fixed or prescribed: nothing to solve
            problem = StepProblem(model, state.x, state.v, state.frame + 1, None, None, impulse, contacts,
                                  support_impulse=support, **motion)
            result = StepResult(dv=np.zeros(0))
        elif self.newton_iters == 1:
            problem = StepProblem.at(model, state.x, state.v, state.frame + 1, rec=rec,
                                     contact_impulse=impulse, contacts=contacts, support_impulse=support, **motion)
            result = self.reducer.solve(problem)
        else:
            problem = StepProblem(model, state.x, state.v, state.frame + 1, None, None, impulse, contacts,
                                  support_impulse=support, **motion)
            result = self._newton(state, problem)
        merge_stats(rec, result.stats)
        dv = result.dv
        if contact is not None:  # Algorithm 1: PGS contact solve with the frame's factorization
            dv = dv + contact.resolve(problem, result, rec)
        v = state.v.copy()
        v.reshape(-1)[free] += dv
        targets = problem.targets
        if targets is not None:
            v[targets.vertices] = targets.v
        self.uncorrected = None
        correction = None if contact is None else contact.correction
        if correction is not None:  # contact's split impulse: penetrations move out through x only
            self.uncorrected = self._positions(result, state.x, v, targets)
            w = v.copy()
            w.reshape(-1)[free] += correction
            x_new = self._positions(result, state.x, w, targets)
        else:
            x_new = self._positions(result, state.x, v, targets)
        return x_new, result.velocities(state.x, v, x_new), result

    def _positions(self, result, x, v, targets):
        """x_{t+1}: the reducer's position update, and prescribed vertices exactly on their path."""
        x_new = result.positions(x, v, self.model.dt)
        if targets is not None:
            x_new[targets.vertices] = targets.x
        return x_new

    # ------------------------------------------------------------------ newton_iters > 1
    def _newton(self, state, problem):
        """Newton to the converged implicit Euler step (the one Newton loop of
        :func:`skfem_affine.integrators.newton.linearized_newton`); its first iterate is the linearized step."""
        stats = {}
        dv, A = linearized_newton(self.model, state.x, state.v, self.solver, self.newton_tol, self.newton_iters,
                                  stats, targets=problem.targets, f_ext=problem.f_ext)
        return StepResult(dv=dv, operator=Operator(self.solver, A), stats=stats)
