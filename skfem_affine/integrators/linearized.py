r"""Linearized backward Euler (affinification paper eq. 1-2, Algorithm 1), optionally iterated.

One frame: find contacts at x_t, build the :class:`~skfem_affine.integrators.problem.StepProblem`
(f and H at x_t), let the reducer solve it, resolve contact with the reducer's factorised
operator, then v += dv and x = x + h v (or the mapping's own position update).

With ``newton_iters > 1`` (full space only) the step is iterated, with a backtracking line
search on the incremental potential

.. math:: \Phi(v) = \tfrac12 (v - v_t)^T M (v - v_t) + \Psi(x_t + h v) - h f_{ext}^T v
          + \tfrac h2 v^T(\alpha M + \beta H_t) v,

whose minimiser is the converged implicit Euler step (the reference solve); its first
iterate is the linearized step.
"""
import time

import numpy as np

from skfem_affine.integrators.problem import Operator, StepProblem, StepResult, merge_stats
from skfem_affine.reducers.full import factorize_and_solve


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

    def __init__(self, model, reducer, solver, contact=None, newton_iters=1, newton_tol=1e-9):
        self.model, self.reducer, self.solver, self.contact = model, reducer, solver, contact
        self.newton_iters, self.newton_tol = int(newton_iters), float(newton_tol)

    def step(self, state, rec):
        """One frame from ``state``; returns (x, v, result) with x, v (n, 3) at t + 1."""
        model, contact = self.model, self.contact
        free = model.system.free
        contacts, impulse = None, 0.0
        if contact is not None:  # Algorithm 1: find contacts at x_t
            contacts = contact.detect(model, state.x, state.v, rec)
            impulse = contact.prediction_impulse()
        if self.newton_iters == 1:
            problem = StepProblem.at(model, state.x, state.v, state.frame + 1, rec=rec,
                                     contact_impulse=impulse, contacts=contacts)
            result = self.reducer.solve(problem)
        else:
            problem = StepProblem(model, state.x, state.v, state.frame + 1, None, None, impulse, contacts)
            result = self._newton(state)
        merge_stats(rec, result.stats)
        dv = result.dv
        if contact is not None:  # Algorithm 1: PGS contact solve with the frame's factorization
            dv = dv + contact.resolve(problem, result, rec)
        v = state.v.copy()
        v.reshape(-1)[free] += dv
        return result.positions(state.x, v, model.dt), v, result

    # ------------------------------------------------------------------ newton_iters > 1
    def _potential(self, state, v, H0):
        """Incremental potential Phi(v) (module docstring); v on free DOFs."""
        m = self.model
        sysm, h, d = m.system, m.dt, m.damping
        x = state.x.copy()
        x.reshape(-1)[sysm.free] += h * v
        dv = v - state.v.reshape(-1)[sysm.free]
        fg = m.f_gravity[sysm.free]
        return (0.5 * dv @ (sysm.Mff @ dv) + sysm.strain_energy(x) - h * fg @ v
                + 0.5 * h * v @ (d.alpha * (sysm.Mff @ v) + d.beta * (H0 @ v)))

    def _newton(self, state):
        """Newton on Phi from v = 0 (x = x_t): the first iterate is the linearized step."""
        m = self.model
        sysm, h, d = m.system, m.dt, m.damping
        cm, _ = m.coefficients
        stats = {}
        free = sysm.free
        vt = state.v.reshape(-1)[free]
        v = np.zeros_like(vt)
        H0 = None
        phi = None
        for it in range(self.newton_iters):
            x = state.x.copy()
            x.reshape(-1)[free] += h * v
            t0 = time.perf_counter()
            f, H = sysm.forces_and_stiffness(x, project=m.project_hessian)
            f += m.f_gravity
            if H0 is None:
                H0data, H0 = H, sysm.pattern.matrix(H)
            grad = sysm.Mff @ (v - vt) - h * f[free] + h * (d.alpha * (sysm.Mff @ v) + d.beta * (H0 @ v))
            # the Hessian of Phi: c_M M + h^2 H(x) + h beta H_t (damping lagged at x_t)
            A = sysm.pattern.matrix(cm * sysm.mass_data + h * h * H + h * d.beta * H0data)
            stats["assembly"] = stats.get("assembly", 0.0) + time.perf_counter() - t0
            step = factorize_and_solve(self.solver, A, -grad, stats)
            phi = self._potential(state, v, H0) if phi is None else phi
            alpha = 1.0
            slope = grad @ step
            while True:
                trial = v + alpha * step
                phi_trial = self._potential(state, trial, H0)
                if phi_trial <= phi + 1e-4 * alpha * slope or alpha < 1e-6:
                    break
                alpha *= 0.5
            v, phi = trial, phi_trial
            stats["newton_iters"] = it + 1
            if h * alpha * np.abs(step).max() <= self.newton_tol * m.size:
                break
        return StepResult(dv=v - vt, operator=Operator(self.solver, A), stats=stats)
