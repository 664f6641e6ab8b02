"""Adaptive affinification (paper sec. 3, Algorithm 1-2): elements with alike deformation rates
become affine bodies of 12 DOFs for one frame."""
import numpy as np

from skfem_affine._kernels import deformation_gradients
from skfem_affine.checks import integer
from skfem_affine.reducers.affine import clustering
from skfem_affine.reducers.affine import mapping as reduction
from skfem_affine.reducers.affine.clustered import ClusteringReducer, forced_fraction, resolve_thresholds


def element_rates(v, t, grads):
    """F_dot (k, 3, 3) of the k elements of connectivity ``t`` (4, k) and shape gradients ``grads``."""
    out = np.empty((t.shape[1], 3, 3))
    deformation_gradients(np.ascontiguousarray(v, dtype=float), np.ascontiguousarray(t), np.ascontiguousarray(grads),
                          out)
    return out


class Affinification(ClusteringReducer):
    """Adaptive affinification (paper sec. 3, Algorithm 1-2).

    Parameters
    ----------
    tau_a : float, optional
        Threshold on the deformation-rate distance (eq. 6) to turn elastic elements affine (1/s).
    tau_e : float, optional
        More permissive threshold for elements that were affine to stay affine (default 2 tau_a).
    target_error : float, optional
        The error budget: the largest vertex distance to the full-space run accepted, in the unit
        ``relative_to``. The reducer then chooses tau_a (and tau_e = 2 tau_a) frame by frame
        (:mod:`skfem_affine.reducers.budget`). Given no thresholds and no budget, the budget is
        :data:`~skfem_affine.reducers.budget.DEFAULT_TARGET_ERROR` (1 % of the response). Thresholds
        and a budget together are refused.
    relative_to : {"response", "size", "metre"}, optional
        The unit of ``target_error``: ``"response"`` (default), the largest displacement of a vertex
        from the rest pose so far in the run (a tip deflection, a fall); ``"size"``, the diagonal of
        the scene's rest bounding box; ``"metre"``, absolute.
    time_budget : float, optional
        Seconds per frame: the forced fraction (``min_fraction``) adapts each frame so that frames
        stay under it; misses are recorded in ``sim.stats`` (``"time_budget_miss"``).
    never_slower : bool, optional
        Solve frames in full space while reduction does not pay (measured), probing it again
        periodically. Default: on with an error budget and no time budget (a time budget bounds
        the frames itself), off with explicit thresholds.
    min_fraction : float
        Resource limiting (sec. 3.5): at least this fraction of the elements is forced into
        clusters.
    seeding : {"random", "index", "temporal"}
    preconditioner : {"ichol", "amg"}
        Factorisation of A_p (eq. 14) used by the one-iteration PCG oracle.
    seed : int
        Seed of the random seeding (reproducible runs).
    solver : str, optional
        Solver of the reduced system (default: the fastest direct solver).
    min_body_elements : int
        Clusters of fewer elements are dissolved (>= 2: a single element is never a body).
    refresh, refresh_tol, refresh_background
        Whether and when the oracle's preconditioner is rebuilt at the current pose
        (:class:`~skfem_affine.reducers.affine.clustered.ClusteringReducer`); default False,
        the paper's preconditioner factorised once at rest.
    pinned_bodies : bool
        Let affine bodies contain fixed and prescribed vertices, their 12 DOFs constrained by
        them (:mod:`skfem_affine.reducers.affine.pinned`; four or more non-coplanar pins
        prescribe the body entirely). Default False: as the paper, elements touching such
        vertices stay elastic.

    Notes
    -----
    The thresholds come first and positionally; the arguments shared with
    :class:`~skfem_affine.Rigidification` follow, keyword-only, in the same order. With a
    budget, ``sim.stats`` records per frame ``estimated_error``, ``tau_a``, ``tau_e``,
    ``reduced`` (the frame returned the reduced solution), ``shadow`` and ``min_fraction``.

    Examples
    --------
    >>> import skfem_affine as sa
    >>> sa.Affinification(0.1, 0.2).target_error is None        # explicit thresholds, as given
    True
    >>> sa.Affinification().target_error                         # the default budget: 1 % of the response
    0.01
    >>> sa.Affinification(target_error=0.002, relative_to="metre").relative_to  # 2 mm
    'metre'
    >>> sa.Affinification(target_error=0.003, time_budget=0.05).time_budget
    0.05
    """

    name = "affinification"
    kind = reduction.AFFINE

    threshold = "tau_a"
    tau_start = 1e-3
    mapping_from_rest = True  # Gamma_i from the rest positions (eq. 8)

    def __init__(self, tau_a=None, tau_e=None, *, target_error=None, relative_to=None, time_budget=None, never_slower=None,
                 min_fraction=None, seeding="random", preconditioner="ichol", seed=0, solver=None,
                 min_body_elements=2, shadow_every=10, memory=0.5, refresh=False,
                 refresh_tol=0.2, refresh_background=False, pinned_bodies=False):
        self.tau_a, tau_e, target_error = resolve_thresholds(tau_a, tau_e, target_error, "tau_a", relative_to)
        # >= 2: singletons are always dissolved
        self.min_body_elements = integer(min_body_elements, "min_body_elements", low=2)
        super().__init__(tau_e, min_fraction=forced_fraction(min_fraction),
                         seeding=seeding, preconditioner=preconditioner, seed=seed, solver=solver,
                         target_error=target_error, time_budget=time_budget, never_slower=never_slower,
                         shadow_every=shadow_every, memory=memory, refresh=refresh, refresh_tol=refresh_tol,
                         refresh_background=refresh_background, relative_to=relative_to, pinned_bodies=pinned_bodies)

    def __repr__(self):
        what = (f"target_error={self.target_error:g}, relative_to={self.relative_to!r}" if self.target_error is not None
                else f"tau_a={self.tau_a:g}, tau_e={self.tau_e:g}")
        budget = f", time_budget={self.time_budget:g}" if self.time_budget is not None else ""
        return (f"Affinification({what}{budget}, min_fraction={self.min_fraction:g}, "
                f"seeding={self.seeding!r}, preconditioner={self.preconditioner_kind!r})")

    def _labels(self, problem, v_pred):
        """Deformation rates (eq. 4; predicted velocities for previously affine elements) and BFS."""
        sysm = problem.system
        was = np.flatnonzero(self.was_reduced)
        # one pass over every element with the velocities most of them need, the others' rates element
        # by element (the same sums): at rest, with nearly all elements affine, one pass, not two
        if 2 * was.size > sysm.m:
            Fdot = sysm.deformation_gradients(v_pred)
            other = np.flatnonzero(~self.was_reduced)
            if other.size:
                Fdot[other] = element_rates(problem.v, sysm.t[:, other], sysm.grads[other])
        else:
            Fdot = sysm.deformation_gradients(problem.v)
            if was.size:
                Fdot[was] = element_rates(v_pred, sysm.t[:, was], sysm.grads[was])
        forced = clustering.forced_set(Fdot, self.adjacency, self.min_fraction) if self.min_fraction > 0 else None
        labels, seeds = clustering.cluster_deformation_rates(
            Fdot, self.adjacency, sysm.t, sysm.n, self.tau_a, self.tau_e, was_affine=self.was_reduced,
            excluded=self.excluded, forced=forced, seeds=self._seeds(sysm.m), return_seeds=True,
            min_size=self.min_body_elements)
        self.previous_seeds = seeds
        return labels

    def _mapping(self, problem, vcluster, n_bodies):
        """Gamma_i = [I_3, I_3 (x) r_i^T], r_i from the body's rest centre of mass (eq. 8)."""
        sysm = problem.system
        return reduction.affine_mapping(sysm.free, vcluster, sysm.p0, sysm.lumped_mass, n_bodies)
