r"""Writing your own reducer: fixed affine bodies from a k-means
============================================================

A reducer decides in which subspace each frame is solved (:mod:`skfem_affine.reducers.base`).
It subclasses :class:`~skfem_affine.reducers.base.Reducer`, declares the integrators it runs
under, and implements two methods:

* ``_setup(model)``, once per run (called by ``attach``): ``model`` holds the system
  (mesh, masses, free DOFs), h, damping and gravity;
* ``solve(problem) -> StepResult``, once per frame: ``problem`` is the linearized backward
  Euler step at x_t (eq. 1-2 of the affinification paper): ``problem.data`` (forces,
  stiffness), ``problem.b`` and ``problem.rhs(v)`` (the right-hand side), ``problem.matrix()``
  (A). The result gives the velocity change ``dv`` of the free DOFs and, so that contact and
  the statistics work, the factorised ``Operator``, the ``mapping`` and the ``clusters``.

The reducer below groups the vertices once, by k-means of their rest positions; the elements
whose four vertices share a group form an affine body of 12 DOFs (eq. 7-8), the others (and
the pinned ones) stay elastic, so that no vertex belongs to two bodies. Each frame it projects the
velocities onto the bodies (eq. 9), solves the reduced system G^T A G dq = G^T b (eq. 10)
and adds the discrepancy back (eq. 11-12), all with the functions of
:mod:`skfem_affine.reducers.affine.mapping`. Unlike affinification it never adapts: it is
the static baseline that the adaptive method improves on.

The lab's runners take any reducer through a *method*, a name and a factory
``(tau_a, tau_e) -> reducer``; :func:`~skfem_affine.lab.runners.compare` then measures it
beside full space and affinification from the same initial state.
"""
import numpy as np

from skfem_affine.integrators.problem import Operator, StepResult
from skfem_affine.lab import runners
from skfem_affine.reducers.affine import mapping
from skfem_affine.reducers.base import Reducer
from skfem_affine.solvers import make_solver


def kmeans(points, k, iterations=20, seed=0):
    """Labels (len(points),) of k clusters by Lloyd's iterations from k random points."""
    rng = np.random.default_rng(seed)
    centres = points[rng.choice(len(points), k, replace=False)]
    for _ in range(iterations):
        labels = np.argmin(((points[:, None] - centres[None]) ** 2).sum(axis=2), axis=1)
        centres = np.array([points[labels == c].mean(axis=0) if np.any(labels == c) else centres[c]
                            for c in range(k)])
    return labels


class StaticAffineBodies(Reducer):
    """``bodies`` affine bodies fixed at rest by k-means of the mesh vertices."""

    name = "static-kmeans"
    integrators = ("linearized",)

    def __init__(self, bodies=4, seed=0):
        self.bodies, self.seed = int(bodies), seed

    def _setup(self, model):
        sysm = model.system
        # vertices by k-means (pinned ones apart); an element is in a body if its 4 vertices are
        vertex_labels = np.where(sysm.fixed, -1, kmeans(sysm.p0, self.bodies, seed=self.seed))
        vt = vertex_labels[sysm.t]                                   # (4, m)
        labels = np.where(np.all(vt == vt[0], axis=0), vt[0], -1)
        kept = np.unique(labels[labels >= 0])
        self.labels = np.where(labels >= 0, np.searchsorted(kept, labels), -1)  # bodies 0 .. n-1
        vcluster = mapping.vertex_clusters(self.labels, sysm.t, sysm.n)
        self.map = mapping.affine_mapping(sysm.free, vcluster, sysm.p0, sysm.lumped_mass, kept.size)
        self.mdiag = sysm.Mff.diagonal()
        self.solver = make_solver("direct")

    def solve(self, problem):
        G, free = self.map.G, problem.system.free
        v = problem.v.reshape(-1)[free]
        q = self.map.project(self.mdiag, v)                          # eq. 9
        d = mapping.discrepancy(G, q, v)                             # eq. 11
        v_projected = problem.v.copy()
        v_projected.reshape(-1)[free] += d
        Ar = mapping.reduced_matrix(problem.model, problem.data, self.map)  # G^T A G (eq. 10)
        self.solver.factorize(Ar)
        dq = self.solver.solve(G.T @ problem.rhs(v_projected))
        stats = {"dofs": Ar.shape[0], "solver": self.solver.name, "n_clusters": self.map.n_bodies,
                 "reduced_fraction": float(np.mean(self.labels >= 0))}
        return StepResult(dv=mapping.lift(G, dq, d), operator=Operator(self.solver, Ar, G),  # eq. 12
                          mapping=self.map, clusters=self.labels, stats=stats)


# register it as a method: the factory receives the (unused) thresholds
runners.register(runners.Method("static-kmeans", lambda tau_a, tau_e: StaticAffineBodies(bodies=4)))
spec = runners.SceneSpec.make("cantilever", resolution=2)           # 192 tets, pinned at x = 0
reference, runs = runners.compare(spec, frames=40, methods=("affinification", "static-kmeans"),
                                  taus={"affinification": (0.3, 0.6)}, keep_every=0)
summary = {name: run.summary for name, run in runs.items()}

if __name__ == "__main__":
    print(f"{'method':>15} {'DOF ratio':>9} {'bodies':>7} {'max error':>9} {'step error':>10}")
    for name, s in summary.items():
        step = "-" if s["max_step_error"] is None else f"{s['max_step_error']:.1e}"
        print(f"{name:>15} {s['dof_ratio']:9.2f} {s['mean_clusters']:7.1f} {s['max_distance_error']:9.1e} {step:>10}")
