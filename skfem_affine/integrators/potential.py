r"""The incremental potential of one time step (adaptive-subspace paper, sec. 3.1, eq. 1-3).

Each time step minimises

.. math:: E(x) = \tfrac12 \|x - \tilde x\|_M^2 + a h^2 \big(\Psi(x) - f_{ext}^T x + D(x) + B(x)\big)
          \qquad \text{(eq. 1-2)},

with the predictor :math:`\tilde x`, weight :math:`a` and velocity update of the scheme:

* implicit Euler (eq. 3): :math:`\tilde x = x_t + h v_t`, :math:`a = 1`,
  :math:`v_{t+1} = (x_{t+1} - x_t)/h`;
* BDF2 (the paper's footnote 9): :math:`a = 4/9`,
  :math:`\tilde x = \tfrac13(4x_t - x_{t-1}) + \tfrac{2h}{9}(4v_t - v_{t-1})`,
  :math:`v_{t+1} = \tfrac{3}{2h}\big(x_{t+1} - \tfrac13(4x_t - x_{t-1})\big)`
  (algebraically the footnote's :math:`\tfrac13(4v_t - v_{t-1}) + \tfrac{2h}3 a_{t+1}`).

Both velocities have the form :math:`v = (x - \hat x)/(c h)` (c = 1, resp. 2/3). Rayleigh damping
(not in the paper; the package's ``Rayleigh(alpha, beta)``) enters as the dissipation potential
:math:`D(x) = \frac{1}{2ch}(x - \hat x)^T (\alpha M + \beta H_t)(x - \hat x)`, whose gradient
:math:`a h^2 (\alpha M + \beta H_t) v` is the damping force with the stiffness lagged at
:math:`x_t`. With :math:`x = x_t + h v`, the implicit-Euler E is :math:`h^2` times the potential
:math:`\Phi(v)` of the linearized integrator's Newton option plus a constant, so both have the
same minimiser. :math:`B(x)` is the IPC barrier against static colliders
(:mod:`skfem_affine.contact.barrier`), absent without colliders.

The potential holds no simulation: it reads the run's fixed data from a ``model``
(``system``, ``dt``, ``damping``, ``f_gravity``, ``size``, ``project_hessian``;
:class:`skfem_affine.integrators.problem.Model`) and carries the Newton settings (``tol``,
``max_iters``) that :func:`skfem_affine.integrators.newton.newton` stops by.
"""
import numpy as np

from skfem_affine.assembly import FrameData
from skfem_affine.checks import positive

SCHEMES = ("implicit_euler", "bdf2")


def vdot(a, b):
    """a . b for 1-D arrays, summed by einsum's loop rather than a BLAS call.

    A BLAS dot hands the work to the BLAS thread pool; for the vector lengths here the
    hand-off costs more than the sum (measurements: docs/threads.md, "One OpenBLAS thread
    during a frame").
    """
    return float(np.einsum("i,i->", a, b))


class IncrementalPotential:
    """E(x) of one time step (eq. 2) with its gradient and Hessian on the free DOFs.

    Parameters
    ----------
    model : Model
        The run's fixed data (see the module docstring); never a simulation.
    x_t, v_t : arrays of 3n values
        Positions and velocities at time t (any shape, flattened).
    x_prev, v_prev : arrays of 3n values, optional
        The state before ``x_t``: BDF2. None gives implicit Euler.
    start : FrameData, optional
        The evaluation at ``x_t`` (forces, element blocks, H), built on first use if None.
    barrier : skfem_affine.contact.barrier.Barrier, optional
        B(x) of eq. 2; None without colliders.
    tol : float
        Newton stops when ``||d||_inf / h <= tol * model.size`` (:func:`converged`).
    max_iters : int
        Newton's iteration cap, >= 1.
    targets : Targets, optional
        Prescribed vertices (:class:`skfem_affine.motion.Targets`): their DOFs sit at
        ``targets.x`` (the path at t + h) in every iterate, from the first (:attr:`x_start`) on.
    f_ext : (3n,) array, optional
        Vertex forces of the step (:class:`skfem_affine.motion.VertexForce`), added to gravity in f_ext.

    Notes
    -----
    Positions ``x`` are flat (3n,) arrays over all DOFs; fixed DOFs stay at ``x_t``, prescribed
    ones at their targets.
    """

    def __init__(self, model, x_t, v_t, x_prev=None, v_prev=None, start=None, barrier=None,
                 tol=1e-6, max_iters=50, targets=None, f_ext=None):
        sysm = model.system
        self.model, self.system, self.free, self.h = model, sysm, sysm.free, model.dt
        self.tol = positive(tol, "newton_tol")
        if int(max_iters) != max_iters or int(max_iters) < 1:
            raise ValueError(f"max_iters (the Newton iteration cap) must be an integer >= 1, got {max_iters}")
        self.max_iters = int(max_iters)
        h = self.h
        x_t, v_t = np.asarray(x_t, float).reshape(-1), np.asarray(v_t, float).reshape(-1)
        if x_prev is None:
            self.scheme, self.a, self.c = "implicit_euler", 1.0, 1.0
            self.x_hat = x_t.copy()
            self.x_tilde = x_t + h * v_t
        else:
            x_prev, v_prev = np.asarray(x_prev, float).reshape(-1), np.asarray(v_prev, float).reshape(-1)
            self.scheme, self.a, self.c = "bdf2", 4.0 / 9.0, 2.0 / 3.0
            self.x_hat = (4.0 * x_t - x_prev) / 3.0
            self.x_tilde = self.x_hat + 2.0 * h / 9.0 * (4.0 * v_t - v_prev)
        self.x_t = x_t
        self.targets = targets
        self.x_start = x_t  # Newton's first iterate
        if targets is not None:
            self.x_start = x_t.copy()
            self.x_start[targets.dofs] = targets.x.reshape(-1)
        self.f_ext = model.f_gravity if f_ext is None else model.f_gravity + f_ext
        self.barrier = barrier
        self._start = start
        d = model.damping
        self.weight = self.a * h * h  # a h^2 in front of the potentials (eq. 2)
        # (alpha M + beta H_t) / (c h), the damping "mass", on the pattern of the free DOFs
        Ht = self.start.H if d.beta else 0.0
        self.damping_data = (d.alpha * sysm.mass_data + d.beta * Ht) / (self.c * h)
        self.damping_matrix = sysm.pattern.matrix(self.damping_data) if (d.alpha or d.beta) else None

    @property
    def starts_at_x_t(self):
        """Whether Newton's first iterate is x_t (no prescribed vertex moves), so that :attr:`start` serves it."""
        return self.targets is None

    @property
    def has_start(self):
        """Whether the evaluation at x_t exists already (Rayleigh beta needs H_t)."""
        return self._start is not None

    @property
    def start(self):
        """:class:`~skfem_affine.assembly.FrameData` at x_t (forces, element blocks, H), built on first use."""
        if self._start is None:
            self._start = self.evaluate(self.x_t)
        return self._start

    def evaluate(self, x, blocks=True):
        """The elastic energy's evaluation at x (flat).

        ``blocks=True``: a full :class:`~skfem_affine.assembly.FrameData` (F, P, projected dP/dF,
        element blocks He, forces f, H). ``blocks=False``: F, P and f only (C, He, H are None),
        for a caller that assembles element blocks only where it needs them.
        """
        sysm = self.system
        if blocks:
            return sysm.evaluate(x.reshape(-1, 3), project=self.model.project_hessian)
        F = sysm.deformation_gradients(x.reshape(-1, 3))
        P, _ = sysm.stresses(F, tangent=False)
        return FrameData(F=F, P=P, C=None, He=None, f=sysm._internal_force(P), H=None)

    # ------------------------------------------------------------------ eq. 2
    def energy(self, x):
        """E(x) (eq. 2); inf where the elastic energy is not finite."""
        free, sysm = self.free, self.system
        r = (x - self.x_tilde)[free]
        val = 0.5 * vdot(r, sysm.Mff @ r)
        psi = sysm.strain_energy(x.reshape(-1, 3))
        pot = psi - vdot(self.f_ext, x)
        if self.damping_matrix is not None:
            z = (x - self.x_hat)[free]
            pot += 0.5 * vdot(z, self.damping_matrix @ z)
        if self.barrier is not None:
            pot += self.barrier.energy(x)
        val += self.weight * pot
        return float(val) if np.isfinite(val) else np.inf

    def gradient(self, x, f_int):
        """grad E on the free DOFs: M (x - x~) + a h^2 (-f_int - f_ext + (alpha M + beta H_t) v + grad B)."""
        free = self.free
        g = self.system.Mff @ (x - self.x_tilde)[free] - self.weight * (f_int + self.f_ext)[free]
        if self.damping_matrix is not None:
            g += self.weight * (self.damping_matrix @ (x - self.x_hat)[free])
        if self.barrier is not None:
            g += self.weight * self.barrier.gradient(x)
        return g

    def hessian_data(self, H, x=None):
        """Data of grad^2 E = M + a h^2 (H + (alpha M + beta H_t)/(c h) + grad^2 B(x)) on the free-DOF pattern.

        The barrier term is included when ``x`` is given.
        """
        data = self.system.mass_data + self.weight * (H + self.damping_data)
        if x is not None and self.barrier is not None:
            data += self.weight * self.barrier.hessian_data(x)
        return data

    def barrier_data(self, x):
        """a h^2 grad^2 B(x) on the free-DOF pattern, or None without colliders."""
        return None if self.barrier is None else self.weight * self.barrier.hessian_data(x)

    def hessian(self, H, x=None):
        """grad^2 E as a CSR matrix on the free DOFs (see :meth:`hessian_data`); with ``x``, also
        the contact terms off the elastic pattern (:meth:`contact_hessian`)."""
        A = self.system.pattern.matrix(self.hessian_data(H, x))
        extra = None if x is None else self.contact_hessian(x)
        return A if extra is None else (A + extra).tocsr()

    def contact_hessian(self, x):
        """a h^2 grad^2 B(x) of a contact model whose Hessian couples vertices that are not mesh
        neighbours (body-body and self contact, :class:`skfem_affine.contact.ipc.IPCContact`) as a
        CSR matrix on the free DOFs, or None (no such contact: its Hessian is in :meth:`hessian_data`)."""
        if self.barrier is None or not hasattr(self.barrier, "hessian"):
            return None
        return self.weight * self.barrier.hessian(x)

    def max_step(self, x, d):
        """Largest step fraction along d (free DOFs) that keeps vertices off the colliders (<= 1)."""
        if self.barrier is None:
            return 1.0
        full = np.zeros_like(x)
        full[self.free] = d
        return self.barrier.max_step(x, full)

    def velocity(self, x):
        """v_{t+1} = (x - x_hat) / (c h) (eq. 3, footnote 9)."""
        return (x - self.x_hat) / (self.c * self.h)

    def with_step(self, x, d):
        """x + d with d on the free DOFs."""
        y = x.copy()
        y[self.free] += d
        return y
