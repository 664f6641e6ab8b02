r"""Adaptive reducers: the one place where the methods differ (paper Algorithm 1).

A reducer is handed the simulation each frame and returns the full-space velocity
change of the free DOFs. :class:`Affinification` (sec. 3) clusters elements
with alike deformation rates into affine bodies; :class:`Rigidification` is the
adaptive-rigidification baseline (Mercier-Aubin et al. 2022) on the same
integrator, solver and statistics, so that the methods compare fairly.

One affinification frame (Algorithm 1), with the phase names of ``sim.stats``:

1. ``assembly``: f, dP/dF and element blocks at x_t (:meth:`ElasticSystem.evaluate`);
2. ``prediction``: one PCG iteration (eq. 13-14), dv_approx;
3. ``clustering``: F_dot = B v (eq. 4, predicted velocities for previously
   affine elements), BFS of Algorithm 2 (eq. 5-6), resource limiting (sec. 3.5);
4. ``map_assembly``: G (eq. 7-8), projection q = (G^T M G)^-1 G^T M v (eq. 9),
   discrepancy d = G q - v (eq. 11);
5. ``reduced_assembly``: G^T A G and G^T b (eq. 10), the matrix gathered from the
   assembled A's vertex blocks (:func:`reduction.reduced_matrix`), upper triangle
   only when the solver is a Cholesky that reads one, and its elimination order
   inherited from the mesh (:meth:`reduction.Mapping.elimination_order`);
6. ``factorization`` and ``solve``: the reduced system, direct solver;
7. dv = G dq + d (eq. 12); positions are integrated in full space.
"""
import time

import numpy as np
import scipy.sparse as sp

from skfem_affine.reducers.affine import clustering

from skfem_affine.reducers.affine import oracle

from skfem_affine.reducers.affine import mapping as reduction
from skfem_affine._kernels import strain_rate_norms
from skfem_affine.threads import serial_blas
from skfem_affine.solvers import make_solver


def _check_threshold(value, name):
    value = float(value)
    if not np.isfinite(value) or value < 0:
        raise ValueError(f"threshold {name} must be finite and >= 0, got {value}")
    return value


class Reducer:
    """Interface: ``attach(sim)`` once, then ``solve(sim, rec)`` -> dv on the free DOFs each frame."""

    name = "reducer"

    def attach(self, sim):
        self.sim = sim

    def solve(self, sim, rec):
        raise NotImplementedError


def _elements_touching(system, mask):
    """Elements with at least one vertex in the vertex mask."""
    return np.any(mask[system.t], axis=0)


class _ClusteringReducer(Reducer):
    """Shared frame flow of affinification and rigidification (Algorithm 1).

    Subclasses define :meth:`_labels` (which elements are reduced, and how they
    group) and :meth:`_map` (the rows Gamma_i of G for reduced vertices).
    """

    width = 12

    def __init__(self, tau_e, preconditioner, min_fraction, seeding, seed, solver):
        self.tau_e = _check_threshold(tau_e, "tau_e")
        if preconditioner not in ("ichol", "amg"):
            raise ValueError(f"preconditioner must be 'ichol' or 'amg', got {preconditioner!r}")
        self.preconditioner_kind = preconditioner
        min_fraction = float(min_fraction)
        if not 0.0 <= min_fraction <= 1.0:
            raise ValueError(f"resource limit fraction must lie in [0, 1], got {min_fraction}")
        self.min_fraction = min_fraction
        if seeding not in ("random", "index", "temporal"):
            raise ValueError(f"seeding must be 'random', 'index' or 'temporal', got {seeding!r}")
        self.seeding = seeding
        self.seed = seed
        self.solver_spec = solver

    def attach(self, sim):
        sysm = sim.system
        self.sim = sim
        self.rng = np.random.default_rng(self.seed)
        self.adjacency = clustering.element_adjacency(sysm.t)
        self.excluded = _elements_touching(sysm, sysm.fixed)  # pinned elements stay elastic
        self.was_reduced = np.zeros(sysm.m, dtype=bool)
        self.previous_seeds = None
        self.labels = np.full(sysm.m, -1, dtype=np.int64)
        t0 = time.perf_counter()
        self.precond = oracle.Preconditioner(sysm, sim.dt, sim.damping, kind=self.preconditioner_kind)
        self.setup_time = time.perf_counter() - t0
        self.solver = make_solver(self.solver_spec if self.solver_spec is not None else "direct")
        self.upper = getattr(self.solver, "accepts_upper", False)  # a Cholesky reads one triangle
        # a fill-reducing order of the free vertices, inherited by every frame's reduced system
        self.vertex_rank = reduction.nested_dissection_rank(sysm) if self.upper else None
        self.mdiag = sysm.Mff.diagonal()
        self.gravity_dv = np.tile(sim.gravity, sysm.n)[sysm.free] * sim.dt

    # -------------------------------------------------------------- frame
    def solve(self, sim, rec):
        with serial_blas():
            return self._frame(sim, rec)

    def _frame(self, sim, rec):
        sysm, h = sim.system, sim.dt
        s = sim.state
        free = sysm.free
        t0 = time.perf_counter()
        # forces, projected dP/dF and the assembled stiffness H: element blocks and their
        # scatter cost little next to the tangent, and H p by CSR is 50x the matrix-free product
        data = sysm.evaluate(s.x, project=sim.project_hessian)
        data.f = data.f + sim.f_gravity
        Hop = sysm.pattern.matrix(data.H)
        t1 = time.perf_counter()
        rec["assembly"] = t1 - t0
        # prediction (eq. 13-14): one PCG iteration, gravity split out, A p = M p + H p (A never formed)
        b = sim.rhs(data.f, Hop, s.v)
        b_ng = b - h * sim.f_gravity[free] + sim.contact_impulse()  # contact impulses as explicit forces (sec. 3.4)
        apply_A = self._operator(sim, Hop)
        dv_pred = oracle.predict(apply_A, b_ng, self.precond, gravity_dv=self.gravity_dv)
        t2 = time.perf_counter()
        rec["prediction"] = t2 - t1
        # deformation rates (eq. 4) and clustering (Algorithm 2)
        v_pred = s.v.copy()
        v_pred.reshape(-1)[free] += dv_pred
        labels = self._labels(sim, data, s.v, v_pred)
        vcluster = reduction.vertex_clusters(labels, sysm.t, sysm.n)
        n_bodies = int(labels.max()) + 1 if labels.size and labels.max() >= 0 else 0
        t3 = time.perf_counter()
        rec["clustering"] = t3 - t2
        # map assembly: G, projection (eq. 9), discrepancy (eq. 11)
        Gam = self._map(sim, vcluster, n_bodies)
        gmap = reduction.mapping(free, vcluster, Gam, n_bodies)
        G = self.G = gmap.G  # also for contact
        vf = s.v.reshape(-1)[free]
        q = gmap.project(self.mdiag, vf) if n_bodies else vf  # eq. 9
        d = reduction.discrepancy(G, q, vf) if n_bodies else np.zeros_like(vf)  # eq. 11
        t4 = time.perf_counter()
        rec["map_assembly"] = t4 - t3
        # reduced system (eq. 10) with the projected velocities
        order = None
        if n_bodies:
            vp = s.v.copy()
            vp.reshape(-1)[free] += d
            bp = sim.rhs(data.f, Hop, vp)
            Ar = reduction.reduced_matrix(sim, data, gmap, vcluster, affine=self.width == 12, upper=self.upper)
            br = gmap.G.T @ bp
            if self.vertex_rank is not None:
                order = gmap.elimination_order(free, vcluster, self.vertex_rank)
        else:
            Ar, br = sim.system_matrix(data.H), b
        t5 = time.perf_counter()
        rec["reduced_assembly"] = t5 - t4
        upper = self.upper and n_bodies
        if upper:
            self.solver.factorize(Ar, upper=True, order=order)
        else:
            self.solver.factorize(Ar)
        # with G, for the contact solve's Delassus operator, which needs the whole symmetric matrix
        self.Ar = (Ar + sp.triu(Ar, k=1, format="csr").T).tocsr() if upper and sim.contact is not None else Ar
        t6 = time.perf_counter()
        dq = self.solver.solve(br)
        t7 = time.perf_counter()
        rec.update(factorization=t6 - t5, solve=t7 - t6, dofs=Ar.shape[0], solver=self.solver.name,
                   iterations=self.solver.last_iterations, clusters=labels, n_clusters=n_bodies,
                   elastic_dofs=int(gmap.n_elastic),
                   reduced_fraction=float(np.mean(labels >= 0)) if labels.size else 0.0)
        self.was_reduced = labels >= 0
        self.labels = labels
        return reduction.lift(G, dq, d)  # eq. 12

    def _operator(self, sim, Hop):
        """p -> A p = (1 + h alpha) M p + (h beta + h^2) H p from the lumped mass and the assembled H (A never formed)."""
        h, dmp = sim.dt, sim.damping
        cm, ck = 1.0 + h * dmp.alpha, h * dmp.beta + h * h
        return lambda p: cm * self.mdiag * p + ck * (Hop @ p)

    def _seeds(self, m):
        return clustering.seed_order(m, self.seeding, rng=self.rng, previous_seeds=self.previous_seeds)


class Affinification(_ClusteringReducer):
    """Adaptive affinification (paper sec. 3, Algorithm 1-2).

    Parameters
    ----------
    tau_a : float
        Threshold on the deformation-rate distance (eq. 6) to turn elastic elements affine.
    tau_e : float
        More permissive threshold for elements that were affine to stay affine.
    seeding : {"random", "index", "temporal"}
    preconditioner : {"ichol", "amg"}
        Factorisation of A_p (eq. 14) used by the one-iteration PCG oracle.
    min_affine_fraction : float
        Resource limiting (sec. 3.5): at least this fraction of elements is forced into clusters.
    seed : int
        Seed of the random seeding (reproducible runs).
    solver : str, optional
        Solver of the reduced system (default: the fastest direct solver).
    """

    name = "affinification"
    width = 12

    def __init__(self, tau_a=1e-4, tau_e=2e-4, seeding="random", preconditioner="ichol",
                 min_affine_fraction=0.0, seed=0, solver=None, min_body_elements=2):
        self.tau_a = _check_threshold(tau_a, "tau_a")
        if int(min_body_elements) < 2:
            raise ValueError(f"min_body_elements must be >= 2 (singletons are always dissolved), got {min_body_elements}")
        self.min_body_elements = int(min_body_elements)
        super().__init__(tau_e, preconditioner, min_affine_fraction, seeding, seed, solver)

    def __repr__(self):
        return (f"Affinification(tau_a={self.tau_a:g}, tau_e={self.tau_e:g}, seeding={self.seeding!r}, "
                f"preconditioner={self.preconditioner_kind!r}, min_affine_fraction={self.min_fraction:g})")

    def attach(self, sim):
        super().attach(sim)
        sysm = sim.system
        # rest-frame centre offsets are per cluster; positions of vertices at rest
        self.X = sysm.p0

    def _labels(self, sim, data, v, v_pred):
        """Deformation rates (eq. 4; predicted velocities for previously affine elements) and BFS."""
        sysm = sim.system
        Fdot = sysm.deformation_gradients(v)
        if np.any(self.was_reduced):
            np.copyto(Fdot, sysm.deformation_gradients(v_pred), where=self.was_reduced[:, None, None])
        forced = clustering.forced_set(Fdot, self.adjacency, self.min_fraction) if self.min_fraction > 0 else None
        labels, seeds = clustering.cluster_deformation_rates(
            Fdot, self.adjacency, sysm.t, sysm.n, self.tau_a, self.tau_e, was_affine=self.was_reduced,
            excluded=self.excluded, forced=forced, seeds=self._seeds(sysm.m), return_seeds=True,
            min_size=self.min_body_elements)
        self.previous_seeds = seeds
        return labels

    def _map(self, sim, vcluster, n_bodies):
        """Gamma_i = [I_3, I_3 (x) r_i^T], r_i from the body's rest centre of mass (eq. 8)."""
        return reduction.affine_rows(vcluster, self.X, sim.system.lumped_mass, n_bodies)


class Rigidification(_ClusteringReducer):
    """Adaptive rigidification baseline (Mercier-Aubin, Kry, Winter & Levin 2022).

    An element may turn rigid once its strain rate ||sym(F^T F_dot)||^2 (F at the
    step midpoint) stays below ``tau_r`` for ``warmup_frames`` consecutive frames
    and the oracle's predicted strain rate stays below ``tau_e``; rigid elements
    stay rigid while the predicted strain rate stays below ``tau_e``. Rigid bodies
    are connected components of such elements (vertex-disjoint, pinned elements
    excluded), each with 6 DOFs v_i = v_c + omega x (x_i - x_c) in the current
    configuration, and their vertices rotate exactly (exponential map) in
    :meth:`integrate`. Same integrator, oracle, solver and statistics as
    :class:`Affinification`.
    """

    name = "rigidification"
    width = 6

    def __init__(self, tau_r=1e-3, tau_e=2e-3, warmup_frames=3, preconditioner="ichol",
                 min_rigid_fraction=0.0, seeding="random", seed=0, solver=None):
        self.tau_r = _check_threshold(tau_r, "tau_r")
        if int(warmup_frames) < 0:
            raise ValueError(f"warmup_frames must be >= 0, got {warmup_frames}")
        self.warmup_frames = int(warmup_frames)
        super().__init__(tau_e, preconditioner, min_rigid_fraction, seeding, seed, solver)

    def __repr__(self):
        return (f"Rigidification(tau_r={self.tau_r:g}, tau_e={self.tau_e:g}, "
                f"warmup_frames={self.warmup_frames})")

    def attach(self, sim):
        super().attach(sim)
        self.calm_frames = np.zeros(sim.system.m, dtype=np.int64)

    def _strain_rate(self, sim, x, v):
        """||sym(F^T F_dot)||^2 per element, F at the step midpoint x + h v / 2 (compiled, one pass)."""
        sysm = sim.system
        out = np.empty(sysm.m)
        strain_rate_norms(np.ascontiguousarray(x + 0.5 * sim.dt * v), np.ascontiguousarray(v), sysm.t, sysm.grads, out)
        return out

    def _labels(self, sim, data, v, v_pred):
        sysm = sim.system
        x = sim.state.x
        metric = self._strain_rate(sim, x, v)
        predicted = self._strain_rate(sim, x, v_pred)
        calm = np.where(self.was_reduced, predicted < self.tau_e, metric < self.tau_r)
        self.calm_frames = np.where(calm, self.calm_frames + 1, 0)
        # calm during the previous ``warmup_frames`` frames and now: the first frames stay elastic
        eligible = (self.calm_frames > self.warmup_frames) & (predicted < self.tau_e)
        if self.min_fraction > 0:
            k = int(round(self.min_fraction * sysm.m))
            if k:
                eligible[np.argpartition(metric, k - 1)[:k]] = True
        labels = clustering.cluster_components(eligible, self.adjacency, sysm.t, sysm.n, excluded=self.excluded,
                                               seeds=self._seeds(sysm.m), min_size=2)
        return labels

    def _map(self, sim, vcluster, n_bodies):
        """Gamma_i = [I_3, -[x_i - x_c]_x] in the current configuration (6 DOFs per body)."""
        Gam, self.com = reduction.rigid_rows(vcluster, sim.state.x, sim.system.lumped_mass, n_bodies)
        self._vcluster = vcluster
        return Gam

    def integrate(self, sim, x, v):
        """x + h v for elastic vertices; exact rotation about the centre for rigid ones."""
        x_new = x + sim.dt * v
        vc = getattr(self, "_vcluster", None)
        if vc is None or not np.any(vc >= 0):
            return x_new
        sysm = sim.system
        red = np.flatnonzero(vc >= 0)
        c = vc[red]
        n_bodies = self.com.shape[0]
        m = sysm.lumped_mass[red]
        mt = np.bincount(c, weights=m, minlength=n_bodies)
        vcom = reduction.group_sum(c, m[:, None] * v[red], n_bodies) / mt[:, None]
        r = x[red] - self.com[c]
        # angular velocity from the (rigid) vertex velocities: I w = sum m r x (v - v_c)
        L = reduction.group_sum(c, m[:, None] * np.cross(r, v[red] - vcom[c]), n_bodies)
        rr = np.einsum("vi,vi->v", r, r)
        I = reduction.group_sum(c, m[:, None, None] * (rr[:, None, None] * np.eye(3) - r[:, :, None] * r[:, None, :]),
                                n_bodies)
        w = np.linalg.solve(I + 1e-300 * np.eye(3), L[..., None])[..., 0]
        R = _rotation(sim.dt * w)
        x_new[red] = self.com[c] + sim.dt * vcom[c] + np.einsum("vij,vj->vi", R[c], r)
        return x_new


def _rotation(phi):
    """Rotation matrices exp([phi]_x) (Rodrigues), phi (k, 3)."""
    theta = np.linalg.norm(phi, axis=1)
    small = theta < 1e-12
    k = np.where(small[:, None], 0.0, phi / np.where(small, 1.0, theta)[:, None])
    K = np.zeros((phi.shape[0], 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    K[:, 1, 0], K[:, 2, 0], K[:, 2, 1] = k[:, 2], -k[:, 1], k[:, 0]
    s, c = np.sin(theta)[:, None, None], np.cos(theta)[:, None, None]
    return np.eye(3) + s * K + (1 - c) * (K @ K)
