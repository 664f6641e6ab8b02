r"""Frictional contact by projected Gauss-Seidel (paper sec. 3.1, 3.3, 3.4 and Algorithm 1).

One frame, in the order of Algorithm 1:

1. **Find contacts** (:meth:`Contact.detect`, at x_t; :mod:`skfem_affine.contact.geometry`):
   free vertices against the static colliders and the boundary triangles of the other
   bodies, and sharp surface edges of different bodies against each other. The three Jacobian
   rows of contact i give the relative velocity ``u_i = [n, t1, t2]^T (v_a - sum_k w_k v_k)`` of
   the vertex a against the closest point (barycentric weights w_k; for a collider, against the
   static obstacle; for two edges, of the closest point on one against the other's).
2. **Prediction impulses** (sec. 3.4): the oracle's one PCG iteration gets
   ``J^T lambda_pred`` as explicit impulses: the warm-started impulses of contacts
   that persist, and, for new contacts, a cheap bilateral estimate (one Jacobi step
   on J_n v = -b_n with the lumped-mass Delassus J_n M^-1 J_n^T), so that an impact
   elastifies the right region before it happens (:meth:`Contact.prediction_impulse`).
3. The elastic (reduced) solve gives ``dv`` (eq. 10-12).
4. **PGS contact solve** (:meth:`Contact.resolve`): with the Delassus operator
   ``W = J A^-1 J^T``, applied through the reducer's factorised
   :class:`~skfem_affine.integrators.problem.Operator` (:mod:`skfem_affine.contact.delassus`,
   through G in a reduced frame), PGS finds impulses lambda with

   .. math:: u = J(\dot x_t + \Delta\dot x) + b + W\lambda, \qquad
             0 \le \lambda_n \perp u_n \ge 0, \qquad
             \|\lambda_t\| \le \mu \lambda_n \ (\text{Coulomb cone, maximal dissipation}),

   with the bias ``b_n = (d - slop) / h`` for a gap beyond the slop (speculative contact: the
   vertex may close it within the step but not cross), ``b_n = 0`` for a penetration (it may not
   deepen) and for a gap within the slop (the vertex touches: a rest offset). The slop, 1e-5 of
   a surface edge by default, keeps resting contacts solvable: a gap of a few nanometres that a
   solve leaves on one of an affine body's many coplanar contacts would otherwise ask for a
   velocity no affine motion gives it alone (the contacts' W has rank 12 per body).
   Restitution is zero. By default (``PGS(solver="block")``) groups of strongly coupled contacts
   are solved together (:func:`block_gauss_seidel`); ``PGS(solver="gauss-seidel")`` runs the plain
   sweeps and ``PGS(solver="anderson")`` accelerates them by Anderson mixing of the last few
   (:func:`anderson_gauss_seidel`). The velocity correction is
   ``dv_c = A^-1 J^T lambda`` (one more solve), and v_{t+1} = v_t + dv + dv_c.
5. **Penetration** (split impulse, :meth:`Contact.resolve` sets :attr:`Contact.correction`):
   when a contact penetrates (d < 0, e.g. bodies that start overlapping or inside a collider),
   a second, frictionless PGS finds a pseudo-velocity ``w = G M_G^-1 G^T J^T mu`` of the *rigid
   motions* G of the bodies without fixed vertices (M_G = G^T M G) with
   ``0 <= mu_n _|_ J(v_{t+1} + w) + b' >= 0``, ``b'_n = max(erp d, -push_limit) / h`` for a
   penetration and ``d / h`` for a gap, and the positions move by it,
   x_{t+1} = x_t + h (v_{t+1} + w), while the velocities keep v_{t+1}. Pushing out thus adds
   no kinetic energy (Baumgarte on the velocities launched bodies out of a penetration) and,
   being rigid, no strain energy (which would make the body spring off): a penetration shrinks
   by the fraction ``erp`` per step, by at most ``push_limit`` (default one mean surface edge),
   and stops when it is resolved. Its operator ``J_n G M_G^-1 G^T J_n^T = B B^T`` has rank at
   most 6 per body and is never formed: ``B = J_n G C`` with ``C C^T = M_G^-1`` (C block
   diagonal, 6 x 6 per body), and the PGS sweep keeps ``B^T mu``
   (:func:`projected_gauss_seidel_lowrank`), with the contact solve's stopping rule and extra sweeps:
   a correction left above :data:`UNRESOLVED` of the frame's velocity scale marks the frame
   unresolved (its penetrations would pile up from frame to frame). Bodies with fixed vertices are held by them and are not
   moved by the correction (their penetrations may not deepen, by the velocity constraint).

Friction is the isotropic Coulomb *cone*: each PGS step projects the tangential
impulse pair onto the disk of radius ``mu lambda_n`` (not a box per tangent).
Impulses are stored in world coordinates and matched next frame by a contact
identity (vertex, collider) or (vertex, other body), so a vertex sliding across
triangles keeps its warm start.
"""

import time
import warnings
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from numba import njit

from skfem_affine import _compile_notice  # noqa: F401 (one stderr line when the cached kernels compile)
from skfem_affine.checks import flag, integer, nonnegative, positive, real
from skfem_affine.contact.colliders import check_colliders
from skfem_affine.contact.delassus import Resolvent, block_solver, jacobian, vertex_unknowns
from skfem_affine.contact.dense import DENSE_MAX
from skfem_affine.contact.schur import SchurInverse
from skfem_affine.contact.geometry import Detector
from skfem_affine.monitor import SimulationWarning
from skfem_affine.reducers.affine.mapping import group_sum
from skfem_affine.threads import serial_blas

# The contact model this module implements, as recorded in ``sim.stats`` ("contact_model").
MODEL = "pgs"

# A frame's contact is unresolved (a warning, ``contact_unresolved`` in ``sim.stats``) when the residual of
# its PGS solve or of its penetration correction is above this fraction of the velocity the contacts remove.
UNRESOLVED = 0.01

# The default slop of PGS, in mean surface edge lengths.
SLOP = 1e-5


@dataclass(frozen=True)
class PGS:
    """Settings of the projected Gauss-Seidel contact solver.

    Parameters
    ----------
    friction : float
        Coulomb coefficient mu >= 0 (the cone ||lambda_t|| <= mu lambda_n).
    iterations : int
        Gauss-Seidel sweeps per frame (>= 1) before the solve stops short of ``tolerance``.
    max_iterations : int, optional
        Sweeps allowed while contact is still unresolved after ``iterations`` (residual above
        :data:`UNRESOLVED` times the velocity to remove, e.g. a heavy stiff body on a light one);
        default 40 times ``iterations``; ``iterations`` turns the extra sweeps off.
    tolerance : float
        A sweep ends the iteration when the contact residual (complementarity and the friction
        cone, in m/s; :func:`contact_residual`) is at most ``tolerance`` times the largest
        velocity the contacts may have to remove (:func:`velocity_scale`). The residual of
        every frame is in ``sim.stats`` (``contact_residual``).
    erp : float
        Error reduction in [0, 1]: a penetration d < 0 shrinks by ``erp |d|`` per step (a
        position correction that adds no velocity; see the module docstring).
    push_limit : float, optional
        Largest position correction of a penetration per step (m, > 0); default the mean
        surface edge length.
    slop : float, optional
        Gap (m, >= 0) below which a contact counts as touching (no speculative bias: the vertex
        may not approach); default 1e-5 of the mean surface edge length (:data:`SLOP`).
    margin : float, optional
        Speculative contact distance (m); default a fifth of the mean surface edge
        length. A vertex becomes a contact when its gap is below ``margin + 2 h`` times its
        normal approach speed (relative to the other body).
    warm_start : bool
        Start from the previous frame's impulses matched by contact identity.
    body_contact : bool
        Detect contact between different bodies (vertices vs boundary triangles, sharp edges
        vs sharp edges).
    block : int
        Columns of J^T solved at once when building the Delassus operator (memory bound).
    edge_contact : bool
        Edge-edge contacts between sharp surface edges of different bodies
        (:mod:`~skfem_affine.contact.edges`), so that edges cannot cross where no vertex meets a
        face; False leaves vertex contacts only (cheaper for stacks of coarse curved bodies,
        whose many sharp edges add contacts).
    solver : str
        The iteration on the contact problem: ``"block"`` (default: block Gauss-Seidel over groups
        of strongly coupled contacts, :func:`block_gauss_seidel`: contacts that are almost the same
        constraint, as where two soft bodies meet, solved together; measured in
        ``docs/contact.md``), ``"gauss-seidel"`` (plain sweeps, :func:`projected_gauss_seidel`) or
        ``"anderson"`` (sweeps accelerated by Anderson mixing of the last few,
        :func:`anderson_gauss_seidel`). All solve the same problem to the same residual;
        ``iterations`` and ``max_iterations`` count sweeps in each.
    schur : bool
        Build the Delassus operator of a one-body system from the Schur complement of the frame's
        matrix on the unknowns the contacts touch (MKL Pardiso, :mod:`~skfem_affine.contact.schur`)
        where that is cheaper than solving their unit columns; False always solves them. In full
        space that complement comes from the frame's own factorisation, made with those unknowns last
        (``SchurInverse.frame``).
    """

    friction: float = 0.5
    iterations: int = 50
    tolerance: float = 1e-6
    erp: float = 0.2
    margin: float = None
    push_limit: float = None
    warm_start: bool = True
    body_contact: bool = True
    block: int = 64
    edge_contact: bool = True
    max_iterations: int = None
    solver: str = "block"
    schur: bool = True
    slop: float = None

    def __post_init__(self):
        put = object.__setattr__  # frozen: store the checked values
        for name in ("friction", "tolerance"):
            put(self, name, nonnegative(getattr(self, name), f"PGS {name}"))
        put(self, "iterations", integer(self.iterations, "PGS iterations", low=1))
        put(self, "erp", real(self.erp, "PGS erp", low=0.0, high=1.0))
        if self.margin is not None:
            put(self, "margin", nonnegative(self.margin, "PGS margin"))
        if self.push_limit is not None:
            put(self, "push_limit", positive(self.push_limit, "PGS push_limit"))
        if self.slop is not None:
            put(self, "slop", nonnegative(self.slop, "PGS slop"))
        put(self, "warm_start", flag(self.warm_start, "PGS warm_start"))
        put(self, "body_contact", flag(self.body_contact, "PGS body_contact"))
        put(self, "block", integer(self.block, "PGS block", low=1))
        put(self, "edge_contact", flag(self.edge_contact, "PGS edge_contact"))
        put(self, "schur", flag(self.schur, "PGS schur"))
        if self.max_iterations is not None:
            put(self, "max_iterations", integer(self.max_iterations, "PGS max_iterations", low=self.iterations))
        if not isinstance(self.solver, str) or self.solver not in SOLVERS:
            raise ValueError(f"PGS solver must be one of {sorted(SOLVERS)}, got {self.solver!r}")

    @property
    def sweep_limit(self):
        """The most sweeps of a frame: ``max_iterations``, default 40 ``iterations``."""
        return 40 * self.iterations if self.max_iterations is None else self.max_iterations


@njit(cache=True, inline="always")
def _tangent_step(W, r):
    """The largest eigenvalue of the 2 x 2 tangent block of the contact at row r (its gradient step)."""
    a, b, c = W[r + 1, r + 1], W[r + 1, r + 2], W[r + 2, r + 2]
    return 0.5 * (a + c) + np.sqrt(0.25 * (a - c) ** 2 + b * b)


@njit(cache=True, inline="always")
def _disk(t1, t2, bound):
    """(t1, t2) projected onto the disk of radius ``bound``."""
    norm = np.sqrt(t1 * t1 + t2 * t2)
    if norm > bound:
        scale = bound / norm
        return t1 * scale, t2 * scale
    return t1, t2


@njit(cache=True, inline="always")
def _contact_error(W, u, lam, mu, r):
    """(complementarity, cone) residual of the contact at row r, in velocity units (m/s).

    Complementarity ``|min(u_n, W_nn lam_n)|``: zero exactly when ``0 <= lam_n _|_ u_n >= 0``.
    Cone: ``step |lam_t - P(lam_t - u_t / step)|`` with P the projection onto the disk of radius
    ``mu lam_n`` and step the tangent block's largest eigenvalue: zero exactly when lam_t lies in
    the cone and is Coulomb's maximal dissipation (the fixed point of the PGS tangent step).
    """
    rn = abs(min(u[r], W[r, r] * lam[r]))
    step = _tangent_step(W, r)
    if step <= 0.0:
        return rn, 0.0
    t1, t2 = _disk(lam[r + 1] - u[r + 1] / step, lam[r + 2] - u[r + 2] / step, mu * max(lam[r], 0.0))
    return rn, step * np.sqrt((t1 - lam[r + 1]) ** 2 + (t2 - lam[r + 2]) ** 2)


@njit(cache=True)
def velocity_scale(u0):
    """The velocity the contacts may have to remove: the largest approach ``-u0_n`` or tangential
    ``|u0_t|`` of the free velocities u0 (3 rows per contact), the unit of the PGS tolerance."""
    s = 0.0
    for r in range(0, u0.size, 3):
        s = max(s, -u0[r], np.sqrt(u0[r + 1] ** 2 + u0[r + 2] ** 2))
    return s


@njit(cache=True)
def contact_residual(W, u0, lam, mu):
    """(complementarity, cone) of the impulses lam: the largest residuals over the contacts, m/s.

    See :func:`_contact_error`; both are zero exactly at a solution of the frictional contact
    problem that :func:`projected_gauss_seidel` solves.
    """
    u = u0 + W @ lam
    rn = rt = 0.0
    for r in range(0, lam.size, 3):
        if W[r, r] <= 0.0:  # a contact no impulse can act on (its vertices fixed): the solver skips it
            continue
        a, b = _contact_error(W, u, lam, mu, r)
        rn, rt = max(rn, a), max(rt, b)
    return rn, rt


@njit(cache=True)
def _worst(W, u, lam, mu):
    """The largest (complementarity, cone) residual over the contacts, from the velocities u = u0 + W lam."""
    worst = 0.0
    for r in range(0, lam.size, 3):
        if W[r, r] > 0.0:
            a, b = _contact_error(W, u, lam, mu, r)
            worst = max(worst, a, b)
    return worst


@njit(cache=True)
def _contact_step(W, u, lam, mu, r, omega):
    """The Gauss-Seidel step of the contact whose normal row is r: lam and u = u0 + W lam in place.

    The normal row by a projected Gauss-Seidel step, then both tangent rows, projected jointly onto
    the disk of radius mu lam_n (Euclidean projection after a gradient step of the 2 x 2 tangent
    block's largest eigenvalue), each step over-relaxed by ``omega`` (1: plain Gauss-Seidel). A
    contact no impulse can act on (W_nn = 0) is skipped.
    """
    m = lam.size
    if W[r, r] <= 0.0:
        return
    new_n = max(0.0, lam[r] - omega * u[r] / W[r, r])
    dn = new_n - lam[r]
    if dn != 0.0:
        lam[r] = new_n
        for j in range(m):
            u[j] += W[r, j] * dn
    # one projected gradient step on both tangents with the largest eigenvalue of their
    # 2 x 2 block: its fixed point is exactly Coulomb's maximal dissipation
    step = _tangent_step(W, r)
    if step <= 0.0:
        return
    t1, t2 = _disk(lam[r + 1] - omega * u[r + 1] / step, lam[r + 2] - omega * u[r + 2] / step, mu * lam[r])
    d1, d2 = t1 - lam[r + 1], t2 - lam[r + 2]
    if d1 != 0.0 or d2 != 0.0:
        lam[r + 1], lam[r + 2] = t1, t2
        for j in range(m):
            u[j] += W[r + 1, j] * d1 + W[r + 2, j] * d2


@njit(cache=True)
def _sweep(W, u, lam, mu):
    """One Gauss-Seidel sweep over the contacts in their order (``_contact_step`` of each)."""
    for r in range(0, lam.size, 3):
        _contact_step(W, u, lam, mu, r, 1.0)


@njit(cache=True)
def _velocities(W, u0, lam):
    """u = u0 + W lam, skipping the zero impulses (a cold start costs nothing)."""
    m = lam.size
    u = u0.copy()
    for i in range(m):
        if lam[i] != 0.0:
            for j in range(m):
                u[j] += W[i, j] * lam[i]
    return u


@njit(cache=True)
def projected_gauss_seidel(W, u0, lam, mu, iterations, tolerance, max_iterations=0, loose=0.0, floor=0.0):
    """PGS on 0 <= lam_n _|_ u_n >= 0, ||lam_t|| <= mu lam_n with u = u0 + W lam (3 rows per contact).

    ``lam`` (3k,) holds the warm start and is updated in place. Per contact: the
    normal row by a projected Gauss-Seidel step, then both tangent rows, projected
    jointly onto the disk of radius mu lam_n (Euclidean projection after a gradient step of
    the 2 x 2 tangent block's largest eigenvalue). A sweep ends the iteration when the contact
    residual (:func:`contact_residual`, from the velocities the sweep kept up to date) is at most
    ``tolerance`` times :func:`velocity_scale` of u0 (at least ``floor``), or after ``iterations`` sweeps; beyond them,
    up to ``max_iterations``, sweeps go on while the residual is above ``loose`` times the scale
    (contact still visibly unresolved). Returns the sweeps done.
    """
    u = _velocities(W, u0, lam)
    scale = max(velocity_scale(u0), floor)
    goal = tolerance * scale
    for sweep in range(max(iterations, max_iterations)):
        _sweep(W, u, lam, mu)
        worst = _worst(W, u, lam, mu)
        if worst <= goal or (sweep + 1 >= iterations and worst <= loose * scale):
            return sweep + 1
    return max(iterations, max_iterations)


@njit(cache=True)
def _project(W, u, lam, mu):
    """lam onto the constraints (lam_n >= 0, lam_t in the disk of radius mu lam_n), u = u0 + W lam kept."""
    m = lam.size
    for r in range(0, m, 3):
        n = max(lam[r], 0.0)
        t1, t2 = _disk(lam[r + 1], lam[r + 2], mu * n)
        d0, d1, d2 = n - lam[r], t1 - lam[r + 1], t2 - lam[r + 2]
        if d0 != 0.0 or d1 != 0.0 or d2 != 0.0:
            lam[r], lam[r + 1], lam[r + 2] = n, t1, t2
            for j in range(m):
                u[j] += W[r, j] * d0 + W[r + 1, j] * d1 + W[r + 2, j] * d2


@njit(cache=True)
def anderson_gauss_seidel(W, u0, lam, mu, iterations, tolerance, max_iterations=0, loose=0.0, floor=0.0, depth=5):
    """PGS accelerated by Anderson mixing of its last ``depth`` sweeps; arguments and stopping rule as
    :func:`projected_gauss_seidel`, whose fixed points (the solutions) it shares.

    Each iteration does one Gauss-Seidel sweep, F(lam), then extrapolates: with the sweep's
    changes g_i = F(lam_i) - lam_i of the last iterations, the combination of the F(lam_i)
    (coefficients summing to one) whose combined change is least in the 2-norm (Anderson
    acceleration, type II), projected back onto the constraints. u = u0 + W lam is affine in lam,
    so the velocities of the combination are the same combination of the sweeps' velocities, and
    an extrapolation costs O(depth) vectors, not a product with W (only the rows of contacts the
    projection moves). The extrapolation is kept when its contact residual is at most the
    sweep's, else the sweep is (a safeguard: never worse than PGS's own step). Returns the sweeps done.
    """
    m = lam.size
    u = _velocities(W, u0, lam)
    scale = max(velocity_scale(u0), floor)
    goal = tolerance * scale
    ring = depth + 1
    F = np.zeros((ring, m))  # the sweeps' impulses F(lam_i), their changes g_i and velocities
    G = np.zeros((ring, m))
    U = np.zeros((ring, m))
    done = 0
    for sweep in range(max(iterations, max_iterations)):
        slot = sweep % ring
        G[slot] = -lam
        _sweep(W, u, lam, mu)
        G[slot] += lam
        F[slot], U[slot] = lam, u
        worst = _worst(W, u, lam, mu)
        n = min(sweep + 1, ring) - 1  # differences against the newest
        if n > 0 and worst > goal:
            dG = np.empty((m, n))
            q = 0
            for i in range(ring):
                if i != slot and i < sweep + 1:
                    dG[:, q] = G[slot] - G[i]
                    q += 1
            A = dG.T @ dG
            for i in range(n):
                A[i, i] += 1e-12 * A[i, i] + 1e-300
            gamma = np.linalg.solve(A, dG.T @ G[slot])
            x, v = F[slot].copy(), U[slot].copy()
            q = 0
            for i in range(ring):
                if i != slot and i < sweep + 1:
                    x -= gamma[q] * (F[slot] - F[i])
                    v -= gamma[q] * (U[slot] - U[i])
                    q += 1
            _project(W, v, x, mu)
            mixed = _worst(W, v, x, mu)
            if mixed <= worst:
                lam[:], u[:], worst = x, v, mixed
        done = sweep + 1
        if worst <= goal or (done >= iterations and worst <= loose * scale):
            return done
    return done


@njit(cache=True)
def projected_gauss_seidel_lowrank(indptr, indices, data, ncols, u0, lam, iterations, tolerance, max_iterations=0,
                                   loose=0.0, floor=0.0):
    """Frictionless PGS on 0 <= lam _|_ u = u0 + B B^T lam >= 0 with the rows of B as CSR.

    W = B B^T is never formed: the sweep keeps w = B^T lam (one entry per column of B, e.g.
    6 per rigid body), so row i costs its own nonzeros, ``u_i = u0_i + B_i w`` and ``W_ii = |B_i|^2``.
    Stops when ``|min(u_i, W_ii lam_i)|`` is at most ``tolerance`` times the largest approach
    ``-u0_i`` (at least ``floor``), or after ``iterations`` sweeps; beyond them, up to ``max_iterations``,
    sweeps go on while it is above ``loose`` times that scale (as :func:`projected_gauss_seidel`). ``lam`` is
    updated in place; returns w (ncols,).
    """
    k = lam.size
    w = np.zeros(ncols)
    diag = np.zeros(k)
    scale = 0.0
    for i in range(k):
        scale = max(scale, -u0[i])
        for p in range(indptr[i], indptr[i + 1]):
            diag[i] += data[p] * data[p]
            w[indices[p]] += data[p] * lam[i]
    scale = max(scale, floor)
    goal = tolerance * scale
    for sweep in range(max(iterations, max_iterations)):
        worst = 0.0
        for i in range(k):
            if diag[i] <= 0.0:
                continue
            u = u0[i]
            for p in range(indptr[i], indptr[i + 1]):
                u += data[p] * w[indices[p]]
            new = max(0.0, lam[i] - u / diag[i])
            d = new - lam[i]
            if d != 0.0:
                lam[i] = new
                for p in range(indptr[i], indptr[i + 1]):
                    w[indices[p]] += data[p] * d
        for i in range(k):
            if diag[i] > 0.0:
                u = u0[i]
                for p in range(indptr[i], indptr[i + 1]):
                    u += data[p] * w[indices[p]]
                worst = max(worst, abs(min(u, diag[i] * lam[i])))
        if worst <= goal or (sweep + 1 >= iterations and worst <= loose * scale):
            break
    return w


@njit(cache=True)
def _lumped_diagonal(indptr, indices, data, inv_mass):
    """The diagonal of J M^-1 J^T (J as CSR, M lumped: ``inv_mass`` per column), each row summed in order."""
    out = np.zeros(indptr.size - 1)
    for i in range(out.size):
        for p in range(indptr[i], indptr[i + 1]):
            out[i] += data[p] * data[p] * inv_mass[indices[p]]
    return out


# PGS(solver="block"): contacts whose rows of W are coupled by more than COUPLING (the largest
# |W_ij| / sqrt(W_ii W_jj) over their two 3 x 3 blocks) are solved together, in groups of at most
# GROUP contacts, each visit by up to INNER sweeps on the group's own block, costing at most WORK
# times the group's plain Gauss-Seidel steps, until the group's residual is at most VISIT times the
# tolerance's.
COUPLING = 0.5
GROUP = 64
INNER = 1000
WORK = 4
VISIT = 0.5


@njit(cache=True)
def _find(parent, i):
    """The root of i in the union-find forest ``parent``, halving the path."""
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


@njit(cache=True)
def _joined(pairs, order, k, largest):
    """The union-find forest of k contacts joining ``pairs`` in ``order`` while their groups keep at most
    ``largest`` contacts, each group's root its first contact."""
    parent = np.arange(k)
    size = np.ones(k, dtype=np.int64)
    for p in order:
        a, b = _find(parent, pairs[p, 0]), _find(parent, pairs[p, 1])
        if a != b and size[a] + size[b] <= largest:
            if a > b:
                a, b = b, a
            parent[b] = a
            size[a] += size[b]
    return parent


@njit(cache=True)
def _coupled_pairs(W, coupling):
    """The pairs of contacts (i < j, in that order) coupled above ``coupling`` and their couplings."""
    k = W.shape[0] // 3
    inv = np.zeros(3 * k)
    for i in range(3 * k):
        if W[i, i] > 0.0:
            inv[i] = 1.0 / np.sqrt(W[i, i])
    pairs, values = np.empty((16, 2), dtype=np.int64), np.empty(16)
    n = 0
    row = np.empty(3 * k)
    for i in range(k):
        s0, s1, s2 = inv[3 * i], inv[3 * i + 1], inv[3 * i + 2]
        w0, w1, w2 = W[3 * i], W[3 * i + 1], W[3 * i + 2]
        for q in range(3 * i + 3, 3 * k):  # the largest coupling of contact i's rows to each row after i's
            row[q] = max(max(abs(w0[q]) * s0 * inv[q], abs(w1[q]) * s1 * inv[q]), abs(w2[q]) * s2 * inv[q])
        for j in range(i + 1, k):
            c = max(row[3 * j], row[3 * j + 1], row[3 * j + 2])
            if c > coupling:
                if n == values.size:
                    grown, more = np.empty((2 * n, 2), dtype=np.int64), np.empty(2 * n)
                    grown[:n], more[:n] = pairs, values
                    pairs, values = grown, more
                pairs[n, 0], pairs[n, 1], values[n] = i, j, c
                n += 1
    return pairs[:n], values[:n]


@njit(cache=True)
def _largest_set(parent):
    """The size of the largest set of the union-find forest ``parent``."""
    size = np.zeros(parent.size, dtype=np.int64)
    for i in range(parent.size):
        size[_find(parent, i)] += 1
    return size.max() if parent.size else 0


@njit(cache=True)
def _strongest_first(values):
    """The order of ``values``, largest first (a tie is ordered as this sort leaves it)."""
    return np.argsort(-values)


@njit(cache=True)
def _members(parent):
    """(ptr, members) of the groups of the forest ``parent``: by first contact, each in order."""
    k = parent.size
    root = np.empty(k, dtype=np.int64)
    for i in range(k):
        root[i] = _find(parent, i)
    members = np.argsort(root * k + np.arange(k))
    ptr = np.zeros(k + 1, dtype=np.int64)
    g = 0
    for q in range(k):
        if q > 0 and root[members[q]] != root[members[q - 1]]:
            g += 1
            ptr[g] = q
    ptr[g + 1] = k
    return ptr[:g + 2], members


def _groups(W, coupling, largest):
    """(ptr, members) of :func:`contact_groups` (arguments checked there)."""
    k = W.shape[0] // 3
    pairs, values = _coupled_pairs(W, coupling)
    # the strongest pairs first, joined while their groups stay within ``largest`` contacts; when no
    # connected set of coupled contacts is larger, every pair joins whatever the order: no sort
    parent = _joined(pairs, np.arange(values.size), k, k)
    if _largest_set(parent) > largest:
        parent = _joined(pairs, _strongest_first(values), k, largest)
    return _members(parent)


def contact_groups(W, coupling=COUPLING, largest=GROUP):
    """Groups of strongly coupled contacts for block Gauss-Seidel (:func:`block_gauss_seidel`).

    Two contacts are coupled by the largest ``|W_ij| / sqrt(W_ii W_jj)`` over their 3 x 3 block
    (1 for two contacts that are the same constraint, e.g. a vertex of one body on a triangle of
    another and a vertex of that triangle on the first body's triangle, meeting at one point).
    Pairs coupled above ``coupling`` are joined, the strongest first, while their group keeps at
    most ``largest`` contacts.

    Returns
    -------
    ptr, members : ndarray of int
        Group g holds the contacts ``members[ptr[g]:ptr[g + 1]]`` (increasing); the groups are
        ordered by their first contact, so that without coupled pairs the order is the contacts'.
    """
    coupling = real(coupling, "coupling", low=0.0, high=1.0, include_low=False)
    largest = integer(largest, "largest", low=1)
    W = np.asarray(W, dtype=float)
    if W.ndim != 2 or W.shape[0] != W.shape[1] or W.shape[0] % 3:
        raise ValueError(f"W must be square with 3 rows per contact, got shape {W.shape}")
    return _groups(W, float(coupling), int(largest))


@njit(cache=True)
def _block_visit(W, u, lam, mu, rows, Wl, inner, goal):
    """Up to ``inner`` Gauss-Seidel sweeps on one group's block ``Wl = W[rows][:, rows]`` with its own
    velocities (stopping once its residual is at most ``goal``), then u updated by the change."""
    nr = rows.size
    ul, ll = u[rows], lam[rows]  # copies (fancy indexing)
    for _ in range(inner):
        for r in range(0, nr, 3):
            _contact_step(Wl, ul, ll, mu, r, 1.0)
        if _worst(Wl, ul, ll, mu) <= goal:
            break
    m = lam.size
    for i in range(nr):
        d = ll[i] - lam[rows[i]]
        if d != 0.0:
            lam[rows[i]] = ll[i]
            for j in range(m):
                u[j] += W[rows[i], j] * d


@njit(cache=True)
def _group_worst(W, u, lam, mu, rows):
    """The largest (complementarity, cone) residual over the contacts of one group (its rows ``rows``)."""
    worst = 0.0
    for q in range(0, rows.size, 3):
        r = rows[q]
        if W[r, r] > 0.0:
            a, b = _contact_error(W, u, lam, mu, r)
            worst = max(worst, a, b)
    return worst


@njit(cache=True)
def _block_gauss_seidel(W, u0, lam, mu, iterations, tolerance, max_iterations, loose, floor, ptr, members, inner, work):
    """The sweeps of :func:`block_gauss_seidel` over the groups (ptr, members) of :func:`contact_groups`."""
    u = _velocities(W, u0, lam)
    scale = max(velocity_scale(u0), floor)
    goal = tolerance * scale
    # the groups' rows (group g: rows[3 ptr[g]:3 ptr[g + 1]]) and blocks of W, gathered once
    ng = ptr.size - 1
    rows = np.empty(3 * members.size, dtype=np.int64)
    for q in range(rows.size):
        rows[q] = 3 * members[q // 3] + q % 3
    start = np.zeros(ng + 1, dtype=np.int64)
    for g in range(ng):
        c = 3 * (ptr[g + 1] - ptr[g])
        start[g + 1] = start[g] + (c * c if c > 3 else 0)
    blocks = np.empty(start[ng])
    for g in range(ng):
        a, b = 3 * ptr[g], 3 * ptr[g + 1]
        if b - a > 3:
            q = start[g]
            for i in range(a, b):
                for j in range(a, b):
                    blocks[q] = W[rows[i], rows[j]]
                    q += 1
    m = lam.size
    for sweep in range(max(iterations, max_iterations)):
        for g in range(ng):
            c = ptr[g + 1] - ptr[g]
            if c == 1:
                _contact_step(W, u, lam, mu, 3 * members[ptr[g]], 1.0)
                continue
            group = rows[3 * ptr[g]:3 * ptr[g + 1]]
            if _group_worst(W, u, lam, mu, group) <= goal:  # already solved to the tolerance: no visit
                continue
            Wl = blocks[start[g]:start[g + 1]].reshape(3 * c, 3 * c)
            # its inner sweeps cost at most ``work`` times its contacts' plain steps (3c x m each)
            _block_visit(W, u, lam, mu, group, Wl, min(inner, max(1, (work * m) // (3 * c))), VISIT * goal)
        worst = _worst(W, u, lam, mu)
        if worst <= goal or (sweep + 1 >= iterations and worst <= loose * scale):
            return sweep + 1
    return max(iterations, max_iterations)


def block_gauss_seidel(W, u0, lam, mu, iterations, tolerance, max_iterations=0, loose=0.0, floor=0.0,
                       coupling=COUPLING, largest=GROUP, inner=INNER, work=WORK):
    """Block Gauss-Seidel over groups of strongly coupled contacts; arguments and stopping rule as
    :func:`projected_gauss_seidel`, whose fixed points (the solutions) it shares.

    The contacts are grouped by :func:`contact_groups` (``coupling``, ``largest``). A sweep visits
    the groups in order: a contact alone takes the plain Gauss-Seidel step; a group of c contacts
    whose residual is already within the tolerance is passed over; any other group takes up to
    ``inner`` sweeps on its own block of W (its velocities kept locally, so that such a sweep costs
    (3c)^2, not a pass over W), until its residual is half the tolerance (:data:`VISIT`) or those
    sweeps have cost ``work`` times the group's plain steps (3c rows of W), and then passes the
    change of its impulses to all velocities (3c rows of W). Contacts that are almost the same constraint
    (between two soft bodies, a vertex of each on the other's triangle at one spot) make plain
    sweeps crawl: their rows of W are nearly parallel, and each step undoes most of the other's;
    solved together they settle in one visit. Without coupled pairs this is exactly
    :func:`projected_gauss_seidel`. Returns the sweeps done (visits of all groups).
    """
    inner = integer(inner, "inner", low=1)
    work = integer(work, "work", low=1)
    ptr, members = contact_groups(W, coupling, largest)
    return _block_gauss_seidel(W, u0, lam, mu, iterations, tolerance, max_iterations, loose, floor, ptr, members,
                               int(inner), int(work))


# The iterations of PGS(solver=...): same arguments, same stopping rule, the sweeps done returned.
SOLVERS = {"gauss-seidel": projected_gauss_seidel, "anderson": anderson_gauss_seidel, "block": block_gauss_seidel}


class Contact:
    """Contact state of one run: detection, warm start and the PGS solve of each frame.

    Built by the simulation (:func:`make_contact`) when it has colliders or several bodies;
    given the :class:`~skfem_affine.integrators.problem.Model`, the frame's state, its
    :class:`~skfem_affine.integrators.problem.StepProblem` and the reducer's
    :class:`~skfem_affine.integrators.problem.StepResult`.
    """

    def __init__(self, model, colliders, settings):
        self.settings = settings or PGS()
        if not isinstance(self.settings, PGS):
            raise TypeError(f"contact must be sa.PGS(...), got {type(settings).__name__}")
        sysm = model.system
        self.detector = Detector(sysm, check_colliders(colliders), self.settings.margin, self.settings.body_contact,
                                 self.settings.edge_contact)
        self.colliders = self.detector.colliders
        self.inv_mass = 1.0 / np.repeat(sysm.lumped_mass, 3)[sysm.free]
        self.previous = None  # (sorted keys, world impulses)
        self.block_solvers = {}  # the Delassus operator's own factorisation (iterative frames with several bodies)
        # the body of each free DOF: the blocks of A the Delassus operator solves side by side
        self.bodies = np.repeat(sysm.body_of_vertex, 3)[sysm.free]
        self.schur = SchurInverse() if self.settings.schur else None  # keeps its analysis across frames
        self.current = None
        self.prediction = None
        self.correction = None
        self.warned = False  # the unresolved-contact warning, once per run
        self.push_limit = self.detector.mean_edge if self.settings.push_limit is None else self.settings.push_limit
        self.slop = SLOP * self.detector.mean_edge if self.settings.slop is None else self.settings.slop
        self._rigid_setup(sysm)

    def _rigid_setup(self, sysm):
        """Which vertices belong to bodies without fixed vertices, their body and free-DOF rows, and
        the sparsity of :meth:`_rigid_motions`' G and C (the same every frame)."""
        body = sysm.body_of_vertex
        pinned = np.zeros(len(sysm.bodies), dtype=bool)
        np.logical_or.at(pinned, body, sysm.fixed)
        movable = np.flatnonzero(~pinned[body])
        dof_map = np.full(3 * sysm.n, -1, dtype=np.int64)
        dof_map[sysm.free] = np.arange(sysm.free.size)
        rank = np.full(len(sysm.bodies), -1)
        rank[~pinned] = np.arange(int((~pinned).sum()))
        nb, owner, rows = int((~pinned).sum()), rank[body[movable]], dof_map[3 * movable[:, None] + np.arange(3)]
        # G: each movable vertex's 3 free-DOF rows hold its body's 6 columns; C: a dense 6 x 6 block per body
        order = np.argsort(rows.ravel(), kind="stable")
        counts = np.zeros(sysm.free.size, dtype=np.int64)
        counts[rows.ravel()] = 6
        g_cols = (6 * np.repeat(owner, 3)[order])[:, None] + np.arange(6)
        c_cols = (6 * np.arange(nb)).repeat(6)[:, None] + np.arange(6)
        self.movable_bodies = nb
        self.rigid = (movable, owner, order, (np.r_[0, np.cumsum(counts)], g_cols.ravel()),
                      (6 * np.arange(6 * nb + 1), c_cols.ravel()), sysm)

    def _rigid_motions(self, x):
        """G (n_free x 6B, sparse): v_i = c_b + omega_b x (x_i - x_b) for the B movable bodies
        (x_b their centres of mass at x), and C (6B x 6B, sparse block diagonal) with
        C C^T = M_G^-1, M_G = G^T M G (C = L^-T for the Cholesky factor L of each body's 6 x 6 block).
        Their sparsity is fixed (:meth:`_rigid_setup`); only the values are computed here."""
        movable, body, order, g_index, c_index, sysm = self.rigid
        nb = self.movable_bodies
        m = sysm.lumped_mass[movable]
        mass = np.bincount(body, m, nb)
        centre = np.stack([np.bincount(body, m * x[movable, k], nb) for k in range(3)], axis=1) / mass[:, None]
        r = x[movable] - centre[body]
        k = movable.size
        vals = np.zeros((k, 3, 6))
        vals[:, :, :3] = np.eye(3)
        # omega x r = -[r]_x omega
        vals[:, 0, 4], vals[:, 0, 5] = r[:, 2], -r[:, 1]
        vals[:, 1, 3], vals[:, 1, 5] = -r[:, 2], r[:, 0]
        vals[:, 2, 3], vals[:, 2, 4] = r[:, 1], -r[:, 0]
        G = sp.csr_matrix((vals.reshape(-1, 6)[order].ravel(), g_index[1], g_index[0]),
                          shape=(sysm.free.size, 6 * nb))
        # the bodies' 6 x 6 blocks of M_G, sum over their vertices of m_i vals_i^T vals_i
        blocks = group_sum(body, m[:, None, None] * np.einsum("kri,krj->kij", vals, vals), nb)
        C = np.linalg.inv(np.linalg.cholesky(blocks)).transpose(0, 2, 1)  # L^-T, upper triangular
        C = sp.csr_matrix((C.ravel(), c_index[1], c_index[0]), shape=(6 * nb, 6 * nb))
        return G, C

    # -------------------------------------------------------------- checkpoint
    def state_dict(self):
        """The warm start carried to the next frame: impulses (world frame) by contact identity."""
        out = {"previous": self.previous is not None, "warned": self.warned}
        if self.previous is not None:
            out.update(previous_keys=self.previous[0].copy(), previous_world=self.previous[1].copy())
        # the per-body solvers of the Delassus operator (a direct solver's ordering history)
        out["blocks"] = [list(key) for key in self.block_solvers]
        for i, solver in enumerate(self.block_solvers.values()):
            if hasattr(solver, "state_dict"):
                out.update({f"block{i}.{k}": v for k, v in solver.state_dict().items()})
        if self.schur is not None:
            out.update(self.schur.state_dict())
        return out

    def load_state_dict(self, state):
        self.previous = ((np.asarray(state["previous_keys"]).copy(), np.asarray(state["previous_world"]).copy())
                         if flag(state["previous"], "previous") else None)
        self.warned = flag(state.get("warned", False), "warned")  # files written before the warning existed lack it
        self.block_solvers = {}
        for i, key in enumerate(state["blocks"]):
            key = tuple(int(k) for k in key)
            solver = block_solver(key[0])
            sub = {k[len(f"block{i}."):]: v for k, v in state.items() if k.startswith(f"block{i}.")}
            if sub and hasattr(solver, "load_state_dict"):
                solver.load_state_dict(sub)
            self.block_solvers[key] = solver
        if self.schur is not None:
            self.schur.load_state_dict(state)

    # -------------------------------------------------------------- frame hooks
    def detect(self, model, x, v, rec, f_ext=None):
        """Algorithm 1, "Find contacts": contacts at (x_t, v_t) (n, 3), their Jacobian, warm start
        and the oracle's prediction impulses J^T lambda_pred (sec. 3.4). Returns the ContactSet or None.

        The approach speeds are those of v_t and of the velocity the step's own acceleration
        leads to, v_t + h (g + f_ext / m) (``f_ext`` (3n,): the frame's vertex forces), so that a
        contact the step can reach under gravity and the forces is found whatever h."""
        t0 = time.perf_counter()
        sysm, h = model.system, model.dt
        a = np.broadcast_to(model.gravity, x.shape)
        if f_ext is not None:
            a = a + f_ext.reshape(-1, 3) / sysm.lumped_mass[:, None]
        w = v + h * a
        w[sysm.fixed] = v[sysm.fixed]  # a fixed vertex (or one on a prescribed path) keeps its velocity
        cs = self.detector.find(x, v, h, w)
        self.current, self.prediction = cs, None
        if cs is not None:
            cs.J = jacobian(cs, sysm.n, sysm.free)
            cs.near_unknowns = vertex_unknowns(cs.near, sysm.n, sysm.free)
            self.Jn = cs.J[0::3]  # the normal rows, sliced once per frame
            self.lam0 = self._warm_start(cs)
            self.bias = self._bias(cs, h)
            vf = v.reshape(-1)[sysm.free]
            self.prediction = cs.J.T @ self._predicted_impulses(cs, w.reshape(-1)[sysm.free])
            cs.impact = self._impacts(cs, vf, model)
        rec["n_contacts"] = 0 if cs is None else cs.size
        # penetrations between bodies at x_t (every penetrating pair is a contact): the frame's record
        # reports them without a second detection at x_{t+1}
        # (of vertices: the gap of two crossed edges is a line-line distance, no depth)
        rec["body_penetration"] = 0.0 if cs is None else float(-cs.distance[self.detector.body_contacts(cs, False)]
                                                                 .min(initial=0.0))
        rec["contact"] = rec.get("contact", 0.0) + time.perf_counter() - t0
        return cs

    def _bias(self, cs, h):
        """b_n = (d - slop) / h for a gap beyond the slop (speculative), 0 within it and for a
        penetration (it may not deepen); tangents 0."""
        d = cs.distance
        b = np.zeros(3 * cs.size)
        b[0::3] = np.maximum(d - self.slop, 0.0) / h
        return b

    def _warm_start(self, cs):
        """Previous impulses of the same contact identities, in the new frames, inside the cone."""
        lam = np.zeros(3 * cs.size)
        if not (self.settings.warm_start and self.previous is not None and self.previous[0].size):
            self.matched = np.zeros(cs.size, dtype=bool)
            return lam
        keys, P = self.previous
        pos = np.minimum(np.searchsorted(keys, cs.key), keys.size - 1)
        self.matched = keys[pos] == cs.key
        local = np.einsum("kij,kj->ki", cs.frames(), np.where(self.matched[:, None], P[pos], 0.0))
        local[:, 0] = np.maximum(local[:, 0], 0.0)
        tn = np.linalg.norm(local[:, 1:], axis=1)
        bound = self.settings.friction * local[:, 0]
        local[:, 1:] *= np.where(tn > bound, bound / np.maximum(tn, 1e-300), 1.0)[:, None]
        return local.ravel()

    def _predicted_impulses(self, cs, v_free):
        """Warm-started impulses, and for contacts without one (new, or carrying none last frame) one
        Jacobi step on the bilateral J_n v = -b_n with the lumped-mass Delassus (sec. 3.4):
        lambda_n = max(0, -(J_n v + b_n)) / (J_n M^-1 J_n^T)."""
        lam = self.lam0.copy()
        Jn = self.Jn
        un = Jn @ v_free + self.bias[0::3]
        wnn = _lumped_diagonal(Jn.indptr, Jn.indices, Jn.data, self.inv_mass)
        new = (self.lam0[0::3] == 0) & (wnn > 0)
        lam[0::3][new] = np.maximum(0.0, -un[new]) / wnn[new]
        return lam

    def _impacts(self, cs, v_free, model):
        """(k,) bool: the contacts that carried no impulse last frame and close their gap at more than
        one step of gravity, ``-(J_n v_t + b_n) > |g| h`` (the velocities before gravity's step).

        The support of a body at rest is not an impact: its contacts keep their warm-started
        impulses, and a resting vertex without one approaches at no more than gravity's step.
        A reducer under an error budget solves a frame with an impact in full space.
        """
        un = self.Jn @ v_free + self.bias[0::3]
        h = model.dt
        speed = max(float(np.linalg.norm(model.gravity)) * h, 1e-6 * model.size / h)
        return (self.lam0[0::3] == 0) & (un < -speed)

    def prediction_impulse(self):
        """J^T lambda_pred on the free DOFs for the oracle's right-hand side (eq. 13), or 0."""
        return 0.0 if self.prediction is None else self.prediction

    def support_impulse(self):
        """J^T lambda_0 on the free DOFs, the warm-started impulses (the support carried over from the
        last frame), or 0."""
        cs = self.current
        if cs is None or not np.any(self.lam0):
            return 0.0
        return cs.J.T @ self.lam0

    def resolve(self, problem, result, rec):
        """PGS contact solve after the elastic step (Algorithm 1): returns dv_c on the free DOFs.

        ``result.dv`` is the elastic step's velocity change and ``result.operator`` its
        factorised system, through which the Delassus operator is applied. Its dense products, solves
        and factorisations are small: the whole solve runs on one OpenBLAS thread
        (:func:`~skfem_affine.threads.serial_blas`), whose idle workers would otherwise spin on the
        cores each call needs.
        """
        with serial_blas():
            return self._resolve(problem, result, rec)

    def _resolve(self, problem, result, rec):
        """:meth:`resolve`, under the thread policy."""
        cs, dv = self.current, result.dv
        self.correction = None
        if cs is None:
            rec["pgs_iterations"] = 0
            self.previous = None
            return np.zeros_like(dv)
        if result.operator is None:
            raise TypeError("PGS contact needs the reducer's factorised operator (StepResult.operator)")
        t0 = time.perf_counter()
        st = self.settings
        resolvent = Resolvent(result.operator, block=st.block, cache=self.block_solvers, schur=self.schur,
                              bodies=self.bodies, dense=DENSE_MAX)
        v_star = problem.v.reshape(-1)[problem.system.free] + dv
        W = resolvent.delassus(cs.J)
        t1 = time.perf_counter()
        lam = self.lam0.copy()
        u0 = cs.J @ v_star + self.bias
        # velocities below a billionth of the scene per step count as rest (bodies touching at rest
        # without gravity have no velocity to remove: no tolerance relative to it could be met)
        floor = 1e-9 * problem.model.size / problem.model.dt
        sweeps = SOLVERS[st.solver](W, u0, lam, float(st.friction), int(st.iterations), float(st.tolerance),
                                    st.sweep_limit, UNRESOLVED, floor)
        self._report(W, u0, lam, sweeps, problem.frame, floor, rec)
        dvc = resolvent.apply(lam)
        d = cs.distance
        if np.any(d < 0) and self.movable_bodies:  # split impulse: push penetrations out through x, rigidly
            h = problem.model.dt
            bn = np.where(d < 0, np.maximum(st.erp * d, -self.push_limit), d) / h
            u1 = self.Jn @ (v_star + dvc) + bn
            G, C = self._rigid_motions(problem.x)
            B = sp.csr_matrix(self.Jn @ G @ C)  # frictionless: the normal rows; W_r = B B^T, rank <= 6 per body
            B.sort_indices()
            mu = np.zeros(cs.size)
            w = projected_gauss_seidel_lowrank(B.indptr, B.indices, B.data, B.shape[1], u1, mu,
                                               int(st.iterations), float(st.tolerance), st.sweep_limit, UNRESOLVED,
                                               rec["contact_scale"])
            self.correction = G @ (C @ w)
            self._report_correction(u1, B @ w, np.asarray(B.multiply(B).sum(axis=1)).ravel(), mu, problem.frame, rec)
        local = lam.reshape(-1, 3)
        world = np.einsum("kij,ki->kj", cs.frames(), local)
        order = np.argsort(cs.key)
        self.previous = (cs.key[order], world[order])
        self.lam = lam
        t2 = time.perf_counter()
        rec.update(pgs_iterations=int(sweeps), delassus=t1 - t0, pgs=t2 - t1,
                   delassus_columns=int(resolvent.columns_solved), delassus_schur=int(resolvent.schur_unknowns),
                   delassus_dense=int(resolvent.dense_unknowns))
        rec["contact"] = rec.get("contact", 0.0) + t2 - t0
        return dvc

    def _report(self, W, u0, lam, sweeps, frame, floor, rec):
        """The frame's contact residual into ``rec``; a warning (once per run) when it is unresolved.

        ``contact_complementarity`` and ``contact_cone`` (m/s, :func:`contact_residual`), their
        maximum ``contact_residual``, ``contact_scale`` (:func:`velocity_scale`), ``pgs_converged``
        (the tolerance was reached within the sweep cap) and ``contact_unresolved``: the residual
        is above :data:`UNRESOLVED` times the scale, so that contact visibly fails (a vertex
        keeps that fraction of its approach: bodies sink into each other or slide out).
        """
        st = self.settings
        normal, cone = contact_residual(W, u0, lam, float(st.friction))
        scale = max(float(velocity_scale(u0)), floor)
        residual = max(normal, cone)
        unresolved = residual > UNRESOLVED * scale
        rec.update(contact_complementarity=float(normal), contact_cone=float(cone), contact_residual=float(residual),
                   contact_scale=scale, pgs_converged=bool(residual <= st.tolerance * scale),
                   contact_unresolved=bool(unresolved))
        if unresolved and not self.warned:
            self.warned = True
            warnings.warn(f"contact unresolved at frame {frame}: after {sweeps} PGS sweeps the contact residual is "
                          f"{residual:.3g} m/s, {residual / scale:.2g} of the {scale:.3g} m/s the contacts remove "
                          f"(bodies may sink into each other; raise PGS(max_iterations=...); further frames are counted "
                          f"in sim.stats['contact_unresolved'], not warned)", SimulationWarning, stacklevel=5)


    def _report_correction(self, u1, Bw, diag, mu, frame, rec):
        """The split impulse's residual into ``rec``; the frame unresolved (a warning, once per run) when
        it is above :data:`UNRESOLVED` times the frame's velocity scale (as the contact solve's).

        ``correction_residual`` (m/s): the largest ``|min(u_n, W_nn mu_n)|`` of its frictionless
        problem (``u = u1 + B w``, ``W_nn = |B_n|^2`` in ``diag``); ``correction_scale`` (m/s): the largest push asked for,
        ``-u1_n``, or the contact solve's ``contact_scale`` when larger. A correction left short keeps that share of its penetrations, which then pile up
        from frame to frame (a heavy body on a light one sinks the light one into the floor).
        """
        acting = diag > 0.0  # a row no rigid motion moves is skipped by the solve
        residual = float(np.abs(np.minimum(u1 + Bw, diag * mu))[acting].max(initial=0.0))
        scale = max(float(np.maximum(-u1[acting], 0.0).max(initial=0.0)), rec["contact_scale"])
        rec.update(correction_residual=residual, correction_scale=scale)
        if residual > UNRESOLVED * scale:
            rec["contact_unresolved"] = True
            if not self.warned:
                self.warned = True
                warnings.warn(f"contact unresolved at frame {frame}: the penetration correction leaves {residual:.3g} m/s "
                              f"of the {scale:.3g} m/s push it was asked for (penetrations pile up from frame to frame; "
                              f"further frames are counted in sim.stats['contact_unresolved'], not warned)",
                              SimulationWarning, stacklevel=5)


def make_contact(model, colliders, settings):
    """The simulation's :class:`Contact`, or None when nothing can touch (one body, no collider)
    or when ``settings is False``."""
    colliders = check_colliders(colliders)
    if settings is False:
        if colliders:
            raise ValueError("contact=False but colliders were given")
        return None
    if settings is not None and not isinstance(settings, PGS):
        raise TypeError(f"contact must be sa.PGS(...), None or False, got {type(settings).__name__}")
    if not colliders and len(model.system.bodies) < 2:
        return None
    return Contact(model, colliders, settings)
