r"""Full-space Newton on the incremental potential (adaptive-subspace paper, sec. 3.1, eq. 1-3).

Each time step minimises

.. math:: E(x) = \tfrac12 \|x - \tilde x\|_M^2 + a h^2 \big(\Psi(x) - f_{ext}^T x + D(x)\big)
          \qquad \text{(eq. 1-2)},

with the predictor :math:`\tilde x`, weight :math:`a` and velocity update of the scheme:

* implicit Euler (eq. 3): :math:`\tilde x = x_t + h v_t`, :math:`a = 1`,
  :math:`v_{t+1} = (x_{t+1} - x_t)/h`;
* BDF2 (the paper's footnote 9): :math:`a = 4/9`,
  :math:`\tilde x = \tfrac13(4x_t - x_{t-1}) + \tfrac{2h}{9}(4v_t - v_{t-1})`,
  :math:`v_{t+1} = \tfrac{3}{2h}\big(x_{t+1} - \tfrac13(4x_t - x_{t-1})\big)`
  (algebraically the footnote's :math:`\tfrac13(4v_t - v_{t-1}) + \tfrac{2h}3 a_{t+1}`).
  The first step, which has no :math:`x_{t-1}`, is implicit Euler.

Both velocities have the form :math:`v = (x - \hat x)/(c h)` (c = 1, resp. 2/3). Rayleigh damping
(not in the paper; the package's ``Rayleigh(alpha, beta)``) enters as the dissipation potential
:math:`D(x) = \frac{1}{2ch}(x - \hat x)^T (\alpha M + \beta H_t)(x - \hat x)`, whose gradient
:math:`a h^2 (\alpha M + \beta H_t) v` is the damping force with the stiffness lagged at
:math:`x_t`. For implicit Euler this is exactly the potential of the package's
``newton_iters`` option, so both converge to the same step.

Newton starts from :math:`x_t` (so its first iterate is the linearized step), takes the
direction :math:`d = -\nabla^2E^{-1}\nabla E` (element Hessians projected to PSD), a backtracking
(Armijo) line search on E, and stops when :math:`\|d\|_\infty / h \le` ``tol`` times the scene
size (the criterion of Li et al., scaled by the bounding-box diagonal as in IPC).
"""
import time

import numpy as np

from skfem_affine.contact.barrier import contact_of

SCHEMES = ("implicit_euler", "bdf2")


def vdot(a, b):
    """a . b for 1-D arrays without a BLAS call (OpenBLAS's thread hand-off costs ~10 ms per dot
    on a loaded 2-core machine, measured; einsum's loop costs microseconds)."""
    return float(np.einsum("i,i->", a, b))


class IncrementalPotential:
    """E(x) of one time step (eq. 2) with its gradient and Hessian on the free DOFs.

    Positions ``x`` are flat (3n,) arrays over all DOFs; fixed DOFs stay at ``x_t``.
    ``x_prev, v_prev`` (the state before ``x_t``) select BDF2; None gives implicit Euler.
    ``start`` is the :class:`~skfem_affine.assembly.FrameData` at ``x_t`` (built if None).
    """

    def __init__(self, sim, x_t, v_t, x_prev=None, v_prev=None, start=None, contact=None):
        sysm = sim.system
        self.sim, self.system, self.free, self.h = sim, sysm, sysm.free, sim.dt
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
        self.f_ext = sim.f_gravity
        self.contact = contact  # barrier.Contact or None (eq. 2's B(x))
        self._start = start
        d = sim.damping
        self.weight = self.a * h * h  # a h^2 in front of the potentials (eq. 2)
        # (alpha M + beta H_t) / (c h), the damping "mass", on the pattern of the free DOFs
        Ht = self.start.H if d.beta else 0.0
        self.damping_data = (d.alpha * sysm.mass_data + d.beta * Ht) / (self.c * h)
        self.damping_matrix = sysm.pattern.matrix(self.damping_data) if (d.alpha or d.beta) else None

    @property
    def has_start(self):
        return self._start is not None

    @property
    def start(self):
        """:class:`~skfem_affine.assembly.FrameData` at x_t (forces, element blocks, H), built on first use."""
        if self._start is None:
            self._start = self.system.evaluate(self.x_t.reshape(-1, 3), project=self.sim.project_hessian)
        return self._start

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
        if self.contact is not None:
            pot += self.contact.energy(x)
        val += self.weight * pot
        return float(val) if np.isfinite(val) else np.inf

    def gradient(self, x, f_int):
        """grad E on the free DOFs: M (x - x~) + a h^2 (-f_int - f_ext + (alpha M + beta H_t) v)."""
        free = self.free
        g = self.system.Mff @ (x - self.x_tilde)[free] - self.weight * (f_int + self.f_ext)[free]
        if self.damping_matrix is not None:
            g += self.weight * (self.damping_matrix @ (x - self.x_hat)[free])
        if self.contact is not None:
            g += self.weight * self.contact.gradient(x)
        return g

    def hessian_data(self, H, x=None):
        """Data of grad^2 E = M + a h^2 (H + (alpha M + beta H_t)/(c h) + grad^2 B(x)) on the free-DOF pattern.

        The barrier term is included when ``x`` is given.
        """
        data = self.system.mass_data + self.weight * (H + self.damping_data)
        if x is not None and self.contact is not None:
            data += self.weight * self.contact.hessian_data(x)
        return data

    def contact_data(self, x):
        """a h^2 grad^2 B(x) on the free-DOF pattern, or None without colliders."""
        return None if self.contact is None else self.weight * self.contact.hessian_data(x)

    def hessian(self, H, x=None):
        return self.system.pattern.matrix(self.hessian_data(H, x))

    def max_step(self, x, d):
        """Largest step fraction along d (free DOFs) that keeps vertices off the colliders (<= 1)."""
        if self.contact is None:
            return 1.0
        full = np.zeros_like(x)
        full[self.free] = d
        return self.contact.max_step(x, full)

    def velocity(self, x):
        """v_{t+1} = (x - x_hat) / (c h) (eq. 3, footnote 9)."""
        return (x - self.x_hat) / (self.c * self.h)

    def with_step(self, x, d):
        """x + d with d on the free DOFs."""
        y = x.copy()
        y[self.free] += d
        return y


def line_search(ip, x, d, g, e0=None, c1=1e-4, min_step=1e-10):
    """Backtracking (Armijo) line search on E(x + alpha d); returns ``(alpha, E(x + alpha d))``.

    ``alpha = 0`` when no decrease is found above ``min_step`` (d is then no descent direction
    at round-off level).
    """
    e0 = ip.energy(x) if e0 is None else e0
    slope = vdot(g, d)
    alpha = ip.max_step(x, d)
    while alpha >= min_step:
        e = ip.energy(ip.with_step(x, alpha * d))
        if e <= e0 + c1 * alpha * min(slope, 0.0):
            return alpha, e
        alpha *= 0.5
    return 0.0, e0


def converged(ip, d, tol):
    """Termination ||d||_inf / h <= tol * scene size (Li et al.; sec. 3.10)."""
    return np.abs(d).max(initial=0.0) / ip.h <= tol * ip.sim.size


def newton_solve(ip, tol, max_iters, solve, rec):
    """Minimise E (eq. 1) by Newton from x_t in full space; returns x_{t+1} (flat).

    ``solve(A, b, rec)`` is the simulation's linear solver. Records ``newton_iters``,
    ``newton_converged``, ``assembly`` and ``line_search`` times in ``rec``.
    """
    sim = ip.sim
    x, data = ip.x_t.copy(), ip.start
    e = ip.energy(x)
    ok = False
    for it in range(max_iters):
        t0 = time.perf_counter()
        if data is None:
            data = sim.system.evaluate(x.reshape(-1, 3), project=sim.project_hessian)
        g = ip.gradient(x, data.f)
        A = ip.hessian(data.H, x)
        rec["assembly"] = rec.get("assembly", 0.0) + time.perf_counter() - t0
        d = solve(A, -g, rec)
        t0 = time.perf_counter()
        alpha, e = line_search(ip, x, d, g, e)
        rec["line_search"] = rec.get("line_search", 0.0) + time.perf_counter() - t0
        x = ip.with_step(x, alpha * d)
        data = None
        rec["newton_iters"] = it + 1
        if converged(ip, d, tol) or alpha == 0.0:
            ok = converged(ip, d, tol)
            break
    rec["newton_converged"] = ok
    return x


def full_space_residual(ip, x):
    """The full-space Newton decrement ||grad^2E^-1 grad E||_inf / h at x (the accuracy of a reduced step)."""
    import scipy.sparse.linalg as spla
    sim = ip.sim
    data = sim.system.evaluate(x.reshape(-1, 3), project=sim.project_hessian)
    d = spla.spsolve(ip.hessian(data.H, x).tocsc(), ip.gradient(x, data.f))
    return float(np.abs(d).max() / ip.h)


class TimeStepper:
    """Implicit Euler or BDF2 steps for a :class:`~skfem_affine.Simulation` (``integrator=``).

    Keeps (x_{t-1}, v_{t-1}) for BDF2; a state changed from outside restarts with implicit Euler.
    A reducer with ``minimize(ip, rec) -> x_{t+1}`` (e.g. :class:`AdaptiveSubspace`) replaces
    the full-space Newton solve.
    """

    def __init__(self, sim, scheme, max_iters, tol):
        if scheme not in SCHEMES:
            raise ValueError(f"integrator must be 'linearized' or one of {SCHEMES}, got {scheme!r}")
        if sim.reducer is not None and not hasattr(sim.reducer, "minimize"):
            raise ValueError(f"{type(sim.reducer).__name__} runs with integrator='linearized'; "
                             f"integrator={scheme!r} needs a reducer such as AdaptiveSubspace")
        self.sim, self.scheme, self.max_iters, self.tol = sim, scheme, int(max_iters), float(tol)
        self.history = None  # (frame, x_prev, v_prev)
        self.contact, self._colliders = None, ()

    def potential(self):
        s = self.sim.state
        prev = (None, None)
        if self.scheme == "bdf2" and self.history is not None and self.history[0] == s.frame - 1:
            prev = self.history[1:]
        colliders = tuple(getattr(self.sim, "colliders", None) or ())
        if tuple(map(id, colliders)) != tuple(map(id, self._colliders)):  # built once per collider set
            self.contact, self._colliders = contact_of(self.sim), colliders
        return IncrementalPotential(self.sim, s.x, s.v, *prev, contact=self.contact)

    def step(self, rec):
        """One step; returns (x, v) as (n, 3) arrays."""
        sim, s = self.sim, self.sim.state
        t0 = time.perf_counter()
        ip = self.potential()
        rec["assembly"] = rec.get("assembly", 0.0) + time.perf_counter() - t0
        rec["integrator"] = ip.scheme
        minimize = getattr(sim.reducer, "minimize", None)
        if minimize is not None:
            x = minimize(ip, rec)
        else:
            x = newton_solve(ip, self.tol, self.max_iters, sim.solve, rec)
        v = ip.velocity(x)  # zero on fixed DOFs, which stay at x_t
        self.history = (s.frame, s.x.copy(), s.v.copy())
        return x.reshape(-1, 3), v.reshape(-1, 3)
