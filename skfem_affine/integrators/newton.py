r"""The one Newton loop with a backtracking line search, and its full-space uses.

:func:`newton` minimises an :class:`~skfem_affine.integrators.potential.IncrementalPotential`
E from x_t. Each iteration at x evaluates the elastic energy, takes the gradient g = grad E(x),
asks a ``direction`` for the step d on the free DOFs, and takes the backtracking (Armijo) line
search on E(x + alpha d); it stops when :math:`\|d\|_\infty / h \le` ``tol`` times the scene
size (the criterion of Li et al., scaled by the bounding-box diagonal as in IPC), when the line
search finds no decrease, or after ``max_iters`` iterations. Every Newton user runs this loop and
differs only in its direction:

* :func:`newton_solve`: full space, :math:`d = -\nabla^2E^{-1}\nabla E` by a direct solve
  (element Hessians projected to PSD); the Newton integrators without a reducer;
* :func:`linearized_newton`: the same on the implicit-Euler potential, for the linearized
  integrator's ``newton_iters > 1`` option (its first iterate is the linearized step);
* :class:`~skfem_affine.reducers.subspace.reducer.AdaptiveSubspace`: the step of the adaptive
  space (modes plus enriched nodes) with its oracle.

Newton starts from :math:`x_t`, so with the full-space direction its first iterate is the
linearized backward Euler step.
"""
import time

import numpy as np

from skfem_affine.checks import positive
from skfem_affine.solvers import SolverError, factorize_and_solve
from skfem_affine.integrators.potential import SCHEMES, IncrementalPotential, vdot  # noqa: F401 (re-exported)


def line_search(problem, x, d, g, e0=None, c1=1e-4, min_step=1e-10):
    """Backtracking (Armijo) line search on E(x + alpha d); returns ``(alpha, E(x + alpha d))``.

    Starts from the largest step that keeps vertices off the colliders (at most 1).
    ``alpha = 0`` when no decrease is found above ``min_step`` (d is then no descent direction
    at round-off level).
    """
    e0 = problem.energy(x) if e0 is None else e0
    slope = vdot(g, d)
    alpha = problem.max_step(x, d)
    while alpha >= min_step:
        y = problem.with_step(x, alpha * d)
        e = problem.energy(y) if np.all(np.isfinite(y)) else np.inf  # an overflowing trial is no decrease
        if e <= e0 + c1 * alpha * min(slope, 0.0):
            return alpha, e
        alpha *= 0.5
    return 0.0, e0


def converged(problem, d):
    """Termination ||d||_inf / h <= problem.tol * scene size (Li et al.; sec. 3.10)."""
    return np.abs(d).max(initial=0.0) / problem.h <= problem.tol * problem.model.size


def _add(rec, key, seconds):
    rec[key] = rec.get(key, 0.0) + seconds


def newton(problem, direction, rec, after_step=None, blocks=True, stop_on="direction"):
    """THE Newton loop: minimise ``problem``'s E from x_t; returns ``(x, converged)``.

    Parameters
    ----------
    problem : IncrementalPotential
        E with its gradient, the line search's ``energy``/``max_step``/``with_step``, and the
        settings ``tol`` and ``max_iters``.
    direction : callable
        ``direction(x, g, data, rec, e) -> d``: the step on the free DOFs at iterate x (flat),
        with g = grad E(x), ``data`` the elastic evaluation at x (:meth:`IncrementalPotential.evaluate`),
        ``e`` = E(x). It records its own phase times in ``rec``.
    rec : dict
        The frame's record: ``assembly`` (evaluation and gradient) and ``line_search`` times are
        added, ``newton_iters`` and ``newton_converged`` set.
    after_step : callable, optional
        ``after_step(x, alpha)`` after each accepted step, with the new iterate and step length
        (a reduced method updates its coordinates and secant data here).
    blocks : bool
        Whether each iterate's evaluation includes the element blocks and H (full Newton), or
        only F, P and f (the direction assembles the blocks it needs). The evaluation at x_t is
        reused when the problem has it.
    stop_on : {"direction", "step"}
        What the tolerance bounds: the Newton direction d (the Newton integrators, Li et al.), or
        the step alpha d the line search took (the linearized integrator's ``newton_tol``, a bound
        on the position change of an iteration).
    """
    if stop_on not in ("direction", "step"):
        raise ValueError(f"stop_on must be 'direction' or 'step', got {stop_on!r}")
    x = problem.x_start.copy()
    data = problem.start if (problem.starts_at_x_t and (blocks or problem.has_start)) else None
    e = problem.energy(x)
    ok = False
    for it in range(problem.max_iters):
        t0 = time.perf_counter()
        if data is None:
            data = problem.evaluate(x, blocks)
        g = problem.gradient(x, data.f)
        _add(rec, "assembly", time.perf_counter() - t0)
        d = direction(x, g, data, rec, e)
        if not np.all(np.isfinite(d)):
            raise SolverError(f"the Newton direction is not finite (iteration {it + 1})")
        t0 = time.perf_counter()
        alpha, e = line_search(problem, x, d, g, e)
        x = problem.with_step(x, alpha * d)
        if after_step is not None:
            after_step(x, alpha)
        data = None
        _add(rec, "line_search", time.perf_counter() - t0)
        rec["newton_iters"] = it + 1
        ok = converged(problem, d if stop_on == "direction" else alpha * d)
        if ok or alpha == 0.0:
            break
    rec["newton_converged"] = ok
    return x, ok


class FullSpaceDirection:
    """The full-space Newton direction d = -grad^2E^-1 grad E by ``solver`` (a direct or CG solver
    of :mod:`skfem_affine.solvers`); ``matrix`` is the last Hessian it factorised."""

    def __init__(self, problem, solver):
        self.problem, self.solver, self.matrix = problem, solver, None

    def __call__(self, x, g, data, rec, e):
        t0 = time.perf_counter()
        A = self.problem.hessian(data.H, x)
        _add(rec, "assembly", time.perf_counter() - t0)
        self.matrix = A
        return factorize_and_solve(self.solver, A, -g, rec)


def newton_solve(problem, solver, rec):
    """Minimise E (eq. 1) by full-space Newton from x_t; returns ``(x_{t+1} (flat), converged)``."""
    return newton(problem, FullSpaceDirection(problem, solver), rec)


def linearized_newton(model, x, v, solver, tol, max_iters, rec, start=None, targets=None, f_ext=None):
    """Newton on the implicit-Euler potential from the linearized state: the linearized
    integrator's ``newton_iters > 1`` option.

    Parameters
    ----------
    model : Model
    x, v : (n, 3) arrays
        The state at time t.
    solver : solver of :mod:`skfem_affine.solvers`
    tol : float
        Stop when the largest position change of an iteration, ``||alpha d||_inf``, is at most
        ``tol`` times the scene size (the linearized integrator's ``newton_tol``).
    max_iters : int
        Iteration cap (``newton_iters``); with 1 the result is the linearized step
        (when the line search takes the full step).
    rec : dict
        The frame's record (as :func:`newton`).
    start : FrameData, optional
        The evaluation at x (reused if given).
    targets, f_ext : Targets, (3n,) array, optional
        The step's prescribed vertices and vertex forces (:mod:`skfem_affine.motion`).

    Returns
    -------
    dv : array
        The velocity change on the free DOFs, v_{t+1} - v_t.
    matrix : scipy.sparse matrix
        The last Hessian factorised by ``solver``: A of eq. 1 at the last iterate (the damping's
        H lagged at x_t), which contact's Delassus operator needs.
    """
    # E = h^2 Phi(v) + const with x = x_t + h v (potential.py): the same minimiser. The loop's
    # criterion ||alpha d||_inf / h <= tol' * size with tol' = tol / h is ||alpha d||_inf <= tol * size.
    problem = IncrementalPotential(model, x, v, start=start, tol=positive(tol, "newton_tol") / model.dt,
                                   max_iters=max_iters, targets=targets, f_ext=f_ext)
    direction = FullSpaceDirection(problem, solver)
    x1, _ = newton(problem, direction, rec, stop_on="step")
    free = model.system.free
    return problem.velocity(x1)[free] - np.asarray(v, float).reshape(-1)[free], direction.matrix


def full_space_residual(problem, x):
    """The full-space Newton decrement ||grad^2E^-1 grad E||_inf / h at x (the accuracy of a reduced step)."""
    import scipy.sparse.linalg as spla
    data = problem.evaluate(x)
    d = spla.spsolve(problem.hessian(data.H, x).tocsc(), problem.gradient(x, data.f))
    return float(np.abs(d).max() / problem.h)


def resolve_newton_settings(sim_tol, sim_iters, reducer=None):
    """The Newton settings ``(tol, max_iters)`` of a run, from the Simulation's and the reducer's.

    The Simulation's ``newton_tol`` / ``newton_iters`` are the one place the settings live. A
    reducer that still takes its own Newton keywords (``AdaptiveSubspace(newton_tol=...,
    max_newton=...)``) hands them over when the Simulation's were not given; given in both places
    they must agree, else ValueError. When neither gives a value, the reducer's recommended default
    (``default_newton_tol``, ``default_max_newton``) is used; None remains when nobody has one (the
    integrator's default then applies).

    Parameters
    ----------
    sim_tol, sim_iters : float, int or None
        The Simulation's arguments as the user gave them (None: not given).
    reducer : object or None

    Returns
    -------
    (tol, max_iters), each None when nobody set it.
    """
    out = []
    own = (None, None) if reducer is None else (reducer.newton_tol, reducer.max_newton)
    default = (None, None) if reducer is None else (reducer.default_newton_tol, reducer.default_max_newton)
    for sim_value, key, red_value, red_default, sim_name in (
            (sim_tol, "newton_tol", own[0], default[0], "newton_tol"),
            (sim_iters, "max_newton", own[1], default[1], "newton_iters")):
        if sim_value is not None and red_value is not None and sim_value != red_value:
            raise ValueError(f"Simulation({sim_name}={sim_value!r}) and {type(reducer).__name__}({key}={red_value!r}) "
                             f"disagree; give the Newton settings once, as Simulation({sim_name}=...)")
        for value in (sim_value, red_value, red_default):
            if value is not None:
                out.append(value)
                break
        else:
            out.append(None)
    return tuple(out)

