r"""The frame flow shared by affinification and rigidification (paper Algorithm 1).

One frame, with the phase names of ``sim.stats`` (``assembly``, f and H at x_t, is the
integrator's, in the :class:`~skfem_affine.integrators.problem.StepProblem`):

1. ``prediction``: one PCG iteration (eq. 13-14), dv_approx, the contact impulses of
   the problem taken as explicit forces (sec. 3.4: the warm-started support, and the new
   contacts' estimates on the bodies an impact hits, :func:`oracle.explicit_impulse`), started from the bodies' mean
   response to the warm-started support when there is any and the thresholds are explicit
   (:func:`oracle.coarse_guess`);
2. ``clustering``: which elements are reduced and how they group (the subclass's
   :meth:`ClusteringReducer._labels`);
3. ``map_assembly``: G (eq. 7-8, the subclass's body kind; affine bodies in the last frame's
   clusters keep its G, numbering and order: :meth:`ClusteringReducer._frame_mapping`), projection
   q = (G^T M G)^-1 G^T M v (eq. 9), discrepancy d = G q - v (eq. 11);
4. ``reduced_assembly``: G^T A G and G^T b (eq. 10), the matrix gathered from the
   assembled A's vertex blocks (:func:`mapping.reduced_matrix`), upper triangle
   only when the solver is a Cholesky that reads one, and its elimination order
   inherited from the mesh (:meth:`mapping.Mapping.elimination_order`); in a scene of
   several bodies, renumbered as full space numbers its unknowns (:mod:`.numbering`);
5. ``factorization`` and ``solve``: the reduced system, direct solver: with the contacts'
   unknowns last where contact's Schur inverse accepts; else, several bodies, one block per
   body (:mod:`skfem_affine.reducers.affine.blocks`: only the bodies whose clusters changed
   are analysed again); else, few constraints and a new pattern, through the full A's
   factorisation (:mod:`.constrained`); else whole;
6. dv = G dq + d (eq. 12); the positions are integrated by the mapping's body kind.

With an error budget, a time budget or ``never_slower`` (:mod:`skfem_affine.reducers.budget`),
the frame is first planned: solved in full space (reduction does not pay), or reduced, with
the thresholds and forced fraction the controllers chose; a reduced frame then estimates its
error (one preconditioned CG step on the full-space residual) and, every ``shadow_every``
reduced frames (up to four times that while the estimate's calibration holds), is also solved
in full space (a *shadow* frame: the full solution is returned, and the difference calibrates
the estimate). Whether reduction pays is judged after the frame, on its wall time
(:meth:`ClusteringReducer.end_frame`), against the frames solved in full space.
"""
import time

import numpy as np

from skfem_affine.checks import choice, flag, integer, positive, real, real_array
from skfem_affine.threads import serial_blas
from skfem_affine.integrators.problem import Operator, StepResult
from skfem_affine.reducers import budget as budgets
from skfem_affine.reducers.affine import blocks, clustering, constrained, oracle, pinned
from skfem_affine.reducers.affine import mapping as reduction
from skfem_affine.reducers.affine.numbering import FullNumbering, several_bodies
from skfem_affine.reducers.base import Reducer
from skfem_affine.reducers.full import contact_factorization, factorize_and_solve, touched_unknowns
from skfem_affine.solvers import Pardiso, make_solver

SEEDINGS = ("random", "index", "temporal")

# The refresh trigger compares growth of the oracle residual with refresh_tol times
# max(reference, RESIDUAL_FLOOR): a preconditioner that leaves a few percent of ||b|| is as good as
# exact for the clustering, and relative noise on such a small residual should not trigger rebuilds.
RESIDUAL_FLOOR = 0.1
#: A probe of the never-slower fall-back that failed on its own error (bodies still settling) is
#: followed by the next as soon as the largest vertex speed has fallen under this fraction of its
#: value then, rather than after the doubled wait (:meth:`ClusteringReducer._judge`).
SETTLED = 0.5


def check_threshold(value, name):
    """A finite threshold >= 0, or a TypeError/ValueError naming it."""
    return real(value, f"threshold {name}", low=0.0)


def forced_fraction(min_fraction):
    """The resource-limit fraction ``min_fraction`` checked (0 to 1); 0 when None."""
    return 0.0 if min_fraction is None else real(min_fraction, "min_fraction", low=0.0, high=1.0)


def resolve_thresholds(tau, tau_e, target_error, name, relative_to=None):
    """(tau, tau_e, target_error) from what the user gave: thresholds, a budget, or neither.

    Explicit thresholds switch the error budget off (a missing one is the other's half or
    double); none gives the default budget, :data:`~skfem_affine.reducers.budget.DEFAULT_TARGET_ERROR`.
    ``relative_to`` (checked here) is the budget's unit; it is refused beside explicit thresholds.
    """
    explicit = tau is not None or tau_e is not None
    unit = budgets.error_unit(relative_to)
    if explicit and target_error is not None:
        raise ValueError(f"give the thresholds ({name}, tau_e) or target_error, not both")
    if explicit and relative_to is not None:
        raise ValueError(f"relative_to is the unit of target_error; explicit thresholds ({name}, tau_e) have none")
    if not explicit:
        target = budgets.DEFAULT_TARGET_ERROR if target_error is None else target_error
        return None, None, budgets.target_error(target, unit)
    tau_e = None if tau_e is None else check_threshold(tau_e, "tau_e")
    tau = check_threshold(tau if tau is not None else 0.5 * tau_e, name)
    return tau, (tau_e if tau_e is not None else 2.0 * tau), None


def _response(operator, force):
    """A^-1 f through a frame's factorised operator: ``G A_r^-1 G^T f`` when reduced.

    The error budget compares reduced and full steps with the frame's predicted contact impulses
    applied (:meth:`ClusteringReducer._controlled_frame`): contact resolution then removes only
    what changed since the last frame. Without them the steady support of a body at rest, which
    the elastic step alone does not see, would count as the reduction's error: in full space the
    elastic step pushes the supported vertices into the ground and contact pushes them back.
    """
    if operator.G is None:
        return np.asarray(operator.solver.solve(force)).ravel()
    return operator.G @ np.asarray(operator.solver.solve(operator.G.T @ force)).ravel()


def frame_cost(judged, rec):
    """(judged, cost) as the never-slower fall-back compares frames: the process's CPU seconds when the
    frame's record has them (``rec["cpu"]``, every thread of the process; the parts in ``judged``
    measured on the same clock), else its wall seconds.

    On a loaded machine the wall time of a frame scatters by 2-3x with the load from other processes,
    which the CPU time does not count: judged on it, a fall-back decides the same under any load
    (measured in ``docs/budget.md``)."""
    if "cpu" not in rec or ("reduced" in judged and "reduced_cpu" not in judged):
        return judged, float(rec["wall"])
    if "reduced" in judged:
        judged = dict(judged, reduced=judged["reduced_cpu"], full=judged["full_cpu"])
    return judged, float(rec["cpu"])


def _speed(problem):
    """The largest vertex speed at the start of the frame (m/s)."""
    v = np.asarray(problem.v, float).reshape(-1, 3)
    return float(np.sqrt(np.max(np.einsum("ij,ij->i", v, v)))) if v.size else 0.0


def elements_touching(system, mask):
    """Elements with at least one vertex in the vertex mask."""
    return np.any(mask[system.t], axis=0)


class ClusteringReducer(Reducer):
    """Affine or rigid bodies chosen every frame from the predicted velocities (Algorithm 1).

    Subclasses define :meth:`_labels` (which elements are reduced, and how they group) and
    :meth:`_mapping` (G of their body kind). The arguments the two methods share have the
    same names, order and meaning:

    Parameters
    ----------
    tau_e : float
        Threshold for previously reduced elements to stay reduced (on the predicted velocities).
    min_fraction : float
        Resource limiting (sec. 3.5): at least this fraction of the elements is forced into bodies.
    seeding : {"random", "index", "temporal"}
        Order in which clusters are grown.
    preconditioner : {"ichol", "amg"}
        Factorisation of A_p (eq. 14) used by the one-iteration PCG oracle.
    seed : int
        Seed of the random seeding (reproducible runs).
    solver : str or solver object, optional
        Solver of the reduced system (default: the fastest direct solver).
    target_error : float or None
        The error budget (None: explicit thresholds); see :mod:`skfem_affine.reducers.budget`.
    relative_to : {"response", "size", "metre"} or None
        The unit of ``target_error`` (None: ``"response"``, the largest displacement from rest).
    time_budget : float or None
        Seconds per frame; the forced fraction adapts to it.
    never_slower : bool or None
        Solve frames in full space while reduction does not pay, judged on measured frame wall
        times (``docs/budget.md``). Default (None): on with an error budget and no time budget.
    shadow_every : int
        Reduced frames per shadow frame (error budget, never slower); the period doubles, up to
        4 shadow_every, while shadow frames confirm the error estimate's calibration.
    memory : float
        Memory time T (s) of the error estimate.
    refresh : {False, True, "laplacian", "tangent"}
        Whether the oracle's preconditioner follows the pose (see Notes). False (default) keeps
        the paper's: A_p factorised once at rest. When the oracle stops predicting well,
        True or ``"laplacian"`` rebuilds A_p (the scalar Laplacian S) in the deformed
        configuration; ``"tangent"`` rebuilds it as an incomplete Cholesky of the frame's whole
        A (:class:`~skfem_affine.reducers.affine.oracle.TangentPreconditioner`), which predicts
        far better but elastifies more and is rebuilt far more often (measurements:
        docs/affinification.md, "The oracle follows the pose").
    refresh_tol : float
        Rebuild when the oracle's averaged residual has grown by more than ``refresh_tol`` times
        its value right after the last build (at least ``refresh_tol`` times :data:`RESIDUAL_FLOOR`).
    refresh_background : bool
        Build the new preconditioner in a background thread (:func:`skfem_affine.threads.background`)
        and swap it in at the first frame after it is ready; False (default) builds it between
        two frames, which keeps runs reproducible. Either way its time is recorded as
        ``oracle_refresh`` in ``sim.stats``, apart from the frame's phases.
    pinned_bodies : bool
        Whether affine bodies may contain fixed and prescribed vertices, their DOFs constrained
        by them (:mod:`skfem_affine.reducers.affine.pinned`); default False, the paper's: elements
        touching such vertices stay elastic. Affine bodies only.

    Notes
    -----
    **Refresh trigger.** Every frame the one-iteration prediction records
    ``oracle_residual`` = ||b - A dv_pred|| / ||b|| (:func:`oracle.predict`, from dot products it
    has anyway). Its exponential average over about four frames (:attr:`residual_avg`) is
    compared with the first value measured after the preconditioner was last built
    (:attr:`residual_ref`); when it has grown by more than ``refresh_tol * max(residual_ref,
    RESIDUAL_FLOOR)``, the preconditioner is rebuilt at the current pose, and the reference restarts. State a checkpoint must keep:
    :attr:`precond` (or the pose :attr:`precond_pose` to rebuild it), :attr:`residual_ref`,
    :attr:`residual_avg`, :attr:`refreshes`; a pending background build is dropped.
    """

    integrators = ("linearized",)
    #: The threshold the error budget drives, its start and bounds (the subclass's unit).
    threshold = "tau"
    tau_start, tau_min, tau_max = 1e-3, 1e-8, 1e3
    #: Whether the body kind's G depends on the clusters alone (not on the pose): a frame with the
    #: last frame's clusters then reuses its mapping (:meth:`_frame_mapping`).
    mapping_from_rest = False

    # carried across frames: who was reduced, the clusters and seeds, the random seeding's generator
    _state_keys = ("was_reduced", "labels", "previous_seeds", "rng_state", "controllers", "refresh_counters",
                   "precond_pose_state")

    #: The controllers' attribute names; their state is plain numbers (checkpoints save it).
    CONTROLLERS = ("error_budget", "timer", "pays", "shadows")
    #: No controller until :meth:`attach` sets them up from the reducer's budgets.
    error_budget = timer = pays = shadows = None
    #: The largest vertex speed when a probe of the fall-back last found bodies settling (0: none; -1:
    #: the coming probe is the early one it allowed, whose failure does not allow another).
    settling_speed = 0.0

    @property
    def controllers(self):
        """The budgets' state as plain numbers, {controller: {attribute: value}} plus the thresholds:
        what a checkpoint saves to resume a controlled run. Setting it (after
        :meth:`~skfem_affine.reducers.base.Reducer.attach`) restores them."""
        state = budgets.controllers_state(self, self.CONTROLLERS)
        state["thresholds"] = {self.threshold: float(getattr(self, self.threshold)), "tau_e": float(self.tau_e),
                               "min_fraction": float(self.min_fraction),
                               "settling_speed": float(self.settling_speed)}
        return state

    @controllers.setter
    def controllers(self, state):
        budgets.restore_controllers(self, state, own="thresholds")

    @property
    def refresh_counters(self):
        """The refresh trigger's numbers (class Notes): ``residual_ref``, ``residual_avg``, ``refreshes``."""
        return {"residual_ref": self.residual_ref, "residual_avg": self.residual_avg, "refreshes": self.refreshes}

    @refresh_counters.setter
    def refresh_counters(self, state):
        self.residual_ref, self.residual_avg = state["residual_ref"], state["residual_avg"]
        self.refreshes = int(state["refreshes"])

    @property
    def precond_pose_state(self):
        """The pose (n, 3) the oracle's preconditioner was built at, None at rest; setting it rebuilds
        the preconditioner there (a pending background build is dropped)."""
        return None if self.precond_pose is None else np.array(self.precond_pose)

    @precond_pose_state.setter
    def precond_pose_state(self, pose):
        self._pending = None
        if pose is None:
            if self.precond_pose is not None:
                model = self.model
                self.precond = oracle.Preconditioner(model.system, model.dt, model.damping,
                                                     kind=self.preconditioner_kind)
            self.precond_pose = None
        else:
            self.precond_pose = real_array(pose, "precond_pose_state", shape=(self.model.system.n, 3))
            self.precond = self._build(self.precond_pose)

    @property
    def rng_state(self):
        """The random seeding generator's state (a dict of integers)."""
        return self.rng.bit_generator.state

    @rng_state.setter
    def rng_state(self, state):
        self.rng.bit_generator.state = state

    def state_dict(self):
        """The listed attributes and the factorisations' histories later frames depend on: the
        frame solver's (e.g. an AMG hierarchy, a Pardiso ordering), the per-body blocks' and the
        full-space handle's orderings."""
        state = super().state_dict()
        for prefix, part in self._solver_parts().items():
            state.update({f"{prefix}.{k}": v for k, v in part.state_dict().items()})
        return state

    def load_state_dict(self, state):
        super().load_state_dict(state)
        for prefix, part in self._solver_parts().items():
            saved = {k[len(prefix) + 1:]: v for k, v in state.items() if k.startswith(prefix + ".")}
            if saved:  # files written before a part saved its state lack it
                part.load_state_dict(saved)

    def _solver_parts(self):
        """The solvers whose state a checkpoint keeps, by key prefix."""
        parts = {"solver": self.solver, "blocks": self.blocks, "full_handle": self.full_handle}
        return {k: v for k, v in parts.items() if hasattr(v, "state_dict")}

    def __init__(self, tau_e, *, min_fraction=0.0, seeding="random", preconditioner="ichol", seed=0, solver=None,
                 target_error=None, time_budget=None, never_slower=None, shadow_every=10, memory=0.5,
                 refresh=False, refresh_tol=0.2, refresh_background=False, pinned_bodies=False, relative_to=None):
        self.target_error = target_error
        self.relative_to = None if target_error is None else budgets.error_unit(relative_to)
        if target_error is not None:
            tau_e = 2.0 * self.tau_start
            setattr(self, self.threshold, self.tau_start)
        self.tau_e = check_threshold(tau_e, "tau_e")
        self.time_budget = None if time_budget is None else positive(time_budget, "time_budget")
        # a time budget bounds the frames itself; falling back to full space would miss any budget under a full frame
        default = target_error is not None and self.time_budget is None
        self.never_slower = default if never_slower is None else flag(never_slower, "never_slower")
        self.shadow_every = integer(shadow_every, "shadow_every", low=1)
        self.memory = positive(memory, "memory")
        self.controlled = target_error is not None or self.time_budget is not None or self.never_slower
        self.preconditioner_kind = choice(preconditioner, "preconditioner", tuple(oracle.KINDS))
        self.min_fraction = min_fraction
        self.seeding = choice(seeding, "seeding", SEEDINGS)
        self.seed = None if seed is None else integer(seed, "seed", low=0)
        self.solver_spec = solver
        if isinstance(refresh, str):
            refresh = choice(refresh, "refresh", ("laplacian", "tangent"))
        elif refresh is not None:  # True: the Laplacian refresh
            refresh = "laplacian" if flag(refresh, "refresh (False, True, 'laplacian' or 'tangent')") else False
        self.refresh = refresh or False
        self.refresh_tol = check_threshold(refresh_tol, "refresh_tol")
        self.refresh_background = flag(refresh_background, "refresh_background")
        pinned_bodies = flag(pinned_bodies, "pinned_bodies")
        if pinned_bodies and getattr(self, "kind", None) is not reduction.AFFINE:
            raise ValueError("pinned_bodies needs affine bodies (Affinification)")
        self.pinned_bodies = pinned_bodies

    def _setup(self, model):
        sysm = model.system
        self.rng = np.random.default_rng(self.seed)
        self.adjacency = clustering.element_adjacency(sysm.t)
        # the paper's: elements touching fixed or prescribed vertices stay elastic; with pinned_bodies
        # they may join bodies, whose DOFs are then constrained (:mod:`.pinned`)
        self.excluded = np.zeros(sysm.m, dtype=bool) if self.pinned_bodies else elements_touching(sysm, sysm.fixed)
        self.was_reduced = np.zeros(sysm.m, dtype=bool)
        self.previous_seeds = None
        self.labels = np.full(sysm.m, -1, dtype=np.int64)
        self.precond = oracle.Preconditioner(sysm, model.dt, model.damping, kind=self.preconditioner_kind)
        # the refresh trigger's state (plain attributes; see the class Notes)
        self.precond_pose = None  # positions the preconditioner was built at; None: rest
        self.residual_ref = self.residual_avg = None
        self.refreshes = 0
        self._pending = None  # (future, pose) of a background build
        self.solver = make_solver(self.solver_spec if self.solver_spec is not None else "direct")
        self.upper = getattr(self.solver, "accepts_upper", False)  # a Cholesky reads one triangle
        # frames reducing few DOFs solve A_r through A's factorisation, kept on this handle (:mod:`.constrained`)
        self.full_handle = Pardiso() if type(self.solver) is Pardiso else None
        self.constraints_max = constrained.CONSTRAINTS_MAX  # -1: never
        self.blocks = blocks.BodyBlocks()  # a frame of several scene bodies, factorised per body (None: whole)
        # a fill-reducing order of the free vertices, inherited by every frame's reduced system
        self.vertex_rank = reduction.nested_dissection_rank(sysm) if self.upper else None
        self.mdiag = sysm.Mff.diagonal()
        # several bodies: a reduced frame numbers its unknowns as full space does (:mod:`.numbering`)
        self.full_numbering = several_bodies(self._contact_bodies)
        self.gravity_dv = np.tile(model.gravity, sysm.n)[sysm.free] * model.dt
        self.translations = oracle.body_translations(sysm)
        self._kept = None  # the last frame's mapping and what derives from it (_frame_mapping)
        self._setup_controllers()

    def _setup_controllers(self):
        """The controllers of :mod:`~skfem_affine.reducers.budget` (plain-number state) and the shadow solver."""
        self.error_budget = self.timer = self.pays = self.shadows = self.full_solver = None
        self._judged = None  # the frame's costs, for the fall-back once its whole cost is known (end_frame)
        self.settling_speed = 0.0  # the largest vertex speed when a probe found bodies settling (class attribute)
        self.min_fraction_floor = self.min_fraction
        if not self.controlled:
            return
        if self.target_error is not None:
            self.error_budget = budgets.ErrorBudget(self.target_error, self.tau_start, memory=self.memory,
                                                    tau_min=self.tau_min, tau_max=self.tau_max, ramp_grow=4.0,
                                                    relative_to=self.relative_to)
            self._set_thresholds(self.tau_start)
        if self.time_budget is not None:
            self.timer = budgets.TimeBudget(self.time_budget, self.min_fraction)
        if self.never_slower:
            # judged on whole frames (end_frame): the least of the latest 5 of each kind, and a full
            # frame solved beside the reduced ones confirms a fall-back, so that load from elsewhere
            # does not decide
            self.pays = budgets.PaysOff(window=5, confirm=True, trial_frames=3)
        if self.error_budget is not None or self.pays is not None:
            self.shadows = budgets.ShadowClock(self.shadow_every)
            spec = self.solver_spec if self.solver_spec is None or isinstance(self.solver_spec, str) else "direct"
            self.full_solver = make_solver(spec if spec is not None else "direct")

    def _set_thresholds(self, tau):
        """The error budget's threshold: ``tau`` to become reduced, 2 tau to stay."""
        setattr(self, self.threshold, float(tau))
        self.tau_e = 2.0 * float(tau)

    def end_frame(self, rec):
        """The time budget takes the frame's wall time; ``rec["time_budget_miss"]`` records a miss.

        Only reduced frames steer the forced fraction: a frame solved in full space (a shadow, an
        impact, the fall-back) takes a full solve whatever the fraction.
        """
        if self.timer is not None and "wall" in rec:
            rec["time_budget_miss"] = bool(self.timer.observe(rec["wall"], steered=rec.get("reduced", True)))
            rec["min_fraction_next"] = float(self.timer.fraction)
        if self.error_budget is not None:  # an estimate over the budget is warned at the first frame it is
            self.error_budget.warn_passed(rec.get("frame"))
        judged, self._judged = self._judged, None
        if self.pays is not None and judged is not None and "wall" in rec:
            self._judge(*frame_cost(judged, rec))
            rec["reduction_pays"] = not self.pays.in_full

    def _judge(self, judged, cost):
        """Feed the fall-back the frame's cost and let it decide (never slower than full space).

        The costs compared (CPU seconds of the process, or wall seconds: :func:`frame_cost`) are whole
        frames, as a full-space run pays them (integrator, contact and checks included): a frame
        solved in full space is a full frame (one that confirms a fall-back replaces the running
        full cost); a shadow frame or a probe is a reduced frame plus a full solve, so it gives
        both, the full frame as its cost minus the reduced part and the reduced frame as its cost
        minus the full solve. A probe that reduced is judged by the reduced frames after it, the
        trial (the least cost of three): a shadow frame resolves contact through the full-space
        operator, at a full frame's contact cost, and the first reduced frame pays new analyses. A
        probe or a trial whose own error, kept up, would take the estimate over the error budget
        fails whatever its cost (bodies still settling): the threshold shrinks, and the frames after
        it would reduce less. The next probe then comes as soon as the largest vertex speed is under
        :data:`SETTLED` times its value at the failure (once per such failure), else after the wait.
        """
        pays, kind = self.pays, judged["kind"]
        if kind in ("full", "confirm"):
            pays.full_solved(cost, fresh=kind == "confirm")
            if kind == "confirm":
                pays.decide(self.shadows.every, confirmed=True)
            elif self.settling_speed > 0 and judged.get("speed", np.inf) < SETTLED * self.settling_speed:
                pays.wait, self.settling_speed = 0, -1.0  # the bodies have slowed down: probe at the next frame
            return
        if kind in ("shadow", "probe") or judged["full"]:  # a refused trial is a shadow frame too
            pays.full_solved(cost - judged["reduced"])
            pays.shadow_added(judged["full"])
            cost -= judged["full"]
            if kind == "probe" and judged["dof_ratio"] < pays.keep_dofs and judged.get("settled", True):
                pays.await_trial()
                return
        probe = kind in ("probe", "trial")
        if judged["ramp"] and not probe:
            return  # frames at a threshold still rising from its small start say nothing of the settled cost
        first = kind == "probe" or (kind == "trial" and pays.trial == pays.trial_frames)
        pays.reduced_solved(cost, judged["dof_ratio"], fresh=first)
        settled = judged.get("settled", True)
        if kind == "trial" and pays.trial > 1 and settled and not judged["full"]:
            pays.trial -= 1  # more trial frames to come: their least cost decides
            return
        pays.decide(self.shadows.every, probed=probe, settled=settled)
        if probe:  # one that failed on its error (bodies still settling) allows one early probe
            early, self.settling_speed = self.settling_speed < 0, 0.0
            if pays.in_full and not settled and not early:  # one early probe per failed one, not a series
                self.settling_speed = judged.get("speed", 0.0)

    # -------------------------------------------------------------- frame
    def solve(self, problem):
        """Algorithm 1 on one :class:`~skfem_affine.integrators.problem.StepProblem`."""
        with serial_blas():
            if self.controlled:
                return self._controlled_frame(problem)
            return self._frame(problem)

    # ------------------------------------------------------- controlled frame
    def _full(self, problem, stats, schur=False):
        """A dv = b in full space with the shadow solver; returns (dv, operator, seconds).

        ``schur``: a frame solved in full space alone (not a shadow) is factorised as the full-space
        run factorises it (:func:`contact_factorization`): with contacts, their unknowns last where
        contact's Schur inverse accepts, so that its Delassus operator costs what full space pays
        for it, not a factorisation of its own. A shadow frame is not: the reduced frame's
        operator, which it solves with after, may be on the same Schur handle."""
        t0 = time.perf_counter()
        A = problem.matrix()
        b = problem.b
        t1 = time.perf_counter()
        part = {}
        out = None if not schur else contact_factorization(self._contact_schur, self._contact_bodies,
                                                           self.full_solver, problem.contacts, A)
        if out is None:
            dv, op = factorize_and_solve(self.full_solver, A, b, part), Operator(self.full_solver, A)
        else:
            handle, keep, S = out
            t2 = time.perf_counter()
            dv = handle.solve(b)
            part.update(factorization=t2 - t1, solve=time.perf_counter() - t2)
            op = Operator(handle, A, schur=(keep, S))
            stats["frame_schur"] = int(keep.size)
        seconds = time.perf_counter() - t0
        for key in ("factorization", "solve"):
            stats[key] = stats.get(key, 0.0) + part[key]
        stats["assembly"] = stats.get("assembly", 0.0) + t1 - t0
        stats["full_solve"] = seconds
        if self.timer is not None:
            self.timer.full_cost = seconds
        return dv, op, seconds

    def _controlled_frame(self, problem):
        """Plan the frame (full, reduced, or reduced with a shadow), solve it, feed the controllers."""
        model, sysm = problem.model, problem.system
        h, eb, pays = model.dt, self.error_budget, self.pays
        if self.timer is not None:
            self.min_fraction = self.timer.fraction
        mode = pays.plan() if pays is not None else "reduced"
        # the budget's unit (m) this frame: the response so far, the scene size, or a metre
        unit = eb.scale(model.size, budgets.largest_displacement(problem.x, sysm.p0)) if eb is not None else model.size
        if eb is not None and mode not in ("full", "confirm") and self._new_contacts(problem):
            mode = "impact"
        if mode in ("full", "confirm", "impact"):
            stats = {}
            dv, op, seconds = self._full(problem, stats, schur=True)
            if pays is not None:
                self._judged = {"kind": "confirm" if mode == "confirm" else "full", "speed": _speed(problem)}
            if eb is not None:
                eb.decay(h)
                if mode == "full":  # the fall-back: the probe to come tries a larger threshold
                    eb.idle()
            self.was_reduced = np.zeros(sysm.m, dtype=bool)
            self.labels = np.full(sysm.m, -1, dtype=np.int64)
            stats.update(dofs=op.shape[0], solver=self.full_solver.name, n_clusters=0, elastic_dofs=op.shape[0],
                         reduced_fraction=0.0, reduced=False, shadow=False, impact=mode == "impact")
            self._record(stats)
            return StepResult(dv=dv, operator=op, clusters=self.labels, stats=stats)
        if eb is not None:
            self._set_thresholds(eb.tau)
        t0, c0 = time.perf_counter(), time.process_time()
        result = self._frame(problem)
        stats = result.stats
        proxy = 0.0
        support = problem.contact_impulse if np.any(problem.contact_impulse) else None
        if eb is not None and stats["n_clusters"]:
            t_est = time.perf_counter()
            apply_A = oracle.system_operator(self.mdiag, problem.Hmat, model.coefficients)
            dv, b = result.dv, problem.b
            if support is not None:  # the step with the predicted support impulses, as contact will end it
                dv, b = dv + _response(result.operator, support), b + support
            e = oracle.predict(apply_A, b - apply_A(dv), self.precond)
            proxy = budgets.vertex_max_norm(e, sysm.free, sysm.n)
            stats["estimation"] = time.perf_counter() - t_est
            stats["prediction"] += stats["estimation"]
        reduced_seconds, reduced_cpu = time.perf_counter() - t0, time.process_time() - c0
        initial = self.shadows is not None and self.shadows.first > 0
        # a trial (the frame after a probe) is judged as a plain reduced frame: a shadow only if refused
        shadow = mode == "probe" or (mode != "trial" and self.shadows is not None and self.shadows.due())
        gap = self._integration_gap(problem, result) if eb is not None and stats["n_clusters"] else 0.0
        refused = not shadow and eb is not None and stats["n_clusters"] > 0 and eb.breaks(eb.local(proxy) + gap, h)
        shadow = shadow or refused  # the reduced step would break the budget: solved again in full space
        if shadow and not initial and mode != "probe" and self.timer is not None \
                and not self.timer.fits(self.timer.full_cost):
            shadow = False  # the time budget wins: a full solve on top of the frame would miss it
        stats.update(reduced_dofs=stats["dofs"], shadow=bool(shadow), reduced=not shadow, refused=bool(refused))
        measured = None
        seconds = full_cpu = 0.0
        if shadow:
            c1 = time.process_time()
            dv, op, seconds = self._full(problem, stats)
            full_cpu = time.process_time() - c1
            gap = result.dv - dv
            if support is not None and stats["n_clusters"]:
                gap += _response(result.operator, support) - _response(op, support)
            measured = budgets.vertex_max_norm(gap, sysm.free, sysm.n) if stats["n_clusters"] else 0.0
            if eb is not None and measured > 0:  # how far this velocity error will carry the vertices
                t_amp = time.perf_counter()
                eb.propagated(*budgets.kick_response(op.solver.solve, sysm.Mff, problem.Hmat, gap, h, sysm.free,
                                                     sysm.n, eb.memory))
                stats["estimation"] = stats.get("estimation", 0.0) + time.perf_counter() - t_amp
                stats["prediction"] += time.perf_counter() - t_amp
            stats.update(dofs=op.shape[0], solver=self.full_solver.name, local_error_measured=measured / unit)
            result = StepResult(dv=dv, operator=op, clusters=np.full(sysm.m, -1, dtype=np.int64), stats=stats)
        ramp = eb is not None and eb.ramping  # this frame's threshold is still on its way up
        settled = True  # the frame's own error, kept up, stays within the budget: the frames after reduce as much
        if eb is not None:
            delta = eb.local(proxy, measured) + (0.0 if shadow else gap)
            if shadow and self.shadows is not None:
                self.shadows.settled(eb.stable and eb.estimate < eb.goal)
            eb.advance(delta, h, model.size, introduced=not shadow)
            stats["local_error"] = delta / unit
            reducible = 1.0 - float(np.mean(self.excluded)) if sysm.m else 0.0
            eb.adapt(saturated=stats["reduced_fraction"] >= reducible - 1e-9)
            settled = eb.steady <= eb.target
        if pays is not None:  # judged in end_frame, on the frame's cost (frame_cost)
            self._judged = {"kind": mode if mode in ("probe", "trial") else "shadow" if shadow else "reduced",
                            "speed": _speed(problem),
                            "reduced": reduced_seconds, "full": seconds, "reduced_cpu": reduced_cpu,
                            "full_cpu": full_cpu, "ramp": ramp, "settled": settled,
                            "dof_ratio": stats["reduced_dofs"] / max(sysm.free.size, 1)}
        self._record(stats)
        return result

    def _integration_gap(self, problem, result):
        """max_i ||x_i(body kind's update) - (x_i + h v_i)|| / h (m/s) of a reduced frame: rigid bodies
        rotate exactly while the full-space step moves along v, a difference in position the
        velocity error does not see; zero for affine bodies (their update is x + h v)."""
        if self.kind is not reduction.RIGID or result.mapping is None:
            return 0.0
        sysm, h = problem.system, problem.model.dt
        v = np.array(problem.v, dtype=float).reshape(-1)
        v[sysm.free] += result.dv
        x, v = np.asarray(problem.x, float).reshape(-1, 3), v.reshape(-1, 3)
        return budgets.largest_displacement(result.positions(x, v, h), x + h * v) / h

    @staticmethod
    def _new_contacts(problem):
        """Whether the frame has an impact the oracle cannot foresee: a contact of a free vertex that
        closes its gap faster than one step of gravity
        (``ContactSet.impact``, set by the contact solver).

        Such a frame is solved in full space under an error budget: the reduced step's error is
        estimated before contact is resolved, so a body reduced whole through an impact would
        carry the impact's error unseen. The steady, warm-started support of a body at rest is
        no impact, so resting bodies stay reduced.
        """
        cs = problem.contacts
        if cs is None or not cs.size or cs.impact is None:
            return False
        sysm = problem.system
        free = np.zeros(sysm.n, dtype=bool)
        free[sysm.free // 3] = True
        return bool(np.any(cs.impact & free[cs.vertex]))

    def _record(self, stats):
        """The controllers' state in the frame's statistics."""
        eb = self.error_budget
        if eb is not None:
            stats["estimated_error"] = float(eb.estimate)
            stats["amplification"] = float(eb.amplification)
            stats["carry"] = float(eb.carry)
            stats["error_unit"] = float(eb.unit)
        stats["tau_a"] = float(getattr(self, self.threshold))
        stats["tau_e"] = float(self.tau_e)
        stats["min_fraction"] = float(self.min_fraction)
        if self.pays is not None:
            stats["reduction_pays"] = not self.pays.in_full

    def _frame(self, problem):
        model, sysm = problem.model, problem.system
        h, free = model.dt, sysm.free
        stats = {}
        t1 = time.perf_counter()
        # prediction (eq. 13-14): one PCG iteration, gravity split out, A p = M p + H p (A never formed)
        b = problem.b
        # contact impulses as explicit forces: the support, and new contacts' estimates on bodies an impact hits
        b_ng = b - h * model.f_gravity[free] + oracle.explicit_impulse(problem)
        apply_A = oracle.system_operator(self.mdiag, problem.Hmat, model.coefficients)
        if self._pending is not None:
            self._swap_if_ready(stats)
        # with steady support, from the bodies' mean response to it (two-level guess): a body at rest on
        # its support is predicted at rest, support and elastic forces balancing its weight; a new
        # contact's impulse is left to the PCG step, which sees it as the local push it is. Explicit
        # thresholds only: under an error budget the paper's oracle stays (docs/contact.md, the
        # resting pills: the stacked beams then reduce more and their sensitivity breaks the budget)
        x0 = None
        if self.target_error is None and np.any(problem.support_impulse):
            x0 = oracle.coarse_guess(self.translations, self.mdiag, problem.Hmat, model.coefficients,
                                     b - h * model.f_gravity[free] + problem.support_impulse)
        dv_pred = oracle.predict(apply_A, b_ng, self.precond, gravity_dv=self.gravity_dv, stats=stats, x0=x0)
        t2 = time.perf_counter()
        stats["prediction"] = t2 - t1
        if self.refresh and "oracle_residual" in stats:
            self._refresh_trigger(problem, stats)
            t2 = time.perf_counter()
        # deformation rates (eq. 4) and clustering (Algorithm 2)
        v_pred = problem.v.copy()
        v_pred.reshape(-1)[free] += dv_pred
        labels = self._labels(problem, v_pred)
        vcluster = reduction.vertex_clusters(labels, sysm.t, sysm.n)
        n_bodies = int(labels.max()) + 1 if labels.size and labels.max() >= 0 else 0
        t3 = time.perf_counter()
        stats["clustering"] = t3 - t2
        # map assembly: G, projection (eq. 9), discrepancy (eq. 11)
        kept = self._frame_mapping(problem, labels, vcluster, n_bodies)
        gmap = kept["gmap"]
        if self.pinned_bodies and n_bodies and np.any(sysm.fixed[vcluster >= 0]):
            return self._pinned_frame(problem, labels, gmap, stats, t3)
        G = gmap.G
        vf = problem.v.reshape(-1)[free]
        q = gmap.project(self.mdiag, vf) if n_bodies else vf  # eq. 9
        d = reduction.discrepancy(G, q, vf) if n_bodies else np.zeros_like(vf)  # eq. 11
        t4 = time.perf_counter()
        stats["map_assembly"] = t4 - t3
        # reduced system (eq. 10) with the projected velocities
        order = None
        if n_bodies:
            vp = problem.v.copy()
            vp.reshape(-1)[free] += d
            # a rigid body's interior adds nothing to its 6 DOFs (self-equilibrated forces, strain a rigid motion
            # keeps): left out of its reduced system, so that it moves by rigid-body dynamics
            reduced = problem.without_elements(reduction.interior_elements(vcluster, sysm.t)) \
                if self.kind is reduction.RIGID else problem
            Ar = reduction.reduced_matrix(model, reduced.data, gmap, upper=self.upper)
            br = G.T @ reduced.rhs(vp)
            if self.vertex_rank is not None:
                if "order" not in kept:
                    kept["order"] = gmap.elimination_order(self.vertex_rank)
                order = kept["order"]
        else:
            Ar, br = problem.matrix(), b
        dofs, num = Ar.shape[0], None
        if n_bodies and self.full_numbering:  # each scene body's unknowns where full space has them
            if "num" not in kept:
                kept["num"] = FullNumbering(gmap, model.coefficients[0] * self.mdiag)
                kept["num_order"] = None if order is None else kept["num"].order(order)
            num = kept["num"]
            Ar, br, G = num.matrix(Ar), num.vector(br), num.mapping(G)
            order = kept["num_order"]
        t5 = time.perf_counter()
        stats["reduced_assembly"] = t5 - t4
        upper = bool(self.upper and n_bodies)
        # with contacts on one body, the factorisation with the unknowns they touch last (through G)
        # also leaves the Schur complement the Delassus operator needs
        solver, schur = self.solver, contact_factorization(self._contact_schur, self._contact_bodies, self.solver,
                                                           problem.contacts, Ar, G, upper=upper)
        if schur is not None:
            solver, schur = schur[0], schur[1:]
            stats["frame_schur"] = int(schur[0].size)
        elif n_bodies and num is not None and order is not None and self.blocks is not None \
                and isinstance(solver, Pardiso) and not solver.analysed_for(Ar, upper):
            # several bodies, a new pattern: one block per body, analysed again where its clusters changed,
            # with the unknowns its contacts touch last where contact's Schur inverse accepts
            solver = self.blocks
            solver.factorize(Ar, blocks.unknown_labels(self._contact_bodies, num, gmap.width), order,
                             **self._body_schur(problem.contacts, G))
            stats["blocks_analysed"] = solver.analyses
            if solver.complements is not None:
                schur = solver.complements
                stats["frame_schur"] = int(schur[0].size)
        elif n_bodies and self._through_full(labels, gmap, Ar, upper):
            solver = self._constrained_solver(problem, gmap, num)
            stats["through_full"] = True
        elif upper:
            solver.factorize(Ar, upper=True, order=order)
        else:
            solver.factorize(Ar)
        t6 = time.perf_counter()
        dq = solver.solve(br)
        t7 = time.perf_counter()
        stats.update(factorization=t6 - t5, solve=t7 - t6, dofs=dofs, solver=self.solver.name,
                     iterations=solver.last_iterations, n_clusters=n_bodies, elastic_dofs=int(gmap.n_elastic),
                     reduced_fraction=float(np.mean(labels >= 0)) if labels.size else 0.0)
        self.was_reduced = labels >= 0
        self.labels = labels
        return StepResult(dv=reduction.lift(G, dq, d), operator=Operator(solver, Ar, G, upper=upper, schur=schur),
                          mapping=gmap, clusters=labels, stats=stats)  # eq. 12

    def _frame_mapping(self, problem, labels, vcluster, n_bodies):
        """The frame's mapping as ``{"labels", "gmap"}`` (plus, once asked, its elimination order and
        full-space numbering): the last frame's when the clusters are the same and G depends on
        them alone (:attr:`mapping_from_rest`: affine bodies' rows come from the rest positions), so
        that a body at rest in the same clusters does not rebuild G, its order and numbering."""
        kept = self._kept
        if not (self.mapping_from_rest and kept is not None and np.array_equal(kept["labels"], labels)):
            kept = self._kept = {"labels": labels, "gmap": self._mapping(problem, vcluster, n_bodies)}
        return kept

    def _body_schur(self, contacts, G):
        """The arguments of :meth:`blocks.BodyBlocks.factorize` that factorise each body's block with its
        touched unknowns last (the columns of J G with a nonzero), or none: no contact, no Schur inverse,
        or its ``frame`` or ``blocks`` setting off."""
        schur = self._contact_schur
        if (schur is None or not (schur.frame and schur.blocks and schur.available) or contacts is None
                or contacts.J is None):
            return {}
        return {"touched": touched_unknowns(contacts.J @ G), "schur": schur}

    def _through_full(self, labels, gmap, Ar, upper):
        """Whether the frame solves A_r through the full A's factorisation (:mod:`.constrained`): a
        Pardiso frame solver, few constraints, and an A_r pattern neither the last frame (its clusters,
        ``labels``) nor the last analysis had."""
        if self.full_handle is None or constrained.constraints(gmap) > self.constraints_max:
            return False
        # the same clusters (so A_r's pattern) on two frames in a row: A_r is factorised, its analysis
        # then serves the frames after
        return not (np.array_equal(self.labels, labels) or self.solver.analysed_for(Ar, upper))

    def _constrained_solver(self, problem, gmap, num):
        """A_r^-1 from the factorisation of the frame's full A, kept on its own handle."""
        self.full_handle.factorize(problem.matrix())
        return constrained.ConstrainedSolver(self.full_handle, gmap, num)

    # -------------------------------------------------------------- bodies with pinned vertices
    def _pinned_frame(self, problem, labels, gmap, stats, t3):
        """The reduced step when bodies contain fixed or prescribed vertices (:mod:`.pinned`)."""
        sysm = problem.system
        for _ in range(2):  # a body whose pins do not move affinely is dissolved, once
            pins = np.flatnonzero((gmap.vcluster >= 0) & sysm.fixed)
            cons, bad = pinned.constraints(gmap, pins, pinned.pinned_velocities(problem, pins))
            if not bad:
                break
            labels = labels.copy()
            labels[np.isin(labels, bad)] = -1
            kept = np.unique(labels[labels >= 0])
            labels[labels >= 0] = np.searchsorted(kept, labels[labels >= 0])
            vcluster = reduction.vertex_clusters(labels, sysm.t, sysm.n)
            gmap = self._mapping(problem, vcluster, kept.size)
        G, g0 = pinned.constrained_mapping(gmap, cons)
        t4 = time.perf_counter()
        stats["map_assembly"] = t4 - t3
        dv, Ar = pinned.solve(problem, G, g0, self.solver, stats)
        stats["factorization"] = time.perf_counter() - t4  # assembly, factorisation and solve of G_N^T A G_N
        stats.update(n_clusters=gmap.n_bodies, elastic_dofs=int(gmap.n_elastic), pinned_bodies=len(cons),
                     reduced_fraction=float(np.mean(labels >= 0)) if labels.size else 0.0)
        self.was_reduced = labels >= 0
        self.labels = labels
        return StepResult(dv=dv, operator=Operator(self.solver, Ar, G), mapping=gmap, clusters=labels, stats=stats)

    # -------------------------------------------------------------- the oracle follows the pose
    def _refresh_trigger(self, problem, stats):
        """Update the averaged oracle residual; rebuild the preconditioner when it has grown (class Notes)."""
        rho = stats["oracle_residual"]
        if self.residual_ref is None:
            self.residual_ref = self.residual_avg = rho
            return
        self.residual_avg = 0.75 * self.residual_avg + 0.25 * rho
        grown = self.residual_avg - self.residual_ref
        if self._pending is None and grown > self.refresh_tol * max(self.residual_ref, RESIDUAL_FLOOR):
            t0 = time.perf_counter()
            pose = np.array(problem.x, dtype=float)
            A = problem.matrix() if self.refresh == "tangent" else None
            if self.refresh_background:
                from skfem_affine import threads
                self._pending = (threads.background(self._build, pose, A), pose)
            else:
                self._install(self._build(pose, A), pose)
            stats["oracle_refresh"] = time.perf_counter() - t0

    def _build(self, pose, A=None):
        """The preconditioner at ``pose`` (positions (n, 3)); A: the frame's matrix for ``"tangent"``
        (assembled at the pose when not given)."""
        model = self.model
        if self.refresh == "tangent":
            if A is None:
                sysm = model.system
                cm, ck = model.coefficients
                A = sysm.pattern.matrix(cm * sysm.mass_data + ck * model.evaluate(pose).H)
            return oracle.TangentPreconditioner(A)
        return oracle.Preconditioner(model.system, model.dt, model.damping, kind=self.preconditioner_kind, x=pose)

    def _install(self, precond, pose):
        self.precond, self.precond_pose = precond, pose
        self.residual_ref = self.residual_avg = None  # the next frame measures the new reference
        self.refreshes += 1

    def _swap_if_ready(self, stats):
        future, pose = self._pending
        if future.done():
            self._pending = None
            self._install(future.result(), pose)
            stats["oracle_refreshed"] = True

    def _labels(self, problem, v_pred):
        """Per-element body labels (m,), -1 elastic, from the problem and the predicted velocities."""
        raise NotImplementedError

    def _mapping(self, problem, vcluster, n_bodies):
        """The frame's :class:`~skfem_affine.reducers.affine.mapping.Mapping` of this body kind."""
        raise NotImplementedError

    def _seeds(self, m):
        return clustering.seed_order(m, self.seeding, rng=self.rng, previous_seeds=self.previous_seeds)
