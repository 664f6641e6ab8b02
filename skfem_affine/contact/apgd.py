r"""Frictional contact without forming the Delassus operator: accelerated projected gradient (APGD).

The contact problem of :mod:`skfem_affine.contact.pgs` (3 rows n, t1, t2 per contact, u = u0 + W lam,
0 <= lam_n _|_ u_n >= 0, Coulomb's cone ||lam_t|| <= mu lam_n with maximal dissipation) solved with
products W y only, so that W = J A^-1 J^T can be applied through the frame's factor, one forward and
backward solve per product, instead of being formed. The iteration is Nesterov's accelerated
projected gradient with a backtracking step and an adaptive restart, as in Mazhar, Heyn, Negrut and
Tasora, "Using Nesterov's method to accelerate multibody dynamics with friction and contact" (ACM
TOG 2015), on the quadratic 1/2 lam^T W lam + (u0 + s)^T lam over the cones, with two changes:

- **Coulomb, not its convex relaxation**: s_n = mu ||u_t|| (De Saxce's shift, taken at the
  extrapolated point of each iteration), whose fixed points are exactly Coulomb's law, the problem
  PGS solves; without it (``coulomb=False``) the iteration solves the cone complementarity problem,
  whose sliding contacts separate at mu ||u_t||.
- **A per-contact step**: the gradient of contact i is scaled by 1 / (the largest eigenvalue of its
  3 x 3 diagonal block W_ii); a scalar per contact maps its cone onto itself, so the projection
  stays the Euclidean one per contact.

One product W x per iteration (the product at the extrapolated point is the same combination of
the last two), one more per rejected step. The residual and its tolerance are PGS's
(:func:`block_residual`, equal to :func:`skfem_affine.contact.pgs.contact_residual` but from the
diagonal blocks of W alone). Measured against PGS in ``docs/contact.md`` (``benchmarks/matrix_free_bound.py``).
"""
from dataclasses import dataclass, field

import numpy as np

from skfem_affine.checks import integer, nonnegative


def _contacts(lam, name):
    lam = np.asarray(lam, dtype=float)
    if lam.ndim != 1 or lam.size % 3:
        raise ValueError(f"{name} must be a vector with 3 entries per contact, got shape {lam.shape}")
    return lam


def _blocks(blocks, k):
    blocks = np.asarray(blocks, dtype=float)
    if blocks.shape != (k, 3, 3):
        raise ValueError(f"blocks must be the ({k}, 3, 3) diagonal blocks of W, got shape {blocks.shape}")
    return blocks


def diagonal_blocks(W):
    """The (k, 3, 3) diagonal blocks of a dense W (3 rows per contact)."""
    W = np.asarray(W, dtype=float)
    if W.ndim != 2 or W.shape[0] != W.shape[1] or W.shape[0] % 3:
        raise ValueError(f"W must be square with 3 rows per contact, got shape {W.shape}")
    k = W.shape[0] // 3
    idx = 3 * np.arange(k)[:, None] + np.arange(3)
    return W[idx[:, :, None], idx[:, None, :]]


def cone_projection(lam, mu):
    """The Euclidean projection of each contact's (lam_n, lam_t) onto the cone ||lam_t|| <= mu lam_n."""
    lam = _contacts(lam, "lam")
    mu = nonnegative(mu, "mu")
    n, t = lam[0::3], lam.reshape(-1, 3)[:, 1:]
    tn = np.linalg.norm(t, axis=1)
    out = lam.reshape(-1, 3).copy()
    inside = tn <= mu * n
    polar = mu * tn <= -n
    rim = ~(inside | polar)
    pn = (n[rim] + mu * tn[rim]) / (1.0 + mu * mu)
    out[polar] = 0.0
    out[rim, 0] = pn
    out[rim, 1:] = (mu * pn / np.where(tn[rim] > 0, tn[rim], 1.0))[:, None] * t[rim]
    return out.ravel()


def _tangent_steps(blocks):
    a, b, c = blocks[:, 1, 1], blocks[:, 1, 2], blocks[:, 2, 2]
    return 0.5 * (a + c) + np.sqrt(0.25 * (a - c) ** 2 + b * b)


def block_residual(blocks, u, lam, mu):
    """(complementarity, cone) of the impulses lam with velocities u = u0 + W lam, from W's diagonal
    blocks (k, 3, 3): the largest over the contacts, m/s, as
    :func:`skfem_affine.contact.pgs.contact_residual` defines them (a contact with W_nn <= 0 skipped)."""
    lam, u = _contacts(lam, "lam"), _contacts(u, "u")
    if u.size != lam.size:
        raise ValueError(f"u and lam must have the same size, got {u.size} and {lam.size}")
    blocks = _blocks(blocks, lam.size // 3)
    mu = nonnegative(mu, "mu")
    act = blocks[:, 0, 0] > 0
    rn = np.abs(np.minimum(u[0::3], blocks[:, 0, 0] * lam[0::3]))
    step = _tangent_steps(blocks)
    ok = step > 0
    s = np.where(ok, step, 1.0)
    L, U = lam.reshape(-1, 3), u.reshape(-1, 3)
    t = L[:, 1:] - U[:, 1:] / s[:, None]
    tn = np.linalg.norm(t, axis=1)
    bound = mu * np.maximum(L[:, 0], 0.0)
    t = t * np.where(tn > bound, bound / np.where(tn > 0, tn, 1.0), 1.0)[:, None]
    rt = np.where(ok, step * np.linalg.norm(t - L[:, 1:], axis=1), 0.0)
    return float(rn[act].max(initial=0.0)), float(rt[act].max(initial=0.0))


@dataclass
class Result:
    """What :func:`apgd` returns: the impulses with the smallest residual met, W lam for them, the
    iterations and products W y spent, that residual (max of complementarity and cone, m/s), the goal
    it was compared with, and the residual after each iteration."""

    lam: np.ndarray
    W_lam: np.ndarray
    iterations: int
    products: int
    residual: float
    goal: float
    converged: bool
    history: list = field(default_factory=list)


def apgd(apply, u0, lam, mu, blocks, goal, max_products=1000, coulomb=True, accelerate=True, steps=None):
    """Solve the frictional contact problem of PGS with products ``apply(y) = W y`` only.

    Parameters
    ----------
    apply : callable
        y (3k,) -> W y (3k,); each call is counted as one product.
    u0 : ndarray (3k,)
        The contacts' free velocities (with the bias), as PGS takes them.
    lam : ndarray (3k,)
        The start (a warm start, or zeros); projected onto the cones first. Not modified.
    mu : float
        Coulomb's coefficient.
    blocks : ndarray (k, 3, 3)
        W's diagonal blocks: the residual, and the per-contact step unless ``steps`` is given.
    goal : float
        Stop once the residual (:func:`block_residual`, m/s) is at most this.
    max_products : int
        The most products W y.
    coulomb : bool
        De Saxce's shift (Coulomb's law, the problem PGS solves); False: the convex relaxation (the
        iterate returned is still the one of least PGS residual, which that relaxation need not reduce).
    accelerate : bool
        Nesterov's extrapolation with restarts; False: plain projected (Jacobi-like) gradient steps.
    steps : ndarray (k, 3, 3), optional
        Other blocks for the per-contact steps (e.g. those of J M^-1 J^T, which need no solve);
        default ``blocks``. The solution does not depend on them, the products spent do.

    Returns
    -------
    Result
    """
    if not callable(apply):
        raise TypeError(f"apply must be callable (y -> W y), got {type(apply).__name__}")
    u0 = _contacts(u0, "u0")
    lam = _contacts(lam, "lam")
    if lam.size != u0.size:
        raise ValueError(f"lam and u0 must have the same size, got {lam.size} and {u0.size}")
    blocks = _blocks(blocks, u0.size // 3)
    mu = nonnegative(mu, "mu")
    goal = nonnegative(goal, "goal")
    max_products = integer(max_products, "max_products", low=1)
    top = np.linalg.eigvalsh(blocks if steps is None else _blocks(steps, u0.size // 3))[:, -1]
    d = np.repeat(np.where(top > 0, 1.0 / np.where(top > 0, top, 1.0), 0.0), 3)  # per-contact step
    inv_d = np.where(d > 0, 1.0 / np.where(d > 0, d, 1.0), 0.0)

    def product(y):
        return np.asarray(apply(y), dtype=float)

    x = cone_projection(lam, mu)
    Wx = product(x)
    products = 1
    best = Result(x, Wx, 0, products, max(block_residual(blocks, u0 + Wx, x, mu)), goal, False)
    best.converged = best.residual <= goal
    history = [best.residual]
    y, Wy, theta, L, it = x, Wx, 1.0, 1.0, 0
    while not best.converged and products < max_products:
        it += 1
        uy = u0 + Wy
        g = uy.copy()
        if coulomb:
            g[0::3] += mu * np.linalg.norm(uy.reshape(-1, 3)[:, 1:], axis=1)
        while True:  # backtracking: f(x') <= f(y) + g.(x' - y) + L/2 |x' - y|^2 in the metric of the steps
            xn = cone_projection(y - (d / L) * g, mu)
            Wxn = product(xn)
            products += 1
            dx = xn - y
            norm2 = float(dx @ (inv_d * dx))
            curvature = float(dx @ (Wxn - Wy))  # f(x') - f(y) - g.(x' - y) = dx.W dx / 2 for the quadratic
            if curvature <= L * norm2 * (1 + 1e-12) or products >= max_products:
                break
            L = max(2.0 * L, curvature / norm2)
        res = max(block_residual(blocks, u0 + Wxn, xn, mu))
        history.append(res)
        if res < best.residual:
            best = Result(xn, Wxn, it, products, res, goal, res <= goal)
        if not accelerate or float(g @ (xn - x)) > 0:  # no extrapolation, or a restart
            y, Wy, theta_n = xn, Wxn, 1.0
        else:
            theta_n = 0.5 * (-theta * theta + theta * np.sqrt(theta * theta + 4.0))
            beta = theta * (1.0 - theta) / (theta * theta + theta_n)
            y, Wy = xn + beta * (xn - x), Wxn + beta * (Wxn - Wx)
        x, Wx, theta = xn, Wxn, theta_n
        L *= 0.9
    best.iterations, best.products, best.history = it, products, history  # the work spent, whichever is best
    return best
