r"""IPC log-barrier contact against static colliders, for the Newton integrators (paper eq. 2, B(x)).

A collider is any object with ``query(points (k, 3)) -> (distance (k,), normal (k, 3))``:
the signed distance of each point to the collider and the unit normal pointing from the collider
towards the point (the distance's gradient). This is the contact model of the Newton integrators
(``integrator="implicit_euler" | "bdf2"``): frictionless, entering the incremental potential
(:mod:`skfem_affine.integrators.potential`); the linearized integrator resolves the same colliders
by PGS with friction instead (:mod:`skfem_affine.contact.pgs`).

The barrier energy over the free vertices i and colliders c (Li et al. 2020) is

.. math:: B(x) = \kappa \sum_{i,c} b(d_{ic}), \qquad
          b(d) = -(d - \hat d)^2 \ln(d / \hat d) \ \ (0 < d < \hat d), \quad 0 \ (d \ge \hat d),

infinite for :math:`d \le 0`, so that a line search that keeps E finite never lets a vertex
cross a collider. Gradient :math:`\kappa b'(d) n`; Hessian :math:`\kappa b''(d) n n^T`
(b'' > 0: positive semi-definite), which drops the collider-curvature term
:math:`\kappa b'(d) \nabla^2 d` (exact for planes). Defaults: :math:`\hat d` = 1e-3 of the scene
size, :math:`\kappa` = 100 m_avg a / :math:`\hat d` (:func:`stiffness_force`: m_avg the mean vertex
mass, a the scene's acceleration scale), so that the barrier's stiffness scales with a vertex's
weight and a body resting under gravity settles inside the barrier's range (measured in
docs/subspace.md, "Contact"). Every default comes from the scene's own scales, so the same scene in
another unit system (mm-tonne-s) moves the same.

The barrier is built once per run from the model (``model.system``, ``model.size``) and the
colliders; it holds no simulation.
"""
import numpy as np

from skfem_affine.checks import positive
from skfem_affine.contact.colliders import check_colliders


def stiffness_force(system, gravity, dhat, dt):
    r"""The force scale of the default barrier stiffness (N): :math:`100\, m_{avg}\, a`.

    ``m_avg`` is the mean lumped vertex mass of ``system`` and ``a`` the scene's acceleration
    scale: the magnitude of ``gravity`` (3,), or, without gravity (None or zero),
    :math:`\hat d / h^2`, the acceleration that moves a vertex by ``dhat`` in one step ``dt``. The
    force of a vertex at half of ``dhat`` is then about 430 vertex weights (under gravity).
    """
    g = 0.0 if gravity is None else float(np.linalg.norm(gravity))
    a = g if g > 0 else dhat / (dt * dt)
    return 100.0 * float(system.lumped_mass.mean()) * a


def barrier(d, dhat):
    """b(d), b'(d), b''(d) elementwise (b = inf for d <= 0, 0 for d >= dhat)."""
    d = np.asarray(d, float)
    b, b1, b2 = np.zeros_like(d), np.zeros_like(d), np.zeros_like(d)
    act = (d > 0) & (d < dhat)
    z = d[act]
    lg = np.log(z / dhat)
    b[act] = -(z - dhat) ** 2 * lg
    b1[act] = -2.0 * (z - dhat) * lg - (z - dhat) ** 2 / z
    b2[act] = -2.0 * lg - 4.0 * (z - dhat) / z + (z - dhat) ** 2 / z ** 2
    b[d <= 0] = np.inf
    return b, b1, b2


class Barrier:
    """The barrier B(x) of one run: energy, gradient and Hessian blocks on the free DOFs.

    Parameters
    ----------
    model : Model
        The run's fixed data; ``model.system``, ``model.size``, ``model.gravity`` and ``model.dt``
        are read.
    colliders : list of colliders
        Objects with ``query(points) -> (distance, normal)``.
    dhat : float, optional
        Barrier range (default 1e-3 of ``model.size``).
    kappa : float, optional
        Barrier stiffness (N/m; default :func:`stiffness_force` / dhat).
    """

    def __init__(self, model, colliders, dhat=None, kappa=None):
        sysm = model.system
        self.colliders = check_colliders(colliders)
        self.dhat = 1e-3 * model.size if dhat is None else positive(dhat, "barrier distance dhat")
        self.kappa = (stiffness_force(sysm, model.gravity, self.dhat, model.dt) / self.dhat if kappa is None
                      else positive(kappa, "barrier stiffness kappa"))
        self.vertices = np.flatnonzero(~sysm.fixed)
        # positions of each free vertex's diagonal 3 x 3 block in the free-DOF pattern
        pat = sysm.pattern
        dof_map = np.full(3 * sysm.n, -1, dtype=np.int64)
        dof_map[sysm.free] = np.arange(sysm.free.size)
        r = dof_map[3 * self.vertices[:, None, None] + np.arange(3)[None, :, None]]
        c = dof_map[3 * self.vertices[:, None, None] + np.arange(3)[None, None, :]]
        r, c = np.broadcast_arrays(r, c)
        key = pat.rows.astype(np.int64) * pat.shape[0] + pat.indices
        self.block_slots = np.searchsorted(key, (r * pat.shape[0] + c).ravel()).reshape(-1, 3, 3)
        self.rows = dof_map[3 * self.vertices[:, None] + np.arange(3)]  # (k, 3) free-DOF rows
        self.nnz = pat.nnz
        self.nfree = sysm.free.size

    def check_state(self, x):
        """Raise a ValueError naming the colliders and vertices when a free vertex of x (n, 3) is on
        or inside a collider (distance <= 0): the barrier is infinite there, so Newton could never
        move such a vertex (the body would stay frozen)."""
        pts = np.asarray(x, float).reshape(-1, 3)[self.vertices]
        problems = []
        for i, c in enumerate(self.colliders):
            d, _ = c.query(pts)
            bad = np.flatnonzero(np.asarray(d) <= 0)
            if bad.size:
                worst = bad[np.argsort(d[bad])[:5]]
                listed = ", ".join(f"{int(self.vertices[j])} (distance {float(d[j]):.3g} m)" for j in worst)
                problems.append(f"collider {i} ({type(c).__name__}): {bad.size} vertices on or inside it, "
                                f"e.g. {listed}")
        if problems:
            raise ValueError("the IPC barrier needs every free vertex strictly outside the colliders (gap > 0); "
                             + "; ".join(problems) + f". Move the bodies out by at least dhat = {self.dhat:.3g} m "
                             "(the barrier's range), or use integrator='linearized', whose PGS contact pushes "
                             "penetrations out")

    def intersection_free(self, x):
        """True when every free vertex of the flat state x lies strictly outside every collider."""
        return all(bool(np.all(d > 0)) for d, _ in self._query(x))

    def _query(self, x):
        pts = x.reshape(-1, 3)[self.vertices]
        for c in self.colliders:
            d, nrm = c.query(pts)
            yield np.asarray(d, float), np.asarray(nrm, float)

    def energy(self, x):
        return float(sum(self.kappa * barrier(d, self.dhat)[0].sum() for d, _ in self._query(x)))

    def vertex_energy(self, x):
        """Barrier energy per vertex (n,) (a point stencil for the oracle)."""
        out = np.zeros(x.size // 3)
        for d, _ in self._query(x):
            out[self.vertices] += self.kappa * barrier(d, self.dhat)[0]
        return out

    def gradient(self, x):
        """dB/dx on the free DOFs."""
        g = np.zeros(self.nfree)
        for d, nrm in self._query(x):
            _, b1, _ = barrier(d, self.dhat)
            np.add.at(g, self.rows, self.kappa * b1[:, None] * nrm)
        return g

    def hessian_data(self, x):
        """kappa b''(d) n n^T per vertex, as data on the free-DOF pattern."""
        data = np.zeros(self.nnz)
        for d, nrm in self._query(x):
            _, _, b2 = barrier(d, self.dhat)
            act = b2 != 0
            blocks = self.kappa * b2[act, None, None] * nrm[act, :, None] * nrm[act, None, :]
            np.add.at(data, self.block_slots[act].ravel(), blocks.ravel())
        return data

    def max_step(self, x, dx):
        """Largest alpha <= 1 keeping every vertex's linearised distance above 10 % of its current one."""
        alpha = 1.0
        step = dx.reshape(-1, 3)[self.vertices]
        for d, nrm in self._query(x):
            rate = np.einsum("ij,ij->i", step, nrm)
            closing = rate < 0
            if np.any(closing):
                alpha = min(alpha, float(np.min(0.9 * d[closing] / -rate[closing])))
        return max(alpha, 0.0)


def barrier_of(model, colliders, dhat=None, kappa=None):
    """The :class:`Barrier` of ``colliders`` (a list, possibly empty or None), or None without colliders."""
    colliders = list(colliders or [])
    if not colliders:
        return None
    return Barrier(model, colliders, dhat, kappa)
