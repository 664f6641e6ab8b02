r"""The adaptive subspace reducer: modal subspace plus nodal enrichment (Trusty et al., sec. 3.2-3.11).

Each time step minimises the incremental potential E
(:class:`~skfem_affine.integrators.potential.IncrementalPotential`) by the package's one Newton
loop (:func:`skfem_affine.integrators.newton.newton`) in an adaptive space, keeping the full
positions x as the state (sec. 3.2). The loop evaluates forces and the gradient at x; this
reducer's direction at x (Algorithm 1) is:

1. ``assembly``: element gradients; element blocks only in subdomains that need exact evaluation
   (those with an element touching an enriched node, sec. 3.9);
2. ``reduced_assembly`` (subspace Hessian, sec. 3.9): per subdomain l of a fixed METIS
   decomposition (:mod:`~skfem_affine.reducers.subspace.subdomains`), the elastic part
   U_a^T H_l U_a is a BFGS approximation (eq. 20), exact where enrichment touches; inertia, damping
   and the contact barrier are exact;
3. ``prediction`` (the oracle, sec. 3.7): the unmasked subspace direction d_q = -H_a^-1 U_a^T grad E
   (eq. 18) scaled by a line search, then nodal and modal errors and progress
   (:mod:`~skfem_affine.reducers.subspace.oracle`, eq. 5-17); a node activates its whole subdomain
   and a block of modes activates when error > eps and progress < eps_progress;
4. the non-overlapping decomposition (sec. 3.6): B_a = U_a with the enriched rows masked, S_a
   selects the enriched DOFs, and the coupled system (eq. 19)
   [[H_q, C], [C^T, H_x]] [d_q; d_x] = -[g_q; g_x] is solved by the Schur complement (eq. 21-22,
   :func:`~skfem_affine.reducers.subspace.linalg.schur_solve`): ``factorization`` = dense Cholesky
   of H_q, ``solve`` = PCG with 3 x 3 block-Jacobi on H_x - C^T H_q^-1 C applied matrix-free
   (sec. 3.10; relative tolerance ``pcg_tol``, the paper's 1e-5);
5. the direction is d = B_a d_q + S_a d_x; after the loop's line search the modal coordinates
   and the BFGS secant pair are updated (the loop's ``after_step``).

The loop stops by the Simulation's Newton settings (||d||_inf / h <= newton_tol * size). After
the step, modes and nodes whose contribution was small are downdated (sec. 3.11); the starting
blocks of the basis (a body's affine/rigid motion) are never downdated.

Never much slower than full space (not in the paper): when the coupled system (eq. 19) would have
more nonzeros than the full-space Newton system (:func:`falls_back`; its dense coupling C has
2 r per enriched DOF for r active columns), at the start of a step or after the oracle enriches
inside it, the rest of the step takes full-space Newton directions by a direct solve: a Schur
PCG iteration then costs more than a CG iteration on the full system, and the exact subdomain
Hessians and extra Newton iterations of the reduced step more than the direct solve saves
(the calibration is in docs/subspace.md, "The never-slower fallback"). After such a step
the modal coordinates are the least-squares fit of the step's displacement on the active
columns, and downdating proceeds as usual, so nodes the subspace captures again are released and
the reducer returns to reduced steps. ``rec["reduced"]`` says which kind each step was.

Never slower by measured time, and the error and time budgets (not in the paper; the default
unless thresholds are given): :mod:`~skfem_affine.reducers.subspace.control` says what is
measured and estimated; the controllers are :mod:`skfem_affine.reducers.budget`'s. Explicit
thresholds without budgets run exactly the paper's algorithm above.

Choices where the paper is silent, stated here: subdomains are element sets (an element belongs
to the METIS part of its first vertex), so the subdomain energies sum exactly to Psi and no
interface averaging is needed in eq. 20; the BFGS update is skipped when y^T s <= 0 (keeping
every H_l positive semi-definite) and reduces to y y^T / y^T s when s^T H_l s = 0; the characteristic
length l of sec. 3.11 is the scene's bounding-box diagonal; the step runs with one BLAS thread by
default, since its dense products are small (a few hundred modes) and the BLAS thread hand-off
costs more than it saves (measurements: docs/threads.md, "Adaptive subspace").
"""
import time

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from skfem_affine.checks import choice, flag, integer, positive, real
from skfem_affine import threads
from skfem_affine.integrators import newton
from skfem_affine.integrators.newton_integrator import NewtonIntegrator
from skfem_affine.integrators.problem import StepResult
from skfem_affine.integrators.potential import IncrementalPotential
from skfem_affine.reducers.base import Reducer
from skfem_affine.reducers import budget as budgets
from skfem_affine.reducers.subspace import control
from skfem_affine.reducers.subspace import oracle as so
from skfem_affine.reducers.subspace.bases import SkinningEigenmodes, _Basis
from skfem_affine.reducers.subspace.linalg import bfgs_update, masked_sandwich, metis_parts, schur_solve
from skfem_affine.reducers.subspace.subdomains import Subdomains
from skfem_affine.solvers import SolverError, direct_solver


def _threshold(value, name):
    """A threshold >= 0 (``inf`` allowed: it switches a test off)."""
    return real(value, f"threshold {name}", low=0.0, finite=False)


def coupled_nonzeros(enriched_dofs, modes, nnz_per_row):
    """Nonzeros of the coupled system (eq. 19): the dense H_q (r^2), C and C^T (2 r s) and H_x
    (about ``nnz_per_row`` s), for s enriched DOFs and r active modal columns."""
    return modes * modes + 2 * modes * enriched_dofs + nnz_per_row * enriched_dofs


def falls_back(enriched_dofs, free_dofs, modes, nnz_full, fallback="nnz"):
    """Whether a step with ``enriched_dofs`` of ``free_dofs`` enriched and ``modes`` active columns
    continues in full space (the full-space Newton system has ``nnz_full`` nonzeros).

    ``fallback="nnz"``: when the coupled system has more nonzeros than the full system
    (:func:`coupled_nonzeros`, H_x's rows as dense as the full system's); a number f: when more
    than the fraction f of the free DOFs are enriched; None: never.
    """
    if fallback is None:
        return False
    if fallback == "nnz":
        return coupled_nonzeros(enriched_dofs, modes, nnz_full / max(free_dofs, 1)) > nnz_full
    return enriched_dofs > fallback * max(free_dofs, 1)


def _count(value, name):
    """A positive integer setting; TypeError/ValueError naming ``name`` otherwise."""
    return integer(value, name, low=1)


class AdaptiveSubspace(Reducer):
    """Adaptive subspace time integration (Trusty et al.): modes + nodal enrichment with an oracle.

    Parameters
    ----------
    basis : AffineModes, LinearModes or SkinningEigenmodes, optional
        A basis spec from :mod:`skfem_affine.reducers.subspace.bases` (default ``SkinningEigenmodes(n=16)``).
    eps_nodal, eps_modal : float, optional
        Error thresholds (dimensionless, eq. 10 and 14); lower enriches more. 0 with
        ``eps_progress=inf`` enriches every node with an error: the full-space solve. Giving
        either switches the controllers off unless asked for (the other is then 0.5); giving
        neither uses 0.5 and 0.5 (the paper's) with ``never_slower`` on, or the error budget.
    target_error : float, optional
        The error budget: the largest vertex distance to the full-space run accepted, in the unit
        ``relative_to``; ``eps_nodal`` (and ``eps_modal`` = 3 ``eps_nodal``) then adapt to it
        (:mod:`~skfem_affine.reducers.subspace.control`). Not together with the thresholds.
    relative_to : {"response", "size", "metre"}, optional
        The unit of ``target_error`` (default ``"response"``, the largest displacement from rest so
        far; :mod:`skfem_affine.reducers.budget`).
    time_budget : float, optional
        Seconds per step; the enrichment is capped so that steps stay under it.
    never_slower : bool, optional
        Solve steps by full-space Newton while measured times say reduction does not pay, and
        probe reduction again later. Default: on unless a threshold is given. The decisions
        follow measured times, so such runs are not bit-reproducible.
    shadow_every : int
        Reduced steps per shadow step (a second, full-space solve of the step, whose solution is
        returned), under an error budget or ``never_slower``; doubling, up to 4x, while the
        estimate's calibration holds (or reduction keeps paying).
    memory : float
        Memory time T (s) of the error estimate.
    eps_progress : float
        Progress threshold (eq. 11, 15): a candidate activates only if the current subspace
        makes less progress than this there. ``inf`` switches the progress test off.
    eps_down : float
        Downdating threshold (sec. 3.11), relative to (scene size x h).
    subdomains : int
        Number of METIS subdomains for nodal enrichment and BFGS (sec. 3.6, 3.9).
    newton_tol, max_newton : float, int, optional
        Kept for old code: the Newton settings belong to the Simulation (``newton_tol``,
        ``newton_iters``), which adopts these when its own are not given and refuses a conflict
        (:func:`skfem_affine.integrators.newton.resolve_newton_settings`). With neither given,
        the reducer's defaults ``default_newton_tol`` = 1e-3 and ``default_max_newton`` = 50 apply.
    pcg_tol, pcg_maxiter : float, int
        The Schur complement's PCG relative tolerance (paper 1e-5) and iteration cap (>= 1).
    hessian_init : {"rest", "exact"}
        What the per-subdomain BFGS Hessians start from at each step and after a basis change:
        the rest-state subspace Hessians (precomputed once; default) or the exact ones at the
        current iterate (all element Hessians, a full evaluation per step).
    blas_threads : int or None
        BLAS threads inside the step (default 1, see the module docstring); None leaves them alone.
    fallback : "nnz", float or None
        When a step continues by full-space Newton (:func:`falls_back`): ``"nnz"`` (default)
        when the coupled system would have more nonzeros than the full one; a number f when
        more than the fraction f of the free DOFs are enriched; None never (the paper's method).
    record_residual : bool
        Also record the full-space Newton decrement of each step's result (a full solve; for
        measuring accuracy only).

    Notes
    -----
    Runs under the Newton integrators, ``Simulation(..., integrator="implicit_euler" | "bdf2")``.
    """

    name = "adaptive_subspace"
    integrators = ("implicit_euler", "bdf2")
    default_newton_tol = 1e-3
    default_max_newton = 50
    # carried across steps: the active blocks of modes and the enriched nodes (the BFGS Hessians
    # restart from hessian_init every step and the inertia cache is a function of the basis)
    # (and the budgets' controllers, plain numbers)
    _state_keys = ("active", "enriched", "controllers")

    def __init__(self, basis=None, eps_nodal=None, eps_modal=None, eps_progress=1e-4, eps_down=0.1,
                 subdomains=200, newton_tol=None, max_newton=None, pcg_tol=1e-5, pcg_maxiter=10000,
                 record_residual=False, hessian_init="rest", blas_threads=1, fallback="nnz",
                 target_error=None, time_budget=None, never_slower=None, shadow_every=10, memory=0.5,
                 relative_to=None):
        basis = SkinningEigenmodes(n=16) if basis is None else basis
        if not isinstance(basis, _Basis):
            raise TypeError(f"basis must be a basis such as sa.SkinningEigenmodes(n=16), got {type(basis).__name__}")
        self.basis_spec = basis
        eps_nodal, eps_modal, self.target_error, self.never_slower, self.relative_to = control.resolve(
            eps_nodal, eps_modal, target_error, never_slower, relative_to)
        self.time_budget, self.shadow_every, self.memory = control.check_settings(time_budget, shadow_every, memory)
        self.controlled = self.target_error is not None or self.time_budget is not None or self.never_slower
        self.eps_nodal = _threshold(eps_nodal, "eps_nodal")
        self.eps_modal = _threshold(eps_modal, "eps_modal")
        self.eps_progress = _threshold(eps_progress, "eps_progress")
        self.eps_down = _threshold(eps_down, "eps_down")
        self.n_subdomains = integer(subdomains, "subdomains", low=1)
        self.newton_tol = None if newton_tol is None else positive(newton_tol, "newton_tol")
        self.max_newton = None if max_newton is None else _count(max_newton, "max_newton")
        self.pcg_tol = positive(pcg_tol, "pcg_tol")
        self.pcg_maxiter = _count(pcg_maxiter, "pcg_maxiter")
        self.record_residual = flag(record_residual, "record_residual")
        self.hessian_init = choice(hessian_init, "hessian_init", ("rest", "exact"))
        self.blas_threads = None if blas_threads is None else integer(blas_threads, "blas_threads", low=1)
        if fallback is not None and fallback != "nnz":
            ok = isinstance(fallback, (int, float, np.integer, np.floating)) and not isinstance(fallback, bool)
            if not ok or not 0.0 <= fallback <= 1.0:
                raise ValueError(f"fallback must be 'nnz', a fraction in [0, 1] or None, got {fallback!r}")
            fallback = float(fallback)
        self.fallback = fallback
        self.control = None
        self.max_enriched = None  # the time budget's cap on enriched vertices (None: no cap)
        self.clock = time.perf_counter  # what the fall-back's measured times are read from (tests feed a fake one)

    def __repr__(self):
        budget = ("" if self.target_error is None
                  else f", target_error={self.target_error}, relative_to={self.relative_to!r}")
        return (f"AdaptiveSubspace(basis={self.basis_spec!r}, eps_nodal={self.eps_nodal}, eps_modal={self.eps_modal}, "
                f"eps_progress={self.eps_progress}, eps_down={self.eps_down}, subdomains={self.n_subdomains}, "
                f"fallback={self.fallback!r}{budget}, never_slower={self.never_slower})")

    @property
    def controllers(self):
        """The budgets' state and the thresholds as plain numbers (checkpoints)."""
        state = {} if self.control is None else self.control.state
        state["thresholds"] = {"eps_nodal": float(self.eps_nodal), "eps_modal": float(self.eps_modal)}
        return state

    @controllers.setter
    def controllers(self, state):
        state = dict(state)
        thresholds = state.pop("thresholds", {})
        self.eps_nodal = thresholds.get("eps_nodal", self.eps_nodal)
        self.eps_modal = thresholds.get("eps_modal", self.eps_modal)
        if state:
            if self.control is None:
                raise ValueError(f"this reducer has no controllers {sorted(state)} to restore")
            self.control.state = state

    # ------------------------------------------------------------------ set-up
    def attach(self, model):
        """Rest-state set-up from the run's ``model`` (``system``, ``project_hessian``): the basis,
        the METIS subdomains and, with ``hessian_init="rest"``, the rest subspace Hessians."""
        t0 = time.perf_counter()
        sysm = model.system
        if sysm.nodal is not None:  # its subspace Hessians are sums of element blocks
            raise ValueError('reducer: AdaptiveSubspace does not support bodies with volumetric="nodal" '
                             '(their stiffness couples vertices beyond the elements); use sa.Affinification '
                             'or full space')
        self.model, self.system, self.project_hessian = model, sysm, bool(model.project_hessian)
        self.basis = self.basis_spec.build(sysm)
        self.U = self.basis.U[sysm.free]  # (nfree, r)
        self.queries = so.ModalQueries(self.basis.U, self.basis.blocks)
        self.area_scale, self.volume_scale = so.node_scaling(sysm)
        self.ring = so.OneRing(sysm)
        self.sub = Subdomains(sysm, metis_parts(sysm, self.n_subdomains))
        self.active = sorted(set(self.basis.initial))
        self.permanent = set(self.basis.initial)
        self.permanent_columns = int(sum(len(self.basis.blocks[j]) for j in self.permanent))
        self.enriched = np.zeros(sysm.n, dtype=bool)
        self.free_vertex = np.zeros(sysm.n, dtype=bool)
        self.free_vertex[sysm.free // 3] = True
        self.dof_map = np.full(3 * sysm.n, -1, dtype=np.int64)
        self.dof_map[sysm.free] = np.arange(sysm.free.size)
        if self.hessian_init == "rest":
            rest = sysm.evaluate(sysm.p0, project=self.project_hessian)
            self.rest_hessians = self.sub.exact(rest.He, range(self.sub.L), self.U)
        self.setup_time = time.perf_counter() - t0
        self.last_system = self.last_hessians = None
        self._inertia_cache = {}
        self.fallback_solver = direct_solver()  # the full-space step's solver (falls_back)
        self.step_enriched = self.enriched.copy()  # the enriched nodes of the last step, before downdating
        self.control = None
        if self.controlled:
            self.control = control.Controllers(self.target_error, self.time_budget, self.never_slower,
                                               self.shadow_every, self.memory, self.relative_to)
            if self.target_error is not None:
                self.rest_diagonal = control.rest_stiffness_diagonal(sysm, self.project_hessian)

    def columns(self):
        """The active modal columns of U, in the order of the active blocks."""
        return np.concatenate([self.basis.blocks[j] for j in self.active])

    def _enriched_dofs(self):
        v = np.flatnonzero(self.enriched)
        return self.dof_map[(3 * v[:, None] + np.arange(3)).ravel()]

    # ------------------------------------------------------------------ one step
    def solve(self, problem):
        """Algorithm 1: the adaptive Newton solve of one step from the incremental potential
        ``problem``; returns a StepResult with ``x`` (flat) and the step's statistics."""
        if not isinstance(problem, IncrementalPotential):
            raise ValueError("AdaptiveSubspace runs with integrator='implicit_euler' or 'bdf2' "
                             f"(it minimises the incremental potential), got a {type(problem).__name__}")
        rec = {}
        if self.control is not None:  # full-space steps run with the BLAS threads of the full-space run
            return StepResult(x=self._controlled(problem, rec), stats=rec)
        with threads.blas_threads(self.blas_threads):
            x = self._step(problem, rec)
        return StepResult(x=x, stats=rec)

    def end_frame(self, rec):
        """The time budget takes the frame's wall time (``rec["time_budget_miss"]`` records a miss); an
        estimate over the error budget is warned at the first frame it is (``BudgetWarning``)."""
        timer = None if self.control is None else self.control.timer
        if timer is not None and "wall" in rec:
            rec["time_budget_miss"] = bool(timer.observe(rec["wall"]))
            rec["min_fraction_next"] = float(timer.fraction)
        budget = None if self.control is None else self.control.error_budget
        if budget is not None:
            budget.warn_passed(rec.get("frame"))

    def _full_step(self, ip, rec):
        """Full-space Newton by the fallback solver, with IPC's lagged friction iterations as the
        full-space run takes them (:class:`~skfem_affine.integrators.newton_integrator.NewtonIntegrator`:
        the friction's normal forces from the solution while they change), so that a step solved in
        full space is the full-space run's step; returns (x, seconds)."""
        t0 = self.clock()
        x, _ = newton.newton_solve(ip, self.fallback_solver, rec)
        relag = getattr(ip.barrier, "relag", None)  # IPCContact's lagged friction (the integrator's interface)
        if relag is not None:
            for _ in range(NewtonIntegrator.FRICTION_ITERATIONS):
                if relag(x) <= NewtonIntegrator.FRICTION_TOL:
                    break
                x, _ = newton.newton_solve(ip, self.fallback_solver, rec)
                rec["friction_iterations"] = rec.get("friction_iterations", 0) + 1
        return x, self.clock() - t0

    def _controlled(self, ip, rec):
        """Plan the step (full, reduced, or reduced with a shadow), solve it, feed the controllers
        (:mod:`~skfem_affine.reducers.subspace.control`)."""
        c = self.control
        if c.error_budget is not None:  # the budget's unit this step: the response so far, the scene size, or a metre
            c.error_budget.scale(ip.model.size, budgets.largest_displacement(ip.x_t, self.system.p0))
        forced = self._cap_enrichment(c)
        mode = c.plan()
        if mode == "full":
            x = self._planned_full_step(ip, rec)
        else:
            x = self._reduced_step(ip, rec, mode)
        self._record(rec, forced)
        return x

    def _cap_enrichment(self, c):
        """The time budget's forced fraction and the cap on enriched vertices it implies."""
        forced = 0.0 if c.timer is None else c.timer.fraction
        self.max_enriched = None if c.timer is None else int((1.0 - forced) * self.free_vertex.sum())
        if self.max_enriched is not None and self.enriched.sum() > self.max_enriched:
            self.enriched[:] = False  # over the cap: the oracle chooses again within it, largest errors first
        return forced

    def _planned_full_step(self, ip, rec):
        """A step the fall-back solves in full space: its cost and the error estimate's decay."""
        c = self.control
        x, seconds = self._full_step(ip, rec)
        if c.pays is not None:
            c.pays.full_solved(seconds, rec.get("newton_iters", 1))
        if c.error_budget is not None:
            c.error_budget.decay(ip.h)
        rec.update(reduced=False, shadow=False, refused=False, dofs=int(ip.free.size), solver=self.fallback_solver.name,
                   full_solve=seconds)
        return x

    def _reduced_step(self, ip, rec, mode):
        """A reduced step (with a shadow full solve when due, or a full one when it ran out of time);
        returns the step's positions after feeding the error budget and the fall-back."""
        c, free = self.control, ip.free
        if c.error_budget is not None:
            self.eps_nodal, self.eps_modal = c.error_budget.tau, control.MODAL_RATIO * c.error_budget.tau
        shadow = c.shadow_due(mode)
        t0 = self.clock()
        with threads.blas_threads(self.blas_threads):
            x_red, step = self._step(ip, rec, deadline=c.deadline(), keep=True)
        reduced_seconds = self.clock() - t0
        went_full = x_red is None or step.full  # the result (if any) is a converged full-space one
        rec["reduced_dofs"] = rec.get("dofs", int(free.size))
        eb = c.error_budget
        # a reduced step whose estimated error would break the budget is solved again in full space
        refused = (not shadow and not went_full and eb is not None
                   and eb.breaks(eb.local(self._proxy(ip, step)), ip.h))
        shadow = shadow or refused
        x, measured = x_red, None
        if shadow or x_red is None:  # a shadow, or a reduced step out of time: full-space Newton from x_t
            x, measured = self._shadow_step(ip, rec, x_red, shadow)
        rec["shadow"] = bool(shadow)
        rec["refused"] = bool(refused)
        rec["reduced"] = bool(not shadow and not went_full)
        if c.error_budget is not None:
            self._feed_error_budget(ip, rec, x_red, step, went_full, measured)
        if c.pays is not None:
            self._feed_fall_back(rec, mode, shadow, reduced_seconds, free.size)
        return x

    def _shadow_step(self, ip, rec, x_red, shadow):
        """Full-space Newton from x_t beside (or instead of) the reduced step; returns its positions
        and the measured local error of the reduced step (None without one)."""
        c, free = self.control, ip.free
        part = {}
        x, seconds = self._full_step(ip, part)
        if c.pays is not None:
            iterations = part.get("newton_iters", 1)
            c.pays.shadow_solved(seconds, iterations) if shadow else c.pays.full_solved(seconds, iterations)
        for key in ("assembly", "line_search", "factorization", "solve"):
            rec[key] = rec.get(key, 0.0) + part.get(key, 0.0)
        measured = None
        if x_red is not None:
            measured = budgets.vertex_max_norm((x_red - x)[free], free, self.system.n) / ip.h
            rec["local_error_measured"] = measured / self._error_unit(ip)
        rec.update(dofs=int(free.size), solver=self.fallback_solver.name, full_solve=seconds,
                   full_newton_iters=part.get("newton_iters", 0))
        return x, measured

    def _feed_error_budget(self, ip, rec, x_red, step, went_full, measured):
        """The error budget's estimate after the step, and eps adapted to it."""
        c, eb, h, size = self.control, self.control.error_budget, ip.h, ip.model.size
        if x_red is None and rec.get("over_deadline"):
            # out of time: nothing measured; eps grows while the estimate is under the goal (a
            # larger eps enriches less, which is what makes a reduced step cheaper)
            eb.advance(0.0, h, size, introduced=False)
            if eb.estimate <= eb.goal:
                eb.adapt()
            return
        estimate = 0.0 if went_full else self._proxy(ip, step)
        if measured is not None and measured > control.NOISE * ip.tol * size:
            delta = eb.local(estimate, measured)  # calibrates the proxy
            c.shadows.settled(eb.stable and eb.estimate < eb.goal)
        else:  # no shadow, or a measured error at the Newton tolerance's level: nothing to calibrate by
            delta = eb.local(estimate) if measured is None else measured
        eb.advance(delta, h, size, introduced=rec["reduced"])
        rec["local_error"] = delta / self._error_unit(ip)
        # the smallest space (no enrichment, the permanent modes only): a larger eps gains nothing
        smallest = not went_full and not self.step_enriched.any() and rec["active_modes"] <= self.permanent_columns
        # a step solved in full space says nothing about eps's error: eps may grow while the
        # estimate is under the goal (so that steps reduce again), and holds over it
        if not went_full or eb.estimate <= eb.goal:
            eb.adapt(saturated=smallest)

    def _proxy(self, ip, step):
        """The proxy of a reduced step's local error (m/s, uncalibrated): :func:`control.proxy` at its last iterate."""
        return control.proxy(step.last_g, step.diagonal(), ip.free, self.system.n, ip.h)

    def _error_unit(self, ip):
        """The budget's unit (m) this step (set by :meth:`_controlled`), or the scene size without a budget."""
        eb = self.control.error_budget
        return ip.model.size if eb is None else eb.unit

    def _feed_fall_back(self, rec, mode, shadow, reduced_seconds, free_dofs):
        """The never-slower fall-back's measurements of the step, and its decision."""
        c, pays = self.control, self.control.pays
        c.reduced_measured(reduced_seconds, shadow)
        pays.reduced_solved(reduced_seconds, rec["reduced_dofs"] / max(free_dofs, 1), fresh=mode == "probe",
                            iterations=max(rec.get("newton_iters", 1), 1))
        pays.decide(c.shadow_period(), probed=mode == "probe")
        if shadow and c.error_budget is None and c.shadows is not None:
            c.shadows.settled(not pays.in_full)  # the fall-back's shadows space out while reduction pays

    def _record(self, rec, forced):
        """The controllers' state in the step's statistics."""
        c = self.control
        if c.error_budget is not None:
            rec["estimated_error"] = float(c.error_budget.estimate)
            rec["error_unit"] = float(c.error_budget.unit)
        rec["eps_nodal"], rec["eps_modal"] = float(self.eps_nodal), float(self.eps_modal)
        rec["min_fraction"] = float(forced)
        if c.pays is not None:
            rec["reduction_pays"] = not c.pays.in_full

    def _too_enriched(self):
        return falls_back(int(self._enriched_dofs().size), int(self.system.free.size), int(self.columns().size),
                          int(self.system.pattern.nnz), self.fallback)

    def _step(self, ip, rec, deadline=None, keep=False):
        """One adaptive Newton solve. ``deadline`` (s): past it, the step stops and x is None.
        ``keep``: return (x, iteration)."""
        step = _Iteration(self, ip, full=self._too_enriched())
        if deadline is not None:
            step.deadline = self.clock() + deadline
        try:
            x, _ = newton.newton(ip, step.direction, rec, step.after_step, blocks=step.full)
        except _LeaveReduction:
            self.last_hessians = step.Hl
            rec["pcg_iters"] = step.pcg_total
            rec["dofs"] = int(self.columns().size + 3 * self.enriched.sum())
            return None, step
        rec["reduced"] = not step.full
        if step.full:
            step.q = self._fit(ip, x)
        self.last_hessians = step.Hl
        rec["pcg_iters"] = step.pcg_total
        rec["active_modes"] = int(self.columns().size)
        rec["enriched_ratio"] = float(self.enriched.sum() / max(self.free_vertex.sum(), 1))
        rec["dofs"] = int(self.columns().size + 3 * self.enriched.sum())
        rec["solver"] = "schur-pcg" if not step.full else self.fallback_solver.name
        if self.record_residual:
            rec["full_residual"] = newton.full_space_residual(ip, x)
        self.step_enriched = self.enriched.copy()
        self._downdate(ip, x, step.q, rec)
        return (x, step) if keep else x

    # ------------------------------------------------------------------ pieces
    def _fit(self, ip, x):
        """Modal coordinates of a full-space step: the least-squares fit of x - x_t on the active
        columns (what downdating measures the step against)."""
        q = np.zeros(self.basis.size)
        cols = self.columns()
        dx = (x - ip.x_t)[ip.free]
        q[cols] = np.linalg.lstsq(self.U[:, cols], dx, rcond=None)[0]
        return q

    def _inertia(self, ip, Meff):
        """U^T (M + w D) U for all candidate modes: once per step, or once per run without beta damping."""
        key = (ip.weight, ip.c)
        beta = ip.model.damping.beta
        if beta == 0 and key in self._inertia_cache:
            return self._inertia_cache[key]
        UMU = self.U.T @ (Meff @ self.U)
        if beta == 0:
            self._inertia_cache[key] = UMU
        return UMU

    def _invalid_subdomains(self):
        """Subdomains with an element touching an enriched node: exact evaluation (sec. 3.9)."""
        touch = np.any(self.enriched[self.system.t], axis=0)
        return np.unique(self.sub.of_element[touch])

    def _elements_of(self, subs):
        return np.concatenate([self.sub.elems[l] for l in subs]) if len(subs) else np.zeros(0, np.int64)

    def _elastic(self, Hl, invalid, F, He, he_valid, Ua, masked=None):
        """Elastic subspace Hessian (sec. 3.9): BFGS H_l in valid subdomains plus the exact
        U^T H_l U (masked: B^T H_l B) summed over the subdomains that enrichment touches."""
        valid = np.ones(Hl.shape[0])
        valid[invalid] = 0.0
        total = np.einsum("l,lab->ab", valid, Hl)  # sum over valid subdomains without copying them
        if invalid.size:
            self._blocks(F, He, he_valid, self._elements_of(invalid))
            total += self.sub.exact_sum(He, invalid, Ua, masked)
        return total

    def _initial_hessians(self, F, He, he_valid, cols, Ua):
        """Per-subdomain elastic subspace Hessians that BFGS starts from (sec. 3.9).

        ``hessian_init="exact"``: U_a^T H_l(x) U_a at the current iterate (all element blocks);
        ``"rest"``: the rest-state U_a^T H_l(X) U_a, precomputed once for all candidate modes.
        Subdomains needing exact evaluation are overwritten by the caller either way.
        """
        if self.hessian_init == "rest":
            return np.ascontiguousarray(self.rest_hessians[:, cols][:, :, cols])
        self._blocks(F, He, he_valid, np.arange(self.system.m))
        return self.sub.exact(He, range(self.sub.L), Ua)

    def _blocks(self, F, He, he_valid, elems):
        """Fill element blocks He of ``elems`` at the current iterate (computed once per iterate)."""
        need = elems[~he_valid[elems]]
        if need.size:
            He[need] = self.system.element_blocks(F, need, self.project_hessian)
            he_valid[need] = True

    def _partial_data(self, He, elems):
        """Stiffness of ``elems`` only, as data on the free-DOF pattern."""
        slot = self.system.pattern.slot.reshape(self.system.m, 144)[elems].ravel()
        ok = slot >= 0
        return np.bincount(slot[ok], weights=He[elems].reshape(-1)[ok], minlength=self.system.pattern.nnz)

    def _update(self, ip, x, g, ge, Ua, Hu, e0, n_scale, m_scale, rec):
        """Oracle (sec. 3.7): activate nodes (by subdomain) and blocks of modes; returns what changed."""
        sysm = self.system
        shift = 1e-10 * max(np.trace(Hu) / max(Hu.shape[0], 1), 1e-300)  # candidate columns may be dependent
        try:
            dq = -sla.solve(Hu + shift * np.eye(Hu.shape[0]), Ua.T @ g, assume_a="pos")  # eq. 18
        except np.linalg.LinAlgError:  # numerically dependent candidate columns: the least-squares step
            dq = -np.linalg.lstsq(Hu + shift * np.eye(Hu.shape[0]), Ua.T @ g, rcond=None)[0]
        du = Ua @ dq
        alpha, _ = newton.line_search(ip, x, du, g, e0)
        du *= alpha
        W0 = so.element_energies(sysm, x.reshape(-1, 3))
        x1 = ip.with_step(x, du)
        W1 = so.element_energies(sysm, x1.reshape(-1, 3))
        dE = so.nodal_shares(ip, x, W0) - so.nodal_shares(ip, x1, W1)  # eq. 7
        point = so.point_gradients(ip, x)
        gnorm = self.ring.gradient_norms(ip.weight * ge, point)
        G_nodal = gnorm / n_scale  # eq. 10
        E_nodal = dE / m_scale  # eq. 11
        cand = self.free_vertex & ~self.enriched & (G_nodal > self.eps_nodal) & (E_nodal < self.eps_progress)
        changed = None
        if np.any(cand):
            parts = np.unique(self.sub.parts[cand])
            add = np.isin(self.sub.parts, parts) & self.free_vertex
            if self.max_enriched is not None:  # the time budget's cap: the largest errors first
                add = control.capped_enrichment(add, self.enriched, parts, self.sub.parts, G_nodal, self.max_enriched)
            if np.any(add & ~self.enriched):
                self.enriched |= add
                changed = "nodes"
        inactive = [j for j in range(len(self.basis.blocks)) if j not in self.active]
        grad_full = np.zeros(3 * sysm.n)
        grad_full[ip.free] = g
        G_modal, E_modal = self.queries.measure(inactive, grad_full, dE, n_scale, m_scale)
        new = [j for j, ge_, pe in zip(inactive, G_modal, E_modal) if ge_ > self.eps_modal and pe < self.eps_progress]
        if new:
            self.active = sorted(set(self.active) | set(new))
            changed = "modes"
        rec["max_nodal_error"] = max(rec.get("max_nodal_error", 0.0), float(G_nodal[self.free_vertex].max(initial=0.0)))
        return changed

    def _downdate(self, ip, x, q, rec):
        """Sec. 3.11: drop modes that moved little and enriched nodes the subspace already captures."""
        h, length = ip.h, ip.model.size
        limit = self.eps_down * length * h
        keep = []
        for j in self.active:
            blk = self.basis.blocks[j]
            if j in self.permanent or np.abs(self.U[:, blk] @ q[blk]).max(initial=0.0) >= limit:
                keep.append(j)
        self.active = keep
        if np.any(self.enriched):
            cols = np.flatnonzero(q)
            da = (self.basis.U[:, cols] @ q[cols]).reshape(-1, 3)
            dx = (x - ip.x_t).reshape(-1, 3)
            small = np.linalg.norm(dx - da, axis=1) < limit
            self.enriched &= ~small
        rec["enriched_after_downdate"] = float(self.enriched.sum() / max(self.free_vertex.sum(), 1))


class _LeaveReduction(Exception):
    """Under the controllers, a reduced step stops: it ran past the full step's cost (the deadline),
    or its enrichment grew past the nnz fallback; the step is solved by full-space Newton from x_t."""


class _Iteration:
    """The reducer's Newton direction and after-step update over one time step (Algorithm 1).

    Holds what lives for one step: the exact inertia sandwich, the per-subdomain BFGS Hessians and
    their secant pair, the modal coordinates q of the step, and the element blocks evaluated at the
    current iterate.
    """

    def __init__(self, red, ip, full=False):
        sysm = red.system
        self.red, self.ip = red, ip
        self.full = bool(full)  # full-space directions (the fallback) for the rest of the step
        self.full_direction = newton.FullSpaceDirection(ip, red.fallback_solver)
        w = ip.weight
        Meff = sysm.pattern.matrix(ip.hessian_data(np.zeros(sysm.pattern.nnz))).copy()  # M + w D (exact)
        Meff.eliminate_zeros()  # diagonal for lumped mass without beta damping (the copy keeps the pattern intact)
        self.Meff = Meff
        self.UMU = red._inertia(ip, Meff)  # U^T (M + w D) U over all candidate columns
        self.n_scale = np.maximum(w * red.area_scale, 1e-300)
        self.m_scale = np.maximum(w * red.volume_scale, 1e-300)
        self.q = np.zeros(red.basis.size)
        self.Hl = None
        self.Y_prev = self.s_prev = None
        self.pcg_total = 0
        self.He = np.empty((sysm.m, 12, 12))
        self.he_valid = np.zeros(sysm.m, dtype=bool)
        self.cols = self.dq = None
        self.deadline = None  # the never-slower fall-back's: past it the step stops (clock time)
        self.last_g = None  # the gradient at the latest iterate (the error budget's proxy)

    def diagonal(self):
        """diag(M + w D + w K(X)) on the free DOFs: the error proxy's Jacobi scaling."""
        return self.Meff.diagonal() + self.ip.weight * self.red.rest_diagonal

    def direction(self, x, g, data, rec, e):
        """d = B_a d_q + S_a d_x at iterate x (steps 1-4 of the module docstring)."""
        red, ip = self.red, self.ip
        self.last_g = g
        self._check_deadline(rec)
        if self.full:
            return self._full(x, g, data, rec, e)
        sysm, sub = red.system, red.sub
        w, free = ip.weight, ip.free
        He, he_valid = self.He, self.he_valid
        t0 = time.perf_counter()
        if data.He is not None:  # the evaluation at x_t with its blocks (Rayleigh beta needs H_t): reuse it
            He[:], he_valid[:] = data.He, True
        F = data.F
        ge = so.element_gradients(sysm, data.P)
        t1 = time.perf_counter()
        rec["assembly"] = rec.get("assembly", 0.0) + t1 - t0
        # ---- subspace Hessian (sec. 3.9): BFGS where valid, exact where enrichment touches
        cols = red.columns()
        Ua = red.U[:, cols]
        invalid = red._invalid_subdomains()
        if self.Hl is None or self.Hl.shape[1] != cols.size:
            self.Hl = red._initial_hessians(F, He, he_valid, cols, Ua)
        else:
            Y = sub.projected_gradients(ge, Ua)
            valid = np.ones(sub.L, dtype=bool)
            valid[invalid] = False
            bfgs_update(self.Hl, self.s_prev, Y - self.Y_prev, valid)
        self.Y_prev = sub.projected_gradients(ge, Ua)
        Meff, UMU = self.Meff, self.UMU
        Mk = Meff if ip.barrier is None else Meff + sysm.pattern.matrix(ip.barrier_data(x))  # exact contact
        extra = ip.contact_hessian(x)  # body-body / self contact, off the elastic pattern
        if extra is not None:
            Mk = (Mk + extra).tocsr()
        Hu = masked_sandwich(UMU, cols, Mk - Meff, Ua) + w * red._elastic(self.Hl, invalid, F, He, he_valid, Ua)
        t2 = time.perf_counter()
        rec["reduced_assembly"] = rec.get("reduced_assembly", 0.0) + t2 - t1
        # ---- oracle (sec. 3.7): tentative subspace step (eq. 18), then error and progress
        changed = red._update(ip, x, g, ge, Ua, Hu, e, self.n_scale, self.m_scale, rec)
        t3 = time.perf_counter()
        rec["prediction"] = rec.get("prediction", 0.0) + t3 - t2
        self._check_deadline(rec)
        if red._too_enriched():  # enrichment grew past the fallback: full space from here on
            if red.control is not None:  # (under the controllers from x_t, as after the deadline)
                raise _LeaveReduction
            self.full = True
            return self._full(x, g, data, rec, e)
        if changed == "modes":
            cols = red.columns()
            Ua = red.U[:, cols]
            self.Hl = red._initial_hessians(F, He, he_valid, cols, Ua)
            self.Y_prev = sub.projected_gradients(ge, Ua)
        # ---- coupled system (eq. 19) on the non-overlapping decomposition (sec. 3.6)
        invalid = red._invalid_subdomains()
        S = red._enriched_dofs()
        Ba = Ua.copy()
        Ba[S] = 0.0
        masked = np.zeros(free.size, dtype=bool)
        masked[S] = True
        Hq = masked_sandwich(UMU, cols, Mk - Meff, Ua, Mk, S) + w * red._elastic(self.Hl, invalid, F, He, he_valid,
                                                                                 Ua, masked)
        # relative 1e-10 shift: fully masked or mutually dependent columns stay solvable
        Hq += (1e-10 * max(np.trace(Hu) / max(cols.size, 1), 1e-300)) * np.eye(cols.size)
        if S.size:
            elems = red._elements_of(invalid)
            Hpart = red._partial_data(He, elems)
            Acols = ip.hessian(Hpart, x).tocsc()[:, S]
            Hx = Acols[S, :].tocsr()
            C = np.asarray((Acols.T @ Ba).T)
        else:
            Hx, C = sp.csr_matrix((0, 0)), np.zeros((cols.size, 0))
        gq, gx = Ba.T @ g, g[S]
        t4 = time.perf_counter()
        rec["reduced_assembly"] = rec.get("reduced_assembly", 0.0) + t4 - t3
        try:
            dq, dx, iters, tf = schur_solve(Hq, C, Hx, gq, gx, red.pcg_tol, red.pcg_maxiter)
        except SolverError as err:
            # an indefinite modal block (a secant update or a fast rotation far from the basis' rest
            # shape): this iterate has no reduced Newton direction; the full-space one has
            if "modal block" not in str(err):
                raise
            rec["modal_fallbacks"] = rec.get("modal_fallbacks", 0) + 1
            if red.control is not None:  # under the controllers: the step again from x_t, in full space
                raise _LeaveReduction from None
            self.full = True
            return self._full(x, g, data, rec, e)
        self.pcg_total += iters
        red.last_system = (Hq, C, Hx, gq, gx)
        t5 = time.perf_counter()
        rec["factorization"] = rec.get("factorization", 0.0) + tf
        rec["solve"] = rec.get("solve", 0.0) + t5 - t4 - tf
        d = Ba @ dq
        d[S] += dx
        self.cols, self.dq = cols, dq
        return d

    def _check_deadline(self, rec):
        """Past the deadline (the never-slower fall-back) the step stops: reduction costs more than a
        full step here, and the caller solves the step by full-space Newton from x_t (from a reduced
        iterate near contact, full Newton can need many more iterations)."""
        if self.deadline is not None and not self.full and self.red.clock() > self.deadline:
            rec["over_deadline"] = True
            raise _LeaveReduction

    def _full(self, x, g, data, rec, e):
        """The full-space Newton direction (the fallback), with the element blocks at x."""
        if data.H is None:
            t0 = time.perf_counter()
            data = self.ip.evaluate(x)
            rec["assembly"] = rec.get("assembly", 0.0) + time.perf_counter() - t0
        return self.full_direction(x, g, data, rec, e)

    def after_step(self, x, alpha):
        """The loop took x + alpha d: advance the modal coordinates and the secant step; the
        element blocks belong to the old iterate."""
        self.he_valid[:] = False
        if self.full:
            return
        self.q[self.cols] += alpha * self.dq
        self.s_prev = alpha * self.dq
