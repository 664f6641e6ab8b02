"""Adaptive rigidification (Mercier-Aubin, Kry, Winter & Levin 2022), the baseline of the paper,
on the same integrator, oracle, solver and statistics as affinification so that they compare fairly."""
import numpy as np

from skfem_affine._kernels import strain_rate_norms
from skfem_affine.checks import integer
from skfem_affine.reducers.affine import clustering
from skfem_affine.reducers.affine import mapping as reduction
from skfem_affine.reducers.affine.clustered import ClusteringReducer, forced_fraction, resolve_thresholds


def strain_rates(system, x, v, dt):
    """||sym(F^T F_dot)||^2 per element (m,), F at the step midpoint x + h v / 2 (compiled, one pass)."""
    out = np.empty(system.m)
    strain_rate_norms(np.ascontiguousarray(x + 0.5 * dt * v), np.ascontiguousarray(v), system.t, system.grads, out)
    return out


class Rigidification(ClusteringReducer):
    """Adaptive rigidification baseline (Mercier-Aubin, Kry, Winter & Levin 2022).

    An element may turn rigid once its strain rate ||sym(F^T F_dot)||^2 (F at the step
    midpoint, :func:`strain_rates`) stays below ``tau_r`` for ``warmup_frames`` consecutive
    frames and the oracle's predicted strain rate stays below ``tau_e``; rigid elements stay
    rigid while the predicted strain rate stays below ``tau_e``. Rigid bodies are connected
    components of such elements (vertex-disjoint, pinned elements excluded), each with 6 DOFs
    v_i = v_c + omega x (x_i - x_c) in the current configuration; their vertices rotate
    exactly (:class:`~skfem_affine.reducers.affine.mapping.RigidBody`).

    Parameters
    ----------
    tau_r : float, optional
        Strain-rate threshold to turn elastic elements rigid.
    tau_e : float, optional
        Predicted strain-rate threshold for rigid elements to stay rigid (default 2 tau_r).
    target_error, relative_to, time_budget, never_slower
        The error budget (default 1 % of the response when no threshold is given) and its unit, the time budget (s per
        frame) and the fall-back to full space, as for :class:`~skfem_affine.Affinification`;
        the budget drives tau_r (recorded as ``tau_a`` in ``sim.stats``) and tau_e = 2 tau_r.
    warmup_frames : int
        Frames an element must stay calm before it may turn rigid.
    min_fraction : float
        Resource limiting: at least this fraction of the elements (the calmest) is eligible.
    seeding, preconditioner, seed, solver, refresh, refresh_tol, refresh_background
        As for :class:`~skfem_affine.Affinification`, in the same order.
    """

    name = "rigidification"
    kind = reduction.RIGID
    _state_keys = ClusteringReducer._state_keys + ("calm_frames",)

    threshold = "tau_r"
    tau_start = 1e-6

    def __init__(self, tau_r=None, tau_e=None, *, target_error=None, relative_to=None, time_budget=None, never_slower=None,
                 warmup_frames=3, min_fraction=None, seeding="random", preconditioner="ichol", seed=0, solver=None,
                 shadow_every=10, memory=0.5, refresh=False, refresh_tol=0.2,
                 refresh_background=False):
        self.tau_r, tau_e, target_error = resolve_thresholds(tau_r, tau_e, target_error, "tau_r", relative_to)
        self.warmup_frames = integer(warmup_frames, "warmup_frames", low=0)
        super().__init__(tau_e, min_fraction=forced_fraction(min_fraction),
                         seeding=seeding, preconditioner=preconditioner, seed=seed, solver=solver,
                         target_error=target_error, time_budget=time_budget, never_slower=never_slower,
                         shadow_every=shadow_every, memory=memory, refresh=refresh, refresh_tol=refresh_tol,
                         refresh_background=refresh_background, relative_to=relative_to)

    def __repr__(self):
        what = (f"target_error={self.target_error:g}, relative_to={self.relative_to!r}" if self.target_error is not None
                else f"tau_r={self.tau_r:g}, tau_e={self.tau_e:g}")
        return f"Rigidification({what}, warmup_frames={self.warmup_frames}, min_fraction={self.min_fraction:g})"

    def _setup(self, model):
        super()._setup(model)
        self.calm_frames = np.zeros(model.system.m, dtype=np.int64)

    def _labels(self, problem, v_pred):
        sysm, h = problem.system, problem.model.dt
        metric = strain_rates(sysm, problem.x, problem.v, h)
        predicted = strain_rates(sysm, problem.x, v_pred, h)
        calm = np.where(self.was_reduced, predicted < self.tau_e, metric < self.tau_r)
        self.calm_frames = np.where(calm, self.calm_frames + 1, 0)
        # calm during the previous ``warmup_frames`` frames and now: the first frames stay elastic
        eligible = (self.calm_frames > self.warmup_frames) & (predicted < self.tau_e)
        if self.min_fraction > 0:
            k = int(round(self.min_fraction * sysm.m))
            if k:
                eligible[np.argpartition(metric, k - 1)[:k]] = True
        return clustering.cluster_components(eligible, self.adjacency, sysm.t, sysm.n, excluded=self.excluded,
                                             seeds=self._seeds(sysm.m), min_size=2)

    def _mapping(self, problem, vcluster, n_bodies):
        """Gamma_i = [I_3, -[x_i - x_c]_x] in the current configuration (6 DOFs per body)."""
        sysm = problem.system
        return reduction.rigid_mapping(sysm.free, vcluster, problem.x, sysm.lumped_mass, n_bodies)
