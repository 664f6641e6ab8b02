r"""The frame flow shared by affinification and rigidification (paper Algorithm 1).

One frame, with the phase names of ``sim.stats`` (``assembly``, f and H at x_t, is the
integrator's, in the :class:`~skfem_affine.integrators.problem.StepProblem`):

1. ``prediction``: one PCG iteration (eq. 13-14), dv_approx, the contact impulses of
   the problem taken as explicit forces (sec. 3.4);
2. ``clustering``: which elements are reduced and how they group (the subclass's
   :meth:`ClusteringReducer._labels`);
3. ``map_assembly``: G (eq. 7-8, the subclass's body kind), projection
   q = (G^T M G)^-1 G^T M v (eq. 9), discrepancy d = G q - v (eq. 11);
4. ``reduced_assembly``: G^T A G and G^T b (eq. 10), the matrix gathered from the
   assembled A's vertex blocks (:func:`mapping.reduced_matrix`), upper triangle
   only when the solver is a Cholesky that reads one, and its elimination order
   inherited from the mesh (:meth:`mapping.Mapping.elimination_order`);
5. ``factorization`` and ``solve``: the reduced system, direct solver;
6. dv = G dq + d (eq. 12); the positions are integrated by the mapping's body kind.
"""
import time

import numpy as np

from skfem_affine.checks import choice, integer, real
from skfem_affine.threads import serial_blas
from skfem_affine.integrators.problem import Operator, StepResult
from skfem_affine.reducers.affine import clustering, oracle
from skfem_affine.reducers.affine import mapping as reduction
from skfem_affine.reducers.base import Reducer
from skfem_affine.solvers import make_solver

SEEDINGS = ("random", "index", "temporal")


def check_threshold(value, name):
    """A finite threshold >= 0, or a TypeError/ValueError naming it."""
    return real(value, f"threshold {name}", low=0.0)


def forced_fraction(min_fraction, old_value, old_name):
    """The resource-limit fraction from ``min_fraction`` or its older keyword ``old_name``."""
    if old_value is not None:
        if min_fraction is not None:
            raise ValueError(f"give min_fraction or its older name {old_name}, not both")
        min_fraction = old_value
    name = "min_fraction" if old_value is None else old_name
    return 0.0 if min_fraction is None else real(min_fraction, name, low=0.0, high=1.0)


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
    """

    integrators = ("linearized",)
    # carried across frames: who was reduced, the clusters and seeds, the random seeding's generator
    _state_keys = ("was_reduced", "labels", "previous_seeds", "rng_state")

    @property
    def rng_state(self):
        """The random seeding generator's state (a dict of integers)."""
        return self.rng.bit_generator.state

    @rng_state.setter
    def rng_state(self, state):
        self.rng.bit_generator.state = state

    def state_dict(self):
        state = super().state_dict()
        if hasattr(self.solver, "state_dict"):  # e.g. an AMG hierarchy reused across frames
            state.update({f"solver.{k}": v for k, v in self.solver.state_dict().items()})
        return state

    def load_state_dict(self, state):
        super().load_state_dict(state)
        solver = {k[7:]: v for k, v in state.items() if k.startswith("solver.")}
        if solver and hasattr(self.solver, "load_state_dict"):
            self.solver.load_state_dict(solver)

    def __init__(self, tau_e, *, min_fraction=0.0, seeding="random", preconditioner="ichol", seed=0, solver=None):
        self.tau_e = check_threshold(tau_e, "tau_e")
        self.preconditioner_kind = choice(preconditioner, "preconditioner", tuple(oracle.KINDS))
        self.min_fraction = min_fraction
        self.seeding = choice(seeding, "seeding", SEEDINGS)
        self.seed = None if seed is None else integer(seed, "seed", low=0)
        self.solver_spec = solver

    def _setup(self, model):
        sysm = model.system
        self.rng = np.random.default_rng(self.seed)
        self.adjacency = clustering.element_adjacency(sysm.t)
        self.excluded = elements_touching(sysm, sysm.fixed)  # pinned elements stay elastic
        self.was_reduced = np.zeros(sysm.m, dtype=bool)
        self.previous_seeds = None
        self.labels = np.full(sysm.m, -1, dtype=np.int64)
        self.precond = oracle.Preconditioner(sysm, model.dt, model.damping, kind=self.preconditioner_kind)
        self.solver = make_solver(self.solver_spec if self.solver_spec is not None else "direct")
        self.upper = getattr(self.solver, "accepts_upper", False)  # a Cholesky reads one triangle
        # a fill-reducing order of the free vertices, inherited by every frame's reduced system
        self.vertex_rank = reduction.nested_dissection_rank(sysm) if self.upper else None
        self.mdiag = sysm.Mff.diagonal()
        self.gravity_dv = np.tile(model.gravity, sysm.n)[sysm.free] * model.dt

    # -------------------------------------------------------------- frame
    def solve(self, problem):
        """Algorithm 1 on one :class:`~skfem_affine.integrators.problem.StepProblem`."""
        with serial_blas():
            return self._frame(problem)

    def _frame(self, problem):
        model, sysm = problem.model, problem.system
        h, free = model.dt, sysm.free
        stats = {}
        t1 = time.perf_counter()
        # prediction (eq. 13-14): one PCG iteration, gravity split out, A p = M p + H p (A never formed)
        b = problem.b
        b_ng = b - h * model.f_gravity[free] + problem.contact_impulse  # contact impulses as explicit forces
        apply_A = oracle.system_operator(self.mdiag, problem.Hmat, model.coefficients)
        dv_pred = oracle.predict(apply_A, b_ng, self.precond, gravity_dv=self.gravity_dv)
        t2 = time.perf_counter()
        stats["prediction"] = t2 - t1
        # deformation rates (eq. 4) and clustering (Algorithm 2)
        v_pred = problem.v.copy()
        v_pred.reshape(-1)[free] += dv_pred
        labels = self._labels(problem, v_pred)
        vcluster = reduction.vertex_clusters(labels, sysm.t, sysm.n)
        n_bodies = int(labels.max()) + 1 if labels.size and labels.max() >= 0 else 0
        t3 = time.perf_counter()
        stats["clustering"] = t3 - t2
        # map assembly: G, projection (eq. 9), discrepancy (eq. 11)
        gmap = self._mapping(problem, vcluster, n_bodies)
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
            Ar = reduction.reduced_matrix(model, problem.data, gmap, upper=self.upper)
            br = G.T @ problem.rhs(vp)
            if self.vertex_rank is not None:
                order = gmap.elimination_order(self.vertex_rank)
        else:
            Ar, br = problem.matrix(), b
        t5 = time.perf_counter()
        stats["reduced_assembly"] = t5 - t4
        upper = bool(self.upper and n_bodies)
        if upper:
            self.solver.factorize(Ar, upper=True, order=order)
        else:
            self.solver.factorize(Ar)
        t6 = time.perf_counter()
        dq = self.solver.solve(br)
        t7 = time.perf_counter()
        stats.update(factorization=t6 - t5, solve=t7 - t6, dofs=Ar.shape[0], solver=self.solver.name,
                     iterations=self.solver.last_iterations, n_clusters=n_bodies, elastic_dofs=int(gmap.n_elastic),
                     reduced_fraction=float(np.mean(labels >= 0)) if labels.size else 0.0)
        self.was_reduced = labels >= 0
        self.labels = labels
        return StepResult(dv=reduction.lift(G, dq, d), operator=Operator(self.solver, Ar, G, upper=upper),  # eq. 12
                          mapping=gmap, clusters=labels, stats=stats)

    def _labels(self, problem, v_pred):
        """Per-element body labels (m,), -1 elastic, from the problem and the predicted velocities."""
        raise NotImplementedError

    def _mapping(self, problem, vcluster, n_bodies):
        """The frame's :class:`~skfem_affine.reducers.affine.mapping.Mapping` of this body kind."""
        raise NotImplementedError

    def _seeds(self, m):
        return clustering.seed_order(m, self.seeding, rng=self.rng, previous_seeds=self.previous_seeds)
