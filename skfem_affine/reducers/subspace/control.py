r"""The error budget, time budget and never-slower fall-back of :class:`AdaptiveSubspace`.

The controllers are those of :mod:`skfem_affine.reducers.budget` (``ErrorBudget``,
``ShadowClock``, ``TimeBudget``, ``PaysOff``); this module says what the subspace reducer
feeds them and what it reads back.

* **Error budget.** The threshold the budget drives is ``eps_nodal`` (``eps_modal = 3
  eps_nodal``, :data:`MODAL_RATIO`). The local error of a step is the largest vertex norm of
  :math:`(x_{red} - x_{full}) / h`, the velocity error against a full-space Newton solve of the
  same incremental potential from the same state. It is measured on *shadow* steps (the reduced
  step, then full-space Newton; the full solution is returned) and estimated on the others by a
  proxy: the Jacobi-scaled full-space gradient at the reduced Newton loop's last iterate,
  :math:`\|D^{-1}\nabla E\|_\infty / h` with D the diagonal of
  :math:`M + w D_{damp} + w K(X)` (rest stiffness), which the shadows calibrate
  (:meth:`~skfem_affine.reducers.budget.ErrorBudget.local`) when they measure more than the
  Newton tolerance (:data:`NOISE`). A step solved in full space (the nnz rule, the deadline
  below) introduces no error, and lets eps grow only while the estimate is under its goal.
* **Time budget.** Its knob is the enrichment: the forced fraction f of
  :class:`~skfem_affine.reducers.budget.TimeBudget` caps the enriched vertices at (1 - f) of the
  free vertices (the subdomains with the largest nodal errors first).
* **Never slower.** :class:`StepCosts` (a :class:`~skfem_affine.reducers.budget.PaysOff`)
  compares the measured wall time of whole reduced steps (oracle, Schur solves, line searches,
  downdating), and of their Newton iterations, with those of full-space Newton steps. The first
  :data:`WARMUP` steps are full-space steps (they measure the full cost; the first includes the
  solver's symbolic analysis and is not counted). A reduced step that runs past the full cost
  (the *deadline*; :data:`TRIAL` of it for the first reduced step and for probes), or whose
  enrichment passes the nnz rule, stops, and the step is solved by full-space Newton from x_t,
  so a step that does not pay costs about half a full step to one full step more. Every
  ``shadow_every`` reduced steps (doubling up to 4x while reduction keeps paying), and when a
  reduced step becomes much cheaper (:data:`PHASE`), a shadow step measures the full cost
  again, so that a verdict does not rest on full steps of another phase of the run (an
  impact's). Full-space steps run outside the reduced step's BLAS thread limit, as the
  full-space run does.
"""
import numpy as np

from skfem_affine.checks import flag, integer, positive, real
from skfem_affine.reducers import budget as budgets

#: eps_modal / eps_nodal under an error budget.
MODAL_RATIO = 3.0
#: Where the error budget's eps_nodal starts, and its bounds.
EPS_START, EPS_MIN, EPS_MAX = 1e-2, 1e-6, 10.0
#: The eps of a reducer given neither thresholds nor a budget (the paper's value).
DEFAULT_EPS = 0.5
#: A shadow step calibrates the proxy only when its measured error exceeds NOISE times the Newton
#: tolerance (a velocity, ``newton_tol * size``): both solves stop within it, so smaller differences
#: are the tolerance's, and a ratio of them says nothing about the proxy.
NOISE = 2.0
#: Full-space steps before the first reduced step when the fall-back is on.
WARMUP = 2
#: While in full space, probe at once when the reduced steps measured cost at most 1 - EARLY_PROBE
#: of the full steps measured since (a hard phase made full steps dearer).
EARLY_PROBE = 0.5
#: The deadline of a reduced step that has not yet been shown to pay (the first, and probes), in
#: full steps: such a step that does not pay costs at most about this much on top of a full step.
TRIAL = 0.5
#: A reduced step that costs less than PHASE times the reduced step measured beside the latest full
#: cost is a shadow step: the run's phase changed (an impact ended), and the full cost with it.
PHASE = 0.5


def resolve(eps_nodal, eps_modal, target_error, never_slower, relative_to=None):
    """(eps_nodal, eps_modal, target_error, never_slower, relative_to) from what the user gave.

    Thresholds given (either one) switch every controller off unless asked for (a missing one is
    :data:`DEFAULT_EPS`, as before budgets existed); ``target_error`` with a threshold is refused.
    ``never_slower`` defaults to on unless a threshold is given. ``relative_to`` is the budget's
    unit (:data:`~skfem_affine.reducers.budget.ERROR_UNITS`), None without a budget.
    """
    explicit = eps_nodal is not None or eps_modal is not None
    unit = budgets.error_unit(relative_to)
    if explicit and target_error is not None:
        raise ValueError("give the thresholds (eps_nodal, eps_modal) or target_error, not both")
    if relative_to is not None and target_error is None:
        raise ValueError("relative_to is the unit of target_error; give target_error with it")
    if target_error is not None:
        target_error = budgets.target_error(target_error, unit)
        eps_nodal, eps_modal = EPS_START, MODAL_RATIO * EPS_START
    eps_nodal = DEFAULT_EPS if eps_nodal is None else eps_nodal
    eps_modal = DEFAULT_EPS if eps_modal is None else eps_modal
    never_slower = (not explicit) if never_slower is None else flag(never_slower, "never_slower")
    return eps_nodal, eps_modal, target_error, never_slower, (unit if target_error is not None else None)


class Controllers:
    """The budgets of one run of the subspace reducer and the plan of each step.

    Parameters
    ----------
    target_error, time_budget : float or None
    never_slower : bool
    relative_to : {"response", "size", "metre"}
        The unit of ``target_error``.
    shadow_every : int
        Reduced steps per shadow step (error budget); doubles up to 4x while the calibration holds.
    memory : float
        The error estimate's memory time T (s).
    """

    NAMES = ("error_budget", "timer", "pays", "shadows")

    def __init__(self, target_error=None, time_budget=None, never_slower=False, shadow_every=10, memory=0.5,
                 relative_to="response"):
        self.error_budget = self.timer = self.pays = self.shadows = None
        if target_error is not None:
            self.error_budget = budgets.ErrorBudget(target_error, EPS_START, memory=memory,
                                                    tau_min=EPS_MIN, tau_max=EPS_MAX, relative_to=relative_to)
        if time_budget is not None:
            self.timer = budgets.TimeBudget(time_budget)
        if never_slower:
            self.pays = StepCosts(patience=1)
        if target_error is not None:
            # the first reduced steps are shadows (they calibrate the proxy); after the fall-back's
            # full-space warm-up one is enough
            self.shadows = budgets.ShadowClock(shadow_every, first=1 if never_slower else 2)
        elif never_slower:  # shadows keep the full cost current (the warm-up measured it first)
            self.shadows = budgets.ShadowClock(shadow_every, first=0)
            self.shadows.since = 1  # the first after shadow_every reduced steps
        self.warmup = WARMUP if never_slower else 0
        self.phase_cost = 0.0  # the reduced step's cost where the full cost was last measured beside it
        self.last_reduced = 0.0
        self.full_before = self.full_now = True  # whether the previous / this step is a full-space step

    def plan(self):
        """"full", "probe" (a reduced step with a shadow) or "reduced" (with a shadow when due)."""
        mode = self._plan()
        self.full_before, self.full_now = self.full_now, mode == "full"
        return mode

    def _plan(self):
        if self.warmup > 0:
            self.warmup -= 1
            return "full"
        pays = self.pays
        if pays is None:
            return "reduced"
        if pays.in_full and pays.wait > 0 and pays.reduced_samples and pays.pays(self.shadow_period(), EARLY_PROBE):
            pays.wait = 0  # full steps grew twice as dear as the reduced steps measured: probe now
        return pays.plan()

    def reduced_measured(self, seconds, shadow):
        """A reduced step's cost; it is the phase's when a full cost was measured beside it (a shadow,
        or full-space steps just before)."""
        self.last_reduced = float(seconds)
        if shadow or self.full_before or not self.phase_cost:
            self.phase_cost = float(seconds)

    def shadow_period(self):
        return None if self.shadows is None else self.shadows.every

    def deadline(self):
        """Seconds a reduced step may run before the step is solved in full space (None: no limit)."""
        pays = self.pays
        if pays is None or not pays.full_samples:
            return None
        trial = pays.in_full or not pays.reduced_samples  # a probe, or the first reduced step
        return pays.full_cost * (TRIAL if trial else 1.0)

    def shadow_due(self, mode):
        if mode == "probe":
            return True
        if self.pays is not None and self.last_reduced and self.last_reduced < PHASE * self.phase_cost:
            return True  # reduced steps became much cheaper: measure the full step again
        return self.shadows is not None and self.shadows.due()

    @property
    def state(self):
        """{controller: {attribute: plain number}} (the reducer's ``controllers``, checkpoints); setting
        it restores them."""
        out = budgets.controllers_state(self, self.NAMES)
        out["plan"] = {"warmup": self.warmup, "phase_cost": self.phase_cost, "last_reduced": self.last_reduced,
                       "full_before": self.full_before, "full_now": self.full_now}
        return out

    @state.setter
    def state(self, state):
        budgets.restore_controllers(self, state, own="plan")


class StepCosts(budgets.PaysOff):
    """:class:`~skfem_affine.reducers.budget.PaysOff` for whole Newton steps: a shadow step sets the
    full cost, and reduction pays only when its Newton iterations are also cheaper than full ones.

    A full step's cost changes several-fold between phases of a run (an impact needs many more
    Newton iterations than free flight), so a running mean over an earlier phase would judge today's
    reduced steps by yesterday's full ones: a shadow measures the full step where the run is now,
    and the cost per Newton iteration, which changes little between phases, is a second test that
    needs no fresh full step.
    """

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.full_iteration = 0.0  # s per full-space Newton iteration (running mean)
        self.reduced_iteration = 0.0  # s per reduced Newton iteration (the latest step, or running mean)

    def shadow_solved(self, seconds, iterations=1):
        self.full_solved(seconds, iterations)
        if self.full_samples:
            self.full_cost = float(seconds)

    def full_solved(self, seconds, iterations=1):
        counted = self.full_seen >= 1  # the first full solve (symbolic analysis) is not a sample
        super().full_solved(seconds)
        if counted:
            per = float(seconds) / max(int(iterations), 1)
            self.full_iteration = per if not self.full_iteration else self._mix(self.full_iteration, per, 1)

    def reduced_solved(self, seconds, dof_ratio, fresh=False, iterations=1):
        per = float(seconds) / max(int(iterations), 1)
        self.reduced_iteration = per if (fresh or not self.reduced_iteration) else self._mix(self.reduced_iteration,
                                                                                              per, 1)
        super().reduced_solved(seconds, dof_ratio, fresh)

    def pays(self, shadow_every=None, margin=0.0):
        if not super().pays(shadow_every, margin):
            return False
        if not (self.full_iteration and self.reduced_iteration):
            return True
        return self.reduced_iteration <= (1.0 - margin) * self.full_iteration


def check_settings(time_budget, shadow_every, memory):
    """The budget settings checked: (time_budget or None, shadow_every, memory)."""
    return (None if time_budget is None else positive(time_budget, "time_budget"),
            integer(shadow_every, "shadow_every", low=1), positive(memory, "memory"))


def rest_stiffness_diagonal(system, project):
    """diag K(X) on the free DOFs (the proxy's scaling)."""
    rest = system.evaluate(system.p0, project=project)
    slot = system.pattern.slot.reshape(system.m, 144).ravel()
    ok = slot >= 0
    data = np.bincount(slot[ok], weights=rest.He.reshape(-1)[ok], minlength=system.pattern.nnz)
    return system.pattern.matrix(data).diagonal()


def proxy(g, diagonal, free, n, h):
    """||D^-1 g||_inf / h as a largest vertex norm (m/s): the local error's per-step estimate."""
    return budgets.vertex_max_norm(g / diagonal, free, n) / h


def capped_enrichment(add, enriched, parts, part_of, score, cap):
    """Of the subdomains ``parts`` whose free vertices ``add`` would enrich, those with the largest
    ``score`` (per vertex) while at most ``cap`` vertices are enriched in all."""
    room = int(cap) - int(enriched.sum())
    if room <= 0:
        return np.zeros_like(add)
    new = add & ~enriched
    best = np.full(parts.max() + 1, -np.inf)
    np.maximum.at(best, part_of[new], score[new])
    sizes = np.bincount(part_of[new], minlength=parts.max() + 1)
    order = parts[np.argsort(-best[parts], kind="stable")]
    take = order[np.cumsum(sizes[order]) <= room]
    return add & np.isin(part_of, take)
